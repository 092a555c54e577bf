"""One-line errors: bad input from the user (UsageError, exit code 2) and the operating system's errors in
one line. The ground floor: imports nothing of coopsumo."""

from __future__ import annotations

import errno

USAGE_EXIT = 2


class UsageError(ValueError):
    """Bad input from the user: reported in one line, exit code 2."""


class ConfigError(UsageError):
    """A configuration value is outside what the model supports (a usage error)."""


def first_line(err: BaseException) -> str:
    """The first line of an exception's message, or its type's name when the message is empty."""
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


USER_ERRNOS = frozenset({errno.ENAMETOOLONG, errno.ELOOP, errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOTDIR,
                         errno.EISDIR, errno.EEXIST, errno.ENOENT})  # fmt: skip

"""operating-system errors a path the user gave causes (exit code 2); the others (a full disk, an I/O error) 1"""


def os_error_text(err: OSError) -> str:
    """An OSError in one line: what the system said and the path(s) it concerns."""
    text = err.strerror or first_line(err)
    paths = [str(p) for p in (err.filename, err.filename2) if p is not None]
    return f"{text}: {' -> '.join(paths)}" if paths else text

