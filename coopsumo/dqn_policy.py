"""A trained DQN as a policy: one batched forward pass per step for all vehicles."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from coopsumo.dqn import ModelFileError, QNetwork, load_model
from coopsumo.observation import Observation
from coopsumo.runio import UsageError


class DQNPolicy:
    """Greedy actions of a Q-network."""

    def __init__(self, net: QNetwork, name: str = "dqn"):
        self.net = net.eval()
        self.name = name

    @classmethod
    def from_file(cls, path: str) -> DQNPolicy:
        """Load model.pt; a missing, corrupt or mismatched file is a usage error."""
        try:
            net, _meta = load_model(path)
        except ModelFileError as err:
            raise UsageError(str(err)) from None
        return cls(net, name=f"dqn:{Path(path).parent.name or path}")

    def act(self, obs: Observation) -> np.ndarray:
        if len(obs) == 0:
            return np.zeros(0, dtype=np.int64)
        with torch.no_grad():
            q = self.net(torch.from_numpy(obs.grids).float(), torch.from_numpy(obs.speed_err))
        return q.argmax(dim=1).numpy().astype(np.int64)
