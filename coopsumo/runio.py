"""Run folders, versions, JSON output and one-line command-line errors."""

from __future__ import annotations

import argparse
import errno
import fcntl
import fnmatch
import hashlib
import json
import math
import os
import platform
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from functools import cache
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any, NoReturn

from coopsumo.paths import NETS_ENV as NETS_ENV  # re-exported: sim.network and cli read it from here
from coopsumo.paths import env_problem, nets_in_out_problem, out_path_problem, outside_link

USAGE_EXIT = 2


class UsageError(ValueError):
    """Bad input from the user: reported in one line, exit code 2."""


def package_version(name: str) -> str:
    try:
        return version(name)
    except PackageNotFoundError:
        return "not installed"


@cache
def source_revision() -> str:
    """The git commit of the coopsumo source this process runs, with '-dirty' when tracked files differ from it;
    'unknown' outside a git checkout (an installed wheel). Read-only: git takes no lock and writes no index."""
    root = str(Path(__file__).resolve().parent.parent)
    env = {**os.environ, "GIT_OPTIONAL_LOCKS": "0"}
    try:
        head = subprocess.run(["git", "-C", root, "rev-parse", "--short=12", "HEAD"], capture_output=True, text=True,
                              timeout=20, env=env)  # fmt: skip
        if head.returncode != 0 or not head.stdout.strip():
            return "unknown"
        status = subprocess.run(["git", "-C", root, "status", "--porcelain", "--untracked-files=no"],
                                capture_output=True, text=True, timeout=20, env=env)  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return head.stdout.strip() + ("-dirty" if status.returncode != 0 or status.stdout.strip() else "")


def versions() -> dict[str, str]:
    """Versions of everything that shapes a result, with the source's git commit (source_revision)."""
    return {"coopsumo": package_version("coopsumo"), "coopsumo_source": source_revision(),
            "sumo": package_version("eclipse-sumo"), "libsumo": package_version("libsumo"),
            "torch": package_version("torch"), "numpy": package_version("numpy"),
            "python": platform.python_version()}  # fmt: skip


def _clean(obj: Any) -> Any:
    """JSON-safe copy: NaN/inf become None."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    return obj


def first_line(err: BaseException) -> str:
    """The first line of an exception's message, or its type's name when the message is empty."""
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


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


def read_json_object(path: Path) -> dict[str, Any] | None:
    """The JSON object in the file `path`; None when it is missing, unreadable, not JSON or not an object."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _marker(folder: Path) -> dict[str, Any] | None:
    data = read_json_object(folder / RUN_MARKER)
    return data if data is not None and isinstance(data.get("kind"), str) else None


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
    if not isinstance(listed, list) and kind != "train":  # only a training marks its folder before it ends
        raise UsageError(f"output folder {out} has a {RUN_MARKER} that lists no files (damaged?) and is left "
                         "alone; remove it yourself or pick another --out")  # fmt: skip
    if isinstance(listed, list):
        extra = sorted(set(_entries(out)) - set(listed))
        if extra:
            more = f" and {len(extra) - 1} more" if len(extra) > 1 else ""
            raise UsageError(f"output folder {out} holds {extra[0]}{more}, which coopsumo {kind} did not write, and "
                             "is left alone; move it away or pick another --out")  # fmt: skip


def finished_run(folder: Path, kind: str) -> bool:
    """True when `folder` is a finished output of the command `kind`: its marker names `kind` and lists its
    entries (written when the command ended), and every listed entry is there."""
    marker = _marker(folder)
    listed = marker.get("files") if marker is not None and marker["kind"] == kind else None
    return isinstance(listed, list) and all(isinstance(f, str) and (folder / f).exists() for f in listed)


