"""Issue 82, probe 14: records read back are checked against the runs they stand for, each value with the others
(F1: scenario II's cell records; F2: a merged part's rows; F9: a training's lane changes)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
from test_scenario2 import faked_train  # noqa: F401  (the fixture: scenario II's cells without SUMO)

from coopsumo.studies.engine import records
from coopsumo.studies.scenario2 import plan as s2_plan
from coopsumo.studies.scenario2 import study as s2


def _every_evaluation(record: dict[str, Any], **values: Any) -> dict[str, Any]:
    """record with `values` set in each evaluation's summary and its summary pooled again (as records.pool_summaries
    does), so that the summary stays what its evaluations pool to."""
    evals = [{**e, **values} for e in record["eval_summaries"]]
    pooled = {k: v for k, v in records.pool_summaries(evals).items() if k != "eval_seed"}
    return {**record, "eval_summaries": evals, "summary": pooled}


def test_a_cell_record_its_runs_cannot_give_or_not_its_run_folders_is_rerun(
        tmp_path: Path, faked_train: list[str], capsys: pytest.CaptureFixture[str]) -> None:  # noqa: F811  # fmt: skip
    """F1: each value in range, together impossible (a loop flow, vehicles on the road, a throughput or a travel
    time that its departures and arrivals cannot give), or not the summary.json its run folder holds: rerun, one line
    naming the record and the contradiction; a record that agrees with its run folder is reused."""
    profile = s2_plan.PROFILES["tiny"]
    assert s2.run_sweep(profile, tmp_path, progress=False, n_boot=20)["cells_ok"] == 8
    first = pd.read_csv(tmp_path / "runs.csv")
    specs = {s["key"]: s for s in s2_plan.cell_specs(profile)}
    cells = tmp_path / "cells"
    for key in ("L2_T4_a0_s1", "L2_T4_a0_s2"):  # their run folders' summary.json, as a real evaluation leaves them
        record = json.loads((cells / f"{key}.json").read_text())
        for run, summary in zip(s2.CELLS.work(specs[key]).runs, record["eval_summaries"], strict=True):
            (tmp_path / run.out).mkdir(parents=True, exist_ok=True)
            (tmp_path / run.out / "summary.json").write_text(json.dumps({**summary, "policy": "dqn:x"}))
    bad = {"L2_T2_a8_s1": ({"mean_vehicles_on_road": 900.0}, "mean_vehicles_on_road = 900, outside 0 to the 10"),
           "L2_T2_a8_s2": ({"throughput_veh_per_h": 1500.0}, "throughput_veh_per_h = 1500, but 0 vehicles arrived"),
           "L2_T2_a0_s1": ({"mean_travel_time_s": 5.0}, "mean_travel_time_s = 5 without a vehicle that arrived"),
           "L2_T2_a0_s2": ({"loop_flow_veh_h_per_lane": 3000.0}, "loop_flow_veh_h_per_lane = 3000, but 10 vehicles"),
           "L2_T4_a0_s1": ({"mean_speed_mps": 25.0}, "mean_speed_mps = 25.0, but its run folder's")}
    for key, (values, _) in bad.items():
        path = cells / f"{key}.json"
        path.write_text(json.dumps(_every_evaluation(json.loads(path.read_text()), **values)))
    capsys.readouterr()
    del faked_train[1:]
    meta = s2.run_sweep(profile, tmp_path, progress=False, n_boot=20)
    err = capsys.readouterr().err.splitlines()
    assert sorted(faked_train[1:]) == sorted(bad)  # exactly the spoiled cells ran again: L2_T4_a0_s2 was reused
    for key, (_, words) in bad.items():
        lines = [line for line in err if f"cell {key}: record" in line]
        assert len(lines) == 1 and words in lines[0] and lines[0].endswith("rerunning it"), (key, lines)
    assert meta["cells_ok"] == 8 and meta["cells_run"] == len(bad)
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "runs.csv").drop(columns=["cell_wall_s", "cell_cpu_s"]),
                                  first.drop(columns=["cell_wall_s", "cell_cpu_s"]))  # fmt: skip


def test_the_loop_flow_bound_accepts_what_departures_and_lane_changes_give() -> None:
    """F1's loop rule: a mean flow per lane of at most the departures and lane changes over the road's lanes and the
    loop's intervals (the last one cut at the run's end) -- met exactly, refused just above."""
    from coopsumo.studies.engine.run_checks import together_problem

    road = {"road": {"lanes": 2, "loop_period_s": 60.0}}
    run = {"departed": 15.0, "lane_changes": 3.0, "arrived": 0.0, "sim_seconds": 90.0}
    most = 18 * 3600 / (2 * 2 * 30.0)  # two intervals (60 s, then 30 s): every count in the short one
    assert together_problem({**run, "loop_flow_veh_h_per_lane": most}, None, road) is None
    assert "at most 540.00 veh/h" in (together_problem({**run, "loop_flow_veh_h_per_lane": most + 1}, None, road)
                                      or "")  # fmt: skip
    pooled = {k: 2 * v for k, v in run.items()}  # two such runs pooled: counts and seconds summed
    assert together_problem({**pooled, "loop_flow_veh_h_per_lane": most}, None, road, runs=2) is None
    assert together_problem({**pooled, "loop_flow_veh_h_per_lane": most + 1}, None, road, runs=2) is not None
