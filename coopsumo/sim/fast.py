"""The world's per-step loops over vehicles in C (kernels.c, the extension module coopsumo.sim._kernels that
`pip install` builds), equal to their numpy definitions in coopsumo.sim.physics and reward bit for bit.

At 100-300 vehicles the definitions' many small numpy calls, not their arithmetic, were the world's largest
Python cost (docs/performance.md); here each is one call into C. Tested against the definitions on random and
hand-made roads (tests/test_fast.py).
"""

from __future__ import annotations

import numpy as np

from coopsumo.sim import _kernels  # type: ignore[attr-defined]  # built from kernels.c
from coopsumo.sim.physics import Neighbours, Occupancy


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


def occupancy_and_neighbours(
    lane: np.ndarray, pos: np.ndarray, other: np.ndarray, speed: np.ndarray, query_lanes: np.ndarray, n_lanes: int,
    car_length_m: float,
) -> tuple[Occupancy, Neighbours]:  # fmt: skip
    """physics.occupancy(lane, pos, other) and physics.neighbours of it for query_lanes (n, k)."""
    pos = _f64(pos)
    occ = occupancy(lane, pos, other)
    query = _i64(query_lanes)
    gaps = np.empty((4, *query.shape))  # lead gap, lead speed, follow gap, follow speed
    idx = np.empty((2, *query.shape), np.int64)  # lead, follow
    exists = np.empty(query.shape, np.bool_)
    _kernels.neighbours(occ.keys, occ.lane, occ.veh, pos, _f64(speed), query, gaps, idx, exists, int(n_lanes),
                        float(car_length_m))  # fmt: skip
    return occ, Neighbours(lead_gap=gaps[0], lead_speed=gaps[1], lead_idx=idx[0], follow_gap=gaps[2],
                           follow_speed=gaps[3], follow_idx=idx[1], exists=exists)  # fmt: skip


def overlaps(lane: np.ndarray, pos: np.ndarray, other: np.ndarray, car_length_m: float) -> np.ndarray:
    """physics.overlaps(physics.occupancy(lane, pos, other), car_length_m): (k, 2) rows (follower, leader)."""
    occ = occupancy(lane, pos, other)
    rows = np.empty((max(len(occ.keys) - 1, 0), 2), np.int64)
    count = _kernels.overlaps(occ.lane, occ.pos, occ.veh, rows, float(car_length_m))
    return rows[:count]


def section_crossings(
    prev_nums: np.ndarray, prev_pos: np.ndarray, nums: np.ndarray, pos: np.ndarray, sections_m: np.ndarray
) -> int:
    """reward.section_crossings: vehicles whose front passed a cross-section between two tables sorted by number."""
    return int(_kernels.section_crossings(_i64(prev_nums), _f64(prev_pos), _i64(nums), _f64(pos), _f64(sections_m)))
