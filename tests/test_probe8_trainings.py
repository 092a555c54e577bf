"""Issue 82, probe 8, J4-J6: a training's folder (train's --out, a model's folder in the model store) is its
training's only when everything in it, at every depth, is what a training writes, and no link is in it
(agents/training_files.foreign_entry). A user's snapshots/step100/notes.txt was deleted by a retrain in the store and
listed by `train --resume` as the training's own (J4); a folder marked as an unfinished training was started over
with the user's config.json replaced and notes.txt listed (J5); a link sumo -> . had SUMO write into the training's
root (J6). Every refusal: one line naming the folder and the entry, exit 2, every byte kept."""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
from test_data_loss import TINY, as_json, interrupted_at_start, one_line, snapshot

from coopsumo.agents import train_cli
from coopsumo.agents.file_checks import prepare_resume
from coopsumo.agents.training_files import foreign_entry
from coopsumo.errors import UsageError
from coopsumo.run_dirs import RUN_MARKER

OWN = ("config.json", RUN_MARKER, "checkpoint.pt", "train_log.csv", "model.pt", "model_last.pt", "train_summary.json",
       "summary.json", "validation.csv", ".model.pt.k2j3h4g5.tmp", "sumo/routes.rou.xml", "sumo/detectors.xml",
       "eval/summary.json", "eval/trajectories.parquet", "eval/.fcd.xml.k2j3h4g5.tmp",
       "tensorboard/events.out.tfevents.1796318587.vm.14204.0", "snapshots/step100/model.pt",
       "snapshots/step100/request.json", "snapshots/step100/screen.json", "snapshots/step100/validation.json",
       "snapshots/step100/.validation.json.k2j3h4g5.tmp", "snapshots/step100/.run0.k2j3h4g5/routes.rou.xml")
"""a file of each kind a training writes, at its depth (a validation's run a kill cut short included)"""


def write(folder: Path, *names: str) -> None:
    for name in names:
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_text("x\n")


def link(to: str, name: str = "sumo") -> Callable[[Path], None]:
    """A change that puts the link `name` -> `to` into a training folder (in place of a folder there)."""
    def change(out: Path) -> None:
        shutil.rmtree(out / name, ignore_errors=True)  # the training's own folder of that name
        if to == "eval":
            (out / "eval").mkdir(exist_ok=True)
        (out / name).symlink_to(to)
    return change


ADDED: dict[str, tuple[Callable[[Path], None], Callable[[Path], str]]] = {
    "a note in a snapshot": (lambda out: write(out, "snapshots/step100/notes.txt"),
                             lambda out: "holds snapshots/step100/notes.txt, which no training writes"),
    "a file in tensorboard": (lambda out: write(out, "tensorboard/mine.txt"),
                              lambda out: "holds tensorboard/mine.txt, which no training writes"),
    "sumo -> .": (link("."), lambda out: f"holds sumo, a link to {out.resolve()}, which no training makes"),
    "sumo -> eval": (link("eval"), lambda out: f"holds sumo, a link to {out.resolve() / 'eval'}, which no training"),
}
"""what the probe put into a training's folder, and the phrase that names it"""


