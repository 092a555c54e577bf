"""Run folders and study roots: markers that say which command wrote a folder and whether it finished, locks,
the checks before a command writes into a folder, and folders made whole or not at all (atomic_run_dir)."""

from __future__ import annotations

import fnmatch
import os
import re
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from coopsumo.errors import UsageError
from coopsumo.files import TEMPORARY, end_if_forked, left_temporaries, read_json, read_text, temporaries_of, write_json
from coopsumo.lock_files import ForeignLock, release_lock, try_lock
from coopsumo.paths import nets_in_out_problem, out_path_problem, outside_link
from coopsumo.provenance import package_version
from coopsumo.run_markers import (
    DIGEST,
    PARTIAL_MARKER,
    RUN_MARKER,
    a_kind,
    committed_planless,
    finished_entries,
    kind_name,
    marker_text,
    other_settings,
)
from coopsumo.run_markers import entries as _entries
from coopsumo.run_markers import read_marker as _marker

RUN_OUTPUTS = ("config.json", "summary.json", "detectors.xml", "detectors.add.xml", "routes.rou.xml", "plain.rou.xml",
               "fcd.xml", "tripinfo.xml", "trajectories.parquet", f".*{TEMPORARY}")
"""the entries a run writes into its folder (agents.rollout.run, SUMO; write_atomic's temporary files):
a study's run folder without a marker holding only these is its own (studies/engine/run_folders.check_run_places)"""


def mark_run_dir(folder: Path, kind: str, finished: bool = True, study: str | None = None,
                 digest: str | None = None) -> None:  # fmt: skip
    """Claim `folder` for the command `kind`; finished: also list what it holds (nothing else may be replaced) and, for
    a run, each file's sha256 (run_markers.finished_entries); study: which study of `kind` a study root holds ("the
    quick profile's study"), digest: its settings' (check_study_root)."""
    write_json(folder / RUN_MARKER, {"kind": kind, "version": package_version("coopsumo"), "finished": finished,
                                     **(finished_entries(folder, kind) if finished else {}),
                                     **({"study": study} if study is not None else {}),
                                     **({DIGEST: digest} if digest is not None else {})})  # fmt: skip


def listed_files(marker: Any) -> list[str] | None:
    """The entries a finished command's marker lists; None for a marker of a command still running or stopped
    ("finished" false, no "files"; an older marker's files null) and for one whose list is not a list of names."""
    if not isinstance(marker, dict) or marker.get("finished", True) is not True:
        return None
    files = marker.get("files")
    return files if isinstance(files, list) and all(isinstance(f, str) for f in files) else None


def _marker_fault(folder: Path) -> str | None:
    """What is wrong with the marker file of `folder` that _marker could not take, or None when there is none."""
    path = folder / RUN_MARKER
    if not path.exists() and not path.is_symlink():
        return None
    try:
        data = read_json(path)
    except OSError as err:
        return f"that cannot be read ({err.strerror or type(err).__name__})"
    except ValueError:
        return "that is not readable JSON (damaged)"
    return "that is not a JSON object" if not isinstance(data, dict) else "that names no command"


def _own_files(marker: dict[str, Any], kind: str) -> list[str] | None:
    """The entries `marker` says its command wrote: a finished command's list (listed_files), or, for a run
    other than a training, the list of a marker that says its run did not finish (simulate never writes one:
    a damaged marker, but its list still names the run's own files, and a study redoes such a run)."""
    listed = listed_files(marker)
    if listed is None and kind != "train" and "files" in marker:
        listed = listed_files({**marker, "finished": True})
    return listed


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
        if fault := _marker_fault(out):
            raise UsageError(f"output folder {out} has a {RUN_MARKER} {fault} and is left alone; remove it "
                             "yourself or pick another --out")  # fmt: skip
        if (out / "config.json").exists():
            raise UsageError(f"output folder {out} has no {RUN_MARKER} (written before coopsumo marked its folders, "
                             "or not by coopsumo) and is left alone: remove it yourself or pick another --out")
        raise UsageError(f"output folder {out} is not empty and is not a coopsumo run folder; pick another --out")
    if marker["kind"] != kind:
        raise UsageError(f"output folder {out} holds a coopsumo {marker['kind']} run, not a {kind} run, and is "
                         "left alone; pick another --out")  # fmt: skip
    listed = _own_files(marker, kind)
    running = marker.get("finished") is False or marker.get("files") is None  # as a training marks it while it runs
    if listed is None and not (kind == "train" and running):  # only a training marks its folder before it ends
        what = "says its run did not finish and lists no files" if marker.get("finished") is False else \
            "lists no files"
        raise UsageError(f"output folder {out} has a {RUN_MARKER} that {what} (damaged?) and is left alone; "
                         "remove it yourself or pick another --out")  # fmt: skip
    if listed is not None:
        extra = sorted(set(_entries(out)) - set(listed))
        if extra:
            more = f" and {len(extra) - 1} more" if len(extra) > 1 else ""
            raise UsageError(f"output folder {out} holds {extra[0]}{more}, which coopsumo {kind} did not write, and "
                             "is left alone; move it away or pick another --out")  # fmt: skip


