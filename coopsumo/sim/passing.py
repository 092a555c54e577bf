"""Passing chances: how often a vehicle is held back by a slower leader while a faster side lane is open to it, and
whether its policy takes that lane. A measure of every run (summary.json: held_share, passing_open_share,
passing_taken_share), read once a second; it changes nothing in the simulation. Pure numpy, no SUMO.
"""

from __future__ import annotations

import numpy as np

from coopsumo.sim.physics import LEFT, RIGHT, Neighbours

PASSING_EVERY_S = 1.0
"""the chances are sampled once every this many seconds of simulated time"""
HELD_BELOW_MPS = 2.0
"""a vehicle is held back when it drives more than this below its expected speed (m/s) ..."""
HELD_GAP_M = 60.0
"""... with a leader in its own lane within this gap (m, bumper to bumper)"""
FASTER_MPS = 1.0
"""a side lane is open when the controller would accept a change into it now and its leader is at least this much
faster than the own lane's leader (m/s), or it has none"""
SIDE_ACTIONS = ((0, LEFT), (2, RIGHT))
"""(column of physics.side_lanes' left, own, right order, action) of the two side lanes"""


def passing_chances(
    speed_mps: np.ndarray, v_exp_mps: np.ndarray, around: Neighbours, feasible: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(held, open), (n,) bool each: held back by a slower leader (HELD_BELOW_MPS, HELD_GAP_M), and of those, with
    a side lane open to pass (FASTER_MPS; feasible: physics.feasible_actions, around: columns left, own, right)."""
    held = (speed_mps < v_exp_mps - HELD_BELOW_MPS) & (around.lead_gap[:, 1] < HELD_GAP_M)
    open_side = np.zeros(len(speed_mps), bool)
    for col, action in SIDE_ACTIONS:
        faster = (around.lead_speed[:, col] >= around.lead_speed[:, 1] + FASTER_MPS) | np.isinf(around.lead_gap[:, col])
        open_side |= around.exists[:, col] & feasible[:, action] & faster
    return held, held & open_side


class PassingCount:
    """Counts of passing chances over a run, sampled once every `every` steps: vehicle samples, held samples, open
    samples, and open samples whose vehicle started a lane change before the next sample."""

    def __init__(self, every: int) -> None:
        self.every = every
        self.samples = self.held = self.open = self.taken = 0
        self._waiting = np.zeros(0, np.int64)  # vehicles with an open side lane at the last sample, not yet changed

    def due(self, step: int) -> bool:
        """Whether `step` is a sample step (a multiple of `every`)."""
        return step % self.every == 0

    def look(self, step: int, nums: np.ndarray, speed_mps: np.ndarray, v_exp_mps: np.ndarray, around: Neighbours,
             feasible: np.ndarray) -> None:  # fmt: skip
        """On a sample step, the observed vehicles' passing chances (passing_chances) as a new sample."""
        if self.due(step):
            self.sample(step, nums, *passing_chances(speed_mps, v_exp_mps, around, feasible))

    def sample(self, step: int, nums: np.ndarray, held: np.ndarray, open_: np.ndarray) -> None:
        """A new sample on the steps that are multiples of `every` (others ignored); nums: the observed vehicles."""
        if not self.due(step):
            return
        self.samples += len(nums)
        self.held += int(held.sum())
        self.open += int(open_.sum())
        self._waiting = nums[open_]

    def changed(self, nums: np.ndarray) -> None:
        """Vehicles that started a lane change this step: those waiting since the last sample count as taken."""
        if len(self._waiting) and len(nums):
            took = np.isin(self._waiting, nums)
            self.taken += int(took.sum())
            self._waiting = self._waiting[~took]

    def summary(self) -> dict[str, float]:
        """held_share and passing_open_share of the vehicle samples, passing_taken_share of the open ones (NaN:
        none)."""
        return {"held_share": self.held / self.samples if self.samples else 0.0,
                "passing_open_share": self.open / self.samples if self.samples else 0.0,
                "passing_taken_share": self.taken / self.open if self.open else float("nan")}  # fmt: skip
