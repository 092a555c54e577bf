"""Scenario I end to end with tiny step counts, and the report's numbers against the run summaries."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import sumolib
from conftest import assert_refused_in_one_line, env_with_display, main_here
from PIL import Image

from coopsumo import run_dirs
from coopsumo.config import AccidentConfig, OutputConfig, SimConfig, to_dict
from coopsumo.files import file_sha256
from coopsumo.studies.engine import run_folders
from coopsumo.studies.scenario1 import gui as scenario1_gui
from coopsumo.studies.scenario1 import measures
from coopsumo.studies.scenario1 import report as rep
from coopsumo.studies.scenario1 import study as scenario1

pytestmark = pytest.mark.sumo
ROOT = Path(__file__).resolve().parent.parent
PNG = b"\x89PNG\r\n\x1a\n"
TINY = ["--quick", "--train-steps", "400", "--steps", "1500", "--seeds", "2", "--mobil-p", "0,1"]
"""the quick study's 2 demands (T_up 3 and 1 s), 2 models per alpha (0 and 8; training seeds 100 and 101), 2
evaluation seeds, MOBIL p = 0 and 1; 1,500 steps, so that the first vehicles
reach the bottleneck (about step 600) while it still holds most of them and a real jam forms for sumo-gui to show
(at 900 steps the scaled accident had nearly ended by then, and only a policy that stood still of itself made one)"""
LEARNED = ("dqn_alpha0", "dqn_alpha8")
BASELINES = ("keep", "greedy", "mobil_p0", "mobil_p1", "sumo")
POLICIES = LEARNED + BASELINES
MODELS = (100, 101)


def run_name(policy: str, seed: int, train_seed: object = None) -> str:
    """A run folder's name: <policy>[_m<training seed>]_seed<k>."""
    return f"{policy}_seed{seed}" if pd.isna(train_seed) else f"{policy}_m{int(train_seed)}_seed{seed}"  # type: ignore[call-overload]


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory, display_or_none: str | None) -> Path:
    """The quick study, on a (virtual) display when there is one, so that it makes its sumo-gui screenshot; its
    model store (beside its folder) its own."""
    out = tmp_path_factory.mktemp("scenario1") / "study"
    cmd = [sys.executable, "-m", "coopsumo", "scenario1", *TINY, "--out", str(out)]
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False,
                         env=env_with_display(display_or_none))  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    return out


def test_every_output_is_written(study: Path) -> None:
    names = ["fig4_trajectories.png", "fig_tts_demand.png", "fig_tts_difference.png"]
    names += [f"{f}_t{t}.png" for f in ("fig5_flow_density", "fig_recovery") for t in (3, 1)]
    for name in names:
        data = (study / name).read_bytes()
        assert data.startswith(PNG) and len(data) > 10_000, name
    for name in ("summary.csv", "runs.csv", "report.md", "plan.json"):
        assert (study / name).stat().st_size > 0
    for t in (3, 1):
        runs = sorted(p.name for p in (study / "runs" / f"t{t}").iterdir())
        expected = [run_name(p, k) for p in BASELINES for k in (1, 2)]
        expected += [run_name(p, k, m) for p in LEARNED for m in MODELS for k in (1, 2)]
        assert runs == sorted(expected)
    for run in (study / "runs").glob("t*/*"):
        for name in ("config.json", "summary.json", "detectors.xml", "trajectories.parquet", "fcd.xml", "tripinfo.xml"):
            assert (run / name).exists(), f"{run.name}/{name}"
        trips = list(sumolib.xml.parse(str(run / "tripinfo.xml"), "tripinfo"))
        assert len(trips) == json.loads((run / "summary.json").read_text())["arrived"], run.name
        times = {float(t.time) for t in sumolib.xml.parse(str(run / "fcd.xml"), "timestep")}
        assert times == {5.0 * k for k in range(30)}, run.name  # every 5 s of the 150 s run
    for alpha in ("alpha0", "alpha8"):
        for m in MODELS:  # each a link into the model store beside the study
            link = study / "models" / f"{alpha}_m{m}"
            assert link.is_symlink() and (link / "model.pt").is_file()
            assert link.resolve().parent == study.parent / "models"
            assert json.loads((link / "config.json").read_text())["config"]["sim"]["seed"] == m
            driven_runs = list((study / "runs").glob(f"t*/dqn_{alpha}_m{m}_seed*"))
            assert driven_runs
            for run in driven_runs:  # which weights drove it
                driven = json.loads((run / "config.json").read_text())["model_trained_on"]["model_sha256"]
                assert driven == file_sha256(link / "model.pt"), run.name


