"""Compiled (numba) versions of the world's per-step array work, equal to coopsumo.sim.physics bit for bit.

physics.py holds the definitions in plain numpy; this module does the same arithmetic in one compiled pass per
step instead of some forty small numpy calls, because at 100-300 vehicles the calls' overhead, not the
arithmetic, was the world's largest Python cost (docs/performance.md). Every function here is tested against
its definition on random and edge-case roads (tests/test_fast.py). The first call in a fresh checkout compiles
(a few seconds); the machine code is cached beside this file (__pycache__) for every later process.
"""

from __future__ import annotations

import numba
import numpy as np

from coopsumo.sim.physics import _LANE_KEY, Neighbours, Occupancy


@numba.njit(cache=True)
def _occupancy(lane, pos, other):  # type: ignore[no-untyped-def]  # numba infers the types
    n = lane.shape[0]
    m = n
    for i in range(n):
        if other[i] >= 0 and other[i] != lane[i]:
            m += 1
    occ_lane = np.empty(m, np.int64)
    occ_pos = np.empty(m, np.float64)
    occ_veh = np.empty(m, np.int64)
    for i in range(n):
        occ_lane[i] = lane[i]
        occ_pos[i] = pos[i]
        occ_veh[i] = i
    j = n
    for i in range(n):
        if other[i] >= 0 and other[i] != lane[i]:
            occ_lane[j] = other[i]
            occ_pos[j] = pos[i]
            occ_veh[j] = i
            j += 1
    keys = np.empty(m, np.float64)
    for i in range(m):
        keys[i] = occ_lane[i] * _LANE_KEY + occ_pos[i]
    order = np.argsort(keys, kind="mergesort")  # stable, as physics.occupancy
    return keys[order], occ_lane[order], occ_pos[order], occ_veh[order]


@numba.njit(cache=True)
def _neighbours(keys, occ_lane, occ_veh, pos, speed, query, n_lanes, car_length_m):  # type: ignore[no-untyped-def]
    n, k = query.shape
    m = keys.shape[0]
    lead_gap = np.empty((n, k), np.float64)
    lead_speed = np.empty((n, k), np.float64)
    lead_idx = np.empty((n, k), np.int64)
    follow_gap = np.empty((n, k), np.float64)
    follow_speed = np.empty((n, k), np.float64)
    follow_idx = np.empty((n, k), np.int64)
    exists = np.empty((n, k), np.bool_)
    for r in range(n):
        qp = pos[r]
        for c in range(k):
            ql = query[r, c]
            ahead = np.searchsorted(keys, ql * _LANE_KEY + qp, side="right")
            behind = ahead - 1
            if behind >= 0 and occ_veh[behind] == r:  # the vehicle itself: step over it
                behind -= 1
            on_road = ql >= 0 and ql < n_lanes
            exists[r, c] = on_road
            lead_gap[r, c] = np.inf
            lead_speed[r, c] = 0.0
            lead_idx[r, c] = -1
            if ahead < m and occ_lane[ahead] == ql:
                v = occ_veh[ahead]
                lead_speed[r, c] = speed[v]
                if on_road:
                    lead_gap[r, c] = pos[v] - car_length_m - qp
                    lead_idx[r, c] = v
            follow_gap[r, c] = np.inf
            follow_speed[r, c] = 0.0
            follow_idx[r, c] = -1
            if behind >= 0 and occ_lane[behind] == ql:
                v = occ_veh[behind]
                follow_speed[r, c] = speed[v]
                if on_road:
                    follow_gap[r, c] = qp - car_length_m - pos[v]
                    follow_idx[r, c] = v
    return lead_gap, lead_speed, lead_idx, follow_gap, follow_speed, follow_idx, exists


def occupancy_and_neighbours(
    lane: np.ndarray, pos: np.ndarray, other: np.ndarray, speed: np.ndarray, query_lanes: np.ndarray, n_lanes: int,
    car_length_m: float,
) -> tuple[Occupancy, Neighbours]:  # fmt: skip
    """physics.occupancy(lane, pos, other) and physics.neighbours of it for query_lanes (n, k), in one pass."""
    lane = np.ascontiguousarray(lane, np.int64)
    pos = np.ascontiguousarray(pos, np.float64)
    occ = Occupancy(*_occupancy(lane, pos, np.ascontiguousarray(other, np.int64)))
    parts = _neighbours(occ.keys, occ.lane, occ.veh, pos, np.ascontiguousarray(speed, np.float64),
                        np.ascontiguousarray(query_lanes, np.int64), int(n_lanes), float(car_length_m))  # fmt: skip
    return occ, Neighbours(*parts)


@numba.njit(cache=True)
def _overlaps(lane, pos, other, car_length_m):  # type: ignore[no-untyped-def]
    keys, occ_lane, occ_pos, occ_veh = _occupancy(lane, pos, other)
    m = keys.shape[0]
    count = 0
    for i in range(m - 1):
        if (occ_lane[i + 1] == occ_lane[i] and occ_pos[i + 1] - occ_pos[i] < car_length_m - 1e-6
                and occ_veh[i + 1] != occ_veh[i]):  # fmt: skip
            count += 1
    rows = np.empty((count, 2), np.int64)
    j = 0
    for i in range(m - 1):
        if (occ_lane[i + 1] == occ_lane[i] and occ_pos[i + 1] - occ_pos[i] < car_length_m - 1e-6
                and occ_veh[i + 1] != occ_veh[i]):  # fmt: skip
            rows[j, 0] = occ_veh[i]
            rows[j, 1] = occ_veh[i + 1]
            j += 1
    return rows


def overlaps(lane: np.ndarray, pos: np.ndarray, other: np.ndarray, car_length_m: float) -> np.ndarray:
    """physics.overlaps(physics.occupancy(lane, pos, other), car_length_m): (k, 2) rows (follower, leader)."""
    return _overlaps(np.ascontiguousarray(lane, np.int64), np.ascontiguousarray(pos, np.float64),
                     np.ascontiguousarray(other, np.int64), float(car_length_m))  # fmt: skip


@numba.njit(cache=True)
def _section_crossings(prev_nums, prev_pos, nums, pos, sections_m):  # type: ignore[no-untyped-def]
    count = 0
    j = 0
    for i in range(nums.shape[0]):
        while j < prev_nums.shape[0] and prev_nums[j] < nums[i]:
            j += 1
        if j < prev_nums.shape[0] and prev_nums[j] == nums[i]:
            for x in sections_m:
                if prev_pos[j] < x and x <= pos[i]:
                    count += 1
    return count


def section_crossings(
    prev_nums: np.ndarray, prev_pos: np.ndarray, nums: np.ndarray, pos: np.ndarray, sections_m: np.ndarray
) -> int:
    """reward.section_crossings: vehicles whose front passed a cross-section between two tables sorted by number."""
    return int(_section_crossings(np.ascontiguousarray(prev_nums, np.int64), np.ascontiguousarray(prev_pos, np.float64),
                                  np.ascontiguousarray(nums, np.int64), np.ascontiguousarray(pos, np.float64),
                                  np.ascontiguousarray(sections_m, np.float64)))  # fmt: skip
