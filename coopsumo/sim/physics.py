"""Pure array physics: who is next to whom, Newell speeds, the collision check, lane-change safety.

Positions are SUMO's lane positions of the front bumper (m). Lane 0 is the rightmost lane;
"left" is lane + 1. A vehicle in a lane change occupies both its origin and target lane
until the change completes. No SUMO, no torch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coopsumo.config import ControlConfig
from coopsumo.sim import _kernels  # type: ignore[attr-defined]  # built from kernels.c

# Actions shared by every policy.
LEFT, RIGHT, SPEEDUP, NONE = 0, 1, 2, 3
ACTION_NAMES = ("left", "right", "speedup", "none")
# Side index used in (n, 3) neighbour arrays and in the grid rows: left, own, right.
SIDE_OFFSETS = np.array([1, 0, -1])

_LANE_KEY = 1.0e6  # lane * _LANE_KEY + position gives one sortable key (road << 1e6 m)


def lane_key(lane: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """The occupancy's sort key of a (lane, position (m)) pair."""
    return np.asarray(lane, np.int64) * _LANE_KEY + np.asarray(pos, np.float64)


@dataclass(frozen=True)
class Occupancy:
    """Every (vehicle, lane) pair a vehicle occupies, sorted by lane then position."""

    keys: np.ndarray  # (m,) lane * 1e6 + pos, sorted
    lane: np.ndarray  # (m,) int
    pos: np.ndarray  # (m,) front position (m)
    veh: np.ndarray  # (m,) row index of the vehicle in the table


def occupancy(lane: np.ndarray, pos: np.ndarray, other_lane: np.ndarray) -> Occupancy:
    """Build the sorted occupancy from each vehicle's lane and the second lane it touches (-1: none)."""
    n = len(lane)
    extra = np.flatnonzero((other_lane >= 0) & (other_lane != lane))
    occ_lane = np.concatenate([lane, other_lane[extra]]).astype(np.int64)
    occ_pos = np.concatenate([pos, pos[extra]]).astype(np.float64)
    occ_veh = np.concatenate([np.arange(n), extra])
    keys = lane_key(occ_lane, occ_pos)
    order = np.argsort(keys, kind="stable")
    return Occupancy(keys[order], occ_lane[order], occ_pos[order], occ_veh[order])


@dataclass(frozen=True)
class Neighbours:
    """Nearest leader and follower of each vehicle in a set of query lanes.

    Arrays are (n, k) for k query lanes per vehicle. Gaps are bumper to bumper (m), +inf
    where there is no vehicle; speeds are 0 there. `exists` is False for lanes off the road.
    """

    lead_gap: np.ndarray
    lead_speed: np.ndarray
    lead_idx: np.ndarray  # row index of the leader, -1 if none
    follow_gap: np.ndarray
    follow_speed: np.ndarray
    follow_idx: np.ndarray
    exists: np.ndarray


