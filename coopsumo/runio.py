"""The command line's helpers: the parser and its help, run_cli (one line and an exit code for every error a
user can cause), and stopping on signals."""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from collections.abc import Callable, Collection, Iterator
from contextlib import contextmanager
from functools import partial
from typing import Any, NoReturn

from coopsumo.errors import (
    USAGE_EXIT,
    USER_ERRNOS,
    NotRegularFileError,
    UsageError,
    first_line,
    gone_folder,
    one_line,
    os_error_text,
)
from coopsumo.files import STOP_SIGNALS, signals_deferred
from coopsumo.owners import nets_env_problem, store_env_problem, tmp_env_problem
from coopsumo.paths import env_problem, library_env_problem, utf8_problem


class DefaultsHelpFormatter(argparse.HelpFormatter):
    """--help gives every option's default: "(default: X)" is added unless the help text already says what the
    default is (an option whose default is None must say so in its text) or the option is an on/off flag."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if "default" in text.lower() or action.default in (None, argparse.SUPPRESS) or action.nargs == 0:
            return text
        return f"{text} (default: %(default)s)".lstrip()

    def _split_lines(self, text: str, width: int) -> list[str]:
        """Lines broken at spaces only, so that a flag (--no-action-mask) or a value (2,1.5,1) stays whole."""
        import textwrap

        return textwrap.wrap(" ".join(text.split()), width, break_on_hyphens=False)


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors, exit code 2, and every default in --help."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", DefaultsHelpFormatter)
        super().__init__(*args, **kwargs)

    def parse_known_args(self, args: Any = None, namespace: Any = None) -> Any:  # type: ignore[override]
        """argparse's, every argument first checked for a byte that is not valid UTF-8 (paths.utf8_problem): one line
        before the command starts, for every flag of every command (issue 82, probe 7, I9); the standard streams made
        steady first (steady_streams: a usage error with stderr closed, or unencodable, was a traceback: probe 17,
        T4)."""
        steady_streams()
        words = sys.argv[1:] if args is None else list(args)
        for word in words:
            if problem := utf8_problem(word):
                self.error(problem)
        return super().parse_known_args(words, namespace)

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(USAGE_EXIT)


def thread_lock_for_bars() -> None:
    """In a worker process: tqdm's bars take a thread lock, not tqdm's default multiprocessing lock, whose semaphore
    a worker stopped by its command leaves behind (the resource tracker's "leaked semaphore objects" warning after a
    Ctrl-C). A worker's bars are its own: no other process writes them."""
    from tqdm import tqdm

    tqdm.set_lock(threading.RLock())


class _Steady:
    """A standard stream that a reader gone cannot stop: a write or flush that fails (a pipe closed at its other end,
    `2>&1 | head -c 1`; a full disk, `2>/dev/full`; a descriptor open for reading) puts the null device onto the
    stream's file descriptor, so that this process and the
    processes it starts afterwards write to nothing, and the command goes on (issue 82, probe 16, T3: the first
    progress bar ended the run in a BrokenPipeError). Everything else is the stream's."""

    def __init__(self, stream: Any, fd: int) -> None:
        self._stream, self._fd = stream, fd
        self.lost: OSError | None = None
        """the failure of a write other than a closed pipe's (a full disk): what the stream was given is incomplete"""

    mid_line = False
    """whether the last text written left a line unended: a stop that came between a print's text and its newline
    (this class's write is Python, where a signal's handler runs) glued its one line to it (fresh_line)"""

    def write(self, text: str) -> int:
        ended = text.endswith(("\n", "\r"))
        if text and not ended:
            self.mid_line = True  # before the write: a stop right after it finds the line unended
        try:
            written = int(self._stream.write(text))
            if ended:
                self.mid_line = False
            return written
        except OSError as err:  # a pipe closed, a full disk (ENOSPC), a descriptor open for reading (EBADF): probe 17
            self._to_null(err)
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except OSError as err:
            self._to_null(err)

    def _to_null(self, err: OSError) -> None:
        if not isinstance(err, BrokenPipeError) and self.lost is None:
            self.lost = err
        null = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(null, self._fd)
        finally:
            os.close(null)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


