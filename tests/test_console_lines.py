"""The closing lines commands print: `train`'s evaluation line rounds its floats as `simulate`'s does (issue 68: it
printed mean_speed_mps=16.219737159743943); `train` says what its model did in the greedy evaluation, warns when that
was `keep`'s driving (no lane change), and says plainly when no evaluation ran (issue 81)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from coopsumo.agents import train as train_module
from coopsumo.agents import train_cli

WARNING = ("train: warning: 0 lane changes in the greedy evaluation: the model drove like `keep`; it learned nothing "
           "beyond keeping its lane")


def _fake_train(summary: dict[str, Any]) -> Any:
    def fake_train(cfg: Any, out: Path, **_: Any) -> dict[str, Any]:
        return summary

    return fake_train


def _closing(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], out: Path,
             summary: dict[str, Any], eval_steps: int) -> list[str]:  # fmt: skip
    monkeypatch.setattr(train_module, "train", _fake_train(summary))
    args = ["--steps", "20", "--eval-steps", str(eval_steps), "--quiet", "--out", str(out)]
    assert train_cli.main(args) == 0
    return capsys.readouterr().out.strip().splitlines()


def test_train_prints_its_evaluation_to_four_digits(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    summary = {"mean_speed_mps": 16.219737159743943, "lane_changes_per_vehicle": 0.012345678, "collisions": 0,
               "teleports": 0, "lane_changes": 1, "departed": 81}  # fmt: skip
    out = tmp_path / "run"
    lines = _closing(monkeypatch, capsys, out, summary, 300)
    assert lines[-2:] == [f"model: {out / 'model.pt'}",
                          f"greedy evaluation (300 steps, {out / 'eval'}): mean_speed_mps=16.22 "
                          "lane_changes_per_vehicle=0.01235 collisions=0 teleports=0"]  # fmt: skip


def test_a_model_that_changed_no_lane_is_called_keep(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    summary = {"mean_speed_mps": 16.22, "lane_changes_per_vehicle": 0.0, "collisions": 0, "teleports": 0,
               "lane_changes": 0, "departed": 81}  # fmt: skip
    lines = _closing(monkeypatch, capsys, tmp_path / "run", summary, 300)
    assert "lane_changes_per_vehicle=0 " in lines[-2]
    assert lines[-1] == WARNING


def test_no_warning_when_no_vehicle_entered_the_evaluation(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    summary = {"mean_speed_mps": 0.0, "lane_changes_per_vehicle": 0.0, "collisions": 0, "teleports": 0,
               "lane_changes": 0, "departed": 0}  # fmt: skip
    lines = _closing(monkeypatch, capsys, tmp_path / "run", summary, 5)
    assert lines[-1].startswith("greedy evaluation (5 steps, ") and not any("train: warning" in line for line in lines)


def _train(out: Path, eval_steps: int) -> list[str]:
    args = ["train", "--steps", "300", "--eval-steps", str(eval_steps), "--seed", "1", "--quiet", "--out", str(out)]
    res = subprocess.run([sys.executable, "-m", "coopsumo", *args], capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr[-1500:]
    return res.stdout.strip().splitlines()


@pytest.mark.sumo
def test_a_real_training_ends_with_its_evaluations_lane_changes(tmp_path: Path) -> None:
    out = tmp_path / "run"
    lines = _train(out, 300)
    summary = json.loads((out / "summary.json").read_text())  # the greedy evaluation's record
    speed, changes = summary["mean_speed_mps"], summary["lane_changes_per_vehicle"]
    assert lines[:2] == [f"model: {out / 'model.pt'}",
                         f"greedy evaluation (300 steps, {out / 'eval'}): mean_speed_mps={speed:.4g} "
                         f"lane_changes_per_vehicle={changes:.4g} collisions=0 teleports=0"]  # fmt: skip
    assert (lines[2:] == [WARNING]) == (summary["lane_changes"] == 0)


@pytest.mark.sumo
def test_a_real_training_without_evaluation_says_so(tmp_path: Path) -> None:
    out = tmp_path / "run"
    lines = _train(out, 0)
    assert lines == [f"model: {out / 'model.pt'}",
                     f"no evaluation ran (--eval-steps 0): what the model does is unmeasured; drive it with coopsumo "
                     f"simulate --policy dqn:{out / 'model.pt'}"]  # fmt: skip
    assert (out / "model.pt").exists() and not (out / "summary.json").exists()
    assert "mean_speed_mps" in json.loads((out / "train_summary.json").read_text())  # the training's own, not printed
