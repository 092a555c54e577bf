"""Occupancy-grid observations (eq. 2-3), built for all vehicles at once with array operations.

A snapshot is 3 lanes (left, own, right) x 20 cells of 1 m, from 5 m behind to 15 m ahead
of the reference line at the vehicle's front bumper. Cell k covers [front - 5 + k, front - 4 + k);
it is 1 when its centre lies inside a vehicle ([front_j - L_car, front_j)), so a 4 m vehicle
fills 4 cells, the observing vehicle included. Lanes off the road are all 1. A vehicle in a
lane change counts in both lanes. The state stacks the last 3 snapshots and speed errors.

The 'v2x' state (DQNConfig.observation) adds what a connected vehicle would be told about its
neighbourhood, now: for the left, own and right lane, whether the lane exists and the gap to and
speed of the nearest leader and follower within V2X_RANGE_M (v2x_features).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coopsumo.sim.physics import Neighbours, Occupancy, side_lanes

N_FRAMES = 3
N_SIDES = 3
N_CELLS = 20
BEHIND_M = 5.0
MAX_PER_WINDOW = 8  # vehicles of 4 m that can touch a 24 m window in one lane, plus room
V2X_RANGE_M = 200.0
"""how far a v2x vehicle is told about its neighbours (m): gaps are clipped to it, farther vehicles are absent"""
V2X_PER_SIDE = ("lane exists", "leader gap", "leader speed - own", "follower gap", "follower speed - own")
V2X_OWN = ("own speed", "expected speed", "lane change under way")
N_V2X = len(V2X_PER_SIDE) * N_SIDES + len(V2X_OWN)
"""v2x features per vehicle (beside the paper's 3 speed errors)"""


def snapshot(occ: Occupancy, lane: np.ndarray, pos: np.ndarray, n_lanes: int, car_length_m: float) -> np.ndarray:
    """(n, 3, 20) uint8 grids of every vehicle from the sorted occupancy (see module doc)."""
    lanes = side_lanes(lane)  # (n, 3)
    centres = pos[:, None] - BEHIND_M + 0.5 + np.arange(N_CELLS)[None, :]  # (n, 20)
    # candidates: occupancy entries in the same lane with front in (window start, window end + L]
    lo_key = lanes * 1.0e6 + (pos[:, None] - BEHIND_M)
    first = np.searchsorted(occ.keys, lo_key, side="right")  # (n, 3)
    cand = first[:, :, None] + np.arange(MAX_PER_WINDOW)[None, None, :]  # (n, 3, K)
    m = len(occ.keys)
    safe = np.minimum(np.maximum(cand, 0), max(m - 1, 0))
    if m == 0:
        valid = np.zeros(cand.shape, dtype=bool)
        front = np.zeros(cand.shape)
    else:
        valid = (cand < m) & (occ.lane[safe] == lanes[:, :, None])
        front = occ.pos[safe]
    # (n, 3, K, 20): cell centre inside [front - L, front)
    c = centres[:, None, None, :]
    f = front[:, :, :, None]
    inside = valid[:, :, :, None] & (c >= f - car_length_m) & (c < f)
    grid: np.ndarray = np.asarray(inside.any(axis=2))
    off_road = (lanes < 0) | (lanes >= n_lanes)
    grid[off_road] = True
    return np.asarray(grid, dtype=np.uint8)


@dataclass
class FrameHistory:
    """The last 3 snapshots and speed errors of every vehicle, indexed by vehicle number."""

    grids: np.ndarray  # (capacity, 3, 3, 20) uint8, oldest frame first
    speed_err: np.ndarray  # (capacity, 3) float32 (m/s), oldest first
    seen: np.ndarray  # (capacity,) bool

    @classmethod
    def empty(cls, capacity: int = 1024) -> FrameHistory:
        return cls(
            np.zeros((capacity, N_FRAMES, N_SIDES, N_CELLS), np.uint8),
            np.zeros((capacity, N_FRAMES), np.float32),
            np.zeros(capacity, bool),
        )

    def _grow(self, needed: int) -> None:
        cap = len(self.seen)
        if needed <= cap:
            return
        new = max(needed, 2 * cap)
        self.grids = np.concatenate([self.grids, np.zeros((new - cap, *self.grids.shape[1:]), np.uint8)])
        self.speed_err = np.concatenate([self.speed_err, np.zeros((new - cap, N_FRAMES), np.float32)])
        self.seen = np.concatenate([self.seen, np.zeros(new - cap, bool)])

    def push(self, nums: np.ndarray, grid: np.ndarray, speed_err: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Append this step's frame for vehicles `nums`; return their stacked (grids, speed errors).

        A vehicle seen for the first time gets its first frame repeated 3 times.
        """
        if len(nums):
            self._grow(int(nums.max()) + 1)
        new = ~self.seen[nums]
        self.grids[nums, :-1] = self.grids[nums, 1:]
        self.grids[nums, -1] = grid
        self.speed_err[nums, :-1] = self.speed_err[nums, 1:]
        self.speed_err[nums, -1] = speed_err
        fresh = nums[new]
        self.grids[fresh] = grid[new][:, None]
        self.speed_err[fresh] = speed_err[new][:, None]
        self.seen[nums] = True
        return self.grids[nums].copy(), self.speed_err[nums].copy()


@dataclass(frozen=True)
class Observation:
    """What every policy sees for the batch of vehicles on the road at one step."""

    nums: np.ndarray  # (n,) vehicle numbers
    grids: np.ndarray  # (n, 3, 3, 20) uint8: frames (oldest first) x sides (left, own, right) x cells
    speed_err: np.ndarray  # (n, 3) float32 v - v_exp (m/s), oldest first
    lane: np.ndarray  # (n,) SUMO lane index
    pos: np.ndarray  # (n,) front position (m)
    speed: np.ndarray  # (n,) (m/s)
    v_exp: np.ndarray  # (n,) expected speed (m/s)
    busy: np.ndarray  # (n,) bool: a lane change is under way
    around: Neighbours  # (n, 3) leaders/followers to the left, own lane, right
    n_lanes: int
    feasible: np.ndarray  # (n, 4) bool: actions the controller accepts now (physics.feasible_actions)

    def __len__(self) -> int:
        return len(self.nums)


def v2x_features(
    around: Neighbours, speed: np.ndarray, v_exp: np.ndarray, busy: np.ndarray, speed_scale_mps: float
) -> np.ndarray:
    """(n, N_V2X) float32: what a connected vehicle is told now, in the order of V2X_PER_SIDE for the left,
    own and right lane, then V2X_OWN.

    Gaps (bumper to bumper, m) are clipped to [-V2X_RANGE_M, V2X_RANGE_M] and divided by it, so 1 means
    nobody within range; a neighbour's speed enters as (its speed - own speed) / speed_scale_mps, 0 when
    there is none within range. A lane off the road has exists 0, gaps 0 and speeds 0. The own speed and
    expected speed are divided by speed_scale_mps; the last feature is 1 during a lane change.
    """
    n = len(speed)
    out = np.zeros((n, N_SIDES, len(V2X_PER_SIDE)), np.float64)
    v = np.asarray(speed, np.float64)[:, None]
    for col, gap, other in ((1, around.lead_gap, around.lead_speed), (3, around.follow_gap, around.follow_speed)):
        near = gap <= V2X_RANGE_M
        out[:, :, col] = np.clip(gap, -V2X_RANGE_M, V2X_RANGE_M) / V2X_RANGE_M
        out[:, :, col + 1] = np.where(near, (other - v) / speed_scale_mps, 0.0)
    out[:, :, 0] = around.exists
    out[~around.exists] = 0.0
    own = np.stack([np.asarray(speed) / speed_scale_mps, np.asarray(v_exp) / speed_scale_mps,
                    np.asarray(busy, np.float64)], axis=1)  # fmt: skip
    return np.concatenate([out.reshape(n, N_SIDES * len(V2X_PER_SIDE)), own], axis=1).astype(np.float32)


def network_features(obs: Observation, observation: str, speed_scale_mps: float) -> np.ndarray:
    """The network's vector input beside the grids: the 3 speed errors (m/s) for 'paper'; those then
    v2x_features for 'v2x'. (n, n_features(observation)) float32."""
    if observation == "paper":
        return obs.speed_err
    if observation == "v2x":
        v2x = v2x_features(obs.around, obs.speed, obs.v_exp, obs.busy, speed_scale_mps)
        return np.concatenate([obs.speed_err, v2x], axis=1)
    raise ValueError(f"unknown observation {observation!r}, expected 'paper' or 'v2x'")


def n_features(observation: str) -> int:
    """Width of network_features for an observation kind ('paper' or 'v2x')."""
    widths = {"paper": N_FRAMES, "v2x": N_FRAMES + N_V2X}
    if observation not in widths:
        raise ValueError(f"unknown observation {observation!r}, expected 'paper' or 'v2x'")
    return widths[observation]
