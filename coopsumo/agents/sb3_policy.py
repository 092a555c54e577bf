"""A Stable-Baselines3 model as a policy: `sb3:PATH`, a DQN saved by SB3's save() (experiments/sb3_dqn.py's
model.zip), trained on coopsumo/Highway-v0 and so reading what that environment gives one vehicle: its occupancy
grids (3 frames x 3 lanes x 20 cells) and its 3 speed errors (m/s). Every vehicle on the road decides by it, greedily
(SB3's predict(deterministic=True)), in one batched call per step.

stable_baselines3 is imported only here, and only when such a policy is asked for. The zip is checked before SB3
reads it: a zip file holding SB3's `data`, a DQN's policy (another algorithm's model: drive it through a class of
your own, docs/extending.md), the environment's observation and action spaces.
"""

from __future__ import annotations

import importlib.util
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from coopsumo.errors import UsageError
from coopsumo.files import file_sha256, loads_json
from coopsumo.policy_spec import parse_policy
from coopsumo.sim.observation import N_CELLS, N_FRAMES, N_SIDES, Observation
from coopsumo.sim.physics import ACTION_NAMES

GRID_SHAPE = [N_FRAMES, N_SIDES, N_CELLS]
"""the grids' shape SB3 saved in the model's observation space (as JSON gives it)"""


class SB3ModelError(UsageError):
    """An sb3:PATH that is not a Stable-Baselines3 DQN of coopsumo/Highway-v0 (one line, exit code 2)."""


def _data(path: str, text: str) -> dict[str, Any]:
    """The `data` entry (JSON) of SB3's zip at path."""
    if not os.path.exists(path):
        raise SB3ModelError(f"{text}: model file not found: {path}")
    if not os.path.isfile(path):
        raise SB3ModelError(f"{text}: {path} is not a file (SB3's model.zip)")
    try:
        with zipfile.ZipFile(path) as archive:
            data = loads_json(archive.read("data"))
    except (zipfile.BadZipFile, KeyError, ValueError, OSError) as err:
        raise SB3ModelError(f"{text}: {path} is not a Stable-Baselines3 model (a zip holding its data): "
                            f"{type(err).__name__}") from None  # fmt: skip
    if not isinstance(data, dict):
        raise SB3ModelError(f"{text}: {path} is not a Stable-Baselines3 model (its data is not a mapping)")
    return data


def check_model(path: str, text: str) -> None:
    """SB3ModelError unless the zip at path is an SB3 DQN with Highway-v0's spaces (read as JSON: nothing runs)."""
    data = _data(path, text)
    policy = data.get("policy_class")
    module = policy.get("__module__", "") if isinstance(policy, dict) else ""
    if not module.startswith("stable_baselines3.dqn"):
        origin = module or "an unknown module"
        raise SB3ModelError(f"{text}: {path} is not a Stable-Baselines3 DQN (its policy comes from {origin}); another "
                            "algorithm drives through a class of your own, py:MODULE:CLASS (docs/extending.md)")
    space = data.get("observation_space")
    spaces = str(space.get("spaces", "")) if isinstance(space, dict) else ""
    if "'grids'" not in spaces or "'speed_err'" not in spaces:
        raise SB3ModelError(f"{text}: {path} was not trained on coopsumo/Highway-v0: it reads {spaces or 'no Dict'}, "
                            "not the grids and speed errors of one vehicle")  # fmt: skip


def _stable_baselines3() -> Any:
    """The stable_baselines3 package, or a usage error saying how to install it."""
    if importlib.util.find_spec("stable_baselines3") is None:
        raise SB3ModelError("sb3:PATH needs stable-baselines3, which is not installed: pip install '.[sb3]'")
    import stable_baselines3

    return stable_baselines3


class SB3Policy:
    """Greedy actions of a Stable-Baselines3 DQN for every vehicle (one predict call per decision)."""

    needs_grids = True
    decision_interval = 1

    def __init__(self, model: Any, text: str, path: str) -> None:
        self.model = model
        self.name = text
        self.trained_on: dict[str, object] = {"policy": text, "policy_file": os.path.abspath(path),
                                              "model_sha256": file_sha256(Path(path))}  # fmt: skip

    @classmethod
    def from_spec(cls, text: str) -> SB3Policy:
        """The policy of 'sb3:PATH' (policy_spec): the file checked, then loaded by SB3 on the CPU."""
        path = parse_policy(text).model
        assert path is not None
        check_model(path, text)
        sb3 = _stable_baselines3()
        import torch

        torch.set_num_threads(1)  # as DQNPolicy: one small batch a step; a second thread only spins
        try:
            model = sb3.DQN.load(path, device="cpu")
        except Exception as err:  # SB3 and pickle raise many types for a file they cannot read
            raise SB3ModelError(f"{text}: Stable-Baselines3 cannot load {path}: {type(err).__name__}") from None
        for name, tensor in model.policy.state_dict().items():  # NaN weights drove every vehicle "left" (probe 18, TR1)
            if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
                raise SB3ModelError(f"{text}: {path} has non-finite values (nan or inf) in weights {name!r}")
        space, actions = model.observation_space, model.action_space
        shapes = {k: list(v.shape) for k, v in getattr(space, "spaces", {}).items()}
        if shapes != {"grids": GRID_SHAPE, "speed_err": [N_FRAMES]} or getattr(actions, "n", None) != len(ACTION_NAMES):
            raise SB3ModelError(f"{text}: {path} reads {shapes} and gives {actions}; coopsumo/Highway-v0's vehicle "
                                f"is grids {GRID_SHAPE} and speed_err [{N_FRAMES}], with {len(ACTION_NAMES)} actions")
        return cls(model, text, path)

    def act(self, obs: Observation) -> np.ndarray:
        if len(obs) == 0:
            return np.zeros(0, np.int64)
        batch = {"grids": np.asarray(obs.grids, np.uint8), "speed_err": np.asarray(obs.speed_err, np.float32)}
        actions, _ = self.model.predict(batch, deterministic=True)
        return np.asarray(actions, np.int64).reshape(len(obs))
