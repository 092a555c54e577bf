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
from conftest import env_with_display
from PIL import Image

from coopsumo.config import AccidentConfig, SimConfig
from coopsumo.studies import scenario1

pytestmark = pytest.mark.sumo
ROOT = Path(__file__).resolve().parent.parent
PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory, display_or_none: str | None) -> Path:
    """The quick study, on a (virtual) display when there is one, so that it makes its sumo-gui screenshot."""
    out = tmp_path_factory.mktemp("scenario1")
    cmd = [sys.executable, "-m", "coopsumo.scenario1", "--quick", "--train-steps", "400", "--steps", "900",
           "--seeds", "2", "--out", str(out)]  # fmt: skip
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False,
                         env=env_with_display(display_or_none))  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    return out


def test_every_output_is_written(study: Path) -> None:
    for name in ("fig4_time_space.png", "fig5_flow_density.png", "fig_recovery.png"):
        data = (study / name).read_bytes()
        assert data.startswith(PNG) and len(data) > 10_000
    for name in ("summary.csv", "runs.csv", "report.md", "plan.json"):
        assert (study / name).stat().st_size > 0
    runs = sorted(p.name for p in (study / "runs").iterdir())
    assert len(runs) == 2 * 7  # 7 policies (alphas 0, 2, 8 and 4 baselines) x 2 seeds
    for run in (study / "runs").iterdir():
        for name in ("config.json", "summary.json", "detectors.xml", "trajectories.parquet", "fcd.xml", "tripinfo.xml"):
            assert (run / name).exists(), f"{run.name}/{name}"
        trips = list(sumolib.xml.parse(str(run / "tripinfo.xml"), "tripinfo"))
        assert len(trips) == json.loads((run / "summary.json").read_text())["arrived"], run.name
        times = {float(t.time) for t in sumolib.xml.parse(str(run / "fcd.xml"), "timestep")}
        assert times == {5.0 * k for k in range(18)}, run.name  # every 5 s of the 90 s run
    for alpha in ("alpha0", "alpha2", "alpha8"):
        assert (study / "models" / alpha / "model.pt").exists()


def test_report_numbers_equal_the_summaries(study: Path) -> None:
    runs = pd.read_csv(study / "runs.csv")
    summary = pd.read_csv(study / "summary.csv").set_index("policy")
    for _, row in runs.iterrows():
        run_dir = study / "runs" / f"{row['policy']}_seed{row['seed']}"
        s = json.loads((run_dir / "summary.json").read_text())
        assert row["mean_speed_mps"] == pytest.approx(s["mean_speed_mps"])
        assert row["throughput_veh_per_h"] == pytest.approx(s["throughput_veh_per_h"])
        assert row["collisions"] == s["collisions"] == 0
        assert row["lane_changes_per_vehicle"] == pytest.approx(s["lane_changes"] / max(s["departed"], 1))
    means = runs.groupby("policy")["mean_speed_mps"].mean()
    report = (study / "report.md").read_text()
    for policy, value in means.items():
        assert summary.loc[policy, "mean_speed_mps_mean"] == pytest.approx(value)
        assert f"| {policy} | " in report
        assert f"{value:.2f}" in report
    assert "Deviations and choices" in report and "fig4_time_space.png" in report


def test_rerun_reuses_models_and_runs(study: Path, display_or_none: str | None) -> None:
    model = study / "models" / "alpha8" / "model.pt"
    before = model.stat().st_mtime_ns
    run_summary = next((study / "runs").iterdir()) / "summary.json"
    run_before = run_summary.stat().st_mtime_ns
    shot_before = (study / "gui_jam.png").stat().st_mtime_ns if (study / "gui_jam.png").exists() else None
    cmd = [sys.executable, "-m", "coopsumo.scenario1", "--quick", "--train-steps", "400", "--steps", "900",
           "--seeds", "2", "--out", str(study)]  # fmt: skip
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False,
                         env=env_with_display(display_or_none))  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    assert "reusing" in res.stderr and "sumo-gui screenshot" not in res.stderr
    assert model.stat().st_mtime_ns == before and run_summary.stat().st_mtime_ns == run_before
    if shot_before is not None:  # the same sumo-gui screenshot is reused too
        assert (study / "gui_jam.png").stat().st_mtime_ns == shot_before


