"""The catalogue reader: the experiments' data files (coopsumo/experiments_data/*.toml, inside the package so that an
installed wheel has them too) read and checked, every error one ConfigError line naming the file and the entry; a
value checked by the very rule its flag is (validation.IntRule, NumberRule, ListRule, names_problem); a study's profile
file (read_profiles: scenario1.toml, scenario2.toml); a study's profile taken from a file of one's own
(`--profile PATH.toml[:NAME]`, own_profile); and the learner catalogue, every learner a study may name (learners.toml,
load_learners, read by the learner protocol and scenario I's `--learner`).

A learner is a training (its DQNConfig: a preset, or a parent learner, with the settings it changes) plus how its
trainings drive: which weights (`model.pt`, the validated best; or `model_last.pt`) and the drive settings a cell's
config.drive gives its policy string (policy_spec.DRIVES). The file says what each key means."""

from __future__ import annotations

import argparse
import math
import re
import tomllib
import types
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol, TypeVar, Union, get_args, get_origin, get_type_hints

from coopsumo.dqn_config import DQN_PRESETS, DQNConfig
from coopsumo.errors import ConfigError, UsageError
from coopsumo.field_rules import TOO_SMALL, Written, as_float, shown, too_small
from coopsumo.files import MAX_JSON_DEPTH, depth_problem, not_regular, open_regular
from coopsumo.policy_spec import DRIVES
from coopsumo.validation import names_problem

DATA = Path(__file__).resolve().parents[2] / "experiments_data"
"""the folder of the experiments' data files"""
P = TypeVar("P")


class Rule(Protocol):
    """A field's rule, shared with its flag (validation.IntRule, NumberRule, ListRule): why a value breaks it, in words
    after the field's name, or None."""

    def problem(self, value: Any) -> str | None: ...


class CommitRule:
    """The rule of a profile's analysis-plan commit (scenario II's response_plan, the protocol's plan): empty, or a
    commit's hash, 7 to 40 lowercase hex digits (any text was taken, and declared the response reading confirmatory:
    `x; rm -rf /` was recorded as the plan's commit; issue 82, probe 13, F21)."""

    def problem(self, value: Any) -> str | None:
        if value == "" or (isinstance(value, str) and re.fullmatch(r"[0-9a-f]{7,40}", value)):
            return None
        return f"must be a commit's hash (7 to 40 hex digits: git rev-parse --short HEAD) or empty, got {shown(value)}"


class Entry:
    """Errors about one entry of one file: `<file>: [<entry>] <what is wrong>`."""

    def __init__(self, path: Path, name: str) -> None:
        self.where = f"{path}: [{name}]"

    def error(self, text: str) -> ConfigError:
        return ConfigError(f"{self.where} {text}")

    def value(self, key: str, value: Any, hint: Any, rule: Rule | None = None) -> Any:
        """`value` as the type `hint` names (bool, int, float, str, tuple[X, ...], tuple[X, Y, Z], X | None): an
        integer where a float belongs becomes one (a learner's identity is its JSON); anything else is an error. With
        `rule` (its flag's), a value the rule refuses is an error too, the value shown as the file gives it."""
        typed = self._typed(key, value, hint, rule is None)  # with a rule, the rule's words for a value too small
        if rule is not None and (problem := rule.problem(value)):
            raise self.error(f"{key} {problem}")
        return typed

    def names(self, key: str, value: Any, known: Sequence[str], least: int = 1) -> tuple[str, ...]:
        """A list of names out of `known` (variants, policies), by its flag's rule (validation.names_problem)."""
        names: tuple[str, ...] = self._typed(key, value, tuple[str, ...])
        if problem := names_problem(names, known, least):
            raise self.error(f"{key} {problem}")
        return names

    def _typed(self, key: str, value: Any, hint: Any, small: bool = True) -> Any:
        """`value` as `hint` names it (value); small: a float too small for a float (1e-400) refused here."""
        origin, args = get_origin(hint), get_args(hint)
        if origin in (Union, types.UnionType):
            return self._typed(key, value, next(a for a in args if a is not type(None)), small)
        if origin is tuple:
            any_length = args[-1] is Ellipsis
            if not isinstance(value, list) or not (any_length or len(value) == len(args)):
                raise self.error(f"{key} must be a list{'' if any_length else f' of {len(args)}'}, got {value!r}")
            items = [args[0]] * len(value) if any_length else list(args)
            return tuple(self._typed(key, v, a, small) for v, a in zip(value, items, strict=True))
        if hint is float and isinstance(value, int | float) and not isinstance(value, bool):
            if isinstance(value, int) and math.isinf(as_float(value)):  # 400 digits: no float holds it
                raise self.error(f"{key} must be a finite number, got {shown(value)}")
            if small and isinstance(value, Written) and too_small(value.text):  # 1e-400 is not 0 (probe 14, F7)
                raise self.error(f"{key} must be a finite number, got {value.text}, {TOO_SMALL}")
            return float(value)
        if isinstance(value, hint) and not (hint is int and isinstance(value, bool)):
            return value
        raise self.error(f"{key} must be {hint.__name__}, got {value!r}")

    def table(self, data: Any, what: str, known: tuple[str, ...] | dict[str, Any]) -> dict[str, Any]:
        if not isinstance(data, dict):
            raise self.error(f"{what} must be a table, got {data!r}")
        for key in data:
            if key not in known:
                raise self.error(f"unknown field {key!r} in {what} (known: {', '.join(known)})")
        return data


