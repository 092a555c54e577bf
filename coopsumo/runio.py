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


RUN_MARKER = ".coopsumo-run.json"
"""Written by a command into every folder it owns: {"kind": command, "version": coopsumo's, "files": the
folder's entries when it finished (null while a training runs)}. A dot-file, so listings stay as they were;
named after the package, so no user's file is taken for it; a separate file, because config.json is a
common name that proves nothing about who wrote a folder."""


def _entries(folder: Path) -> list[str]:
    """Every file and folder under `folder` (relative, '/'-separated), the marker left out."""
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p != folder / RUN_MARKER)


def mark_run_dir(folder: Path, kind: str, finished: bool = True) -> None:
    """Claim `folder` for the command `kind`; finished: also list what it holds (nothing else may be replaced)."""
    write_json(folder / RUN_MARKER, {"kind": kind, "version": package_version("coopsumo"),
                                     "files": _entries(folder) if finished else None})  # fmt: skip


def _marker(folder: Path) -> dict[str, Any] | None:
    try:
        data = json.loads((folder / RUN_MARKER).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and isinstance(data.get("kind"), str) else None


def check_run_dir(out: Path, kind: str) -> None:
    """UsageError unless `out` is missing, empty, or a folder the command `kind` wrote and nobody added to.

    The ownership rule: an existing non-empty folder is written into or replaced only when its marker names
    the same command and every entry in it is one the marker lists (a training's marker lists none until
    the training has finished: it only overwrites its own file names).
    """
    out = out.resolve()
    if not out.exists():
        return
    if not out.is_dir():
        raise UsageError(f"output folder {out} exists and is not a folder")
    if not any(out.iterdir()):
        return
    marker = _marker(out)
    if marker is None:
        if (out / "config.json").exists():
            raise UsageError(f"output folder {out} has no {RUN_MARKER} (written before coopsumo marked its folders, "
                             "or not by coopsumo) and is left alone: remove it yourself or pick another --out")
        raise UsageError(f"output folder {out} is not empty and is not a coopsumo run folder; pick another --out")
    if marker["kind"] != kind:
        raise UsageError(f"output folder {out} holds a coopsumo {marker['kind']} run, not a {kind} run, and is "
                         "left alone; pick another --out")  # fmt: skip
    listed = marker.get("files")
    if isinstance(listed, list):
        extra = sorted(set(_entries(out)) - set(listed))
        if extra:
            more = f" and {len(extra) - 1} more" if len(extra) > 1 else ""
            raise UsageError(f"output folder {out} holds {extra[0]}{more}, which coopsumo {kind} did not write, and "
                             "is left alone; move it away or pick another --out")  # fmt: skip


def check_apart(out: Path, model: Path) -> None:
    """UsageError when `out` is the folder `model` is read from or holds it (it would be replaced), or lies
    inside it while that folder is a run folder (a training's: marker or config.json). A loose model file
    in a plain folder (the current one, say) does not forbid run folders beneath it."""
    o, m = out.resolve(), model.resolve().parent
    run_folder = (m / RUN_MARKER).exists() or (m / "config.json").exists()
    if o == m or m.is_relative_to(o) or (run_folder and o.is_relative_to(m)):
        raise UsageError(f"--out {out} would write into or replace {m}, the folder the model is read from; "
                         "pick another --out")  # fmt: skip


def start_run_dir(out: Path, kind: str = "simulate") -> Path:
    """A fresh temporary folder beside `out`; results appear in `out` only when finish_run_dir is called.

    Raises UsageError if `out` cannot be written or is not ours to replace (check_run_dir).
    """
    out = out.resolve()
    check_run_dir(out, kind)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    except OSError as err:
        raise UsageError(f"cannot write output folder {out}: {err.strerror}") from None


def finish_run_dir(tmp: Path, out: Path, kind: str = "simulate") -> None:
    """Mark the finished run and move it into place, replacing an earlier run of `kind` in the same folder.

    The earlier folder is removed only if it is still ours by check_run_dir (marker of `kind`, nothing
    added); else the new run is discarded and UsageError raised.
    """
    out = out.resolve()
    mark_run_dir(tmp, kind)
    if out.exists():
        try:
            check_run_dir(out, kind)
        except UsageError:
            discard_run_dir(tmp)
            raise
        shutil.rmtree(out)
    os.replace(tmp, out)


def discard_run_dir(tmp: Path) -> None:
    shutil.rmtree(tmp, ignore_errors=True)


@contextmanager
def atomic_run_dir(out: Path, kind: str = "simulate") -> Iterator[Path]:
    """A temporary run folder (start_run_dir) moved into `out` when the block ends normally and removed when
    it raises, so a failed or killed run never leaves a half-written `out`."""
    tmp = start_run_dir(out, kind)
    try:
        yield tmp
    except BaseException:
        discard_run_dir(tmp)
        raise
    finish_run_dir(tmp, out, kind)


class DefaultsHelpFormatter(argparse.HelpFormatter):
    """--help gives every option's default: "(default: X)" is added unless the help text already says what the
    default is (an option whose default is None must say so in its text) or the option is an on/off flag."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if "default" in text.lower() or action.default in (None, argparse.SUPPRESS) or action.nargs == 0:
            return text
        return f"{text} (default: %(default)s)".lstrip()


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors, exit code 2, and every default in --help."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", DefaultsHelpFormatter)
        super().__init__(*args, **kwargs)

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