def steady_streams() -> None:
    """sys.stdout and sys.stderr made safe for every line and progress bar: a stream closed when the process started
    (`2>&-`: Python's None) gets the null device on its descriptor, which the processes it starts inherit (issue 82,
    probe 16, T3: tqdm's first bar ended every run in an AttributeError); a character its encoding cannot take is
    written as a backslash escape (probe 16, T2: a path with 'é' under PYTHONIOENCODING=ascii ended `models`, `history`
    and both merges in a UnicodeEncodeError after their outputs were written); a pipe closed at its other end is
    written to as nothing (_Steady)."""
    import io

    for fd, name in ((1, "stdout"), (2, "stderr")):
        stream = getattr(sys, name)
        if isinstance(stream, _Steady):
            continue
        if stream is None:
            null = os.open(os.devnull, os.O_WRONLY)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
            stream = open(fd, "w", encoding="utf-8", closefd=False)  # noqa: SIM115 (the process's stream)
        if isinstance(stream, io.TextIOWrapper):
            stream.reconfigure(errors="backslashreplace")
        setattr(sys, name, _Steady(stream, fd))


class Stop(KeyboardInterrupt):
    """SIGINT or SIGTERM received while stop_on_signals holds (a KeyboardInterrupt, so every handler of Ctrl-C
    takes it); signum: which one."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


_STOPS_RAISED: list[int] = []
"""every signal _raise_stop turned into Stop, or held back while torch was imported, in this process, in order
(run_interruptible reads it)"""


_COMMAND_STOPS: list[int | None] = [None]
"""len(_STOPS_RAISED) when the running command began (run_interruptible); None outside a command"""


def swallowed_stop() -> int | None:
    """The signal of a Stop raised since the command began, in the main thread, while the command runs on: the code
    the Stop landed in swallowed it (a library's `except ImportError` or `except BaseException` around an import,
    once numpy turned the Stop into an ImportError), so that a Ctrl-C in the command's first second was lost until a
    study's cells all ended (1 run in about 2,900 of the suite's, 2026-12-02). None when there is none, outside a
    command, once the command said it was stopped, or in another thread. Where a long command waits (the study
    runner's loop, the training loop's start) this raises the Stop again."""
    base = _COMMAND_STOPS[0]
    if base is None or _ENDING[0] or len(_STOPS_RAISED) <= base:
        return None
    return _STOPS_RAISED[-1] if threading.current_thread() is threading.main_thread() else None


def raise_swallowed_stop() -> None:
    """Raise Stop again for a swallowed one (swallowed_stop)."""
    if (signum := swallowed_stop()) is not None:
        raise Stop(signum)


_ENDING: list[bool] = [False]
"""[True] once a stopped command has said so (stop_reported), until the next command starts"""


def stop_reported() -> None:
    """The command was stopped and has said so in its line: a SIGINT or SIGTERM that comes while it ends is counted,
    not raised (issue 82, probe 4, F15: `timeout -s INT` sends its signal to the command and again to its process
    group, and a second Ctrl-C does the same; raised as the command released its lock, it printed a second line).
    Undone when a command starts (stop_on_signals, run_interruptible)."""
    _ENDING[0] = True


def _raise_stop(signum: int, frame: Any) -> None:
    _STOPS_RAISED.append(signum)  # also when it waits: a command that ends before it comes again was interrupted
    if _ENDING[0]:
        return
    if _importing_torch(frame):  # raised there, torch's C++ ends the process (abort, its stack): the signal again soon
        retry = threading.Timer(RETRY_S, os.kill, (os.getpid(), signum))
        retry.daemon = True
        retry.start()
        return
    raise Stop(signum)


RETRY_S = 0.1
"""how soon a signal that came while torch was being imported is sent again (_raise_stop)"""


def _importing_torch(frame: Any) -> bool:
    """True when the main thread, at `frame`, is running a torch module's body (importing torch): some of it is C++
    (pybind11) calling back into Python, where an exception cannot pass and ends the process with SIGABRT
    ("terminate called after throwing an instance of 'pybind11::error_already_set'"), 1 Ctrl-C in 40 during the
    import."""
    while frame is not None:
        code = frame.f_code
        if code.co_name == "<module>" and f"{os.sep}torch{os.sep}" in code.co_filename:
            return True
        frame = frame.f_back
    return False


@contextmanager
def stop_on_signals() -> Iterator[None]:
    """For the block, SIGINT and SIGTERM raise Stop wherever the command is, its setup included: also when the
    command was started with them ignored (a job a shell script put in the background ignores SIGINT, which was then
    lost until the training loop took it). Only in the main thread (elsewhere the block runs as it is)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _ENDING[0] = False
    old = {s: signal.signal(s, _raise_stop) for s in STOP_SIGNALS}
    hook_before = _quiet_unraisable_stops()
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
        _restore_unraisable(hook_before)


