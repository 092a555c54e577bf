"""The replay memory of the shared DQN: a ring buffer of transitions and the minibatches drawn from it.

Pure numpy + torch. One transition: grids (3, 3, 20) = 3 frames x 3 lanes x 20 cells of 1 m, 0/1 occupancy,
stored as uint8; features (F,) float32 (speed errors in m/s, then any v2x features); the action; the reward;
the same for the next state; done; the actions feasible in the next state; for a conditioned learner also the
alpha and the lane changes started (so that a minibatch can be relabelled with other alphas).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from coopsumo.config import PAPER_ALPHAS

GRID_SHAPE = (3, 3, 20)
"""(frames, lanes, cells) of one observation's occupancy grids"""
N_ACTIONS = 4
"""0 = left, 1 = right, 2 = speedup, 3 = none"""


def relabelled(rewards: np.ndarray, alphas: np.ndarray, lane_changes: np.ndarray, new_alphas: np.ndarray) -> np.ndarray:
    """Rewards of stored transitions as they would have been at new_alphas: the reward is linear in alpha
    (r = r_speed + r_flow - alpha x lane changes started), so r' = r + (alpha - alpha') x lane changes."""
    return (rewards + (alphas - new_alphas) * lane_changes).astype(np.float32)



@dataclass(frozen=True)
class ReplayBatch:
    """A minibatch of B transitions as float32 tensors (actions int64)."""

    grids: torch.Tensor
    """(B, 3, 3, 20) occupancy, 0/1"""
    features: torch.Tensor
    """(B, F) speed errors (m/s), then any v2x features"""
    actions: torch.Tensor
    """(B,) action indices, int64"""
    rewards: torch.Tensor
    """(B,) rewards"""
    next_grids: torch.Tensor
    """(B, 3, 3, 20) occupancy of the next state"""
    next_features: torch.Tensor
    """(B, F) features of the next state"""
    dones: torch.Tensor
    """(B,) 1.0 where the episode ended at this transition (no bootstrap), else 0.0"""
    next_mask: torch.Tensor
    """(B, 4) bool: actions feasible in the next state (all True when masking is off)"""
    alphas: torch.Tensor | None = None
    """(B,) the alpha each transition is learned at (conditioned replay only; reward already at that alpha)"""


def buffer_fields(width: int, conditioned: bool = False) -> dict[str, tuple[tuple[int, ...], Any]]:
    """name -> (shape of one transition, storage dtype) of a replay memory whose feature vectors have `width`;
    a conditioned one also stores each transition's alpha and its lane changes started (for relabelling)."""
    fields: dict[str, tuple[tuple[int, ...], Any]] = {
        "grids": (GRID_SHAPE, np.uint8),
        "features": ((width,), np.float32),
        "actions": ((), np.int64),
        "rewards": ((), np.float32),
        "next_grids": (GRID_SHAPE, np.uint8),
        "next_features": ((width,), np.float32),
        "dones": ((), np.float32),
        "next_mask": ((N_ACTIONS,), np.bool_),
    }
    if conditioned:
        fields.update(alphas=((), np.float32), lane_changes=((), np.float32))
    return fields


_OLD_NAMES = {"speed_err": "features", "next_speed_err": "next_features"}
"""replay field names in checkpoints written before the v2x state -> their names now"""