def read_toml(path: Path) -> dict[str, Any]:
    """The TOML file `path`; ConfigError in one line naming it when it cannot be read, is not UTF-8 or not TOML,
    or nests deeper than any catalogue or profile does (tomllib's RecursionError, files.depth_problem)."""
    try:
        with open_regular(path) as f:  # a named pipe is refused, not waited on
            data = tomllib.load(f, parse_float=Written)  # each float with its text: judged as written (Written)
    except OSError as err:
        raise ConfigError(f"{path}: cannot read it ({err.strerror})") from None
    except UnicodeDecodeError as err:
        raise ConfigError(f"{path}: not TOML (not UTF-8: byte {err.object[err.start]:#04x} at {err.start})") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not TOML ({err})") from None
    except RecursionError:
        raise ConfigError(f"{path}: not TOML (nested deeper than {MAX_JSON_DEPTH} levels)") from None
    except ValueError as err:  # int() of more digits than Python converts (4,300), passed on by tomllib
        raise ConfigError(f"{path}: not TOML ({str(err).splitlines()[0][:80]})") from None
    if (problem := depth_problem(data)) is not None:
        raise ConfigError(f"{path}: not TOML ({problem})")
    return data


# -- a study's profile file ------------------------------------------------------------------------------------------
def read_profiles(path: Path, settable: tuple[str, ...], build: Callable[[Entry, str, dict[str, Any]], P],
                  default_needed: bool = True,
                  own: tuple[str, ...] = ()) -> tuple[dict[str, P], dict[str, str], Any]:  # fmt: skip
    """A study's profile file (scenario1.toml, scenario2.toml, protocol.toml, or a file of one's own in their
    format): its `default`
    (the profile run when none is named; a file of one's own may leave it out: not `default_needed`), `[shared.NAME]`
    tables of settings, and `[profiles.NAME]` tables, each with `help` (what --help says of it), optionally `use`
    (the shared table it starts from) and settings out of `settable` (or `own`, which a shared table does not hold).
    `build(entry, name, settings)` types and checks one profile's settings (its shared table's, its own over them)
    and makes it. Returns the profiles, their help and the default as the file gives it (or None); one ConfigError
    naming the file and the entry for an unknown key, `use` or default."""
    data = dict(read_toml(path))
    shared, tables, default = data.pop("shared", {}), data.pop("profiles", None), data.pop("default", None)
    if data or tables is None:  # the keys it has named before a missing [profiles] (issue 82, probe 13, F19)
        raise ConfigError(f"{path}: {_top_level_problem(list(data), tables is None)}")
    for key, table in (("shared", shared), ("profiles", tables)):
        if not isinstance(table, dict):
            raise Entry(path, key).error(f"must be a table, got {table!r}")
    profiles, helps = {}, {}
    for name, entry in tables.items():
        at = Entry(path, f"profiles.{name}")
        entry = dict(at.table(entry, "the profile", ("help", "use", *own, *settable)))
        if (use := entry.pop("use", None)) is not None and (not isinstance(use, str) or use not in shared):
            raise at.error(f"use must name a [shared.NAME] table ({', '.join(shared) or 'none'}), got {use!r}")
        base = Entry(path, f"shared.{use}").table(shared[use], "the shared table", settable) if use else {}
        helps[name] = at.value("help", entry.pop("help", ""), str)
        profiles[name] = build(at, name, {**base, **entry})
    if (default_needed or default is not None) and (not isinstance(default, str) or default not in profiles):
        raise ConfigError(f"{path}: default must name one of its profiles ({', '.join(profiles)}), got {default!r}")
    return profiles, helps, default


