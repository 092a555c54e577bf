"""One grammar for policy strings, parsed once into a typed PolicySpec (every command, study and environment).

    keep | random | greedy                          no parameters
    mobil[:p=P,threshold=T,b_safe=B,bias=R]          any subset, any order (MOBIL_LIMITS)
    sumo[:lcCooperative=X,lcSpeedGain=X,...]          SUMO's LC2013 factors (SUMO_LC_LIMITS)
    dqn:PATH[,alpha=A|alpha=adaptive][,margin=M][,noreturn=S][,restart=R][,queue=V]
                                                     PATH: a model file, or a folder holding model.pt; M: the
                                                     change margin it drives with (Q units; default: the model's);
                                                     S: seconds after a lane change before the change back
                                                     (default 0: none);
                                                     R: 'none' withheld below R m/s (default: the model's);
                                                     V: no lane change chosen below V m/s (default 0: none)
    py:MODULE:CLASS                                  a class of your own (agents/user_policy.py): MODULE a Python
                                                     file (a path ending in .py) or a module name (MODULE.py in the
                                                     current folder, else an importable module); CLASS a class in it
                                                     whose act(obs) gives one action per vehicle (docs/extending.md)
    sb3:PATH                                         a Stable-Baselines3 DQN model saved by its save() (a .zip file,
                                                     e.g. experiments/sb3_dqn.py's model.zip; agents/sb3_policy.py)

Parameters are KEY=VALUE separated by ','; each key at most once; each value a finite number in its key's range
(alpha also 'adaptive'). No spaces anywhere, no empty parameter, and no ',' inside a model path (the grammar and
SUMO's file lists split at commas). py and sb3 take no parameters. Pure text (model_file aside): whether a model
exists or is alpha-conditioned, whether a module defines its class, is checked when it is loaded
(agents/dqn_policy.py, agents/user_policy.py, agents/sb3_policy.py).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

from coopsumo.errors import UsageError
from coopsumo.field_rules import TOO_SMALL, ascii_text, decimal_outside, too_small
from coopsumo.validation import ALPHA_MAX, ALPHA_MIN, MOBIL_LIMITS, SUMO_LC_LIMITS, number_problem

ADAPTIVE = "adaptive"
"""the value of a dqn policy's alpha that chooses alpha online from the loops (agents/adaptive.py)"""
MARGIN_MAX = 100.0
"""the largest change margin a dqn policy string takes (Q units; a few is already large)"""
NORETURN_MAX_S = 600.0
"""the longest time a dqn policy string withholds the change back (s)"""
RESTART_MAX_MPS = 50.0
"""the largest 'none'-withholding speed a dqn policy string takes (m/s; above every expected speed: never 'none')"""
PLAIN = ("keep", "random", "greedy")
"""policies without parameters"""
KEYS: dict[str, dict[str, tuple[float, float, bool]]] = {
    "mobil": MOBIL_LIMITS,
    "sumo": SUMO_LC_LIMITS,
    "dqn": {"alpha": (ALPHA_MIN, ALPHA_MAX, False), "margin": (0.0, MARGIN_MAX, False),
            "noreturn": (0.0, NORETURN_MAX_S, False), "restart": (0.0, RESTART_MAX_MPS, False),
            "queue": (0.0, RESTART_MAX_MPS, False)},
}
"""the parameters each policy takes: key -> (lowest, highest, lowest excluded)"""
RETIRED_KEYS: dict[str, tuple[str, tuple[float, float, bool]]] = {
    "cooldown": ("change_cooldown_s", (0.0, 600.0, False)), "ensemble": ("ensemble_snapshots", (1.0, 20.0, False))}
"""dqn parameters tried and not adopted (issue 80; results/history keeps their rows, each made at the commit it
names): the drive setting each was recorded as and the range it took. A policy string with one is refused in one
line; a frozen study's record of one is read as it was (protocol.history)"""
DRIVES = (("margin", "change_margin", "change margin"), ("noreturn", "no_return_s", "no change back within (s)"),
          ("restart", "restart_below_mps", "'none' withheld below (m/s)"),
          ("queue", "queue_below_mps", "no lane change below (m/s)"))