def _quiet_unraisable_stops() -> Callable[[Any], None]:
    """Put _unraisable_stop on top of sys.unraisablehook; the hook before it (for _restore_unraisable)."""
    before = sys.unraisablehook
    sys.unraisablehook = partial(_unraisable_stop, before)
    return before


def _restore_unraisable(before: Callable[[Any], None]) -> None:
    """Take _unraisable_stop off again, unless another hook was put on top of it since (a py: policy's)."""
    if isinstance(sys.unraisablehook, partial) and sys.unraisablehook.func is _unraisable_stop:
        sys.unraisablehook = before


def _unraisable_stop(before: Callable[[Any], None], unraisable: Any) -> None:
    """sys.unraisablehook while stop_on_signals holds: a Stop raised where Python can only print it (a weakref
    callback, e.g. importlib's module lock's, a __del__) is not printed: it is counted (_STOPS_RAISED) and raised
    again where the command waits (swallowed_stop), so that the command still ends in its one line (it printed
    "Exception ignored in ..." and a traceback before it: 1 SIGTERM in the suite's ~30 at 0.1 s into train,
    2026-12-04). Anything else goes to the hook before it."""
    if not isinstance(unraisable.exc_value, Stop):
        before(unraisable)


def training_stop(err: Exception) -> int | None:
    """The signal that stopped a training, when `err` says one did (agents.train.Interrupted, or the update worker
    ended by a Ctrl-C to the whole group: LearnerProcessError); else None. Their modules are looked up, not imported
    (torch)."""
    train, worker = sys.modules.get("coopsumo.agents.train"), sys.modules.get("coopsumo.agents.update_worker")
    if train is not None and isinstance(err, train.Interrupted):
        return int(err.signum)
    if worker is not None and isinstance(err, worker.LearnerProcessError) and err.signum in STOP_SIGNALS:
        return int(err.signum)
    return None


def fresh_line() -> str:
    """A newline when what stderr was last given left a line unended (a stop landed mid-print: _Steady.mid_line),
    else nothing: put before a command's one last line."""
    return "\n" if getattr(sys.stderr, "mid_line", False) else ""


def interrupted(prog: str, err: KeyboardInterrupt) -> int:
    """The one line of a command stopped by a signal (`prog: interrupted`); its exit code, 128 + the signal."""
    print(f"{fresh_line()}{prog}: interrupted", file=sys.stderr)
    return 128 + getattr(err, "signum", signal.SIGINT)


