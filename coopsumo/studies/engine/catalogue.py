"""The catalogue reader: the experiments' data files (coopsumo/experiments_data/*.toml, inside the package so that an
installed wheel has them too) read and checked, every error one ConfigError line naming the file and the entry."""

from __future__ import annotations

import tomllib
import types
from pathlib import Path
from typing import Any, Union, get_args, get_origin

from coopsumo.errors import ConfigError

DATA = Path(__file__).resolve().parents[2] / "experiments_data"
"""the folder of the experiments' data files"""


class Entry:
    """Errors about one entry of one file: `<file>: [<entry>] <what is wrong>`."""

    def __init__(self, path: Path, name: str) -> None:
        self.where = f"{path}: [{name}]"

    def error(self, text: str) -> ConfigError:
        return ConfigError(f"{self.where} {text}")

    def value(self, key: str, value: Any, hint: Any) -> Any:
        """`value` as the type `hint` names (bool, int, float, str, tuple[X, ...], tuple[X, Y, Z], X | None): an
        integer where a float belongs becomes one (a learner's identity is its JSON); anything else is an error."""
        origin, args = get_origin(hint), get_args(hint)
        if origin in (Union, types.UnionType):
            return self.value(key, value, next(a for a in args if a is not type(None)))
        if origin is tuple:
            any_length = args[-1] is Ellipsis
            if not isinstance(value, list) or not (any_length or len(value) == len(args)):
                raise self.error(f"{key} must be a list{'' if any_length else f' of {len(args)}'}, got {value!r}")
            items = [args[0]] * len(value) if any_length else list(args)
            return tuple(self.value(key, v, a) for v, a in zip(value, items, strict=True))
        if hint is float and isinstance(value, int | float) and not isinstance(value, bool):
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
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except OSError as err:
        raise ConfigError(f"{path}: cannot read it ({err.strerror})") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not TOML ({err})") from None



