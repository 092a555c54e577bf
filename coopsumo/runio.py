"""Run folders, versions, JSON output and one-line command-line errors."""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any, NoReturn

USAGE_EXIT = 2


class UsageError(ValueError):
    """Bad input from the user: reported in one line, exit code 2."""


def package_version(name: str) -> str:
    try:
        return version(name)
    except PackageNotFoundError:
        return "not installed"


def versions() -> dict[str, str]:
    """Versions of everything that shapes a result."""
    return {
        "coopsumo": package_version("coopsumo"),
        "sumo": package_version("eclipse-sumo"),
        "libsumo": package_version("libsumo"),
        "torch": package_version("torch"),
        "numpy": package_version("numpy"),
        "python": platform.python_version(),
    }


def _clean(obj: Any) -> Any:
    """JSON-safe copy: NaN/inf become None."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    return obj


def write_json(path: Path, data: Any) -> None:
    """Write JSON atomically (temp file + rename)."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(_clean(data), indent=2, sort_keys=True) + "\n")
    os.replace(tmp, path)


def start_run_dir(out: Path) -> Path:
    """A fresh temporary folder beside `out`; results appear in `out` only when finish_run_dir is called.

    Raises UsageError if `out` cannot be written or holds something that is not a run folder.
    """
    out = out.resolve()
    if out.exists() and not out.is_dir():
        raise UsageError(f"output folder {out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not (out / "config.json").exists():
        raise UsageError(f"output folder {out} is not empty and is not a coopsumo run folder")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    except OSError as err:
        raise UsageError(f"cannot write output folder {out}: {err.strerror}") from None


def finish_run_dir(tmp: Path, out: Path) -> None:
    """Move the finished run into place, replacing an earlier run in the same folder."""
    out = out.resolve()
    if out.exists():
        shutil.rmtree(out)
    os.replace(tmp, out)


def discard_run_dir(tmp: Path) -> None:
    shutil.rmtree(tmp, ignore_errors=True)


@contextmanager
def atomic_run_dir(out: Path) -> Iterator[Path]:
    """A temporary run folder (start_run_dir) moved into `out` when the block ends normally and removed when
    it raises, so a failed or killed run never leaves a half-written `out`."""
    tmp = start_run_dir(out)
    try:
        yield tmp
    except BaseException:
        discard_run_dir(tmp)
        raise
    finish_run_dir(tmp, out)


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors and exit code 2."""

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(USAGE_EXIT)


def _watch_parent(parent_pid: int) -> None:
    while True:
        time.sleep(1.0)
        if os.getppid() != parent_pid:
            os._exit(3)


def start_parent_watch(parent_pid: int) -> None:
    """In a pool worker: exit when the main process `parent_pid` is gone (no orphan keeps working)."""
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True, name="watch-parent").start()


def run_cli(prog: str, body: Callable[[], int]) -> int:
    """Run a command's body; usage errors (config.ConfigError among them) become one line on stderr and exit code 2."""
    try:
        return body()
    except UsageError as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        return USAGE_EXIT
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
