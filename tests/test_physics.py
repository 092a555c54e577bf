"""Pure physics (no SUMO): Newell speed (eq. 9), collision check (eq. 11), lane-change safety,
same-step conflicts, and who is next to whom on hand-made layouts."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from coopsumo.config import ControlConfig
from coopsumo.sim import physics

INF = math.inf


def arr(*values: float) -> np.ndarray:
    return np.array(values, dtype=np.float64)


# -- eq. (9): Newell car-following -------------------------------------------------------------


def test_newell_speed_matches_hand_computed_values() -> None:
    cfg = ControlConfig(newell_c_per_s=1.0, newell_d=-0.1)
    # v_exp * (1 - exp(-c * gap / v_exp - d)) worked out by hand:
    # gap 30, v_exp 20: 20 * (1 - e^-1.4) = 15.0680600...
    # gap 10, v_exp 25: 25 * (1 - e^-0.3) = 6.4795444...
    # gap 2.5, v_exp 20: 20 * (1 - e^-0.025) = 0.4938017...
    # gap 1.5, v_exp 20 (below the standstill gap -d * v_exp / c = 2 m): 20 * (1 - e^0.025) < 0 -> 0
    got = physics.newell_speed(arr(30.0, 10.0, 2.5, 1.5), arr(20.0, 25.0, 20.0, 20.0), cfg)
    assert got == pytest.approx([15.0680600, 6.4795445, 0.4938018, 0.0], abs=1e-6)


def test_newell_speed_is_zero_up_to_the_standstill_gap_and_tends_to_v_exp() -> None:
    cfg = ControlConfig(newell_c_per_s=1.1, newell_d=-0.1)
    v_exp = 22.0
    standstill = -cfg.newell_d * v_exp / cfg.newell_c_per_s  # 2 m
    got = physics.newell_speed(arr(0.0, standstill - 1e-3, standstill + 1e-3, 1e4, INF), np.full(5, v_exp), cfg)
    assert got[0] == 0.0 and got[1] == 0.0
    assert 0.0 < got[2] < 0.01
    assert got[3] == pytest.approx(v_exp) and got[4] == v_exp
    gaps = np.linspace(0.0, 300.0, 301)
    assert np.all(np.diff(physics.newell_speed(gaps, np.full(301, v_exp), cfg)) >= 0.0)


def test_next_speed_is_the_minimum_of_speedup_newell_and_v_exp(ctrl: ControlConfig) -> None:
    c = dataclasses.replace(ctrl, newell_c_per_s=1.0, newell_d=-0.1)
    v = arr(10.0, 10.0, 19.8, 15.0, 15.0)
    v_exp = arr(20.0, 20.0, 20.0, 20.0, 20.0)
    speedup = np.array([True, False, True, True, False])
    gap = arr(INF, INF, INF, 30.0, 30.0)  # gap 30 > 8 + 0.5 * 15: no collision check
    got = physics.next_speed(v, v_exp, speedup, gap, np.zeros(5), c)
    # 10 + 0.4; keep 10; 19.8 + 0.4 capped at v_exp 20; Newell 15.068 below 15.4; Newell 15.068 above 15 -> 15
    assert got == pytest.approx([10.4, 10.0, 20.0, 15.068060, 15.0], abs=1e-6)


def test_collision_check_fires_exactly_at_a1_l_plus_a2_v(ctrl: ControlConfig) -> None:
    v = np.full(4, 10.0)  # threshold a1 * L + a2 * v = 2 * 4 + 0.5 * 10 = 13 m
    gap = arr(13.0, 13.0 + 1e-9, 12.0, 100.0)
    v_new = np.full(4, 10.0)
    v_lead = np.full(4, 6.0)
    got = physics.collision_check(v_new, v, gap, v_lead, ctrl)
    assert got.tolist() == [5.0, 10.0, 5.0, 10.0]  # capped at v_lead - v_cc = 5 when gap <= 13


def test_collision_check_cap_never_below_zero_and_never_raises_speed(ctrl: ControlConfig) -> None:
    v = arr(10.0, 10.0, 10.0)
    gap = arr(5.0, 5.0, 5.0)
    v_new = arr(10.0, 10.0, 2.0)
    v_lead = arr(0.5, 0.0, 8.0)
    got = physics.collision_check(v_new, v, gap, v_lead, ctrl)
    # v_lead - 1 < 0 -> 0; already below the cap 7 -> unchanged
    assert got.tolist() == [0.0, 0.0, 2.0]


def test_next_speed_applies_the_collision_check_after_newell(ctrl: ControlConfig) -> None:
    # gap 17 <= 8 + 0.5 * 20 = 18: the check caps at v_lead - 1 = 9 even though Newell allows 12.2
    got = physics.next_speed(arr(20.0), arr(30.0), np.array([True]), arr(17.0), arr(10.0), ctrl)
    assert got[0] == pytest.approx(9.0)
    assert physics.newell_speed(arr(17.0), arr(30.0), ctrl)[0] > 12.0


def test_a_follower_never_reaches_its_leader_even_if_the_leader_stops_dead(ctrl: ControlConfig) -> None:
    """Safety by construction: the next-step travel v * dt stays below the current gap (c * dt < 1, d < 0)."""
    rng = np.random.default_rng(0)
    n = 20_000
    gap = rng.uniform(1e-3, 120.0, n)
    v = rng.uniform(0.0, 31.0, n)
    v_exp = rng.uniform(40 / 3.6, 110 / 3.6, n)
    v_lead = rng.uniform(0.0, 31.0, n)
    v_next = physics.next_speed(v, v_exp, rng.random(n) < 0.5, gap, v_lead, ctrl)
    assert np.all(v_next >= 0.0)
    assert np.all(v_next * ctrl.dt_s < gap)
    # iterated against a standing obstacle the gap stays positive
    g, s = gap.copy(), v.copy()
    for _ in range(300):
        s = physics.next_speed(s, v_exp, np.ones(n, bool), g, np.zeros(n), ctrl)
        g = g - s * ctrl.dt_s
    assert np.all(g > 0.0)


# -- occupancy and neighbours ------------------------------------------------------------------


def test_occupancy_counts_a_lane_changer_in_both_lanes_sorted_by_lane_then_position() -> None:
    lane = np.array([1, 0, 1])
    pos = arr(50.0, 80.0, 20.0)
    other = np.array([-1, 1, -1])  # vehicle 1 is changing between lanes 0 and 1
    occ = physics.occupancy(lane, pos, other)
    assert occ.lane.tolist() == [0, 1, 1, 1]
    assert occ.pos.tolist() == [80.0, 20.0, 50.0, 80.0]
    assert occ.veh.tolist() == [1, 2, 0, 1]
    assert np.all(np.diff(occ.keys) > 0)


def nb_of(lane: list[int], pos: list[float], speed: list[float], other: list[int] | None = None, n_lanes: int = 3):
    lane_a = np.array(lane)
    pos_a = np.array(pos, float)
    other_a = np.full(len(lane), -1) if other is None else np.array(other)
    occ = physics.occupancy(lane_a, pos_a, other_a)
    return physics.neighbours(occ, pos_a, np.array(speed, float), physics.side_lanes(lane_a), n_lanes, 4.0)


def test_neighbours_on_a_hand_made_layout() -> None:
    # vehicle 0: lane 1 at 100 m. 1: ahead in lane 1 at 130. 2: behind in lane 1 at 60.
    # 3: lane 2 at 110 (left leader). 4: lane 0 at 99 (right follower, 3 m overlap -> gap -3).
    nb = nb_of([1, 1, 1, 2, 0], [100, 130, 60, 110, 99], [20, 21, 19, 22, 18])
    # sides are (left, own, right)
    assert nb.lead_gap[0].tolist() == [6.0, 26.0, INF]
    assert nb.lead_idx[0].tolist() == [3, 1, -1]
    assert nb.lead_speed[0].tolist() == [22.0, 21.0, 0.0]
    assert nb.follow_gap[0].tolist() == [INF, 36.0, -3.0]
    assert nb.follow_idx[0].tolist() == [-1, 2, 4]
    assert nb.follow_speed[0].tolist() == [0.0, 19.0, 18.0]
    assert nb.exists[0].tolist() == [True, True, True]
    # the leader of the lane has no one ahead; the rearmost no one behind
    assert nb.lead_gap[1, 1] == INF and nb.lead_idx[1, 1] == -1
    assert nb.follow_gap[2, 1] == INF and nb.follow_idx[2, 1] == -1


def test_neighbours_exclude_the_vehicle_itself_also_in_its_second_lane() -> None:
    # vehicle 0 changes between lanes 1 and 2; alone on the road except vehicle 1 far ahead in lane 0
    nb = nb_of([1, 0], [100, 300], [20, 20], other=[2, -1])
    assert nb.lead_idx[0].tolist() == [-1, -1, 1]
    assert nb.follow_idx[0].tolist() == [-1, -1, -1]
    assert nb.lead_gap[0, 0] == INF and nb.follow_gap[0, 0] == INF


def test_a_lane_changer_is_seen_from_both_lanes() -> None:
    # vehicle 0 changes from lane 0 to lane 1 at 100 m; vehicle 1 behind in lane 1, vehicle 2 behind in lane 0
    nb = nb_of([0, 1, 0], [100, 70, 50], [20, 20, 20], other=[1, -1, -1])
    assert nb.lead_idx[1, 1] == 0 and nb.lead_gap[1, 1] == 26.0
    assert nb.lead_idx[2, 1] == 0 and nb.lead_gap[2, 1] == 46.0


def test_off_road_lanes_do_not_exist_and_empty_lanes_have_infinite_gaps() -> None:
    nb = nb_of([0, 2], [100, 400], [20, 25], n_lanes=3)
    assert nb.exists.tolist() == [[True, True, False], [False, True, True]]
    # vehicle 1 (lane 2, at 400 m) is ahead of vehicle 0 but two lanes away: every lane seen is empty
    assert np.all(np.isinf(nb.lead_gap)) and np.all(np.isinf(nb.follow_gap))
    assert np.all(nb.lead_idx == -1) and np.all(nb.follow_idx == -1)
    assert np.all(nb.lead_speed == 0.0) and np.all(nb.follow_speed == 0.0)


def test_neighbours_of_a_single_vehicle_and_of_an_empty_road() -> None:
    nb = nb_of([1], [10.0], [5.0])
    assert np.all(np.isinf(nb.lead_gap)) and np.all(np.isinf(nb.follow_gap))
    assert nb.lead_idx.tolist() == [[-1, -1, -1]]
    empty = nb_of([], [], [])
    assert empty.lead_gap.shape == (0, 3)


def test_neighbours_agree_with_a_brute_force_search_on_random_layouts() -> None:
    rng = np.random.default_rng(1)
    n_lanes = 4
    n = 60
    lane = rng.integers(0, n_lanes, n)
    pos = rng.permutation(np.arange(n) * 7.3 + 5.0) + rng.uniform(0, 1, n)  # distinct positions
    other = np.where(rng.random(n) < 0.3, lane + rng.choice([-1, 1], n), -1)
    other = np.where((other >= 0) & (other < n_lanes), other, -1)
    speed = rng.uniform(0, 30, n)
    occ = physics.occupancy(lane, pos, other)
    nb = physics.neighbours(occ, pos, speed, physics.side_lanes(lane), n_lanes, 4.0)
    for i in range(n):
        for k, q in enumerate(lane[i] + physics.SIDE_OFFSETS):
            in_q = [j for j in range(n) if j != i and 0 <= q < n_lanes and q in (lane[j], other[j])]
            ahead = [j for j in in_q if pos[j] > pos[i]]
            behind = [j for j in in_q if pos[j] < pos[i]]
            lead = min(ahead, key=lambda j: pos[j]) if ahead else -1
            foll = max(behind, key=lambda j: pos[j]) if behind else -1
            assert nb.lead_idx[i, k] == lead, (i, k)
            assert nb.follow_idx[i, k] == foll, (i, k)
            assert nb.lead_gap[i, k] == (pos[lead] - 4.0 - pos[i] if lead >= 0 else INF)
            assert nb.follow_gap[i, k] == (pos[i] - 4.0 - pos[foll] if foll >= 0 else INF)


# -- lane-change safety and same-step conflicts -------------------------------------------------


def test_lane_change_safe_thresholds(ctrl: ControlConfig) -> None:
    # ahead: gap >= 2 + 0.5 * v (v = 10 -> 7 m); behind: gap >= 2 + 0.5 * v_follow (20 -> 12 m)
    lead = arr(7.0, 6.99, 7.0, 7.0, INF)
    follow = arr(12.0, 12.0, 11.99, INF, 12.0)
    v = np.full(5, 10.0)
    v_follow = arr(20.0, 20.0, 20.0, 0.0, 20.0)
    assert physics.lane_change_safe(lead, follow, v, v_follow, ctrl).tolist() == [True, False, False, True, True]


def target_side_safety(nb: physics.Neighbours, i: int, side: int, speed: np.ndarray, c: ControlConfig) -> bool:
    return bool(
        physics.lane_change_safe(
            nb.lead_gap[i : i + 1, side], nb.follow_gap[i : i + 1, side], speed[i : i + 1],
            nb.follow_speed[i : i + 1, side], c,
        )[0]
    )  # fmt: skip


def test_lane_change_rejected_with_a_car_too_close_ahead_or_behind_in_the_target_lane(ctrl: ControlConfig) -> None:
    speed = arr(10.0, 15.0, 20.0)
    # ego in lane 1 at 100 m, 10 m/s. Left lane: a car whose rear is 2 m ahead (front 106).
    # Right lane: a car at 90 m doing 20 m/s: gap 6 m < 2 + 0.5 * 20 = 12 m.
    nb = nb_of([1, 2, 0], [100, 106, 90], speed.tolist())
    assert not target_side_safety(nb, 0, 0, speed, ctrl)
    assert not target_side_safety(nb, 0, 2, speed, ctrl)
    # move them: left leader rear 8 m ahead (>= 7), right follower 13 m behind (>= 12): both safe
    nb = nb_of([1, 2, 0], [100, 112, 83], speed.tolist())
    assert target_side_safety(nb, 0, 0, speed, ctrl)
    assert target_side_safety(nb, 0, 2, speed, ctrl)


def test_resolve_conflicts_rejects_the_rear_of_two_cars_cutting_into_the_same_lane(ctrl: ControlConfig) -> None:
    # vehicles 0 (lane 0) and 1 (lane 2) both move into lane 1, side by side (1 m apart)
    target = np.array([1, 1])
    pos = arr(100.0, 101.0)
    v = arr(20.0, 20.0)
    keep = physics.resolve_conflicts(target, pos, v, np.array([True, True]), ctrl)
    assert keep.tolist() == [False, True]
    # far enough apart (gap 50 - 4 = 46 >= 2 + 0.5 * 20): both go
    keep = physics.resolve_conflicts(target, arr(100.0, 150.0), v, np.array([True, True]), ctrl)
    assert keep.tolist() == [True, True]
    # different target lanes never conflict
    keep = physics.resolve_conflicts(np.array([1, 2]), pos, v, np.array([True, True]), ctrl)
    assert keep.tolist() == [True, True]


def test_resolve_conflicts_measures_against_the_last_kept_car_and_ignores_refused_ones(ctrl: ControlConfig) -> None:
    # into lane 1: A at 200 (kept), B at 195 (gap 1 to A: rejected), C at 185 (gap 11 to A, 6 to B):
    # C needs 2 + 0.5 * 10 = 7 m to A, which it has; B no longer counts
    target = np.array([1, 1, 1, 1])
    pos = arr(200.0, 195.0, 185.0, 150.0)
    v = np.full(4, 10.0)
    accepted = np.array([True, True, True, False])
    keep = physics.resolve_conflicts(target, pos, v, accepted, ctrl)
    assert keep.tolist() == [True, False, True, False]


# -- the collision counter: overlapping bodies -------------------------------------------------


def test_overlaps_finds_exactly_the_pairs_closer_than_one_car_length() -> None:
    # lane 0: fronts at 10, 13.9 (overlap: 3.9 < 4), 30, 34 (touching, gap 0: not a collision)
    # lane 1: fronts at 50 and 52 (rows 4 and 5, overlap)
    lane = np.array([0, 0, 0, 0, 1, 1])
    pos = arr(10.0, 13.9, 30.0, 34.0, 50.0, 52.0)
    occ = physics.occupancy(lane, pos, np.full(6, -1))
    pairs = physics.overlaps(occ, 4.0)
    assert sorted(map(tuple, pairs.tolist())) == [(0, 1), (4, 5)]


def test_overlaps_sees_a_vehicle_in_its_second_lane_and_never_pairs_it_with_itself() -> None:
    # row 0 changes from lane 0 to 1 at 20 m; row 1 is in lane 1 at 22 m; row 0 alone in lane 0
    occ = physics.occupancy(np.array([0, 1]), arr(20.0, 22.0), np.array([1, -1]))
    assert physics.overlaps(occ, 4.0).tolist() == [[0, 1]]
    alone = physics.occupancy(np.array([0]), arr(20.0), np.array([1]))
    assert physics.overlaps(alone, 4.0).shape == (0, 2)


def test_body_lanes_follow_the_sideways_move_of_a_lane_change() -> None:
    # W 3.2, width 1.8, 4 s: the body enters the target lane after 0.7 m (0.875 s) and leaves the
    # origin lane after 2.5 m (3.125 s); the last vehicle is not changing lane.
    lc_left = arr(3.9, 3.0, 2.0, 0.8, 0.0)
    first, second = physics.body_lanes(np.array([0, 0, 1, 1, 2]), np.full(5, 0), np.full(5, 1), lc_left, 4.0, 3.2, 1.8)
    assert first.tolist() == [0, 0, 0, 1, 2]
    assert second.tolist() == [-1, 1, 1, -1, -1]