def test_report_shows_sumo_guis_screenshot_of_the_jam(study: Path, gui_display: str) -> None:
    shot = study / "gui_jam.png"
    assert shot.read_bytes().startswith(PNG)
    pixels = np.asarray(Image.open(shot).convert("RGB")).reshape(-1, 3)
    _, counts = np.unique(pixels, axis=0, return_counts=True)
    assert len(counts) >= 4 and counts.max() < 0.9 * len(pixels)  # not one flat colour
    assert (pixels == (255, 0, 0)).all(axis=1).any()  # the accident bar
    record = json.loads((study / "gui_jam.json").read_text())
    assert record["identical_to_run"] is True and record["run"] == "dqn_alpha8_seed1"
    report = (study / "report.md").read_text()
    assert "![sumo-gui](gui_jam.png)" in report and f"sumo-gui at step {record['step']} " in report
    assert "identical to the recorded run" in report


def test_without_a_display_the_report_says_why_there_is_no_screenshot(tmp_path: Path) -> None:
    (tmp_path / "gui_jam.png").write_bytes(PNG)  # from an earlier study: must not stay beside the new report
    cfg = SimConfig(accident=AccidentConfig(enabled=True), policy="keep")
    text = scenario1.gui_section(tmp_path, tmp_path / "no_such_run", "keep_seed1", cfg, environ={})
    assert text.startswith("No sumo-gui screenshot: no display") and "xvfb-run" in text
    assert list(tmp_path.iterdir()) == []


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
    assert scenario1.jam_step(traj, cfg) == 400  # 2 < 0.9 * 3
    assert scenario1.jam_step(traj[traj["time_s"] < 35], cfg) == 200
    assert scenario1.jam_step(traj[traj["speed_mps"] > 5], cfg) is None


@pytest.mark.parametrize("args", [["--seeds", "0"], ["--workers", "0"], ["--steps", "5"], ["--bogus"]])
def test_bad_input(tmp_path: Path, args: list[str]) -> None:
    out = tmp_path / "s1"
    res = subprocess.run([sys.executable, "-m", "coopsumo.scenario1", *args, "--out", str(out)], cwd=ROOT,
                         capture_output=True, text=True, check=False)  # fmt: skip
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr
    assert not out.exists()