def test_the_rule_takes_what_a_training_writes_and_names_the_first_entry_it_does_not(tmp_path: Path) -> None:
    """One rule at every depth: every file a training writes passes; a user's file or folder anywhere, a folder
    named like a snapshot that is none, a folder where a training writes a file, and a link anywhere (inside the
    folder too) are named by their path in the folder."""
    out = tmp_path / "t"
    write(out, *OWN)
    assert foreign_entry(out) is None
    write(out, "group_cost.json")
    assert foreign_entry(out, also=("group_cost.json",)) is None
    assert foreign_entry(out) == "holds group_cost.json, which no training writes"
    (out / "group_cost.json").unlink()
    for added, first in (("snapshots/stepX/model.pt", "snapshots/stepX"), ("eval/sub/summary.json", "eval/sub"),
                         ("snapshots/step100/.run0.k2j3h4g5/notes.txt", "snapshots/step100/.run0.k2j3h4g5/notes.txt"),
                         ("model_last.pt.d/x", "model_last.pt.d"), ("config.json/x", "config.json"),
                         ("tensorboard/mine.txt", "tensorboard/mine.txt"), ("notes.txt", "notes.txt")):  # fmt: skip
        if first == "config.json":
            (out / first).unlink()  # a folder where a training writes a file
        write(out, added)
        assert foreign_entry(out) == f"holds {first}, which no training writes", added
        if (out / first).is_dir():
            shutil.rmtree(out / first)
        else:
            (out / first).unlink()
    (out / "snapshots/step100/model.pt").unlink()
    (out / "snapshots/step100/model.pt").symlink_to(tmp_path)
    assert foreign_entry(out) == f"holds snapshots/step100/model.pt, a link to {tmp_path.resolve()}, which no " \
        "training makes"  # fmt: skip
    (out / "snapshots/step100/model.pt").unlink()
    (tmp_path / "mine.csv").write_text("my data\n")
    (out / "train_log.csv").unlink()
    os.link(tmp_path / "mine.csv", out / "train_log.csv")  # probe 9: a resume appended to the user's file
    assert foreign_entry(out) == "holds train_log.csv, a file with another name too (a hard link), which no " \
        "training makes"  # fmt: skip


