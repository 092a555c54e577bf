"""Reward components of eq. (5)-(7) and the loop count behind q_t, on hand-computed cases; no SUMO."""

from __future__ import annotations

import numpy as np
import pytest

from coopsumo.config import RewardConfig
from coopsumo.sim import physics
from coopsumo.sim.reward import flow_term, followers_mean, reward_parts, section_crossings


def test_speed_term_is_the_speed_error_over_the_speed_range() -> None:
    cfg = RewardConfig(v_min_mps=0.0, v_max_mps=30.0, alpha=0.0)
    parts = reward_parts(np.array([20.0, 25.0, 0.0]), np.array([25.0, 25.0, 15.0]), np.zeros(3, bool), 0.0, cfg)
    assert parts.speed == pytest.approx([-5.0 / 30.0, 0.0, -0.5])
    cfg = RewardConfig(v_min_mps=10.0, v_max_mps=30.0, w_speed=2.0)
    parts = reward_parts(np.array([20.0]), np.array([25.0]), np.zeros(1, bool), 0.0, cfg)
    assert parts.speed == pytest.approx([2.0 * -5.0 / 20.0])


def test_lane_change_penalty_only_on_a_started_change() -> None:
    cfg = RewardConfig(alpha=8.0)
    started = np.array([True, False, True])
    parts = reward_parts(np.full(3, 20.0), np.full(3, 20.0), started, 0.0, cfg)
    assert parts.lane_change.tolist() == [-8.0, 0.0, -8.0]
    zero_alpha = reward_parts(np.full(3, 20.0), np.full(3, 20.0), started, 0.0, RewardConfig(alpha=0.0))
    assert np.all(zero_alpha.lane_change == 0.0)


def test_flow_term_is_shared_and_the_total_is_the_sum_of_the_parts() -> None:
    cfg = RewardConfig(alpha=0.5, v_min_mps=0.0, v_max_mps=30.0, w_flow=2.0)
    parts = reward_parts(np.array([24.0, 30.0]), np.array([30.0, 30.0]), np.array([False, True]), 0.25, cfg)
    assert parts.flow.tolist() == [0.5, 0.5]
    # -6/30 + 0 + 0.5 and 0 - 0.5 + 0.5
    assert parts.total == pytest.approx([0.3, 0.0])
    assert parts.speed.shape == parts.lane_change.shape == parts.flow.shape == (2,)


def test_flow_term_normalises_the_loop_flow_by_the_road_capacity() -> None:
    cfg = RewardConfig(capacity_veh_h_per_lane=2000.0)
    # 90 vehicles over 9 cross-sections in 60 s: 10 per section per minute = 600 veh/h; 3 lanes carry 6000
    assert flow_term(90, 60.0, 9, 3, cfg) == pytest.approx(0.1)
    # 2 lanes at capacity: 4000 veh/h = 4000 / 60 per minute per section, over 9 sections
    assert flow_term(600, 60.0, 9, 2, cfg) == pytest.approx(1.0)
    assert flow_term(5, 0.0, 9, 3, cfg) == 0.0 and flow_term(5, 60.0, 0, 3, cfg) == 0.0


def test_section_crossings_counts_each_vehicle_once_per_section_passed() -> None:
    sections = np.array([200.0, 400.0])
    prev_nums = np.array([1, 2, 3, 4, 5])
    prev_pos = np.array([199.0, 200.0, 150.0, 395.0, 10.0])
    # 1 passes 200 (199 -> 201); 2 was exactly on 200 and is not counted again; 3 does not reach 200;
    # 4 passes 400; 5 left the road; 7 is new (no previous position): not counted
    nums = np.array([1, 2, 3, 4, 7])
    pos = np.array([201.0, 202.5, 199.9, 400.0, 4.0])
    assert section_crossings(prev_nums, prev_pos, nums, pos, sections) == 2


def test_section_crossings_counts_a_vehicle_at_every_section_it_passes() -> None:
    sections = np.array([200.0, 400.0, 600.0])
    assert section_crossings(np.array([0]), np.array([190.0]), np.array([0]), np.array([410.0]), sections) == 2
    assert section_crossings(np.array([0]), np.array([190.0]), np.array([0]), np.array([190.0]), sections) == 0


def test_section_crossings_on_empty_tables() -> None:
    empty_i, empty_f = np.zeros(0, np.int64), np.zeros(0)
    sections = np.array([200.0])
    assert section_crossings(empty_i, empty_f, np.array([1]), np.array([300.0]), sections) == 0
    assert section_crossings(np.array([1]), np.array([100.0]), empty_i, empty_f, sections) == 0
    assert section_crossings(np.array([1]), np.array([100.0]), np.array([1]), np.array([300.0]), np.zeros(0)) == 0


def test_followers_mean_averages_the_vehicles_behind_in_every_lane_a_vehicle_occupies() -> None:
    # lane 0: vehicles at 100, 80, 30 m; lane 1: one at 90 m changing into lane 0, one at 60 m
    lane, pos = np.array([0, 0, 0, 1, 1]), np.array([100.0, 80.0, 30.0, 90.0, 60.0])
    other = np.array([-1, -1, -1, 0, -1])
    value = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    occ = physics.occupancy(lane, pos, other)
    got = followers_mean(occ.keys, value[occ.veh], lane, other, pos, 50.0)
    # 100 m: the one at 80 and the changer at 90 (in lane 0 too); 80 m: the one at 30 (the window's edge counts);
    # 30 m: none; the changer: 60 m in lane 1 and 80 m in lane 0; 60 m: none within 50 m behind
    np.testing.assert_allclose(got, [3.0, 3.0, 0.0, 3.5, 0.0])
    # a shorter window leaves out the vehicle 50 m behind; an empty road gives nothing
    np.testing.assert_allclose(followers_mean(occ.keys, value[occ.veh], lane, other, pos, 49.0)[1], 0.0)
    assert followers_mean(occ.keys[:0], value[:0], lane[:0], other[:0], pos[:0], 50.0).shape == (0,)
