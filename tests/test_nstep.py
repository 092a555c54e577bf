"""n-step returns (agents/nstep.py): joining a vehicle's transitions of consecutive decision rounds. Pure numpy,
no SUMO; a real training with --n-step is in tests/test_train.py."""

from __future__ import annotations

import numpy as np
import pytest

from coopsumo.agents.nstep import DONES, LANE_CHANGES, NEXT_GRIDS, REWARD, Round, join, mature
from coopsumo.agents.replay import relabelled

G = 0.9


def _round(nums: list[int], rewards: list[float], *, done: list[int] | None = None, changes: list[float] | None = None,
           tag: int = 0, alpha: float = 0.0) -> Round:  # fmt: skip
    """A round whose next grids carry `tag` (which round a joined transition bootstraps from)."""
    k = len(nums)
    batch = (
        np.zeros((k, 3, 3, 20), np.uint8),
        np.arange(k, dtype=np.float32)[:, None] * np.ones((1, 3), np.float32),
        np.full(k, 2, np.int64),
        np.array(rewards, np.float32),
        np.full((k, 3, 3, 20), tag, np.uint8),
        np.zeros((k, 3), np.float32),
        np.array(done or [0] * k, np.float32),
        np.ones((k, 4), bool),
        np.array(changes or [0.0] * k, np.float32),
    )
    return Round(np.array(nums, np.int64), batch, alpha)


def test_three_rounds_join_into_the_discounted_sum_bootstrapped_from_the_last() -> None:
    rounds = [_round([5, 7, 9], [1.0, 2.0, 3.0], tag=1),
              _round([9, 7, 5], [10.0, 20.0, 30.0], tag=2),  # another row order
              _round([7, 5, 9], [100.0, 200.0, 300.0], tag=3)]  # fmt: skip
    out = join(rounds, G)
    assert out[REWARD] == pytest.approx([1 + G * 30 + G**2 * 200, 2 + G * 20 + G**2 * 100, 3 + G * 10 + G**2 * 300])
    assert (out[NEXT_GRIDS] == 3).all() and (out[DONES] == 0).all()
    assert out[1][:, 0].tolist() == [0.0, 1.0, 2.0]  # round 0's own state, in its row order


def test_a_vehicle_that_left_ends_its_sum_when_terminal_and_is_dropped_otherwise() -> None:
    rounds = [_round([1, 2, 3], [1.0, 1.0, 1.0], tag=1),
              _round([1, 2, 3], [2.0, 2.0, 2.0], done=[0, 1, 0], tag=2),  # 2 left, stored as terminal
              _round([1], [4.0], tag=3)]  # 3 left and was dropped (exit_transition "drop")
    out = join(rounds, G)
    assert out[REWARD] == pytest.approx([1 + G * 2 + G**2 * 4, 1 + G * 2])
    assert out[DONES].tolist() == [0.0, 1.0]
    assert out[NEXT_GRIDS][:, 0, 0, 0].tolist() == [3, 2]


def test_rewards_of_later_rounds_are_rewritten_at_the_first_rounds_alpha() -> None:
    """A conditioned training's alpha changes between rounds: the joined reward is the sum at round 0's alpha,
    and relabelling it at any alpha gives the sum every round would have had at that alpha."""
    rounds = [_round([4], [1.0], changes=[1.0], alpha=0.0),
              _round([4], [-7.0], changes=[1.0], alpha=8.0),  # -8 charged for its change, +1 speed
              _round([4], [0.5], changes=[0.0], alpha=8.0)]
    out = join(rounds, G)
    assert out[REWARD][0] == pytest.approx(1 + G * 1 + G**2 * 0.5)
    assert out[LANE_CHANGES][0] == pytest.approx(1 + G)
    at_2 = relabelled(out[REWARD], np.zeros(1, np.float32), out[LANE_CHANGES], np.full(1, 2.0, np.float32))
    assert at_2[0] == pytest.approx((1 - 2) + G * (1 - 2) + G**2 * 0.5, rel=1e-6)


def test_mature_waits_for_n_rounds_then_takes_the_oldest() -> None:
    rounds: list[Round] = []
    rounds.append(_round([1], [1.0], alpha=1.0))
    assert mature(rounds, 2, G) is None and len(rounds) == 1
    rounds.append(_round([1], [2.0], alpha=2.0))
    joined = mature(rounds, 2, G)
    assert joined is not None and joined[1] == 1.0 and joined[0][REWARD][0] == pytest.approx(1 + G * (2 + 1 * 0))
    assert len(rounds) == 1 and rounds[0].alpha == 2.0


def test_an_empty_later_round_drops_every_vehicle_still_on_the_road() -> None:
    out = join([_round([1, 2], [1.0, 1.0], done=[1, 0]), _round([], [])], G)
    assert out[REWARD].tolist() == [1.0] and out[DONES].tolist() == [1.0]