@pytest.mark.parametrize("resume", [True, False], ids=["resume", "new"])
@pytest.mark.parametrize("case", sorted(ADDED))
def test_train_refuses_a_training_folder_holding_what_no_training_writes(
        case: str, resume: bool, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """J4, J6 (resume) and J5 (a new training over an interrupted one's folder without its checkpoint): the resume
    listed snapshots/step100/notes.txt and tensorboard/mine.txt in its finished marker, and wrote SUMO's files through
    sumo -> . into the training's root. Refused before anything is written."""
    out = tmp_path / "t"
    interrupted_at_start(out, TINY)
    if not resume:
        (out / "checkpoint.pt").unlink()
        train_cli.check_new_training(out)  # only a training's files: a new training starts over there
    ADDED[case][0](out)
    before = snapshot(tmp_path)
    argv = ["--resume"] if resume else ["--steps", "200", "--eval-steps", "0"]
    one_line(capsys, train_cli.main([*argv, "--quiet", "--out", str(out)]), f"--out {out} {ADDED[case][1](out)}")
    assert snapshot(tmp_path) == before


def test_a_folder_marked_as_an_unfinished_training_with_a_users_files_is_not_started_over(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """J5: a marker saying a training did not finish, beside a user's config.json and notes.txt, was taken: the
    config.json replaced, notes.txt listed as the training's. Refused naming notes.txt, then (it moved away) the
    config.json that records no training; every byte kept."""
    out = tmp_path / "X"
    out.mkdir()
    (out / RUN_MARKER).write_text(json.dumps({"finished": False, "kind": "train", "version": "0.1.0"}))
    (out / "config.json").write_text('{"mine": 1}\n')
    (out / "notes.txt").write_text("notes\n")
    argv = ["--quiet", "--steps", "200", "--eval-steps", "0", "--out", str(out)]
    for fragment in ("holds notes.txt, which no training writes", "holds config.json, which records no training's"):
        before = snapshot(tmp_path)
        one_line(capsys, train_cli.main(argv), f"--out {out} {fragment}", "is left alone")
        assert snapshot(tmp_path) == before
        (out / "notes.txt").unlink(missing_ok=True)


def test_a_store_model_holding_what_no_training_writes_at_any_depth_is_left_alone(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """J4, J6 in the model store: a whole stored model with a user's snapshots/step100/notes.txt was used without a
    word, and trained again (the user's file deleted) once its train_summary.json was gone; a stored model with
    sumo -> . was trained again through the link. Refused in one line naming the folder and the entry, as a user's
    notes.txt beside its config.json is (probe 7, I6)."""
    from coopsumo.studies.engine.model_store import model_id, stored_model, train_shared
    from coopsumo.studies.engine.store_listing import listing

    monkeypatch.delenv("COOPSUMO_MODELS", raising=False)
    store, config = tmp_path / "models", as_json(TINY)
    entry, study_link = store / model_id(config), tmp_path / "s" / "t"
    train_shared(TINY, study_link, store)
    assert stored_model(config, store) == entry
    shutil.copytree(entry / "sumo", tmp_path / "sumo")  # to put back after a case that makes sumo a link
    steps = (lambda: stored_model(config, store), lambda: train_shared(TINY, study_link, store))
    for case in sorted(ADDED):
        for summary_gone in (False, True):
            ADDED[case][0](entry)
            if summary_gone:
                (entry / "train_summary.json").rename(tmp_path / "train_summary.json")
            before = snapshot(tmp_path)
            for step in steps:
                with pytest.raises(UsageError) as err:
                    step()
                assert f"{entry}, a model's folder in the model store, {ADDED[case][1](entry)}" in str(err.value)
                assert len(str(err.value).splitlines()) == 1 and snapshot(tmp_path) == before
            state = {row["model"]: row["state"] for row in listing(store)}[entry.name]  # `coopsumo models` says so
            assert state.startswith(f"not usable: {ADDED[case][1](entry)}") and state.endswith("(move it away)")
            restore(entry, tmp_path)
            assert stored_model(config, store) == entry  # whole again: used
            assert {row["model"]: row["state"] for row in listing(store)}[entry.name] == "ok"


def restore(entry: Path, tmp_path: Path) -> None:
    """Undo an ADDED change to the store model `entry`: its sumo/ and train_summary.json back from tmp_path."""
    for name in ("snapshots", "tensorboard"):
        shutil.rmtree(entry / name, ignore_errors=True)
    if (entry / "sumo").is_symlink():
        (entry / "sumo").unlink()
        shutil.copytree(tmp_path / "sumo", entry / "sumo")
    if (entry / "eval").is_dir() and not any((entry / "eval").iterdir()):
        (entry / "eval").rmdir()
    if (tmp_path / "train_summary.json").exists():
        (tmp_path / "train_summary.json").rename(entry / "train_summary.json")


@pytest.mark.parametrize("name", ["notes.tmp", "experiment.tmp", ".hidden.tmp", "mywork.tmp/x"])
def test_a_users_tmp_file_in_a_training_folder_is_refused_by_name_and_kept(
        name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """J22: `train --resume` deleted every '*.tmp' and '.*.tmp' in the folder, a user's notes.tmp too, taking it for
    a temporary file of a write a kill cut short; a folder mywork.tmp/ ended it in "Is a directory". Only the
    temporaries of the training's own files ('.NAME.XXXXXXXX.tmp') are its own: anything else is refused by name
    before the resume, every byte kept."""
    out = tmp_path / "t"
    interrupted_at_start(out, TINY)
    write(out, name, ".checkpoint.pt.k2j3h4g5.tmp")  # the second: a killed write of the checkpoint, the training's
    before = snapshot(tmp_path)
    first = name.split("/")[0]
    one_line(capsys, train_cli.main(["--resume", "--quiet", "--out", str(out)]),
             f"--out {out} holds {first}, which no training writes")
    assert snapshot(tmp_path) == before


def test_a_resume_removes_no_file_named_like_a_temporary(tmp_path: Path) -> None:
    """J22: prepare_resume removed every '*.tmp'; then what a kill left of a write of the training's files, a
    user's file of such a name too (probe 12, N3): now none. The rule that judges the folder takes the names of
    the training's own temporaries (a store's group_cost.json's too, given as its own) and refuses the others."""
    own = [".checkpoint.pt.k2j3h4g5.tmp", ".train_log.csv.abcdefgh.tmp", ".model.pt.a_b1c2d3.tmp"]
    users = ["notes.tmp", ".hidden.tmp", "checkpoint.pt.tmp", ".model.pt.short.tmp", ".notes.txt.k2j3h4g5.tmp"]
    write(tmp_path, *own, *users)
    prepare_resume(tmp_path, 0)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(own + users)
    for name in own + users:
        (tmp_path / name).unlink()
    for name in users:  # each refused by name by the rule of what a training writes
        write(tmp_path, name)
        assert foreign_entry(tmp_path) == f"holds {name}, which no training writes"
        (tmp_path / name).unlink()
    write(tmp_path, *own, ".group_cost.json.k2j3h4g5.tmp")
    assert foreign_entry(tmp_path, also=("group_cost.json",)) is None
    assert foreign_entry(tmp_path) == "holds .group_cost.json.k2j3h4g5.tmp, which no training writes"
