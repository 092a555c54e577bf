"""How a study's local worker processes start (runner.LocalBackend): forked by multiprocessing's fork server, which
imported the heavy third-party modules once, then given the main process's environment, standard streams and signal
handling, and made to exit with it."""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import sys
import threading
import time
from typing import Any

from coopsumo.files import exit_between_writes
from coopsumo.runio import STOP_SIGNALS, children_start_deaf, steady_streams, thread_lock_for_bars

PRELOADED = ("numpy", "torch", "pandas", "libsumo")
"""the modules a study's worker processes find imported: they are forked from multiprocessing's fork server, which
imported them once, rather than each started afresh to import them (about 2 CPU s each; the suite's summed test time
fell by 5-10%, docs/performance.md). No module of coopsumo: some read the environment as they are imported, and the
server's is the one it started with."""


def worker_context() -> Any:
    """multiprocessing's context of a study's workers: the fork server (PRELOADED), started here if it is not running,
    with SIGINT and SIGTERM blocked: the workers it forks inherit the mask and lift it when ready (init_worker), and a
    stop of the process group never ends the server itself, which later workers need. Spawn when the server cannot
    start: its socket is a file in the temporary folder, whose path a long TMPDIR makes longer than an AF_UNIX address
    may be (108 bytes: a study ended in "AF_UNIX path too long", where spawned workers need no socket)."""
    from multiprocessing import forkserver

    ctx = mp.get_context("forkserver")
    ctx.set_forkserver_preload(list(PRELOADED))
    try:
        with children_start_deaf(STOP_SIGNALS):  # the resource tracker first: it unblocks both as it starts
            forkserver.ensure_running()
    except OSError:
        return mp.get_context("spawn")
    return ctx


class ParentStreams:
    """This process's stdout and stderr as a pool's initializer argument: pickled as duplicates that multiprocessing
    hands to the worker (reduction.DupFd), a closed one as None. A worker forked by the fork server has the server's
    streams, those of whoever started it, not the study's (a test's captured stderr lost the worker's lines)."""

    def __reduce__(self) -> tuple[Any, ...]:
        from multiprocessing.reduction import DupFd

        fds: list[Any] = []
        for fd in (1, 2):
            try:
                os.fstat(fd)
            except OSError:
                fds.append(None)
            else:
                fds.append(DupFd(fd))
        return (_taken, tuple(fds))


def _taken(*fds: Any) -> tuple[int | None, ...]:
    return tuple(None if fd is None else fd.detach() for fd in fds)


def _take_streams(fds: tuple[int | None, ...]) -> None:
    """Make the file descriptors `fds` this process's stdout and stderr (None: the null device, as a closed one)."""
    for stream in (sys.stdout, sys.stderr):
        if stream is not None:
            stream.flush()
    for target, fd in zip((1, 2), fds, strict=True):
        source = os.open(os.devnull, os.O_WRONLY) if fd is None else fd
        if source != target:  # a spawned worker gets the very descriptor, at its number
            os.dup2(source, target)
            os.close(source)


def init_worker(parent_pid: int, environ: dict[str, str], streams: Any) -> None:
    """Pool initializer: the main process's environment and standard streams when the pool was made (a worker of the
    fork server has the server's), and exit with the main process. Ctrl-C reaches the whole process group: a worker
    leaves it to the main process, which stops the workers (abort: SIGTERM, on which a training saves its
    checkpoint), so a worker never dies with a traceback of its own. It started with SIGINT and SIGTERM blocked
    (worker_context), so that one sent while it starts waits until now: SIGINT ignored here, then both unblocked (a
    cell's training takes them with its own handler)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    os.environ.clear()
    os.environ.update(environ)
    _take_streams(streams)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
    start_parent_watch(parent_pid)
    steady_streams()  # a closed or broken stderr: its bars write to nothing (issue 82, probe 16, T3)
    thread_lock_for_bars()


def _watch_parent(parent_pid: int) -> None:
    """Return when the process `parent_pid` has ended: a pidfd becomes readable then (Linux 5.3 on); without one,
    looked for every second. Watched by its pid, not as the worker's parent: a study's worker is the fork server's
    child, and the server lives on while its workers do."""
    import select

    try:
        fd = os.pidfd_open(parent_pid)
    except ProcessLookupError:
        return
    except (OSError, AttributeError):  # no pidfd here
        while True:
            time.sleep(1.0)
            try:
                os.kill(parent_pid, 0)
            except ProcessLookupError:
                return
            except OSError:
                pass
    select.select([fd], [], [])


def _exit_with_parent(parent_pid: int) -> None:
    _watch_parent(parent_pid)
    exit_between_writes(3)  # not while a write's temporary file is on disk


def start_parent_watch(parent_pid: int) -> None:
    """In a pool worker: exit when the main process `parent_pid` is gone (no orphan keeps working)."""
    threading.Thread(target=_exit_with_parent, args=(parent_pid,), daemon=True, name="watch-parent").start()
