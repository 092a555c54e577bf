"""Issue 67: nothing a user made is overwritten or deleted by a command that did not make it.

Each data-loss path of the issue, closed and pinned: a new training over an interrupted or finished one, `train
--out` into the model store or a study's model link, a study's `models/<name>` that is a real folder, a training
folder whose outputs are links leading outside it. Every case ends in one line, and the user's files are there
byte for byte afterwards (the fault injection: the command is run against them)."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
import torch

from coopsumo.agents import train_cli
from coopsumo.agents.model_file import load_model
from coopsumo.agents.train import Trainer, model_meta, train
from coopsumo.config import SimConfig, TrainConfig, to_dict
from coopsumo.dqn_config import DQN_PRESETS
from coopsumo.files import write_json
from coopsumo.run_dirs import finished_run, mark_run_dir

pytestmark = pytest.mark.sumo
TINY = TrainConfig(sim=SimConfig(steps=40, seed=3, policy="dqn"), dqn=DQN_PRESETS["paper"], eval_steps=0,
                   log_every_steps=20)  # fmt: skip
"""a training of 40 steps (about a second)"""
OTHER = replace(TINY, sim=replace(TINY.sim, seed=4))


def as_json(cfg: TrainConfig) -> dict[str, Any]:
    """A configuration as a study's cell holds it (read back from JSON)."""
    return dict(json.loads(json.dumps(to_dict(cfg))))


def snapshot(folder: Path) -> dict[str, str]:
    """Every entry under folder: a file's sha256, a link's target, 'dir' for a folder."""
    def entry(p: Path) -> str:
        if p.is_symlink():
            return "-> " + os.readlink(p)
        return "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()

    return {str(p.relative_to(folder)): entry(p) for p in sorted(folder.rglob("*"))}


def one_line(capsys: pytest.CaptureFixture[str], code: int, *fragments: str, exit_code: int = 2) -> str:
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == exit_code and len(lines) == 1 and "Traceback" not in err, (code, err)
    assert all(f in lines[0] for f in fragments), (fragments, lines[0])
    return lines[0]


