"""The world's per-step loops over vehicles in C (kernels.c, the extension module coopsumo.sim._kernels that
`pip install` builds), equal to their numpy definitions in coopsumo.sim.physics, controller and reward bit for bit.

At 100-300 vehicles the definitions' many small numpy calls, not their arithmetic, were the world's largest
Python cost (docs/performance.md); here each is one call into C, and the controller's step three calls (sight,
decide, after_step). Tested against the definitions on random and hand-made roads and whole runs
(tests/test_fast.py, tests/test_fast_step.py).
"""

from __future__ import annotations

import numpy as np

from coopsumo.sim import _kernels  # type: ignore[attr-defined]  # built from kernels.c
from coopsumo.sim.accident import HoldDraw
from coopsumo.sim.controller import Controls, Decision, LaneState, Sight
from coopsumo.sim.physics import Neighbours, Occupancy
from coopsumo.sim.vehicle_table import VehicleTable


def _i64(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, np.int64)


def _f64(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, np.float64)


def occupancy(lane: np.ndarray, pos: np.ndarray, other_lane: np.ndarray) -> Occupancy:
    """physics.occupancy: every (vehicle, lane) pair a vehicle occupies, sorted by lane then position."""
    lane, pos, other = _i64(lane), _f64(pos), _i64(other_lane)
    m = len(lane) + int(np.count_nonzero((other >= 0) & (other != lane)))
    occ = Occupancy(np.empty(m), np.empty(m, np.int64), np.empty(m), np.empty(m, np.int64))
    _kernels.occupancy(lane, pos, other, occ.keys, occ.lane, occ.pos, occ.veh)
    return occ


def section_crossings(
    prev_nums: np.ndarray, prev_pos: np.ndarray, nums: np.ndarray, pos: np.ndarray, sections_m: np.ndarray
) -> int:
    """reward.section_crossings: vehicles whose front passed a cross-section between two tables sorted by number."""
    return int(_kernels.section_crossings(_i64(prev_nums), _f64(prev_pos), _i64(nums), _f64(pos), _f64(sections_m)))


def followers_mean(
    occ_keys: np.ndarray, occ_value: np.ndarray, lane: np.ndarray, other_lane: np.ndarray, pos: np.ndarray,
    window_m: float,
) -> np.ndarray:
    """reward.followers_mean: per vehicle, the mean value of the vehicles behind it within window_m (m) in every lane
    it occupies; 0 where none is there."""
    out = np.empty(len(pos))
    _kernels.followers_mean(_f64(occ_keys), _f64(occ_value), _i64(lane), _i64(other_lane), _f64(pos), float(window_m),
                            out)  # fmt: skip
    return out


def snapshot(occ: Occupancy, lane: np.ndarray, pos: np.ndarray, n_lanes: int, car_length_m: float) -> np.ndarray:
    """observation.snapshot: the (n, 3, 20) uint8 occupancy grids of every vehicle from the sorted occupancy."""
    out = np.empty((len(lane), 3, 20), np.uint8)
    _kernels.snapshot(_f64(occ.keys), _i64(occ.lane), _f64(occ.pos), _i64(lane), _f64(pos), int(n_lanes),
                      float(car_length_m), out)  # fmt: skip
    return out


def sight(nums: np.ndarray, lane: np.ndarray, pos: np.ndarray, speed: np.ndarray, state: LaneState,
          controls: Controls) -> Sight:  # fmt: skip
    """controller.sight in one call."""
    n = len(nums)
    nums, lane, pos, speed = _i64(nums), _i64(lane), _f64(pos), _f64(speed)
    gaps = np.empty((4, n, 4))  # lead gap, lead speed, follow gap, follow speed
    idx = np.empty((2, n, 4), np.int64)  # lead, follow
    exists = np.empty((n, 4), np.bool_)
    vec = np.empty((3, n))  # expected speed, nearest leader's gap and speed
    other = np.empty(n, np.int64)
    busy = np.empty(n, np.bool_)
    feasible = np.empty((n, 4), np.bool_)
    occ_f = np.empty((2, 2 * n))  # keys, positions
    occ_i = np.empty((2, 2 * n), np.int64)  # lanes, vehicles
    m = _kernels.sight(nums, lane, pos, speed, state.v_exp, state.lc_from, state.lc_to, state.lc_left_s,
                       controls.params, gaps, idx, exists, vec, other, busy, feasible, occ_f[0], occ_i[0], occ_f[1],
                       occ_i[1])  # fmt: skip
    occ = Occupancy(occ_f[0, :m], occ_i[0, :m], occ_f[1, :m], occ_i[1, :m])
    nb = Neighbours(lead_gap=gaps[0], lead_speed=gaps[1], lead_idx=idx[0], follow_gap=gaps[2],
                    follow_speed=gaps[3], follow_idx=idx[1], exists=exists)  # fmt: skip
    return Sight(vec[0], other, busy, occ, nb, vec[1], vec[2], feasible)


def decide(
    nums: np.ndarray, lane: np.ndarray, pos: np.ndarray, speed: np.ndarray, seen: Sight, actions: np.ndarray,
    state: LaneState, sent: np.ndarray, draw: HoldDraw, controls: Controls,
) -> Decision:  # fmt: skip
    """controller.decide in one call (state's arrays are written in place)."""
    n = len(nums)
    ok, rejected, changed = np.empty(n, np.bool_), np.empty(n, np.bool_), np.empty(n, np.bool_)
    target, speeds = np.empty(n, np.int64), np.empty(n)
    _kernels.decide(_i64(nums), _i64(lane), _f64(pos), _f64(speed), _f64(seen.v_exp), _i64(actions),
                    np.ascontiguousarray(seen.feasible, np.bool_), _f64(seen.leader_gap), _f64(seen.leader_speed),
                    state.lc_left_s, state.lc_from, state.lc_to, state.hold, sent, _f64(draw.u), controls.params, ok,
                    rejected, target, speeds, changed, float(draw.p), bool(draw.redraw))  # fmt: skip
    return Decision(ok, rejected, target, speeds, changed)


def after_step(nums: np.ndarray, lane: np.ndarray, pos: np.ndarray, state: LaneState, controls: Controls) -> np.ndarray:
    """controller.after_step in one call (state.lc_left_s is written in place)."""
    rows = np.empty((max(2 * len(nums) - 1, 0), 2), np.int64)
    count = _kernels.after_step(_i64(nums), _i64(lane), _f64(pos), state.lc_left_s, state.lc_from, state.lc_to,
                                controls.params, rows)  # fmt: skip
    return rows[:count]


def advanced_table(
    table: VehicleTable, sent_mps: np.ndarray, switch_to: np.ndarray, arrived: np.ndarray, dt_s: float
) -> VehicleTable | None:
    """vehicle_table.advanced_table in one call."""
    n = len(table.nums)
    nums, lane, pos, speed = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n), np.empty(n)
    count = _kernels.advanced_table(table.nums, table.lane, table.pos, sent_mps, _i64(switch_to), _i64(arrived),
                                    nums, lane, pos, speed, float(dt_s))  # fmt: skip
    if count < 0:
        return None
    return VehicleTable(nums[:count], lane[:count], pos[:count], speed[:count])