def _top_level_problem(unknown: list[str], no_profiles: bool) -> str:
    """Why a profile file's top level is not one (after its path): the keys it has that no profile file holds, the
    ones it may hold, and, without [profiles], the format it needs (an old-format file, `current = "mine"` and a
    `[mine]` table, or a file holding `x = 1`, was "[profiles] must be a table, got None", naming nothing)."""
    known = "default, shared, profiles"
    text = f"unknown top-level keys {', '.join(map(repr, unknown))[:200]} (known: {known})" if unknown else ""
    if no_profiles:
        text += ("; " if text else "") + ("no [profiles] table: a profile file holds each profile as a "
                                          "[profiles.NAME] table (with `default = NAME` naming the one run when none "
                                          "is named; the format before 2026-12-04 had `current` and a [NAME] table)")
    return text


# -- a profile of one's own --------------------------------------------------------------------------
OWN_PROFILE = "PATH.toml or PATH.toml:NAME"
"""how --profile names a profile in a file of one's own"""


def profile_file(text: str) -> tuple[Path, str | None] | None:
    """(file, profile name or None) when --profile's `text` names a file of one's own (PATH.toml, PATH.toml:NAME),
    else None (a packaged profile's name)."""
    if text.endswith(".toml"):
        return Path(text), None
    head, sep, name = text.rpartition(".toml:")
    return (Path(head + ".toml"), name) if sep and head else None


def profile_arg(known: Collection[str]) -> Callable[[str], str]:
    """The `type=` of a study's --profile: one of `known` (the packaged profiles) or a file of one's own
    (profile_file), read later by own_profile; anything else is refused naming both forms."""

    def parse(text: str) -> str:
        if text in known or profile_file(text) is not None:
            return text
        raise argparse.ArgumentTypeError(f"invalid choice: {text!r} (choose from {', '.join(known)}, or a profile "
                                         f"file of your own: {OWN_PROFILE})")  # fmt: skip

    parse.__name__ = "profile"
    return parse


def own_profile(text: str, read: Callable[[Path], tuple[Mapping[str, P], str | None]], packaged: Collection[str],
                default_key: str | None = None) -> P:  # fmt: skip
    """The profile --profile PATH.toml[:NAME] names, read by `read` (the study's loader, which checks every profile of
    the file as it checks the packaged ones, and gives the file's `default_key`, or None): NAME, else the file's
    only profile, else the one its `default_key` names; UsageError naming the file otherwise (the profiles it holds
    listed), and for a profile that takes a packaged profile's name (it would share that profile's results folder
    and records)."""
    where = profile_file(text)
    assert where is not None, text
    path, name = where
    if (kind := not_regular(path)) not in (None, "a folder"):  # a named pipe was "no file" (issue 82, fifth probe)
        raise UsageError(f"--profile {text}: {path} is not a regular file but {kind}")
    if not path.is_file():
        raise UsageError(f"--profile {text}: no file {path}" + (" (it is a folder)" if path.is_dir() else ""))
    profiles, default = read(path)
    if not profiles:
        raise UsageError(f"--profile {text}: {path} holds no profile")
    if name is None:
        if len(profiles) > 1 and default is None:
            unset = f" and no {default_key}" if default_key else ""
            raise UsageError(f"--profile {text}: {path} holds {len(profiles)} profiles ({', '.join(profiles)}){unset}; "
                             f"name one: --profile {path}:NAME")  # fmt: skip
        name = default if default is not None else next(iter(profiles))
    if name not in profiles:
        raise UsageError(f"--profile {text}: {path} has no profile {name!r} (it has {', '.join(profiles)})")
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}", name) or ".." in name:
        raise UsageError(f"--profile {text}: {path}'s profile name {name!r} must be 1-64 letters, digits, '_', '-' or "
                         "'.' (it names the results folder)")  # fmt: skip
    if name in packaged:
        raise UsageError(f"--profile {text}: {path}'s profile {name!r} takes the name of a packaged profile; name it "
                         "otherwise (the name chooses its results folder and its records)")  # fmt: skip
    return profiles[name]


