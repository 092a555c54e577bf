"""From decision rounds to replay transitions: what the trainer carries between two rounds of decisions (Pending)
and the pure array function that turns an interval into transitions (transitions)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from coopsumo.agents.dqn import N_ACTIONS
from coopsumo.sim.observation import Observation


def transitions(
    prev: Observation,
    prev_features: np.ndarray,
    actions: np.ndarray,
    reward_sum: np.ndarray,
    now: Observation,
    now_features: np.ndarray,
    now_mask: np.ndarray,
    change_sum: np.ndarray,
) -> tuple[np.ndarray, ...]:
    """(grids, features, actions, rewards, next_grids, next_features, dones, next_mask, lane_changes, nums) of the
    last interval, nums the vehicle number of each row.

    prev: the last decision round's observation, its network features (observation.network_features) and its
    `actions`; now: this round's observation and features;
    now_mask: the actions offered in it (decisions.offered; all True when nothing is withheld).
    reward_sum, change_sum: rewards and lane changes started over the interval, indexed by vehicle number.
    Vehicles present in both rounds give ordinary transitions (dones all 0); a vehicle that left the road in between
    gives none (storing its last transition as terminal was tried and retired, issue 80: dqn_config.RETIRED_FIELDS).
    """
    _, i_prev, i_now = np.intersect1d(prev.nums, now.nums, assume_unique=True, return_indices=True)
    reward = reward_sum[prev.nums]
    changes = change_sum[prev.nums]
    g, e = prev.grids[i_prev], prev_features[i_prev]
    ng, ne = now.grids[i_now], now_features[i_now]
    a, r, c, nums = actions[i_prev], reward[i_prev], changes[i_prev], prev.nums[i_prev]
    nm = now_mask[i_now]
    done = np.zeros(len(i_prev), np.float32)
    return g, e, a, r.astype(np.float32), ng, ne, done, nm, c.astype(np.float32), nums


def all_if_none(mask: np.ndarray | None, obs: Observation) -> np.ndarray:
    """mask, or every action offered to every vehicle of obs when it is None."""
    return np.ones((len(obs), N_ACTIONS), bool) if mask is None else mask


@dataclass
class Pending:
    """What the trainer carries between decision rounds (rebuilt by replay on resume)."""

    prev: Observation | None = None
    """the last decision round's observation"""
    prev_features: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.float32))
    """its network features (observation.network_features)"""
    prev_actions: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """the actions decided then"""
    reward_sum: np.ndarray = field(default_factory=lambda: np.zeros(1024))
    """rewards since each vehicle's last decision, by vehicle number"""
    change_sum: np.ndarray = field(default_factory=lambda: np.zeros(1024))
    """lane changes started since each vehicle's last decision, by vehicle number"""
    prev_alpha: float = 0.0
    """the alpha of the last decision round (a conditioned training's draw)"""

    def _grow(self, nums: np.ndarray) -> None:
        if len(nums) and int(nums.max()) >= len(self.reward_sum):
            extra = max(int(nums.max()) + 1, 2 * len(self.reward_sum)) - len(self.reward_sum)
            self.reward_sum = np.concatenate([self.reward_sum, np.zeros(extra)])
            self.change_sum = np.concatenate([self.change_sum, np.zeros(extra)])

    def start_interval(self, obs: Observation, features: np.ndarray, actions: np.ndarray, alpha: float) -> None:
        """A decision round at `alpha`: remember it and zero the sums of the vehicles that decided."""
        self._grow(obs.nums)
        self.reward_sum[obs.nums] = 0.0
        self.change_sum[obs.nums] = 0.0
        self.prev, self.prev_features, self.prev_actions = obs, features, actions
        self.prev_alpha = alpha

    def add_rewards(self, nums: np.ndarray, rewards: np.ndarray, changes: np.ndarray) -> None:
        self._grow(nums)
        self.reward_sum[nums] += rewards
        self.change_sum[nums] += changes