def test_report_numbers_equal_the_summaries_per_demand(study: Path) -> None:
    runs = pd.read_csv(study / "runs.csv")
    assert sorted(runs["t_up_s"].unique()) == [1.0, 3.0]
    summary = pd.read_csv(study / "summary.csv").set_index(["t_up_s", "policy"])
    for _, row in runs.iterrows():
        run_dir = study / "runs" / f"t{row['t_up_s']:g}" / run_name(row["policy"], row["seed"], row["train_seed"])
        s = json.loads((run_dir / "summary.json").read_text())
        cfg = json.loads((run_dir / "config.json").read_text())["config"]
        assert cfg["demand"]["t_up_s"] == row["t_up_s"]
        assert row["mean_speed_mps"] == pytest.approx(s["mean_speed_mps"])
        assert row["collisions"] == s["collisions"] == 0 and row["teleports"] == s["teleports"] == 0
        assert row["lane_changes_per_vehicle"] == pytest.approx(s["lane_changes"] / max(s["departed"], 1))
        assert row["tts_veh_h"] >= row["waiting_veh_h"] >= 0
    means = runs.groupby(["t_up_s", "policy"])["tts_veh_h"].mean()
    report = (study / "report.md").read_text()
    for key, value in means.items():
        assert summary.loc[key, "tts_veh_h_mean"] == pytest.approx(value)
    for t in (3, 1):
        part = report.split(f"### T_up = {t} s")[1].split("### ")[0]
        for policy in POLICIES:
            assert f"| {policy} | " in part
        # the verdicts of this demand: alpha 8 against 0 and MOBIL p 1 against 0, each with its interval, none
        # passed on 2 models or 2 seeds; the table of each model's total time spent
        assert "- `dqn_alpha8` against `dqn_alpha0` cannot be judged on 2 models (at least 3 needed)" in part
        assert "- `mobil_p1` against `mobil_p0` cannot be judged on 2 seeds" in part and "95% CI" in part
        assert "lower for " in part and " of 2 models, each on 2 seeds" in part
        assert "| policy | model 100 | model 101 | worst | spread (sd) |" in part
    models = runs[runs["train_seed"].notna()]
    assert set(models["train_seed"].astype(int)) == set(MODELS) and runs["train_seed"].isna().sum() == 2 * 2 * 5
    assert "Deviations and choices" in report and "fig4_trajectories.png" in report
    assert "![difference in total time spent](fig_tts_difference.png)" in report and "linear scale" in report
    assert "Where the queue goes" in report and "| T_up (s) |" in report


