"""The model store: every trained model lives once, in a folder named by what made it (its identity: the results
view of its TrainConfig), `<preset>_a<alpha>_seed<seed>_<digest>`; every study takes it from there, through a link
in its own folder (e.g. OUT/train/<key>). The store is the folder `models` beside the study's results folder, or
$COOPSUMO_MODELS. A stored model is used only when it is whole and its identity's (trainings.finished_training); a
hand-edited or truncated one is trained again in its folder, a killed one resumes exactly from its checkpoint
(train_resuming: the learner gets the study's typed TrainConfig as it is, the store names it by its data), and
nothing else in the store is touched. A model that differs from a stored one only in how its snapshots are judged
(selection.SELECTION_FIELDS) is not trained: the stored snapshots are validated again (reselectable).
"""
from __future__ import annotations

import hashlib
import json
import os
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from coopsumo.config import TrainConfig, as_data, results_view
from coopsumo.errors import UsageError
from coopsumo.files import read_json
from coopsumo.paths import STORE_ENV
from coopsumo.validation import number_name

GROUP_COST = "group_cost.json"
"""written into each model trained in a group (engine/groups.py): {"group_size": K, "cpu_s": its CPU seconds over K}"""
FIRST_TRAIN_SEED = 100
"""training seeds of the studies' models are 100, 101, ...: none of the evaluation seeds (1-5, 5000+) nor the
validation seed"""


def store_for(root: Path) -> Path:
    """The store a study with results folder root uses: $COOPSUMO_MODELS, else the folder `models` beside root.
    UsageError when that path is not a store's to write: it is, or lies inside, a folder a coopsumo marker claims (a
    training's, a simulate run's, a study's: owners.claimed_problem; issue 82, probe 5, G3), or it holds what a store
    does not (store_problem); and when it is root or lies inside it, the study's own folder, checked before the study
    writes anything (issue 82, probe 7, I12: `--out models` was refused only after its marker and plan were written)."""
    from coopsumo.owners import claimed_problem

    env, real = os.environ.get(STORE_ENV), Path(root).resolve()
    store = Path(env) if env else real.parent / "models"
    where = f"${STORE_ENV}" if env else f"beside {root}"
    advice = f"pick another --out or set ${STORE_ENV} to a store elsewhere"
    if store.resolve() == real or store.resolve().is_relative_to(real):
        raise UsageError(f"the model store {store} ({where}) {'is' if store.resolve() == real else 'lies inside'} "
                         f"{root}, the study's own --out, which holds its results, not models; {advice}")  # fmt: skip
    if problem := claimed_problem(store, f"the model store {store} ({where})", advice):
        raise UsageError(problem)
    if problem := store_problem(store):
        raise UsageError(f"the model store {store} ({where}) {problem}; move it away, pick another --out or set "
                         f"${STORE_ENV} to a store")  # fmt: skip
    return store


def store_problem(store: Path) -> str | None:
    """Why the folder `store` is not a model store a study may write, or None: it is missing (made when a model is
    stored), or a folder whose visible entries are all store models (owners.STORE_NAME, folders); its dot-entries
    are the store's locks and partial folders, none a link (_lock_problem). A user's file or folder there is left
    alone, and so is a link named like a model (is_dir follows it: a study would train into the folder it leads
    to)."""
    from coopsumo.owners import STORE_NAME

    if not os.path.lexists(store):
        return None
    if not store.is_dir():
        return "exists and is not a folder"
    try:
        entries = list(store.iterdir())
    except OSError as err:
        return f"cannot be read ({err.strerror})"
    if links := sorted(p.name for p in entries if p.is_symlink() and STORE_NAME.fullmatch(p.name)):
        return f"holds {links[0]}, a link (to a training of the user's?) where the store keeps only its own folders"
    foreign = sorted(p.name for p in entries if not p.name.startswith(".")
                     and not (STORE_NAME.fullmatch(p.name) and p.is_dir() and not p.is_symlink()))  # fmt: skip
    more = f" and {len(foreign) - 1} more" if len(foreign) > 1 else ""
    if foreign:
        return f"holds {foreign[0]}{more}, which is not a stored model"
    return _lock_problem(store, sorted(p.name for p in entries if p.name.startswith(".")))


