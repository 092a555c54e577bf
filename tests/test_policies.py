"""Baseline policies on hand-made observations; no SUMO."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from coopsumo.agents.policies import GreedyPolicy, KeepPolicy, PolicySpecError, RandomPolicy, make_policy
from coopsumo.errors import UsageError
from coopsumo.sim.observation import Observation
from coopsumo.sim.physics import LEFT, NONE, RIGHT, SPEEDUP

ObsOf = Callable[..., Observation]


def test_keep_never_changes_lane(observation_of: ObsOf) -> None:
    rng = np.random.default_rng(0)
    n = 200
    obs = observation_of(
        rng.integers(0, 3, n).tolist(), (np.arange(n) * 9.0).tolist(), rng.uniform(0, 30, n).tolist(),
        rng.uniform(11, 30, n).tolist(),
    )  # fmt: skip
    actions = KeepPolicy().act(obs)
    assert actions.dtype == np.int64 and actions.shape == (n,)
    assert not np.any((actions == LEFT) | (actions == RIGHT))
    assert np.all(actions == SPEEDUP)


def test_keep_and_greedy_on_an_empty_batch(observation_of: ObsOf) -> None:
    obs = observation_of([], [], [], [])
    assert KeepPolicy().act(obs).shape == (0,)
    assert GreedyPolicy().act(obs).shape == (0,)
    assert RandomPolicy(np.random.default_rng(0)).act(obs).shape == (0,)


def test_random_is_reproducible_with_a_seeded_rng_and_uses_every_action(observation_of: ObsOf) -> None:
    n = 500
    obs = observation_of([1] * n, (np.arange(n) * 10.0).tolist(), [20.0] * n, [25.0] * n)
    a1 = RandomPolicy(np.random.default_rng(42)).act(obs)
    a2 = RandomPolicy(np.random.default_rng(42)).act(obs)
    a3 = RandomPolicy(np.random.default_rng(43)).act(obs)
    np.testing.assert_array_equal(a1, a2)
    assert not np.array_equal(a1, a3)
    assert set(a1.tolist()) == {LEFT, RIGHT, SPEEDUP, NONE}
    counts = np.bincount(a1, minlength=4)
    assert np.all(counts > n / 4 * 0.7)  # uniform: about 125 each


def greedy(observation_of: ObsOf, lane: list[int], pos: list[float], speed: list[float], v_exp: list[float],
           n_lanes: int = 3) -> np.ndarray:  # fmt: skip
    return GreedyPolicy(look_m=60.0, margin_m=20.0, slack_mps=1.0).act(
        observation_of(lane, pos, speed, v_exp, n_lanes=n_lanes)
    )


def test_greedy_moves_left_when_held_back_and_the_left_lane_is_clearly_freer(observation_of: ObsOf) -> None:
    # ego (0) in lane 1 at 100 m, 15 m/s wanting 25; leader 20 m ahead (gap 16); left lane empty;
    # right lane has a car 50 m ahead (gap 46 >= 16 + 20, but the left is freer still)
    a = greedy(observation_of, [1, 1, 0], [100.0, 120.0, 150.0], [15.0, 15.0, 15.0], [25.0, 15.0, 15.0])
    assert a[0] == LEFT


def test_greedy_moves_right_when_only_the_right_lane_is_clearly_freer(observation_of: ObsOf) -> None:
    # left lane: a car 30 m ahead (gap 26 < 16 + 20): not clearly better; right lane empty
    a = greedy(observation_of, [1, 1, 2], [100.0, 120.0, 130.0], [15.0, 15.0, 15.0], [25.0, 15.0, 15.0])
    assert a[0] == RIGHT


def test_greedy_stays_when_not_held_back(observation_of: ObsOf) -> None:
    # leader far (gap 96 >= 60): not held, even though the side lanes are empty
    a = greedy(observation_of, [1, 1], [100.0, 200.0], [15.0, 15.0], [25.0, 15.0])
    assert a[0] == SPEEDUP
    # leader close but ego already within 1 m/s of v_exp: not held
    a = greedy(observation_of, [1, 1], [100.0, 120.0], [24.5, 15.0], [25.0, 15.0])
    assert a[0] == SPEEDUP


def test_greedy_stays_when_no_side_lane_has_clearly_more_room(observation_of: ObsOf) -> None:
    # held back (gap 16), left gap 30 and right gap 35, both < 16 + 20
    a = greedy(observation_of, [1, 1, 2, 0], [100.0, 120.0, 134.0, 139.0], [15.0] * 4, [25.0, 15.0, 15.0, 15.0])
    assert a[0] == SPEEDUP


def test_greedy_never_leaves_the_road(observation_of: ObsOf) -> None:
    # held back in the leftmost lane of 2 with the right lane busy, and in lane 0 with the left lane busy
    a = greedy(observation_of, [1, 1, 0], [100.0, 110.0, 112.0], [10.0] * 3, [30.0, 10.0, 10.0], n_lanes=2)
    assert a[0] == SPEEDUP
    a = greedy(observation_of, [0, 0, 1], [100.0, 110.0, 112.0], [10.0] * 3, [30.0, 10.0, 10.0], n_lanes=2)
    assert a[0] == SPEEDUP
    # with the other lane free it goes there
    a = greedy(observation_of, [1, 1], [100.0, 110.0], [10.0] * 2, [30.0, 10.0], n_lanes=2)
    assert a[0] == RIGHT
    a = greedy(observation_of, [0, 0], [100.0, 110.0], [10.0] * 2, [30.0, 10.0], n_lanes=2)
    assert a[0] == LEFT


@pytest.mark.parametrize("spec", ["foo", "", "Keep", "random:3", "dqn"])
def test_make_policy_rejects_unknown_names(spec: str) -> None:
    with pytest.raises(PolicySpecError, match="unknown policy|policy must be|takes no parameters|needs a model"):
        make_policy(spec, np.random.default_rng(0))
    assert issubclass(PolicySpecError, UsageError)


def test_make_policy_builds_the_baselines() -> None:
    rng = np.random.default_rng(0)
    assert isinstance(make_policy("keep", rng), KeepPolicy)
    assert isinstance(make_policy("greedy", rng), GreedyPolicy)
    policy = make_policy("random", rng)
    assert isinstance(policy, RandomPolicy) and policy.rng is rng
