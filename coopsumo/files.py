"""Files written whole or not at all (a temporary file renamed into place), JSON out and in, file digests."""

from __future__ import annotations

import hashlib
import json
import math
import os
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


def temporary_of(path: Path) -> Path:
    """The temporary file write_atomic writes `path` through: 'PATH.tmp' (left behind only by a SIGKILL)."""
    return path.with_name(path.name + ".tmp")


def write_atomic(path: Path, write: Callable[[Path], Any]) -> None:
    """write(tmp) into 'PATH.tmp', then rename it to `path`: a reader sees the old file or the whole new one.
    On any failure (a full disk, a kill by signal) the temporary file is removed and the error passed on."""
    tmp = temporary_of(path)
    try:
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


def read_json_object(path: Path) -> dict[str, Any] | None:
    """The JSON object in the file `path`; None when it is missing, unreadable, not JSON or not an object."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None