def _agg_rows(values: dict[str, dict[str, list[float]]]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """runs rows and their aggregate from {policy: {metric: [value per seed]}} (other metrics 0)."""
    rows = []
    for policy, metrics in values.items():
        n = len(next(iter(metrics.values())))
        for k in range(n):
            row = {"policy": policy, "seed": k + 1, **{m: 0.0 for m, _, _ in scenario1.METRICS}, "recovery_time_s": 0.0,
                   "backlog_at_accident_end_veh": 0.0, "speed_after_accident_mps": 0.0}  # fmt: skip
            row.update({m: v[k] for m, v in metrics.items()})
            rows.append(row)
    runs = pd.DataFrame(rows)
    return runs, scenario1.aggregate(runs)


def test_cooperative_alpha_is_the_largest_that_still_changes_lanes() -> None:
    _, agg = _agg_rows({"dqn_alpha0": {"lane_changes_per_vehicle": [2.0, 2.0]},
                        "dqn_alpha2": {"lane_changes_per_vehicle": [0.5, 0.3]},
                        "dqn_alpha8": {"lane_changes_per_vehicle": [0.0, 0.1]}})  # fmt: skip
    assert scenario1.cooperative_alpha(agg, "default", (0.0, 2.0, 8.0)) == 2.0  # 0.05 < 10% of 2.0
    _, keep_like = _agg_rows({"dqn_alpha0": {"lane_changes_per_vehicle": [2.0]},
                              "dqn_alpha8": {"lane_changes_per_vehicle": [0.0]}})  # fmt: skip
    assert scenario1.cooperative_alpha(keep_like, "default", (0.0, 8.0)) is None


def test_verdict_on_recovery_and_waves() -> None:
    nan = float("nan")
    runs, agg = _agg_rows({"dqn_alpha8": {"recovery_step": [74_000.0, 76_000.0], "wave_share": [0.01, 0.02]},
                           "dqn_alpha0": {"recovery_step": [nan, nan], "wave_share": [0.05, 0.04]}})  # fmt: skip
    text = scenario1.verdict(runs, agg, "dqn_alpha8", "dqn_alpha0")
    assert text.startswith("**The claim holds here**")
    assert "recovers in 2 of 2 seeds, at step 75000 ± 1414" in text and "never recovers (0 of 2 seeds)" in text
    assert "fewer with `dqn_alpha8` on 2 of 2 seeds" in text
    runs, agg = _agg_rows({"dqn_alpha8": {"recovery_step": [nan, nan], "wave_share": [0.05, 0.05]},
                           "dqn_alpha0": {"recovery_step": [7e4, 7e4], "wave_share": [0.01, 0.01]}})  # fmt: skip
    assert scenario1.verdict(runs, agg, "dqn_alpha8", "dqn_alpha0").startswith("**The claim does not hold here**")


def test_a_run_is_not_reused_after_its_model_changed(tmp_path: Path) -> None:
    cfg = SimConfig(accident=AccidentConfig(enabled=True), policy="keep")
    out = tmp_path / "run"
    out.mkdir()
    outputs = scenario1.OutputConfig()
    (out / "config.json").write_text(json.dumps({"config": scenario1.to_dict(cfg),
                                                 "sumo_outputs": scenario1.to_dict(outputs)}))  # fmt: skip
    (out / "summary.json").write_text("{}")
    model = tmp_path / "model.pt"
    model.write_bytes(b"old")
    old = out.stat().st_mtime_ns - 10**9
    os.utime(model, ns=(old, old))
    assert scenario1._reusable_run(out, cfg, outputs, model)
    new = (out / "summary.json").stat().st_mtime_ns + 10**9
    os.utime(model, ns=(new, new))  # retrained after the run
    assert not scenario1._reusable_run(out, cfg, outputs, model)
    assert not scenario1._reusable_run(out, cfg, outputs, tmp_path / "missing.pt")


@pytest.mark.parametrize("args", [["--alphas", "-1"], ["--alphas", "x"], ["--preset", "bogus"]])
def test_bad_study_lists(tmp_path: Path, args: list[str]) -> None:
    out = tmp_path / "s1"
    assert scenario1.main([*args, "--out", str(out)]) == 2
    assert not out.exists()


def test_the_paper_preset_stands_beside_the_default(tmp_path: Path) -> None:
    """--preset default,paper --alphas 0: both learners' alpha = 0 models in one study and one report."""
    out = tmp_path / "s1"
    cmd = [sys.executable, "-m", "coopsumo.scenario1", "--quick", "--train-steps", "300", "--steps", "450",
           "--seeds", "1", "--alphas", "0", "--preset", "default,paper", "--out", str(out)]  # fmt: skip
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False, env=env_with_display(None))
    assert res.returncode == 0, res.stderr[-2000:]
    assert (out / "models" / "alpha0" / "model.pt").exists() and (out / "models" / "paper_alpha0" / "model.pt").exists()
    paper = json.loads((out / "models" / "paper_alpha0" / "config.json").read_text())
    assert paper["config"]["dqn"]["preset"] == "paper"
    summary = pd.read_csv(out / "summary.csv")
    assert {"dqn_alpha0", "dqn_paper_alpha0", "keep"} <= set(summary["policy"])
    report = (out / "report.md").read_text()
    assert "### Learner preset `default`" in report and "### Learner preset `paper`" in report
