"""The compiled kernels (coopsumo.sim.fast) equal their numpy definitions (physics, reward) bit for bit; hand-made
cases of the neighbour search and the overlap scan (the controller's step: test_fast_step.py)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from coopsumo.config import AccidentConfig, ControlConfig
from coopsumo.sim import fast, physics
from coopsumo.sim.controller import Controls
from coopsumo.sim.observation import snapshot
from coopsumo.sim.reward import followers_mean, section_crossings

CAR_M = 4.0
CONTROLS = Controls(ControlConfig(car_length_m=CAR_M), AccidentConfig(), 3, 3.2)


def road(rng: np.random.Generator, n: int, lanes: int = 3) -> tuple[np.ndarray, ...]:
    """A random road: lane, position (m; some on a 1 m grid so that vehicles share positions, some overlapping),
    speed (m/s), the second lane of about one vehicle in five (a lane changer; -1 otherwise)."""
    lane = rng.integers(0, lanes, n)
    pos = np.where(rng.random(n) < 0.3, np.round(rng.uniform(0, 300, n)), rng.uniform(0, 300, n))
    speed = rng.uniform(0, 30, n)
    other = np.where(rng.random(n) < 0.2, np.clip(lane + rng.choice([-1, 1], n), -1, lanes), -1)
    return lane, pos, speed, other


def same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)


def test_neighbours_see_leader_and_follower_across_lanes() -> None:
    """A hand-made case, so that the comparisons with the definitions (here and in test_fast_step.py) cannot pass on
    two equal mistakes: vehicle 1 changes from lane 0 to 1 and is in both; vehicle 0 sees it ahead in lane 1,
    vehicle 2 behind in lane 0."""
    nums, lane, pos = np.array([0, 1, 2]), np.array([1, 0, 0]), np.array([40.0, 60.0, 100.0])
    state = SimpleNamespace(v_exp=np.full(3, 30.0), lc_left_s=np.array([0.0, 2.0, 0.0]), lc_from=np.array([-1, 0, -1]),
                            lc_to=np.array([-1, 1, -1]), hold=np.zeros(3, np.int8))  # fmt: skip
    seen = fast.sight(nums, lane, pos, np.array([10.0, 20.0, 30.0]), state, CONTROLS)
    own = 1  # the columns: left, own, right, second lane
    assert seen.other.tolist() == [-1, 1, -1] and seen.busy.tolist() == [False, True, False]
    assert seen.nb.lead_idx[:, own].tolist() == [1, 2, -1]
    assert seen.nb.lead_gap[0, own] == 60.0 - CAR_M - 40.0 and seen.nb.lead_speed[0, own] == 20.0
    assert seen.nb.follow_idx[:, own].tolist() == [-1, -1, 1]
    assert seen.leader_gap[1] == 100.0 - CAR_M - 60.0  # its nearest over lanes 0 and 1
    assert not seen.feasible[1, physics.LEFT] and seen.feasible[:, physics.SPEEDUP].all()


def test_overlaps_find_a_known_collision() -> None:
    """after_step's overlap scan: 0 and 1 overlap (3 m < one car); 2, alone in lane 1, overlaps both once it is half
    way into lane 0."""
    nums, lane, pos = np.array([0, 1, 2]), np.array([0, 0, 1]), np.array([10.0, 13.0, 11.0])
    state = SimpleNamespace(lc_left_s=np.zeros(3), lc_from=np.full(3, -1), lc_to=np.full(3, -1))
    assert fast.after_step(nums, lane, pos, state, CONTROLS).tolist() == [[0, 1]]
    state.lc_left_s[2], state.lc_from[2], state.lc_to[2] = 2.0, 1, 0
    assert fast.after_step(nums, lane, pos, state, CONTROLS).tolist() == [[0, 2], [2, 1]]
    assert state.lc_left_s[2] == 2.0 - CONTROLS.control.dt_s  # its clock ran down by one step


@pytest.mark.parametrize("seed", range(40))
def test_section_crossings_equal_the_definition(seed: int) -> None:
    rng = np.random.default_rng(200 + seed)
    n = int(rng.integers(0, 50))
    prev_nums = np.sort(rng.choice(200, n, replace=False))
    prev_pos = rng.uniform(0, 1000, n)
    keep = rng.random(n) < 0.8  # some leave; others arrive
    nums = np.sort(np.concatenate([prev_nums[keep], rng.choice(np.arange(200, 260), 3, replace=False)]))
    pos = rng.uniform(0, 1000, len(nums))
    row = np.searchsorted(prev_nums, nums)
    found = (row < n) & (prev_nums[np.minimum(row, max(n - 1, 0))] == nums) if n else np.zeros(len(nums), bool)
    pos[found] = prev_pos[row[found]] + rng.uniform(0, 30, int(found.sum()))  # moving on
    sections = np.arange(200.0, 1000.0, 200.0)
    got = fast.section_crossings(prev_nums, prev_pos, nums, pos, sections)
    assert got == section_crossings(prev_nums, prev_pos, nums, pos, sections)


def test_section_crossings_counts_a_front_reaching_the_loop() -> None:
    nums = np.array([1, 2, 3])
    before = np.array([199.0, 150.0, 200.0])
    after = np.array([200.0, 199.0, 201.0])  # 1 reaches 200 (counted), 2 does not, 3 was on it already
    assert fast.section_crossings(nums, before, nums, after, np.array([200.0])) == 1


@pytest.mark.parametrize("seed", range(40))
def test_occupancy_equals_the_definition(seed: int) -> None:
    rng = np.random.default_rng(300 + seed)
    lane, pos, _, other = road(rng, int(rng.integers(0, 80)))
    got, ref = fast.occupancy(lane, pos, other), physics.occupancy(lane, pos, other)
    for name in ("keys", "lane", "pos", "veh"):
        assert same(getattr(got, name), getattr(ref, name)), name


@pytest.mark.parametrize("seed", range(40))
def test_followers_mean_equals_the_definition(seed: int) -> None:
    """Bit for bit, on roads with shared positions, lane changers in two lanes, windows of 0 m to everything."""
    rng = np.random.default_rng(400 + seed)
    lane, pos, speed, other = road(rng, int(rng.integers(0, 80)), lanes=int(rng.integers(2, 7)))
    occ = physics.occupancy(lane, pos, other)
    value = speed[occ.veh] * rng.normal(size=len(occ.veh))  # a vehicle in two lanes: its value twice
    for window in (0.0, 4.0, 50.0, 1e9):
        got = fast.followers_mean(occ.keys, value, lane, other, pos, window)
        assert same(got, followers_mean(occ.keys, value, lane, other, pos, window)), window


def test_followers_mean_of_a_hand_made_road() -> None:
    """Lane 0: vehicles at 10, 30 and 70 m; at 30 m one changing into lane 1, where one stands at 5 m."""
    lane, pos, other = np.array([0, 0, 0, 1]), np.array([10.0, 30.0, 70.0, 5.0]), np.array([-1, 1, -1, -1])
    value = np.array([1.0, 2.0, 4.0, 8.0])
    occ = physics.occupancy(lane, pos, other)
    got = fast.followers_mean(occ.keys, value[occ.veh], lane, other, pos, 50.0)
    # 10 m: nobody behind; 30 m: 10 m in lane 0 and 5 m in lane 1; 70 m: 30 m only (10 m is 60 m behind); 5 m: none
    assert got.tolist() == [0.0, (1.0 + 8.0) / 2, 2.0, 0.0]


@pytest.mark.parametrize("seed", range(40))
def test_snapshot_equals_the_definition(seed: int) -> None:
    """Bit for bit, with shared and overlapping positions, lane changers in two lanes, vehicles behind the road's start
    and lanes off the road, for several vehicle lengths."""
    rng = np.random.default_rng(500 + seed)
    lanes = int(rng.integers(2, 7))
    lane, pos, _, other = road(rng, int(rng.integers(0, 120)), lanes=lanes)
    pos = pos - 10.0 * (rng.random(len(pos)) < 0.1)
    occ = physics.occupancy(lane, pos, other)
    for car in (4.0, 4.5, 7.3):
        assert same(fast.snapshot(occ, lane, pos, lanes, car), snapshot(occ, lane, pos, lanes, car)), car


def test_snapshot_of_a_hand_made_road() -> None:
    """Two lanes; the vehicle at 100 m in lane 0 sees its own body (cells 1-4), one ahead at 112 m (cells 13-16) and,
    to its left, one at 103 m (cells 4-7); right of it is off the road."""
    lane, pos, other = np.array([0, 0, 1]), np.array([100.0, 112.0, 103.0]), np.full(3, -1)
    grid = fast.snapshot(physics.occupancy(lane, pos, other), lane, pos, 2, 4.0)[0]
    assert np.flatnonzero(grid[1]).tolist() == [1, 2, 3, 4, 13, 14, 15, 16]
    assert np.flatnonzero(grid[0]).tolist() == [4, 5, 6, 7]
    assert grid[2].tolist() == [1] * 20


def test_the_kernels_refuse_arrays_of_the_wrong_kind() -> None:
    """A caller that bypasses fast.py gets a Python error, not a read out of bounds."""
    from coopsumo.sim import _kernels  # type: ignore[attr-defined]

    lane = np.array([0, 1])
    with pytest.raises(TypeError, match="bytes"):
        _kernels.section_crossings(lane.astype(np.int32), np.zeros(2), lane, np.zeros(2), np.zeros(1))
    with pytest.raises(ValueError, match="lengths"):
        _kernels.occupancy(lane, np.zeros(3), lane, np.zeros(2), lane, np.zeros(2), lane)
    with pytest.raises(TypeError, match="arguments"):
        _kernels.after_step(lane)
    with pytest.raises(TypeError, match="arguments"):
        _kernels.followers_mean(lane)
    with pytest.raises(ValueError, match="lengths"):
        _kernels.snapshot(np.zeros(2), lane, np.zeros(2), lane, np.zeros(2), 3, 4.0, np.zeros((3, 3, 20), np.uint8))
    with pytest.raises(ValueError, match="lengths"):
        _kernels.followers_mean(np.zeros(2), np.zeros(3), lane, lane, np.zeros(2), 1.0, np.zeros(2))