class ReplayBuffer:
    """Fixed-capacity ring buffer of transitions; the oldest are overwritten first.

    width: length of each state's feature vector (observation.n_features; 3 for the paper's state);
    conditioned: each transition also carries its alpha and its lane changes started (add_batch's alphas and
    lane_changes), and sample may relabel a share of a minibatch with other alphas.
    """

    def __init__(self, capacity: int, width: int = GRID_SHAPE[0], conditioned: bool = False) -> None:
        if capacity <= 0:
            raise ValueError(f"replay capacity must be positive, got {capacity}")
        self.capacity = capacity
        self.conditioned = conditioned
        self.fields = buffer_fields(width, conditioned)
        self._pos = 0  # index the next transition is written to
        self._size = 0
        self._data = {name: np.zeros((capacity, *shape), dtype=dtype) for name, (shape, dtype) in self.fields.items()}

    def __len__(self) -> int:
        return self._size

    def add_batch(
        self,
        grids: np.ndarray,
        features: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_grids: np.ndarray,
        next_features: np.ndarray,
        dones: np.ndarray,
        next_mask: np.ndarray | None = None,
        alphas: np.ndarray | None = None,
        lane_changes: np.ndarray | None = None,
    ) -> None:
        """Store N transitions (arrays with leading dimension N); only the newest capacity are kept.

        next_mask (N, 4) bool: feasible actions of the next state; None means all feasible.
        alphas, lane_changes (N,): a conditioned buffer's alpha and lane changes started of each transition.
        """
        if next_mask is None:
            next_mask = np.ones((len(actions), N_ACTIONS), dtype=bool)
        if self.conditioned != (alphas is not None and lane_changes is not None):
            raise ValueError("a conditioned replay stores alphas and lane changes, another neither")
        arrays = {
            "grids": grids,
            "features": features,
            "actions": actions,
            "rewards": rewards,
            "next_grids": next_grids,
            "next_features": next_features,
            "dones": dones,
            "next_mask": next_mask,
        }
        if alphas is not None and lane_changes is not None:
            arrays.update(alphas=alphas, lane_changes=lane_changes)
        n = len(actions)
        for name, arr in arrays.items():
            shape = (n, *self.fields[name][0])
            if np.shape(arr) != shape:
                raise ValueError(f"replay {name} must have shape {shape}, got {np.shape(arr)}")
        if n == 0:
            return
        skip = max(0, n - self.capacity)  # transitions overwritten within this same batch
        idx = (self._pos + skip + np.arange(n - skip)) % self.capacity
        for name, arr in arrays.items():
            self._data[name][idx] = np.asarray(arr)[skip:]
        self._pos = (self._pos + n) % self.capacity
        self._size = min(self._size + n, self.capacity)

    def sample(
        self, batch_size: int, rng: np.random.Generator, relabel: float = 0.0,
        relabel_to: tuple[float, ...] = PAPER_ALPHAS,
    ) -> ReplayBatch:  # fmt: skip
        """batch_size transitions drawn uniformly with replacement.

        relabel (conditioned buffer): each transition is, with this probability, learned at an alpha drawn from
        relabel_to (conditioning.conditioned_alphas) instead of its own, its reward recomputed (relabelled).
        """
        if self._size == 0:
            raise ValueError("cannot sample from an empty replay buffer")
        idx = rng.integers(0, self._size, size=batch_size)
        d = self._data
        rewards = d["rewards"][idx]
        alphas = None
        if self.conditioned:
            alphas = d["alphas"][idx]
            if relabel > 0:
                new = np.where(rng.random(batch_size) < relabel,
                               rng.choice(np.array(relabel_to, np.float32), size=batch_size), alphas)  # fmt: skip
                rewards = relabelled(rewards, alphas, d["lane_changes"][idx], new)
                alphas = new.astype(np.float32)
        return ReplayBatch(
            grids=torch.from_numpy(d["grids"][idx].astype(np.float32)),
            features=torch.from_numpy(d["features"][idx]),
            actions=torch.from_numpy(d["actions"][idx]),
            rewards=torch.from_numpy(rewards),
            next_grids=torch.from_numpy(d["next_grids"][idx].astype(np.float32)),
            next_features=torch.from_numpy(d["next_features"][idx]),
            dones=torch.from_numpy(d["dones"][idx]),
            next_mask=torch.from_numpy(d["next_mask"][idx]),
            alphas=None if alphas is None else torch.from_numpy(alphas),
        )

    def state_dict(self) -> dict[str, Any]:
        """A snapshot (copies) of the buffer as plain types and tensors."""
        return {
            "capacity": self.capacity,
            "pos": self._pos,
            "size": self._size,
            "data": {name: torch.from_numpy(arr.copy()) for name, arr in self._data.items()},
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a snapshot from state_dict(); the capacity must match."""
        if state["capacity"] != self.capacity:
            raise ValueError(f"replay capacity mismatch: buffer has {self.capacity}, state has {state['capacity']}")
        data = {_OLD_NAMES.get(name, name): arr for name, arr in state["data"].items()}
        if set(data) != set(self.fields):
            raise ValueError(f"replay fields {sorted(data)} differ from this buffer's {sorted(self.fields)}")
        for name, (shape, dtype) in self.fields.items():
            arr = data[name].numpy().astype(dtype, copy=True)
            if arr.shape[1:] != shape:
                raise ValueError(f"replay {name} has shape {tuple(arr.shape[1:])} per transition, expected {shape}")
            self._data[name] = arr
        self._pos = int(state["pos"])
        self._size = int(state["size"])
