"""The catalogue reader: the experiments' data files (coopsumo/experiments_data/*.toml, inside the package so that an
installed wheel has them too) read and checked, every error one ConfigError line naming the file and the entry; a
value checked by the very rule its flag is (validation.IntRule, NumberRule, ListRule, names_problem); a study's profile
file (read_profiles: scenario1.toml, scenario2.toml); and a study's profile taken from a file of one's own
(`--profile PATH.toml[:NAME]`, own_profile)."""

from __future__ import annotations

import argparse
import math
import re
import tomllib
import types
from collections.abc import Callable, Collection, Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol, TypeVar, Union, get_args, get_origin

from coopsumo.errors import ConfigError, UsageError
from coopsumo.field_rules import as_float, shown
from coopsumo.files import MAX_JSON_DEPTH, depth_problem, not_regular, open_regular
from coopsumo.validation import names_problem

DATA = Path(__file__).resolve().parents[2] / "experiments_data"
"""the folder of the experiments' data files"""
P = TypeVar("P")


class Rule(Protocol):
    """A field's rule, shared with its flag (validation.IntRule, NumberRule, ListRule): why a value breaks it, in words
    after the field's name, or None."""

    def problem(self, value: Any) -> str | None: ...


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
        typed = self._typed(key, value, hint)
        if rule is not None and (problem := rule.problem(value)):
            raise self.error(f"{key} {problem}")
        return typed

    def names(self, key: str, value: Any, known: Sequence[str], least: int = 1) -> tuple[str, ...]:
        """A list of names out of `known` (variants, policies), by its flag's rule (validation.names_problem)."""
        names: tuple[str, ...] = self._typed(key, value, tuple[str, ...])
        if problem := names_problem(names, known, least):
            raise self.error(f"{key} {problem}")
        return names

    def _typed(self, key: str, value: Any, hint: Any) -> Any:
        origin, args = get_origin(hint), get_args(hint)
        if origin in (Union, types.UnionType):
            return self._typed(key, value, next(a for a in args if a is not type(None)))
        if origin is tuple:
            any_length = args[-1] is Ellipsis
            if not isinstance(value, list) or not (any_length or len(value) == len(args)):
                raise self.error(f"{key} must be a list{'' if any_length else f' of {len(args)}'}, got {value!r}")
            items = [args[0]] * len(value) if any_length else list(args)
            return tuple(self._typed(key, v, a) for v, a in zip(value, items, strict=True))
        if hint is float and isinstance(value, int | float) and not isinstance(value, bool):
            if isinstance(value, int) and math.isinf(as_float(value)):  # 400 digits: no float holds it
                raise self.error(f"{key} must be a finite number, got {shown(value)}")
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
            data = tomllib.load(f)
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
                  default_needed: bool = True, own: tuple[str, ...] = ()) -> tuple[dict[str, P], dict[str, str], Any]:
    """A study's profile file (scenario1.toml, scenario2.toml, or a file of one's own in their format): its `default`
    (the profile run when none is named; a file of one's own may leave it out: not `default_needed`), `[shared.NAME]`
    tables of settings, and `[profiles.NAME]` tables, each with `help` (what --help says of it), optionally `use`
    (the shared table it starts from) and settings out of `settable` (or `own`, which a shared table does not hold).
    `build(entry, name, settings)` types and checks one profile's settings (its shared table's, its own over them)
    and makes it. Returns the profiles, their help and the default as the file gives it (or None); one ConfigError
    naming the file and the entry for an unknown key, `use` or default."""
    data = dict(read_toml(path))
    shared, tables, default = data.pop("shared", {}), data.pop("profiles", None), data.pop("default", None)
    for key, table in (("shared", shared), ("profiles", tables)):
        if not isinstance(table, dict):
            raise Entry(path, key).error(f"must be a table, got {table!r}")
    if data:
        raise ConfigError(f"{path}: unknown top-level keys {', '.join(map(repr, data))} (known: default, shared, "
                          "profiles)")  # fmt: skip
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
