"""Scenario I end to end with tiny step counts, and the report's numbers against the run summaries."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

pytestmark = pytest.mark.sumo
ROOT = Path(__file__).resolve().parent.parent
PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("scenario1")
    cmd = [sys.executable, "-m", "coopsumo.scenario1", "--quick", "--train-steps", "400", "--steps", "900",
           "--seeds", "2", "--out", str(out)]  # fmt: skip
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr[-2000:]
    return out


def test_every_output_is_written(study: Path) -> None:
    for name in ("fig4_time_space.png", "fig5_flow_density.png"):
        data = (study / name).read_bytes()
        assert data.startswith(PNG) and len(data) > 10_000
    for name in ("summary.csv", "runs.csv", "report.md", "plan.json"):
        assert (study / name).stat().st_size > 0
    runs = sorted(p.name for p in (study / "runs").iterdir())
    assert len(runs) == 2 * 6  # 6 policies x 2 seeds
    for run in (study / "runs").iterdir():
        for name in ("config.json", "summary.json", "detectors.xml", "trajectories.parquet"):
            assert (run / name).exists(), f"{run.name}/{name}"
    for alpha in ("alpha0", "alpha8"):
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


def test_rerun_reuses_models_and_runs(study: Path) -> None:
    model = study / "models" / "alpha8" / "model.pt"
    before = model.stat().st_mtime_ns
    run_summary = next((study / "runs").iterdir()) / "summary.json"
    run_before = run_summary.stat().st_mtime_ns
    cmd = [sys.executable, "-m", "coopsumo.scenario1", "--quick", "--train-steps", "400", "--steps", "900",
           "--seeds", "2", "--out", str(study)]  # fmt: skip
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "reusing" in res.stderr
    assert model.stat().st_mtime_ns == before and run_summary.stat().st_mtime_ns == run_before


@pytest.mark.parametrize("args", [["--seeds", "0"], ["--workers", "0"], ["--steps", "5"], ["--bogus"]])
def test_bad_input(tmp_path: Path, args: list[str]) -> None:
    out = tmp_path / "s1"
    res = subprocess.run([sys.executable, "-m", "coopsumo.scenario1", *args, "--out", str(out)], cwd=ROOT,
                         capture_output=True, text=True, check=False)  # fmt: skip
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr
    assert not out.exists()
