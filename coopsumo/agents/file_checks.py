"""What the learner reads back from disk, checked by type and range before it is used, and the repairs a resume
makes to a training folder.

model_problem checks a model file's payload (model_file.save_model's dict), checkpoint_problem a training checkpoint
(train.Trainer.save_checkpoint's dict): each says in words why the file cannot be trusted, or None. The learner
settings inside either are checked by config.DQNConfig.validate (types and the limits on its fields).
prepare_resume makes a training folder ready to continue from its checkpoint's step; ended_training reads the
summary of a training whose checkpoint holds its last step (it was interrupted during its evaluation).
"""

from __future__ import annotations

import csv
import dataclasses
import math
import numbers
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from coopsumo.agents.checkpoint_bounds import bounds_problem
from coopsumo.agents.checkpoint_kinds import kind_problem
from coopsumo.agents.training_logs import LOG_RULES as LOG_RULES
from coopsumo.agents.training_logs import log_problem
from coopsumo.dqn_config import DQNConfig
from coopsumo.field_rules import as_float, digits, shown
from coopsumo.files import read_json_object, read_text, write_atomic
from coopsumo.record_schemas import (
    CHECKPOINT_TENSORS,
    MODEL_TENSORS,
    REWARD_MAX,
    SPEED_MAX_MPS,
    tensor_problem,
)

_LIMITS = {f.name: f.metadata.get("limits") or (-math.inf, math.inf) for f in dataclasses.fields(DQNConfig)}
"""each learner setting's (low, high, ...) limits"""
SPEED_SCALE_MAX_MPS = float(_LIMITS["speed_scale_mps"][1])
"""the largest speed scale a model file takes: the limit of the learner setting it comes from"""
N_ACTIONS = 4
"""actions a recorded action may take: 0 left, 1 right, 2 speedup, 3 none (dqn.N_ACTIONS)"""
LEARNER_KEYS = ("online", "target", "optimizer", "buffer", "numpy_rng", "torch_rng", "env_steps", "decisions",
                "updates")  # fmt: skip
"""what a checkpoint's learner state holds (dqn.Learner.state_dict)"""
WINDOW_KEYS = ("loss", "r_speed", "r_lane_change", "r_flow", "samples", "speed_sum", "vehicle_steps", "lane_changes",
               "rejected")  # fmt: skip
"""what a checkpoint's log window holds (tb_log.Window's fields)"""


def _is_count(x: Any) -> bool:
    """A non-negative integer (not a bool)."""
    return isinstance(x, numbers.Integral) and not isinstance(x, bool) and int(x) >= 0


def odd_tensor(x: Any, where: str = "") -> str | None:
    """Where the nested mappings and lists `x` hold a tensor that is not a plain one (dense, in this machine's
    memory): a sparse or meta tensor passes torch's safe loader but no check can read its values (probe 6, H1)."""
    if isinstance(x, torch.Tensor):
        plain = x.layout == torch.strided and x.device.type == "cpu"
        return None if plain else f"{where or 'a tensor'} ({x.layout}, {x.device.type})"
    items = x.items() if isinstance(x, Mapping) else enumerate(x) if isinstance(x, list | tuple) else ()
    return next((found for key, value in items if (found := odd_tensor(value, f"{where}.{key}".lstrip(".")))), None)


def _weights_problem(weights: Any, what: str) -> str | None:
    """Why a state dict of weights is not one (a mapping of names to finite float tensors), or None."""
    if not isinstance(weights, Mapping) or not weights:
        return f"has {what} of type {type(weights).__name__}, not a mapping of tensors"
    for name, tensor in weights.items():
        if not isinstance(tensor, torch.Tensor) or not tensor.is_floating_point():
            kind = f"a {tensor.dtype} tensor" if isinstance(tensor, torch.Tensor) else type(tensor).__name__
            return f"has {what} {name!r} {kind}, not a tensor of floats"
        if not bool(torch.isfinite(tensor).all()):
            return f"has non-finite values (nan or inf) in {what} {name!r}"
    return None