def check_study_root(root: Path, kind: str, own: Sequence[str]) -> None:
    """UsageError unless `root` is missing, empty, marked by the study `kind`, or (a root written before the
    marker) holds the study's plan file own[0] or only entries whose names match the study's own patterns `own`
    (fnmatch: 'fig*.png'; a study writes only these names and never replaces the root as a whole)."""
    root = root.resolve()
    if not root.exists():
        return
    if not root.is_dir():
        raise UsageError(f"output folder {root} exists and is not a folder")
    marker = _marker(root)
    if marker is not None:
        if marker["kind"] != kind:
            raise UsageError(f"output folder {root} holds a coopsumo {marker['kind']} run, not a {kind} study, and "
                             "is left alone; pick another --out")  # fmt: skip
        return
    if (root / own[0]).is_file():  # the study's own plan file: a root it wrote before markers existed
        return
    foreign = sorted(p.name for p in root.iterdir() if not any(fnmatch.fnmatchcase(p.name, pat) for pat in own))
    if foreign:
        more = f" and {len(foreign) - 1} more" if len(foreign) > 1 else ""
        raise UsageError(f"output folder {root} holds {foreign[0]}{more}, which coopsumo {kind} does not write, and "
                         f"has no {RUN_MARKER}: it is left alone; pick another --out")  # fmt: skip


@contextmanager
def study_root(root: Path, kind: str, own: Sequence[str]) -> Iterator[Path]:
    """Claim the study root `root` for the block: its path checked (check_out_path), its lock held (out_lock),
    ownership checked (check_study_root) and its marker written (unfinished: a study adds to it run by run)."""
    check_out_path(root)
    root = root.resolve()
    check_study_root(root, kind, own)
    with out_lock(root, kind):
        check_study_root(root, kind, own)  # again, under the lock
        try:
            root.mkdir(exist_ok=True)
            mark_run_dir(root, kind, finished=False)
        except OSError as err:
            raise UsageError(f"cannot write output folder {root}: {err.strerror}") from None
        yield root


# -- output paths ---------------------------------------------------------------------------------------
def check_out_path(out: Path, flag: str = "--out") -> None:
    """UsageError naming `flag` when out_path_problem faults `out` or $COOPSUMO_NETS_DIR lies in it
    (nets_in_out_problem): every command's --out and every study's root, given or default."""
    problem = out_path_problem(out) or nets_in_out_problem(out)
    if problem:
        raise UsageError(f"{flag} {problem}")


# -- locks and the partial folders of killed runs --------------------------------------------------------
PARTIAL = ".partial-"
"""infix of the temporary folder a run is built in beside its --out: '.<name>.partial-XXXXXXXX'"""
_PARTIAL_NAME = re.compile(r"\.(.+)\.partial-[A-Za-z0-9_]{8}")
_LOCK_NAME = re.compile(r"\.(.+)\.lock")


def lock_path(out: Path) -> Path:
    """The lock file of the output folder `out`: '.<name>.lock' beside it."""
    return out.parent / f".{out.name}.lock"


def _same_file(fd: int, path: Path) -> bool:
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return False
    own = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (own.st_dev, own.st_ino)


def try_lock(path: Path) -> int | None:
    """An open descriptor holding an exclusive flock on the lock file `path` (made if missing), or None when
    another process holds it. A file removed or replaced between opening and locking is opened again."""
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            held = _same_file(fd, path)
            os.close(fd)
            if held:
                return None
            continue
        if _same_file(fd, path):
            return fd
        os.close(fd)  # its holder removed it after we opened it: lock the file now at the path


def release_lock(fd: int, path: Path) -> None:
    """Remove the lock file (while still holding it) and release it."""
    path.unlink(missing_ok=True)
    os.close(fd)


def _holder(path: Path) -> str:
    try:
        text = path.read_text().strip()
    except OSError:
        return ""
    return f" ({text})" if text else ""


LOCK_WAIT_S = 1.0
"""how long a command waits for a held lock before it is refused (s): clear_partials holds another run's lock
only while it removes that run's partial folder; a command writing a folder holds it for the whole run"""


@contextmanager
def out_lock(out: Path, kind: str) -> Iterator[None]:
    """Hold the lock of the output folder `out` for the block (fcntl.flock on lock_path(out), removed after);
    UsageError in one line when another command holds it. Released by the kernel if the process is killed."""
    out = out.resolve()
    path = lock_path(out)
    deadline = time.monotonic() + LOCK_WAIT_S
    while True:
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            fd = try_lock(path)
        except OSError as err:
            raise UsageError(f"cannot write output folder {out}: {err.strerror}") from None
        if fd is not None or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    if fd is None:
        raise UsageError(f"another coopsumo command is writing {out}{_holder(path)}; wait for it to end or pick "
                         "another --out")  # fmt: skip
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{kind}, pid {os.getpid()}\n".encode())
        yield
    finally:
        release_lock(fd, path)


