"""experiments/profile_cost.py, issue 77's estimate of a scenario II profile's hours from finished studies' records
(docs/performance.md): it must give back a measured study's own cost from that study's cells, and refuse a folder
without runs.csv in one usage line."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "experiments" / "profile_cost.py"


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=120, cwd=ROOT)


def test_the_full_profile_estimated_from_its_own_study_is_its_measured_cost() -> None:
    """results/scenario2 is the full profile run in parts: its report measured 9.74 core-hours of cells (some cells
    ran twice, in two parts); the estimate from its own cells' times must come within 5% of it."""
    done = _run("full", "results/scenario2")
    assert done.returncode == 0, done.stderr
    found = re.fullmatch(r"full: 90 trainings 0\.00 core-h, evaluation cells (\d+\.\d\d) core-h; (\d+\.\d\d) h on 2 "
                         r"cores\n", done.stdout)  # fmt: skip
    assert found, done.stdout
    measured = float(re.search(r"children included: \*\*(\d+\.\d+) core-hours", (ROOT / "results/scenario2/report.md")
                               .read_text()).group(1))  # type: ignore[union-attr]  # fmt: skip
    assert abs(float(found.group(1)) - measured) <= 0.05 * measured
    assert abs(float(found.group(2)) - float(found.group(1)) / 2) <= 0.01  # the CPU over 2 cores


def test_a_folder_without_runs_csv_is_a_usage_line(tmp_path: Path) -> None:
    done = _run("full", str(tmp_path))
    assert done.returncode == 2 and "no runs.csv in" in done.stderr.splitlines()[-1] and not done.stdout