def model_problem(payload: Mapping[str, Any]) -> str | None:
    """Why a model file's payload (keys checked by the caller) cannot be used, or None: grid shape a list of
    positive integers, action count an integer, speed scale a finite positive number within its setting's limits,
    dueling a bool, weights finite tensors, meta a mapping."""
    if (where := odd_tensor(payload)) is not None:
        return f"holds a tensor that is not a dense one in memory: {where}"
    shape = payload["grid_shape"]
    if not isinstance(shape, list | tuple) or not all(_is_count(n) and n > 0 for n in shape):
        return f"has grid shape {shape!r}, not a list of positive integers"
    if not _is_count(payload["n_actions"]):
        return f"has action count {payload['n_actions']!r}, not an integer"
    scale = payload["speed_scale_mps"]
    number = isinstance(scale, numbers.Real) and not isinstance(scale, bool)
    if not (number and math.isfinite(scale) and 0 < float(scale) <= SPEED_SCALE_MAX_MPS):
        return f"has speed scale {scale!r}, not a finite number > 0 and <= {SPEED_SCALE_MAX_MPS:g} (m/s)"
    if not isinstance(payload.get("dueling", False), bool):
        return f"has dueling = {payload['dueling']!r}, not true or false"
    if not isinstance(payload["meta"], Mapping):
        return f"has meta of type {type(payload['meta']).__name__}, expected a dict"
    return (_weights_problem(payload["state_dict"], "weights")
            or tensor_problem(payload, MODEL_TENSORS, deciding_entries))


def deciding_entries(x: Any) -> tuple[float, ...] | None:
    """The entries of a tensor that decide whether it keeps its field's rule (record_schemas.tensor_problem): its
    smallest and largest (booleans as 0 and 1) and its first that is not whole, if any (an Integer's: a replay done of
    0.5 lies between 0 and 1); None for an empty one or not a tensor."""
    if not isinstance(x, torch.Tensor) or not x.numel():
        return None
    x = x.to(torch.float64) if x.dtype == torch.bool else x.flatten()
    ends = (float(x.min()), float(x.max()))
    fractions = x[x != x.round()] if x.is_floating_point() else x[:0]
    return (*ends, float(fractions[0])) if len(fractions) else ends


def _int_tensor(x: Any) -> bool:
    return isinstance(x, torch.Tensor) and x.dim() == 1 and not x.is_floating_point() and x.dtype != torch.bool