# -- a study's flags, from its plan's fields -------------------------------------------------------------------
@dataclass(frozen=True)
class PlanFlag:
    """A command-line flag that sets fields of a study's plan, as train's flags set DQNConfig's: its names (the flag
    and its aliases), what its value sets (`apply`: the parsed value and the plan so far -> the fields it gives,
    checked, UsageError otherwise), what --help says of it, and how a profile's value shows as --help's default
    (`shown`; None: `text` says the default itself). kind: argparse's type= (None: the text as given); dest: the
    namespace's name (None: argparse's, from the first name); choices: argparse's."""

    names: tuple[str, ...]
    apply: Callable[[Any, Any], dict[str, Any]]
    text: str
    shown: Callable[[Any], Any] | None = None
    kind: Callable[[str], Any] | None = None
    dest: str | None = None
    choices: Sequence[str] | None = None


def by_profile(profiles: Mapping[str, Any], show: Callable[[Any], Any]) -> str:
    """A flag's default as --help states it, from the packaged profiles: "the profile's: tiny 2; full 5; paper 10",
    or one value when every profile gives the same."""
    values = {name: str(show(profile)) for name, profile in profiles.items()}
    if len(set(values.values())) == 1:
        return next(iter(values.values()))
    return "the profile's: " + "; ".join(f"{name} {value}" for name, value in values.items())


def numbers(values: Sequence[float]) -> str:
    """A list of numbers as a list flag takes it: 0,0.25,1."""
    return ",".join(f"{x:g}" for x in values)


def add_plan_flags(parser: Any, flags: Sequence[PlanFlag], profiles: Mapping[str, Any]) -> None:
    """One option per PlanFlag, unset (None) unless given, its help ending in the profiles' defaults."""
    for flag in flags:
        text = flag.text if flag.shown is None else f"{flag.text} (default: {by_profile(profiles, flag.shown)})"
        more = {"dest": flag.dest} if flag.dest else {}
        parser.add_argument(*flag.names, type=flag.kind, choices=flag.choices, default=None, help=text, **more)


def plan_from_flags(plan: P, args: Any, flags: Sequence[PlanFlag]) -> P:
    """`plan` with every given flag's fields set, in the flags' order (a flag may read what an earlier one set)."""
    for flag in flags:
        dest = flag.dest or flag.names[0].removeprefix("--").replace("-", "_")
        if (value := getattr(args, dest)) is not None:
            plan = replace(plan, **flag.apply(value, plan))  # type: ignore[type-var]
    return plan


def at_least(field: str, name: str, least: int = 1, bound: str = "") -> Callable[[int, Any], dict[str, Any]]:
    """A PlanFlag's apply for a count: `field` set to it; below `least` "NAME must be BOUND, got V" (BOUND: ">= least"
    unless given)."""

    def apply(value: int, _plan: Any) -> dict[str, Any]:
        if value < least:
            raise UsageError(f"{name} must be {bound or f'>= {least}'}, got {value}")
        return {field: value}

    return apply


# -- the learner catalogue (learners.toml): every learner a study may name, one name one learner ------------------
LEARNERS_FILE = DATA / "learners.toml"
STATUSES = ("default", "current", "tried", "retired")
"""a learner's status (learners.toml says what each means)"""
WEIGHTS = ("model.pt", "model_last.pt")
KEYS = ("parent", "preset", "status", "why", "learner", "drive", "weights", "steps_factor")


@dataclass(frozen=True)
class Learner:
    """A learner as judged: the training (its learner settings) and the weights that drive."""

    name: str
    text: str
    """what it is and why it is judged (learners.toml's `why`; the reports' words)"""
    learner: DQNConfig
    weights: str = "model.pt"
    margin: float | None = None
    """the change margin it drives with (Q units; None: the learner's own); the trainings are the same"""
    noreturn: float | None = None
    """how long after a lane change it does not choose the change back (s; None: no such rule)"""
    restart: float | None = None
    """the speed below which it withholds 'none' (m/s; None: the learner's own)"""
    queue: float | None = None
    """the speed below which it chooses no lane change (m/s; None: none)"""
    steps_factor: int = 1
    """the protocol trains it this many times its profile's steps"""

    def drive(self) -> dict[str, float]:
        """How it drives its trainings otherwise (a cell's config.drive; empty: as saved)."""
        return {key: getattr(self, field) for field, key, _ in DRIVES if getattr(self, field) is not None}


