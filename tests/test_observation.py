"""Occupancy grids (observation.snapshot) and FrameHistory on hand-made layouts; no SUMO.

Cell k of a row covers [front - 5 + k, front - 4 + k) around the observer's front bumper and is 1
when its centre lies inside a vehicle [front_j - 4, front_j). Rows are (left, own, right).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import pytest

from coopsumo.sim import physics
from coopsumo.sim.observation import (
    N_CELLS,
    N_V2X,
    FrameHistory,
    Observation,
    n_features,
    network_features,
    snapshot,
    v2x_features,
)

L_CAR = 4.0
LEFT, OWN, RIGHT = 0, 1, 2


def grids(lane: list[int], pos: list[float], n_lanes: int = 3, other: list[int] | None = None) -> np.ndarray:
    lane_a = np.array(lane, np.int64)
    pos_a = np.array(pos, np.float64)
    other_a = np.full(len(lane), -1, np.int64) if other is None else np.array(other, np.int64)
    occ = physics.occupancy(lane_a, pos_a, other_a)
    return snapshot(occ, lane_a, pos_a, n_lanes, L_CAR)


def cells(*ks: int) -> list[int]:
    row = [0] * N_CELLS
    for k in ks:
        row[k] = 1
    return row


def test_grid_shape_and_type() -> None:
    g = grids([1, 0], [100.0, 50.0])
    assert g.shape == (2, 3, 20) and g.dtype == np.uint8
    assert set(np.unique(g).tolist()) <= {0, 1}


def test_the_observer_fills_its_own_four_cells() -> None:
    g = grids([1], [100.0])[0]
    # own body [96, 100): centres 95.5 + k inside for k = 1..4
    assert g[OWN].tolist() == cells(1, 2, 3, 4)
    assert g[LEFT].tolist() == cells() and g[RIGHT].tolist() == cells()


def test_a_car_ahead_in_the_left_lane() -> None:
    # front 15 m ahead: body [111, 115) -> the right-most 4 cells (centres 111.5 .. 114.5)
    g = grids([1, 2], [100.0, 115.0])[0]
    assert g[LEFT].tolist() == cells(16, 17, 18, 19)
    # front 10 m ahead: body [106, 110) -> cells 11..14
    g = grids([1, 2], [100.0, 110.0])[0]
    assert g[LEFT].tolist() == cells(11, 12, 13, 14)
    assert g[OWN].tolist() == cells(1, 2, 3, 4) and g[RIGHT].tolist() == cells()


def test_window_edges_behind_and_ahead() -> None:
    # a car just behind in the right lane, front 3 m behind: body [93, 97) -> centres 95.5, 96.5 -> cells 0, 1
    g = grids([1, 0], [100.0, 97.0])[0]
    assert g[RIGHT].tolist() == cells(0, 1)
    # front 19 m ahead: body [115, 119) starts at the window's end: nothing
    # front 16.5 m ahead: body [112.5, 116.5) covers centres 112.5 .. 114.5 -> cells 17..19
    g = grids([1, 2, 0], [100.0, 119.0, 116.5])[0]
    assert g[LEFT].tolist() == cells()
    assert g[RIGHT].tolist() == cells(17, 18, 19)
    # a car whose front is exactly at the window start (95) is out; at 96 it covers cell 0 (centre 95.5)
    assert grids([1, 0], [100.0, 95.0])[0][RIGHT].tolist() == cells()
    assert grids([1, 0], [100.0, 96.0])[0][RIGHT].tolist() == cells(0)


def test_a_car_changing_lanes_appears_in_both_lanes() -> None:
    # vehicle 1 moves from lane 0 to lane 1 with its front 10 m ahead of the observer (lane 1 at 100)
    g = grids([1, 0], [100.0, 110.0], other=[-1, 1])
    assert g[0, RIGHT].tolist() == cells(11, 12, 13, 14)
    assert g[0, OWN].tolist() == cells(1, 2, 3, 4, 11, 12, 13, 14)
    assert g[0, LEFT].tolist() == cells()
    # and the changing vehicle itself (SUMO lane 0) sees its own body in its lane and in lane 1 (its left)
    assert g[1, OWN].tolist() == cells(1, 2, 3, 4) and g[1, LEFT].tolist() == cells(1, 2, 3, 4)


def test_road_edges_are_all_ones() -> None:
    g = grids([0, 2], [100.0, 300.0], n_lanes=3)
    assert np.all(g[0, RIGHT] == 1) and g[0, LEFT].tolist() == cells()
    assert np.all(g[1, LEFT] == 1) and g[1, RIGHT].tolist() == cells()
    g2 = grids([0, 1], [100.0, 300.0], n_lanes=2)
    assert np.all(g2[0, RIGHT] == 1) and not np.any(g2[0, LEFT])
    assert np.all(g2[1, LEFT] == 1) and not np.any(g2[1, RIGHT])


def test_a_lone_vehicle_on_an_empty_neighbourhood_and_an_empty_road() -> None:
    assert grids([], []).shape == (0, 3, 20)
    g = grids([3], [50.0], n_lanes=6)[0]
    assert g.sum() == 4


def brute_force_grid(i: int, lane: np.ndarray, pos: np.ndarray, other: np.ndarray, n_lanes: int) -> np.ndarray:
    out = np.zeros((3, N_CELLS), np.uint8)
    for row, q in enumerate(lane[i] + physics.SIDE_OFFSETS):
        if not 0 <= q < n_lanes:
            out[row] = 1
            continue
        for k in range(N_CELLS):
            centre = pos[i] - 5.0 + k + 0.5
            for j in range(len(lane)):
                if q in (lane[j], other[j]) and pos[j] - L_CAR <= centre < pos[j]:
                    out[row, k] = 1
    return out


def test_snapshot_agrees_with_a_brute_force_grid_on_dense_random_layouts() -> None:
    rng = np.random.default_rng(7)
    n_lanes = 4
    for _ in range(5):
        # bumper-to-bumper traffic: gaps of 0-3 m, some vehicles changing lanes (so lanes hold overlaps)
        lane_list, pos_list = [], []
        for q in range(n_lanes):
            x = rng.uniform(4, 8)
            while x < 200:
                lane_list.append(q)
                pos_list.append(x)
                x += L_CAR + rng.uniform(0.0, 3.0)
        lane = np.array(lane_list)
        pos = np.array(pos_list) + rng.uniform(0, 1e-3, len(pos_list))
        other = np.where(rng.random(len(lane)) < 0.1, lane + 1, -1)
        other = np.where(other < n_lanes, other, -1)
        occ = physics.occupancy(lane, pos, other)
        g = snapshot(occ, lane, pos, n_lanes, L_CAR)
        for i in range(len(lane)):
            np.testing.assert_array_equal(g[i], brute_force_grid(i, lane, pos, other, n_lanes), err_msg=str(i))


# -- FrameHistory -------------------------------------------------------------------------------


def frame(value: int) -> np.ndarray:
    return np.full((3, N_CELLS), value, np.uint8)


def test_a_new_vehicle_gets_its_first_frame_three_times() -> None:
    h = FrameHistory.empty(capacity=8)
    g, e = h.push(np.array([5]), frame(1)[None], np.array([-2.0], np.float32))
    assert g.shape == (1, 3, 3, N_CELLS) and e.shape == (1, 3)
    assert [int(g[0, f, 0, 0]) for f in range(3)] == [1, 1, 1]
    assert e[0].tolist() == [-2.0, -2.0, -2.0]


def test_frames_are_in_time_order_oldest_first() -> None:
    h = FrameHistory.empty(capacity=8)
    for t in range(1, 5):  # frames 1, 2, 3, 4 for vehicle 3
        g, e = h.push(np.array([3]), frame(t)[None], np.array([-float(t)], np.float32))
    assert [int(g[0, f, 0, 0]) for f in range(3)] == [2, 3, 4]
    assert e[0].tolist() == [-2.0, -3.0, -4.0]


def test_vehicles_keep_separate_histories_and_latecomers_start_fresh() -> None:
    h = FrameHistory.empty(capacity=2)  # vehicle numbers beyond the capacity make it grow
    h.push(np.array([0]), frame(1)[None], np.array([1.0], np.float32))
    h.push(np.array([0, 6]), np.stack([frame(2), frame(9)]), np.array([2.0, 9.0], np.float32))
    g, e = h.push(np.array([0, 6]), np.stack([frame(3), frame(8)]), np.array([3.0, 8.0], np.float32))
    assert [int(g[0, f, 0, 0]) for f in range(3)] == [1, 2, 3]
    assert [int(g[1, f, 0, 0]) for f in range(3)] == [9, 9, 8]
    assert e.tolist() == [[1.0, 2.0, 3.0], [9.0, 9.0, 8.0]]
    # a vehicle absent for a step keeps its history; the returned arrays are copies
    g[:] = 0
    g2, _ = h.push(np.array([6]), frame(7)[None], np.array([7.0], np.float32))
    assert [int(g2[0, f, 0, 0]) for f in range(3)] == [9, 8, 7]


def test_history_keeps_whole_grids_not_just_one_cell() -> None:
    h = FrameHistory.empty(capacity=4)
    a = np.zeros((3, N_CELLS), np.uint8)
    a[1, 1:5] = 1
    b = a.copy()
    b[0, 16:20] = 1
    h.push(np.array([1]), a[None], np.zeros(1, np.float32))
    g, _ = h.push(np.array([1]), b[None], np.zeros(1, np.float32))
    np.testing.assert_array_equal(g[0, 0], a)
    np.testing.assert_array_equal(g[0, 1], a)
    np.testing.assert_array_equal(g[0, 2], b)


# --- the v2x state (observation.v2x_features) ----------------------------------------------------

SCALE = 30.0  # speed scale (m/s) of the tests below


def v2x(lane: list[int], pos: list[float], speed: list[float], n_lanes: int = 3,
        other: list[int] | None = None) -> np.ndarray:  # fmt: skip
    """(n, 3 sides, 5) per-side v2x features and (n, 3) own features of a hand-made layout."""
    lane_a, pos_a, speed_a = np.array(lane, np.int64), np.array(pos, np.float64), np.array(speed, np.float64)
    other_a = np.full(len(lane), -1, np.int64) if other is None else np.array(other, np.int64)
    occ = physics.occupancy(lane_a, pos_a, other_a)
    around = physics.neighbours(occ, pos_a, speed_a, physics.side_lanes(lane_a), n_lanes, L_CAR)
    feats = v2x_features(around, speed_a, np.full(len(lane), 25.0), other_a >= 0, SCALE)
    assert feats.shape == (len(lane), N_V2X) and feats.dtype == np.float32
    return feats


def side(feats: np.ndarray, row: int, which: int) -> list[float]:
    """[exists, lead gap, lead dv, follow gap, follow dv] of vehicle row in side which (0 left, 1 own, 2 right)."""
    return feats[row, which * 5 : which * 5 + 5].round(6).tolist()


def test_v2x_gaps_and_speeds_of_leaders_and_followers_in_every_lane() -> None:
    # observer on lane 1 at 500 m, 20 m/s; leader own lane at 540 (18 m/s), follower own lane at 470 (22 m/s);
    # left lane: leader at 600 (30 m/s); right lane: follower at 495 (10 m/s)
    f = v2x([1, 1, 1, 2, 0], [500, 540, 470, 600, 495], [20, 18, 22, 30, 10])
    gap_own_lead, gap_own_follow = (540 - 4 - 500) / 200, (500 - 4 - 470) / 200
    assert side(f, 0, OWN) == pytest.approx([1, gap_own_lead, -2 / SCALE, gap_own_follow, 2 / SCALE], abs=1e-6)
    assert side(f, 0, LEFT) == pytest.approx([1, (600 - 4 - 500) / 200, 10 / SCALE, 1, 0], abs=1e-6)
    assert side(f, 0, RIGHT) == pytest.approx([1, 1, 0, (500 - 4 - 495) / 200, -10 / SCALE], abs=1e-6)
    assert f[0, 15:].tolist() == pytest.approx([20 / SCALE, 25 / SCALE, 0.0])


def test_v2x_neighbours_beyond_range_are_absent_and_gaps_clip_at_one() -> None:
    f = v2x([1, 1, 1], [500, 500 + 4 + 250, 500 - 4 - 201], [20, 5, 35])
    assert side(f, 0, OWN) == [1, 1, 0, 1, 0]  # both farther than 200 m: told nothing
    near = v2x([1, 1], [500, 500 + 4 + 199], [20, 5])
    assert side(near, 0, OWN) == pytest.approx([1, 199 / 200, -15 / SCALE, 1, 0], abs=1e-6)


def test_v2x_road_edges_are_zero_and_say_no_lane() -> None:
    f = v2x([0, 2], [100, 300], [20, 20])
    assert side(f, 0, RIGHT) == [0, 0, 0, 0, 0]  # right of lane 0: off the road
    assert side(f, 0, LEFT)[0] == 1 and side(f, 1, LEFT) == [0, 0, 0, 0, 0]
    assert side(f, 1, RIGHT)[0] == 1
    two = v2x([0], [100], [20], n_lanes=2)
    assert side(two, 0, LEFT)[0] == 1 and side(two, 0, RIGHT)[0] == 0


def test_v2x_a_vehicle_changing_lanes_counts_in_both_lanes_and_says_so() -> None:
    # vehicle 1 at 530 m goes from lane 2 to lane 1: the observer on lane 1 sees it as its own leader,
    # and sees it in the left lane too; vehicle 1 itself says it is changing
    f = v2x([1, 2], [500, 530], [20, 20], other=[-1, 1])
    assert side(f, 0, OWN)[:2] == pytest.approx([1, (530 - 4 - 500) / 200])
    assert side(f, 0, LEFT)[:2] == pytest.approx([1, (530 - 4 - 500) / 200])
    assert f[0, -1] == 0.0 and f[1, -1] == 1.0


def test_network_features_paper_is_the_speed_errors_and_v2x_appends(
    observation_of: Callable[..., Observation],
) -> None:
    obs = observation_of([1, 1], [100.0, 150.0], [20.0, 10.0], [25.0, 30.0])
    obs = dataclasses.replace(obs, speed_err=np.array([[1, 2, 3], [4, 5, 6]], np.float32))
    assert network_features(obs, "paper", SCALE) is obs.speed_err
    both = network_features(obs, "v2x", SCALE)
    assert both.shape == (2, n_features("v2x")) and n_features("paper") == 3
    assert both[:, :3].tolist() == obs.speed_err.tolist()
    expected = v2x_features(obs.around, obs.speed, obs.v_exp, obs.busy, SCALE)
    assert np.array_equal(both[:, 3:], expected)
    with pytest.raises(ValueError, match="unknown observation"):
        network_features(obs, "lidar", SCALE)


def test_v2x_of_an_empty_road_has_its_shape() -> None:
    empty = physics.neighbours(physics.occupancy(np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64)),
                               np.zeros(0), np.zeros(0), np.zeros((0, 3), np.int64), 3, L_CAR)  # fmt: skip
    assert v2x_features(empty, np.zeros(0), np.zeros(0), np.zeros(0, bool), SCALE).shape == (0, N_V2X)