def checkpoint_problem(state: Mapping[str, Any]) -> str | None:
    """Why a training checkpoint (its keys checked by the caller) cannot be resumed, or None: its configuration
    a mapping with sim and dqn mappings; step a count; one recorded action count per step, the actions 0-3 and
    as many as counted; the log window a mapping of numbers; the learner's state complete, counts as counts,
    weights finite."""
    if (where := odd_tensor(state)) is not None:
        return f"holds a tensor that is not a dense one in memory: {where}"
    if (problem := kind_problem(state)) is not None:  # every tensor's dtype and shape before any value (probe 16, T1)
        return problem
    config = state["config"]
    if not isinstance(config, Mapping) or not all(isinstance(config.get(k), Mapping) for k in ("sim", "dqn")):
        return "has no training configuration (sim and dqn settings)"
    step = state["step"]
    if not _is_count(step):
        return f"has step {step!r}, not an integer >= 0"
    counts, actions = state["action_counts"], state["actions"]
    if not (_int_tensor(counts) and _int_tensor(actions)):
        return "has recorded actions that are not integer tensors"
    if len(counts) != step:
        return f"records actions for {len(counts)} steps, not its {step}"
    if bool((counts < 0).any()):
        return f"records a negative number of actions at step {int(torch.nonzero(counts < 0)[0])}"
    in_range = not len(actions) or 0 <= int(actions.min()) <= int(actions.max()) < N_ACTIONS
    if len(actions) != int(counts.sum()) or not in_range:
        return "has recorded actions that do not match their counts or lie outside 0-3"
    window = state["window"]
    if (problem := _window_entries_problem(window)) is not None:
        return problem
    if set(window) != set(WINDOW_KEYS):
        return f"has a log window with the entries {sorted(window)}, not {sorted(WINDOW_KEYS)}"
    learner = state["learner"]
    if not isinstance(learner, Mapping):
        return f"has learner state of type {type(learner).__name__}, not a mapping"
    missing = [k for k in LEARNER_KEYS if k not in learner]
    if missing:
        return f"has learner state without {missing[0]}"
    bad = next((k for k in ("env_steps", "decisions", "updates") if not _is_count(learner[k])), None)
    if bad:
        return f"has learner {bad} = {learner[bad]!r}, not an integer >= 0"
    for net in ("online", "target"):
        if net in learner and (problem := _weights_problem(learner[net], f"{net} weights")):
            return problem
    if not isinstance(learner["buffer"], Mapping) or not isinstance(learner["optimizer"], Mapping):
        return "has a replay memory or optimizer state that is not a mapping"
    if not isinstance(learner["torch_rng"], torch.Tensor) or not isinstance(learner["numpy_rng"], Mapping):
        return "has random-generator states of the wrong type"
    if (problem := _rng_problem(learner["numpy_rng"])) is not None:
        return problem
    if (where := non_finite(window)) is not None:
        return f"has non-finite values (nan or inf) in its log window ({where})"
    if (where := non_finite(learner["optimizer"])) is not None:
        return f"has non-finite values (nan or inf) in its optimizer state ({where})"
    return (_window_problem(window) or _counters_problem(step, learner, config["dqn"])
            or _buffer_problem(learner["buffer"], config["dqn"])
            or _optimizer_problem(learner["optimizer"], learner["online"])
            or _moments_problem(learner["optimizer"], len(learner["online"]), int(learner["updates"]), config["dqn"])
            or tensor_problem(state, CHECKPOINT_TENSORS, deciding_entries)  # the limits of record_schemas
            or _group_problem(learner["optimizer"]["param_groups"][0], config["dqn"])
            or _moment_ratio_problem(learner["optimizer"], config["dqn"])
            or _window_steps_problem(window, step, config) or bounds_problem(state))


def _moments_problem(optimizer: Mapping[str, Any], n_params: int, updates: int, dqn: Mapping[str, Any]) -> str | None:
    """Why Adam's saved state cannot be that of its updates, or None: after the first update every parameter has its
    step and both moments (torch's Adam keeps them for every parameter that had a gradient, and every one has)."""
    if dqn.get("optimizer") != "adam" or updates == 0:
        return None
    state = optimizer["state"]
    missing = [i for i in range(n_params)
               if not (isinstance(state.get(i), Mapping) and {"step", "exp_avg", "exp_avg_sq"} <= set(state[i]))]
    if missing:
        return f"has no Adam state for parameter {missing[0]} after {updates} gradient updates (of {n_params})"
    return None