def neighbours(
    occ: Occupancy,
    pos: np.ndarray,
    speed: np.ndarray,
    query_lanes: np.ndarray,
    n_lanes: int,
    car_length_m: float,
) -> Neighbours:
    """Leader and follower of vehicle i in lane query_lanes[i, j], ignoring vehicle i itself."""
    n, k = query_lanes.shape
    rows = np.repeat(np.arange(n), k)
    ql = query_lanes.reshape(-1)
    qp = pos[rows]
    m = len(occ.keys)
    if m == 0:  # an empty road: pad with one sentinel that matches no lane
        occ = Occupancy(np.array([np.inf]), np.array([-99]), np.array([0.0]), np.array([-1]))
        m = 1
    ahead = np.searchsorted(occ.keys, ql * _LANE_KEY + qp, side="right")
    behind = ahead - 1
    # the vehicle itself sits at or just below its own key: step over it
    behind = np.where((behind >= 0) & (occ.veh[np.maximum(behind, 0)] == rows), behind - 1, behind)

    def pick(idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        safe = np.minimum(np.maximum(idx, 0), m - 1)
        valid = (idx >= 0) & (idx < m) & (occ.lane[safe] == ql)
        return valid, np.where(valid, occ.veh[safe], 0)

    lead_ok, lead_veh = pick(ahead)
    foll_ok, foll_veh = pick(behind)
    lead_gap = np.where(lead_ok, pos[lead_veh] - car_length_m - qp, np.inf)
    follow_gap = np.where(foll_ok, qp - car_length_m - pos[foll_veh], np.inf)
    exists = (ql >= 0) & (ql < n_lanes)
    shape = (n, k)
    return Neighbours(
        lead_gap=np.where(exists, lead_gap, np.inf).reshape(shape),
        lead_speed=np.where(lead_ok, speed[lead_veh], 0.0).reshape(shape),
        lead_idx=np.where(lead_ok & exists, lead_veh, -1).reshape(shape),
        follow_gap=np.where(exists, follow_gap, np.inf).reshape(shape),
        follow_speed=np.where(foll_ok, speed[foll_veh], 0.0).reshape(shape),
        follow_idx=np.where(foll_ok & exists, foll_veh, -1).reshape(shape),
        exists=exists.reshape(shape),
    )


def overlaps(occ: Occupancy, car_length_m: float) -> np.ndarray:
    """(k, 2) row indices (follower, leader) of neighbours in one lane whose bodies overlap (a collision).

    Overlap: the leader's front is less than one car length ahead of the follower's front (gap < 0,
    the criterion of SUMO's collision check with a zero minimum gap). Neighbours in the sorted
    occupancy suffice: any overlapping pair has an overlapping pair of neighbours between them.
    """
    same_lane = occ.lane[1:] == occ.lane[:-1]
    close = occ.pos[1:] - occ.pos[:-1] < car_length_m - 1e-6
    distinct = occ.veh[1:] != occ.veh[:-1]
    i = np.flatnonzero(same_lane & close & distinct)
    return np.stack([occ.veh[i], occ.veh[i + 1]], axis=1)


def body_lanes(
    lane: np.ndarray,
    lc_from: np.ndarray,
    lc_to: np.ndarray,
    lc_left_s: np.ndarray,
    t_change_s: float,
    lane_width_m: float,
    vehicle_width_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The lanes a vehicle's body physically touches: (first, second), second -1 when only one.

    A lane changer moves sideways at constant speed over t_change_s; its body (vehicle_width_m wide)
    leaves the origin lane once it has moved (lane_width + width) / 2 and enters the target lane
    after (lane_width - width) / 2. Others are in `lane` only. (The controller is stricter: it
    counts a changer in both lanes for the whole change.)
    """
    busy = lc_left_s > 0
    moved = (1.0 - lc_left_s / t_change_s) * lane_width_m  # sideways from the origin lane's centre (m)
    on_from = moved < (lane_width_m + vehicle_width_m) / 2
    on_to = moved > (lane_width_m - vehicle_width_m) / 2
    first = np.where(busy, np.where(on_from, lc_from, lc_to), lane)
    second = np.where(busy & on_from & on_to, lc_to, -1)
    return first, second


def side_lanes(lane: np.ndarray) -> np.ndarray:
    """(n, 3) lanes to the left, own and to the right of each vehicle (may be off the road)."""
    return lane[:, None] + SIDE_OFFSETS[None, :]


def exp(x: np.ndarray) -> np.ndarray:
    """e ** x elementwise by the C library's exp (as math.exp), whose bits do not depend on AVX-512. np.exp's do:
    on CPUs with AVX-512 it takes a vector path that differs in the last bit for about 5% of arguments, and a dense
    run that meets one such difference goes elsewhere."""
    flat = np.ascontiguousarray(x, np.float64).reshape(-1)
    out = np.empty_like(flat)
    _kernels.exp_into(flat, out)
    return out.reshape(np.shape(x))


def newell_speed(gap_m: np.ndarray, v_exp_mps: np.ndarray, cfg: ControlConfig) -> np.ndarray:
    """Speed bound of eq. (9) (m/s): v_exp * (1 - exp(-c * gap / v_exp - d)), never below 0."""
    bound = v_exp_mps * (1.0 - exp(-cfg.newell_c_per_s * gap_m / v_exp_mps - cfg.newell_d))
    return np.maximum(bound, 0.0)


def collision_check(
    v_new_mps: np.ndarray, v_mps: np.ndarray, gap_m: np.ndarray, v_lead_mps: np.ndarray, cfg: ControlConfig
) -> np.ndarray:
    """Eq. (11): if gap <= a1 * L_car + a2 * v, cap the new speed at v_lead - v_cc (and at 0)."""
    close = gap_m <= cfg.a1 * cfg.car_length_m + cfg.a2_s * v_mps
    capped = np.minimum(v_new_mps, np.maximum(v_lead_mps - cfg.v_cc_mps, 0.0))
    return np.where(close, capped, v_new_mps)


def next_speed(
    v_mps: np.ndarray,
    v_exp_mps: np.ndarray,
    speedup: np.ndarray,
    gap_m: np.ndarray,
    v_lead_mps: np.ndarray,
    cfg: ControlConfig,
) -> np.ndarray:
    """The controller's speed for the next step: eq. (9) then eq. (11), capped at v_exp."""
    accel = np.where(speedup, cfg.v_acc_mps, 0.0)
    v_new = np.minimum(np.minimum(v_mps + accel, newell_speed(gap_m, v_exp_mps, cfg)), v_exp_mps)
    v_new = collision_check(v_new, v_mps, gap_m, v_lead_mps, cfg)
    return np.maximum(v_new, 0.0)


def lane_change_safe(
    lead_gap_m: np.ndarray,
    follow_gap_m: np.ndarray,
    v_mps: np.ndarray,
    v_follow_mps: np.ndarray,
    cfg: ControlConfig,
) -> np.ndarray:
    """Room ahead and behind in the target lane: gap >= min gap + headway * speed of the rear car."""
    ahead_ok = lead_gap_m >= cfg.lc_min_gap_m + cfg.lc_headway_s * v_mps
    behind_ok = follow_gap_m >= cfg.lc_min_gap_m + cfg.lc_headway_s * v_follow_mps
    return ahead_ok & behind_ok


def feasible_actions(around: Neighbours, busy: np.ndarray, v_mps: np.ndarray, cfg: ControlConfig) -> np.ndarray:
    """(n, 4) bool: which of left, right, speedup, none the controller accepts for each vehicle now.

    A lane change is accepted when the target lane exists, no change is under way, and the gaps
    pass lane_change_safe. Speed-up and none are always accepted. A masked-in change can still be
    refused by resolve_conflicts when another vehicle enters the same lane in the same step.
    """
    n = len(v_mps)
    out = np.ones((n, 4), dtype=bool)
    for action, side in ((LEFT, 0), (RIGHT, 2)):
        safe = lane_change_safe(around.lead_gap[:, side], around.follow_gap[:, side], v_mps,
                                around.follow_speed[:, side], cfg)  # fmt: skip
        out[:, action] = ~busy & around.exists[:, side] & safe
    return out


def resolve_conflicts(
    target_lane: np.ndarray, pos: np.ndarray, v_mps: np.ndarray, accepted: np.ndarray, cfg: ControlConfig
) -> np.ndarray:
    """Keep only accepted changes that do not cut into each other in the same target lane.

    Two vehicles entering the same lane in the same step must leave each other the same room
    as lane_change_safe asks; the rear one of a too-close pair is rejected.
    """
    keep = accepted.copy()
    idx = np.flatnonzero(accepted)
    order = idx[np.lexsort((-pos[idx], target_lane[idx]))]  # by lane, front first
    last = -1
    for b in order:
        if last >= 0 and target_lane[last] == target_lane[b]:
            gap = pos[last] - cfg.car_length_m - pos[b]
            if gap < cfg.lc_min_gap_m + cfg.lc_headway_s * v_mps[b]:
                keep[b] = False
                continue
        last = b
    return keep
