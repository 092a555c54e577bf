"""Occupancy grids (observation.snapshot) and FrameHistory on hand-made layouts; no SUMO.

Cell k of a row covers [front - 5 + k, front - 4 + k) around the observer's front bumper and is 1
when its centre lies inside a vehicle [front_j - 4, front_j). Rows are (left, own, right).
"""

from __future__ import annotations

import numpy as np

from coopsumo.sim import physics
from coopsumo.sim.observation import N_CELLS, FrameHistory, snapshot

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