def _moment_ratio_problem(optimizer: Mapping[str, Any], dqn: Mapping[str, Any]) -> str | None:
    """Why Adam's first moment cannot be an average of the gradients its second moment averages the squares of, or
    None. Both are averages of the same gradients g (m = sum (1-b1) b1^k g_k, v = sum (1-b2) b2^k g_k^2), so by
    Cauchy-Schwarz |m| <= (1-b1) / sqrt((1-b2) (1 - b1^2/b2)) sqrt(v), 7.27 sqrt(v) at torch's betas, whatever the
    gradients; Adam's step, lr m / (sqrt(v) + eps), is then at most 7.27 lr. Each moment inside its own limits
    (record_schemas.CHECKPOINT_TENSORS) is not enough: a first moment of 9e5 beside a real second moment was resumed
    into a model of weights 8e11 that every reader refuses (issue 82, probe 13, F3)."""
    betas = optimizer["param_groups"][0].get("betas")
    if dqn.get("optimizer") != "adam" or not (isinstance(betas, tuple | list) and len(betas) == 2):
        return None
    b1, b2 = (float(b) for b in betas)  # numbers in range: _group_problem and the schema checked them
    if not (0 <= b1 < 1 and 0 < b2 < 1 and b1 * b1 < b2):
        return None
    most = (1 - b1) / math.sqrt((1 - b2) * (1 - b1 * b1 / b2)) * 1.001  # and float32's rounding
    for index, moments in optimizer["state"].items():
        m, v = moments.get("exp_avg"), moments.get("exp_avg_sq")
        if not (isinstance(m, torch.Tensor) and isinstance(v, torch.Tensor) and m.shape == v.shape):
            continue
        excess = m.double().abs() - most * v.double().clamp(min=0).sqrt() - 1e-12  # a gradient's underflow: 1e-12
        if bool((excess > 0).any()):
            at = int(torch.nonzero(excess.flatten() > 0)[0])
            return (f"field learner.optimizer.state.{index}.exp_avg is {float(m.flatten()[at]):g} beside an "
                    f"exp_avg_sq of {float(v.flatten()[at]):g}: Adam's first moment is at most {most:.2f} times the "
                    "square root of its second (both average the same gradients)")  # fmt: skip
    return None


def _window_steps_problem(window: Mapping[str, Any], step: int, config: Mapping[str, Any]) -> str | None:
    """Why the log window's counts and losses cannot be those of the steps it covers, or None. The window begins
    again at every logged step (a multiple of log_every_steps), so it covers step % log_every_steps steps, each with
    at most a jam's vehicles on the road (lanes x length / car length, twice that for margin): no more vehicle steps
    or transitions than that (issue 82, probe 13, F4: 1e14 vehicle steps in a window of 593 steps were resumed into
    train_log.csv; its losses' limit: record_schemas.LOSS_MAX)."""
    try:
        sim = config["sim"]
        every, lanes = int(config["log_every_steps"]), int(sim["road"]["lanes"])
        jam = 2 * lanes * float(sim["road"]["length_m"]) / float(sim["control"]["car_length_m"])
    except (KeyError, TypeError, ValueError, ZeroDivisionError, OverflowError):
        return None  # a configuration the configuration's own check names
    if every <= 0 or not math.isfinite(jam):
        return None
    steps = step % every
    for name in ("vehicle_steps", "samples"):
        if float(window[name]) > jam * steps:
            return (f"has a log window of {window[name]} {name.replace('_', ' ')} in {steps} steps (at most "
                    f"{jam:.0f} vehicles a step on {lanes} lanes)")  # fmt: skip
    return None


def _window_entries_problem(window: Any) -> str | None:
    """Why the log window is not a mapping of numbers, naming the entry (window.loss.0, window.r_speed), or None: its
    losses a list of numbers, every other entry a number; a bool or a text is none, nor an integer no float holds
    (its sums are added to floats and written to train_log.csv)."""
    if not isinstance(window, Mapping):
        return "has a log window that is not a mapping of numbers"
    for key, value in window.items():
        if key == "loss" and not isinstance(value, list):
            return f"has a log window whose window.loss is {shown(value)}, not a list of numbers"
        for where, number in ((f"loss.{i}", v) for i, v in enumerate(value)) if key == "loss" else ((key, value),):
            if isinstance(number, bool) or not isinstance(number, numbers.Real):
                return f"has a log window whose window.{where} is {shown(number)}, not a number"
            if isinstance(number, numbers.Integral) and math.isinf(as_float(number)):
                return f"has a log window whose window.{where} is {shown(number)}, larger than a float holds"
    return None