def _remove_partial(entry: Path, prog: str) -> None:
    shutil.rmtree(entry, ignore_errors=True)
    print(f"{prog}: removed {entry}, the partial folder of an interrupted run", file=sys.stderr)


def clear_partials(parent: Path, prog: str, mine: str | None = None) -> list[Path]:
    """Remove the partial folders and lock files that killed runs left in `parent` (one line on stderr per
    folder); those of runs still going (their lock is held) are left alone. mine: the name of the output
    folder whose lock the caller holds (its partial folders are removed, its lock file kept). Returns the
    folders removed."""
    removed: list[Path] = []
    try:
        entries = [p for p in parent.iterdir() if p.name.startswith(".")]
    except OSError:
        return removed
    for entry in entries:
        found = _PARTIAL_NAME.fullmatch(entry.name)
        is_partial = found is not None and entry.is_dir() and not entry.is_symlink()
        if not is_partial:
            found = _LOCK_NAME.fullmatch(entry.name) if entry.is_file() else None
        if found is None:
            continue
        name = found.group(1)
        if name == mine:
            if is_partial:
                _remove_partial(entry, prog)
                removed.append(entry)
            continue
        path = lock_path(parent / name)
        try:
            fd = try_lock(path)
        except OSError:
            continue
        if fd is None:
            continue  # its run is still going
        try:
            if is_partial and entry.exists():
                _remove_partial(entry, prog)
                removed.append(entry)
        finally:
            release_lock(fd, path)
    return removed


def check_no_outside_link(folder: Path) -> None:
    """UsageError naming the first link in `folder` that leads outside it (outside_link)."""
    if found := outside_link(folder):
        raise UsageError(f"{found[0]} is a link to {found[1]}, outside {folder.resolve()}: a command writes only "
                         "inside its own folder; remove the link or pick another --out")  # fmt: skip


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

    Raises UsageError if `out` cannot be written or is not ours to replace (check_run_dir). Partial folders
    that killed runs left in the same parent are removed first (clear_partials).
    """
    check_out_path(out)
    out = out.resolve()
    check_run_dir(out, kind)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        clear_partials(out.parent, kind, mine=out.name)
        return Path(tempfile.mkdtemp(prefix=f".{out.name}{PARTIAL}", dir=out.parent))
    except OSError as err:
        raise UsageError(f"cannot write output folder {out}: {err.strerror}") from None


def finish_run_dir(tmp: Path, out: Path, kind: str = "simulate") -> None:
    """Mark the finished run and move it into place, replacing an earlier run of `kind` in the same folder.

    The earlier folder is removed only if it is still ours by check_run_dir (marker of `kind`, nothing
    added); else the new run is discarded and UsageError raised.
    """
    out = out.resolve()
    mark_run_dir(tmp, kind)
    if not out.exists():
        os.replace(tmp, out)
        return
    try:
        check_run_dir(out, kind)
    except UsageError:
        discard_run_dir(tmp)
        raise
    # the old folder steps aside under a partial name (clear_partials removes it if a kill comes now), the new
    # one takes its place, then the old one goes: at every moment one whole result is on disk
    aside = Path(tempfile.mkdtemp(prefix=f".{out.name}{PARTIAL}", dir=out.parent))
    os.replace(out, aside / out.name)
    os.replace(tmp, out)
    shutil.rmtree(aside, ignore_errors=True)


def retrain_folder(out: Path) -> Path:
    """Where a new training into `out` is built while `out` holds a finished one: '.<name>.retrain' beside it
    (it replaces `out` when it has finished; `train --resume --out OUT` continues it after a kill)."""
    return out.parent / f".{out.name}.retrain"


def discard_run_dir(tmp: Path) -> None:
    shutil.rmtree(tmp, ignore_errors=True)


@contextmanager
def atomic_run_dir(out: Path, kind: str = "simulate") -> Iterator[Path]:
    """A temporary run folder (start_run_dir) moved into `out` when the block ends normally and removed when
    it raises, so a failed or killed run never leaves a half-written `out`; `out`'s lock is held throughout
    (out_lock: a second command writing to the same folder is refused)."""
    check_out_path(out)
    check_run_dir(out.resolve(), kind)  # before the lock's parent folder is made
    with out_lock(out, kind):
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


class Stop(KeyboardInterrupt):
    """SIGINT or SIGTERM received while stop_on_signals holds (a KeyboardInterrupt, so every handler of Ctrl-C
    takes it); signum: which one."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _raise_stop(signum: int, _frame: Any) -> None:
    raise Stop(signum)


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def stop_on_signals() -> Iterator[None]:
    """For the block, SIGINT and SIGTERM raise Stop wherever the command is, its setup included: also when the
    command was started with them ignored (a job a shell script put in the background ignores SIGINT, which was then
    lost until the training loop took it). Only in the main thread (elsewhere the block runs as it is)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.signal(s, _raise_stop) for s in STOP_SIGNALS}
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)


@contextmanager
def signals_deferred() -> Iterator[None]:
    """For the block (a few file operations that must happen together), SIGINT and SIGTERM wait: one that comes
    meanwhile is raised again right after it, to the handler that was in place. Only in the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    got: list[int] = []
    old = {s: signal.signal(s, lambda signum, _frame: got.append(signum)) for s in STOP_SIGNALS}
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
        if got:
            signal.raise_signal(got[0])


