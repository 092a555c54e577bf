"""A trained DQN as a policy: one batched forward pass per step for the vehicles whose input changed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from coopsumo.dqn import GRID_SHAPE, ModelFileError, QNetwork, load_model
from coopsumo.observation import Observation
from coopsumo.runio import UsageError


class DQNPolicy:
    """Greedy actions of a Q-network (its weights must not change while the policy is in use).

    A vehicle whose grids and speed errors are exactly those of its previous step (typically one
    standing in a queue) gets its previous action again without a forward pass: the network is
    deterministic, so the action is the same, and a jam costs far less.
    """

    needs_grids = True

    def __init__(self, net: QNetwork, name: str = "dqn"):
        self.net = net.eval()
        self.name = name
        self._grids = np.zeros((0, *GRID_SHAPE), np.uint8)  # last input and action, by vehicle number
        self._speed_err = np.zeros((0, GRID_SHAPE[0]), np.float32)
        self._action = np.full(0, -1, np.int64)  # -1: no previous decision

    @classmethod
    def from_file(cls, path: str) -> DQNPolicy:
        """Load model.pt; a missing, corrupt or mismatched file is a usage error."""
        try:
            net, _meta = load_model(path)
        except ModelFileError as err:
            raise UsageError(str(err)) from None
        return cls(net, name=f"dqn:{Path(path).parent.name or path}")

    def _grow(self, needed: int) -> None:
        cap = len(self._action)
        if needed <= cap:
            return
        extra = max(needed, 2 * cap, 1024) - cap
        self._grids = np.concatenate([self._grids, np.zeros((extra, *GRID_SHAPE), np.uint8)])
        self._speed_err = np.concatenate([self._speed_err, np.zeros((extra, GRID_SHAPE[0]), np.float32)])
        self._action = np.concatenate([self._action, np.full(extra, -1, np.int64)])

    def act(self, obs: Observation) -> np.ndarray:
        n = len(obs)
        if n == 0:
            return np.zeros(0, dtype=np.int64)
        nums = obs.nums
        self._grow(int(nums.max()) + 1)
        same = (
            (self._action[nums] >= 0)
            & (self._grids[nums] == obs.grids).reshape(n, -1).all(axis=1)
            & (self._speed_err[nums] == obs.speed_err).all(axis=1)
        )
        actions = self._action[nums]
        fresh = ~same
        if fresh.any():
            with torch.no_grad():
                q = self.net(torch.from_numpy(obs.grids[fresh]).float(), torch.from_numpy(obs.speed_err[fresh]))
            actions[fresh] = q.argmax(dim=1).numpy()
            changed = nums[fresh]
            self._grids[changed] = obs.grids[fresh]
            self._speed_err[changed] = obs.speed_err[fresh]
            self._action[changed] = actions[fresh]
        return actions
