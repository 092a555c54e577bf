"""Issue 25: nothing a user owns is deleted by --out. An existing non-empty folder is replaced or written
into only if the same command wrote it (.coopsumo-run.json) and nothing was added; a run never writes into,
or replaces, the folder its model is read from. Every refusal: one line, exit code 2, every byte kept."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

from coopsumo import simulate
from coopsumo.agents import train_cli as train
from coopsumo.errors import UsageError
from coopsumo.run_dirs import RUN_MARKER, atomic_run_dir

SIM = ["--steps", "20", "--quiet"]


def snapshot(folder: Path) -> dict[str, str]:
    """Every entry under folder: a file's sha256, or 'dir'."""
    return {p.relative_to(folder).as_posix(): "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*"))}  # fmt: skip


def refused(capsys: pytest.CaptureFixture[str], code: int, *fragments: str) -> str:
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert "Traceback" not in err and all(f in lines[0] for f in fragments), err
    return lines[0]


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny training folder (model.pt, train_log.csv, eval/) written by the train command."""
    out = tmp_path_factory.mktemp("own") / "train"
    proc = subprocess.run([sys.executable, "-m", "coopsumo.train", "--steps", "200", "--eval-steps", "20", "--quiet",
                           "--out", str(out)], capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert {"model.pt", "train_log.csv", "eval", RUN_MARKER} <= {p.name for p in out.iterdir()}
    return out


@pytest.fixture(scope="module")
def simulated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("own") / "sim"
    assert simulate.main([*SIM, "--out", str(out)]) == 0
    return out


def test_the_training_folder_given_as_out_to_simulate_is_kept_byte_for_byte(trained: Path) -> None:
    """The user's report: simulate --policy dqn:D/model.pt --out D replaced D (model, log and eval gone)."""
    before = snapshot(trained.parent)
    proc = subprocess.run([sys.executable, "-m", "coopsumo.simulate", *SIM, "--policy", f"dqn:{trained / 'model.pt'}",
                           "--out", str(trained)], capture_output=True, text=True, timeout=300)  # fmt: skip
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "the model is read from" in lines[0] and proc.stdout == ""
    assert snapshot(trained.parent) == before


@pytest.mark.parametrize("where", ["parent", "inside"])
def test_simulate_never_writes_around_its_model(
    trained: Path, capsys: pytest.CaptureFixture[str], where: str
) -> None:
    out = trained.parent if where == "parent" else trained / "sim"
    before = snapshot(trained.parent)
    code = simulate.main([*SIM, "--policy", f"dqn:{trained / 'model.pt'}", "--out", str(out)])
    refused(capsys, code, "--out", "the model is read from")
    assert snapshot(trained.parent) == before


def test_simulate_refuses_a_training_folder(trained: Path, capsys: pytest.CaptureFixture[str]) -> None:
    before = snapshot(trained)
    refused(capsys, simulate.main([*SIM, "--out", str(trained)]), str(trained), "train run, not a simulate run")
    assert snapshot(trained) == before


def test_train_refuses_a_simulate_folder(simulated: Path, capsys: pytest.CaptureFixture[str]) -> None:
    before = snapshot(simulated)
    code = train.main(["--steps", "20", "--eval-steps", "0", "--quiet", "--out", str(simulated)])
    refused(capsys, code, str(simulated), "simulate run, not a train run")
    code = train.main(["--resume", "--quiet", "--out", str(simulated)])
    refused(capsys, code, str(simulated), "simulate run, not a train run")
    assert snapshot(simulated) == before


def test_train_refuses_a_study_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    study = tmp_path / "study"
    (study / "cells").mkdir(parents=True)
    (study / "cells" / "c1.json").write_text('{"ok": true}\n')
    (study / "summary.json").write_text("{}\n")
    before = snapshot(tmp_path)
    code = train.main(["--steps", "20", "--eval-steps", "0", "--quiet", "--out", str(study)])
    refused(capsys, code, str(study), "not a coopsumo run folder")
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("command", ["simulate", "train"])
def test_a_config_json_beside_foreign_files_is_not_a_run_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    """Before: any folder holding a config.json was replaced; a run of an older coopsumo is refused too."""
    out = tmp_path / "mine"
    out.mkdir()
    (out / "config.json").write_text('{"config": {}}\n')
    (out / "notes.txt").write_text("keep me\n")
    (out / "summary.json").write_text("{}\n")
    before = snapshot(tmp_path)
    if command == "simulate":
        code = simulate.main([*SIM, "--out", str(out)])
    else:
        code = train.main(["--steps", "20", "--eval-steps", "0", "--quiet", "--out", str(out)])
    refused(capsys, code, str(out), RUN_MARKER, "remove it yourself or pick another --out")
    assert snapshot(tmp_path) == before


def test_a_file_added_to_a_simulate_folder_keeps_it_from_being_replaced(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    assert simulate.main([*SIM, "--out", str(out)]) == 0
    (out / "notes.txt").write_text("my notes\n")
    before = snapshot(tmp_path)
    refused(capsys, simulate.main([*SIM, "--out", str(out)]), str(out), "notes.txt", "did not write")
    assert snapshot(tmp_path) == before


def test_simulate_reruns_into_its_own_folder_and_into_an_empty_one(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()  # an empty existing folder is fine
    assert simulate.main([*SIM, "--out", str(out)]) == 0
    marker = json.loads((out / RUN_MARKER).read_text())
    assert marker["kind"] == "simulate" and {"config.json", "summary.json"} <= set(marker["files"])
    assert simulate.main(["--steps", "30", "--quiet", "--out", str(out)]) == 0
    assert json.loads((out / "summary.json").read_text())["steps"] == 30
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_finish_keeps_a_folder_that_gained_a_file_during_the_run(tmp_path: Path) -> None:
    """The replacement deletes nothing it did not write, even what appeared while the run was going."""
    out = tmp_path / "run"
    with atomic_run_dir(out) as tmp:
        (tmp / "summary.json").write_text("1\n")
    (out / "late.txt").write_text("added by hand\n")
    before = snapshot(tmp_path)
    with pytest.raises(UsageError, match="late.txt"), atomic_run_dir(out) as tmp:
        (tmp / "summary.json").write_text("2\n")
    assert snapshot(tmp_path) == before  # and no partial folder left beside it