def working_folder_problem() -> str | None:
    """Why no command can run in the current folder (it was deleted: torch cannot even be imported there, and the
    studies' worker processes start in it), or None."""
    try:
        os.getcwd()
    except OSError:
        return "the current folder no longer exists (deleted?); change to an existing folder and run the command again"
    return None


def run_cli(prog: str, body: Callable[[], int]) -> int:
    """Run a command's body; usage errors (config.ConfigError among them) become one line on stderr and exit code 2,
    and so does a working folder that was deleted (working_folder_problem)."""
    if problem := working_folder_problem():
        print(f"{prog}: error: {problem}", file=sys.stderr)
        return USAGE_EXIT
    if problem := env_problem():  # $COOPSUMO_NETS_DIR, $COOPSUMO_MODELS
        print(f"{prog}: error: {problem}", file=sys.stderr)
        return USAGE_EXIT
    try:
        return body()
    except UsageError as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        return USAGE_EXIT
    except KeyboardInterrupt as err:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 128 + getattr(err, "signum", signal.SIGINT)
    except OSError as err:  # the system refused a file operation: one line naming the path and the problem
        print(f"{prog}: error: {os_error_text(err)}", file=sys.stderr)
        return USAGE_EXIT if err.errno in USER_ERRNOS else 1
    except RuntimeError as err:  # Python 3.11's Path.resolve reports a loop of symbolic links so; torch a failed write
        if "PytorchStreamWriter" in str(err) or "inline_container" in str(err):
            print(f"{prog}: error: writing a model or checkpoint failed (is the disk full?): {first_line(err)}",
                  file=sys.stderr)  # fmt: skip
            return 1
        if not str(err).startswith("Symlink loop from "):
            raise
        print(f"{prog}: error: {str(err)[len('Symlink loop from '):]} goes through a loop of symbolic links",
              file=sys.stderr)  # fmt: skip
        return USAGE_EXIT


USER_ERRNOS = frozenset({errno.ENAMETOOLONG, errno.ELOOP, errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOTDIR,
                         errno.EISDIR, errno.EEXIST, errno.ENOENT})  # fmt: skip
"""operating-system errors a path the user gave causes (exit code 2); the others (a full disk, an I/O error) 1"""


def os_error_text(err: OSError) -> str:
    """An OSError in one line: what the system said and the path(s) it concerns."""
    text = err.strerror or first_line(err)
    paths = [str(p) for p in (err.filename, err.filename2) if p is not None]
    return f"{text}: {' -> '.join(paths)}" if paths else text
