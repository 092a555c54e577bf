"""The runs that read or extend what the other studies made (scenario1 --regime-map, accident-seeds): --help, bad
input (one line, exit 2, nothing written), tiny real runs on hand-made study folders (models with untrained weights,
so each run takes seconds), a rerun that reuses every cell, and the old spellings under experiments/."""

from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import pandas as pd
import pytest

from coopsumo import cli
from coopsumo.dqn_config import DQNConfig
from coopsumo.studies.learning import study as ablation

ROOT = Path(__file__).resolve().parent.parent
COMMANDS = {"regime-map": ("scenario1", ["--regime-map"]), "accident-seeds": ("accident-seeds", [])}
"""name -> (its command, the options that choose it: the regime map is a profile of scenario I)"""


def command_main(name: str, argv: list[str]) -> int:
    command, chosen = COMMANDS[name]
    module = importlib.import_module(cli.COMMANDS[command][0])
    try:
        return int(module.main([*chosen, *argv]))
    except SystemExit as stop:
        return int(stop.code or 0)


def listing(folder: Path) -> dict[str, int]:
    """Every file and folder under folder with its modification time: equal before and after means nothing written."""
    return {p.relative_to(folder).as_posix(): p.stat().st_mtime_ns for p in folder.rglob("*")}


def save_untrained(folder: Path, train_config: dict[str, Any]) -> None:
    """folder/model.pt: a network of the training's learner with untrained weights, and its train_log.csv."""
    import torch

    from coopsumo.agents.dqn import QNetwork
    from coopsumo.agents.model_file import save_model

    torch.manual_seed(0)
    dqn = train_config["dqn"]
    net = QNetwork(dqn["speed_scale_mps"], dueling=dqn["dueling"], observation=dqn["observation"],
                   conditioned=dqn["alpha_conditioned"])  # fmt: skip
    folder.mkdir(parents=True, exist_ok=True)
    save_model(folder / "model.pt", net, {"config": train_config})
    pd.DataFrame({"step": [100, 200], "vehicles": [10, 12], "lane_changes": [3, 1], "mean_speed_mps": [20.0, 21.0],
                  "td_loss": ["", 0.5]}).to_csv(folder / "train_log.csv", index=False)  # fmt: skip


TRAINED = {"steps": 300, "departed": 40, "mean_speed_mps": 20.0, "lane_changes": 12, "collisions": 0, "updates": 20,
           "wall_seconds": 3.0, "steps_per_second": 100.0}  # fmt: skip
"""a training's summary as its record keeps it (every study record of a training holds one)"""


