"""Scenario II's lane-network profiles (full, check, paper; issue 65): the full-road speed on known trajectories, the
gate, the trends' models-to-decide and the check on hand-made tables, the plan (one model per alpha, or one
alpha-conditioned network, per lane count and seed; its store identity), bad input, and the check and full profiles
end to end at a tiny size on SUMO."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from conftest import main_here

from coopsumo.config import as_data
from coopsumo.studies.engine.model_store import model_id
from coopsumo.studies.scenario2 import gate, gate_report, plan
from coopsumo.studies.scenario2 import study as s2
from coopsumo.studies.scenario2.redraw import TIMING, rewrite_outputs

REPO = Path(__file__).resolve().parent.parent
FULL_ROAD = plan.FULL_ROAD


# -- the measure that starts when the road is full -------------------------------------------------------------
def trajectory(speed_at: Any, every_s: float = 5.0, end_s: float = 400.0, insert_every_s: float = 2.0,
               travel_s: float = 80.0) -> pd.DataFrame:  # fmt: skip
    """A road filling from empty: vehicle i enters at i x insert_every_s and leaves travel_s later; sampled every
    every_s (the sample at exactly its leaving time no longer holds it), each sample's speed speed_at(t)."""
    rows = []
    for t in np.arange(0.0, end_s + 1e-9, every_s):
        n_in = int(t // insert_every_s) + 1
        for vid in range(n_in):
            if vid * insert_every_s <= t < vid * insert_every_s + travel_s:
                rows.append({"time_s": t, "vid": vid, "speed_mps": speed_at(t)})
    return pd.DataFrame(rows)


def test_the_full_road_speed_sees_a_jam_the_whole_run_dilutes() -> None:
    """Free (25 m/s) for the first 200 s, jammed (5 m/s) after: the road is full from 80 s, when vehicle 0 has left,
    so the measure weighs the jam more than the whole-run mean does, and equals distance over vehicle time from
    80 s on."""
    traj = trajectory(lambda t: 25.0 if t < 200 else 5.0)
    speed, start = gate.full_road_speed(traj)
    assert start == 80.0
    later = traj[traj["time_s"] >= 80.0]
    assert speed == pytest.approx(later["speed_mps"].mean())
    assert speed < traj["speed_mps"].mean() - 1.0
    assert 5.0 < speed < 25.0


def test_the_full_road_speed_ignores_the_fill_up() -> None:
    """Whatever the speeds while the road fills (a free road: fast, or a slow start), the measure is the speed once it
    is full: 12 m/s."""
    for fill in (33.0, 1.0):
        speed, start = gate.full_road_speed(trajectory(lambda t, fill=fill: fill if t < 80 else 12.0))
        assert (speed, start) == (12.0, 80.0)
    whole = trajectory(lambda t: 33.0 if t < 80 else 12.0)["speed_mps"].mean()
    assert whole > 12.5  # the whole-run mean carries the fill-up


def test_the_full_road_speed_needs_the_first_vehicle_to_leave() -> None:
    assert all(math.isnan(x) for x in gate.full_road_speed(trajectory(lambda t: 20.0, end_s=75.0)))
    assert all(math.isnan(x) for x in gate.full_road_speed(pd.DataFrame(columns=["time_s", "vid", "speed_mps"])))
    # two vehicles first seen together: the smaller vid is the first inserted; it leaves at 10 s, the other later
    both = pd.DataFrame({"time_s": [0.0, 0.0, 5.0, 5.0, 10.0, 15.0], "vid": [3, 1, 3, 1, 3, 3],
                         "speed_mps": [30.0, 30.0, 30.0, 30.0, 8.0, 6.0]})  # fmt: skip
    assert gate.full_road_speed(both) == (7.0, 10.0)


# -- the gate on hand-made tables -------------------------------------------------------------------------------
KEEP = {2001: 15.0, 2002: 15.4, 2003: 14.6}


def hand_made(gaps: dict[tuple[int, float], dict[str, float]], models: int = 3) -> tuple[pd.DataFrame, pd.DataFrame]:
    """runs and evals tables for conditions {(lanes, t_up): {"a0": gap of alpha-0 models to keep, "a8": ..., "pa0",
    "pa8" (per-alpha models), "mobil0": gap of MOBIL p 0, "mobil1": ..., "greedy": ...}}; a model's seed adds 0.01
    x seed, lane changes per vehicle: alpha 0 0.9, alpha 8 0.1, MOBIL p 0 1.4, p 1 1.8."""
    evals, runs = [], []
    lc = {"a0": 0.9, "a8": 0.1, "pa0": 1.0, "pa8": 0.2, "mobil0": 1.4, "mobil1": 1.8, "greedy": 2.5, "keep": 0.0}
    for (lanes, t_up), by in gaps.items():
        load = plan.load_of(lanes, t_up)
        coords = {"lanes": lanes, "t_up_s": t_up, "load": load}
        for name, gap in {**by, "keep": 0.0}.items():
            if name.startswith(("a", "pa")):
                policy = "dqn" if name.startswith("a") else plan.PER_ALPHA
                alpha = float(name.lstrip("pa"))
                for seed in range(1, models + 1):
                    key = f"L{lanes}_T{t_up:g}_{name}_s{seed}"
                    speeds = [v + gap + 0.01 * seed for v in KEEP.values()]
                    for e, v in zip(KEEP, speeds, strict=True):
                        evals.append({"key": key, **coords, "policy": policy, "alpha": alpha, "p": np.nan,
                                      "seed": seed, "eval_seed": e, FULL_ROAD: v, "mean_speed_mps": v + 1,
                                      "lane_changes_per_vehicle": lc[name], "wall_seconds": 9.0})  # fmt: skip
                    runs.append({"key": key, **coords, "alpha": alpha, "seed": seed, "policy": policy, "p": np.nan,
                                 "status": "ok", FULL_ROAD: float(np.mean(speeds)),
                                 "mean_speed_mps": float(np.mean(speeds)) + 1,
                                 "lane_changes_per_vehicle": lc[name], "collisions": 0, "teleports": 0,
                                 "cell_cpu_s": 627.0, "resumed_from_step": pd.NA if seed == 1 else 90_000})  # fmt: skip
            else:
                policy = "mobil" if name.startswith("mobil") else name
                p = float(name.removeprefix("mobil")) if policy == "mobil" else np.nan
                for e, v in KEEP.items():
                    key = f"L{lanes}_T{t_up:g}_{name}_s{e}"
                    row = {"key": key, **coords, "policy": policy, "alpha": np.nan, "p": p, FULL_ROAD: v + gap,
                           "mean_speed_mps": v + gap + 1, "lane_changes_per_vehicle": lc[name]}  # fmt: skip
                    evals.append({**row, "seed": np.nan, "eval_seed": e, "wall_seconds": 4.5})
                    runs.append({**row, "seed": e, "status": "ok", "collisions": 0, "teleports": 0, "cell_cpu_s": 4.5,
                                 "resumed_from_step": pd.NA})  # fmt: skip
    runs_df = pd.DataFrame(runs)
    runs_df["resumed_from_step"] = runs_df["resumed_from_step"].astype("Int64")
    return runs_df, pd.DataFrame(evals)


CONDITIONS = {(3, 1.33): {"a0": 1.0, "a8": 0.5, "pa0": 1.1, "pa8": 0.4, "mobil0": 1.2, "mobil1": 0.9, "greedy": 0.3},
              (3, 0.67): {"a0": -0.5, "a8": -0.2, "pa0": -0.4, "pa8": -0.1, "mobil0": 0.8, "mobil1": 1.0,
                          "greedy": -1.0}}  # fmt: skip
"""one condition whose alpha-0 models beat keep by 1 m/s, one where they lose 0.5 m/s to it"""


def flag(value: Any) -> bool | None:
    """A gate flag as Python's bool (a table's column of flags may hold numpy's), None kept."""
    return None if value is None else bool(value)


def tables(runs: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    from coopsumo.studies.scenario2.measures import alpha_star_table, mobil_p_star_table, policy_rows

    alpha, _ = alpha_star_table(policy_rows(runs, "dqn"), (0.0, 8.0), (1, 2, 3), n_boot=200, metric=FULL_ROAD)
    p = mobil_p_star_table(policy_rows(runs, "mobil"), (0.0, 1.0), tuple(KEEP), metric=FULL_ROAD)
    return alpha, p


def test_the_gate_on_a_condition_that_passes_and_one_that_does_not() -> None:
    runs, evals = hand_made(CONDITIONS)
    alpha, p = tables(runs)
    table = gate.gate_table(runs, evals, alpha, p, FULL_ROAD, reps=500).set_index("t_up_s")
    passes, fails = table.loc[1.33], table.loc[0.67]
    assert flag(passes["passes"]) is True and flag(passes["beats_keep"]) is True and passes["alpha0_models"] == 3
    assert passes["alpha0_minus_keep_mps"] == pytest.approx(1.02)  # + 0.01 x the mean seed, 2
    assert passes["alpha0_minus_keep_low"] > 0 and passes["keep_mps"] == pytest.approx(15.0)
    assert passes["alpha0_lc_per_vehicle"] == 0.9 and passes["lc_share"] == pytest.approx(0.9 / 1.4)
    # alpha* 0 against p* 0: 1.02 against 1.2, within 0.3 m/s and not ahead
    assert passes["alpha_star"] == 0.0 and passes["p_star"] == 0.0
    assert passes["alpha_star_minus_p_star_mps"] == pytest.approx(-0.18)
    assert flag(passes["near_p_star"]) is True and flag(passes["ahead_of_p_star"]) is False
    assert flag(fails["passes"]) is False and fails["alpha0_minus_keep_high"] < 0
    assert fails["alpha_star"] == 8.0 and fails["p_star"] == 1.0 and flag(fails["near_p_star"]) is False
    # without keep runs or alpha-0 models the gate cannot be judged: None, and every condition enters the trends
    no_keep = gate.gate_table(runs, evals[evals["policy"] != "keep"], alpha, p, FULL_ROAD, reps=100)
    assert no_keep["passes"].isna().all()
    assert gate_report.passing_conditions(no_keep) == {(3, 1.33), (3, 0.67)}
    assert gate_report.passing_conditions(gate.gate_table(runs, evals, alpha, p, FULL_ROAD, reps=100)) == {(3, 1.33)}


def test_each_alpha_gets_its_lane_changes_and_the_check_compares_spreads() -> None:
    runs, _ = hand_made(CONDITIONS)
    alpha, _ = tables(runs)
    with_lc = gate.lane_change_columns(alpha, runs, (0.0, 8.0)).set_index("t_up_s")
    assert with_lc.loc[1.33, "lc_per_vehicle_alpha0"] == pytest.approx(0.9)
    assert with_lc.loc[1.33, "lc_per_vehicle_alpha8"] == pytest.approx(0.1)
    assert with_lc.loc[0.67, "alpha_star_lc_per_vehicle"] == pytest.approx(0.1)  # alpha* 8 there
    check = gate.check_table(runs, (0.0, 8.0), FULL_ROAD).set_index(["t_up_s", "alpha"])
    assert len(check) == 4 and (check["conditioned_models"] == 3).all() and (check["per_alpha_models"] == 3).all()
    # per-alpha models at +1.1 + 0.01 seed (15.11-15.13 over the seeds' mean speed 15): the network's +1.02 is below
    row = check.loc[(1.33, 0.0)]
    assert row["per_alpha_min_mps"] == pytest.approx(16.11) and row["per_alpha_max_mps"] == pytest.approx(16.13)
    assert row["conditioned_mps"] == pytest.approx(16.02) and flag(row["within"]) is False
    same = runs.copy()
    same.loc[same["policy"] == plan.PER_ALPHA, FULL_ROAD] -= 0.1  # now 16.01-16.03: the network's 16.02 within
    assert flag(gate.check_table(same, (0.0,), FULL_ROAD).set_index("t_up_s").loc[1.33, "within"]) is True


def test_models_to_decide_a_trend() -> None:
    # half-width 0.55 at 5 models for a slope of -0.5: (0.55 / 0.5)^2 x 5 = 6.05 -> 7 models
    assert gate.models_to_decide(-0.5, -1.05, 0.05, 5) == 7
    assert gate.models_to_decide(-0.5, -0.9, -0.1, 5) is None  # decided already
    assert gate.models_to_decide(0.0, -0.5, 0.5, 5) is None  # no number of models decides a zero slope
    assert gate.models_to_decide(-0.01, -1.0, 1.0, 5) == 5 * 100**2
    assert gate.models_to_decide(-2.0, -2.1, 0.1, 5) == 6  # at least one more than measured


def test_trends_over_the_passing_conditions() -> None:
    rows = [(2, 2.0, 0.0), (2, 1.0, 1.0), (3, 1.33, 0.0), (3, 0.67, 2.0), (4, 1.0, 1.0), (4, 0.5, 8.0)]
    table = pd.DataFrame([{"lanes": n, "t_up_s": t, "alpha_star": a} for n, t, a in rows])
    rng = np.random.default_rng(1)
    boots = {(n, t): np.clip(a + rng.normal(0, 1.0, 400), 0, None) for n, t, a in rows}
    trends = gate.trend_rows(table, boots, 5)
    assert trends["n"] == 6 and trends["b1"] < 0 and {"b1_p05", "b2_p95"} <= set(trends["bootstrap"])
    assert set(trends) >= {"b1_models_to_decide", "b2_models_to_decide"}
    assert "error" in gate.trend_rows(table.iloc[:2], boots, 5)  # one lane count: no plane
    text = gate_report.trend_text(trends, 6, 12, 5)
    assert "Fitted over the 6 of 12 conditions that pass the gate" in text and "90% interval over models" in text


def test_the_report_of_hand_made_tables(tmp_path: Path) -> None:
    """write_lane_outputs without SUMO: the gate marks the failing condition, the trends say how many remain, the
    check says where the network lies, the costs are measured and extrapolated."""
    runs, evals = hand_made(CONDITIONS)
    profile = replace(plan.PROFILES["check"], alphas=(0.0, 8.0), check_alphas=(0.0, 8.0), mobil_ps=(0.0, 1.0))
    meta: dict[str, Any] = {"conditions": [{"lanes": 3, "t_up_s": t} for t in (1.33, 0.67)], "cells": len(runs),
                            "cells_ok": len(runs), "cells_failed": 0, "trainings": 12, "backend": "local",
                            "workers": 2, "wall_seconds": 3600.0, "cells_run": len(runs),
                            "cell_cpu_seconds_sum": 7000.0, "cell_wall_seconds_sum": 7100.0,
                            "bootstrap_replicates": 200, "versions": {}}  # fmt: skip
    gate_report.write_lane_outputs(tmp_path, runs, evals, profile, meta, n_boot=200)
    for name in ("gate.csv", "alpha_star.csv", "mobil_p_star.csv", "check.csv", "fig6_speed_heatmap.png"):
        assert (tmp_path / name).is_file(), name
    report = (tmp_path / "report.md").read_text()
    assert "**The alpha-0 models beat `keep` in 1 of 2 conditions**" in report
    assert "| 3 | 0.67 |" in report and "**no** ✗" in report and "| 3 ✗ | 0.67 |" in report
    assert "Fitted over the 1 of 2 conditions that pass the gate" in report and "No plane fitted" in report
    assert "within the per-alpha models' spread (min to max over models) at 0 of 4" in report
    assert "**1.00 h**" in report and "**1.94 core-hours**" in report
    assert "| `full` | 90 | 576 |" in report and "| `paper` | 600 | 3750 |" in report
    assert meta["gate"] == {"conditions": 2, "judged": True, "passing": 1, "in_trend_fit": 1}
    json.dumps(meta)  # sweep.json can hold it
    costs = meta["step_costs"]
    # a training: its cell's 627 core-s less its 3 evaluations of 9 s, over 90,000 steps
    assert costs["train_core_s_by_lanes"] == {3: 600.0} and costs["train_a"] == pytest.approx(600 / 90_000)
    full = meta["estimates"]["full"]
    evaluation = sum(len(plan.PROFILES["full"].eval_seeds) * 9000 * (30 * 1e-3 + 6 * 5e-4)
                     for _ in plan.PROFILES["full"].conditions())  # fmt: skip
    assert full["training_core_hours"] == pytest.approx(90 * 600 / 3600)
    assert full["evaluation_core_hours"] == pytest.approx(evaluation / 3600)


# -- the plan --------------------------------------------------------------------------------------------------
def test_the_full_and_check_profiles() -> None:
    full, check = plan.PROFILES["full"], plan.PROFILES["check"]
    assert full.lanes == (2, 3, 4) and full.loads == (0.25, 0.5, 0.75, 1.0) and len(full.eval_seeds) == 3
    assert full.alphas == (0.0, 0.25, 1.0, 2.0, 8.0, 32.0) and len(full.seeds) == 5 and full.criterion == FULL_ROAD
    assert (full.train_steps, full.eval_steps, full.n_trainings(), full.n_cells()) == (90_000, 9000, 90, 576)
    assert set(full.policies) == {"dqn", "mobil", "keep", "greedy"} and full.mobil_ps == (0.0, 0.25, 0.5, 1.0)
    assert check.conditions() == [(3, 1.33, 0.5), (3, 0.67, 1.0)] and check.n_trainings() == 12
    assert s2.DEFAULT_PROFILE == "full" and plan.PROFILES["paper"].n_trainings() == 5 * 12 * 10
    specs = plan.cell_specs(full)
    trainings: dict[str, list[dict[str, Any]]] = {}
    for spec in specs:
        if spec["policy"] == "dqn":
            trainings.setdefault(spec["train_key"], []).append(spec)
    assert len(trainings) == 3 * 6 * 5 and all(len(cells) == 4 for cells in trainings.values())
    for key, cells in trainings.items():  # every cell of a training waits for its first, which trains it
        assert "after" not in cells[0] and all(c["after"] == cells[0]["key"] for c in cells[1:]), key
        assert len({json.dumps(c["config"]["train"], sort_keys=True) for c in cells}) == 1
        assert all(not c["conditioned"] and c["evals_key"] == c["key"] for c in cells)
        assert len({c["alpha"] for c in cells}) == 1 and len({c["t_up_s"] for c in cells}) == 4
    train = trainings["L4_a32_s2"][0]["config"]["train"]
    dqn = train["dqn"]
    assert not dqn["alpha_conditioned"] and train["sim"]["reward"]["alpha"] == 32
    assert dqn["train_t_ups"] == dqn["validation_t_ups"] == [2.0, 1.0, 0.67, 0.5]
    assert dqn["preset"] == "default" and dqn["accident_share"] == 0 and dqn["validation_accident_steps"] == 0
    assert dqn["select_every_steps"] == 15_000 and train["sim"]["steps"] == 90_000 and train["sim"]["seed"] == 2
    assert train["sim"]["road"]["lanes"] == 4
    cell = next(s for s in specs if s["key"] == "L4_T0.5_a32_s2")
    assert [e["seed"] for e in cell["config"]["evals"]] == [2001, 2002, 2003]
    assert cell["config"]["evals"][0]["steps"] == 9000 and cell["config"]["trajectory_every_steps"] == 50
    keep = next(s for s in specs if s["key"] == "L4_T0.5_keep_s2003")
    assert keep["config"]["run"]["policy"] == "keep" and keep["config"]["trajectory_every_steps"] == 50
    assert sum(s["policy"] == "greedy" for s in specs) == 12 * 3 and sum(s["policy"] == "mobil" for s in specs) == 144


def test_a_stored_model_of_another_identity_is_another_folder() -> None:
    """The model store names a model by its whole training configuration (model_store.model_id): the check's 3-lane
    per-alpha models are the full profile's of those alphas (trained once), and a network whose alpha draw,
    selection alphas, demands, steps or preset differ is another folder, trained anew, never the stored one."""
    full, check = plan.PROFILES["full"], plan.PROFILES["check"]
    ident = model_id(as_data(plan.lane_train_config(3, 1, full)))
    assert ident == model_id(as_data(plan.lane_train_config(3, 1, check)))
    others = [replace(full, alpha_draw_max=48.0), replace(full, validation_alphas=(0.0, 8.0)),
              replace(full, loads=(0.5, 1.0)), replace(full, train_steps=80_000), replace(full, preset="alpha_only")]
    names = {model_id(as_data(plan.lane_train_config(3, 1, p))) for p in others}
    assert ident not in names and len(names) == len(others)
    per_alpha = model_id(as_data(plan.lane_train_config(3, 1, check, 1.0)))
    assert per_alpha.startswith("default_a1_seed1_") and ident.startswith("default_ac_seed1_")
    full_specs = {s["key"]: s for s in plan.cell_specs(full)}
    assert model_id(full_specs["L3_T0.67_a1_s1"]["config"]["train"]) == per_alpha


# -- bad input ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--t-up", "1,2,3,4,5,6,7,8,9,10,11"], "at most 10; got 11"),
        (["--policies", "dqn,keep,", "--profile", "full"], "--policies"),
        (["--policies", "keep", "--mobil-p", "0"], "--mobil-p"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(argv: list[str], words: str, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    try:
        code = s2.main([*argv, "--out", str(tmp_path / "out")])
    except SystemExit as stop:
        code = int(stop.code or 0)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "error" in err[0] and words in err[0], err
    assert not (tmp_path / "out").exists()


def test_help_names_every_profile_and_the_default() -> None:
    text = s2.build_parser().format_help()
    for name in plan.PROFILES:
        assert f"{name} (" in " ".join(text.split()), name
    assert s2.build_parser().get_default("profile") == "full"


# -- end to end on SUMO, at a tiny size ------------------------------------------------------------------------
TINY = ["--lanes", "2", "--t-up", "4,2", "--alphas", "0,8", "--seeds", "2", "--eval-seeds", "1", "--steps", "300",
        "--eval-steps", "1200", "--mobil-p", "0", "--bootstrap", "200", "--workers", "2", "--quiet"]  # fmt: skip
"""2 lanes at 2 demands, networks and per-alpha models of 300 steps (2 a condition, for the spread over models), one
evaluation seed, evaluations of 1,200 steps (the first vehicle leaves the 2 km road after about 90 s, so the full-road
speed is measured)"""


@pytest.mark.sumo
def test_the_check_profile_end_to_end(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    """The check profile at a tiny size: lane networks and per-alpha models trained into the model store, every
    cell evaluated with its full-road speed, keep, greedy and MOBIL on the same seeds, the gate, the check and the
    report; a rerun runs nothing (scenario2's main in this process: the study itself ran as a process)."""
    out = tmp_path / "check"
    cmd = [sys.executable, "-m", "coopsumo", "scenario2", "--profile", "check", *TINY, "--out", str(out)]
    res = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=900, check=False)
    assert res.returncode == 0, res.stderr[-3000:]
    runs = pd.read_csv(out / "runs.csv")
    assert (runs["status"] == "ok").all(), runs["error"].tolist()
    assert runs["policy"].value_counts().to_dict() == {"dqn": 8, plan.PER_ALPHA: 8, "mobil": 2, "keep": 2,
                                                       "greedy": 2}  # fmt: skip
    assert runs[FULL_ROAD].between(5, 35).all() and (runs["full_road_from_s"] > 60).all()
    assert (runs["collisions"] == 0).all()
    links = sorted(p.name for p in (out / "train").iterdir())
    assert links == ["L2_a0_s1", "L2_a0_s2", "L2_a8_s1", "L2_a8_s2", "L2_cond_s1", "L2_cond_s2"]
    assert all((out / "train" / k).is_symlink() and (out / "train" / k / "model.pt").is_file() for k in links)
    cond = json.loads((out / "train" / "L2_cond_s1" / "config.json").read_text())["config"]["dqn"]
    assert cond["alpha_conditioned"] and cond["train_t_ups"] == [4.0, 2.0]
    evals = pd.read_csv(out / "evals.csv")
    assert len(evals) == 8 + 8 + 6 and evals[FULL_ROAD].notna().all()
    assert (out / "evals" / "L2_T2_a8_s1" / "eval_a8_s2001" / "trajectories.parquet").is_file()
    assert (out / "baselines" / "L2_T4_greedy_s2001" / "trajectories.parquet").is_file()
    gate_csv = pd.read_csv(out / "gate.csv")
    assert len(gate_csv) == 2 and set(gate_csv["keep_mps"].round(6)) == set(
        runs[runs["policy"] == "keep"].groupby("t_up_s")[FULL_ROAD].mean().round(6))  # fmt: skip
    check = pd.read_csv(out / "check.csv")
    assert len(check) == 4 and set(check["alpha"]) == {0.0, 8.0}
    report = (out / "report.md").read_text()
    for text in ("## The gate: where the learner is fit to be asked", "## The paper's trends",
                 "## One network per lane count against per-alpha models", "core-hours", "| `full` | 90 | 576 |"):
        assert text in report, text
    assert "gate" in res.stdout and "scenario2: 22 ok, 0 failed" in res.stdout
    sweep = json.loads((out / "sweep.json").read_text())
    assert sweep["criterion"] == FULL_ROAD and sweep["trainings"] == 6 and "2_lanes" in sweep["learner"]
    code, _, err = main_here(s2.main, cmd[4:], capfd)
    assert code == 0 and "22 already done" in err and "0 to run" in err, err[-2000:]
    # a committed folder keeps no cells/: its tables and report are redrawn from runs.csv, evals.csv and sweep.json
    redrawn = tmp_path / "redrawn"
    redrawn.mkdir()
    for name in ("runs.csv", "evals.csv", "sweep.json"):
        (redrawn / name).write_bytes((out / name).read_bytes())
    rewrite_outputs(redrawn)
    for name in ("report.md", "gate.csv", "alpha_star.csv", "check.csv", "mobil_p_star.csv"):
        assert (redrawn / name).read_text() == (out / name).read_text(), name


PART = ["--t-up", "4", "--alphas", "0,8", "--seeds", "1", "--eval-seeds", "1", "--steps", "300", "--eval-steps",
        "1200", "--mobil-p", "0", "--bootstrap", "50", "--workers", "2", "--quiet"]  # fmt: skip
"""one part of the full profile at a tiny size: one condition, a model per alpha of 300 steps, one evaluation seed"""


def test_the_full_profile_in_parts_merged(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    """The full profile (one model per alpha, lane count and seed) run in parts, one lane count or some of its alphas
    at a time, then --merge: the merged tables are the parts' together (the classical runs two parts of one lane
    count both made, once), its report covers both lane counts and says it ran in parts, and the gate row of a lane
    count run in one part is the one that part drew alone. The first part runs as a process, the two others by
    scenario2's main in this process (capfd: their workers' output too); the merges, which run no simulation, in this
    process (the command's one-line refusals as a process: tests/test_bad_inputs.py)."""
    parts = {"L2": (2, "0,8"), "L3a": (3, "0"), "L3b": (3, "8")}
    folders = {name: tmp_path / name for name in parts}
    for name, (n, alphas) in parts.items():
        out = folders[name]
        cmd = [sys.executable, "-m", "coopsumo", "scenario2", "--lanes", str(n), *PART, "--alphas", alphas, "--out",
               str(out)]  # fmt: skip
        if name == "L2":
            res = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600, check=False)
            assert res.returncode == 0, res.stderr[-3000:]
        else:
            code, _, err = main_here(s2.main, cmd[4:], capfd)
            assert code == 0, err[-3000:]
        assert sorted(p.name for p in (out / "train").iterdir()) == [f"L{n}_a{a}_s1" for a in alphas.split(",")]
    cfg = json.loads((folders["L2"] / "train" / "L2_a8_s1" / "config.json").read_text())["config"]
    assert not cfg["dqn"]["alpha_conditioned"] and cfg["sim"]["reward"]["alpha"] == 8
    merged = tmp_path / "merged"
    argv = ["--merge", ",".join(map(str, folders.values())), "--out"]
    capfd.readouterr()
    code = s2.main([*argv, str(merged)])
    out, err = capfd.readouterr()
    assert code == 0, err[-3000:]
    assert "merged 3 parts (10 cells, lanes 2, 3)" in out
    runs = pd.read_csv(merged / "runs.csv")
    assert len(runs) == 10 and set(runs["lanes"]) == {2, 3} and (runs["status"] == "ok").all()
    alone = {name: pd.read_csv(out / "runs.csv") for name, out in folders.items()}
    assert len(alone["L3a"]) == len(alone["L3b"]) == 4  # one model and the classical runs, in both
    pd.testing.assert_frame_equal(runs, pd.concat([alone["L2"], alone["L3a"], alone["L3b"].iloc[[0]]],
                                                  ignore_index=True))  # fmt: skip
    classical = alone["L3b"][alone["L3b"]["policy"] != "dqn"].reset_index(drop=True)
    same = alone["L3a"][alone["L3a"]["policy"] != "dqn"].reset_index(drop=True)
    timing = [c for c in TIMING if c in classical]
    pd.testing.assert_frame_equal(classical.drop(columns=timing), same.drop(columns=timing))
    evals = pd.read_csv(merged / "evals.csv")
    assert len(evals) == sum(len(pd.read_csv(out / "evals.csv")) for out in folders.values()) - 3
    gate = pd.read_csv(merged / "gate.csv")
    pd.testing.assert_frame_equal(gate[gate["lanes"] == 2].reset_index(drop=True),
                                  pd.read_csv(folders["L2"] / "gate.csv"))  # fmt: skip
    sweep = json.loads((merged / "sweep.json").read_text())
    assert sweep["profile"]["lanes"] == [2, 3] and sweep["profile"]["alphas"] == [0, 8]
    assert [(p["lanes"], p["alphas"]) for p in sweep["parts"]] == [([2], [0, 8]), ([3], [0]), ([3], [8])]
    assert sweep["cells"] == 10 and sweep["trainings"] == 4 and len(sweep["conditions"]) == 2
    learners = [json.loads((folders[name] / "sweep.json").read_text())["learner"] for name in ("L2", "L3a")]
    assert list(sweep["learner"]) == ["2_lanes", "3_lanes"] and sweep["learner"] == {**learners[0], **learners[1]}
    report = (merged / "report.md").read_text()
    assert "It ran in 3 parts" in report and "3 lanes at alphas 8" in report
    assert "| 2 | 4 |" in report and "| 3 | 4 |" in report
    assert s2.main([*argv, str(tmp_path / "other")]) == 0
    assert (tmp_path / "other" / "report.md").read_text() == report
    changed = tmp_path / "L3b_changed"
    changed.mkdir()
    for name in ("sweep.json", "evals.csv"):
        (changed / name).write_bytes((folders["L3b"] / name).read_bytes())
    keep_row = alone["L3b"]["policy"] == "keep"
    alone["L3b"].assign(mean_speed_mps=alone["L3b"]["mean_speed_mps"].where(~keep_row, 1.0)).to_csv(
        changed / "runs.csv", index=False)
    copy = tmp_path / "L2_copy"
    copy.mkdir()
    for name in ("sweep.json", "runs.csv", "evals.csv"):
        (copy / name).write_bytes((folders["L2"] / name).read_bytes())
    relearned = tmp_path / "L3b_relearned"
    relearned.mkdir()
    for name in ("runs.csv", "evals.csv"):
        (relearned / name).write_bytes((folders["L3b"] / name).read_bytes())
    meta = json.loads((folders["L3b"] / "sweep.json").read_text())
    meta["learner"]["3_lanes"]["lr"] *= 2
    (relearned / "sweep.json").write_text(json.dumps(meta))
    for bad_argv, words in (([f"{folders['L3a']},{changed}"], "with different results"),
                            ([f"{folders['L3a']},{relearned}"], "trained 3 lanes with different learners"),
                            ([f"{folders['L2']},{folders['L3b']}"], "no part holds lanes 3 at alpha 0"),
                            ([f"{folders['L2']},{copy}"], "repeats lanes 2 at alpha 0"),
                            ([str(tmp_path / "none")], "not a finished"),
                            ([str(folders["L2"]), "--lanes", "2"], "--lanes cannot go with it")):  # fmt: skip
        capfd.readouterr()
        code = s2.main(["--merge", *bad_argv, "--out", str(tmp_path / "bad")])
        err = capfd.readouterr().err
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and words in lines[0], err
        assert not (tmp_path / "bad").exists()
