"""The run beside the studies (scenario1 --regime-map; accident-seeds was retired by issue 80): --help, bad input
(one line, exit 2, nothing written), a tiny real run, a rerun that reuses every cell, and the SB3 example under
experiments/."""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from coopsumo import cli

ROOT = Path(__file__).resolve().parent.parent
COMMANDS = {"regime-map": ("scenario1", ["--regime-map"])}
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
]  # fmt: skip


@pytest.mark.parametrize("name, setup, args, fragment", BAD)
def test_bad_input_is_one_line_exit_2_and_writes_nothing(name: str, setup: str | None, args: list[str],
                                                         fragment: str, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    root = tmp_path / "study"
    if setup == "foreign":
        (root / "cells").mkdir(parents=True)
        (root / "notes.txt").write_text("mine")
    before = listing(tmp_path)
    capsys.readouterr()
    argv = [*args, "--out", str(root)]
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