def _window_problem(window: Mapping[str, Any]) -> str | None:
    """Why the log window's sums cannot be its steps', or None: speeds of at most SPEED_MAX_MPS per vehicle step,
    rewards of at most REWARD_MAX in magnitude per transition, lane changes started and refused at most one per
    vehicle step or transition (issue 82, probe 8, J13: 50,000 lane changes in a window of 3,943 vehicle steps were
    resumed into train_log.csv); the counts' own limits: record_schemas."""
    if float(window["speed_sum"]) > SPEED_MAX_MPS * float(window["vehicle_steps"]):
        return (f"has a log window whose speeds sum to {window['speed_sum']:g} m/s over {window['vehicle_steps']} "
                f"vehicle steps (at most {SPEED_MAX_MPS:g} m/s each)")  # fmt: skip
    for name in ("lane_changes", "rejected"):
        if float(window[name]) > max(float(window["vehicle_steps"]), float(window["samples"])):
            return (f"has a log window of {window[name]} {name.replace('_', ' ')} over {window['vehicle_steps']} "
                    f"vehicle steps and {window['samples']} transitions (at most one each)")  # fmt: skip
    for name in ("r_speed", "r_lane_change", "r_flow"):
        if abs(float(window[name])) > REWARD_MAX * max(float(window["samples"]), 1.0):
            return f"has a log window whose {name} sums to {window[name]:g} over {window['samples']} transitions"
    return None


def _rng_problem(state: Any) -> str | None:
    """Why numpy's saved PCG64 state cannot be numpy's, or None: its 128-bit state and increment and its buffered
    32-bit half (has_uint32 0 or 1, uinteger below 2^32) in range."""
    inner = state.get("state") if isinstance(state, Mapping) else None
    if not isinstance(inner, Mapping) or not all(_is_count(inner.get(k)) and int(inner[k]) < 2**128
                                                 for k in ("state", "inc")):  # fmt: skip
        return "has a numpy random-generator state whose state or increment is not a 128-bit whole number"
    if state.get("has_uint32") not in (0, 1) or not (_is_count(state.get("uinteger"))
                                                     and int(state["uinteger"]) < 2**32):  # fmt: skip
        return "has a numpy random-generator state whose buffered value (has_uint32, uinteger) is out of range"
    return None


def _optimizer_problem(optimizer: Mapping[str, Any], online: Mapping[str, Any]) -> str | None:
    """Why the optimizer's state does not fit the online network it steps, or None: one group, its parameters the
    network's tensors in order, each parameter's moments of that tensor's shape."""
    groups, state, shapes = optimizer.get("param_groups"), optimizer.get("state"), [t.shape for t in online.values()]
    if not (isinstance(groups, list) and len(groups) == 1 and isinstance(groups[0], Mapping)
            and isinstance(state, Mapping)):  # fmt: skip
        return "has an optimizer state without its one parameter group"
    if groups[0].get("params") != list(range(len(shapes))):
        return f"has optimizer parameters {str(groups[0].get('params'))[:40]}, not its network's {len(shapes)} tensors"
    for index, moments in state.items():
        if index not in range(len(shapes)) or not isinstance(moments, Mapping):
            return f"has optimizer state for a parameter {index!r} its network does not have"
        for name, tensor in moments.items():
            if name != "step" and tensor is not None and (not isinstance(tensor, torch.Tensor)
                                                          or tensor.shape != shapes[index]):  # fmt: skip
                return (f"has optimizer state field {index}.{name} of another shape than its parameter "
                        f"{tuple(shapes[index])}")  # fmt: skip
    return None


def _group_problem(group: Mapping[str, Any], dqn: Mapping[str, Any]) -> str | None:
    """Why the optimizer's parameter group holds settings its training's optimizer does not have, or None: every
    setting as dqn.make_optimizer gives it (the configuration's learning rate, torch's defaults for the rest), of the
    same type; a configuration whose optimizer or rate is itself wrong is named by its own check."""
    from types import SimpleNamespace

    from coopsumo.agents.dqn import make_optimizer

    lr, (low, high) = dqn.get("lr"), _LIMITS["lr"][:2]
    if (dqn.get("optimizer") not in ("adam", "sgd") or not isinstance(lr, numbers.Real) or isinstance(lr, bool)
            or not low < float(lr) <= high):  # fmt: skip
        return None
    settings: Any = SimpleNamespace(optimizer=dqn["optimizer"], lr=float(lr))  # what make_optimizer reads
    made = make_optimizer(torch.nn.Linear(1, 1), settings)
    expected = {k: v for k, v in made.state_dict()["param_groups"][0].items() if k != "params"}
    for key in sorted(set(group) - {"params"} | set(expected)):
        got = group.get(key, "(none)")
        if key not in expected or not _same_setting(got, expected[key]):
            want = "none" if key not in expected else repr(expected[key])
            return f"has optimizer setting {key} = {got!r}, not {want} (its training's optimizer's)"
    return None


