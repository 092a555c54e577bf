"""One validation layer for the inputs of every command.

A bad value becomes one line naming the flag, the value and the allowed range (exit code 2),
before anything is written. Single values are checked while parsing (`argparse` `type=`
callables: `seed`, `integer(...)`, `number(...)`; argparse names the flag); values that depend
on each other or come as lists are checked after parsing (`check_*`, `number_list`), raising
UsageError with the flag in the message. The rules a data file's values share with their flags (IntRule, NumberRule,
ListRule) live in field_rules.py and are given here under the same names.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import numbers
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from coopsumo.errors import ConfigError, UsageError
from coopsumo.field_rules import IntRule as IntRule
from coopsumo.field_rules import ListRule as ListRule
from coopsumo.field_rules import NumberRule as NumberRule
from coopsumo.field_rules import (
    as_float,
    ascii_text,
    int_problem,
    int_range,
    integer,
    number_problem,
    shown,
    split_list,
)
from coopsumo.field_rules import names_problem as names_problem
from coopsumo.field_rules import number as number
from coopsumo.field_rules import number_list as number_list
from coopsumo.field_rules import parse_number as parse_number
from coopsumo.field_rules import same_twice as same_twice
from coopsumo.field_rules import twice_at as twice_at
from coopsumo.paths import out_path_problem, policy_path_problem

SEED_MAX = 2**31 - 1
"""largest seed: SUMO's --seed is a C int"""
MAX_STEPS = 10_000_000
"""largest step count of one run (about 11.6 days of 0.1 s steps, 100 times the paper's run)"""
MAX_SEEDS = 1000
"""largest number of seeds of a study"""
MAX_REPLAY = 1_000_000
"""largest replay memory (transitions; about 0.4 GB)"""
ALPHA_MIN = 0.0
"""the lane-change penalty alpha of eq. (7) is a finite number >= this (the one place the rule lives)"""
ALPHA_MAX = 1000.0
"""... and <= this: far above the paper's largest (48); the reward's other terms are about 1 per step"""
MAX_T_UP_S = 3600.0
"""largest upstream departure interval T_up (s): one vehicle an hour"""
MAX_GUI_DELAY_MS = 10_000.0
"""largest pause of sumo-gui between two steps (ms): 10 s a step"""
MAX_FCD_PERIOD_S = 86_400.0
"""largest period of SUMO's FCD output (s): a day, longer than any run (SUMO's clock overflows near 1e16 s)"""
MOBIL_LIMITS: dict[str, tuple[float, float, bool]] = {
    "p": (0.0, 10.0, False),
    "threshold": (0.0, 100.0, False),
    "b_safe": (0.0, 1e6, True),
    "bias": (-100.0, 100.0, False),
}
"""MOBIL's parameters: (lowest, highest, lowest excluded); m/s^2 but p (politeness, 1: others weigh as much as
oneself). The controller's accelerations lie between about -400 m/s^2 (a stop in one 0.1 s step) and 4 m/s^2"""
SUMO_LC_LIMITS: dict[str, tuple[float, float, bool]] = {
    "lcCooperative": (0.0, 1.0, False),
    "lcSpeedGain": (0.0, 100.0, False),
    "lcStrategic": (-1.0, 100.0, False),
    "lcKeepRight": (0.0, 100.0, False),
    "lcAssertive": (0.0, 100.0, True),
}
"""SUMO's LC2013 factors a `sumo:` policy may set: (lowest, highest, lowest excluded); lcStrategic -1 turns
strategic changes off; lcCooperative is a share"""
def max_workers() -> int:
    """Largest --workers: four processes per core of this machine."""
    return 4 * (os.cpu_count() or 1)


_KINDS = {"int": "an integer", "float": "a finite number", "bool": "true or false", "str": "a string"}


def _kind_fits(kind: str, value: Any) -> bool:
    if kind == "bool":
        return isinstance(value, bool)
    if isinstance(value, bool):
        return False
    if kind == "int":
        return isinstance(value, numbers.Integral)
    if kind == "float":
        return isinstance(value, numbers.Real) and math.isfinite(as_float(value))  # 400 digits: not finite
    return isinstance(value, str)