def run_interruptible(body: Callable[[], int], prog: Callable[[], str], whole_process: bool = False) -> int:
    """body(), a console command's whole run: a Ctrl-C (SIGINT) or a SIGTERM from this call's first instruction on
    raises Stop wherever it lands, the command's imports included (seconds for torch, libsumo, pandas, when Python's own
    KeyboardInterrupt used to end in a traceback, and SIGTERM ended the process without a line: issue 82, probe 7, I15),
    and also when the process was started with them ignored. A command that reports its own interruption (run_cli)
    returns its exit code; one that reaches here ends in one line, `prog(): interrupted`, exit code 128 + the signal.
    whole_process: body is the process's command, which exits next; a signal while Python exits then has nothing left to
    stop and waits (it used to kill the ending process without a line, or print a traceback from an exit handler): if
    the process has not ended EXIT_GRACE_S later (a policy of one's own left a thread running or an atexit callback that
    blocks: issue 82, probe 12, N6), it ends in one line (_exit_stop). A Ctrl-C that the code it landed in swallowed, so
    that body() ran on and returned 0, still ends in that line and 130. Only in the main thread (elsewhere: body()).
    Past Python's exit callbacks the signals are blocked (_deaf_at_exit): the process ends with its command's code."""
    if threading.current_thread() is not threading.main_thread():
        return body()
    if whole_process:
        import atexit

        atexit.register(_deaf_at_exit)  # the first registered runs last: after every exit callback of the command's
    old, stops_before, _ENDING[0] = {s: signal.getsignal(s) for s in STOP_SIGNALS}, len(_STOPS_RAISED), False
    outer = _COMMAND_STOPS[0]  # a command run by another (cli.main runs train.main) began with the outer one
    _COMMAND_STOPS[0] = stops_before if outer is None else outer
    hook_before = _quiet_unraisable_stops()
    try:
        for s in STOP_SIGNALS:
            signal.signal(s, _raise_stop)
        code = body()
        if code == 0 and len(_STOPS_RAISED) > stops_before:
            # a Ctrl-C swallowed by the code it landed in (a library's `except ImportError` around an optional
            # import, once numpy turned the Stop into an ImportError): the command ran on, but was interrupted
            return interrupted(prog(), Stop(_STOPS_RAISED[-1]))
        return code
    except KeyboardInterrupt as err:
        return interrupted(prog(), err)
    except Exception:
        if len(_STOPS_RAISED) == stops_before:
            raise
        # the Stop of a signal, turned into another error by the code it landed in: numpy makes one raised while its
        # C extension loads an ImportError (PyCapsule_Import), which pandas's import passes on as its own
        return interrupted(prog(), Stop(_STOPS_RAISED[-1]))
    finally:
        _COMMAND_STOPS[0] = outer
        _restore_unraisable(hook_before)
        ending = _exit_stop(prog)  # one clock for both signals
        for s, handler in old.items():
            signal.signal(s, ending if whole_process else signal.SIG_DFL if handler is None else handler)


def _deaf_at_exit() -> None:
    """The last exit callback of a console command: SIGINT and SIGTERM blocked for the rest of Python's exit. Right
    after its exit callbacks Python gives every signal back its default action (_PySignal_Fini), and a signal that
    came while it then tore its modules down (seconds, with torch loaded) killed the process without a line, exit code
    130, after the command had finished and printed everything (issue 82, probe 13, F22: `models`, `train`). Blocked,
    it is never delivered and the exit code is the command's; the exit callbacks before it (a policy's that blocks:
    _exit_stop) still take the signal; its clock, if one started, is stopped (their exit is done). Blocking holds in
    this thread only: a library's worker threads (OpenMP, BLAS) would take the signal with its default action once
    _PySignal_Fini restored it, so the signals are ignored too, process-wide, which _PySignal_Fini leaves as it is
    (probe 14, F6: `models`, `history` and both merges killed after their last line)."""
    signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    for s in STOP_SIGNALS:
        signal.signal(s, signal.SIG_IGN)
    signal.alarm(0)


EXIT_GRACE_S = 3
"""how long a signal that comes while the process exits waits for the exit before it ends the process"""


def _exit_stop(prog: Callable[[], str]) -> Callable[[int, Any], None]:
    """The handler of SIGINT and SIGTERM once the command is done and Python exits: the first such signal starts a
    clock (SIGALRM in EXIT_GRACE_S); an exit that ends before it is not cut short (a second Ctrl-C or `timeout`'s
    signal to the process group while a stopped command ends: issue 82, probe 4, F15), one still running then ends in
    one line, exit code 128 + the signal."""

    armed: list[int] = []

    def stopped(signum: int, frame: Any) -> None:
        if not armed:
            armed.append(signum)
            signal.signal(signal.SIGALRM, lambda _s, _f: _end_now(prog, signum))
            signal.alarm(EXIT_GRACE_S)

    return stopped


def _end_now(prog: Callable[[], str], signum: int) -> None:
    try:
        print(f"{fresh_line()}{prog()}: stopped by {signal.Signals(signum).name} while it exited ({EXIT_GRACE_S} s "
              "later): its work was done; something it ran (a thread or an atexit callback of a policy of one's own?) "
              "kept it from ending", file=sys.stderr, flush=True)  # fmt: skip
    finally:
        os._exit(128 + signum)