def test_rerun_reuses_models_and_runs(study: Path, display_or_none: str | None, monkeypatch: pytest.MonkeyPatch,
                                      capfd: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """The study (a process: the module's fixture) rerun by scenario I's main in this process, with the fixture's
    display: it reuses every model and run."""
    model = study / "models" / "alpha8_m100" / "model.pt"
    before = model.stat().st_mtime_ns
    run_summary = next((study / "runs" / "t3").iterdir()) / "summary.json"
    run_before = run_summary.stat().st_mtime_ns
    shot_before = (study / "gui_jam.png").stat().st_mtime_ns if (study / "gui_jam.png").exists() else None
    (study / "fig_backup.png").write_bytes(b"mine")  # a user's: kept (issue 82, probe 8, J24: every fig*.png went)
    (study / "fig5_flow_density_t9.png").write_bytes(b"old")  # a demand the last report showed, this one not: goes
    (study / "report.md").write_text((study / "report.md").read_text() + "\n![old](fig5_flow_density_t9.png)\n")
    users = ["fig_recovery_t7.png", "fig5_flow_density_t1.5.png"] + ([] if display_or_none else ["gui_jam.png"])
    for name in users:  # a user's, at a demand never run, no report showed: kept (issue 82, probe 12, N4)
        (study / name).write_bytes(b"mine")
    with monkeypatch.context() as patch:
        if display_or_none is None:
            patch.delenv("DISPLAY", raising=False)
        else:
            patch.setenv("DISPLAY", display_or_none)
        code, _, err = main_here(scenario1.main, [*TINY, "--out", str(study)], capfd)
    assert code == 0, err[-2000:]
    assert "4 of 4 models from the model store" in err and "sumo-gui screenshot" not in err
    assert model.stat().st_mtime_ns == before and run_summary.stat().st_mtime_ns == run_before
    if shot_before is not None:  # the same sumo-gui screenshot is reused too
        assert (study / "gui_jam.png").stat().st_mtime_ns == shot_before
    assert (study / "fig_backup.png").read_bytes() == b"mine" and not (study / "fig5_flow_density_t9.png").exists()
    for name in ["fig_backup.png", *users]:
        assert (study / name).read_bytes() == b"mine", name
        (study / name).unlink()


def test_the_studys_trainings_run_as_groups(study: Path) -> None:
    """Scenario I's trainings go through the study engine (engine/cells.Study), which trains the stacked learner's
    models as groups first (engine/groups.train_groups): each of the study's 4 models records its share of its
    group's CPU time beside it in the store."""
    from coopsumo.studies.engine.groups import GROUP_COST, group_cpu_s

    links = sorted((study / "models").iterdir())
    assert len(links) == 4
    for link in links:
        assert (link / GROUP_COST).is_file() and json.loads((link / GROUP_COST).read_text())["group_size"] > 1
        assert group_cpu_s(link) is not None, link.name


def test_a_rerun_of_the_finished_study_runs_no_cell(study: Path, monkeypatch: pytest.MonkeyPatch,
                                                    capfd: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Every cell of the finished study (each model's training, each run) is reused: the engine's first line says 0
    to run and no cell record is written again (its report, faked here, is the other rerun test's)."""
    cells = {p.name: p.stat().st_mtime_ns for p in (study / "cells").iterdir()}
    assert len(cells) == 4 + 2 * 2 * (4 + 5)  # 4 trainings; 2 demands x 2 seeds x (4 models + 5 baselines)
    monkeypatch.setattr(scenario1, "write_outputs", lambda *args: None)
    monkeypatch.delenv("DISPLAY", raising=False)
    code, _, err = main_here(scenario1.main, [*TINY, "--out", str(study)], capfd)
    assert code == 0, err[-2000:]
    assert "scenario1: 4 of 4 models from the model store" in err and "; 0 trainings to run" in err
    assert f"scenario1: profile quick: {len(cells)} cells, {len(cells)} already done, 0 failed before (retried), 0 " \
        "to run on the local backend" in err.splitlines(), err[-2000:]  # fmt: skip
    assert {p.name: p.stat().st_mtime_ns for p in (study / "cells").iterdir()} == cells


def test_report_shows_sumo_guis_screenshot_of_the_jam(study: Path, gui_display: str) -> None:
    shot = study / "gui_jam.png"
    assert shot.read_bytes().startswith(PNG)
    pixels = np.asarray(Image.open(shot).convert("RGB")).reshape(-1, 3)
    _, counts = np.unique(pixels, axis=0, return_counts=True)
    assert len(counts) >= 4 and counts.max() < 0.9 * len(pixels)  # not one flat colour
    assert (pixels == (255, 0, 0)).all(axis=1).any()  # the accident bar
    record = json.loads((study / "gui_jam.json").read_text())
    assert record["identical_to_run"] is True and record["run"] == "t1/dqn_alpha8_m100_seed1"
    report = (study / "report.md").read_text()
    assert "![sumo-gui](gui_jam.png)" in report and f"sumo-gui at step {record['step']} " in report
    assert "identical to the recorded run" in report


def test_without_a_display_the_report_says_why_there_is_no_screenshot(tmp_path: Path) -> None:
    (tmp_path / "gui_jam.png").write_bytes(PNG)  # a user's, no report showed it: kept (issue 82, probe 12, N4)
    cfg = SimConfig(accident=AccidentConfig(enabled=True), policy="keep")
    text = scenario1_gui.gui_section(tmp_path, tmp_path / "no_such_run", "keep_seed1", cfg, environ={})
    assert text.startswith("No sumo-gui screenshot: no display") and "xvfb-run" in text
    assert (tmp_path / "gui_jam.png").read_bytes() == PNG
    (tmp_path / "report.md").write_text("# Scenario I\n\n![sumo-gui](gui_jam.png)\n")  # an earlier study's: goes
    scenario1_gui.gui_section(tmp_path, tmp_path / "no_such_run", "keep_seed1", cfg, environ={})
    assert [p.name for p in tmp_path.iterdir()] == ["report.md"]


def test_jam_step_is_the_first_time_the_view_is_nearly_full_of_slow_vehicles() -> None:
    cfg = SimConfig(accident=AccidentConfig(enabled=True, x_m=1300.0))
    rows = [
        (10.0, 1, 1250.0, 2.0),  # 1 slow vehicle in view
        (20.0, 1, 1290.0, 1.0),
        (20.0, 2, 1200.0, 3.0),
        (20.0, 3, 1000.0, 0.0),  # 2 (one is out of view)
        (30.0, 1, 1299.0, 0.5),
        (30.0, 2, 1250.0, 2.0),
        (30.0, 4, 1150.0, 6.0),  # 2 (one is not slow)
        (40.0, 1, 1299.0, 0.5),
        (40.0, 2, 1280.0, 0.0),
        (40.0, 4, 1200.0, 1.0),
    ]  # 3: the most
    traj = pd.DataFrame(rows, columns=["time_s", "vid", "pos_m", "speed_mps"])  # fmt: skip
    assert measures.jam_step(traj, cfg) == 400  # 2 < 0.9 * 3
    assert measures.jam_step(traj[traj["time_s"] < 35], cfg) == 200
    assert measures.jam_step(traj[traj["speed_mps"] > 5], cfg) is None


@pytest.mark.parametrize(
    "args",
    [["--seeds", "0"], ["--workers", "0"], ["--steps", "5"], ["--bogus"], ["--quick", "--full"],
     ["--profile", "quick", "--full"], ["--profile", "huge"], ["--profile", "none.toml"],
     ["--t-up", ""], ["--t-up", "3,,1"], ["--t-up", "0"], ["--t-up", "-1"], ["--t-up", "nan"], ["--t-up", "3,3"],
     ["--t-up", "1,1.0"], ["--t-up", "0.01"], ["--t-up", "x"], ["--mobil-p", "-0.5"], ["--mobil-p", "0,0"],
     ["--mobil-p", "0,"], ["--mobil-p", "inf"]],
)  # fmt: skip
def test_bad_input(tmp_path: Path, args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    """scenario1's main in this process (the one-line refusal of a command run as a process:
    tests/test_bad_inputs.py)."""
    out = tmp_path / "s1"
    code, _, err = main_here(scenario1.main, [*args, "--out", str(out)], capsys)
    assert_refused_in_one_line(code, err, out)


def _rows(values: dict[str, dict[str, list[float]]], t_up: float = 1.0) -> pd.DataFrame:
    """Runs rows of one demand from {policy: {metric: [value per seed]}} (other measures 0)."""
    rows = []
    for policy, metrics in values.items():
        n = len(next(iter(metrics.values())))
        for k in range(n):
            row = {"t_up_s": t_up, "policy": policy, "seed": k + 1, **{m: 0.0 for m, _, _ in measures.METRICS},
                   "horizon_after_start_s": 1000.0}  # fmt: skip
            row.update({m: v[k] for m, v in metrics.items()})
            rows.append(row)
    return pd.DataFrame(rows)


def test_the_consoles_closing_table_says_which_demand_it_shows() -> None:
    rows = pd.concat([_rows({"keep": {"tts_veh_h": [10.0, 12.0]}}, t_up=2.0),
                      _rows({"keep": {"tts_veh_h": [30.0, 34.0]}}, t_up=1.0)])  # fmt: skip
    text = rep.closing_table(measures.aggregate(rows), 1.0)
    head, *table = text.splitlines()
    assert "T_up = 1 s (3,600 veh/h)" in head and "report.md" in head
    assert len([line for line in table if line.startswith("| keep |")]) == 1 and "32.0" in text and "11.0" not in text


def test_cooperative_alpha_is_the_largest_that_still_changes_lanes() -> None:
    rows = _rows({"dqn_alpha0": {"lane_changes_per_vehicle": [2.0, 2.0]},
                  "dqn_alpha2": {"lane_changes_per_vehicle": [0.5, 0.3]},
                  "dqn_alpha8": {"lane_changes_per_vehicle": [0.0, 0.1]}})  # fmt: skip
    labels = {0.0: "dqn_alpha0", 2.0: "dqn_alpha2", 8.0: "dqn_alpha8"}
    assert measures.cooperative_alpha(rows, labels) == 2.0  # 0.05 < 10% of 2.0
    keep_like = _rows({"dqn_alpha0": {"lane_changes_per_vehicle": [2.0]},
                       "dqn_alpha8": {"lane_changes_per_vehicle": [0.0]}})  # fmt: skip
    assert measures.cooperative_alpha(keep_like, {0.0: "dqn_alpha0", 8.0: "dqn_alpha8"}) is None


def test_verdict_on_total_time_spent_with_recovery_counted_at_the_end_when_never() -> None:
    nan = float("nan")
    rows = _rows({"dqn_alpha8": {"tts_veh_h": [90.0, 95.0, 92.0], "system_recovery_s": [500.0, 600.0, 550.0],
                                 "waves": [1.0, 0.0, 1.0]},
                  "dqn_alpha0": {"tts_veh_h": [100.0, 101.0, 99.0], "system_recovery_s": [nan, 700.0, 650.0],
                                 "waves": [3.0, 2.0, 2.0]}})  # fmt: skip
    c = measures.compare(rows, 1.0, "dqn_alpha8", "dqn_alpha0")
    assert c is not None and c["pairs"] == 3 and c["tts_fewer"] == 3
    assert c["tts_veh_h"][0] == pytest.approx(-23.0 / 3) and c["tts_veh_h"][2] < 0
    assert c["system_recovery_s"][0] == pytest.approx((-500.0 - 100.0 - 100.0) / 3)  # never = the 1000 s horizon
    assert c["never_b"] == 1 and c["never_a"] == 0
    text = rep.verdict_line(c)
    assert text.startswith("`dqn_alpha8` against `dqn_alpha0` **helps**: total time spent -7.7 veh-h")
    assert "never recovered: 0 of 3 and 1 of 3 runs" in text and "lower on 3 of 3 seeds" in text
    worse = _rows({"a": {"tts_veh_h": [110.0, 112.0, 111.0]}, "b": {"tts_veh_h": [100.0, 101.0, 99.0]}})
    assert "**hurts**" in rep.verdict_line(measures.compare(worse, 1.0, "a", "b"))
    mixed = _rows({"a": {"tts_veh_h": [90.0, 112.0, 100.0]}, "b": {"tts_veh_h": [100.0, 101.0, 99.0]}})
    undecided = rep.verdict_line(measures.compare(mixed, 1.0, "a", "b"))
    assert "**cannot decide** (the interval includes 0; at the spread measured here it would take about" in undecided
    two = _rows({"a": {"tts_veh_h": [90.0, 91.0]}, "b": {"tts_veh_h": [100.0, 101.0]}})
    assert "cannot be judged on 2 seeds" in rep.verdict_line(measures.compare(two, 1.0, "a", "b"))
    one = _rows({"a": {"tts_veh_h": [90.0]}, "b": {"tts_veh_h": [100.0]}})  # the quick profile's single seed
    assert "cannot be judged on 1 seed (" in rep.verdict_line(measures.compare(one, 1.0, "a", "b"))
    assert rep.verdict_word(measures.compare(one, 1.0, "a", "b")) == "1 seed: too few"
    assert measures.compare(rows, 3.0, "dqn_alpha8", "dqn_alpha0") is None  # no runs at that demand


def test_a_run_is_not_reused_after_its_model_changed(tmp_path: Path) -> None:
    cfg = SimConfig(accident=AccidentConfig(enabled=True), policy="keep")
    out = tmp_path / "run"
    out.mkdir()
    outputs = OutputConfig()
    (out / "config.json").write_text(json.dumps({"config": to_dict(cfg),
                                                 "sumo_outputs": to_dict(outputs)}))  # fmt: skip
    # a run's summary and loops as they agree with each other and the configuration (run_checks)
    summary = {**dict.fromkeys(run_folders.RUN_SUMMARY, 1.0), "throughput_veh_per_h": 0.0, "steps": cfg.steps,
               "sim_seconds": cfg.steps * cfg.control.dt_s}  # fmt: skip
    (out / "summary.json").write_text(json.dumps(summary))
    rows = [f'<interval begin="{t}" end="{t + 60}" id="e1_x00200_l0" nVehContrib="0" flow="0.00" occupancy="0.00" '
            'speed="-1.00"/>' for t in range(0, 900, 60)]  # SUMO's E1 attributes (its -1: no vehicle)
    (out / "detectors.xml").write_text("<detector>\n" + "\n".join(rows) + "\n</detector>\n")
    run_dirs.mark_run_dir(out, "simulate")  # simulate's marker, listing its files: the study may run it again
    model = tmp_path / "model.pt"
    model.write_bytes(b"old")
    old = out.stat().st_mtime_ns - 10**9
    os.utime(model, ns=(old, old))
    assert run_folders.reusable_run(out, to_dict(cfg), outputs, model)
    new = (out / "summary.json").stat().st_mtime_ns + 10**9
    os.utime(model, ns=(new, new))  # retrained after the run
    assert not run_folders.reusable_run(out, to_dict(cfg), outputs, model)
    assert not run_folders.reusable_run(out, to_dict(cfg), outputs, tmp_path / "missing.pt")
    # issue 25: a finished run's values are checked too, not only its configuration
    os.utime(model, ns=(old, old))
    (out / "summary.json").write_text(json.dumps({**summary, "mean_speed_mps": None}))
    assert not run_folders.reusable_run(out, to_dict(cfg), outputs, model)
    # a run that recorded its model's digest is reused exactly when the file holds those bytes, whatever the times:
    # the study's link moved to another, older model file (a model chosen otherwise) is caught
    (out / "summary.json").write_text(json.dumps(summary))
    (out / "config.json").write_text(json.dumps({"config": to_dict(cfg), "sumo_outputs": to_dict(outputs),
                                                 "model_trained_on": {"model_sha256": file_sha256(model)}}))
    run_dirs.mark_run_dir(out, "simulate")  # as such a run marks its folder: its config.json the one it wrote
    other = tmp_path / "other.pt"
    other.write_bytes(b"another model, written long before the run")
    os.utime(other, ns=(old, old))
    assert not run_folders.reusable_run(out, to_dict(cfg), outputs, other)
    os.utime(model, ns=(new, new))  # the same bytes written again (copied, restored) after the run
    assert run_folders.reusable_run(out, to_dict(cfg), outputs, model)


@pytest.mark.parametrize("args", [["--alphas", "-1"], ["--alphas", "x"], ["--preset", "bogus"], ["--t-up", "2,2"],
                                  ["--mobil-p", "-1"], ["--train-seeds", "0"], ["--train-seeds", "-1"],
                                  ["--train-seeds", "2,2"], ["--train-seeds", "abc"], ["--train-seeds", "100,3"],
                                  ["--train-seeds", "3,x"], ["--train-seeds", ""]])  # fmt: skip
def test_bad_study_lists(tmp_path: Path, args: list[str]) -> None:
    out = tmp_path / "s1"
    assert scenario1.main([*args, "--out", str(out)]) == 2
    assert not out.exists()


def test_the_paper_preset_stands_beside_the_default(tmp_path: Path) -> None:
    """--preset default,paper --alphas 0: both learners' alpha = 0 models in one study and one report."""
    out = tmp_path / "s1"
    cmd = [sys.executable, "-m", "coopsumo", "scenario1", "--quick", "--train-steps", "300", "--steps", "450",
           "--seeds", "1", "--train-seeds", "1", "--alphas", "0", "--preset", "default,paper", "--t-up", "2",
           "--mobil-p", "0", "--out", str(out)]  # fmt: skip
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False, env=env_with_display(None))
    assert res.returncode == 0, res.stderr[-2000:]
    models = out / "models"
    assert (models / "alpha0_m100" / "model.pt").exists() and (models / "paper_alpha0_m100" / "model.pt").exists()
    paper = json.loads((models / "paper_alpha0_m100" / "config.json").read_text())
    assert paper["config"]["dqn"]["preset"] == "paper"
    summary = pd.read_csv(out / "summary.csv")
    assert {"dqn_alpha0", "dqn_paper_alpha0", "keep"} <= set(summary["policy"])
    report = (out / "report.md").read_text()
    assert "| dqn_alpha0 | " in report and "| dqn_paper_alpha0 | " in report


def test_regime_map_tells_the_regimes_apart(tmp_path: Path) -> None:
    """`coopsumo scenario1 --regime-map` on shortened plans: a light demand keeps the queue on the road, a heavy one
    (one vehicle every 0.2 s, beyond what 3 lanes can take in) fills the entrance and still waits at the end."""
    from dataclasses import replace

    from coopsumo.studies.scenario1 import regime_map

    base = replace(scenario1.PROFILES["quick"], steps=1500, accident_start=300, accident_steps=900, seeds=(1,),
                   t_ups=(4.0, 0.2))  # fmt: skip
    plans = {"default": base, "paper": replace(base, accident_steps=1100)}
    assert regime_map.run_study(plans, tmp_path, 1) == 0
    table = pd.read_csv(tmp_path / "runs.csv").set_index(["accident", "t_up_s"])
    assert len(table) == 4 and set(table["collisions"]) == {0} and set(table["teleports"]) == {0}
    for length in plans:
        assert table.loc[(length, 4.0), "regime"] == "on the road"
        assert table.loc[(length, 0.2), "regime"] == "still waiting at the end"
        assert table.loc[(length, 0.2), "tts_veh_h"] > table.loc[(length, 4.0), "tts_veh_h"]
    report = (tmp_path / "report.md").read_text()
    assert report.count("| still waiting at the end |") == 2 and report.count("| on the road |") == 2
    # a rerun reuses every run
    stamp = (tmp_path / "runs.csv").stat().st_mtime_ns
    cells = {p: p.stat().st_mtime_ns for p in (tmp_path / "cells").glob("*.json")}
    assert regime_map.run_study(plans, tmp_path, 1) == 0
    assert {p: p.stat().st_mtime_ns for p in (tmp_path / "cells").glob("*.json")} == cells
    assert (tmp_path / "runs.csv").stat().st_mtime_ns >= stamp


def test_regime_map_bad_input_one_line_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """scenario1 --regime-map in this process (the one-line refusal of a command run as a process:
    tests/test_bad_inputs.py): bad demands, and the options of the learned study, which it does not take."""
    out = tmp_path / "out"
    for bad in ("0", "1,,2", "nan", "2,2", "-1"):
        code, _, err = main_here(scenario1.main, ["--regime-map", "--t-up", bad, "--out", str(out)], capsys)
        assert_refused_in_one_line(code, err, out, "--t-up")
    for flag, value in (("--alphas", "8"), ("--train-seeds", "2"), ("--mobil-p", "0"), ("--preset", "paper"),
                        ("--baseline", "keep"), ("--train-steps", "100"), ("--merge", "a,b")):  # fmt: skip
        code, _, err = main_here(scenario1.main, ["--regime-map", flag, value, "--out", str(out)], capsys)
        assert_refused_in_one_line(code, err, out, flag)
    for other in (["--quick"], ["--full"], ["--profile", "quick"]):  # one profile at a time (argparse's exit code 2)
        code, _, err = main_here(scenario1.main, ["--regime-map", *other, "--out", str(out)], capsys)
        assert_refused_in_one_line(code, err, out, "--regime-map")


def _model_rows(policy: str, tts: dict[int, list[float]], t_up: float = 1.0) -> pd.DataFrame:
    """Runs rows of one learned policy: {training seed: [total time spent per evaluation seed]}."""
    frames = []
    for train_seed, values in tts.items():
        frame = _rows({policy: {"tts_veh_h": values}}, t_up)
        frame["train_seed"] = float(train_seed)
        frames.append(frame)
    return pd.concat(frames, ignore_index=True)


def test_claim_a_side_by_side_with_the_default_learners_study(tmp_path: Path) -> None:
    """A study of another learner preset reads the default's study beside it (the same plan but for the presets):
    alpha 8 minus alpha 0 for each learner on its own models, and whether the baselines agree."""
    from dataclasses import replace

    from coopsumo.config import to_dict
    from coopsumo.studies.scenario1.plan import PROFILES

    plan = replace(PROFILES["default"], presets=("alpha_only",), t_ups=(1.0,), train_seeds=(100, 101, 102))
    keep = _rows({"keep": {"tts_veh_h": [120.0, 121.0, 122.0]}})
    keep["train_seed"] = np.nan
    ours = pd.concat([keep, _model_rows("dqn_alpha_only_alpha8", {m: [90.0, 91.0, 92.0] for m in (100, 101, 102)}),
                      _model_rows("dqn_alpha_only_alpha0", {m: [100.0, 101.0, 102.0] for m in (100, 101, 102)})])
    theirs = pd.concat([keep.assign(tts_veh_h=[120.0, 121.0, 130.0]),
                        _model_rows("dqn_alpha8", {100: [99.0, 104.0, 98.0], 101: [103.0, 98.0, 101.0],
                                                   102: [100.0, 100.0, 103.0]}),
                        _model_rows("dqn_alpha0", {m: [100.0, 101.0, 102.0] for m in (100, 101, 102)})])
    text = rep.side_by_side(ours, plan, theirs, "results/scenario1_3models")
    row = next(line for line in text.splitlines() if line.startswith("| T_up 1 s |"))
    ours_cell, theirs_cell = row.split(" | ")[2:4]
    assert ours_cell.startswith("-10.0 [-10.0, -10.0] veh-h, lower for 3 of 3 models: **helps**")
    assert "lower for 2 of 3 models: **cannot decide**" in theirs_cell and "would take about" in theirs_cell
    assert text.endswith("2 of 3 give the same total time spent.")
    # the study beside it is found only when its plan is this plan for the default learner
    root = tmp_path / "scenario1_alpha_only_3models"
    beside = tmp_path / "scenario1_3models"
    beside.mkdir()
    theirs.to_csv(beside / "runs.csv", index=False)
    (beside / "plan.json").write_text(json.dumps({"plan": to_dict(replace(plan, presets=("default",)))}))
    assert rep.default_study(root, plan) == beside
    assert rep.default_study(root, replace(plan, seeds=(1, 2))) is None  # another plan: no pairing
    assert rep.default_study(root, replace(plan, presets=("default",))) is None  # the default's study itself


def test_the_difference_figure_plots_the_numbers_compare_gives() -> None:
    """fig_tts_difference.png's numbers (difference_table) are compare()'s: the verdict table's, pair by pair and
    demand by demand; a pair missing at a demand has no point there."""
    frames = []
    for t_up, shift in ((2.0, 0.0), (1.0, 30.0)):
        frames += [_model_rows("dqn_alpha8", {100: [90.0 + shift, 95.0, 92.0], 101: [99.0, 104.0 + shift, 98.0],
                                              102: [100.0, 97.0, 103.0]}, t_up),
                   _model_rows("dqn_alpha0", {m: [100.0 + shift, 101.0, 102.0] for m in (100, 101, 102)}, t_up),
                   _rows({"mobil_p0": {"tts_veh_h": [120.0, 121.0 + shift, 119.0]}}, t_up)]  # fmt: skip
    frames.append(_rows({"mobil_p0.5": {"tts_veh_h": [118.0, 150.0, 117.0]}}, 1.0))  # at T_up 1 s only
    rows = pd.concat(frames, ignore_index=True)
    pairs = [("dqn_alpha8", "dqn_alpha0"), ("mobil_p0.5", "mobil_p0"), ("dqn_alpha8", "mobil_p0")]
    table = measures.difference_table(rows, pairs)
    assert list(table.columns) == ["a", "b", "t_up_s", "diff", "lo", "hi"]
    assert sorted(zip(table["a"], table["b"], table["t_up_s"], strict=True)) == sorted(
        [(a, b, t) for a, b in pairs for t in (2.0, 1.0) if (a, t) != ("mobil_p0.5", 2.0)])
    for _, r in table.iterrows():
        c = measures.compare(rows, r["t_up_s"], r["a"], r["b"])
        assert c is not None and (r["diff"], r["lo"], r["hi"]) == c["tts_veh_h"]
        assert r["lo"] < r["diff"] < r["hi"]
    at = table.set_index(["a", "b", "t_up_s"])
    assert at.loc[("mobil_p0.5", "mobil_p0", 1.0), "diff"] == pytest.approx(-5.0 / 3)  # (-2 - 1 - 2) / 3
    assert at.loc[("dqn_alpha8", "dqn_alpha0", 2.0), "diff"] == pytest.approx((-26.0 - 2.0 - 3.0) / 9)
    waves = measures.difference_table(rows, pairs[:1], "waves")
    assert (waves["diff"] == 0.0).all() and len(waves) == 2
    assert measures.difference_table(rows, []).empty


def test_the_report_writes_the_difference_figure_and_names_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """write_outputs on a synthetic runs table and run folders (no SUMO): fig_tts_difference.png is written, the
    report shows it beside fig_tts_demand.png, whose caption points to it, and says what it plots."""
    from dataclasses import replace

    from coopsumo.studies.scenario1.plan import PROFILES, Run

    monkeypatch.delenv("DISPLAY", raising=False)  # no sumo-gui screenshot
    plan = replace(PROFILES["default"], t_ups=(2.0, 1.0), seeds=(1, 2, 3), train_seeds=(100, 101, 102),
                   alphas=(0.0, 8.0), mobil_ps=(0.0, 0.5), steps=1200)  # fmt: skip
    cfg = SimConfig(accident=AccidentConfig(enabled=True, x_m=1300.0, start_step=200, duration_steps=600))
    t = np.arange(0.0, 600.0, 1.0)
    traj = pd.DataFrame([(x, v, v % 3, 20.0 * (x - 4.0 * v), 20.0) for v in range(100) for x in t
                         if 0.0 <= 20.0 * (x - 4.0 * v) < 2000.0],
                        columns=["time_s", "vid", "lane", "pos_m", "speed_mps"])  # fmt: skip
    loop = ('<detector><interval begin="0" end="60" id="e1_x01400_l0" nVehContrib="10" flow="600" occupancy="5" '
            'speed="20" harmonicMeanSpeed="20"/></detector>')  # fmt: skip
    root = tmp_path / "study"
    frames, runs = [], []
    for t_up in plan.t_ups:
        for policy, shift in (("dqn_alpha0", 0.0), ("dqn_alpha8", -1.0)):
            frames.append(_model_rows(policy, {m: [100.0 + shift + m - 100, 101.0, 102.0] for m in (100, 101, 102)},
                                      t_up))  # fmt: skip
            runs.append(Run(policy, t_up, 1, root / "runs" / f"{policy}_t{t_up:g}", cfg, 100))
        for policy, tts in (("keep", 110.0), ("mobil_p0", 104.0), ("mobil_p0.5", 103.0)):
            base = _rows({policy: {"tts_veh_h": [tts, tts + 2.0, tts - 1.0]}}, t_up)
            frames.append(base.assign(train_seed=np.nan))
            runs.append(Run(policy, t_up, 1, root / "runs" / f"{policy}_t{t_up:g}", cfg))
    for run in runs:
        run.out.mkdir(parents=True)
        traj.to_parquet(run.out / "trajectories.parquet")
        (run.out / "detectors.xml").write_text(loop)
    rows = pd.concat(frames, ignore_index=True).assign(regime="on the road", spilled_s=np.nan)
    from coopsumo.report import plots

    drawn, draw = [], plots.difference_figure
    monkeypatch.setattr(plots, "difference_figure", lambda *args: drawn.append(args) or draw(*args))
    rep.write_outputs(root, plan, rows, runs, "timing")
    data = (root / "fig_tts_difference.png").read_bytes()
    assert data.startswith(PNG) and len(data) > 10_000
    assert [args[1] for args in drawn] == [rep.TTS_DIFFERENCE_LABEL] and "lower is better" in rep.TTS_DIFFERENCE_LABEL
    report = (root / "report.md").read_text()
    figures = report.split("## Figures")[1]
    assert figures.index("(fig_tts_demand.png)") < figures.index("(fig_tts_difference.png)") < figures.index("Fig. 4")
    assert "the next figure shows the differences" in figures and "a minus b (veh-h, linear scale)" in figures
    assert "learned policies thick, the baselines dashed behind" in report
    assert f"(grey: the accident window; {rep.RECOVERY_LINE})." in report and "dotted: 15 m/s" in rep.RECOVERY_LINE


def test_the_paper_horizon_section_reads_every_model_and_draws_fig4_for_each_learner(study: Path) -> None:
    """The --full profile's section, on the quick study's real run folders: a recovery step (or never) for every
    model of every learned policy, waves on Fig. 4's lane for every run, Fig. 4 of a second learner preset and of the
    calmest and the most thrashing model."""
    from dataclasses import replace

    from coopsumo.studies.scenario1 import horizon as hz
    from coopsumo.studies.scenario1.plan import PROFILES, Run

    rows = pd.read_csv(study / "runs.csv")
    rows["train_seed"] = rows["train_seed"].astype("Int64")
    plan = replace(PROFILES["quick"], t_ups=(3.0, 1.0), seeds=(1, 2), train_seeds=MODELS,
                   presets=("default", "default"), steps=1500)  # fmt: skip
    from coopsumo.config import sim_config_from_dict

    record = json.loads((study / "runs" / "t3" / "keep_seed1" / "config.json").read_text())
    cfg = sim_config_from_dict(record["config"])
    runs = [Run(r.policy, r.t_up_s, r.seed, study / "runs" / f"t{r.t_up_s:g}" / run_name(r.policy, r.seed,
                r.train_seed), cfg, None if pd.isna(r.train_seed) else int(r.train_seed))
            for r in rows.itertuples()]  # fmt: skip
    out = study.parent / "horizon"
    out.mkdir()
    text = hz.horizon_outputs(out, plan, rows, runs, rep.FIG4_LANE)
    for policy in LEARNED:
        lines = [line for line in text.splitlines() if line.startswith(f"| `{policy}` |")]
        assert len(lines) == 2 and all("m100: " in line and "m101: " in line for line in lines)
    waves = [line for line in text.splitlines() if line.count("|") == 5 and line.startswith("| 3 |")]
    assert len(waves) == len(POLICIES)
    assert (out / "fig4_trajectories_default.png").read_bytes().startswith(PNG)
    assert (out / "fig4_calm_thrashing.png").read_bytes().startswith(PNG)  # the calmest and the most thrashing model
    assert "Fig. 4 for the calmest and the most thrashing model at T_up = 1 s" in text and "beside `keep`" in text