"""the drive settings a dqn policy string takes besides alpha, each as (its key in the string, the DQNConfig field it
replaces: the key of a study cell's config.drive and of a protocol variant's `drive` table in learners.toml, the
report's words); the string of a model with its drive settings: studies/engine/cells.dqn_policy. The retired ones:
RETIRED_KEYS"""
OWN = ("py", "sb3")
"""policies from the user's own files: a class of their own (py:MODULE:CLASS), a Stable-Baselines3 model (sb3:PATH)"""
FORMS = ("keep, random, greedy, mobil[:p=P,...], sumo[:lcCooperative=X,...], "
         "dqn:PATH[,alpha=A|adaptive,margin=M,noreturn=S,restart=R,queue=V], py:MODULE:CLASS, "
         "sb3:PATH")


class PolicySpecError(UsageError):
    """A policy string the grammar refuses (a usage error: one line, exit code 2)."""


@dataclass(frozen=True)
class PolicySpec:
    """A parsed policy string: its name, its numeric parameters in the order given, and for dqn the model path,
    alpha (a number, 'adaptive', or None when not given), the change margin (None: the model's own), how long (s)
    the change back into the lane just left is not chosen (None: no such rule), the speed (m/s) below which 'none'
    is withheld (None: the model's own) and the speed (m/s) below which no lane change is chosen (None: none)."""

    name: str
    params: tuple[tuple[str, float], ...] = ()
    model: str | None = None
    alpha: float | str | None = None
    margin: float | None = None
    noreturn: float | None = None
    restart: float | None = None
    queue: float | None = None
    module: str | None = None
    """py: the module's file or name"""
    class_name: str | None = None
    """py: the class in it"""

    def values(self) -> dict[str, float]:
        return dict(self.params)


def split_dqn_spec(text: str) -> tuple[str, float | str | None]:
    """'dqn:PATH[,alpha=A|adaptive]' -> (PATH, alpha: a number, 'adaptive' or None); PolicySpecError otherwise."""
    spec = parse_policy(text)
    if spec.name != "dqn" or spec.model is None:
        raise _fail(text, "is not a dqn policy; expected dqn:PATH[,alpha=A|adaptive]")
    return spec.model, spec.alpha


def model_file(path: str) -> str:
    """The model file a dqn policy's PATH names: PATH, or PATH/model.pt when PATH is a folder (a training's)."""
    return os.path.join(path, "model.pt") if os.path.isdir(path) else path


def _fail(text: str, problem: str) -> PolicySpecError:
    return PolicySpecError(f"policy {text!r}: {problem}")


def _value(text: str, name: str, key: str, value: str) -> float | str:
    if name == "dqn" and key == "alpha" and value == ADAPTIVE:  # only alpha takes a word
        return ADAPTIVE
    low, high, low_open = KEYS[name][key]
    try:
        number = float(ascii_text(value))  # '٠' and '1_0' as a flag refuses them (field_rules.ascii_text)
    except ValueError:
        number = math.nan
    if decimal_outside(value, low, high, low_open):
        number = math.nan  # over a limit by less than a float's precision
    small = too_small(value)  # 1e-400 is not 0 (issue 82, probe 14, F7: mobil:p=1e-400 drove with p = 0)
    if problem := number_problem(math.nan if small else number, low, high, low_open):
        also = f" or {ADAPTIVE!r}" if (name, key) == ("dqn", "alpha") else ""
        raise _fail(text, f"{key} must be {problem}{also}, got {value!r}" + (f", {TOO_SMALL}" if small else ""))
    return number