@contextmanager
def children_start_deaf(signals: Collection[int] = (signal.SIGINT,)) -> Iterator[None]:
    """Child processes started in the block (multiprocessing's spawn, subprocess) begin with `signals` blocked, from
    their first instruction on (a signal mask survives fork and exec): a Ctrl-C to the whole process group while a
    child's interpreter starts cannot end it in a KeyboardInterrupt traceback of its own. The child takes them when
    it is ready (a study's worker ignores SIGINT, then unblocks it: pool_workers.init_worker) or never (it is stopped by
    this process). Here SIGINT and SIGTERM wait for the block's end (signals_deferred), so that a start is never cut
    half-way (a child left reading what it was to be sent). multiprocessing's resource tracker unblocks SIGINT and
    SIGTERM when it starts, so it is started first. Only in the main thread (elsewhere the block runs as it is)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()
    old = signal.pthread_sigmask(signal.SIG_BLOCK, signals)
    try:
        with signals_deferred():
            yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def working_folder_problem() -> str | None:
    """Why no command can run in the current folder (it was deleted: torch cannot even be imported there, and the
    studies' worker processes start in it), or None."""
    try:
        os.getcwd()
    except OSError:
        return "the current folder no longer exists (deleted?); change to an existing folder and run the command again"
    return None


def environment_problem() -> str | None:
    """Why a folder the environment names cannot be used (a line naming the variable), or None: $COOPSUMO_NETS_DIR,
    $COOPSUMO_MODELS, $TMPDIR; and the variables of the libraries coopsumo draws with (library_env_problem)."""
    return env_problem() or nets_env_problem() or store_env_problem() or tmp_env_problem() or library_env_problem()


def _stdout_kept(prog: str, code: int) -> int:
    """The command's exit code `code`, or 1 with one line on stderr when what it printed could not all be written to
    stdout (a file on a full disk: issue 82, probe 17, O1, "error: No space left on device" named nothing, or the
    table was lost without a word once the stream was steady); a pipe closed by its reader is not such a loss."""
    out = sys.stdout
    if isinstance(out, _Steady):
        out.flush()
        if out.lost is not None:
            print(f"{prog}: error: its output could not be written to stdout ({out.lost.strerror or out.lost}): what "
                  "it printed is incomplete", file=sys.stderr)  # fmt: skip
            return code or 1
    return code


def run_cli(prog: str, body: Callable[[], int]) -> int:
    """Run a command's body; usage errors (config.ConfigError among them) become one line on stderr and exit code 2,
    and so does a working folder that was deleted (working_folder_problem)."""
    steady_streams()
    if problem := working_folder_problem():
        print(f"{prog}: error: {problem}", file=sys.stderr)
        return USAGE_EXIT
    if problem := environment_problem():
        print(f"{prog}: error: {problem}", file=sys.stderr)
        return USAGE_EXIT
    try:
        return _stdout_kept(prog, body())
    except UsageError as err:
        print(f"{prog}: error: {one_line(err)}", file=sys.stderr)  # one line, whatever a library's text it passes on
        return USAGE_EXIT
    except KeyboardInterrupt as err:
        return interrupted(prog, err)
    except OSError as err:  # the system refused a file operation: one line naming the path and the problem
        if err.filename is None and working_folder_problem():  # named nothing (issue 82, probe 18, O2)
            print(f"{prog}: error: the current folder was deleted while the command ran ({os_error_text(err)}); "
                  "change to an existing folder and run the command again", file=sys.stderr)  # fmt: skip
            return 1
        if (gone := gone_folder(err)) is not None:  # named only a temporary file in it (probe 19, O3)
            print(f"{prog}: error: the folder {gone} is gone, moved or deleted while the command ran "
                  f"({os_error_text(err)})", file=sys.stderr)  # fmt: skip
            return 1
        print(f"{prog}: error: {os_error_text(err)}", file=sys.stderr)
        return USAGE_EXIT if err.errno in USER_ERRNOS or isinstance(err, NotRegularFileError) else 1
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