def _lock_problem(store: Path, names: list[str]) -> str | None:
    """Why a dot-entry of the store is not the store's, or None: a link (the store makes none), or a file named
    like a model's lock ('.MODEL.lock') that coopsumo did not write (lock_files.not_a_lock)."""
    from coopsumo.lock_files import not_a_lock

    for name in names:
        path = store / name
        if path.is_symlink():
            return f"holds {name}, a link to {os.path.realpath(path)}, which the store does not make"
        if name.endswith(".lock") and (why := not_a_lock(path, empty_ok=True)):
            return f"holds {name}, which {why} and is not a lock file coopsumo made"
    return None


def identity(config: dict[str, Any]) -> dict[str, Any]:
    """What identifies a model: the results view of its TrainConfig dict (JSON round trip)."""
    return results_view(json.loads(json.dumps(config)))


def model_id(config: dict[str, Any]) -> str:
    """The store folder name of the training `config` (a TrainConfig dict)."""
    ident = identity(config)
    digest = hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest()[:12]
    dqn, sim = ident.get("dqn", {}), ident.get("sim", {})
    alpha = "c" if dqn.get("alpha_conditioned") else number_name(float(sim.get("reward", {}).get("alpha", 0.0)))
    return f"{dqn.get('preset', 'dqn')}_a{alpha}_seed{sim.get('seed')}_{digest}"


def stored_model(config: dict[str, Any], store: Path, link: Path | None = None) -> Path | None:
    """The stored folder of the training `config` when the store holds it whole (trainings.finished_training), with
    `link` made a link to it; None when it must be trained (absent, unfinished, or not this identity's)."""
    from coopsumo.studies.engine.trainings import finished_training

    folder = store / model_id(config)
    check_entry(folder)
    if link is not None:
        check_link(link)  # before anything is read: a real folder there is the user's
    if not folder.is_dir() or identity(config).get("eval_steps", 0) != 0:
        return None
    if finished_training(folder, config, quiet=True) is None:  # the training cell says why, once
        return None
    if link is not None:
        _link(link, folder)
    return folder


def train_shared(cfg: TrainConfig, out: Path, store: Path) -> tuple[dict[str, Any], int | None]:
    """The model of the training `cfg` from `store`, trained (or resumed) there first if it is not whole. The store
    names and judges it by its data (config.as_data, here at the store's edge); the learner gets `cfg` as it is.

    Under a lock per model, so that cells and studies asking at once (the margin variants, a conditioned model's
    alphas, scenario I and the protocol) train it once. out, the study's own training folder, becomes a link to the
    stored one; a real folder there is never deleted, moved or trained into (check_link).
    Returns (train summary, step resumed from or None).
    """
    from coopsumo.owners import mark_store
    from coopsumo.studies.engine.trainings import finished_training

    check_link(out)
    store.mkdir(parents=True, exist_ok=True)
    config = as_data(cfg)
    folder = store / model_id(config)
    with _locked(store / f".{folder.name}.lock"):
        check_link(out)  # again under the lock
        check_entry(folder)
        mark_store(store)  # as it takes its first model (owners.STORE_MARK)
        folder.mkdir(exist_ok=True)
        _link(out, folder)  # before training: its checkpoint shows through the study's folder
        if finished_training(folder, config, quiet=True) is None:
            if (src := reselectable(cfg, store)) is not None:
                return _reselect(src, folder, cfg), None
            import sys

            print(f"coopsumo: training {folder.name} in the model store {store.resolve()} (`coopsumo models` lists "
                  "it)", file=sys.stderr)  # written outside the study's folder: said where
        return train_resuming(cfg, folder)


def train_resuming(cfg: TrainConfig, out: Path) -> tuple[dict[str, Any], int | None]:
    """Train `cfg` into out, resuming a checkpoint there made with exactly this configuration (judged by its data).

    Returns train()'s summary and the step resumed from (None: started afresh). A stop by signal
    becomes KeyboardInterrupt.
    """
    import torch

    from coopsumo.agents.train import Interrupted, train
    from coopsumo.studies.engine.trainings import finished_training

    torch.set_num_threads(1)
    config = as_data(cfg)
    out.mkdir(parents=True, exist_ok=True)
    if cfg.eval_steps == 0 and (stored := finished_training(out, config)) is not None:
        return stored, cfg.sim.steps
    resumed_from = resumable_step(config, out)
    try:
        summary = train(cfg, out, resume=resumed_from is not None, progress=False)
    except Interrupted as err:
        raise KeyboardInterrupt(str(err)) from err
    return summary, resumed_from