def type_problem(obj: Any, prefix: str = "") -> str | None:
    """The first field of the dataclass `obj` (nested dataclasses too) whose value does not fit its annotation
    (int, float, bool or str; an integer is a float, a bool is neither; floats finite), in words; None when every
    one fits. Configurations read back from files (checkpoints, model files) may hold anything."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            if problem := type_problem(value, f"{prefix}{f.name}."):
                return problem
            continue
        kind = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", "")
        if kind in _KINDS and not _kind_fits(kind, value):
            return f"{prefix}{f.name} must be {_KINDS[kind]}, got {shown(value)}"
    return None


def from_fields(cls: Any, d: dict[str, Any], what: str) -> Any:
    """cls(**d); a field cls does not know is a ConfigError naming it (missing fields take their defaults)."""
    if not isinstance(d, dict):
        raise ConfigError(f"{what} settings are not a mapping: {d!r}")
    unknown = sorted(set(d) - {f.name for f in dataclasses.fields(cls)})
    if unknown:
        raise ConfigError(f"unknown {what} setting {unknown[0]!r} (written by a newer coopsumo?)")
    return cls(**d)


def limits_problem(obj: Any, limits: Mapping[str, tuple[float, float, bool, bool]]) -> str | None:
    """The first attribute of `obj` named in `limits` outside its (lowest, highest, lowest excluded, highest
    excluded) range, in words; None when all are inside."""
    for name, (low, high, low_open, high_open) in limits.items():
        value = getattr(obj, name)
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            return f"{name} must be a number, got {shown(value)}"
        if isinstance(low, int) and isinstance(high, int) and not (low_open or high_open):
            if isinstance(value, numbers.Integral):  # a Python int compared as it is: 400 digits too
                problem = int_problem(value if isinstance(value, int) else int(float(value)), low, high)
            else:
                problem = int_range(low, high)
        else:
            problem = number_problem(as_float(value), low, high, low_open, high_open)  # 400 digits: outside
        if problem:
            return f"{name} must be {problem}, got {shown(value)}"
    return None


# -- argparse type= callables (argparse prefixes "argument --flag:") ------------------------------
seed = integer(0, SEED_MAX, " (SUMO's seed range)")
"""`type=` of a --seed flag"""
steps = integer(1, MAX_STEPS)
"""`type=` of a step-count flag"""
seed_count = integer(1, MAX_SEEDS)
"""`type=` of a --seeds (how many) flag"""
alpha = number(ALPHA_MIN, ALPHA_MAX)
"""`type=` of an --alpha flag"""


def out_dir(text: str) -> Path:
    """A `type=` for --out: a folder path SUMO and the file system can take (paths.out_path_problem: no ':' or ','
    in it, not too long, no symlink loop, ASCII under an ASCII locale, a current folder that exists), checked
    here instead of failing inside SUMO after a folder was made."""
    if not text:
        raise argparse.ArgumentTypeError("must be a folder path, got ''")
    path = Path(text)
    problem = out_path_problem(path)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return path


def model_out_dir(text: str) -> Path:
    """A `type=` for the --out of a command whose models a policy string names later (train and the studies that
    train): out_dir, and no space in it (policy_path_problem), refused before hours of training, not after."""
    path = out_dir(text)
    problem = policy_path_problem(path)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return path


def default_model_out(default: Path) -> Path:
    """The folder a command of model_out_dir writes when --out is not given (its default, resolved from the current
    folder), checked as model_out_dir checks a given one: UsageError when SUMO cannot take it (out_path_problem) or a
    policy string could not name its models (policy_path_problem: a project cloned into a path with a space)."""
    problem = out_path_problem(default) or policy_path_problem(default)
    if problem:
        raise UsageError(f"--out not given, and its default {default} {problem}; name another folder with --out")
    return default


def workers(text: str) -> int:
    """`type=` of a --workers flag: 1 to four per core."""
    return integer(1, max_workers(), f" (4 per core; this machine has {os.cpu_count() or 1})")(text)


# -- checks after parsing (UsageError naming the flag) ---------------------------------------------
def check_int(flag: str, value: int, low: int, high: int | None = None, note: str = "") -> int:
    problem = int_problem(value, low, high)
    if problem:
        raise UsageError(f"{flag} must be {problem}{note}, got {value}")
    return value


def check_number(flag: str, value: float, low: float | None = None, high: float | None = None,
                 low_open: bool = False, high_open: bool = False, note: str = "") -> float:  # fmt: skip
    problem = number_problem(value, low, high, low_open, high_open)
    if problem:
        raise UsageError(f"{flag} must be {problem}{note}, got {number_name(value)}")  # as given, not rounded
    return value


def name_list(flag: str, text: str, known: Sequence[str]) -> tuple[str, ...]:
    """A comma-separated list of names out of `known` (split_list); UsageError naming an unknown one."""
    items = split_list(flag, text)
    unknown = [x for x in items if x not in known]
    if unknown:
        raise UsageError(f"{flag}: unknown {', '.join(map(repr, unknown))}; expected a comma-separated subset of "
                         f"{','.join(known)}")  # fmt: skip
    return tuple(items)


ALPHA_LIST = ListRule(ALPHA_MIN, ALPHA_MAX)
"""a list of alphas (--alphas, a profile's alphas): distinct finite numbers from ALPHA_MIN to ALPHA_MAX"""
SEED_LIST = ListRule(0, SEED_MAX, whole=True, note=" (SUMO's seed range)", most=MAX_SEEDS)
"""a list of training seeds (a profile's seeds): distinct, at most MAX_SEEDS (--seeds N: seeds 1..N)"""
MOBIL_P_LIST = ListRule(0.0, MOBIL_LIMITS["p"][1])
"""a list of MOBIL politeness values (--mobil-p, a profile's mobil_ps)"""


def alpha_list(flag: str, text: str) -> tuple[float, ...]:
    """A comma-separated list of alphas (--alphas), each a finite number from ALPHA_MIN to ALPHA_MAX."""
    return ALPHA_LIST.parse(flag, text)


def train_seed_list(flag: str, text: str, first: int, evaluation: Sequence[int] = ()) -> tuple[int, ...]:
    """--train-seeds: K (the K seeds first, first + 1, ...) or a comma-separated list of training seeds; UsageError
    naming the flag for anything else (0, a negative count, a seed twice, a word) and for a seed that is also an
    evaluation seed (a model is judged only on seeds it never trained on)."""
    items = split_list(flag, text)

    def whole(item: str) -> int:
        try:
            return int(ascii_text(item))  # '٣' or '1_0' as every flag refuses them
        except ValueError:
            raise UsageError(f"{flag}: {item!r} is not an integer; give a model count K or a comma-separated list of "
                             "training seeds") from None  # fmt: skip

    if len(items) == 1:
        k = whole(items[0])
        if not 1 <= k <= MAX_SEEDS:
            raise UsageError(f"{flag} must be a model count in [1, {MAX_SEEDS}] or a comma-separated list of seeds, "
                             f"got {text!r}")  # fmt: skip
        seeds = tuple(range(first, first + k))
    else:
        seeds = tuple(whole(x) for x in items)
        same_twice(flag, text, items, seeds)
        bad = [x for x in seeds if not 0 <= x <= SEED_MAX]
        if bad:
            raise UsageError(f"{flag}: seed {bad[0]} is outside [0, {SEED_MAX}]")
    shared = sorted(set(seeds) & set(evaluation))
    if shared:
        raise UsageError(f"{flag}: training seed(s) {', '.join(map(str, shared))} also used as evaluation seed(s); a "
                         "model is judged only on seeds it never trained on")  # fmt: skip
    return seeds


def number_name(x: float) -> str:
    """x in a cell key, folder or column name: as :g prints it when that reads back as exactly x (8 -> "8",
    0.125 -> "0.125"), else the shortest text that does (8.000001 -> "8.000001"); distinct values never share one."""
    short = f"{x:g}"
    return short if float(short) == x else repr(float(x))


def distinct_list(flag: str, text: str, low: float | None = None, low_open: bool = False,
                  note: str = "", high: float | None = None) -> tuple[float, ...]:  # fmt: skip
    """A study axis: comma-separated finite numbers inside the bounds, no empty item and no value twice in any
    form (number_list; they name run folders: number_name); UsageError otherwise."""
    return number_list(flag, text, low=low, high=high, low_open=low_open, note=note)


def min_t_up_s(dt_s: float) -> float:
    """Smallest accepted T_up (s): one vehicle per simulation step, so the demand never schedules more
    vehicles than the run has steps (its memory stays bounded whatever T_up is asked for)."""
    return dt_s


def t_up_note(dt_s: float) -> str:
    """Why T_up has its lower limit, for messages."""
    limit = min_t_up_s(dt_s)
    return f" s (one vehicle per {limit:g} s simulation step, {3600 / limit:,.0f} veh/h)"


def t_up_type(dt_s: float) -> NumberRule:
    """The `type=` of a --t-up flag: the limits check_t_up applies, read from the text as given, so that a value over
    MAX_T_UP_S by less than a float's precision is refused too (issue 82, probe 13, F16: 3600.00000000000001 ran)."""
    return number(min_t_up_s(dt_s), MAX_T_UP_S, note=t_up_note(dt_s))


def check_t_up(flag: str, value: float, dt_s: float) -> float:
    """T_up (s) finite, at least one simulation step and at most MAX_T_UP_S."""
    return check_number(flag, value, low=min_t_up_s(dt_s), high=MAX_T_UP_S, note=t_up_note(dt_s))


def t_up_rule(dt_s: float, least: int = 1) -> ListRule:
    """The rule of a list of distinct demands T_up (s), each from one simulation step to MAX_T_UP_S."""
    return ListRule(min_t_up_s(dt_s), MAX_T_UP_S, note=t_up_note(dt_s), least=least)


def t_up_list(flag: str, text: str, dt_s: float) -> tuple[float, ...]:
    """A list of distinct demands T_up (s), each from one simulation step to MAX_T_UP_S."""
    return t_up_rule(dt_s).parse(flag, text)


def check_accident(start: int, duration: int, steps: int, start_flag: str = "--accident-start",
                   steps_flag: str = "--accident-steps") -> None:  # fmt: skip
    """The accident window starts inside the run (0 .. steps - 1) and has a positive length.

    It may end after the run (the hold probability then has not decayed to 0 when the run ends).
    """
    if problem := accident_problem(start, duration, steps, start_flag, steps_flag):
        raise UsageError(problem)


def accident_problem(start: int, duration: int, steps: int, start_name: str, steps_name: str) -> str | None:
    """check_accident's rule in words naming the flag or field at fault (a data file's accident_start), or None."""
    for name, value, rule in ((start_name, start, integer(0, steps - 1, f" (a step of the {steps}-step run)")),
                              (steps_name, duration, integer(1, MAX_STEPS))):  # fmt: skip
        if int_problem(value, rule.low, rule.high):
            return f"{name} must be {rule.words()}, got {value}"
    return None


# -- Ray cluster addresses ------------------------------------------------------------------------
