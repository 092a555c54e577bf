"""Issue 82, probe 8: places a single run's output (simulate --out, train --out, --gui-screenshot, history --out) may
not go: deeper in a model store than its first level (J1: `simulate --out models/sub/run` beside a study was
written, and the study then refused its store), and inside a study's folder written before markers, as every
committed study is on a fresh clone (J2: only `history --out` refused it). Every refusal: one line, exit code 2,
nothing written."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_study_places import listing, one_line, run

from coopsumo.owners import owned_problem

MODEL = "default_a0_seed1_0123456789ab"


def store_beside(tmp_path: Path) -> Path:
    """The model store `models` beside a study's root, holding one model's folder."""
    (tmp_path / "models" / MODEL).mkdir(parents=True)
    return tmp_path / "models"


def unmarked_protocol(folder: Path) -> Path:
    """A protocol study's folder as a fresh clone holds it: study.json, runs.csv and report.md, no marker."""
    folder.mkdir(parents=True)
    for name, text in (("study.json", '{"profile": {"name": "x", "t_ups": [1.5]}}'), ("runs.csv", "a\n1\n"),
                       ("report.md", "# x\n")):  # fmt: skip
        (folder / name).write_text(text)
    return folder


@pytest.mark.parametrize("below", ["sub/run", ".x/run", "sub/deeper/run"])
def test_a_path_at_any_depth_in_a_model_store_is_refused(below: str, tmp_path: Path) -> None:
    store = store_beside(tmp_path)
    problem = owned_problem(store / below, "--out X")
    assert problem is not None and f"is in {store}, a model store" in problem
    assert owned_problem(tmp_path / "elsewhere" / "run", "--out X") is None


def test_a_path_inside_an_unmarked_study_is_refused_and_beside_it_is_not(tmp_path: Path) -> None:
    study = unmarked_protocol(tmp_path / "P")
    problem = owned_problem(study / "sim", "--out P/sim")
    assert problem is not None and f"lies inside {study}, a coopsumo study's folder (its study.json" in problem
    assert owned_problem(tmp_path / "sim", "--out sim") is None
    assert owned_problem(study / "sim", "--out P/sim", unmarked=False) is None


@pytest.mark.parametrize("case", ["store", "study"])
@pytest.mark.parametrize("command", ["simulate", "train"])
def test_a_single_run_is_not_written_there(command: str, case: str, tmp_path: Path,
                                           monkeypatch: pytest.MonkeyPatch,
                                           capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("COOPSUMO_MODELS", raising=False)
    place = store_beside(tmp_path) / "sub" / "run" if case == "store" else unmarked_protocol(tmp_path / "P") / "run"
    before = listing(tmp_path)
    argv = ["--quiet", "--steps", "100", "--out", str(place)] + (["--eval-steps", "0"] if command == "train" else [])
    one_line(capsys, run(command, argv), f"--out {place}", "a model store" if case == "store" else "study's folder")
    assert listing(tmp_path) == before


def test_a_gui_screenshot_is_not_written_in_an_unmarked_study(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                              capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    monkeypatch.chdir(tmp_path)
    study = unmarked_protocol(tmp_path / "P")
    before = listing(tmp_path)
    code = run("simulate", ["--quiet", "--steps", "30", "--out", "g", "--gui", "--gui-screenshot",
                            str(study / "fig_new.png")])  # fmt: skip
    one_line(capsys, code, "--gui-screenshot", "study's folder")
    assert listing(tmp_path) == before