def parse_policy(text: str) -> PolicySpec:
    """The PolicySpec of a policy string; PolicySpecError naming the first problem (see the module's grammar)."""
    if not isinstance(text, str) or not text:
        raise PolicySpecError(f"policy must be one of {FORMS}; got {text!r}")
    if any(ch.isspace() for ch in text):
        raise _fail(text, "has a space; write it without spaces (KEY=VALUE,KEY=VALUE)")
    name, colon, body = text.partition(":")
    if name in PLAIN:
        if colon:
            raise _fail(text, f"{name} takes no parameters; write {name}")
        return PolicySpec(name)
    if name in OWN:
        return _own(text, name, colon, body)
    if name not in KEYS:
        raise _fail(text, f"unknown policy {name!r}; expected one of {FORMS}")
    items = body.split(",") if colon else []
    model = None
    if name == "dqn":
        if not colon or not items[0]:
            raise _fail(text, "dqn needs a model: dqn:PATH (a model file, or a folder holding model.pt)")
        model, items = items[0], items[1:]
    elif colon and not body:
        raise _fail(text, f"nothing after ':'; write {name} for the defaults or {name}:KEY=VALUE")
    seen: dict[str, float | str] = {}
    for item in items:
        key, eq, value = item.partition("=")
        if not item:
            raise _fail(text, "has an empty parameter (',' at the end, or ',,')")
        if not eq:
            if name == "dqn":
                raise _fail(text, f"{item!r} is not KEY=VALUE; a model path cannot hold ',' (rename the folder)")
            raise _fail(text, f"{item!r} is not KEY=VALUE")
        if name == "dqn" and key in RETIRED_KEYS:
            raise _fail(text, f"{key} was retired (tried, not adopted: results/history); drive without it")
        if key not in KEYS[name]:
            raise _fail(text, f"unknown parameter {key!r} of {name}; expected one of {', '.join(KEYS[name])}")
        if key in seen:
            raise _fail(text, f"parameter {key!r} is given twice")
        if not value:
            raise _fail(text, f"parameter {key!r} has no value")
        seen[key] = _value(text, name, key, value)
    if name == "dqn":
        def number(key: str) -> float | None:
            return None if seen.get(key) is None else float(seen[key])

        return PolicySpec(name, model=model, alpha=seen.get("alpha"), margin=number("margin"),
                          noreturn=number("noreturn"), restart=number("restart"), queue=number("queue"))
    return PolicySpec(name, params=tuple((k, float(v)) for k, v in seen.items()))


def _own(text: str, name: str, colon: str, body: str) -> PolicySpec:
    """The spec of py:MODULE:CLASS or sb3:PATH (no parameters, no ',' anywhere)."""
    form = "py:MODULE:CLASS (MODULE a .py file or a module name)" if name == "py" else "sb3:PATH (a model.zip)"
    if not colon or not body:
        raise _fail(text, f"{name} needs {'a module and a class' if name == 'py' else 'a model'}: {form}")
    if "," in body:
        raise _fail(text, f"{name} takes no parameters and its path cannot hold ','; write {form}")
    if name == "sb3":
        return PolicySpec(name, model=body)
    module, sep, class_name = body.rpartition(":")
    if not sep or not module:
        raise _fail(text, f"names no class; write {form}")
    if not class_name.isidentifier():
        raise _fail(text, f"{class_name!r} is not a Python class name; write {form}")
    return PolicySpec(name, module=module, class_name=class_name)


def policy_file(text: str) -> str | None:
    """The file a policy string drives, whose bytes decide what it does (a study reruns a run when they change), or
    None: a dqn policy's model file, an sb3 policy's model, a py policy's module when MODULE is a file (a .py path, or
    MODULE.py in the current folder); None for the built-in policies and an installed module."""
    spec = parse_policy(text)
    if spec.name == "dqn" and spec.model is not None:
        return model_file(spec.model)
    if spec.name == "sb3":
        return spec.model
    if spec.name == "py" and spec.module is not None:
        return module_file(spec.module)
    return None


def module_file(module: str) -> str | None:
    """The file of a py policy's MODULE: MODULE itself when it ends in .py, MODULE.py (dots as folders) in the
    current folder when that file exists, else None (an importable module, found by Python's import)."""
    if module.endswith(".py"):
        return module
    local = os.path.join(*module.split(".")) + ".py" if all(p.isidentifier() for p in module.split(".")) else None
    return local if local is not None and os.path.isfile(local) else None


LC_KEYS = tuple(SUMO_LC_LIMITS)
"""LC2013 parameters a `sumo:` spec may set on every vehicle"""


def sumo_models(spec: str) -> bool:
    """True when the policy spec puts SUMO's own models in charge (`sumo` or `sumo:...`): its Krauss car-following
    and LC2013 lane changing drive instead of the Newell controller."""
    return spec == "sumo" or spec.startswith("sumo:")


def sumo_lc_params(spec: str) -> dict[str, float]:
    """The LC2013 parameters of `sumo` or `sumo:lcCooperative=0.5,lcSpeedGain=1` (empty for plain `sumo`)."""
    parsed = parse_policy(spec)
    if parsed.name != "sumo":
        raise PolicySpecError(f"policy {spec!r} is not a sumo policy")
    return parsed.values()
