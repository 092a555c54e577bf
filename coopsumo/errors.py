"""One-line errors: bad input from the user (UsageError, exit code 2) and the operating system's errors in
one line. The ground floor: imports nothing of coopsumo."""

from __future__ import annotations

import errno
import os
from pathlib import Path

USAGE_EXIT = 2


class UsageError(ValueError):
    """Bad input from the user: reported in one line, exit code 2."""


class ConfigError(UsageError):
    """A configuration value is outside what the model supports (a usage error)."""


def first_line(err: BaseException) -> str:
    """The first line of an exception's message, or its type's name when the message is empty."""
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


def one_line(err: BaseException) -> str:
    """An error's whole message on one line: its lines joined by a space (a library's text passed on, such as pandas'
    ParserError, may end in a newline or hold several: a command's error is one line; issue 82, probe 13, F17)."""
    return " ".join(line.strip() for line in str(err).strip().splitlines() if line.strip())


USER_ERRNOS = frozenset({errno.ENAMETOOLONG, errno.ELOOP, errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOTDIR,
                         errno.EISDIR, errno.EEXIST, errno.ENOENT})  # fmt: skip

"""operating-system errors a path the user gave causes (exit code 2); the others (a full disk, an I/O error) 1"""


class NotRegularFileError(OSError):
    """A record that is not a regular file but a named pipe, a socket, a device or a folder (files.open_regular):
    never read, since reading a pipe waits for a writer and a device may never end. strerror says what it is ("not a
    regular file but a named pipe"), for a reader's own line; str() and os_error_text name the path first. A user's
    error: exit code 2 (runio.run_cli)."""

    def __init__(self, path: object, kind: str) -> None:
        super().__init__(errno.EINVAL, f"not a regular file but {kind}", str(path))
        self.kind = kind

    def __str__(self) -> str:
        return f"{self.filename} is not a regular file but {self.kind}"


def why_unreadable(err: BaseException) -> str:
    """Why a record could not be read, in a few words for a reader's line: what a record that is not a regular file
    is ("not a regular file but a named pipe"), else the error's type (UnicodeDecodeError, ValueError)."""
    return str(err.strerror) if isinstance(err, NotRegularFileError) else type(err).__name__


def os_error_text(err: OSError) -> str:
    """An OSError in one line: what the system said and the path(s) it concerns."""
    if isinstance(err, NotRegularFileError):
        return str(err)
    text = err.strerror or first_line(err)
    paths = [str(p) for p in (err.filename, err.filename2) if p is not None]
    return f"{text}: {' -> '.join(paths)}" if paths else text


def gone_folder(err: OSError) -> str | None:
    """The folder on the path of a file an OSError of ENOENT names that is not there (the nearest to the root), or
    None: the file alone is missing, or the error is another."""
    if err.errno != errno.ENOENT or not isinstance(err.filename, str) or not os.path.isabs(err.filename):
        return None
    missing = None
    for folder in [*Path(err.filename).parents][:-1]:
        if os.path.isdir(folder):
            break
        missing = folder
    return None if missing is None else str(missing)