def learning_folder(root: Path, variants: tuple[str, ...] = ("margin", "conditioned")) -> Path:
    """A learning study's folder as `coopsumo learning` leaves it, for training seed 0 at alpha 0: study.json, each
    training's record in cells/ and its model in train/<train_key>/ (untrained weights)."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "study.json").write_text("{}")
    profile = replace(ablation.PROFILES["tiny"], variants=variants, alphas=(0.0,), seeds=(0,), alpha_variants=variants)
    for spec in ablation.cell_specs(profile, DQNConfig()):
        if spec["kind"] != "train":
            continue
        record = {**ablation.new_record(spec), "status": "ok",
                  "summary": {"mean_speed_mps": 20.0, "lane_changes_per_vehicle": 0.5, "collisions": 0,
                              "teleports": 0}, "train_summary": dict(TRAINED)}  # fmt: skip
        (root / "cells").mkdir(parents=True, exist_ok=True)
        (root / "cells" / f"{spec['key']}.json").write_text(json.dumps(record))
        save_untrained(root / "train" / spec["train_key"], spec["config"]["train"])
    return root


# -- --help and the command table -------------------------------------------------------------------------------
@pytest.mark.parametrize("name", COMMANDS)
def test_help_names_the_command(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert command_main(name, ["--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: coopsumo {COMMANDS[name][0]} ") and "(default" in out


# -- bad input ----------------------------------------------------------------------------------------------------
BAD = [
    ("regime-map", None, ["--t-up", "0"], "--t-up"),
    ("regime-map", None, ["--t-up", "2,,1"], "--t-up"),
    ("regime-map", None, ["--seeds", "0"], "--seeds"),
    ("regime-map", None, ["--steps", "5"], "--steps"),
    ("regime-map", None, ["--workers", "0"], "--workers"),
    ("regime-map", None, ["--address", "127.0.0.1:1"], "--address"),
    ("regime-map", "foreign", [], "does not write"),
    ("accident-seeds", "none", [], "not a learning-study folder"),
    ("accident-seeds", "empty", [], "no finished models"),
    ("accident-seeds", "learning", ["--variants", "margin,warp"], "warp"),
    ("accident-seeds", "learning", ["--variants", "margin", "--alphas", "-1"], "--alphas"),
    ("accident-seeds", "learning", ["--variants", "margin", "--t-up", "nan"], "--t-up"),
    ("accident-seeds", "learning", ["--variants", "margin", "--seeds", "0"], "--seeds"),
    ("accident-seeds", "learning", ["--variants", "margin", "--quick", "--steps", "600"], "--steps"),
    ("accident-seeds", "learning", ["--variants", "margin", "--adaptive"], "--adaptive"),
    ("accident-seeds", "learning", ["--variants", "margin", "--alphas", "8"], "no finished models"),
    ("accident-seeds", "no model", ["--variants", "margin"], "is missing"),
    ("accident-seeds", "learning", ["--variants", "margin", "--out", "a,b"], "--out"),
]  # fmt: skip


@pytest.mark.parametrize("name, setup, args, fragment", BAD)
def test_bad_input_is_one_line_exit_2_and_writes_nothing(name: str, setup: str | None, args: list[str],
                                                         fragment: str, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    root = tmp_path / "study"
    if setup in ("empty", "learning", "no model", "foreign"):
        (root / "cells").mkdir(parents=True)
    if setup in ("learning", "no model"):
        learning_folder(root, ("margin",))
    if setup == "no model":
        next(root.rglob("model.pt")).unlink()
    if setup == "foreign":
        (root / "notes.txt").write_text("mine")
    before = listing(tmp_path)
    capsys.readouterr()
    argv = ([] if name == "regime-map" else [str(root)]) + args
    if name == "regime-map" and "--out" not in args:
        argv += ["--out", str(root)]
    code = command_main(name, argv)
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2, lines
    assert len(lines) == 1 and fragment in lines[0] and "Traceback" not in lines[0], lines
    assert listing(tmp_path) == before


# -- tiny real runs -----------------------------------------------------------------------------------------------
def coopsumo(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "coopsumo", *args, "--quiet"], cwd=ROOT, capture_output=True,
                          text=True, timeout=600, check=False)  # fmt: skip


def cell_times(root: Path, pattern: str = "*.json") -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in (root / "cells").glob(pattern)}


@pytest.mark.sumo
def test_regime_map_runs_both_lengths_and_reuses_every_cell(tmp_path: Path) -> None:
    out = tmp_path / "rm"
    res = coopsumo("scenario1", "--regime-map", "--t-up", "4", "--steps", "600", "--out", str(out))
    assert res.returncode == 0, res.stderr[-2000:]
    runs = pd.read_csv(out / "runs.csv")
    assert list(runs["accident"]) == ["default", "paper"] and list(runs["run_steps"]) == [600, 2700]
    assert set(runs["collisions"]) == {0} and set(runs["teleports"]) == {0}
    # the cells and run folders keep the names the old experiments/regime_map.py gave them: its folders are reused
    assert sorted(cell_times(out)) == ["default_t4_seed1.json", "paper_t4_seed1.json"]
    assert (out / "runs/default/t4/keep_seed1/summary.json").exists()
    report = (out / "report.md").read_text()
    assert "Made by `coopsumo scenario1 --regime-map`" in report and "steps 60-360 of a 600-step run" in report
    cells = cell_times(out)
    again = coopsumo("scenario1", "--regime-map", "--t-up", "4", "--steps", "600", "--out", str(out))
    assert again.returncode == 0, again.stderr[-2000:]
    assert cell_times(out) == cells and pd.read_csv(out / "runs.csv").equals(runs)


@pytest.mark.sumo
def test_accident_seeds_drives_every_model_beside_the_baselines(tmp_path: Path) -> None:
    root = learning_folder(tmp_path / "learning")
    out = tmp_path / "acc"
    args = [str(root), "--variants", "margin,conditioned", "--alphas", "0", "--adaptive", "--seeds", "1", "--t-up",
            "3", "--steps", "600", "--out", str(out)]  # fmt: skip
    res = coopsumo("accident-seeds", *args)
    assert res.returncode == 0, res.stderr[-2000:]
    runs = pd.read_csv(out / "runs.csv")
    assert list(runs["variant"]) == ["keep", "greedy", "mobil:p=0", "conditioned", "margin", "conditioned_adaptive"]
    assert (runs["collisions"] == 0).all() and (runs["teleports"] == 0).all()
    assert list(runs["seed"]) == [0] * 6
    # the margin variant drove a copy of its model carrying the margin; the conditioned one at alpha 0 and adaptive
    from coopsumo.agents.model_file import load_model

    copies = sorted((out / "models").glob("*.pt"))  # both variants drive with the change margin of 1
    assert len(copies) == 2 and all(load_model(c)[1]["config"]["dqn"]["change_margin"] == 1.0 for c in copies)
    config = json.loads((out / "runs/t3/t3_conditioned_adaptive_train0_seed0/config.json").read_text())["config"]
    assert config["policy"].endswith(",alpha=adaptive") and config["seed"] == 2000
    report = (out / "report.md").read_text()
    assert "| 3 | `margin` | 0 | 1 |" in report and "## Adaptive alpha against every fixed alpha" in report
    cells = cell_times(out)
    assert len(cells) == 6
    again = coopsumo("accident-seeds", *args)
    assert again.returncode == 0, again.stderr[-2000:]
    assert cell_times(out) == cells


# -- the SB3 example (experiments/sb3_dqn.py: an example of the Gymnasium interface, not a command) ---------------
def test_sb3_example_help_shows_every_default() -> None:
    res = subprocess.run([sys.executable, "experiments/sb3_dqn.py", "--help"], cwd=ROOT, capture_output=True,
                         text=True, timeout=120, check=False)  # fmt: skip
    assert res.returncode == 0
    text = " ".join(res.stdout.split())
    assert text.count("(default") == 10  # every option but --help


@pytest.mark.parametrize("args, fragment", [(["--steps", "0"], "--steps"), (["--seed", "-1"], "--seed"),
                                            (["--t-up", "nan"], "--t-up"), (["--threads", "0"], "--threads"),
                                            (["--background", "warp"], "warp")])  # fmt: skip
def test_sb3_example_bad_input_is_one_line_exit_2_and_writes_nothing(args: list[str], fragment: str,
                                                                     tmp_path: Path) -> None:  # fmt: skip
    if args[0] == "--background":
        pytest.importorskip("stable_baselines3")  # checked where the env is made, after the extra's check
    res = subprocess.run([sys.executable, "experiments/sb3_dqn.py", *args, "--out", str(tmp_path / "x")], cwd=ROOT,
                         capture_output=True, text=True, timeout=120, check=False,
                         env={**os.environ, "TMPDIR": str(tmp_path)})  # fmt: skip
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1 and fragment in lines[0], res.stderr[-1500:]
    assert list(tmp_path.iterdir()) == []
