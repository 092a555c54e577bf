"""Issue 82, probe 13, F7: `scenario1 --merge` took a part's runs.csv rows as written, though the part still held the
run folders they are measured from (collisions 3 where the run had none, a total time spent of 0.01 veh-h where
the run gives 0.069). A part's row is re-derived from its run folder where the part holds it (merge.derived_problem):
a quick study's own rows are what its runs give, and one edited row is named with its run folder."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO

from coopsumo.studies.scenario1.merge import derived_problem
from coopsumo.studies.scenario1.plan import recorded_plan
from coopsumo.study_tables import SCENARIO1_RUNS

pytestmark = pytest.mark.sumo

STUDY = ["scenario1", "--quick", "--alphas", "0", "--t-up", "2", "--mobil-p", "0", "--seeds", "1", "--train-seeds", "1",
         "--workers", "1", "--steps", "200", "--train-steps", "200", "--quiet"]  # fmt: skip
"""one model and the baselines through a 20 s accident run each (the probe's fixture)"""


@pytest.mark.parametrize("column, value, gives", [("collisions", 3, "gives 0"), ("tts_veh_h", 0.01, "gives 0.0")])
def test_a_row_its_run_folder_does_not_give_is_named(column: str, value: float, gives: str, tmp_path: Path) -> None:
    out = tmp_path / "s1"
    result = subprocess.run([sys.executable, "-m", "coopsumo", *STUDY, "--out", str(out)], capture_output=True,
                            text=True, cwd=REPO, timeout=600, check=False)  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    plan = recorded_plan(out / "plan.json", json.loads((out / "plan.json").read_text())["plan"])
    runs = SCENARIO1_RUNS.read(out / "runs.csv")
    assert derived_problem(out, plan, runs) is None  # every row is what its run gives
    model = int(runs.index[runs["train_seed"].notna()][0])
    edited = runs.assign(**{column: runs[column].mask(runs.index == model, value)})
    problem = derived_problem(out, plan, edited)
    assert problem is not None and problem.startswith(f"row {model + 1} has {column} = "), problem
    assert f"but its run folder {out / 'runs' / 't2'}" in problem and gives in problem, problem
    assert derived_problem(tmp_path / "pruned", plan, edited) is None  # no run folders: values_problem's alone