def load_learners(path: Path = LEARNERS_FILE) -> dict[str, Learner]:
    """Every learner of a learners.toml, in the file's order, each its parent with its own changes; one ConfigError
    naming the file and the entry for an unknown field, parent or status, a cycle of parents, or a value the learner
    refuses."""
    data = read_toml(path)
    for name, entry in data.items():
        _check_entry(Entry(path, name), name, entry, data)
    learner_hints = get_type_hints(DQNConfig)
    drive_hints = {key: get_type_hints(Learner)[field] for field, key, _ in DRIVES}
    built: dict[str, Learner] = {}

    def build(name: str, below: tuple[str, ...]) -> Learner:
        if name in below:
            raise Entry(path, name).error(f"is its own ancestor: {' -> '.join((*below[below.index(name):], name))}")
        if name not in built:
            entry, at = data[name], Entry(path, name)
            base = build(entry["parent"], (*below, name)) if "parent" in entry else \
                Learner(entry["preset"], "", DQN_PRESETS[entry["preset"]])
            changes = {k: at.value(f"learner.{k}", v, learner_hints[k]) for k, v in entry.get("learner", {}).items()}
            drives = {field: at.value(f"drive.{key}", entry["drive"][key], drive_hints[key])
                      for field, key, _ in DRIVES if key in entry.get("drive", {})}  # fmt: skip
            try:
                learner = replace(base.learner, **changes)
                learner.validate()
            except ConfigError as err:
                raise at.error(f"learner: {err}") from None
            built[name] = replace(base, name=name, text=entry["why"], learner=learner,
                                  weights=entry.get("weights", base.weights), **drives,
                                  steps_factor=_steps_factor(at, entry))  # fmt: skip
        return built[name]

    for name in data:
        build(name, ())
    defaults = [name for name, entry in data.items() if entry["status"] == "default"]
    if len(defaults) != 1:
        raise ConfigError(f"{path}: exactly one learner has status 'default' (today's default learner), got "
                          f"{len(defaults)}: {', '.join(defaults) or 'none'}")  # fmt: skip
    if built[defaults[0]].learner != DQN_PRESETS["default"] or built[defaults[0]].drive():
        raise Entry(path, defaults[0]).error("has status 'default' but is not the default preset (DQNConfig())")
    return {name: built[name] for name in data}


def _check_entry(at: Entry, name: str, entry: Any, data: dict[str, Any]) -> None:
    """One table of the file: its keys, its parent or preset, status, why and weights (its values: build)."""
    at.table(entry, "a learner", KEYS)
    if ("parent" in entry) == ("preset" in entry):
        raise at.error("needs a parent (a learner here) or a preset (one of config.DQN_PRESETS), not both")
    for key in ("parent" if "parent" in entry else "preset", "status", "why"):
        if not isinstance(entry.get(key), str) or not entry[key]:
            raise at.error(f"needs {key} (a string), got {entry.get(key)!r}")
    if entry.get("parent", name) not in data:
        raise at.error(f"unknown parent {entry['parent']!r} (a learner here: {', '.join(data)})")
    if entry.get("preset", "default") not in DQN_PRESETS:
        raise at.error(f"unknown preset {entry['preset']!r} (one of {', '.join(DQN_PRESETS)})")
    if entry["status"] not in STATUSES:
        raise at.error(f"unknown status {entry['status']!r} (one of {', '.join(STATUSES)})")
    if entry.get("weights", WEIGHTS[0]) not in WEIGHTS:
        raise at.error(f"weights must be one of {', '.join(WEIGHTS)}, got {entry['weights']!r}")
    at.table(entry.get("learner", {}), "learner", tuple(get_type_hints(DQNConfig)))
    at.table(entry.get("drive", {}), "drive", tuple(key for _, key, _ in DRIVES))


def _steps_factor(at: Entry, entry: dict[str, Any]) -> int:
    factor = int(at.value("steps_factor", entry.get("steps_factor", 1), int))
    if factor < 1:
        raise at.error(f"steps_factor must be at least 1, got {factor}")
    return factor


LEARNERS = load_learners()
"""the packaged catalogue (learners.toml), in its order"""
