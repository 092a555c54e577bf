"""The decision interval: on which steps vehicles decide, and what a decision does until the next one.

Vehicles decide together on every k-th step (step_count % k == 0); the controller still runs
every 0.1 s step. A decision holds until the next decision round:
- left/right: the lane change is requested on the decision step only (it starts then, if the
  controller accepts it); on the k - 1 steps after it the vehicle asks to speed up;
- speedup and none: repeated on every step of the interval.
A vehicle that entered the road after the last decision round asks to speed up until it decides.
With k = 1 every step is a decision round, as in the paper. Pure numpy, no SUMO.
"""

from __future__ import annotations

import numpy as np

from coopsumo.sim.physics import LEFT, NONE, RIGHT, SPEEDUP


def is_decision_step(step_count: int, interval_steps: int) -> bool:
    """True when vehicles decide on this step (steps counted from 0)."""
    return step_count % interval_steps == 0


def offered(
    feasible: np.ndarray, speed_mps: np.ndarray, action_mask: bool, restart_below_mps: float
) -> np.ndarray | None:
    """(n, 4) bool: the actions a learned vehicle may choose; None when every action is offered.

    feasible: the controller's feasible actions (physics.feasible_actions), used when action_mask;
    'none' is withdrawn from vehicles slower than restart_below_mps (m/s; 0: never), so that a
    standing vehicle cannot choose to stay standing (speed-up is always feasible).
    """
    if not action_mask and restart_below_mps <= 0:
        return None
    mask = feasible.copy() if action_mask else np.ones(feasible.shape, bool)
    if restart_below_mps > 0:
        mask[:, NONE] &= speed_mps >= restart_below_mps
    return mask


def with_change_margin(q_values: np.ndarray, change_margin: float) -> np.ndarray:
    """Q-values (n, 4) as the choice sees them: left and right lowered by change_margin (Q units), so a lane
    change is chosen only when it beats the best of speed-up and none by more than the margin (0: unchanged)."""
    if change_margin == 0:
        return q_values
    out = np.array(q_values, dtype=np.float64)
    out[:, [LEFT, RIGHT]] -= change_margin
    return out


def no_change_in_queue(mask: np.ndarray, speed_mps: np.ndarray, below_mps: float) -> np.ndarray:
    """(n, 4) mask without left and right for vehicles moving below below_mps (m/s; 0: unchanged): a lane change
    takes 4 s across both lanes, so one made where the traffic stands holds up two queues."""
    if below_mps <= 0:
        return mask
    out = mask.copy()
    slow = speed_mps < below_mps
    out[slow, LEFT] = False
    out[slow, RIGHT] = False
    return out


def no_return(mask: np.ndarray, since_change_s: np.ndarray, last_change: np.ndarray, window_s: float) -> np.ndarray:
    """(n, 4) mask without the change back into the lane a vehicle's last lane change left (last_change LEFT or
    RIGHT; anything else: none), for window_s seconds after that change was last under way (since_change_s; inf when
    never): no left-right dithering, while a second change onward stays offered."""
    if window_s <= 0:
        return mask
    out = mask.copy()
    recent = since_change_s < window_s
    out[recent & (last_change == LEFT), RIGHT] = False
    out[recent & (last_change == RIGHT), LEFT] = False
    return out


def follow_up(actions: np.ndarray) -> np.ndarray:
    """The action held on the steps after a decision: speedup after a lane change, else the same."""
    actions = np.asarray(actions, np.int64)
    return np.where((actions == LEFT) | (actions == RIGHT), SPEEDUP, actions)


class ActionHold:
    """Per-vehicle held actions between decision rounds, indexed by vehicle number."""

    def __init__(self, interval_steps: int) -> None:
        if interval_steps <= 0:
            raise ValueError(f"decision interval must be positive, got {interval_steps}")
        self.interval_steps = interval_steps
        self._held = np.full(1024, SPEEDUP, np.int64)

    def is_decision_step(self, step_count: int) -> bool:
        return is_decision_step(step_count, self.interval_steps)

    def actions(self, nums: np.ndarray, decided: np.ndarray | None) -> np.ndarray:
        """This step's actions of vehicles `nums`: `decided` on a decision step, else the held ones."""
        if len(nums) and int(nums.max()) >= len(self._held):
            extra = max(int(nums.max()) + 1, 2 * len(self._held)) - len(self._held)
            self._held = np.concatenate([self._held, np.full(extra, SPEEDUP, np.int64)])
        if decided is None:
            return self._held[nums].copy()
        decided = np.asarray(decided, np.int64)
        self._held[nums] = follow_up(decided)
        return decided
