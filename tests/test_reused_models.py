"""Issue 82, probe 13, F9: a finished study's rerun reused every cell although the store model its cells drove was
deleted, swapped or damaged, so the study called itself complete while its train/ link led to no model, or to
another; accident-seeds then refused the model and advised a rerun that did nothing. A cell is reused only beside
the model a training would reuse (trainings.unusable_trainings, finished_training's own judgement), else it is run
again, which trains its model again, with one line naming the file and why.

Each test's first sweep runs as the command a user runs (a process); the reruns, which judge what that sweep left,
run scenario2's main in this process, its workers' output captured as well (capfd), and the alpha-8 model swapped in
is made by train's main here too (`coopsumo train` as a process: tests/test_train.py)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO

SWEEP = ["scenario2", "--profile", "tiny", "--workers", "1", "--steps", "200", "--eval-steps", "300", "--seeds", "1",
         "--lanes", "2", "--alphas", "0", "--policies", "dqn", "--quiet", "--bootstrap", "20"]  # fmt: skip
"""two cells (T_up 2 s and 4 s) of one model"""


def sweep(out: Path) -> subprocess.CompletedProcess[str]:
    result = subprocess.run([sys.executable, "-m", "coopsumo", *SWEEP, "--out", str(out)], capture_output=True,
                            text=True, cwd=REPO, timeout=600, check=False)  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    return result


def rerun(out: Path, capfd: pytest.CaptureFixture[str]) -> str:
    """The same sweep by scenario2's main in this process: its stderr (its workers' too)."""
    from coopsumo.studies.scenario2 import study as s2

    capfd.readouterr()
    code = s2.main([*SWEEP[1:], "--out", str(out)])
    err = capfd.readouterr().err
    assert code == 0, err[-2000:]
    return err


def swap_in_another_model(model: Path, tmp_path: Path) -> None:
    """model.pt replaced by an alpha-8 training's (what train writes of that training, made here first)."""
    from coopsumo.agents import train_cli

    other = tmp_path / "other"
    assert train_cli.main(["--quiet", "--steps", "200", "--eval-steps", "0", "--lanes", "2", "--alpha", "8", "--seed",
                           "100", "--out", str(other)]) == 0  # fmt: skip
    shutil.copy(other / "model.pt", model / "model.pt")


EDITS = {
    "model.pt deleted": (lambda m, _: (m / "model.pt").unlink(), "holds no finished training's model.pt"),
    "config.json garbage": (lambda m, _: (m / "config.json").write_text("garbage"), "its config.json is missing"),
    "train_summary.json a list": (lambda m, _: (m / "train_summary.json").write_text("[1, 2]"), "is list, not"),
    "another model swapped in": (swap_in_another_model, "made by another configuration than its config.json"),
}  # fmt: skip


@pytest.mark.sumo
def test_a_cell_whose_store_model_was_spoiled_is_rerun_and_its_model_trained_again(
        tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Each spoiling in turn on one finished study (one study, not one a case: the suite's time): its rerun runs both
    cells again with one line naming the training's link and why, and trains the model again; once all are done, a
    last rerun reuses every cell."""
    out = tmp_path / "s2"
    sweep(out)
    model = (out / "train" / "L2_a0_s1").resolve()
    assert model.parent == tmp_path / "models" and (model / "model.pt").is_file()
    for case in sorted(EDITS):
        edit, words = EDITS[case]
        edit(model, tmp_path)
        err = rerun(out, capfd)
        assert "2 cells, 0 already done" in err and "2 to run" in err, (case, err)
        named = [line for line in err.splitlines() if "rerunning the 2 cells of its training" in line]
        assert len(named) == 1 and words in named[0] and str(out / "train" / "L2_a0_s1") in named[0], (case, err)
        assert json.loads((model / "train_summary.json").read_text())["steps"] == 200, case  # trained again
    again = rerun(out, capfd)  # the model trained again: every cell reused now
    assert "2 cells, 2 already done" in again and "rerunning" not in again, again


@pytest.mark.sumo
def test_a_study_copied_with_its_links_links_its_own_store(tmp_path: Path,
                                                          capfd: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """The probe's s2_rawcopy: `cp -a` of a finished study elsewhere kept its train/ links into the original study's
    store, and the copy reused them silently, depending on a store not its own. Its cells run again, each training's
    model made (or found) in the copy's own store, with a line naming the link."""
    out = tmp_path / "a" / "s2"
    sweep(out)
    copy = tmp_path / "b" / "s2"
    shutil.copytree(out, copy, symlinks=True)
    err = rerun(copy, capfd)
    named = [line for line in err.splitlines() if "outside the study's model store" in line]
    assert len(named) == 1 and "2 to run" in err, err  # one line for the training its 2 cells share
    assert str(copy / "train" / "L2_a0_s1") in named[0] and "rerunning the 2 cells of its training" in named[0], named
    assert (copy / "train" / "L2_a0_s1").resolve().parent == tmp_path / "b" / "models"
    assert (out / "train" / "L2_a0_s1").resolve().parent == tmp_path / "a" / "models"  # the original untouched
