"""Lock files beside a user's paths ('.NAME.lock' beside --out, '.MODEL.lock' in the model store): opened without
following a link, made new (O_EXCL) when missing, and taken over only when coopsumo wrote them (a stale lock of a
killed command: 'coopsumo KIND, pid N'); a link, or a file coopsumo did not write, is refused (ForeignLock), never
written into or removed."""

from __future__ import annotations

import fcntl
import os
import re
import stat
import time
from pathlib import Path

from coopsumo.errors import UsageError

_OLD_KINDS = "simulate|train|scenario1|scenario2|ablation|regime_map|protocol|accident_seeds"
LOCK_TEXT = re.compile(rf"coopsumo [a-z0-9_]+, pid [0-9]+\n|({_OLD_KINDS}), pid [0-9]+\n?")
"""what a command writes into the lock file it holds ('coopsumo simulate, pid 8301'; before issue 82 without
'coopsumo '); a file of other content is not a lock"""

EMPTY_WAIT_S = 0.5
"""how long an empty, unheld lock file is taken for one being made (a command between making and writing it)"""


class ForeignLock(UsageError):
    """The lock file's name is taken by a link or by a file coopsumo did not write."""


def _foreign(path: Path, what: str) -> ForeignLock:
    return ForeignLock(f"{path} {what}, not a lock file coopsumo made, and is left alone; move it away (coopsumo "
                       "locks a folder through a file of that name)")  # fmt: skip


def _open(path: Path) -> tuple[int, bool] | None:
    """(descriptor, made) for the lock file `path`: made new, or the regular file there opened (no link followed);
    None when it went between the two attempts."""
    flags = os.O_RDWR | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC
    try:
        return os.open(path, flags | os.O_CREAT | os.O_EXCL, 0o644), True
    except FileExistsError:
        pass
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        return None
    except OSError:
        if os.path.islink(path):
            raise _foreign(path, f"is a link to {os.path.realpath(path)}") from None
        if os.path.isdir(path):
            raise _foreign(path, "is a folder") from None
        raise
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise _foreign(path, "is not a regular file")
    return fd, False


def not_a_lock(path: Path, empty_ok: bool = False) -> str | None:
    """Why the entry `path`, named like a lock file, is not one coopsumo made (a link, not a regular file, text of
    its own; empty_ok: an empty file is one), or None (its lock is taken as try_lock would take it)."""
    if os.path.islink(path):
        return f"is a link to {os.path.realpath(path)}"
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None  # gone, or unreadable: try_lock says so when the lock is needed
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return "is not a regular file"
        text = _text(fd)
    finally:
        os.close(fd)
    return None if LOCK_TEXT.fullmatch(text) or (not text and empty_ok) else "holds text of its own"


def same_file(fd: int, path: Path) -> bool:
    """True when `path` (no link followed) is the file open as `fd`."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return False
    own = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (own.st_dev, own.st_ino)


def _text(fd: int) -> str:
    data = os.pread(fd, 4096, 0)
    try:
        return data.decode()
    except UnicodeDecodeError:
        return "\ufffd"


def _owned(fd: int, path: Path, empty_ok: bool, since: float) -> bool:
    """Whether the lock file open as `fd` (locked, not made now) is coopsumo's: its text a lock's; empty: a lock
    being made (False: look again), taken as coopsumo's when `empty_ok` or after EMPTY_WAIT_S. ForeignLock if not."""
    text = _text(fd)
    if LOCK_TEXT.fullmatch(text) or (not text and empty_ok):
        return True
    if not text and time.monotonic() - since < EMPTY_WAIT_S:
        return False
    raise _foreign(path, "is empty and held by no command" if not text else "holds text of its own")


def try_lock(path: Path, kind: str = "coopsumo", wait: bool = False, empty_ok: bool = False) -> int | None:
    """An open descriptor holding an exclusive flock on the lock file `path` (made if missing), with
    'coopsumo KIND, pid N' written into it; None when another process holds it (wait: wait for it instead). A file
    removed or replaced between opening and locking is opened again. ForeignLock when `path` is a link or a file
    coopsumo did not write (empty_ok: an empty file is taken for a lock, as the model store's were written empty)."""
    since = time.monotonic()
    while True:
        opened = _open(path)
        if opened is None:
            continue
        fd, made = opened
        try:
            fcntl.flock(fd, fcntl.LOCK_EX if wait else fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            held = same_file(fd, path)
            os.close(fd)
            if held:
                return None
            continue
        try:
            ours = same_file(fd, path) and (made or _owned(fd, path, empty_ok, since))
        except BaseException:
            os.close(fd)
            raise
        if ours:
            text = f"coopsumo {kind}, pid {os.getpid()}\n".encode()
            os.pwrite(fd, text, 0)  # written before the old text is cut: never empty while held
            os.ftruncate(fd, len(text))
            return fd
        os.close(fd)  # its holder removed it after we opened it, or it is being made: look at the path again
        time.sleep(0.01)


def release_lock(fd: int, path: Path) -> None:
    """Remove the lock file (while still holding it: only the file this descriptor holds) and release it."""
    try:
        if same_file(fd, path):
            path.unlink(missing_ok=True)
    finally:
        os.close(fd)
