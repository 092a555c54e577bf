"""Issue 82, probe 14, F3: `scenario1 --merge` took a row whose run folder is gone with a recovery of 500 s in a 25 s
horizon, or queue lane changes beside no lane changes; they reached runs.csv and summary.csv. A row is bounded by its
run's horizon and its own lane changes (merge._run_bounds): one line naming the part and the row, exit 2, nothing
written; every committed scenario I runs.csv still passes."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pandas as pd
import pytest
from conftest import REPO
from test_scenario1_merge import HALVES, make_part

from coopsumo.studies.scenario1 import study as s1
from coopsumo.studies.scenario1.merge import values_problem
from coopsumo.studies.scenario1.plan import recorded_plan
from coopsumo.study_tables import SCENARIO1_RUNS

EDITS = [  # (column, seconds after the row's horizon or None: queue lane changes beside none, the words)
    ("recovery_time_s", 500.0, "recovery_time_s = "),
    ("system_recovery_s", 1.0, "system_recovery_s = "),
    ("spilled_s", 1.0, "spilled_s = "),
    ("queue_lane_changes_per_vehicle", None,
     "queue_lane_changes_per_vehicle = 1 above its lane_changes_per_vehicle = 0"),
]


def edited(runs: pd.DataFrame, row: int, column: str, after: float | None) -> pd.DataFrame:
    runs = runs.copy()
    if after is None:
        runs.at[row, "lane_changes_per_vehicle"], runs.at[row, column] = 0.0, 1.0
    else:
        runs.at[row, column] = float(runs.at[row, "horizon_after_start_s"]) + after
    return runs


@pytest.mark.parametrize(("column", "after", "words"), EDITS, ids=[e[0] for e in EDITS])
def test_a_merge_refuses_a_row_its_horizon_or_its_lane_changes_cannot_give(
        column: str, after: float | None, words: str, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    parts = [make_part(tmp_path, name, seeds) for name, seeds in HALVES.items()]
    runs = pd.read_csv(parts[1] / "runs.csv")
    row = int(runs.index[runs["train_seed"].notna()][0])
    edited(runs, row, column, after).to_csv(parts[1] / "runs.csv", index=False)
    out = tmp_path / "merged"
    code = s1.main(["--merge", ",".join(map(str, parts)), "--out", str(out)])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1, err
    assert f"{parts[1]}/runs.csv row {row + 1} has {words}" in err[0], err[0]
    assert not out.exists()


def test_every_committed_scenario1_runs_csv_is_inside_the_bounds() -> None:
    listed = subprocess.run(["git", "ls-files", "*runs.csv"], cwd=REPO, capture_output=True, text=True, check=True)
    files = [REPO / f for f in listed.stdout.split()]
    judged = 0
    for path in files:
        if not (path.parent / "plan.json").is_file() or "queue_lane_changes_per_vehicle" not in path.read_text()[:2000]:
            continue
        recorded = json.loads((path.parent / "plan.json").read_text())
        if not isinstance(recorded.get("plan"), dict):
            continue
        plan = recorded_plan(path.parent / "plan.json", recorded["plan"])
        assert values_problem(plan, SCENARIO1_RUNS.read(path)) is None, path
        judged += 1
    assert judged == 18, judged  # every scenario I study committed (the learning studies hold no scenario I plan)