@pytest.fixture(scope="module")
def finished(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished training folder (train() of TINY), with a user's notes added to it."""
    out = tmp_path_factory.mktemp("finished") / "run"
    train(TINY, out, progress=False)
    assert finished_run(out, "train")
    return out


def interrupted_at_start(out: Path, cfg: TrainConfig = TINY) -> None:
    """A training folder as a training killed right after its start leaves it: its marker, config.json and the
    checkpoint of step 0."""
    out.mkdir(parents=True)
    mark_run_dir(out, "train", finished=False)
    write_json(out / "config.json", model_meta(cfg))
    Trainer(cfg, out, progress=False).save_checkpoint()


def interrupted_in_evaluation(out: Path, finished: Path) -> None:
    """A training interrupted in its evaluation: model.pt written, its checkpoint still there, not marked done."""
    shutil.copytree(finished, out)
    mark_run_dir(out, "train", finished=False)
    Trainer(TINY, out, progress=False).save_checkpoint()


def killed_retrain(out: Path, finished: Path, cfg: TrainConfig = TINY) -> None:
    """A finished training with, beside it, the killed new training of its configuration an earlier coopsumo built
    there (`cfg`: another training put there by hand)."""
    shutil.copytree(finished, out)
    interrupted_at_start(out.parent / f".{out.name}.retrain", cfg)


FOLDERS: dict[str, tuple[Callable[[Path, Path], None], str]] = {
    "interrupted": (lambda out, _: interrupted_at_start(out), "there is an interrupted training here: --resume, "
                                                              "or another --out"),
    "interrupted in its evaluation": (interrupted_in_evaluation, "there is an interrupted training here"),
    "a killed retrain beside a finished one": (killed_retrain, "there is an interrupted training here"),
    "finished": (lambda out, src: shutil.copytree(src, out), "there is a finished training here"),
    "a model.pt, the marker unfinished": (lambda out, src: (shutil.copytree(src, out),
                                                            mark_run_dir(out, "train", finished=False)),
                                           "there is a finished training here"),
}  # fmt: skip
"""folder states a new training must not start over on -> what the refusal says"""
COMMANDS = {
    "the same command": ["--steps", "40", "--seed", "3", "--eval-steps", "0", "--preset", "paper"],
    "another --steps": ["--steps", "90000"],
    "another seed and preset": ["--seed", "9"],
}


@pytest.mark.parametrize("command", sorted(COMMANDS))
@pytest.mark.parametrize("state", sorted(FOLDERS))
def test_a_new_training_never_starts_over_on_an_interrupted_or_finished_one(
    state: str, command: str, finished: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    make, fragment = FOLDERS[state]
    out = tmp_path / "run"
    make(out, finished)
    before = snapshot(tmp_path)
    code = train_cli.main([*COMMANDS[command], "--quiet", "--out", str(out)])
    one_line(capsys, code, f"--out {out}", fragment)
    assert snapshot(tmp_path) == before  # byte for byte, and nothing beside it (no lock file)


def test_an_unfinished_training_with_nothing_to_lose_is_started_again(tmp_path: Path) -> None:
    """A training killed before its first checkpoint leaves its marker and config.json only: a new one may go."""
    out = tmp_path / "run"
    out.mkdir()
    mark_run_dir(out, "train", finished=False)
    write_json(out / "config.json", model_meta(TINY))
    args = ["--steps", "40", "--eval-steps", "0", "--preset", "paper", "--quiet", "--out", str(out)]
    assert train_cli.main(args) == 0
    assert finished_run(out, "train")


def test_the_studies_still_train_again_over_their_own_folders(finished: Path, tmp_path: Path) -> None:
    """The refusal is the command's: train() itself, which the model store calls to train a damaged model again in
    its folder, still starts over there, and resumes an interrupted one."""
    from coopsumo.studies.engine.model_store import train_resuming

    damaged = tmp_path / "damaged"
    shutil.copytree(finished, damaged)
    (damaged / "model.pt").write_bytes(b"cut short")
    summary, resumed = train_resuming(TINY, damaged)
    assert resumed is None and summary["steps"] == 40 and finished_run(damaged, "train")
    again, first = load_model(damaged / "model.pt")[0].state_dict(), load_model(finished / "model.pt")[0].state_dict()
    assert all(torch.equal(again[k], first[k]) for k in first)  # the same seed's weights
    stopped = tmp_path / "stopped"
    interrupted_at_start(stopped)
    _, resumed = train_resuming(TINY, stopped)
    assert resumed == 0 and finished_run(stopped, "train")


def test_resume_finishes_the_retrain_an_earlier_version_left_beside_a_finished_training(
    finished: Path, tmp_path: Path
) -> None:
    """A coopsumo before the rule built a new training beside a finished one ('.<name>.retrain'): --resume still
    completes it, and only then does it replace the finished one."""
    out = tmp_path / "run"
    killed_retrain(out, finished)
    assert train_cli.main(["--resume", "--quiet", "--out", str(out)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"] and finished_run(out, "train")
    assert json.loads((out / "config.json").read_text())["config"]["sim"]["seed"] == 3
    resumed, first = load_model(out / "model.pt")[0].state_dict(), load_model(finished / "model.pt")[0].state_dict()
    assert all(torch.equal(resumed[k], first[k]) for k in first)


def linked_user_training(out: Path, finished: Path) -> None:
    """A finished training with, beside it, a link named as its retrain leading to a user's interrupted training."""
    shutil.copytree(finished, out)
    interrupted_at_start(out.parent / "user_ck", OTHER)
    (out.parent / f".{out.name}.retrain").symlink_to(out.parent / "user_ck", target_is_directory=True)


NOT_RETRAINS = {"another training put there": (lambda out, src: killed_retrain(out, src, OTHER), "another training"),
                "a link to a user's training": (linked_user_training, "is a link to")}


@pytest.mark.parametrize("case", sorted(NOT_RETRAINS))
def test_resume_never_continues_a_retrain_folder_it_did_not_make(
    case: str, finished: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 82, fourth probe (F23): `train --resume --out A` continued any `.A.retrain` holding a checkpoint (a link
    to a user's training: trained through it) and then replaced the finished training A with it. Taken only when it
    is a real folder recording A's configuration; else one line naming it, exit 2, A and it kept byte for byte."""
    out = tmp_path / "A"
    make, fragment = NOT_RETRAINS[case]
    make(out, finished)
    before = snapshot(tmp_path)
    code = train_cli.main(["--resume", "--quiet", "--out", str(out)])
    one_line(capsys, code, str(tmp_path / ".A.retrain"), fragment, "left alone")
    assert snapshot(tmp_path) == before


# -- 2. the model store is the studies' alone ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A study folder whose models/alpha0_m100 links into the model store beside it, as a study leaves them."""
    from coopsumo.studies.engine.model_store import train_shared

    root = tmp_path_factory.mktemp("shared")
    train_shared(TINY, root / "study" / "models" / "alpha0_m100", root / "models")
    return root / "study"


def test_an_emptied_model_store_is_a_store_whatever_path_names_it(tmp_path: Path) -> None:
    """Probe 12 (N1): `--out store` (the target of a study's link `models -> store`, the same folder) was taken once
    the store was emptied (`rm -rf store/*`): its first model marks it, and the mark stays."""
    from coopsumo.owners import STORE_MARK, owned_problem
    from coopsumo.studies.engine.model_store import train_shared

    store = tmp_path / "kept" / "store"
    train_shared(TINY, tmp_path / "study" / "models" / "alpha0_m100", store)
    assert (store / STORE_MARK).is_file()
    for entry in store.iterdir():  # emptied as `rm -rf store/*` empties it: dot-entries stay
        if not entry.name.startswith("."):
            shutil.rmtree(entry)
    for where, itself in (("kept/store", False), ("kept/store/run", False), ("kept/store/nets", True)):
        problem = owned_problem(tmp_path / where, f"--out {where}", itself=itself)
        assert problem is not None and "a model store" in problem, (where, problem)
    assert owned_problem(tmp_path / "kept" / "other", "--out kept/other") is None


STORE_OUTS: dict[str, tuple[str, bool, str]] = {
    "the study's model link": ("study/models/alpha0_m100", False, "a model of a model store"),
    "inside the study's model link": ("study/models/alpha0_m100/more", False, "a model of a model store"),
    "the store's model folder": ("models/{model}", False, "a model of a model store"),
    "a new folder in the store": ("models/mine", False, "a model store (it holds the studies' models)"),
    "a new folder in $COOPSUMO_MODELS": ("models/mine", True, "is in the model store"),
    "results/models": ("results/models/mine", False, "is in the model store"),
}  # fmt: skip
"""--out (relative to the study's parent, the current folder), $COOPSUMO_MODELS set to that store, the refusal"""


@pytest.mark.parametrize("resume", [False, True])
@pytest.mark.parametrize("case", sorted(STORE_OUTS))
def test_train_never_writes_into_the_model_store(
    case: str, resume: bool, study: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from coopsumo.studies.engine.model_store import model_id

    where, env, fragment = STORE_OUTS[case]
    root = study.parent
    monkeypatch.chdir(root)
    monkeypatch.delenv("COOPSUMO_MODELS", raising=False)
    if env:
        monkeypatch.setenv("COOPSUMO_MODELS", str(root / "models"))
    before = snapshot(root)
    out = Path(where.format(model=model_id(as_json(TINY))))
    args = ["--resume"] if resume else ["--steps", "40", "--eval-steps", "0", "--preset", "paper"]
    one_line(capsys, train_cli.main([*args, "--quiet", "--out", str(out)]), f"--out {out}", fragment)
    assert snapshot(root) == before


def test_the_store_names_train_knows_are_the_stores() -> None:
    from coopsumo import owners
    from coopsumo.studies.engine import model_store

    assert owners.STORE_ENV == model_store.STORE_ENV  # the store the check behind train's --out knows (owners)
    cond = replace(TINY, dqn=replace(DQN_PRESETS["default"], alpha_conditioned=True))
    for cfg in (TINY, replace(TINY, sim=replace(TINY.sim, reward=replace(TINY.sim.reward, alpha=0.125))), cond):
        assert owners.STORE_NAME.fullmatch(model_store.model_id(as_json(cfg)))
    assert not owners.STORE_NAME.fullmatch("lanes3_alpha8_tup1.5_seed0")  # train's own default folder name


# -- 3. a study's models/<name> that is not its link ------------------------------------------------------------------
def user_copy(link: Path, finished: Path) -> None:
    """A training copied in with `cp -rL`, with the user's own file in it."""
    shutil.copytree(finished, link)
    (link / "notes.txt").write_text("my notes\n")


def notes_folder(link: Path, _: Path) -> None:
    link.mkdir(parents=True)
    (link / "notes.txt").write_text("my notes\n")


def a_file(link: Path, _: Path) -> None:
    link.parent.mkdir(parents=True)
    link.write_text("not a folder\n")


STUDY_FOLDERS = {"a training copied in": user_copy, "a folder of notes": notes_folder, "a file": a_file}
STORE_STATES = ("holds the model", "lacks the model", "holds it damaged")


@pytest.mark.parametrize("store_state", STORE_STATES)
@pytest.mark.parametrize("what", sorted(STUDY_FOLDERS))
def test_a_real_folder_where_the_study_links_its_model_is_never_deleted_moved_or_trained_into(
    what: str, store_state: str, finished: Path, tmp_path: Path
) -> None:
    from coopsumo.errors import UsageError
    from coopsumo.studies.engine.model_store import model_id, stored_model, train_shared

    store = tmp_path / "models"
    stored = store / model_id(as_json(TINY))
    if store_state != "lacks the model":
        shutil.copytree(finished, stored)
    if store_state == "holds it damaged":
        (stored / "model.pt").write_bytes(b"cut short")
    link = tmp_path / "study" / "models" / "alpha0_m100"
    STUDY_FOLDERS[what](link, finished)
    before = snapshot(tmp_path)
    for step in (lambda: stored_model(as_json(TINY), store, link), lambda: train_shared(TINY, link, store)):
        with pytest.raises(UsageError) as err:
            step()
        assert str(link) in str(err.value) and "the study did not make" in str(err.value)
        assert len(str(err.value).splitlines()) == 1
        assert snapshot(tmp_path) == before  # nothing deleted, moved or trained; no .alpha0_m100.<pid>.link


def test_a_store_entry_that_is_a_link_to_a_users_training_is_never_trained_into(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue 82, fourth probe (F4): a model's folder in the store replaced by a link to a user's interrupted training
    was trained into through the link, the user's checkpoint deleted. The store makes only folders: the store is
    refused as a study's store (store_for, before anything is written), and stored_model and train_shared refuse the
    link in one line naming it; the user's training is kept byte for byte."""
    from coopsumo.errors import UsageError
    from coopsumo.studies.engine.model_store import model_id, store_for, stored_model, train_shared

    monkeypatch.delenv("COOPSUMO_MODELS", raising=False)
    user, store = tmp_path / "user_ck", tmp_path / "models"
    interrupted_at_start(user, OTHER)
    store.mkdir()
    entry = store / model_id(as_json(TINY))
    entry.symlink_to(user, target_is_directory=True)
    link = tmp_path / "study" / "train" / "L2_a0_s1"
    before = snapshot(tmp_path)
    with pytest.raises(UsageError, match=f"holds {entry.name}, a link"):
        store_for(tmp_path / "study")
    for step in (lambda: stored_model(as_json(TINY), store, link), lambda: train_shared(TINY, link, store)):
        with pytest.raises(UsageError) as err:
            step()
        assert str(entry) in str(err.value) and "is a link" in str(err.value), err.value
        assert len(str(err.value).splitlines()) == 1
        assert snapshot(tmp_path) == before


def test_scenario1_refuses_a_real_model_folder_before_any_cell(
    finished: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from coopsumo.studies.scenario1 import study as scenario1

    monkeypatch.delenv("COOPSUMO_MODELS", raising=False)
    root = tmp_path / "study"
    link = root / "models" / "alpha0_m100"
    user_copy(link, finished)
    mark_run_dir(root, "scenario1", finished=False, study="the quick profile's study")  # its own (probe 7, I5)
    before = snapshot(link)
    code = scenario1.main(["--quick", "--train-steps", "40", "--steps", "450", "--seeds", "1", "--alphas", "0",
                           "--train-seeds", "1", "--out", str(root)])  # fmt: skip
    one_line(capsys, code, str(link), "the study did not make")
    assert snapshot(link) == before and not (tmp_path / "models").exists() and not (root / "cells").exists()


def test_the_studys_own_link_is_made_and_kept(study: Path) -> None:
    """What the rule leaves to the study: its links, made again when they point elsewhere."""
    from coopsumo.studies.engine.model_store import model_id, stored_model

    link = study / "models" / "alpha0_m100"
    assert link.is_symlink() and link.resolve() == (study.parent / "models" / model_id(as_json(TINY))).resolve()
    other = study / "models" / "other"
    other.symlink_to(study.parent)  # a link to elsewhere is the study's to replace
    assert stored_model(as_json(TINY), study.parent / "models", other) is not None
    assert other.resolve() == link.resolve()
    assert not [p for p in (study / "models").iterdir() if p.name.endswith(".link")]
    other.unlink()


# -- 4. a training folder's outputs linked outside it ------------------------------------------------------------
LINKED = ("sumo", "eval", "snapshots", "tensorboard", "train_log.csv", "config.json", "sumo/routes.rou.xml")
"""what a training writes (folders and files), each made a link to the user's folder or file outside it"""


def unfinished(out: Path) -> None:
    """A training killed before its first checkpoint: a new training may go there (nothing to lose)."""
    out.mkdir(parents=True)
    mark_run_dir(out, "train", finished=False)
    write_json(out / "config.json", model_meta(TINY))


MODES: dict[str, tuple[Callable[[Path], None], Callable[[Path], int]]] = {
    "train": (unfinished, lambda out: train_cli.main(["--steps", "40", "--eval-steps", "0", "--preset", "paper",
                                                      "--quiet", "--out", str(out)])),
    "train --resume": (interrupted_at_start, lambda out: train_cli.main(["--resume", "--quiet", "--out", str(out)])),
    "a study's training (train())": (unfinished, lambda out: train(TINY, out, progress=False) and 0),
}  # fmt: skip


@pytest.mark.parametrize("mode", sorted(MODES))
@pytest.mark.parametrize("name", LINKED)
def test_a_training_never_writes_through_a_link_leading_outside_its_folder(
    name: str, mode: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from coopsumo.errors import UsageError

    make, run = MODES[mode]
    out = tmp_path / "run"
    make(out)
    user = tmp_path / "user"
    user.mkdir()
    (user / "routes.rou.xml").write_text("the user's own routes\n")
    (user / "data.csv").write_text("1,2,3\n")
    link = out / name
    link.parent.mkdir(exist_ok=True)
    link.unlink(missing_ok=True)
    folder = not name.endswith((".csv", ".json", ".xml"))
    link.symlink_to(user if folder else user / "data.csv" if name.endswith(".csv") else user / "routes.rou.xml")
    before = snapshot(tmp_path)
    if mode.startswith("a study"):
        with pytest.raises(UsageError, match="outside"):
            run(out)
    else:
        one_line(capsys, run(out), str(link), f"is a link to {user}", "outside")
    assert snapshot(tmp_path) == before


def test_links_inside_the_folder_and_the_folder_itself_behind_a_link_are_fine(tmp_path: Path) -> None:
    from coopsumo.paths import outside_link

    real = tmp_path / "disk" / "run"
    (real / "sumo").mkdir(parents=True)
    (real / "latest").symlink_to(real / "sumo")
    (tmp_path / "run").symlink_to(real)  # --out itself a link (a results folder on another disk)
    assert outside_link(tmp_path / "run") is None
    (real / "sumo" / "up").symlink_to(tmp_path / "disk")
    assert outside_link(tmp_path / "run") == (real / "sumo" / "up", tmp_path / "disk")


STUDIES = {  # a study that trains, with a run small enough to start: refused before it writes anything
    "scenario1": ("coopsumo.studies.scenario1.study", ["--quick", "--alphas", "0", "--train-seeds", "1"]),
    "scenario2": ("coopsumo.studies.scenario2.study", ["--profile", "tiny", "--quiet"]),
    "protocol": ("coopsumo.studies.protocol.study", ["--profile", "tiny", "--quiet"]),
}


@pytest.mark.parametrize("command", sorted(STUDIES))
@pytest.mark.parametrize("users", ["a file", "a folder of the user's"])
def test_a_study_never_takes_a_users_models_beside_its_out_for_its_store(
    command: str, users: str, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The probe's (2026-12-02): a file named `models` beside --out ended in a traceback, and a user's own `models/`
    folder there became the study's model store; each is now one line, exit 2, before anything is written."""
    import importlib

    monkeypatch.delenv("COOPSUMO_MODELS", raising=False)
    models = tmp_path / "models"
    if users == "a file":
        models.write_text("my notes\n")
    else:
        (models / "mine").mkdir(parents=True)
        (models / "mine" / "model.pt").write_bytes(b"a user's model")
    before = snapshot(tmp_path)
    module, args = STUDIES[command]
    code = importlib.import_module(module).main([*args, "--out", str(tmp_path / "study")])
    what = "exists and is not a folder" if users == "a file" else "holds mine, which is not a stored model"
    one_line(capsys, code, f"the model store {models} (beside {tmp_path / 'study'}) {what}")
    assert snapshot(tmp_path) == before
