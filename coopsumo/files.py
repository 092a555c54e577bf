"""Files written whole or not at all (a temporary file renamed into place), records read back only from regular
files (open_regular), JSON out and in, file digests."""

from __future__ import annotations

import errno
import fnmatch
import hashlib
import json
import math
import os
import re
import signal
import stat
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, BinaryIO

from coopsumo.errors import NotRegularFileError


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


def left_temporaries(folder: Path, own: Sequence[str]) -> list[Path]:
    """The temporary files write_atomic left in `folder` (a SIGKILL while it wrote) of files whose names match one of
    the fnmatch patterns `own`: '.NAME.XXXXXXXX.tmp' (temporaries_of)."""
    try:
        entries = list(folder.iterdir())
    except OSError:
        return []
    pattern = re.compile(r"\.(.+)\.[A-Za-z0-9_]{8}" + re.escape(TEMPORARY))
    return [p for p in entries if (m := pattern.fullmatch(p.name)) and p.is_file() and not p.is_symlink()
            and any(fnmatch.fnmatchcase(m[1], pat) for pat in own)]  # fmt: skip


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
    disk, a kill by signal) the temporary file is removed and the error passed on. One a SIGKILL left stays: a file
    of that name may be a user's (issue 82, probe 8, J23); a study clears its own root's (left_temporaries)."""
    _write_beside(path, write, os.replace)


def write_new(path: Path, write: Callable[[Path], Any]) -> None:
    """write(tmp) as write_atomic does, then link it at `path` only if no file is there (os.link refuses a name taken,
    even one taken since a check: FileExistsError), never over one; the temporary file removed either way. For an
    output that must be a new file (sumo-gui's screenshot: issue 82, probe 15, D1)."""
    _write_beside(path, write, os.link)


Stamp = tuple[int, int, int, int]
"""what tells one file from another or from itself changed: (device, inode, size, modification time in ns)"""


def stamp(path: Path) -> Stamp:
    """The Stamp of the file at `path` (links followed)."""
    st = os.stat(path)
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns


def write_over(path: Path, write: Callable[[Path], Any], checked: Stamp) -> None:
    """write(tmp) as write_atomic does, then rename it over `path` only while the file there is the one stamped
    `checked` (stamp) when it was judged ours to replace: FileExistsError if it was changed, replaced or removed since
    (a user's note added to it: issue 82, probe 16, D1); the temporary file removed either way."""

    def place(tmp: Path, path: Path) -> None:
        try:
            now = stamp(path)
        except FileNotFoundError:
            now = None
        if now != checked:
            raise FileExistsError(f"{path} changed since it was checked")
        os.replace(tmp, path)

    _write_beside(path, write, place)


_WRITES = threading.Condition()
_ACTIVE = [0]
"""how many writes through a temporary file run in this process (their temporaries exist): exit_between_writes waits
for none"""


@contextmanager
def _write_running() -> Iterator[None]:
    with _WRITES:
        _ACTIVE[0] += 1
    try:
        yield
    finally:
        with _WRITES:
            _ACTIVE[0] -= 1
            _WRITES.notify_all()


def exit_between_writes(code: int) -> None:
    """End the process now (os._exit), from a thread other than the writing one, but never while a write of this
    module has a temporary file on disk: it waits for the running ones to end, and no new one starts. A study's worker
    whose main process was gone ended with os._exit while it wrote a stored model's model.pt, which left
    '.model.pt.XXXXXXXX.tmp' in the store (test_scenario2's interrupted sweep, once on a clean clone)."""
    with _WRITES:
        _WRITES.wait_for(lambda: _ACTIVE[0] == 0)
        os._exit(code)


def end_if_forked(pid: int, then: str) -> None:
    """End this process at once (os._exit, one line on stderr ending with `then`) when it is not `pid` but a copy that
    code the process ran forked (a policy of one's own) and that came back into the run: it would drive a second copy
    of the run's SUMO and finish or discard the run's folder too, racing the run itself (issue 82, probes 19 and 20,
    TR1: every loop interval twice in a run marked finished, a run folder gone after exit 0). A child that
    multiprocessing's fork started never comes back into the run."""
    if os.getpid() != pid:
        print(f"coopsumo: process {os.getpid()}, a copy of process {pid} forked by code the run ran, ends here {then}",
              file=sys.stderr, flush=True)  # fmt: skip
        os._exit(2)


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""the signals that stop a command (runio.Stop) or, left at their default, end a worker process at once"""


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


def _write_beside(path: Path, write: Callable[[Path], Any], place: Callable[[Path, Path], None]) -> None:
    """write(tmp) into a new temporary file beside `path` (mkstemp, the mode a file written in place gets, not its
    0600), then place(tmp, path); the temporary file is gone afterwards, whatever happened. SIGINT and SIGTERM wait
    for its end (signals_deferred): a training's process that a stop of its study's process group reached, with their
    default action, while it wrote model.pt after its last step left '.model.pt.XXXXXXXX.tmp' in the model store
    (test_scenario2's interrupted sweep, once on CI, 2026-12-05)."""
    with _write_running(), signals_deferred():
        _write_temporary(path, write, place)


def _write_temporary(path: Path, write: Callable[[Path], Any], place: Callable[[Path, Path], None]) -> None:
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=TEMPORARY)
    tmp = Path(name)
    try:
        try:
            os.fchmod(fd, 0o666 & ~_umask())
        finally:
            os.close(fd)
        write(tmp)
        place(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)  # renamed away already, or left by a failure or a link


_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a named pipe"), (stat.S_ISSOCK, "a socket"),
          (stat.S_ISCHR, "a device"), (stat.S_ISBLK, "a device"))  # fmt: skip


