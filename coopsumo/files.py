"""Files written whole or not at all (a temporary file renamed into place), JSON out and in, file digests."""

from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any


def _clean(obj: Any) -> Any:
    """JSON-safe copy: NaN/inf become None."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    return obj


TEMPORARY = ".tmp"
"""suffix of the temporary file write_atomic writes a file through: '.NAME.XXXXXXXX.tmp' beside it"""


def temporaries_of(path: Path) -> list[Path]:
    """The temporary files write_atomic left beside `path` (a SIGKILL while it wrote): '.NAME.XXXXXXXX.tmp'."""
    try:
        names = [p for p in path.parent.iterdir() if p.name.startswith(f".{path.name}.")]
    except OSError:
        return []
    return [p for p in names if p.name.endswith(TEMPORARY) and len(p.name) == len(path.name) + 14 and p.is_file()
            and not p.is_symlink()]  # fmt: skip


def _umask() -> int:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    return 0o022


def write_atomic(path: Path, write: Callable[[Path], Any]) -> None:
    """write(tmp) into a temporary file beside `path` made new (mkstemp: a unique name, never an existing file or
    a link), then rename it to `path`: a reader sees the old file or the whole new one. On any failure (a full
    disk, a kill by signal) the temporary file is removed and the error passed on."""
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=TEMPORARY)
    tmp = Path(name)
    try:
        try:
            os.fchmod(fd, 0o666 & ~_umask())  # the mode a file written in place gets, not mkstemp's 0600
        finally:
            os.close(fd)
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def file_sha256(path: Path) -> str:
    """sha256 of a file's bytes (a model file: which weights a run was driven by)."""
    h = hashlib.sha256()
    with path.open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def write_json(path: Path, data: Any) -> None:
    """Write JSON atomically (write_atomic)."""
    text = json.dumps(_clean(data), indent=2, sort_keys=True) + "\n"
    write_atomic(path, lambda tmp: tmp.write_text(text))


MAX_JSON_DEPTH = 64  # no record of coopsumo nests deeper than a handful of levels


def depth_problem(data: Any) -> str | None:
    """Why `data` (parsed JSON or TOML) nests too deeply to be a record, or None; walked without recursion."""
    stack = [(data, 1)]
    while stack:
        value, depth = stack.pop()
        if depth > MAX_JSON_DEPTH:
            return f"nested deeper than {MAX_JSON_DEPTH} levels"
        children = value.values() if isinstance(value, dict) else value if isinstance(value, list) else ()
        stack.extend((child, depth + 1) for child in children if isinstance(child, dict | list))
    return None


def loads_json(text: str | bytes) -> Any:
    """json.loads for a record read back: text nested too deeply (json's decoder raises RecursionError for it,
    deeper code would later) is a ValueError, like any other text that is not JSON."""
    try:
        data = json.loads(text)
    except RecursionError:
        raise ValueError(f"not JSON: nested deeper than {MAX_JSON_DEPTH} levels") from None
    if (problem := depth_problem(data)) is not None:
        raise ValueError(f"not JSON: {problem}")
    return data


def read_json(path: Path) -> Any:
    """The JSON in the file `path` (loads_json): OSError when it cannot be read, ValueError when it is not JSON."""
    return loads_json(path.read_text())


def read_json_object(path: Path) -> dict[str, Any] | None:
    """The JSON object in the file `path`; None when it is missing, unreadable, not JSON or not an object."""
    try:
        data = read_json(path)
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None

