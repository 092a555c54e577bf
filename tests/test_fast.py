"""The compiled kernels (coopsumo.sim.fast) equal their numpy definitions (physics, reward) bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from coopsumo.sim import fast, physics
from coopsumo.sim.reward import section_crossings

CAR_M = 5.0


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


@pytest.mark.parametrize("seed", range(40))
def test_occupancy_and_neighbours_equal_the_definitions(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(0, 60))
    lane, pos, speed, other = road(rng, n)
    busy = other >= 0
    query = np.concatenate([physics.side_lanes(lane), np.where(busy, other, lane)[:, None]], axis=1)
    occ, nb = fast.occupancy_and_neighbours(lane, pos, other, speed, query, 3, CAR_M)
    occ_ref = physics.occupancy(lane, pos, other)
    nb_ref = physics.neighbours(occ_ref, pos, speed, query, 3, CAR_M)
    for name in ("keys", "lane", "pos", "veh"):
        assert same(getattr(occ, name), getattr(occ_ref, name)), name
    for name in ("lead_gap", "lead_speed", "lead_idx", "follow_gap", "follow_speed", "follow_idx", "exists"):
        assert same(getattr(nb, name), getattr(nb_ref, name)), name


def test_neighbours_see_leader_and_follower_across_lanes() -> None:
    """A hand-made case, so that the comparison above cannot pass on two equal mistakes: vehicle 1 changes from
    lane 0 to 1 and is in both; vehicle 0 sees it ahead in lane 1, vehicle 2 behind in lane 0."""
    lane = np.array([1, 0, 0])
    pos = np.array([40.0, 60.0, 100.0])
    other = np.array([-1, 1, -1])
    query = np.array([[1], [0], [0]])
    _, nb = fast.occupancy_and_neighbours(lane, pos, other, np.array([10.0, 20.0, 30.0]), query, 3, CAR_M)
    assert nb.lead_idx[:, 0].tolist() == [1, 2, -1]
    assert nb.lead_gap[0, 0] == 60.0 - CAR_M - 40.0
    assert nb.follow_idx[:, 0].tolist() == [-1, -1, 1]
    assert nb.lead_speed[0, 0] == 20.0


@pytest.mark.parametrize("seed", range(40))
def test_overlaps_equal_the_definition(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    lane, pos, _, other = road(rng, int(rng.integers(0, 80)))
    got = fast.overlaps(lane, pos, other, CAR_M)
    assert same(got, physics.overlaps(physics.occupancy(lane, pos, other), CAR_M))


def test_overlaps_finds_a_known_collision() -> None:
    lane = np.array([0, 0, 1])
    pos = np.array([10.0, 13.0, 11.0])  # 0 and 1 overlap (3 m < one car); 2 is alone in lane 1
    assert fast.overlaps(lane, pos, np.full(3, -1), CAR_M).tolist() == [[0, 1]]
    assert fast.overlaps(lane, pos, np.array([-1, -1, 0]), CAR_M).tolist() == [[0, 2], [2, 1]]


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


def test_the_kernels_refuse_arrays_of_the_wrong_kind() -> None:
    """A caller that bypasses fast.py gets a Python error, not a read out of bounds."""
    from coopsumo.sim import _kernels  # type: ignore[attr-defined]

    lane = np.array([0, 1])
    with pytest.raises(TypeError, match="bytes"):
        _kernels.section_crossings(lane.astype(np.int32), np.zeros(2), lane, np.zeros(2), np.zeros(1))
    with pytest.raises(ValueError, match="lengths"):
        _kernels.overlaps(lane, np.zeros(3), lane, np.zeros((1, 2), np.int64), CAR_M)
    with pytest.raises(TypeError, match="arguments"):
        _kernels.overlaps(lane)
