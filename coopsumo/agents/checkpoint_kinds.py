"""The kind and shape of every tensor a training checkpoint holds, checked before any of its values is (issue 82,
probe 16, T1).

A training saves each tensor of a fixed dtype (train.Trainer.save_checkpoint, dqn.Learner.state_dict,
replay.buffer_fields, torch's Adam): weights, Adam's moments and step, replay features, rewards, dones and alphas as
float32; replay actions as int64, occupancy grids as uint8, next masks as bool; the recorded actions as int8 and their
counts as int64; torch's generator state as uint8. The limits of record_schemas.CHECKPOINT_TENSORS and the bounds of
checkpoint_bounds take the smallest and largest entry of a tensor, or its one number: a complex tensor has neither (a
traceback), a bool one no magnitude, Adam's step of two entries no one number. Another dtype of the same sort is
refused too: the resume would cast it without a word (float64 features rounded to float32, integer moments whole).
A tensor where a training saves none (a step, a window entry or a learning rate as a tensor) is refused by name.
Shapes that depend on the network or the configuration (weights, moments, replay rows) are judged where they are
loaded or by file_checks; here only the number of dimensions and the fixed sizes.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping
from typing import Any

import torch

from coopsumo.agents.replay import GRID_SHAPE


@dataclasses.dataclass(frozen=True)
class Kind:
    """A checkpoint tensor's dtype and shape (None: any, judged where it is loaded; a text entry: any size, named so
    in the refusal) and its name in words ({0}, {1}: the keys the pattern's `*` stand for)."""

    dtype: torch.dtype
    shape: tuple[int | str, ...] | None
    what: str


_ROWS = ("rows",)
_REPLAY = {
    **{name: Kind(torch.uint8, ("rows", *GRID_SHAPE), f"replay {name}") for name in ("grids", "next_grids")},
    **{name: Kind(torch.float32, ("rows", "width"), f"replay {name}")
       for name in ("features", "next_features", "speed_err", "next_speed_err")},  # the last two: replay._OLD_NAMES
    **{name: Kind(torch.float32, _ROWS, f"replay {name}") for name in ("rewards", "dones", "alphas", "lane_changes")},
    "actions": Kind(torch.int64, _ROWS, "replay actions"),
    "next_mask": Kind(torch.bool, ("rows", 4), "replay next_mask"),
}  # fmt: skip
KINDS: dict[tuple[str, ...], Kind] = {
    **{("learner", net, "*"): Kind(torch.float32, None, f"{net} weights {{0!r}}")
       for net in ("online", "target", "average")},
    **{("learner", "buffer", "data", name): kind for name, kind in _REPLAY.items()},
    ("learner", "optimizer", "state", "*", "step"): Kind(torch.float32, (), "Adam's step for parameter {0}"),
    **{("learner", "optimizer", "state", "*", name): Kind(torch.float32, None, f"Adam's {name} for parameter {{0}}")
       for name in ("exp_avg", "exp_avg_sq")},
    ("learner", "optimizer", "state", "*", "momentum_buffer"): Kind(torch.float32, None, "SGD's momentum_buffer for "
                                                                                         "parameter {0}"),
    ("learner", "torch_rng"): Kind(torch.uint8, ("bytes",), "torch random-generator state"),
    ("action_counts",): Kind(torch.int64, ("steps",), "recorded action counts"),
    ("actions",): Kind(torch.int8, ("actions",), "recorded actions"),
}  # fmt: skip
"""pattern of keys (`*`: any key) -> the tensor a training saves there"""


def kind_problem(state: Any) -> str | None:
    """Why a tensor in the checkpoint `state` (its tensors dense and in memory: file_checks.odd_tensor) is not of the
    dtype and shape a training saves at its place, or where a training saves none, or None; values that are not
    tensors are the structural checks' (file_checks.checkpoint_problem) to name."""
    for keys, tensor in _tensors(state, ()):
        found = next(((kind, stars) for pattern, kind in KINDS.items() if (stars := _match(pattern, keys)) is not None),
                     None)  # fmt: skip
        if found is None:
            return f"holds a tensor at {'.'.join(str(k) for k in keys)}, where a training saves none"
        kind, stars = found
        what = kind.what.format(*stars)
        if tensor.dtype != kind.dtype:
            want = _sort(kind.dtype)
            if _sort(tensor.dtype) != want:
                return f"has {what} a {tensor.dtype} tensor, not a tensor of {want}"
            return f"has {what} a {tensor.dtype} tensor, not the {kind.dtype} one a training saves"
        if kind.shape is not None and not _fits(tuple(tensor.shape), kind.shape):
            return f"has {what} of shape {tuple(tensor.shape)}, not {_shape_words(kind.shape)}"
    return None


def _tensors(x: Any, keys: tuple[Any, ...]) -> Iterator[tuple[tuple[Any, ...], torch.Tensor]]:
    """(keys, tensor) of every tensor in the nested mappings, lists and tuples `x`."""
    if isinstance(x, torch.Tensor):
        yield keys, x
        return
    items = x.items() if isinstance(x, Mapping) else enumerate(x) if isinstance(x, list | tuple) else ()
    for key, value in items:
        yield from _tensors(value, (*keys, key))


def _match(pattern: tuple[str, ...], keys: tuple[Any, ...]) -> list[Any] | None:
    """The keys the pattern's `*` stand for when `keys` is one of its places, else None."""
    if len(pattern) != len(keys) or any(p not in ("*", str(k)) for p, k in zip(pattern, keys, strict=True)):
        return None
    return [k for p, k in zip(pattern, keys, strict=True) if p == "*"]


def _sort(dtype: torch.dtype) -> str:
    if dtype.is_complex:
        return "complex numbers"
    if dtype.is_floating_point:
        return "floats"
    return "true/false values" if dtype == torch.bool else "integers"


def _fits(shape: tuple[int, ...], want: tuple[int | str, ...]) -> bool:
    return len(shape) == len(want) and all(isinstance(w, str) or w == n for n, w in zip(shape, want, strict=True))


def _shape_words(want: tuple[int | str, ...]) -> str:
    if not want:
        return "one number"
    return f"of shape ({', '.join(str(w) for w in want)}{',' if len(want) == 1 else ''})"
