"""n-step returns (DQNConfig.n_step, not in the paper): a vehicle's transitions of n consecutive decision rounds
joined into one, so that a reward reaches the decision that earned it n rounds sooner than by bootstrapping.

Pure numpy. A round is what agents.transitions.transitions gives for one interval between two decision rounds,
with the vehicle numbers of its rows. The joined transition of a vehicle that decided in round 0 has

- reward r_0 + g r_1 + ... + g^(n-1) r_(n-1) (g: the discount per decision round), every r_i rewritten at round
  0's alpha (a conditioned training draws alpha afresh every alpha_period_steps: r_i + (alpha_i - alpha_0) c_i,
  with c_i the lane changes it started in round i, exact because the reward is linear in alpha);
- lane changes c_0 + g c_1 + ... (what replay.relabelled needs to rewrite the sum at another alpha);
- the next state, feasible next actions and done of round n-1, bootstrapped with g^n (dqn.learn).

A vehicle that left the road as a terminal transition (exit_transition "terminal") within the n rounds ends its
sum there, done. One that is missing from a later round (it left and exit_transition "drop" dropped its last
transition) is dropped too, as its 1-step transition would have been. With n = 1 nothing is joined.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

REWARD, NEXT_GRIDS, NEXT_FEATURES, DONES, NEXT_MASK, LANE_CHANGES = 3, 4, 5, 6, 7, 8
"""positions in a transitions() batch: (grids, features, actions, rewards, next_grids, next_features, dones,
next_mask, lane_changes)"""


@dataclass(frozen=True)
class Round:
    """One interval's transitions, by row: the vehicles' numbers, the batch, and the alpha their rewards carry."""

    nums: np.ndarray
    batch: tuple[np.ndarray, ...]
    alpha: float


def join(rounds: list[Round], gamma: float) -> tuple[np.ndarray, ...]:
    """The n-step transitions (n = len(rounds)) of the vehicles that decided in rounds[0], in its row order,
    as a transitions() batch without the rows dropped (module docstring)."""
    first = rounds[0]
    batch = [np.array(x, copy=True) for x in first.batch]
    reward = first.batch[REWARD].astype(np.float64)
    changes = first.batch[LANE_CHANGES].astype(np.float64)
    ended = first.batch[DONES] > 0
    kept = np.ones(len(first.nums), bool)
    for i, later in enumerate(rounds[1:], start=1):
        if not len(later.nums):  # nobody left on the road: only the chains that already ended stay
            kept &= ended
            continue
        order = np.argsort(later.nums, kind="stable")
        rows = order[np.minimum(np.searchsorted(later.nums, first.nums, sorter=order), len(order) - 1)]
        found = later.nums[rows] == first.nums
        kept &= found | ended
        go = np.flatnonzero(found & ~ended & kept)
        src = rows[go]
        step_changes = later.batch[LANE_CHANGES][src].astype(np.float64)
        step_reward = later.batch[REWARD][src].astype(np.float64)
        if later.alpha != first.alpha:
            step_reward = step_reward + (later.alpha - first.alpha) * step_changes
        reward[go] += gamma**i * step_reward
        changes[go] += gamma**i * step_changes
        for field in (NEXT_GRIDS, NEXT_FEATURES, DONES, NEXT_MASK):
            batch[field][go] = later.batch[field][src]
        ended[go] = later.batch[DONES][src] > 0
    batch[REWARD] = reward.astype(np.float32)
    batch[LANE_CHANGES] = changes.astype(np.float32)
    return tuple(x[kept] for x in batch)


def mature(rounds: list[Round], n: int, gamma: float) -> tuple[tuple[np.ndarray, ...], float] | None:
    """When `rounds` (oldest first, the newest just appended) holds n rounds: the oldest one's joined
    transitions and its alpha, and it leaves the list; else None."""
    if len(rounds) < n:
        return None
    joined = join(rounds[:n], gamma)
    alpha = rounds[0].alpha
    del rounds[0]
    return joined, alpha
