"""Folders that are not a command's to write into: those a coopsumo marker claims (a study's root, a simulate run's or
a training's folder) and the model store. One check (owned_problem) for every path a command writes beside its own
folder's: a single run's --out (simulate, train), a study's root (run_dirs.check_study_place: every study's --out),
history's --out file, the networks folder (--nets-dir, $COOPSUMO_NETS_DIR); and one (claimed_problem) for the model
store ($COOPSUMO_MODELS, or `models` beside a study's root), which no marker may claim."""

from __future__ import annotations

import os
import re
from pathlib import Path

from coopsumo.paths import NETS_ENV, STORE_ENV
from coopsumo.run_markers import PARTIAL_MARKER, PLANLESS_TITLES, RUN_KINDS, RUN_MARKER, kind_name, marker_kind

DEFAULT_STORE = Path("results") / "models"
"""the committed studies' model store"""
STORE_NAME = re.compile(r".+_a[^_/]+_seed\d+_[0-9a-f]{12}")
"""the name of a model's folder in the store (model_store.model_id: <preset>_a<alpha>_seed<seed>_<digest>)"""


DAMAGED = "damaged"
"""the kind _marked gives a folder whose marker cannot be read: coopsumo's all the same (issue 82, probe 8, J2)"""


def _marked(real: Path, itself: bool, study: bool) -> tuple[Path, str] | None:
    """The nearest folder holding `real` (`real` too when itself) whose marker names a study (study) or a single
    run (not study), and that kind; a marker that cannot be read counts as a study's (DAMAGED); None."""
    for folder in [real] * itself + list(real.parents):
        kind = marker_kind(folder)
        if kind is None and study and os.path.lexists(folder / RUN_MARKER):
            return folder, DAMAGED
        if kind is not None and (kind not in RUN_KINDS) == study:
            return folder, kind
    return None


STORE_MARK = ".coopsumo-store"
"""the file a model store holds from its first model on (mark_store): emptied of its models (`rm -rf store/*`), it is
still a store, whatever path names it (issue 82, probe 12, N1: the target of a link `models -> elsewhere`)"""