def finished_run(folder: Path, kind: str) -> bool:
    """True when `folder` is a finished output of the command `kind`: its marker names `kind` and lists its
    entries (written when the command ended), and every listed entry is there."""
    marker = _marker(folder)
    listed = listed_files(marker) if marker is not None and marker["kind"] == kind else None
    return listed is not None and all((folder / f).exists() for f in listed)


Recorded = Callable[[Path], str | None]
"""recorded(root) -> the study a root written before its marker named it holds, read from its plan file, or None"""


LEARNERS = " (learner preset"
"""how a study's name goes on when it ran learner presets other than the default (run_folders.profile_study)"""


def held_study(root: Path, recorded: Recorded | None = None) -> str | None:
    """Which study the study root `root` holds: its marker's "study", else (a root marked before markers named it,
    or not marked) what recorded(root) reads from its plan file; None when neither says. A marker written before a
    study's name said its learners (LEARNERS) names the study its plan file records when that is the marker's name
    and learners: the study it was made with."""
    marker = _marker(root)
    named = marker.get("study") if marker is not None else None
    found = recorded(root) if recorded is not None else None
    if isinstance(named, str):
        return found if found is not None and found.startswith(named + LEARNERS) else named
    return found


def check_study_place(root: Path) -> None:
    """UsageError when the study root `root` lies inside a folder another command owns: another study's root, a
    simulate run's or a training's folder, the model store (owners.owned_problem, as for a single run's --out; issue
    82, probe 5, G1-G2: the study was written there, and that folder's command then refused its own folder). `root`
    itself may be a study's: check_study_root judges whose."""
    from coopsumo.owners import owned_problem

    if problem := owned_problem(root.resolve(), f"--out {root}"):
        raise UsageError(problem)


def _untold_study(root: Path, plan: str, advice: str) -> str | None:
    """Why the study root `root`, whose study held_study cannot tell, is not taken for the study that comes (a line),
    or None when nothing claims it: no marker and no plan file `plan` (a fresh folder; a study interrupted before its
    marker was written). A marker names its study from the first moment (study_root marks the root before anything
    else is written), so one that names none, or a plan file that cannot be read or names no study of this kind, is
    a study that cannot be told from another (issue 82, probe 5, G5: another learner preset's sweep replaced it)."""
    marker, plan_file = root / RUN_MARKER, root / plan
    if not os.path.lexists(marker) and not os.path.lexists(plan_file):
        return None
    said = (f"its {RUN_MARKER} names none" if _marker(root) is not None else f"its {RUN_MARKER} cannot be read") \
        if os.path.lexists(marker) else f"it has no {RUN_MARKER}"  # fmt: skip
    read = f"its {plan} cannot be read as one: damaged, cut short or edited" if os.path.lexists(plan_file) else \
        f"it has no {plan}"  # fmt: skip
    return (f"cannot tell which study output folder {root} holds ({said}, and {read}): it is left alone; remove it "
            f"yourself or {advice}")  # fmt: skip