def resumable_step(config: dict[str, Any], out: Path) -> int | None:
    """The step of a checkpoint in out made with exactly the training `config`, or None (none, damaged, another's):
    then the training starts afresh."""
    from coopsumo.agents.train import Trainer

    if not (out / "checkpoint.pt").exists():
        return None
    try:
        state = Trainer.load_checkpoint(out)
        if results_view(json.loads(json.dumps(state["config"]))) == results_view(config):
            return int(state["step"])
    except Exception:  # a damaged checkpoint: start afresh
        return None
    return None


def without_selection(config: dict[str, Any]) -> dict[str, Any]:
    """A training's identity without the settings that only judge its snapshots (selection.SELECTION_FIELDS)."""
    from coopsumo.agents.selection import trained_part

    ident = identity(config)
    ident["dqn"] = trained_part(ident.get("dqn", {}))
    return ident


def reselectable(cfg: TrainConfig, store: Path) -> Path | None:
    """A whole stored training that differs from the training `cfg` only in how snapshots are judged, or None:
    then `cfg`'s model is that training's snapshots validated again, and nothing is trained. Only for a training
    that selects its model (agents/selection.selecting) and has no evaluation of its own."""
    from coopsumo.agents.selection import selecting
    from coopsumo.studies.engine.trainings import finished_training

    if not selecting(cfg) or cfg.eval_steps != 0:
        return None
    config = as_data(cfg)
    wanted, name = without_selection(config), model_id(config)
    for folder in sorted(p for p in store.iterdir() if p.is_dir() and not p.is_symlink() and not p.name.startswith(".")
                         and p.name != name):  # fmt: skip
        try:
            other = read_json(folder / "config.json")["config"]
        except (OSError, ValueError, KeyError, TypeError):
            continue
        if without_selection(other) == wanted and model_id(other) == folder.name \
                and finished_training(folder, other, quiet=True) is not None:  # fmt: skip
            return folder
    return None


def _reselect(src: Path, folder: Path, cfg: TrainConfig) -> dict[str, Any]:
    """The model of `cfg` from the snapshots of `src` (selection.reselect), under its lock (a training of src
    cannot change it meanwhile)."""
    from coopsumo.agents.selection import reselect

    print(f"coopsumo: {folder.name}: the snapshots of {src.name} judged again (they differ only in model selection; "
          "nothing is trained)", file=sys.stderr)  # fmt: skip
    with _locked(src.parent / f".{src.name}.lock"):
        return reselect(src, folder, cfg)


@contextmanager
def _locked(path: Path) -> Iterator[None]:
    """An exclusive lock on the file `path` (waited for), removed when released: a waiter that locked a file already
    removed opens the path again, so the lock file never outlives the holders. A link or a file coopsumo did not
    write of that name is refused (lock_files.ForeignLock, a UsageError), never written into or removed; an empty
    file is a lock of an earlier version (they were written empty)."""
    from coopsumo.lock_files import release_lock, try_lock

    fd = try_lock(path, "store", wait=True, empty_ok=True)
    assert fd is not None  # waited for
    try:
        yield
    finally:
        release_lock(fd, path)


def check_entry(folder: Path) -> None:
    """UsageError naming `folder`, a model's folder in the store, when it is a link: the store makes only folders,
    so a link there leads to someone's folder (a user's training), which is never trained into or replaced; and when
    it is not a training's to write (foreign_entry)."""
    if folder.is_symlink():
        raise UsageError(f"{folder} is a link to {folder.resolve()} where the model store keeps its own folder of "
                         "that model; it is left alone: remove the link and run again")  # fmt: skip
    if (problem := foreign_entry(folder)) is not None:
        raise UsageError(f"{folder}, a model's folder in the model store, {problem}, and is left alone (a training "
                         "there would replace it, write through it or list it as its own): move it away and run "
                         "again")  # fmt: skip


