"""A model file: the network's weights with its shapes and the configuration that made it (`model.pt`), written
whole and read back checked, so that a truncated, foreign or tampered file is one clear error, never a traceback."""

from __future__ import annotations

import hashlib
import os
import re
import warnings
from pathlib import Path
from typing import Any

import torch

from coopsumo.agents.dqn import QNetwork
from coopsumo.agents.file_checks import model_problem
from coopsumo.agents.replay import GRID_SHAPE, N_ACTIONS
from coopsumo.dqn_config import OBSERVATIONS
from coopsumo.errors import UsageError
from coopsumo.files import write_atomic


class ModelFileError(ValueError):
    """A model file is missing, unreadable, not a coopsumo model, or has the wrong shape."""


_MODEL_KEYS = ("state_dict", "grid_shape", "n_actions", "speed_scale_mps", "meta")


def load_error_text(exc: BaseException) -> str:
    """The first line of an exception's message, or its type name if empty. torch's "Error(s) in loading state_dict
    for QNetwork:" lists what did not fit on the lines below: the first of them is added, cut after its first key
    ('Missing key(s) in state_dict: "value.weight" and more'), so the line names a key."""
    lines = [line.strip() for line in str(exc).strip().splitlines() if line.strip()]
    if not lines:
        return type(exc).__name__
    if not (lines[0].endswith(":") and len(lines) > 1):
        return lines[0]
    detail = lines[1]
    if (keys := re.match(r'((?:Missing|Unexpected) key\(s\) in state_dict: "[^"]*")(,)?', detail)) is not None:
        detail = keys.group(1) + (" and more" if keys.group(2) else "")
    return f"{lines[0]} {detail}"


MAX_MODEL_BYTES = 512 * 2**20
"""a model file larger than this is refused before it is read (a coopsumo model is a few MB)"""


def weights_digest(state_dict: dict[str, torch.Tensor]) -> str:
    """sha256 of a network's weights: every tensor's name, shape, dtype and bytes, in name order."""
    h = hashlib.sha256()
    for name in sorted(state_dict):
        t = state_dict[name].detach().cpu().contiguous()
        h.update(f"{name}:{tuple(t.shape)}:{t.dtype}".encode())
        h.update(t.numpy().tobytes())
    return h.hexdigest()


def save_model(path: str | os.PathLike[str], net: QNetwork, meta: dict[str, Any]) -> None:
    """Write net and meta (plain types only) to path atomically (temp file in the same folder, then rename), with
    the digest of its weights (weights_digest: load_model refuses weights changed after they were written); weights
    outside a model's limits are refused in one line, nothing written (issue 82, probe 13, F3: train wrote a model of
    weights 8e11, marked its folder finished and exited 0, and every reader then refused it)."""
    path = Path(path)
    weights = {k: v.detach().clone() for k, v in net.state_dict().items()}
    payload = {
        "state_dict": weights,
        "weights_sha256": weights_digest(weights),
        "grid_shape": list(GRID_SHAPE),
        "n_actions": N_ACTIONS,
        "speed_scale_mps": net.speed_scale_mps,
        "dueling": net.dueling,
        "observation": net.observation,
        "alpha_conditioned": net.conditioned,
        "meta": meta,
    }
    if problem := model_problem(payload):  # what every reader checks (load_model): never a file no command reads
        raise UsageError(f"{path} is not written: its weights are no model's ({problem}); the training diverged or was "
                         "resumed from an edited checkpoint: train again without --resume")  # fmt: skip
    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            torch.save(payload, f)
            f.flush()
            os.fsync(f.fileno())

    write_atomic(path, write)  # a worker's exit waits for it (files.exit_between_writes): no temporary file left


def load_model(path: str | os.PathLike[str]) -> tuple[QNetwork, dict[str, Any]]:
    """Read a model written by save_model; raise ModelFileError naming the problem."""
    path = Path(path)
    if not path.is_file():
        if not path.exists():
            raise ModelFileError(f"model file not found: {path}")
        kinds = ((path.is_dir, "a folder"), (path.is_fifo, "a FIFO (named pipe)"), (path.is_socket, "a socket"),
                 (path.is_char_device, "a device"), (path.is_block_device, "a device"))  # fmt: skip
        kind = next((name for test, name in kinds if test()), "not a file")
        raise ModelFileError(f"model file {path} is not a regular file but {kind}; give a model.pt a training wrote")
    if (size := path.stat().st_size) > MAX_MODEL_BYTES:
        raise ModelFileError(f"model file {path} is {size / 2**20:,.0f} MB; a coopsumo model is a few MB "
                             "(not a model?)")  # fmt: skip
    try:
        with warnings.catch_warnings():  # torch warns about a pickle of another protocol before it refuses it
            warnings.simplefilter("ignore")
            payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a corrupt or unsafe file
        text = load_error_text(exc)
        if "weights_only" in text:  # torch's advice to load with weights_only=False is unsafe and wrong here
            text = "not a file of tensors torch can read safely"
        raise ModelFileError(f"cannot read model file {path}: {text}") from exc
    if not isinstance(payload, dict) or any(k not in payload for k in _MODEL_KEYS):
        raise ModelFileError(f"not a coopsumo model file: {path}")
    if problem := model_problem(payload):  # types and ranges (file_checks)
        raise ModelFileError(f"model {path} {problem}")
    grid_shape = payload["grid_shape"]
    if not isinstance(grid_shape, (list, tuple)) or tuple(grid_shape) != GRID_SHAPE:
        raise ModelFileError(f"model {path} has grid shape {grid_shape}, expected {list(GRID_SHAPE)}")
    if payload["n_actions"] != N_ACTIONS:
        raise ModelFileError(f"model {path} has {payload['n_actions']} actions, expected {N_ACTIONS}")
    observation = payload.get("observation", "paper")  # written before the v2x state: the paper's
    if observation not in OBSERVATIONS:
        raise ModelFileError(f"model {path} reads observation {observation!r}, which this coopsumo does not know "
                             f"(it knows {', '.join(OBSERVATIONS)}; written by a newer coopsumo?)")  # fmt: skip
    conditioned = payload.get("alpha_conditioned", False)  # written before conditioned networks: not conditioned
    if not isinstance(conditioned, bool):
        raise ModelFileError(f"model {path} has alpha_conditioned = {conditioned!r}, not true or false")
    try:
        net = QNetwork(float(payload["speed_scale_mps"]), bool(payload.get("dueling", False)), observation,
                       conditioned)  # fmt: skip
        net.load_state_dict(payload["state_dict"])
    except (RuntimeError, ValueError, TypeError) as exc:
        raise ModelFileError(f"model {path} has incompatible weights: {load_error_text(exc)}") from exc
    if not isinstance(payload["meta"], dict):
        raise ModelFileError(f"model {path} has meta of type {type(payload['meta']).__name__}, expected a dict")
    stored = payload.get("weights_sha256")  # written since digests: the weights must be the ones saved
    if stored is not None and stored != weights_digest(payload["state_dict"]):
        raise ModelFileError(f"model {path} has weights that do not match the digest saved with them (changed after "
                             "the model was written?); train it again")  # fmt: skip
    return net, payload["meta"]
