"""Issue 82, probe 13: what `scenario2 --merge` reads of a part, checked without a sweep. F1: a part whose profile
runs keep or MOBIL without trajectories (the tiny profile's cells, or a profile of one's own) ended the merge in a
KeyError; its classical cells' configuration is the SimConfig itself."""

from __future__ import annotations

from dataclasses import replace

import pandas as pd

from coopsumo.studies.scenario2 import plan as s2_plan
from coopsumo.studies.scenario2 import redraw


def test_a_part_with_baselines_and_no_trajectories_has_its_speeds_checked() -> None:
    """Every cell's road is found (no KeyError), and a keep run above its road's limit is still refused."""
    profile = replace(s2_plan.PROFILES["tiny"], policies=("dqn", "mobil", "keep"))
    assert not profile.trajectory_every_steps
    specs = s2_plan.cell_specs(profile)
    keep = next(s["key"] for s in specs if s["policy"] == "keep")
    runs = pd.DataFrame([{"key": s["key"], "mean_speed_mps": 20.0} for s in specs])
    assert redraw._speed_problem(specs, runs, runs.iloc[:0]) is None
    runs.loc[runs["key"] == keep, "mean_speed_mps"] = 60.0
    problem = redraw._speed_problem(specs, runs, runs.iloc[:0])
    assert problem is not None and f"mean_speed_mps = 60.0 for {keep}, above any vehicle's speed" in problem