def check_study_root(root: Path, kind: str, own: Sequence[str], study: str | None = None,
                     recorded: Recorded | None = None, advice: str = "pick another --out",
                     digest: str | None = None) -> None:  # fmt: skip
    """UsageError unless `root` lies in no folder another command owns (check_study_place) and is missing,
    empty, marked by the study `kind`, or holds the study's plan file own[0] and nothing but the study's names `own`
    (a root written before markers; fnmatch patterns: a study writes only these and never replaces its root; issue 82,
    probe 8, J3: a user's notes.txt and report.md beside a copied plan file were taken). An unmarked root without
    the plan file is taken only when it holds nothing but the temporary file of its marker's write: a first run marks
    its root before anything else, so even files named like the study's (report.md, runs.csv) or like their
    temporaries are a user's (issue 82, probe 7, I5; probe 9: a user's .report.md.abcdefgh.tmp was deleted). study:
    which study of `kind` the command writes ("the quick profile's study"): a root that holds another (held_study, with
    `recorded` for a root whose marker does not name it) is refused too, with `advice`, and so is a marked root, or one
    with a plan file, whose study cannot be told (_untold_study); the same study resumes, unless its marker records
    other settings than `digest` (run_markers.other_settings). Either way a link in it is refused (study_link), but
    the study's own links into the model store."""
    check_study_place(root)
    root = root.resolve()
    if not root.exists():
        return
    if not root.is_dir():
        raise UsageError(f"output folder {root} exists and is not a folder")
    marker = _marker(root)
    if marker is not None and marker["kind"] != kind:
        raise UsageError(f"output folder {root} holds a coopsumo {kind_name(marker['kind'])} run, not "
                         f"{a_kind(kind, 'study')}, and is left alone; pick another --out")  # fmt: skip
    unclaimed = marker is None and not (root / own[0]).is_file()  # neither marked nor a root written before markers
    marking = {p.name for p in temporaries_of(root / RUN_MARKER) if marker_text(p)}  # a first marking, killed
    names = sorted(p.name for p in root.iterdir() if p.name not in marking)
    if marker is None and (foreign := [n for n in names if not any(fnmatch.fnmatchcase(n, pat) for pat in own)]):
        more = f" and {len(foreign) - 1} more" if len(foreign) > 1 else ""
        raise UsageError(f"output folder {root} holds {foreign[0]}{more}, which coopsumo {kind_name(kind)} does not "
                         f"write, and has no {RUN_MARKER}: it is left alone; pick another --out")  # fmt: skip
    held = held_study(root, recorded) if study is not None else None
    if held is not None and held != study:
        raise UsageError(f"output folder {root} holds {held}, not {study}: a study writes into its own folder, and "
                         f"this one is left alone; {advice}")  # fmt: skip
    if study is not None and held is None and (untold := _untold_study(root, own[0], advice)):
        raise UsageError(untold)
    if study is not None and held == study and (other := other_settings(root, marker, study, digest, advice)):
        raise UsageError(other)
    if unclaimed and names and not committed_planless(root, kind):  # a first run marks its root first (probe 7, I5)
        more = f" and {len(names) - 1} more" if len(names) > 1 else ""
        raise UsageError(f"output folder {root} holds {names[0]}{more}, named like a coopsumo {kind_name(kind)} "
                         f"study's files, but neither a {RUN_MARKER} nor its {own[0]}: no study wrote it (a study "
                         "marks its folder before anything else), so it is left alone; move it away or pick another "
                         "--out")  # fmt: skip
    if found := study_link(root):
        where = "inside" if found[1].is_relative_to(root) else "outside"
        raise UsageError(f"{found[0]} is a link to {found[1]}, {where} the study's folder {root}: a study makes no "
                         "links there but its model links (through this one it would replace what is there); remove "
                         "the link or pick another --out")  # fmt: skip


STORE_LINKS = ("models", "train")
"""the folders of a study root whose entries are the study's links into the model store (studies/engine/model_store:
link_problem and check_link judge them; the store may lie anywhere)"""


def study_link(root: Path) -> tuple[Path, Path] | None:
    """The first symbolic link in the study root `root` (none followed), and where it leads, or None; the entries of
    its STORE_LINKS folders, links into the model store, are not looked into. A study makes no other link: writing
    into a run folder that is one (runs/t2/greedy_seed1 -> a user's folder, or -> runs/t2/keep_seed1, another run of
    the study) would write into, or replace, the folder it leads to."""
    root = root.resolve()
    for parent, folders, files in os.walk(root):
        here = Path(parent)
        if here.parent == root and here.name in STORE_LINKS:
            folders[:] = []
            continue
        for name in folders + files:
            path = here / name
            if path.is_symlink():
                return path, path.resolve()
    return None


@contextmanager
def study_root(root: Path, kind: str, own: Sequence[str], study: str | None = None, recorded: Recorded | None = None,
               advice: str = "pick another --out", digest: str | None = None) -> Iterator[Path]:  # fmt: skip
    """Claim the study root `root` for the block: its path checked (check_out_path), its lock held (out_lock),
    its place and ownership checked (check_study_root: of the study `study`, if given)
    and its marker written (unfinished: a study adds to it run by run), naming `study` (without one: the study it
    named before, kept) and `digest`, its profile's settings. The marker is the first thing written into the root: a
    root interrupted after it names its study."""
    check_out_path(root)
    root = root.resolve()
    check_study_root(root, kind, own, study, recorded, advice, digest)
    with out_lock(root, kind):
        check_study_root(root, kind, own, study, recorded, advice, digest)  # again, under the lock
        try:
            root.mkdir(exist_ok=True)
            ours = _marker(root) is not None  # marked before: its temporaries are the study's (an unmarked one's may
            mark_run_dir(root, kind, finished=False, study=study or held_study(root, recorded),  # be a user's: probe 9)
                         digest=digest)
            for left in left_temporaries(root, (*own, RUN_MARKER)) if ours else ():  # of its own files, from a write
                left.unlink(missing_ok=True)  # a SIGKILL cut (probe 8, J23)
        except OSError as err:
            raise UsageError(f"cannot write output folder {root}: {err.strerror}") from None
        yield root