def _same_setting(got: Any, want: Any) -> bool:
    """got is the optimizer setting want: equal and of its kind (a number for a number, True/False/None as they are,
    a tuple entry by entry)."""
    if isinstance(want, tuple | list):
        return (isinstance(got, tuple | list) and len(got) == len(want)
                and all(_same_setting(g, w) for g, w in zip(got, want, strict=True)))  # fmt: skip
    if want is None or isinstance(want, bool):
        return got is want
    if isinstance(want, numbers.Real):
        return isinstance(got, numbers.Real) and not isinstance(got, bool) and float(got) == float(want)
    return type(got) is type(want) and bool(got == want)


def non_finite(x: Any, at: str = "") -> str | None:
    """Where the nested mappings, lists and tuples `x` hold a number or floating-point tensor that is nan or
    infinite (the keys joined by '.'), or None."""
    if isinstance(x, torch.Tensor):
        finite = not x.is_floating_point() or bool(torch.isfinite(x).all())
        return None if finite else at or "a tensor"
    if isinstance(x, numbers.Real) and not isinstance(x, numbers.Integral):
        return None if math.isfinite(x) else at or "a number"
    items = x.items() if isinstance(x, Mapping) else enumerate(x) if isinstance(x, list | tuple) else ()
    for key, value in items:
        if (found := non_finite(value, f"{at}.{key}" if at else str(key))) is not None:
            return found
    return None


def _setting(dqn: Mapping[str, Any], name: str) -> int | None:
    """A learner setting that must be a positive integer, or None when it is not one (the configuration's own
    check names it)."""
    value: Any = dqn.get(name)
    return int(value) if _is_count(value) and int(value) > 0 else None