def foreign_entry(folder: Path) -> str | None:
    """Why the store's model folder `folder` holds what no training writes (a phrase), or None: a file where the
    folder belongs, a marker of another command, or, at any depth, an entry that is not a training's or a link
    (training_files.foreign_entry, with the group's GROUP_COST; issue 82, probe 7, I6: a user's folder of that name
    was trained into, and a retrain listed notes.txt as its own; probe 8, J4, J6: a user's snapshots/step100/notes.txt
    was deleted by a retrain, and a link sumo -> . had SUMO write into the folder itself)."""
    from coopsumo.agents.training_files import foreign_entry as training_entry
    from coopsumo.run_markers import kind_name, marker_kind

    if not folder.is_dir():
        return "is a file" if os.path.lexists(folder) else None
    if (kind := marker_kind(folder)) not in (None, "train"):
        return f"is the folder of a coopsumo {kind_name(kind)} run"
    return training_entry(folder, also=(GROUP_COST,))


def check_link(link: Path) -> None:
    """UsageError naming `link`, a study's model folder (models/<name>, train/<key>), when it is there and is not a
    link: the study makes only links there, so a real folder (a training copied in, a folder of notes) or a file is
    the user's, and is never deleted, moved into the store or trained into."""
    from coopsumo.errors import UsageError

    if os.path.lexists(link) and not link.is_symlink():
        what = "a folder" if link.is_dir() else "a file"
        raise UsageError(f"{link} is {what} the study did not make (it makes a link into the model store there) "
                         "and is left alone; move it away and run the study again")  # fmt: skip


def link_problem(link: Path, config: dict[str, Any]) -> str | None:
    """Why the study's model link `link` (train/<key>, models/<name>) does not lead to the model of the training
    `config`, or None: it leads to no folder, to a folder not named for this training (model_id: another model, a
    training folder of the user's), to one outside the study's store (store_for: a study folder copied with its links
    into the other study's store, which the copy would then depend on) or to one whose config.json records another
    training (identity; a config.json that is missing or unreadable is finished_training's to judge when the model is
    used). A study reusing a result of that model runs it again, which makes the link lead to its model once more
    (_link). Not a link: None (a real folder there is check_link's)."""
    if not link.is_symlink():
        return None
    target = link.resolve()
    if not target.is_dir():
        return f"leads to {target}, which is not a folder (the stored model moved or removed?)"
    if target.name != (name := model_id(config)):
        return f"leads to {target}, not to {name}, the model of its training (pointed at another model?)"
    if target.parent != (store := store_for(link.parent.parent).resolve()):  # issue 82, probe 13, F9 (s2_rawcopy)
        return f"leads to {target}, outside the study's model store {store} (a study copied with its links?)"
    try:
        recorded = read_json(target / "config.json")["config"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if identity(recorded) != identity(config):
        return f"leads to {target}, whose config.json records another training than its name (edited?)"
    return None


def repointed_trainings(root: Path, specs: Sequence[dict[str, Any]], prog: str) -> set[str]:
    """The cells of `specs` (records otherwise reusable) whose training's link, ROOT/train/<training>, does not lead to
    that training's model (link_problem: pointed at another training's store folder, at a file): each is run again,
    which links its model back, with one line per training naming the link and its cells. Scenario II's repointed for
    the study that draws its trainings' logs (the protocol; issue 82, probe 6, H4: every cell was reused and
    their figures and diagnosis.csv drew the other training's logs)."""
    from coopsumo.studies.engine.trainings import rerun_cells

    def problem(link: Path, config: dict[str, Any]) -> tuple[Path, str] | None:
        return None if (why := link_problem(link, config)) is None else (link, why)

    return rerun_cells(root, specs, prog, problem, "which link its model back")


def _link(link: Path, folder: Path) -> None:
    """link -> folder (absolute), replacing a link to elsewhere (never anything else: check_link); a race with
    another cell is harmless. The temporary link it is made as is removed if that fails."""
    check_link(link)
    target = folder.resolve()
    if link.is_symlink() and Path(os.readlink(link)) == target:
        return
    link.parent.mkdir(parents=True, exist_ok=True)
    tmp = link.parent / f".{link.name}.{os.getpid()}.link"
    tmp.unlink(missing_ok=True)
    try:
        tmp.symlink_to(target, target_is_directory=True)
        os.replace(tmp, link)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