def kind_of(mode: int) -> str:
    """What an entry of st_mode `mode` that is not a regular file is, in words ("a named pipe")."""
    return next((words for test, words in _KINDS if test(mode)), "an entry of another kind")


def not_regular(path: Path) -> str | None:
    """What the entry at `path` (links followed) is when it is there and is not a regular file ("a named pipe",
    kind_of), else None: a regular file, nothing there, or an entry that cannot be looked at (its reader says so)."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return None
    return None if stat.S_ISREG(mode) else kind_of(mode)


MAX_RECORD_BYTES = 1 << 30
"""the largest record read whole (1 GiB; a study's largest table or SUMO output is tens of MB): a larger file is
refused as unreadable (EFBIG), not read into memory until it fails (probe 6, H5: an 8 GB sparse file as a profile
or a marker ended in a MemoryError traceback)"""


def open_regular(path: Path, limit: int | None = MAX_RECORD_BYTES) -> BinaryIO:
    """The file `path` (links followed) opened to read its bytes when it is a regular file; NotRegularFileError,
    before anything is read, for a named pipe, a socket, a device or a folder, the system's OSError for a missing or
    unreadable one. Every record is read back through it (read_bytes, read_text, read_json, read_csv): a named pipe
    where a record belongs hung the command reading it (issue 82, fifth probe, G4). Its kind is looked at before it
    is opened (opening a device may do something) and again on the open file (fstat): opened without waiting
    (O_NONBLOCK: opening a pipe to read waits for a writer), a pipe put there in between is refused too."""
    if (kind := not_regular(path)) is not None:
        raise NotRegularFileError(path, kind)
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise NotRegularFileError(path, kind_of(mode))
        if limit is not None and (size := os.fstat(fd).st_size) > limit:
            raise OSError(errno.EFBIG, f"{size / 2**30:,.1f} GiB, larger than any record ({limit / 2**30:g} GiB)")
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_bytes(path: Path) -> bytes:
    """The bytes of the regular file `path` (open_regular)."""
    with open_regular(path) as f:
        return f.read()


def read_text(path: Path, errors: str = "strict") -> str:
    """The UTF-8 text of the regular file `path` (open_regular), its line ends as Path.read_text gives them ('\\n');
    UnicodeDecodeError (a ValueError; its start: the byte's offset in the file) for bytes that are not UTF-8, unless
    `errors` says otherwise."""
    return read_bytes(path).decode("utf-8", errors).replace("\r\n", "\n").replace("\r", "\n")


def read_csv(path: Path, **options: Any) -> Any:
    """pandas.read_csv of the regular file `path` (open_regular: a named pipe is refused, not waited on)."""
    import pandas as pd

    with open_regular(path) as f:
        return pd.read_csv(f, **options)


def file_sha256(path: Path) -> str:
    """sha256 of a file's bytes (a model file: which weights a run was driven by); a regular file's only."""
    h = hashlib.sha256()
    with open_regular(path, limit=None) as f:  # read in chunks
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
    """The JSON in the file `path` (loads_json): OSError when it cannot be read or is not a regular file
    (open_regular: NotRegularFileError), ValueError when it is not JSON."""
    return loads_json(read_text(path))


def read_json_object(path: Path) -> dict[str, Any] | None:
    """The JSON object in the file `path`; None when it is missing, unreadable, not JSON or not an object."""
    try:
        data = read_json(path)
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None



def write_text_atomic(path: Path, text: str) -> None:
    """Write text atomically (write_atomic): a study's report is replaced whole, never written into whatever entry
    holds its name (a named pipe there hung the study: probe 6, H3)."""
    write_atomic(path, lambda tmp: tmp.write_text(text))
