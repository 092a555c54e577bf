"""`python -m coopsumo.simulate` in subprocesses: the run folder it writes, and one-line usage errors."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Callable
from pathlib import Path

import pandas as pd
import pytest
import sumolib
from conftest import REPO, TIMING_KEYS

from coopsumo.config import sim_config_from_dict

pytestmark = pytest.mark.sumo

Cli = Callable[..., subprocess.CompletedProcess[str]]

SUMMARY_KEYS = {
    "steps", "sim_seconds", "departed", "arrived", "insertion_blocked", "insertion_pending_at_end",
    "collisions", "sumo_collisions", "teleports", "lane_changes", "lane_changes_rejected", "lane_changes_per_vehicle",
    "mean_speed_mps", "mean_vehicles_on_road", "mean_travel_time_s", "throughput_veh_per_h", "wall_seconds",
    "steps_per_second", "sumo_step_share", "policy", "scenario", "table_max_dev_pos_m", "table_max_dev_speed_mps",
    "table_mismatch_step", "held_share", "passing_open_share", "passing_taken_share",
}  # fmt: skip


@pytest.fixture(scope="module")
def small_run(
    tmp_path_factory: pytest.TempPathFactory, simulate_cli: Cli
) -> tuple[subprocess.CompletedProcess[str], Path]:
    out = tmp_path_factory.mktemp("cli") / "runs" / "small"
    args = ["--lanes", "2", "--t-up", "1.5", "--policy", "greedy", "--steps", "600", "--seed", "7",
            "--out", str(out), "--trajectories", "--quiet"]  # fmt: skip
    return simulate_cli(args), out


def test_a_valid_run_succeeds_and_leaves_only_its_folder(
    small_run: tuple[subprocess.CompletedProcess[str], Path],
) -> None:
    proc, out = small_run
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "departed=" in proc.stdout and "collisions=0" in proc.stdout
    assert sorted(p.name for p in out.parent.iterdir()) == ["small"]  # no partial folder left behind


def test_config_json_holds_the_config_the_seed_and_versions(
    small_run: tuple[subprocess.CompletedProcess[str], Path],
) -> None:
    _, out = small_run
    data = json.loads((out / "config.json").read_text())
    cfg = sim_config_from_dict(data["config"])
    assert (cfg.seed, cfg.steps, cfg.policy, cfg.road.lanes, cfg.demand.t_up_s) == (7, 600, "greedy", 2, 1.5)
    assert cfg.scenario == "free" and cfg.full_read_every_steps == 10
    for package in ("coopsumo", "sumo", "libsumo", "numpy", "python"):
        assert data["versions"][package] not in ("", None, "not installed"), package
    # the source's commit, as git names it (this checkout is a git clone in CI and here)
    head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short=12", "HEAD"], capture_output=True, text=True)
    if head.returncode != 0:
        pytest.skip("not a git checkout")
    assert data["versions"]["coopsumo_source"].split("-")[0] == head.stdout.strip()


def test_detectors_xml_is_sumo_loop_output_readable_by_sumolib(
    small_run: tuple[subprocess.CompletedProcess[str], Path],
) -> None:
    _, out = small_run
    intervals = list(sumolib.xml.parse(str(out / "detectors.xml"), "interval"))
    ids = {iv.id for iv in intervals}
    assert len(ids) == 2 * 9  # 2 lanes x loops every 200 m from 200 to 1800 m
    assert {float(iv.begin) for iv in intervals} == {0.0}
    assert sum(int(iv.nVehContrib) for iv in intervals) > 0


def test_summary_json_has_every_key_and_agrees_with_the_trajectories(
    small_run: tuple[subprocess.CompletedProcess[str], Path],
) -> None:
    _, out = small_run
    summary = json.loads((out / "summary.json").read_text())
    assert SUMMARY_KEYS <= set(summary)
    assert summary["steps"] == 600 and summary["sim_seconds"] == pytest.approx(60.0)
    assert summary["policy"] == "greedy" and summary["scenario"] == "free"
    assert summary["collisions"] == 0 and summary["teleports"] == 0
    traj = pd.read_parquet(out / "trajectories.parquet")
    assert list(traj.columns) == ["time_s", "vid", "lane", "pos_m", "speed_mps"]
    assert traj["vid"].nunique() == summary["departed"]
    assert traj["time_s"].max() == pytest.approx(60.0)
    assert set(traj["lane"].unique().tolist()) <= {0, 1}
    assert traj["pos_m"].between(0.0, 2000.0).all() and (traj["speed_mps"] >= 0).all()
    last = traj[traj["time_s"] == traj["time_s"].max()]
    assert summary["arrived"] == summary["departed"] - len(last)


def test_read_every_step_is_recorded_in_the_config_and_changes_nothing(
    small_run: tuple[subprocess.CompletedProcess[str], Path], simulate_cli: Cli
) -> None:
    _, small = small_run
    out = small.parent.parent / "every"  # beside runs/, which must hold only small
    args = ["--lanes", "2", "--t-up", "1.5", "--policy", "greedy", "--steps", "600", "--seed", "7",
            "--out", str(out), "--trajectories", "--quiet", "--read-every-step"]  # fmt: skip
    proc = simulate_cli(args)
    assert proc.returncode == 0, proc.stderr
    assert json.loads((out / "config.json").read_text())["config"]["full_read_every_steps"] == 1
    summaries = [{k: v for k, v in json.loads((d / "summary.json").read_text()).items() if k not in TIMING_KEYS}
                 for d in (small, out)]  # fmt: skip
    assert summaries[0] == summaries[1] and summaries[0]["table_max_dev_pos_m"] == 0.0
    pd.testing.assert_frame_equal(pd.read_parquet(small / "trajectories.parquet"),
                                  pd.read_parquet(out / "trajectories.parquet"))  # fmt: skip


def test_trajectories_only_when_asked(tmp_path: Path, simulate_cli: Cli) -> None:
    out = tmp_path / "plain"
    proc = simulate_cli(["--lanes", "3", "--steps", "50", "--out", str(out), "--quiet"])
    assert proc.returncode == 0, proc.stderr
    assert {p.name for p in out.iterdir()} >= {"config.json", "detectors.xml", "summary.json"}
    assert not (out / "trajectories.parquet").exists()
    # running again into the same run folder replaces it
    proc = simulate_cli(["--lanes", "3", "--steps", "60", "--out", str(out), "--quiet"])
    assert proc.returncode == 0, proc.stderr
    assert json.loads((out / "summary.json").read_text())["steps"] == 60


BAD_INPUTS = [
    (["--lanes", "1"], "lanes"),
    (["--lanes", "7"], "lanes"),
    (["--t-up", "0"], "t-up"),
    (["--t-up", "-1"], "t-up"),
    (["--t-up", "nan"], "t-up"),
    (["--steps", "0"], "steps"),
    (["--policy", "foo"], "foo"),
    (["--scenario", "foo"], "scenario"),
    (["--lanes", "three"], "lanes"),
]


@pytest.mark.parametrize(("extra", "named"), BAD_INPUTS, ids=[" ".join(a) for a, _ in BAD_INPUTS])
def test_bad_input_is_one_line_exit_2_and_no_folder(
    tmp_path: Path, simulate_cli: Cli, extra: list[str], named: str
) -> None:
    out = tmp_path / "run"
    proc = simulate_cli(["--steps", "50", "--quiet", "--out", str(out), *extra])
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert named in lines[0] and "error" in lines[0]
    assert proc.stdout == ""
    assert list(tmp_path.iterdir()) == []


def test_an_output_folder_that_cannot_be_written_is_a_usage_error(tmp_path: Path, simulate_cli: Cli) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder\n")
    proc = simulate_cli(["--steps", "50", "--quiet", "--out", str(blocker / "run")])
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "output folder" in lines[0], proc.stderr
    assert [p.name for p in tmp_path.iterdir()] == ["a_file"]


def test_an_output_folder_holding_something_else_is_left_alone(tmp_path: Path, simulate_cli: Cli) -> None:
    out = tmp_path / "precious"
    out.mkdir()
    (out / "notes.txt").write_text("keep me\n")
    proc = simulate_cli(["--steps", "50", "--quiet", "--out", str(out)])
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "not a coopsumo run folder" in lines[0], proc.stderr
    assert [p.name for p in out.iterdir()] == ["notes.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["precious"]
