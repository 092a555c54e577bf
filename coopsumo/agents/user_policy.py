"""A policy of the user's own: `py:MODULE:CLASS`, a class in the user's file or module, checked against the policy
interface when it is loaded and wrapped so that every decision it gives is checked too.

The class needs act(obs) -> one action per vehicle of the batch (coopsumo.sim.physics: 0 left, 1 right, 2 speed-up,
3 none), obs being the batch's coopsumo.sim.observation.Observation. It may set `needs_grids` (False: the world need
not build the occupancy grids for it; default True), `decision_interval` (steps between two decisions, the actions
held between; default 1) and `name`. Its constructor takes no argument, or one named `rng`: the run's policy stream
(config.rng_stream(seed, POLICY_STREAM)), so that a policy that draws repeats with the run's seed. docs/extending.md
shows one.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import importlib.util
import inspect
import os
import sys
import threading
import traceback
import weakref
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any, TypeVar

import numpy as np

from coopsumo.errors import UsageError, first_line
from coopsumo.files import end_if_forked, file_sha256
from coopsumo.policy_spec import module_file, parse_policy
from coopsumo.sim.observation import Observation
from coopsumo.sim.physics import ACTION_NAMES

MAX_DECISION_INTERVAL = 600
"""the longest decision interval a policy of one's own may ask for (steps; a minute), as the learner's"""
ACTIONS_TEXT = "0 left, 1 right, 2 speed-up, 3 none"
PASSED_ON = (KeyboardInterrupt,)
"""what the user's code may raise that is no failure of its own, passed on as Python would: a Ctrl-C or a signal
(runio ends the run in one line as for any). A SystemExit (`sys.exit()` in act or as its module is run) is a failure
of the policy's, in one line: passed on, it ended the command with its code, silently, no run kept (issue 82, probe
18, O3: exit 0)"""
T = TypeVar("T")


class UserPolicyError(UsageError):
    """A py:MODULE:CLASS the interface refuses, or a decision outside it (one line, exit code 2)."""


def _from_file(path: str, text: str) -> ModuleType:
    """The module of the Python file at `path`, run once under a private name (a file named like an installed
    module shadows nothing)."""
    if not os.path.isfile(path):
        raise UserPolicyError(f"{text}: no file {path} (MODULE is a .py file, or a module name)")
    real = os.path.realpath(path)
    name = f"_coopsumo_py_{hashlib.sha256(real.encode()).hexdigest()[:12]}"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, real)
    if spec is None or spec.loader is None:
        raise UserPolicyError(f"{text}: {path} cannot be loaded as Python")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses and pickling look a class's module up there
    writes, sys.dont_write_bytecode = sys.dont_write_bytecode, True  # reading it leaves no __pycache__ beside it
    _said_in_one_line(real, text)  # a thread it starts as it is run (probe 12, N7)
    try:
        spec.loader.exec_module(module)
    except PASSED_ON:
        del sys.modules[name]
        raise
    except BaseException as err:  # the user's code: any error, in one line
        del sys.modules[name]
        raise UserPolicyError(f"{text}: running {path} failed: {_failure(err)}") from None
    finally:
        sys.dont_write_bytecode = writes
    return module


def _imported(module: str, text: str) -> ModuleType:
    """An importable module by name; its own import errors in one line."""
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as err:
        if err.name is not None and (module == err.name or module.startswith(f"{err.name}.")):
            raise UserPolicyError(f"{text}: no module {module!r}: neither {module.replace('.', '/')}.py in the current "
                                  "folder nor an importable module") from None  # fmt: skip
        raise UserPolicyError(f"{text}: importing {module} failed: {first_line(err)}") from None
    except PASSED_ON:
        raise
    except BaseException as err:  # the user's code: any error, in one line
        raise UserPolicyError(f"{text}: importing {module} failed: {_failure(err)}") from None


def load_class(module: str, class_name: str, text: str) -> type:
    """The class `class_name` of `module` (a .py file, MODULE.py in the current folder, or an importable module),
    checked: a class with an act method; UserPolicyError naming what is missing otherwise."""
    path = module_file(module)
    found = _from_file(path, text) if path is not None else _imported(module, text)
    where = path or module
    # read inside _users: a module's __getattr__, a metaclass's or an object's __str__ may raise (probe 11, M3)
    return _users(lambda: _checked_class(found, class_name, where, text), f"{text}: reading {class_name} raised")


def _checked_class(found: ModuleType, class_name: str, where: Any, text: str) -> type:
    cls = getattr(found, class_name, None)
    if cls is None:
        classes = sorted(n for n, v in vars(found).items() if inspect.isclass(v) and v.__module__ == found.__name__)
        also = f" (it defines {', '.join(classes)})" if classes else " (it defines no class)"
        raise UserPolicyError(f"{text}: {where} defines no {class_name!r}{also}")
    if not inspect.isclass(cls):
        raise UserPolicyError(f"{text}: {class_name} in {where} is not a class (it is {type(cls).__name__} "
                              f"{str(cls)[:40]})")
    if not callable(getattr(cls, "act", None)):
        raise UserPolicyError(f"{text}: class {class_name} has no act(obs) method; a policy needs act(obs) giving "
                              f"one action per vehicle ({ACTIONS_TEXT})")  # fmt: skip
    return cls


def _instance(cls: type, rng: np.random.Generator, text: str) -> Any:
    """cls() or cls(rng=rng) when its constructor takes `rng`; its errors in one line."""
    try:
        takes_rng = "rng" in inspect.signature(cls).parameters
    except PASSED_ON:
        raise
    except BaseException:  # no signature, or the user's __signature__ raised (probe 11, M3)
        takes_rng = False
    return _users(lambda: cls(rng=rng) if takes_rng else cls(), f"{text}: {_name(cls)}() failed:",
                  " (its constructor takes no argument, or only rng)")  # fmt: skip


def _attribute(inner: Any, key: str, default: Any, text: str) -> Any:
    """A policy attribute the class may set, checked (needs_grids a bool, decision_interval 1-600, name a string).
    Read, shown and made a plain bool, int or str by _users: a property, a __getattr__, a __repr__ or a subclass's
    conversion that raises ends in one line (issue 82, probe 10, L4: tracebacks)."""
    value, shown = _users(lambda: _plain(getattr(inner, key, default), type(default)), f"{text}: its {key} raised")
    if value is None or value == "" or (key == "decision_interval" and not 1 <= value <= MAX_DECISION_INTERVAL):
        must = {"needs_grids": "True or False", "decision_interval": f"an integer from 1 to {MAX_DECISION_INTERVAL}",
                "name": "a non-empty string"}[key]  # fmt: skip
        raise UserPolicyError(f"{text}: its {key} must be {must}, got {shown}")
    return value


def _plain(value: Any, kind: type) -> tuple[Any, str]:
    """(value as a plain `kind`, bool, int or str, or None when it is none of that kind; its repr, cut short)."""
    shown = repr(value)
    shown = shown if len(shown) <= 60 else f"{shown[:57]}..."
    if kind is bool:
        return (bool(value) if isinstance(value, bool | np.bool_) else None), shown
    if kind is int:
        whole = isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)
        return (int(value) if whole else None), shown
    return (str(value) if isinstance(value, str) else None), shown


class UserPolicy:
    """The user's policy object behind the policy interface: its attributes checked once, every decision checked
    (one integer 0-3 per vehicle)."""

    def __init__(self, inner: Any, text: str, file: str | None, pid: int | None = None) -> None:
        self.inner = inner
        self.text = text
        self.pid = os.getpid() if pid is None else pid
        """the process the policy drives the run in (from_spec: the one that loaded its class)"""
        _said_in_one_line(_class_file(type(inner)), text)
        self.name = _attribute(inner, "name", type(inner).__name__, text)
        self.needs_grids = _attribute(inner, "needs_grids", True, text)
        self.decision_interval = _attribute(inner, "decision_interval", 1, text)
        self.trained_on: dict[str, object] = {"policy": text}
        """what config.json records of it (rollout: model_trained_on): its file and that file's sha256, by which a
        study sees that the file changed (run_folders.model_driven)"""
        if file is not None:
            self.trained_on.update(policy_file=os.path.abspath(file), model_sha256=file_sha256(Path(file)))

    @classmethod
    def from_spec(cls, text: str, rng: np.random.Generator) -> UserPolicy:
        """The policy of 'py:MODULE:CLASS' (policy_spec), its class loaded, checked and made."""
        spec = parse_policy(text)
        assert spec.module is not None and spec.class_name is not None
        pid = os.getpid()
        inner = _instance(load_class(spec.module, spec.class_name, text), rng, text)
        _end_if_forked(pid, text, "its module or constructor")
        return cls(inner, text, module_file(spec.module), pid)

    def act(self, obs: Observation) -> np.ndarray:
        seen = _read_only(obs)  # the run reads obs again after act (probe 11, M5: nums set to 10**9 hung it; 12, N5)
        actions = _users(lambda: self.inner.act(seen), f"{self.text}: act(obs) raised")  # issue 82, probe 9 (K10)
        _end_if_forked(self.pid, self.text, "act(obs)")
        try:
            return checked_actions(actions, len(obs), self.text)  # runs what act gave's own code (its __array__)
        finally:
            _end_if_forked(self.pid, self.text, "what act(obs) gave")  # probe 20, TR1


def _end_if_forked(pid: int, text: str, where: str) -> None:
    """files.end_if_forked, the line naming the policy and what of it forked (probe 19, TR1)."""
    end_if_forked(pid, f"(the policy {text}: {where} forked it; the run goes on in process {pid})")


def _read_only(obs: Observation) -> Observation:
    """obs with read-only copies of its arrays (its neighbours' too): a write by the user's act is a ValueError of its
    own, and an act that makes one writeable again (flags, setflags, its base, ctypes) writes into its own copy, which
    the run never reads (issue 82, probe 12, N5: read-only views of the run's arrays were one flag away from them)."""
    def frozen(value: Any) -> Any:
        if isinstance(value, np.ndarray):
            value = value.copy()
            value.flags.writeable = False
        elif dataclasses.is_dataclass(value) and not isinstance(value, type):
            value = dataclasses.replace(value, **{f.name: frozen(getattr(value, f.name))
                                                  for f in dataclasses.fields(value)})  # fmt: skip
        return value

    return frozen(obs)  # type: ignore[no-any-return]


def _users(call: Callable[[], T], says: str, after: str = "") -> T:
    """call(), the user's code: whatever it raises (any BaseException but PASSED_ON: a GeneratorExit, a class of the
    user's own) ends in one UserPolicyError, '`says` TYPE: its first line (FILE:LINE)`after`', the line of the user's
    file where it was raised. Issue 82, probe 9 (K10): act(obs); probe 10 (L4): the attributes, what act gave."""
    try:
        return call()
    except UserPolicyError:
        raise
    except PASSED_ON:
        raise
    except BaseException as err:
        raise UserPolicyError(f"{says} {_failure(err)}{_where(err)}{after}") from None


_FILES: dict[str, str] = {}
"""the folder of each policy file of the user's loaded (its real path), and the policy text that loaded it
(_said_in_one_line)"""
_BEFORE: dict[str, Callable[..., object]] = {}
"""the hooks before coopsumo's (unraisable, thread, excepthook), which they hand every error not the user's"""
_SAID: set[str] = set()
"""the lines said already"""


def _said_in_one_line(file: str | None, text: str) -> None:
    """An error the user's code raises where no caller can catch it, from the moment its file is run: a __del__ (when
    the run drops it, or as Python exits), an atexit callback, a thread it started (at import, in its constructor,
    in act) or a weakref.finalize callback, is said in one line on stderr rather than Python's 'Exception ignored in
    ... Traceback'; the exit code is the run's (issue 82, probe 10, L4: __del__; probe 11, M4: the others; probe 12,
    N7: before the class was made, a KeyboardInterrupt or SystemExit there, a helper module beside it). An error is
    the user's when its traceback passes through a file in the policy file's folder or below it (not coopsumo's, not
    Python's); any other goes to the hook before."""
    if file is None:
        return
    _FILES.setdefault(os.path.dirname(os.path.realpath(file)), text)
    if sys.unraisablehook is not _unraisable:
        _BEFORE["unraisable"], sys.unraisablehook = sys.unraisablehook, _unraisable
    if threading.excepthook is not _thread_raised:
        _BEFORE["thread"], threading.excepthook = threading.excepthook, _thread_raised
    if sys.excepthook is not _uncaught:
        _BEFORE["uncaught"], sys.excepthook = sys.excepthook, _uncaught


def _class_file(cls: type) -> str | None:
    """The real path of the file defining cls, read without running the user's code (no attribute of the class or
    its module is looked up through a __getattr__ or a property), or None."""
    try:
        own: Any = vars(type)["__dict__"]  # the class's and the module's own dicts, past a metaclass's properties
        module = sys.modules.get(own.__get__(cls)["__module__"])
        names: Any = vars(ModuleType)["__dict__"]
        file = names.__get__(module).get("__file__") if module is not None else None
        return os.path.realpath(file) if isinstance(file, str) else None
    except PASSED_ON:
        raise
    except BaseException:  # a class or module not as Python makes them (a __module__ whose hash raises: probe 12, N8)
        return None


def _users_file(path: str) -> str | None:
    """The policy text whose file's folder holds `path` (a real path), unless it is coopsumo's or Python's, or None."""
    if path.startswith(_NOT_USERS):
        return None
    return next((text for folder, text in _FILES.items() if path.startswith(folder + os.sep)), None)


_NOT_USERS = tuple(os.path.realpath(p) + os.sep for p in {
    os.path.dirname(os.path.dirname(os.path.abspath(__file__))), sys.prefix, sys.base_prefix, sys.exec_prefix})
"""coopsumo's package and Python's own folders (its library, the environment's packages), as real paths"""


def _said(err: BaseException | None, kind: str) -> bool:
    """Print '`text`: `kind` raised TYPE: its first line (FILE:LINE)' (once a run) when err's traceback passes through
    a policy file of the user's; False (nothing said) otherwise."""
    if err is None:
        return False
    try:
        files = [os.path.realpath(f.filename) for f in traceback.extract_tb(err.__traceback__)
                 if not f.filename.startswith("<")]  # not code without a file (<string>, <frozen ...>)
    except Exception:  # a __traceback__ the user's class made something else (probe 11, M3)
        return False
    text = next(filter(None, map(_users_file, files)), None)
    if text is None:
        return False
    line = f"{text}: {kind} raised {_failure(err)}{_where(err)}"
    if line not in _SAID:  # once: a thread started at every decision would say it at every step
        _SAID.add(line)
        print(line, file=sys.stderr)
    return True


def _unraisable(unraisable: Any) -> None:
    """sys.unraisablehook: a __del__, an atexit callback or a weakref.finalize of the user's in one line"""
    found = unraisable.object
    if inspect.isfunction(found) and found.__name__ == "__del__":
        kind = "its __del__"
    elif "atexit" in (unraisable.err_msg or ""):
        kind = "its atexit callback"
    elif isinstance(found, weakref.finalize):
        kind = "its weakref.finalize callback"
    else:
        kind = "its code"
    if not _said(unraisable.exc_value, kind):
        _BEFORE["unraisable"](unraisable)


def _thread_raised(args: Any) -> None:
    """threading.excepthook: a thread the user's policy started, in one line"""
    if not _said(args.exc_value, "a thread it started"):
        _BEFORE["thread"](args)


def _uncaught(kind: type[BaseException], err: BaseException, tb: Any) -> None:
    """sys.excepthook, which a weakref.finalize callback's error reaches as Python exits: the user's in one line"""
    if not _said(err, "its weakref.finalize callback" if _at_exit(tb) else "its code"):
        _BEFORE["uncaught"](kind, err, tb)


def _at_exit(tb: Any) -> bool:
    """True when a traceback starts in weakref's exit function (a finalize callback run as Python exits)"""
    try:
        return traceback.extract_tb(tb)[0].name == "_exitfunc"
    except Exception:
        return False


def _failure(err: BaseException) -> str:
    """'TYPE: the first line of its message' of an exception the user's code raised (a message that cannot be read
    said so)."""
    try:
        line = first_line(err)[:120]
    except PASSED_ON:
        raise
    except BaseException:
        line = "(its message cannot be read)"
    return f"{_name(type(err))}: {line}"


def _name(cls: type) -> str:
    """The class's own name, past a metaclass whose __name__ raises (probe 11, M3)."""
    return str(type.__dict__["__name__"].__get__(cls, type))


def _where(err: BaseException) -> str:
    """' (FILE:LINE)', the innermost frame of the exception's traceback outside coopsumo, or ''."""
    try:
        frames = traceback.extract_tb(err.__traceback__)
    except Exception:  # a __traceback__ the user's class made something else (probe 11, M3)
        return ""
    own = os.path.dirname(os.path.abspath(__file__)).rsplit(os.sep, 1)[0]  # the coopsumo package
    outside = [f for f in frames if not os.path.abspath(f.filename).startswith(own + os.sep)]
    return f" ({outside[-1].filename}:{outside[-1].lineno})" if outside else ""


def checked_actions(actions: Any, n: int, who: str) -> np.ndarray:
    """`actions` as an int64 array of n actions 0-3; UserPolicyError naming `who` and what it gave otherwise (a ragged
    list or an object whose __array__ raises: what numpy said, by _users; issue 82, probe 10, L4)."""
    arr = _users(lambda: np.asarray(actions), f"{who}: act(obs) gave a {type(actions).__name__} that is no array of "
                 f"{n} integers, one per vehicle ({ACTIONS_TEXT}):")  # fmt: skip
    if arr.shape != (n,) or not (np.issubdtype(arr.dtype, np.integer) or (n == 0 and arr.dtype == float)):
        raise UserPolicyError(f"{who}: act(obs) gave {arr.dtype} of shape {arr.shape}; it must give {n} integers, one "
                              f"per vehicle ({ACTIONS_TEXT})")  # fmt: skip
    if n and (arr.min() < 0 or arr.max() >= len(ACTION_NAMES)):
        raise UserPolicyError(f"{who}: act(obs) gave the action {int(arr.max() if arr.max() >= 4 else arr.min())}; "
                              f"actions are {ACTIONS_TEXT}")  # fmt: skip
    return arr.astype(np.int64, copy=False)