def _counters_problem(step: int, learner: Mapping[str, Any], dqn: Mapping[str, Any]) -> str | None:
    """Why the learner's counters disagree with the checkpoint's step and with each other, or None: one environment
    step per training step; at most one decision round per step and at least one per decision interval; gradient
    updates only in whole rounds of updates_per_learn, one round per learn_every decision rounds at most."""
    env_steps, decisions, updates = (int(learner[k]) for k in ("env_steps", "decisions", "updates"))
    if env_steps != step:
        return f"has learner env_steps = {env_steps}, not its step {step}"
    interval = _setting(dqn, "decision_interval_steps")
    if decisions > env_steps or (interval is not None and decisions < env_steps // interval):
        return f"has {decisions} decision rounds in {env_steps} steps (a decision every {interval} steps)"
    per_round, every = _setting(dqn, "updates_per_learn"), _setting(dqn, "learn_every")
    if per_round and every and (updates % per_round or updates > decisions // every * per_round):
        return (f"has {updates} gradient updates, not a number {decisions} decision rounds can make ({per_round} "
                f"every {every} rounds)")  # fmt: skip
    return None


def _buffer_problem(buffer: Mapping[str, Any], dqn: Mapping[str, Any]) -> str | None:
    """Why the replay memory (replay.ReplayBuffer.state_dict) cannot be loaded as it is, or None: its capacity the
    configuration's, its size and position inside it (a memory not yet full is written in order), one row per slot
    in every field, finite numbers, actions 0-3."""
    counts: list[Any] = [buffer.get(k) for k in ("capacity", "size", "pos")]
    data = buffer.get("data")
    if not (all(_is_count(n) for n in counts) and isinstance(data, Mapping)):
        return "has a replay memory without a capacity, size, position or data"
    capacity, size, pos = (int(n) for n in counts)
    if _setting(dqn, "replay_size") not in (None, capacity):
        return f"has a replay memory of capacity {capacity}, not its configuration's {dqn.get('replay_size')}"
    if size > capacity or pos >= capacity or (size < capacity and pos != size):
        return f"has a replay memory position {pos} and size {size} that do not fit its capacity {capacity}"
    for name, tensor in data.items():
        if not isinstance(tensor, torch.Tensor) or tensor.dim() == 0 or len(tensor) != capacity:
            return f"has replay memory {name!r} that is not a tensor of {capacity} rows"
    if (where := non_finite(data)) is not None:
        return f"has non-finite values (nan or inf) in its replay memory ({where})"
    actions = data.get("actions")
    if isinstance(actions, torch.Tensor) and len(actions) and not 0 <= int(actions.min()) <= int(actions.max()) < 4:
        return "has actions outside 0-3 in its replay memory"
    for name in ("grids", "next_grids"):  # occupancy: 0 or 1 in every cell
        grid = data.get(name)
        if isinstance(grid, torch.Tensor) and grid.numel() and not 0 <= int(grid.min()) <= int(grid.max()) <= 1:
            return f"has occupancy grids outside 0-1 in its replay memory ({name})"
    mask = data.get("next_mask")
    if isinstance(mask, torch.Tensor) and mask.dim() == 2 and not bool(mask[:size].any(dim=1).all()):
        return "has a replay memory row whose next state allows no action (next_mask all false)"
    return None


def truncate_log(path: Path, step: int) -> int:
    """Drop the rows of train_log.csv (at path) logged after `step`, and a last row cut short by a kill; keep the
    header and every row up to `step`. A run killed after its last checkpoint had logged rows past it; its resume
    logs them again. Returns how many rows were dropped (0 when the file is missing)."""
    try:
        lines = read_text(path).splitlines(keepends=True)
    except FileNotFoundError:
        return 0
    if not lines:
        return 0
    width = len(next(csv.reader([lines[0]])))
    kept = [lines[0]] if lines[0].endswith("\n") else []
    for line in lines[1:]:
        row = next(csv.reader([line]), [])
        if not line.endswith("\n") or len(row) != width or not digits(row[0]) or int(row[0]) > step:
            break
        kept.append(line)
    dropped = len(lines) - len(kept)
    if dropped:
        text = "".join(kept)
        write_atomic(path, lambda tmp: tmp.write_text(text))
    return dropped


def resume_problem(out: Path, state: Mapping[str, Any]) -> str | None:
    """Why the training folder `out` cannot resume from its checkpoint `state` (its keys checked by the caller), the
    file named: the checkpoint (checkpoint_problem) or the log rows the resume keeps (log_problem); or None."""
    if problem := checkpoint_problem(state):
        return f"checkpoint {out / 'checkpoint.pt'} {problem}"
    if problem := log_problem(out / "train_log.csv", int(state["step"])):
        return f"training log {out / 'train_log.csv'} {problem}"
    return None


def prepare_resume(out: Path, step: int) -> None:
    """Make the training folder `out` ready to continue from a checkpoint at `step`: train_log.csv rows past it
    dropped (truncate_log). Files named like the temporaries a kill left of writes of the training's own files
    ('.NAME.XXXXXXXX.tmp') stay: they may be a user's (files.write_atomic, J23; issue 82, probe 8, J22: every
    '*.tmp' was removed; probe 12, N3: '.checkpoint.pt.ABCDEFGH.tmp' still was), and the resume's own writes
    take fresh names."""
    truncate_log(out / "train_log.csv", step)


def ended_training(out: Path, step: int, steps: int) -> dict[str, Any] | None:
    """train_summary.json of `out` when the checkpoint's `step` is the training's last (`steps`) and the file
    was written (the training ended and was interrupted in its evaluation); else None (the training resumes)."""
    if step != steps:
        return None
    summary = read_json_object(out / "train_summary.json")
    return summary if summary is not None and summary.get("steps") == steps else None