def check_out_path(out: Path, flag: str = "--out") -> None:
    """UsageError naming `flag` when out_path_problem faults `out` or $COOPSUMO_NETS_DIR lies in it
    (nets_in_out_problem): every command's --out and every study's root, given or default."""
    problem = out_path_problem(out) or nets_in_out_problem(out)
    if problem:
        raise UsageError(f"{flag} {problem}")


PARTIAL = ".partial-"
"""infix of the temporary folder a run is built in beside its --out: '.<name>.partial-XXXXXXXX'"""


def _new_partial(out: Path) -> Path:
    """A new partial folder beside `out` ('.<name>.partial-XXXXXXXX', mkdtemp), marked as coopsumo's."""
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}{PARTIAL}", dir=out.parent))
    (tmp / PARTIAL_MARKER).write_text(f"the partial folder of a coopsumo run into {out}\n")
    return tmp


def _is_partial(entry: Path) -> bool:
    marker = entry / PARTIAL_MARKER
    return entry.is_dir() and not entry.is_symlink() and marker.is_file() and not marker.is_symlink()


_PARTIAL_NAME = re.compile(r"\.(.+)\.partial-[A-Za-z0-9_]{8}")
_LOCK_NAME = re.compile(r"\.(.+)\.lock")


def lock_path(out: Path) -> Path:
    """The lock file of the output folder `out`: '.<name>.lock' beside it."""
    return out.parent / f".{out.name}.lock"


def _holder(path: Path) -> str:
    try:
        text = read_text(path).strip()
    except (OSError, ValueError):
        return ""
    return f" ({text})" if text else ""


LOCK_WAIT_S = 1.0
"""how long a command waits for a held lock before it is refused (s): clear_partials holds another run's lock
only while it removes that run's partial folder; a command writing a folder holds it for the whole run"""


@contextmanager
def out_lock(out: Path, kind: str) -> Iterator[None]:
    """Hold the lock of the output folder `out` for the block (fcntl.flock on lock_path(out), removed after);
    UsageError in one line when another command holds it, or when a link or a file coopsumo did not write has the
    lock file's name (ForeignLock: never written into or removed). Released by the kernel if the process is killed."""
    out = out.resolve()
    path = lock_path(out)
    deadline = time.monotonic() + LOCK_WAIT_S
    while True:
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            fd = try_lock(path, kind)
        except OSError as err:
            raise UsageError(f"cannot write output folder {out}: {err.strerror}") from None
        if fd is not None or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    if fd is None:
        raise UsageError(f"another coopsumo command is writing {out}{_holder(path)}; wait for it to end or pick "
                         "another --out")  # fmt: skip
    try:
        yield
    finally:
        release_lock(fd, path)


def _remove_partial(entry: Path, prog: str) -> None:
    shutil.rmtree(entry, ignore_errors=True)
    print(f"{prog}: removed {entry}, the partial folder of an interrupted run", file=sys.stderr)


def clear_partials(parent: Path, prog: str, mine: str | None = None) -> list[Path]:
    """Remove the partial folders and lock files that killed runs left in `parent` (one line on stderr per
    folder); those of runs still going (their lock is held) are left alone, and so are a folder without the
    PARTIAL_MARKER and a lock file coopsumo did not write (lock_files.try_lock), whatever their names. mine: the
    name of the output folder whose lock the caller holds (its partial folders are removed, its lock file kept).
    Returns the folders removed."""
    removed: list[Path] = []
    try:
        entries = [p for p in parent.iterdir() if p.name.startswith(".")]
    except OSError:
        return removed
    for entry in entries:
        found = _PARTIAL_NAME.fullmatch(entry.name)
        is_partial = found is not None and _is_partial(entry)
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
            fd = try_lock(path, prog)
        except (OSError, ForeignLock):
            continue  # not a lock file coopsumo made: left alone
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
        return _new_partial(out)
    except OSError as err:
        raise UsageError(f"cannot write output folder {out}: {err.strerror}") from None


def finish_run_dir(tmp: Path, out: Path, kind: str = "simulate") -> None:
    """Mark the finished run and move it into place, replacing an earlier run of `kind` in the same folder.

    The earlier folder is removed only if it is still ours by check_run_dir (marker of `kind`, nothing
    added); else the new run is discarded and UsageError raised.
    """
    out = out.resolve()
    (tmp / PARTIAL_MARKER).unlink(missing_ok=True)
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
    aside = _new_partial(out)
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
    pid = os.getpid()  # a copy a policy forked neither finishes nor discards the run (issue 82, probe 20, TR1)
    with out_lock(out, kind):
        tmp = start_run_dir(out, kind)
        try:
            yield tmp
        except BaseException:
            end_if_forked(pid, f"without touching {out}")
            discard_run_dir(tmp)
            raise
        end_if_forked(pid, f"without touching {out}")
        finish_run_dir(tmp, out, kind)