def mark_store(store: Path) -> None:
    """Put STORE_MARK into the model store `store` (a folder) unless it is there."""
    try:
        fd = os.open(store / STORE_MARK, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    except FileExistsError:
        return
    with os.fdopen(fd, "w") as f:
        f.write("a coopsumo model store: the studies' models, which only the studies write (`coopsumo models`)\n")


def _holds_models(folder: Path) -> bool:
    """True when `folder` holds a store model's folder or lock, or the store's mark (a model store)."""
    try:
        names = [p.name for p in folder.iterdir()]
    except OSError:
        return False
    return any(STORE_NAME.fullmatch(name) or STORE_NAME.fullmatch(name[1:].removesuffix(".lock")) or name == STORE_MARK
               for name in names)  # fmt: skip


def _marked_store(folder: Path) -> bool:
    return (folder / STORE_MARK).is_file()


def _in_partial(real: Path, itself: bool) -> Path | None:
    """The nearest folder holding `real` (`real` too when itself) that is a run's partial folder (it holds the
    PARTIAL_MARKER file: a run's next start in its parent removes it, with whatever was put in it; issue 82, probe 9:
    a model store and a screenshot there were deleted), or None."""
    return next((f for f in [real] * itself + list(real.parents) if (f / PARTIAL_MARKER).is_file()), None)


def _beside_a_study(folder: Path) -> bool:
    """True when `folder` is named `models` and lies beside a study's root (its marker's kind a study's): that
    study's model store, even when it holds no model yet or any more (issue 82, probe 9: a run written into an
    emptied store made the study refuse its store)."""
    if folder.name != "models":
        return False
    try:
        siblings = [p for p in folder.parent.iterdir() if p.is_dir() and not p.is_symlink()]
    except OSError:
        return False
    return any((kind := marker_kind(p)) is not None and kind not in RUN_KINDS for p in siblings)


def _in_store(real: Path, what: str, itself: bool, given: Path | None = None) -> str | None:
    """Why `real` may not be written for being in a model store (a phrase starting with `what`), or None: in
    $COOPSUMO_MODELS or results/models, in (or named as) a store model's folder, in a folder holding store models, in
    the `models` beside a study; `given`, the path as given (links not resolved): that `models` may be a link to a
    store kept elsewhere (issue 82, probe 11, M1: an emptied store so linked took a run)."""
    env = os.environ.get(STORE_ENV)
    for store in [DEFAULT_STORE.resolve(), *([Path(env).resolve()] if env else [])]:
        if real.is_relative_to(store):
            return f"{what} is in the model store {store}, which only the studies write"
    for folder in (real, *real.parents):
        if STORE_NAME.fullmatch(folder.name):
            return (f"{what} leads into {folder}, a model of a model store (a study's model link?), which only the "
                    "studies write")  # fmt: skip
    linked = [f for f in ([given, *given.parents] if given else []) if f.is_symlink()]
    for folder in [real, *real.parents, *linked]:  # any depth: models/sub/run, models/.x/run (probe 8)
        # an emptied store beside a study is one as an --out too (probe 10, L3: a run's marker made it refused)
        # the folder itself too once it is marked: an emptied store (probe 12, N1: its link's target as --out)
        if (folder not in linked and (folder != real or itself or _marked_store(folder)) and _holds_models(folder)) \
                or _beside_a_study(folder):
            return f"{what} is in {folder}, a model store (it holds the studies' models), which only the studies write"
    return None


def _claim_line(real: Path, found: tuple[Path, str], what: str, advice: str) -> str:
    """`what` is or lies inside found[0], claimed by the coopsumo command or study found[1], which alone writes it."""
    where = "is" if found[0] == real else "lies inside"
    if found[1] == DAMAGED:
        return (f"{what} {where} {found[0]}, whose {RUN_MARKER} cannot be read (a coopsumo run's or study's folder, "
                f"damaged?), which no other command writes; {advice}")  # fmt: skip
    if found[1] in RUN_KINDS:
        return (f"{what} {where} {found[0]}, the folder of a coopsumo {found[1]} run, which only that command writes; "
                f"{advice}")  # fmt: skip
    return (f"{what} {where} {found[0]}, a coopsumo {kind_name(found[1])} study's folder, which only that study "
            f"writes; {advice}")  # fmt: skip


def owned_problem(path: Path, what: str, advice: str = "pick another --out", itself: bool = False) -> str | None:
    """Why a command may not write `path` (what: the flag and value naming it, advice: what to do instead), or None:
    `path`, its links resolved, lies inside a study's root, in the model store or in a single run's folder (a
    simulate run's, a training's), or inside a study's root written before markers (unmarked_study_problem;
    issue 82, probe 8: `simulate --out P/sim` inside a committed protocol study); itself: `path` is not the command's
    own folder, so it may not be one of these either (the networks folder). The study's folder is named first (a run
    inside it is the study's)."""
    real = path.expanduser().resolve()
    if found := _marked(real, itself, study=True):
        return _claim_line(real, found, what, advice)
    if partial := _in_partial(real, itself):
        return f"{what} lies inside {partial}, the folder a coopsumo run is built in (or was, when killed); {advice}"
    if problem := _in_store(real, what, itself, Path(os.path.abspath(path.expanduser()))):
        return f"{problem}; {advice}"
    if found := _marked(real, itself, study=False):
        return _claim_line(real, found, what, advice)
    return unmarked_study_problem(real, what, advice)


def claimed_problem(path: Path, what: str, advice: str) -> str | None:
    """Why `path` may not be written for being, or lying inside, a folder a coopsumo marker claims (a study's root, a
    simulate run's or a training's folder), or None; the study's folder named first. The check of the model store's
    place (claimed_problem of the store: $COOPSUMO_MODELS, model_store.store_for): a study training into a folder a
    run or another study owns would fill it with models, and its command would then refuse its own folder (issue 82,
    probe 5, G3)."""
    real = path.expanduser().resolve()
    found = _marked(real, True, study=True) or _marked(real, True, study=False)
    if not found and (partial := _in_partial(real, True)):
        return f"{what} lies inside {partial}, the folder a coopsumo run is built in (or was, when killed); {advice}"
    return _claim_line(real, found, what, advice) if found else unmarked_study_problem(real, what, advice)


def store_env_problem() -> str | None:
    """claimed_problem of $COOPSUMO_MODELS, as a line naming it (runio.run_cli, beside nets_env_problem), or None."""
    value = os.environ.get(STORE_ENV)
    problem = claimed_problem(Path(value), repr(value), "pick a model store elsewhere") if value else None
    return f"${STORE_ENV} {problem}" if problem else None


def tmp_env_problem() -> str | None:
    """owned_problem of $TMPDIR (itself included: a study's root, a run's folder, the model store), as a line naming
    it (runio.run_cli), or None: bench's trainings and sumo-gui's screenshot run are made there, and one killed left
    its folder in a model store, which every study then refused (issue 82, probe 9, K9)."""
    value = os.environ.get("TMPDIR")
    advice = "pick a temporary folder elsewhere"
    problem = owned_problem(Path(value), repr(value), advice, itself=True) if value else None
    return f"$TMPDIR {problem}" if problem else None


def nets_problem(text: str) -> str | None:
    """Why `text` cannot be the networks folder for being, or lying in, a folder a study, a run or the model store owns
    (a phrase to follow --nets-dir or $COOPSUMO_NETS_DIR), or None: the networks SUMO builds there would be taken for
    files their folder's command did not write (issue 82, probe 4, F18: every study then refused the store)."""
    return owned_problem(Path(text), repr(text), "pick a networks folder elsewhere", itself=True)


def nets_env_problem() -> str | None:
    """nets_problem of $COOPSUMO_NETS_DIR, as a line naming it (runio.run_cli, beside paths.env_problem), or None."""
    value = os.environ.get(NETS_ENV)
    problem = nets_problem(value) if value else None
    return f"${NETS_ENV} {problem}" if problem else None


PLAN_FILES = ("plan.json", "sweep.json", "study.json")
"""the plan files of the studies' roots (run_folders.STUDY_OUTPUTS' first names): with cells/, runs.csv or report.md
beside (the committed studies keep no cells/), a study's root"""


def _planless_report(folder: Path) -> str | None:
    """'report.md' when `folder`'s report.md begins as a study committed without a plan file does (PLANLESS_TITLES:
    issue 82, probe 9, K8: a copy of results/regime_map took a simulate run), else None."""
    if not (folder / "report.md").is_file():  # a regular file only: a pipe there is not waited on
        return None
    try:
        with open(folder / "report.md", encoding="utf-8") as report:
            first = report.readline(200).rstrip("\n")
    except (OSError, UnicodeDecodeError):
        return None
    return "report.md" if first in PLANLESS_TITLES.values() else None


def unmarked_study_problem(path: Path, what: str, advice: str) -> str | None:
    """Why `path` may not be written for lying inside a study's root written before markers (no marker: a plan file
    beside its cells/, runs.csv or report.md, as the committed results/learner_protocol_* hold them), or None (issue
    82, probe 7, I14: history's --out table was written into such a protocol study's folder; owned_problem sees only
    marked folders)."""
    real = path.expanduser().resolve()
    for folder in real.parents:
        plan = next((name for name in PLAN_FILES if (folder / name).is_file()), None) or _planless_report(folder)
        if plan is not None and any(os.path.lexists(folder / name) for name in ("cells", "runs.csv", "report.md")):
            return (f"{what} lies inside {folder}, a coopsumo study's folder (its {plan}, written before markers), "
                    f"which only that study writes; {advice}")  # fmt: skip
    return None
