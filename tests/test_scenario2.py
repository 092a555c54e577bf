"""Scenario II alpha sweep: alpha* selection, win shares, bootstrap and plane on hand-made tables, and the report
drawn and redrawn from them; the command's bad input; the tiny sweep end to end on both backends; a sweep killed and
resumed."""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from conftest import InlineBackend, main_here

from coopsumo.config import PAPER_ALPHAS
from coopsumo.errors import UsageError
from coopsumo.run_dirs import RUN_MARKER, mark_run_dir
from coopsumo.studies.engine import cells as engine_cells
from coopsumo.studies.engine import groups as engine_groups
from coopsumo.studies.engine import records, runner, trainings
from coopsumo.studies.scenario2 import gate_report
from coopsumo.studies.scenario2 import measures as stats
from coopsumo.studies.scenario2 import plan as s2_plan
from coopsumo.studies.scenario2 import study as s2
from coopsumo.studies.scenario2.redraw import rewrite_outputs
from coopsumo.studies.scenario2.text import ALPHA_STAR_FIGURE

REPO = Path(__file__).resolve().parent.parent
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
OUTPUTS = ("sweep.json", "runs.csv", "evals.csv", "alpha_star.csv", "gate.csv", ALPHA_STAR_FIGURE,
           "fig6_speed_heatmap.png", "report.md")
COMPARED = [*stats.KEY_COLUMNS, "status", *stats.METRIC_COLUMNS]


# -- hand-made tables ---------------------------------------------------------------------------------
def runs_from(speeds: dict[tuple[int, float], dict[float, list[float]]]) -> pd.DataFrame:
    """A runs table: {(lanes, t_up): {alpha: [speed of seed 1, seed 2, ...]}}; NaN marks a failed cell."""
    rows = []
    for (lanes, t_up), by_alpha in speeds.items():
        for alpha, values in by_alpha.items():
            for seed, v in enumerate(values, start=1):
                failed = not np.isfinite(v)
                rows.append({"key": s2_plan.cell_key(lanes, t_up, alpha, seed), "lanes": lanes, "t_up_s": t_up,
                             "load": s2_plan.load_of(lanes, t_up), "alpha": alpha, "seed": seed,
                             "status": "failed" if failed else "ok", "error": "boom" if failed else None,
                             "mean_speed_mps": v, "collisions": 0, "teleports": 0})  # fmt: skip
    return pd.DataFrame(rows)


def evals_of(runs: pd.DataFrame, eval_seeds: tuple[int, ...] = (2001,)) -> tuple[pd.DataFrame, pd.DataFrame]:
    """A hand-made runs table as a sweep writes it, with what the report reads beside the speed (policy, p, lane
    changes, timings), and its evals.csv: each successful model's evaluation on each of eval_seeds at its speed, each
    successful MOBIL, keep or greedy cell's one run (its seed the evaluation seed)."""
    runs = runs.assign(policy=runs["policy"] if "policy" in runs else "dqn", p=runs["p"] if "p" in runs else np.nan,
                       lane_changes_per_vehicle=0.5, cell_cpu_s=60.0, wall_seconds=6.0,
                       resumed_from_step=pd.array([pd.NA] * len(runs), dtype="Int64"))  # fmt: skip
    ok = runs[runs["status"] == "ok"]
    columns = ["key", "lanes", "t_up_s", "load", "policy", "alpha", "p", "seed", "mean_speed_mps",
               "lane_changes_per_vehicle", "collisions", "teleports", "wall_seconds"]  # fmt: skip
    dqn, classical = ok[ok["policy"] == "dqn"], ok[ok["policy"] != "dqn"]
    evals = [dqn[columns].assign(eval_seed=seed) for seed in eval_seeds]
    evals.append(classical[columns].assign(eval_seed=classical["seed"], seed=np.nan))
    return runs, pd.concat(evals, ignore_index=True)


def sweep_meta(profile: s2_plan.Profile, runs: pd.DataFrame, n_boot: int) -> dict[str, Any]:
    """What a sweep's sweep.json holds when its report is drawn."""
    failed = runs.loc[runs["status"] != "ok", "key"].tolist()
    return {"profile": asdict(profile), "conditions": s2_plan.condition_rows(profile), "cells": len(runs),
            "cells_ok": len(runs) - len(failed), "cells_failed": len(failed), "failed_cells": failed,
            "trainings": profile.n_trainings(), "backend": "local", "workers": 1, "wall_seconds": 1.0, "cells_run": 0,
            "cell_wall_seconds_sum": 0.0, "cell_cpu_seconds_sum": 0.0, "bootstrap_replicates": n_boot,
            "versions": {}}  # fmt: skip


def mobil_runs_from(speeds: dict[tuple[int, float], dict[float, list[float]]]) -> pd.DataFrame:
    """Like runs_from, for MOBIL cells: {(lanes, t_up): {p: [speed of seed 1, ...]}}."""
    rows = []
    for (lanes, t_up), by_p in speeds.items():
        for p, values in by_p.items():
            for seed, v in enumerate(values, start=1):
                failed = not np.isfinite(v)
                rows.append({"key": s2_plan.mobil_key(lanes, t_up, p, seed), "lanes": lanes, "t_up_s": t_up,
                             "load": s2_plan.load_of(lanes, t_up), "alpha": np.nan, "seed": seed, "policy": "mobil",
                             "p": p, "status": "failed" if failed else "ok", "error": "boom" if failed else None,
                             "mean_speed_mps": v, "collisions": 0, "teleports": 0})  # fmt: skip
    return pd.DataFrame(rows)


def test_win_shares_split_ties_and_skip_empty_seeds() -> None:
    speeds = np.array([
        [10.0, 12.0, 11.0, np.nan],
        [11.0, 12.0, 10.0, np.nan],
        [9.0, 1.0, 11.0, np.nan],
    ])  # fmt: skip
    # seed 1: alpha 1 wins; seed 2: alphas 0 and 1 tie; seed 3: alphas 0 and 2 tie; seed 4: no data
    np.testing.assert_allclose(stats.win_shares(speeds), [1 / 3, 1 / 2, 1 / 6])


def test_alpha_star_known_answer() -> None:
    runs = runs_from({
        (3, 1.0): {0.0: [20.0, 21.0, 22.0], 2.0: [23.0, 20.0, 24.0], 8.0: [19.0, 19.5, 20.0]},
        (3, 2.0): {0.0: [25.0, 25.0, 25.0], 2.0: [24.0, 24.0, 24.0], 8.0: [23.0, 23.0, 23.0]},
    })  # fmt: skip
    table, boots = stats.alpha_star_table(runs, n_boot=500)
    a = table.set_index("t_up_s")
    # T_up 1 s: means 21, 22.33, 19.5 -> alpha* = 2, winning seeds 1 and 3 of 3
    assert a.loc[1.0, "alpha_star"] == 2.0
    assert a.loc[1.0, "alpha_star_speed_mps"] == pytest.approx(67 / 3)
    assert a.loc[1.0, "win_share"] == pytest.approx(2 / 3)
    assert a.loc[1.0, "win_share_alpha0"] == pytest.approx(1 / 3)
    assert a.loc[1.0, "speed_mps_alpha8"] == pytest.approx(19.5)
    assert a.loc[1.0, "spread_mps"] == pytest.approx(67 / 3 - 19.5)
    assert 0.3 < a.loc[1.0, "boot_support"] < 1.0  # alpha 0 wins resamples made mostly of seed 2
    # T_up 2 s: alpha 0 best on every seed: certain
    assert a.loc[2.0, "alpha_star"] == 0.0
    assert a.loc[2.0, "win_share"] == 1.0 and a.loc[2.0, "boot_support"] == 1.0
    assert a.loc[2.0, "boot_alpha_p05"] == a.loc[2.0, "boot_alpha_p95"] == 0.0
    assert set(boots) == {(3, 1.0), (3, 2.0)} and boots[(3, 2.0)].shape == (500,)
    # reproducible: the bootstrap has its own fixed seed
    again, _ = stats.alpha_star_table(runs, n_boot=500)
    pd.testing.assert_frame_equal(table, again)


def test_alpha_star_ties_go_to_the_smaller_alpha() -> None:
    table, _ = stats.alpha_star_table(runs_from({(2, 1.0): {4.0: [20.0, 21.0], 0.5: [20.0, 21.0]}}), n_boot=50)
    assert table.loc[0, "alpha_star"] == 0.5
    assert table.loc[0, "win_share"] == 0.5 and table.loc[0, "boot_support"] == 1.0


def test_failed_cells_are_left_out() -> None:
    runs = runs_from({(2, 1.0): {0.0: [20.0, np.nan], 8.0: [np.nan, np.nan], 32.0: [19.0, 18.0]}})
    table, _ = stats.alpha_star_table(runs, n_boot=100)
    row = table.iloc[0]
    assert row["alpha_star"] == 0.0 and row["alpha_star_speed_mps"] == 20.0
    assert np.isnan(row["speed_mps_alpha8"])
    assert row["cells_failed"] == 3 and row["seeds_min"] == 0
    assert row["win_share"] == 0.5  # seed 1: alpha 0 wins; seed 2: only alpha 32 ran


def test_the_gate_target_is_five_in_six_of_the_conditions() -> None:
    from coopsumo.studies.scenario2.gate_report import gate_target

    assert [gate_target(n) for n in (2, 4, 12, 20)] == [2, 4, 10, 17]


def test_fit_plane_recovers_known_coefficients() -> None:
    t = np.array([0.5, 1.0, 2.0, 0.5, 1.0, 2.0, 0.7])
    n = np.array([2, 2, 2, 4, 4, 4, 6])
    fit = stats.fit_plane(t, n, 30.0 - 6.0 * t - 2.5 * n)
    assert (fit.b0, fit.b1, fit.b2) == pytest.approx((30.0, -6.0, -2.5))
    assert fit.r2 == pytest.approx(1.0) and fit.n == 7
    noisy = stats.fit_plane(t, n, 30.0 - 6.0 * t - 2.5 * n + np.array([1, -1, 0.5, -0.5, 1, -1, 0]))
    assert 0.5 < noisy.r2 < 1.0


def test_fit_plane_refuses_what_it_cannot_fit() -> None:
    with pytest.raises(stats.PlaneFitError, match="at least 3 distinct conditions"):
        stats.fit_plane([1.0, 2.0], [2, 2], [8.0, 4.0])
    with pytest.raises(stats.PlaneFitError, match="at least 3 distinct conditions"):
        stats.fit_plane([1.0, 1.0, 1.0, 2.0], [2, 2, 2, 3], [8.0, 4.0, 2.0, np.nan])  # NaN left out
    with pytest.raises(stats.PlaneFitError, match="only T_up varies"):
        stats.fit_plane([0.5, 1.0, 2.0], [3, 3, 3], [8.0, 4.0, 2.0])
    flat = stats.fit_plane([0.5, 1.0, 2.0], [2, 3, 4], [8.0, 8.0, 8.0])
    assert flat.b1 == pytest.approx(0.0, abs=1e-9) and np.isnan(flat.r2)


def test_plane_bootstrap_and_trend_statements() -> None:
    # alpha* falls with T_up and with lanes in every condition, on every seed: the trends hold for sure
    speeds = {}
    for lanes in (2, 3, 4):
        for t_up in (0.5, 1.0, 2.0):
            best = 32.0 if lanes == 2 and t_up == 0.5 else 8.0 if lanes + t_up < 5 else 0.0
            speeds[(lanes, t_up)] = {a: [20.0 + (a == best)] * 3 for a in (0.0, 8.0, 32.0)}
    table, boots = stats.alpha_star_table(runs_from(speeds), n_boot=200)
    fit = stats.fit_plane(table["t_up_s"], table["lanes"], table["alpha_star"])
    assert fit.b1 < 0 and fit.b2 < 0
    boot = stats.plane_bootstrap(table, boots)
    assert boot["b1_negative_share"] == 1.0 and boot["b2_negative_share"] == 1.0
    assert boot["b1_p05"] == pytest.approx(fit.b1) and boot["replicates"] == 200
    text = trend_lines({**asdict(fit), "bootstrap": boot})
    assert len(text) == 2 and all(s.startswith("- **Holds**") for s in text)
    opposite = trend_lines({**asdict(stats.PlaneFit(1.0, 2.0, 0.5, 0.3, 9)), "bootstrap": {}})
    assert all(s.startswith("- **Does not hold**") and "b" in s for s in opposite)
    # with models behind the fit, a verdict only when the 90% interval excludes 0
    wide = {"replicates": 1000, "b1_negative_share": 0.8, "b1_p05": -1.7, "b1_p95": 0.5,
            "b2_negative_share": 0.0, "b2_p05": 0.1, "b2_p95": 0.9}  # fmt: skip
    undecided, reversed_ = trend_lines({**asdict(stats.PlaneFit(1.0, -0.6, 0.5, 0.3, 9)), "bootstrap": wide,
                                        "b1_models_to_decide": 12})  # fmt: skip
    assert undecided.startswith("- **Cannot decide**") and "about 12 models per condition would decide" in undecided
    assert reversed_.startswith("- **Reversed**")


def trend_lines(trends: dict[str, Any]) -> list[str]:
    """The report's lines on the paper's two trends (gate_report.trend_text), one per trend."""
    return [line for line in gate_report.trend_text(trends, 9, 9, 3).splitlines() if line.startswith("- ")]


def test_outputs_from_a_hand_made_table(tmp_path: Path) -> None:
    """write_lane_outputs (no SUMO): alpha_star.csv, both figures and a report with the plane and failed cells; the
    same redrawn from runs.csv, evals.csv and sweep.json alone."""
    speeds = {(lanes, t): {a: [18.0 + a / (lanes * t) - a * a / 400, 19.0 - a / 100] for a in (0.0, 2.0, 8.0, 32.0)}
              for lanes in (2, 3) for t in (0.7, 1.4)}  # fmt: skip
    speeds[(2, 0.7)][8.0] = [np.nan, 18.0]
    runs, evals = evals_of(runs_from(speeds))
    profile = s2_plan.Profile("hand", lanes=(2, 3), loads=(), alphas=(0.0, 2.0, 8.0, 32.0), seeds=(1, 2),
                              train_steps=10, eval_steps=10, t_up_s=(0.7, 1.4), alpha_models=True)  # fmt: skip
    meta = sweep_meta(profile, runs, 100)
    gate_report.write_lane_outputs(tmp_path, runs, evals, profile, meta, n_boot=100)
    for name in ("alpha_star.csv", "gate.csv", ALPHA_STAR_FIGURE, "fig6_speed_heatmap.png", "report.md"):
        assert (tmp_path / name).is_file(), name
    assert (tmp_path / ALPHA_STAR_FIGURE).read_bytes()[:8] == PNG_SIGNATURE
    table = pd.read_csv(tmp_path / "alpha_star.csv")
    assert len(table) == 4 and {"alpha_star", "win_share", "boot_support", "speed_mps_alpha32"} <= set(table)
    report = (tmp_path / "report.md").read_text()
    # the condition with a failed cell gets no alpha* (it would rest on one seed of alpha 8): 3 conditions remain
    assert np.isnan(table.set_index(["lanes", "t_up_s"]).loc[(2, 0.7), "alpha_star"])
    assert "| 2 | 0.7 | – |" in report and "| 3 | 0.7 | 32 |" in report
    assert "**alpha\\* = 32.000 +0.000 T_up +0.000 lanes**, R² = –" in report  # alpha* 32 in the 3 others
    assert "| L2_T0.7_a8_s1 | boom |" in report
    assert meta["plane"]["n"] == 3
    assert f"]({ALPHA_STAR_FIGURE})" in report and not (tmp_path / "fig6_alpha_star.png").exists()
    # the same outputs redrawn from runs.csv, evals.csv and sweep.json alone (a committed folder keeps no cells/)
    redrawn = tmp_path / "redrawn"
    redrawn.mkdir()
    runs.to_csv(redrawn / "runs.csv", index=False)
    evals.to_csv(redrawn / "evals.csv", index=False)
    (redrawn / "sweep.json").write_text(json.dumps(sweep_meta(profile, runs, 100)))
    rewrite_outputs(redrawn)
    for name in ("alpha_star.csv", "gate.csv", "report.md"):
        assert (redrawn / name).read_text() == (tmp_path / name).read_text(), name
    assert (redrawn / ALPHA_STAR_FIGURE).read_bytes()[:8] == PNG_SIGNATURE


@pytest.mark.parametrize("recorded", [{"lane_networks": False}, {"criterion": None}])
def test_a_sweep_of_the_retired_per_alpha_design_is_not_redrawn(recorded: dict[str, Any], tmp_path: Path) -> None:
    """A sweep.json of the per-alpha design (lane_networks = false, or from before the lane networks: neither it nor
    a criterion, as results/archive's) is refused with the commit that redraws it, nothing written; one that records
    lane_networks = true (the lane-network sweeps made before it was dropped) is today's design."""
    archived = REPO / "results" / "archive" / "scenario2_quick"
    meta = json.loads((archived / "sweep.json").read_text())
    assert "lane_networks" not in meta["profile"] and "criterion" not in meta["profile"]
    speeds = {(2, t): {a: [20.0 + a / 8, 21.0] for a in (0.0, 8.0)} for t in (2.0, 4.0)}
    runs, evals = evals_of(runs_from(speeds))
    profile = s2_plan.Profile("mine", lanes=(2,), loads=(), alphas=(0.0, 8.0), seeds=(1, 2), train_steps=10,
                              eval_steps=10, t_up_s=(2.0, 4.0), alpha_models=True)  # fmt: skip
    meta = sweep_meta(profile, runs, 10)
    runs.to_csv(tmp_path / "runs.csv", index=False)
    evals.to_csv(tmp_path / "evals.csv", index=False)
    for name, profile_record in (("today", meta["profile"]), ("before", {**meta["profile"], "lane_networks": True})):
        (tmp_path / "sweep.json").write_text(json.dumps({**meta, "profile": profile_record}))
        rewrite_outputs(tmp_path)
        assert (tmp_path / "report.md").is_file(), name
        (tmp_path / "report.md").unlink()
    retired = {k: v for k, v in {**meta["profile"], **recorded}.items() if v is not None}
    (tmp_path / "sweep.json").write_text(json.dumps({**meta, "profile": retired}))
    with pytest.raises(UsageError, match=f"per-alpha design, retired on 2026-12-03: redraw it at commit "
                                         f"{s2_plan.RETIRED_PER_ALPHA}"):  # fmt: skip
        rewrite_outputs(tmp_path)
    assert not (tmp_path / "report.md").exists()


def test_alpha_star_chart_has_one_panel_per_lane_count(tmp_path: Path) -> None:
    """The alpha* figure: one panel per lane count on a shared y axis ticked at the alphas tried (0 shown, a
    symmetric log scale), alpha* against inflow, its bootstrap range and discs, a withheld alpha* said so."""
    from coopsumo.report.plots_sweep import alpha_star_lanes_chart, alpha_star_lanes_figure

    alphas = (0.0, 0.125, 1.0, 8.0)
    rows = [(2, 2.0, 0.0), (2, 1.0, 1.0), (3, 1.33, 0.125), (3, 0.67, np.nan), (4, 1.0, 8.0), (4, 0.5, 1.0)]
    table = pd.DataFrame([{"lanes": n, "t_up_s": t, "inflow_veh_h": round(3600 / t, 1), "alpha_star": a,
                           "boot_alpha_p05": 0.0, "boot_alpha_p95": 8.0} for n, t, a in rows])  # fmt: skip
    boots = {(n, t): np.array([a, a, 0.0, 8.0]) for n, t, a in rows}
    fig = alpha_star_lanes_chart(table, alphas, plane=(0.5, -0.1, -0.05), boot_alphas=boots)
    assert [ax.get_title() for ax in fig.axes] == ["2 lanes", "3 lanes", "4 lanes"]
    first = fig.axes[0]
    assert all(first.get_shared_y_axes().joined(first, ax) for ax in fig.axes)
    assert first.get_yscale() == "symlog" and list(first.get_yticks()) == list(alphas)
    assert first.get_ylim()[0] < 0 < first.get_ylim()[1] and first.get_ylim()[1] > 8
    for ax, n in zip(fig.axes, (2, 3, 4), strict=True):
        shown = table[(table["lanes"] == n) & table["alpha_star"].notna()].sort_values("inflow_veh_h")
        star = next(line for line in ax.get_lines() if line.get_marker() == "D")
        assert list(star.get_xdata()) == list(shown["inflow_veh_h"])
        assert list(star.get_ydata()) == list(shown["alpha_star"])
        assert "inflow (veh/h)" in ax.get_xlabel()
    assert [t.get_text() for t in fig.axes[1].texts] == ["no α*"]
    path = alpha_star_lanes_figure(table, alphas, tmp_path / "chart.png")  # no plane, no bootstrap discs
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    with pytest.raises(ValueError, match="at least one condition"):
        alpha_star_lanes_chart(table.iloc[:0], alphas)


def test_mobil_p_star_beside_alpha_star(tmp_path: Path) -> None:
    """p* (best mean over seeds, ties to the smaller p) and the report's alpha* beside p* (no SUMO)."""
    mobil = mobil_runs_from({
        (2, 1.0): {0.0: [20.0, 22.0], 0.5: [23.0, 21.0], 1.0: [19.0, 21.0]},
        (2, 2.0): {0.0: [19.0, 20.0], 0.25: [20.0, 21.0], 1.0: [21.0, 20.0], 2.0: [np.nan, 30.0]},
    })  # fmt: skip
    table = stats.mobil_p_star_table(mobil, ps=(0.0, 0.25, 0.5, 1.0, 2.0), seeds=(1, 2)).set_index("t_up_s")
    # T_up 1 s: means 21, 22, 20 -> p* = 0.5, best on seed 1 only
    assert table.loc[1.0, "p_star"] == 0.5 and table.loc[1.0, "p_star_speed_mps"] == 22.0
    assert table.loc[1.0, "win_share"] == 0.5 and np.isnan(table.loc[1.0, "speed_mps_p0.25"])
    # T_up 2 s: p 0.25 and 1 tie at 20.5 -> the smaller p; p 2 ran on one seed only (30) and wins
    assert table.loc[2.0, "p_star"] == 2.0 and table.loc[2.0, "cells_failed"] == 1
    no_two = stats.mobil_p_star_table(mobil[mobil["p"] != 2.0]).set_index("t_up_s")
    assert no_two.loc[2.0, "p_star"] == 0.25 and no_two.loc[2.0, "speed_mps_p1"] == 20.5
    assert no_two.loc[2.0, "win_share"] == pytest.approx(0.5)  # seed 1: p 1 wins; seed 2: p 0.25 wins
    # through write_lane_outputs: mobil_p_star.csv, and the gate's alpha* beside p*: alpha* faster at T_up 1 s
    # (23 > 22), slower at T_up 2 s (19 < 20.5)
    dqn = runs_from({(2, 1.0): {0.0: [22.0, 24.0], 8.0: [20.0, 20.0]},
                     (2, 2.0): {0.0: [19.0, 19.0], 8.0: [18.0, 18.0]}})  # fmt: skip
    dqn["policy"], dqn["p"] = "dqn", np.nan
    profile = s2_plan.Profile("hand", lanes=(2,), loads=(), alphas=(0.0, 8.0), seeds=(1, 2), train_steps=10,
                              eval_steps=10, t_up_s=(1.0, 2.0), policies=("dqn", "mobil"), mobil_ps=(0.0, 0.5, 1.0),
                              eval_seeds=(2001, 2002), alpha_models=True)  # fmt: skip
    assert profile.n_cells() == 2 * (2 * 2 + 3 * 2)  # conditions x (alphas x training seeds + ps x eval seeds)
    mobil = mobil[mobil["p"].isin([0.0, 0.5, 1.0])].assign(seed=lambda m: m["seed"] + 2000)
    runs, evals = evals_of(pd.concat([dqn, mobil], ignore_index=True), profile.eval_seeds)
    gate_report.write_lane_outputs(tmp_path, runs, evals, profile, sweep_meta(profile, runs, 10), n_boot=10)
    written = pd.read_csv(tmp_path / "mobil_p_star.csv")
    assert written["p_star"].tolist() == [0.5, 1.0] and "speed_mps_p0.25" not in written
    assert pd.read_csv(tmp_path / "alpha_star.csv")["alpha_star"].tolist() == [0.0, 0.0]
    gate = pd.read_csv(tmp_path / "gate.csv")
    assert gate[["alpha_star", "p_star"]].values.tolist() == [[0.0, 0.5], [0.0, 1.0]]
    assert gate["alpha_star_minus_p_star_mps"].tolist() == pytest.approx([1.0, -1.5])
    report = (tmp_path / "report.md").read_text()
    assert "| α* | p* | v(α*) − v(p*) [90%] |" in report and "MOBIL at p = 0, 0.5, 1 run once" in report


def test_grid_and_profiles() -> None:
    for lanes in range(2, 7):
        assert s2_plan.t_up_for(lanes, 1.0) == round(2.0 / lanes, 2)  # near capacity: lanes x 1,800 veh/h
    full = s2_plan.PROFILES["full"]
    assert full.n_cells() == 3 * 4 * (6 * 5 + (4 + 2) * 3)  # conditions x (alphas x seeds + classical x eval seeds)
    assert {0.25, 1.0, 32.0} <= set(full.alphas) and full.preset == "default"
    assert [t for n, t, _ in full.conditions() if n == 3] == [2.67, 1.33, 0.89, 0.67]
    paper = s2_plan.PROFILES["paper"]
    assert paper.alphas == PAPER_ALPHAS and len(paper.seeds) == 10 and paper.train_steps == 90_000
    assert paper.lanes == (2, 3, 4, 5, 6) and len(paper.conditions()) >= 20
    # the tests' profile: one model per alpha and seed on both demands of its 2 lanes, 300 steps, DQN alone
    tiny = s2_plan.PROFILES["tiny"]
    assert len(tiny.conditions()) == 2 and len(tiny.alphas) == 2 and len(tiny.seeds) == 2
    assert tiny.alpha_models and tiny.n_trainings() == 4 and tiny.n_cells() == 8 and tiny.policies == ("dqn",)
    assert (tiny.train_steps, tiny.eval_steps, tiny.criterion) == (300, 300, s2_plan.CRITERION)
    assert "quick" not in s2_plan.PROFILES  # the per-alpha sweep, retired (s2_plan.RETIRED_PER_ALPHA)
    for profile in (full, tiny):
        keys = [c["key"] for c in s2_plan.cell_specs(profile)]
        assert len(set(keys)) == len(keys)
    fixed = s2_plan.Profile("f", lanes=(2, 4), loads=(), alphas=(0.0,), seeds=(1,), train_steps=1, eval_steps=1,
                       t_up_s=(1.0, 2.0))  # fmt: skip
    assert fixed.conditions() == [(2, 2.0, 0.5), (2, 1.0, 1.0), (4, 2.0, 0.25), (4, 1.0, 0.5)]
    assert s2.parse_number("1/8") == 0.125


# -- bad input ------------------------------------------------------------------------------------------
def run_main(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str]]:
    try:
        code = s2.main(argv)
    except SystemExit as stop:
        code = int(stop.code or 0)
    err = capsys.readouterr().err.strip().splitlines()
    return code, err


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--profile", "huge"], "huge"),
        (["--backend", "dask"], "dask"),
        (["--workers", "0"], "workers"),
        (["--alphas", "0,x"], "alphas"),
        (["--alphas", "-1"], "alphas"),
        (["--lanes", "7"], "lanes"),
        (["--t-up", "0"], "t-up"),
        (["--seeds", "0"], "seeds"),
        (["--steps", "-5"], "steps"),
        (["--address", "auto"], "--address"),
        (["--policies", "dqn,ppo"], "policies"),
        (["--policies", "mobil", "--mobil-p", "0,-1"], "mobil-p"),
        (["--policies", "dqn", "--mobil-p", "0.5"], "--mobil-p"),
    ],
)
def test_bad_input_one_line_exit_2(argv: list[str], words: str, tmp_path: Path,
                                   capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    code, err = run_main([*argv, "--out", str(tmp_path / "out")], capsys)
    assert code == 2
    assert len(err) == 1 and "error" in err[0] and words in err[0]
    assert not (tmp_path / "out").exists()


def test_ray_backend_without_ray(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                 capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    code, err = run_main(["--profile", "tiny", "--backend", "ray", "--out", str(tmp_path / "out")], capsys)
    assert code == 2 and len(err) == 1 and "needs Ray" in err[0]
    assert not (tmp_path / "out").exists()


# -- real sweeps ------------------------------------------------------------------------------------------
def sweep_cmd(out: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "coopsumo", "scenario2", "--profile", "tiny", "--out", str(out), "--quiet", *extra]


def run_sweep_cli(out: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    result = subprocess.run(sweep_cmd(out, *extra), capture_output=True, text=True, cwd=REPO, timeout=600,
                            check=False)  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    return result


def sweep_here(out: Path, capfd: pytest.CaptureFixture[str], *extra: str) -> tuple[str, str]:
    """run_sweep_cli's sweep by scenario2's main in this process, for a rerun or a sweep on top of the module's
    local_sweep, which ran as a process: its stdout and stderr (its workers' too)."""
    code, out_text, err = main_here(s2.main, sweep_cmd(out, *extra)[4:], capfd)
    assert code == 0, err[-2000:]
    return out_text, err


def assert_outputs(out: Path) -> pd.DataFrame:
    for name in OUTPUTS:
        assert (out / name).is_file(), name
    for name in (ALPHA_STAR_FIGURE, "fig6_speed_heatmap.png"):
        assert (out / name).read_bytes()[:8] == PNG_SIGNATURE
    runs = pd.read_csv(out / "runs.csv")
    assert len(runs) == s2_plan.PROFILES["tiny"].n_cells() == 8
    assert (runs["status"] == "ok").all(), runs["error"].tolist()
    assert set(stats.METRIC_COLUMNS) <= set(runs.columns) and "throughput_veh_per_h" in runs
    assert runs["mean_speed_mps"].between(1, 35).all() and (runs["collisions"] == 0).all()
    assert len(list((out / "cells").glob("*.json"))) == 8
    # one model per alpha and training seed, trained on both demands of the 2 lanes, drives both conditions
    assert sorted(p.name for p in (out / "train").iterdir()) == ["L2_a0_s1", "L2_a0_s2", "L2_a8_s1", "L2_a8_s2"]
    assert all((out / "train" / k / "model.pt").is_file() for k in ("L2_a0_s1", "L2_a0_s2", "L2_a8_s1", "L2_a8_s2"))
    assert runs.set_index("key").loc["L2_T4_a8_s2", "train_dir"] == "train/L2_a8_s2"
    trained = json.loads((out / "train" / "L2_a8_s2" / "config.json").read_text())["config"]
    assert trained["dqn"]["train_t_ups"] == [4.0, 2.0] and not trained["dqn"]["alpha_conditioned"]
    assert trained["sim"]["reward"]["alpha"] == 8 and trained["sim"]["steps"] == 300
    # every model was driven on the evaluation seed, a demand its training (seed 1 or 2) never saw
    evals = pd.read_csv(out / "evals.csv")
    assert len(evals) == 8 and (evals["eval_seed"] == 2001).all() and set(evals["seed"]) == {1, 2}
    assert all(json.loads((out / "evals" / k / "eval_s2001" / "summary.json").read_text())["steps"] == 300
               for k in runs["key"])  # fmt: skip
    pd.testing.assert_series_equal(evals["mean_speed_mps"], runs["mean_speed_mps"], check_names=False)
    table = pd.read_csv(out / "alpha_star.csv")
    assert len(table) == 2 and table["alpha_star"].isin([0.0, 8.0]).all()
    report = (out / "report.md").read_text()
    assert "No plane fitted" in report and "Failed cells\n\nNone." in report and "**tiny**" in report
    assert "The gate could not be judged (no alpha-0 model or no `keep` run)" in report  # tiny runs no keep
    return runs


@pytest.fixture(scope="module")
def local_sweep(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("s2") / "local"
    run_sweep_cli(out, "--workers", "2")
    return out


@pytest.mark.sumo
def test_tiny_sweep_local(local_sweep: Path, capfd: pytest.CaptureFixture[str]) -> None:
    runs = assert_outputs(local_sweep)
    assert runs["train_updates"].gt(0).all()
    # a rerun finds every cell done and recomputes nothing
    before = {p.name: p.stat().st_mtime_ns for p in (local_sweep / "cells").iterdir()}
    _, err = sweep_here(local_sweep, capfd, "--workers", "2")
    assert "8 already done" in err and "0 to run" in err
    assert before == {p.name: p.stat().st_mtime_ns for p in (local_sweep / "cells").iterdir()}


@pytest.mark.sumo
def test_tiny_sweep_with_the_baselines(local_sweep: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    """--policies dqn,mobil,keep,greedy on the finished DQN cells: only the 8 runs that need no training run (2
    conditions x (2 p + keep + greedy) x 1 evaluation seed); the gate judged, p* beside alpha* in the report."""
    out = tmp_path / "baselines"
    shutil.copytree(local_sweep / "cells", out / "cells")  # the sweep's cells in a folder its study marked
    mark_run_dir(out, "scenario2", finished=False, study=json.loads((local_sweep / RUN_MARKER).read_text())["study"])
    stdout, err = sweep_here(out, capfd, "--workers", "2", "--policies", "dqn,mobil,keep,greedy")
    assert "16 cells, 8 already done" in err and "8 to run" in err
    runs = pd.read_csv(out / "runs.csv")
    assert (runs["status"] == "ok").all(), runs["error"].tolist()
    assert runs["policy"].value_counts().to_dict() == {"dqn": 8, "mobil": 4, "keep": 2, "greedy": 2}
    dqn, mobil = runs[runs["policy"] == "dqn"], runs[runs["policy"] == "mobil"]
    assert dqn["p"].isna().all() and mobil["alpha"].isna().all() and set(mobil["p"]) == {0.0, 1.0}
    assert mobil["mean_speed_mps"].between(1, 35).all() and (mobil["collisions"] == 0).all()
    local = pd.read_csv(local_sweep / "runs.csv")
    pd.testing.assert_frame_equal(dqn[COMPARED].reset_index(drop=True), local[COMPARED], check_dtype=False)
    assert (out / "alpha_star.csv").read_text() == (local_sweep / "alpha_star.csv").read_text()
    # a MOBIL cell runs a DQN model's evaluation world: same condition, evaluation seed and steps
    cell = json.loads((out / "cells" / "L2_T4_mobil_p1_s2001.json").read_text())
    dqn_eval = json.loads((out / "cells" / "L2_T4_a0_s2.json").read_text())["config"]["evals"][0]
    for k in ("road", "demand", "control", "accident", "seed", "steps", "time_to_teleport_s"):
        assert cell["config"][k] == dqn_eval[k], k
    assert cell["config"]["seed"] == 2001 and cell["config"]["policy"] == "mobil:p=1.0"
    assert (out / "mobil" / "L2_T4_mobil_p1_s2001" / "summary.json").is_file()
    assert (out / "baselines" / "L2_T4_keep_s2001" / "summary.json").is_file()
    table = pd.read_csv(out / "mobil_p_star.csv")
    assert len(table) == 2 and table["p_star"].isin([0.0, 1.0]).all()
    assert {"win_share", "speed_mps_p0", "speed_mps_p1"} <= set(table)
    gate = pd.read_csv(out / "gate.csv")
    assert gate["passes"].notna().all() and gate["p_star"].isin([0.0, 1.0]).all()
    assert np.isfinite(gate["alpha_star_minus_p_star_mps"]).all() and np.isfinite(gate["keep_mps"]).all()
    report = (out / "report.md").read_text()
    assert "| α* | p* | v(α*) − v(p*) [90%] |" in report and "**The alpha-0 models beat `keep` in" in report
    assert "MOBIL p* =" in stdout and ("gate passes" in stdout or "gate fails" in stdout)


@pytest.mark.sumo
def test_parts_of_a_profile_without_trajectories_merge(local_sweep: Path, tmp_path: Path,
                                                      capfd: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Issue 82, probe 8: two parts of the tiny profile (no trajectories: a sweep writes no full-road columns) were
    refused by the merge, "t0's runs.csv has no full_road_speed_mps column ...: not as a sweep writes it". The
    parts reuse the tiny sweep's cells; their merge is the sweep. The parts and the merge run in this process (a
    merge as a process: tests/test_early_interrupts.py)."""
    study = json.loads((local_sweep / RUN_MARKER).read_text())["study"]
    parts = []
    for alpha in ("0", "8"):
        out = tmp_path / f"a{alpha}"
        (out / "cells").mkdir(parents=True)
        for cell in (local_sweep / "cells").glob(f"*_a{alpha}_*.json"):
            shutil.copy(cell, out / "cells")
        mark_run_dir(out, "scenario2", finished=False, study=study)
        _, err = sweep_here(out, capfd, "--alphas", alpha)
        assert "4 already done" in err and "0 to run" in err
        assert "full_road_speed_mps" not in pd.read_csv(out / "runs.csv")
        parts.append(str(out))
    code, _, err = main_here(s2.main, ["--merge", ",".join(parts), "--out", str(tmp_path / "m")], capfd)
    assert code == 0, err[-2000:]
    runs = pd.read_csv(tmp_path / "m" / "runs.csv").sort_values("key", ignore_index=True)
    local = pd.read_csv(local_sweep / "runs.csv").sort_values("key", ignore_index=True)
    pd.testing.assert_frame_equal(runs[COMPARED], local[COMPARED], check_dtype=False)
    assert (tmp_path / "m" / "alpha_star.csv").read_text() == (local_sweep / "alpha_star.csv").read_text()


@pytest.mark.sumo
def test_tiny_sweep_ray_matches_local(local_sweep: Path, tmp_path: Path, ray_alone: None) -> None:
    pytest.importorskip("ray", reason="ray is not installed: the ray backend cannot be tested")
    out = tmp_path / "ray"
    run_sweep_cli(out, "--backend", "ray", "--workers", "2")
    runs = assert_outputs(out)
    local = pd.read_csv(local_sweep / "runs.csv")
    pd.testing.assert_frame_equal(runs[COMPARED], local[COMPARED])
    assert (out / "alpha_star.csv").read_text() == (local_sweep / "alpha_star.csv").read_text()


def wait_for_cells(out: Path, n: int, proc: subprocess.Popen[str], timeout: float = 300.0) -> None:
    end = time.monotonic() + timeout
    while len(list((out / "cells").glob("*.json"))) < n:
        assert proc.poll() is None, "the sweep ended before it could be interrupted"
        assert time.monotonic() < end, "no cell finished in time"
        time.sleep(0.1)


def kill_group(proc: subprocess.Popen[str], sig: int) -> None:
    os.killpg(proc.pid, sig)
    proc.communicate(timeout=60)


def start_sweep(out: Path, *extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen(sweep_cmd(out, "--workers", "2", *extra), cwd=REPO, start_new_session=True, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip


def wait_group_gone(pgid: int, timeout: float = 60.0) -> None:
    """Wait until no process of the group is left (the workers of a killed sweep exit on their own)."""
    end = time.monotonic() + timeout
    while True:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return
        assert time.monotonic() < end, "the killed sweep's workers are still running"
        time.sleep(0.1)


def assert_records_trustworthy(out: Path, main_killed: bool = False) -> int:
    """Every record a killed sweep left is whole: a JSON object, status ok with a sound summary, or failed.
    main_killed: the main process (the only writer of records) was SIGKILLed, which no process can catch: the one
    record it was writing at that instant may be left as its temporary file, never read as a record (the next run
    removes it, which the last step of the test below checks)."""
    paths = list((out / "cells").glob("*.json"))
    for path in paths:
        record = json.loads(path.read_text())
        assert record["status"] == "failed" or records.record_problem(record, s2.REQUIRED_SUMMARY) is None, path
    left = list((out / "cells").glob("*.tmp"))
    assert not left or (main_killed and len(left) == 1 and ".json." in left[0].name), left
    return len(paths)


@pytest.fixture(scope="module")
def lone_sweep(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny sweep of a learner that trains inside its cells, one training each (the paper preset: no stacked
    updates, so no groups before the cells)."""
    out = tmp_path_factory.mktemp("s2lone") / "lone"
    run_sweep_cli(out, "--workers", "2", *LONE)
    return out


LONE = ("--preset", "paper")
"""a learner whose cells train their own models (stacked_updates off): interrupts land while cells train"""


@pytest.mark.sumo
def test_a_sweep_interrupted_at_every_point_ends_as_the_uninterrupted_one(lone_sweep: Path, tmp_path: Path,
                                                                          capfd: pytest.CaptureFixture[str]) -> None:
    """Issue 25: Ctrl-C (SIGINT to the process group) while cells run, SIGKILL of the main process alone (its workers
    notice and exit), SIGTERM to the process group, SIGKILL while the report is being written; the last rerun equals
    the uninterrupted sweep, and the cells done before it are neither recomputed nor rewritten. On a learner whose
    cells train (the default's trainings run as groups before its cells: the test below)."""
    out = tmp_path / "cut"
    # 1. Ctrl-C once a cell is done: the trainings save their checkpoints, the sweep exits 130 in one line
    proc = start_sweep(out, *LONE)
    wait_for_cells(out, 1, proc)
    time.sleep(0.3)
    kill_group(proc, signal.SIGINT)
    wait_group_gone(proc.pid)
    assert proc.returncode == 130
    done = assert_records_trustworthy(out)
    assert 1 <= done < 8
    # 2. SIGKILL of the main process alone, once one more cell is done
    proc = start_sweep(out, *LONE)
    wait_for_cells(out, done + 1, proc)
    proc.kill()
    proc.communicate(timeout=60)
    wait_group_gone(proc.pid)
    done = assert_records_trustworthy(out, main_killed=True)
    # 3. SIGTERM to the whole process group once one more cell is done
    proc = start_sweep(out, *LONE)
    wait_for_cells(out, done + 1, proc)
    kill_group(proc, signal.SIGTERM)
    wait_group_gone(proc.pid)
    assert proc.returncode != 0
    done = assert_records_trustworthy(out)
    # 4. SIGKILL while the report is written (runs.csv comes first, then the figures and report.md); not Ctrl-C,
    # which CPython may drop when it lands in a garbage collector's callback (test_faults_scenario1.py)
    proc = start_sweep(out, *LONE)
    end = time.monotonic() + 300
    while not (out / "runs.csv").exists():
        assert proc.poll() is None and time.monotonic() < end, "the sweep ended before its report"
        time.sleep(0.01)
    kill_group(proc, signal.SIGKILL)
    wait_group_gone(proc.pid)
    assert proc.returncode == -signal.SIGKILL and not (out / "report.md").exists()
    assert assert_records_trustworthy(out) == 8
    # 5. the rerun reuses every cell, neither recomputed nor rewritten, and equals the uninterrupted sweep; nothing
    # partial is left anywhere
    cells = {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in (out / "cells").glob("*.json")}
    _, err = sweep_here(out, capfd, "--workers", "2", *LONE)  # the interrupted sweeps ran as processes
    assert "8 already done" in err and "0 to run" in err
    assert {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in (out / "cells").glob("*.json")} == cells
    runs = assert_outputs(out)
    pd.testing.assert_frame_equal(runs[COMPARED], pd.read_csv(lone_sweep / "runs.csv")[COMPARED])
    assert (out / "alpha_star.csv").read_text() == (lone_sweep / "alpha_star.csv").read_text()
    left = [p for p in tmp_path.rglob("*") if p.name.endswith((".tmp", ".lock")) or ".partial-" in p.name]
    assert left == [] and not list(out.rglob("checkpoint.pt"))
    assert all(trainings.model_folder_problem(out / folder) is None for folder in runs["train_dir"])


@pytest.mark.sumo
def test_a_sweep_interrupted_while_its_trainings_group_ends_as_the_uninterrupted_one(
        local_sweep: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """The default learner's trainings run as groups before the cells (engine/groups.py): Ctrl-C while the first
    group trains exits 130 with no half-written record; SIGKILL of the main process alone in the rerun's trainings
    leaves no process behind; the last rerun equals the uninterrupted sweep and leaves no partial file."""
    out = tmp_path / "cut"
    store = tmp_path / "models"
    for sig, whole_group in ((signal.SIGINT, True), (signal.SIGKILL, False)):
        proc = start_sweep(out)
        end = time.monotonic() + 300
        while not (store.is_dir() and any(p.is_dir() for p in store.iterdir())):  # a group has begun
            assert proc.poll() is None and time.monotonic() < end, "the sweep ended before its trainings"
            time.sleep(0.01)
        if whole_group:
            kill_group(proc, sig)
            assert proc.returncode == 130
        else:
            proc.kill()
            proc.communicate(timeout=60)
        wait_group_gone(proc.pid)
        assert_records_trustworthy(out, main_killed=not whole_group)
    sweep_here(out, capfd, "--workers", "2")  # the interrupted sweeps ran as processes
    runs = assert_outputs(out)
    pd.testing.assert_frame_equal(runs[COMPARED], pd.read_csv(local_sweep / "runs.csv")[COMPARED])
    assert (out / "alpha_star.csv").read_text() == (local_sweep / "alpha_star.csv").read_text()
    left = [p for p in tmp_path.rglob("*") if p.name.endswith((".tmp", ".lock")) or ".partial-" in p.name]
    assert left == [] and not list(tmp_path.rglob("checkpoint.pt"))


def test_failed_cell_is_recorded_and_retried(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A cell that raises is written as failed with its error; the next run retries it (no SUMO: train is faked).
    The model whose training fails (alpha 8, seed 2) is its first condition's cell's; its other condition's cell,
    which waits for it, fails saying so."""
    import coopsumo.agents.train as train_module

    trained: list[str] = []
    broken = [True]

    def fake_train(cfg, out, resume=False, progress=True, on_steps=None):  # type: ignore[no-untyped-def]
        trained.append(trained_key(cfg))
        if cfg.sim.reward.alpha == 8.0 and cfg.sim.seed == 2 and broken[0]:
            raise RuntimeError("SUMO said no\nsecond line")
        return write_fake_model(cfg, out)

    import torch

    monkeypatch.setattr(torch, "set_num_threads", lambda n: None)  # keep this test process's threads
    monkeypatch.setattr(train_module, "train", fake_train)
    monkeypatch.setattr(engine_groups, "train_groups", lambda *a, **k: 0)  # every training by the fake, alone
    monkeypatch.setattr(s2, "evaluate_model", fake_evaluation)
    monkeypatch.setattr(trainings, "unusable_trainings", lambda *a: set())  # a faked training: no model.pt to judge
    ran = inline_cells(monkeypatch)
    monkeypatch.setattr("coopsumo.sim.network.build_net", lambda road: None)
    meta = s2.run_sweep(s2_plan.PROFILES["tiny"], tmp_path, progress=False, n_boot=50)
    assert meta["cells_failed"] == 2 and meta["cells_ok"] == 6
    assert sorted(set(trained)) == ["L2_a0_s1", "L2_a0_s2", "L2_a8_s1", "L2_a8_s2"]
    runs = pd.read_csv(tmp_path / "runs.csv")
    failed = runs[runs["status"] == "failed"]
    assert sorted(failed["key"]) == ["L2_T2_a8_s2", "L2_T4_a8_s2"]
    assert failed.set_index("key")["error"].to_dict() == {"L2_T4_a8_s2": "RuntimeError: SUMO said no",
                                                          "L2_T2_a8_s2": "needs cell L2_T4_a8_s2, which failed"}
    assert "| L2_T4_a8_s2 | RuntimeError: SUMO said no |" in (tmp_path / "report.md").read_text()
    ran.clear()
    trained.clear()
    broken[0] = False  # the fake now succeeds
    meta = s2.run_sweep(s2_plan.PROFILES["tiny"], tmp_path, progress=False, n_boot=50)
    assert meta["cells_failed"] == 0 and meta["cells_run"] == 2
    assert sorted(ran) == ["L2_T2_a8_s2", "L2_T4_a8_s2"] and set(trained) == {"L2_a8_s2"}


def fake_cell(spec: dict[str, object], root: str) -> dict[str, object]:
    """A cell without SUMO (run in a spawned worker): the key L2_T2_a8_s2 (a cell no other waits for) kills its
    worker process."""
    if spec["key"] == "L2_T2_a8_s2":
        os._exit(7)
    record = s2.failed_record(spec, "")
    record.update(status="ok", error=None, summary={"mean_speed_mps": 20.0 + float(spec["seed"])})  # type: ignore[arg-type]
    return record


def test_dead_worker_is_retried_then_recorded_failed(tmp_path: Path) -> None:
    """A cell whose worker process dies is retried in a fresh pool, then recorded as failed; the others finish."""
    specs = s2_plan.cell_specs(s2_plan.PROFILES["tiny"])
    backend = runner.LocalBackend(2, cell_fn=fake_cell)
    try:
        counts = runner.execute(specs, tmp_path, backend, len(specs), 0, progress=False, failed_record=s2.failed_record)
    finally:
        backend.close()
    assert counts == {"ok": 7, "failed": 1}
    records = {p.stem: json.loads(p.read_text()) for p in (tmp_path / "cells").glob("*.json")}
    assert len(records) == 8
    assert records["L2_T2_a8_s2"]["status"] == "failed"
    assert "worker process died 2 times" in records["L2_T2_a8_s2"]["error"]


def slow_cell(spec: dict[str, object], root: str) -> dict[str, object]:
    """A cell that outlasts the test (run in a spawned worker)."""
    time.sleep(60)
    return fake_cell(spec, root)


def test_an_abort_ends_the_pools_thread_before_it_returns(monkeypatch: pytest.MonkeyPatch) -> None:
    """After abort() the pool's manager thread has ended and closed its wake-up pipe: an exit right after used to
    race with it (Python's exit hook wrote into the pipe as the thread closed it: a traceback, EBADF, after
    "scenario1: interrupted", 1 Ctrl-C in about 600). Here the thread is slow to close its pipe."""
    import concurrent.futures.process as pool_module

    close = pool_module._ThreadWakeup.close

    def slow_close(self: Any) -> None:
        time.sleep(1.0)
        close(self)

    monkeypatch.setattr(pool_module._ThreadWakeup, "close", slow_close)
    specs = s2_plan.cell_specs(s2_plan.PROFILES["tiny"])
    backend = runner.LocalBackend(2, cell_fn=slow_cell)
    handles = [backend.submit(spec, Path("unused")) for spec in specs[:2]]
    assert backend.wait(handles, timeout=0.5) == []  # both cells running
    manager = backend._pool._executor_manager_thread  # type: ignore[attr-defined]
    assert manager is not None and manager.is_alive()
    backend.abort()
    assert not manager.is_alive()


def lingering_cell(spec: dict[str, object], root: str) -> dict[str, object]:
    """A cell that leaves a thread running, as a policy of one's own may (run in a spawned worker)."""
    import threading

    threading.Thread(target=time.sleep, args=(600,)).start()  # not a daemon: the worker's exit waits for it
    return fake_cell(spec, root)


def lingering_backend(monkeypatch: pytest.MonkeyPatch) -> tuple[runner.LocalBackend, list[Any]]:
    """A local backend of one worker whose one cell (lingering_cell) is done, and its worker processes; close() waits
    2 s for them."""
    monkeypatch.setattr(runner, "CLOSE_WAIT_S", 2.0)
    specs = s2_plan.cell_specs(s2_plan.PROFILES["tiny"])
    backend = runner.LocalBackend(1, cell_fn=lingering_cell)
    handles = [backend.submit(specs[0], Path("unused"))]
    deadline = time.monotonic() + 120
    while not backend.wait(handles, timeout=1.0):
        assert time.monotonic() < deadline
    return backend, mp.active_children()


def test_a_worker_that_cannot_exit_does_not_hold_the_study(monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 82, probe 12, N6: close() waited without end for a worker whose cell left a thread running; now the
    worker is stopped CLOSE_WAIT_S after the pool is shut."""
    backend, workers = lingering_backend(monkeypatch)
    start = time.monotonic()
    backend.close()
    assert time.monotonic() - start < 30 and workers and not any(p.is_alive() for p in workers)


def test_a_worker_the_pools_thread_reaps_is_not_seen_alive_after_close(monkeypatch: pytest.MonkeyPatch) -> None:
    """The race of the test above, made to happen (it failed once on CI, 2026-12-05): the pool's thread and close()
    both wait for the lingering worker; the one that reaps it notes its exit code a moment later, and the other's wait
    meanwhile finds no child (ECHILD: multiprocessing says "not ended yet"). When the pool's thread reaped it, the
    worker looked alive after close() returned. Here the pool's thread reaps first, 0.5 s before it notes the exit code.
    On a spawn context: its workers are the main process's children, reaped with waitpid (the fork server's are not)."""
    import threading

    waitpid = os.waitpid

    def slow_to_note(pid: int, options: int) -> tuple[int, int]:
        if threading.current_thread() is threading.main_thread():
            time.sleep(0.1)  # the pool's thread, already waiting, reaps the worker first
            return waitpid(pid, options)
        got = waitpid(pid, options)
        if got[0] != 0:
            time.sleep(0.5)
        return got

    monkeypatch.setattr(runner, "worker_context", lambda: mp.get_context("spawn"))
    backend, workers = lingering_backend(monkeypatch)
    monkeypatch.setattr(os, "waitpid", slow_to_note)
    backend.close()
    assert workers and not any(p.is_alive() for p in workers)


def test_neighbour_separation_on_hand_made_speeds() -> None:
    rng = np.random.default_rng(0)
    speeds = np.array([[10.0, 10.5, 9.5],  # alpha 0
                       [12.0, 12.5, 11.5],  # alpha* : 2 above alpha 0 on every seed
                       [11.9, 12.6, 11.4]])  # within noise of alpha*  # fmt: skip
    assert stats.neighbour_separation(speeds, 1, 500, rng) == (True, False)
    assert stats.neighbour_separation(speeds, 0, 500, rng) == (None, False)  # no smaller alpha; alpha 1 is faster
    assert stats.neighbour_separation(speeds, 2, 500, rng)[1] is None


@pytest.mark.sumo
def test_tiny_sweep_with_the_paper_preset(lone_sweep: Path) -> None:
    """--preset paper: every cell trains the paper-literal learner (recorded in its configuration). The sweep is
    lone_sweep's (the same command line), which the interrupted sweep's test only reads."""
    out = lone_sweep
    assert_outputs(out)
    for cell in (out / "cells").glob("*.json"):
        dqn = json.loads(cell.read_text())["config"]["train"]["dqn"]
        assert dqn["preset"] == "paper" and dqn["decision_interval_steps"] == 1 and dqn["dueling"] is False


# -- records that cannot be trusted, failures, close alphas (no SUMO: train is faked) ---------------------------
def trained_key(cfg: Any) -> str:
    """The model a training makes, as its study's train/ link names it (plan.lane_key: lane count, seed and alpha; its
    store folder is named by its whole configuration)."""
    return s2_plan.lane_key(cfg.sim.road.lanes, cfg.sim.seed, cfg.sim.reward.alpha)


def inline_cells(monkeypatch: pytest.MonkeyPatch, ran: list[str] | None = None) -> list[str]:
    """Cells run in this process, one at a time (conftest.InlineBackend); the key of each cell run is appended to
    `ran` (None: a new list), which is returned."""
    ran = [] if ran is None else ran

    def cell(spec: dict[str, Any], root: str) -> dict[str, Any]:
        ran.append(spec["key"])
        return s2.run_cell(spec, root)

    monkeypatch.setattr(engine_cells, "make_backend", lambda *_: InlineBackend(cell))
    return ran


def write_fake_model(cfg: Any, out: Path) -> dict[str, Any]:
    """What a faked training leaves: its summary, holding in place of a model the speed its evaluations will give
    (from alpha and the training seed); only files a training writes (the store refuses others: probe 7, I6). Returns
    the summary, as train() returns the summary it writes."""
    summary = {"steps": cfg.sim.steps, "departed": 40, "mean_speed_mps": 20.0, "lane_changes": 12, "collisions": 0,
               "updates": 3, "wall_seconds": 3.0, "steps_per_second": 100.0,
               "fake_speed": 20.0 + cfg.sim.reward.alpha / 100 + cfg.sim.seed}  # fmt: skip
    (out / "train_summary.json").write_text(json.dumps(summary))
    return summary


def fake_evaluation(config: dict[str, Any], out: Path, label: str) -> dict[str, Any]:
    """scenario2.evaluate_model without SUMO: the faked model's speed, plus a thousandth per evaluation seed above
    the first (so that pooling shows), no collision; its counts and seconds a run of its configuration's can give
    (records.runs_problem judges them as scenario I judges a run folder's)."""
    model = Path(config["policy"].removeprefix("dqn:").split(",")[0])
    speed = json.loads((model.parent / "train_summary.json").read_text())["fake_speed"] + (config["seed"] - 2001) / 1000
    run = {"steps": config["steps"], "sim_seconds": config["steps"] * config["control"]["dt_s"], "departed": 10,
           "arrived": 0, "lane_changes_per_vehicle": 0.1}
    return {"mean_speed_mps": speed, "collisions": 0, "teleports": 0, "lane_changes": 1, **run}


@pytest.fixture
def faked_train(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """train() and the evaluations faked in this process (cells run inline): the returned list's first item is
    "fail:<keys>", comma-separated: a model named (plan.lane_key, "L2_a8_s2") fails its training, a cell named
    ("L2_T2_a8_s2") its evaluation, "*" every training; the items after it are the keys of the cells run, in order.
    A model's speed comes from its alpha and training seed."""
    import torch

    import coopsumo.agents.train as train_module

    calls = ["fail:"]

    def failing() -> list[str]:
        return calls[0].removeprefix("fail:").split(",") if calls[0].startswith("fail:") else []

    def fake_train(cfg, out, resume=False, progress=True, on_steps=None):  # type: ignore[no-untyped-def]
        if "*" in failing() or trained_key(cfg) in failing():
            raise RuntimeError("SUMO said no")
        return write_fake_model(cfg, out)

    def evaluation(config: dict[str, Any], out: Path, label: str) -> dict[str, Any]:
        if label in failing():
            raise RuntimeError("SUMO said no")
        return fake_evaluation(config, out, label)

    monkeypatch.setattr(torch, "set_num_threads", lambda n: None)
    monkeypatch.setattr(train_module, "train", fake_train)
    monkeypatch.setattr(engine_groups, "train_groups", lambda *a, **k: 0)  # every training by the fake, alone
    monkeypatch.setattr(s2, "evaluate_model", evaluation)
    monkeypatch.setattr(trainings, "unusable_trainings", lambda *a: set())  # a faked training: no model.pt to judge
    inline_cells(monkeypatch, calls)
    monkeypatch.setattr("coopsumo.sim.network.build_net", lambda road: None)
    return calls


def test_a_corrupt_record_is_rerun_not_counted(tmp_path: Path, faked_train: list[str],
                                               capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    assert s2.run_sweep(s2_plan.PROFILES["tiny"], tmp_path, progress=False, n_boot=20)["cells_ok"] == 8
    first = pd.read_csv(tmp_path / "alpha_star.csv")
    cells = tmp_path / "cells"
    bad = {"L2_T2_a8_s1": lambda r: {**r, "summary": {}}, "L2_T2_a8_s2": lambda r: {**r, "summary": None},
           "L2_T2_a0_s1": lambda r: {**r, "summary": {**r["summary"], "mean_speed_mps": "fast"}},
           "L2_T2_a0_s2": lambda r: {**r, "summary": {**r["summary"], "mean_speed_mps": float("nan")}},
           "L2_T4_a0_s1": lambda r: [r], "L2_T4_a0_s2": lambda r: {k: v for k, v in r.items() if k != "status"}}
    for key, spoil in bad.items():
        path = cells / f"{key}.json"
        path.write_text(json.dumps(spoil(json.loads(path.read_text()))))
    (cells / "L2_T4_a8_s1.json").write_text((cells / "L2_T4_a8_s1.json").read_text()[:50])  # truncated
    capsys.readouterr()
    del faked_train[1:]
    meta = s2.run_sweep(s2_plan.PROFILES["tiny"], tmp_path, progress=False, n_boot=20)
    err = capsys.readouterr().err
    assert sorted(faked_train[1:]) == sorted([*bad, "L2_T4_a8_s1"])  # exactly the spoiled cells ran again
    for key in [*bad, "L2_T4_a8_s1"]:
        assert sum(f"cell {key}: record" in line and line.endswith("rerunning it") for line in err.splitlines()) == 1
    assert "1 already done" in err and meta["cells_ok"] == 8 and meta["cells_run"] == 7
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "alpha_star.csv"), first)


def test_a_failed_cell_withholds_its_alpha_star_and_an_all_failed_sweep_exits_1(
        tmp_path: Path, faked_train: list[str], capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    faked_train[0] = "fail:L2_T2_a8_s2"
    code, err = run_main(["--profile", "tiny", "--out", str(tmp_path / "one"), "--quiet", "--bootstrap", "20"], capsys)
    assert code == 1 and err[-1].startswith("scenario2: error: 1 of 8 cells failed (L2_T2_a8_s2)")
    table = pd.read_csv(tmp_path / "one" / "alpha_star.csv").set_index("t_up_s")
    assert np.isnan(table.loc[2.0, "alpha_star"]) and table.loc[4.0, "alpha_star"] == 8.0
    report = (tmp_path / "one" / "report.md").read_text()
    assert "| 2 | 2 | – |" in report and "| 2 | 4 | 8 |" in report  # no alpha* at T_up 2 s, in the alpha* table
    assert "| L2_T2_a8_s2 | RuntimeError: SUMO said no |" in report
    faked_train[:] = ["fail:*"]
    code, err = run_main(["--profile", "tiny", "--out", str(tmp_path / "all"), "--quiet", "--bootstrap", "20"], capsys)
    assert code == 1 and len([e for e in err if "error" in e]) == 1 and "Traceback" not in "\n".join(err)
    assert err[-1].startswith("scenario2: error: 8 of 8 cells failed (") and "L2_T2_a0_s1, " in err[-1]
    assert pd.read_csv(tmp_path / "all" / "alpha_star.csv")["alpha_star"].isna().all()
    report = (tmp_path / "all" / "report.md").read_text()
    assert "![alpha* per lane count]" not in report and not (tmp_path / "all" / ALPHA_STAR_FIGURE).exists()
    assert "| 2 | – | – | – | ––– |" in report and "| 4 | – | – | – | ––– |" in report and "nan" not in report


def test_close_alphas_are_two_cells_on_the_command_line(tmp_path: Path, faked_train: list[str],
                                                        capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    argv = ["--profile", "tiny", "--alphas", "8,8.000001", "--seeds", "1", "--out", str(tmp_path), "--quiet"]
    code, err = run_main([*argv, "--bootstrap", "0"], capsys)
    assert code == 0, err
    assert sorted(p.stem for p in (tmp_path / "cells").glob("*.json")) == [
        "L2_T2_a8.000001_s1", "L2_T2_a8_s1", "L2_T4_a8.000001_s1", "L2_T4_a8_s1"]
    assert sorted(faked_train[1:]) == ["L2_T2_a8.000001_s1", "L2_T2_a8_s1", "L2_T4_a8.000001_s1", "L2_T4_a8_s1"]
    assert (pd.read_csv(tmp_path / "alpha_star.csv")["alpha_star"] == 8.000001).all()


def test_every_model_meets_every_evaluation_seed_and_none_was_trained_on(tmp_path: Path,
                                                                        faked_train: list[str]) -> None:  # fmt: skip
    """Each DQN cell trains on its training seed and is evaluated on every evaluation seed, none of them a training
    seed; its summary pools them; MOBIL runs once per evaluation seed (no SUMO: training and evaluation faked)."""
    profile = replace(s2_plan.PROFILES["tiny"], eval_seeds=s2_plan.eval_seeds(3), policies=("dqn", "mobil"))
    specs = s2_plan.cell_specs(profile)
    dqn = [s for s in specs if s["policy"] == "dqn"]
    mobil = [s for s in specs if s["policy"] == "mobil"]
    assert len(dqn) == 8 and len(mobil) == 2 * 2 * 3 == profile.n_cells() - 8
    for spec in dqn:
        assert spec["config"]["train"]["sim"]["seed"] == spec["seed"] and spec["config"]["train"]["eval_steps"] == 0
        assert [e["seed"] for e in spec["config"]["evals"]] == [2001, 2002, 2003]
        assert all(e["reward"]["alpha"] == spec["alpha"] for e in spec["config"]["evals"])
    assert {s["seed"] for s in mobil} == {2001, 2002, 2003} and not {2001, 2002, 2003} & set(profile.seeds)
    meta = s2.run_sweep(replace(profile, policies=("dqn",)), tmp_path, progress=False, n_boot=20)
    assert meta["cells_ok"] == 8
    record = json.loads((tmp_path / "cells" / "L2_T4_a8_s2.json").read_text())
    assert [e["eval_seed"] for e in record["eval_summaries"]] == [2001, 2002, 2003]
    assert record["summary"]["mean_speed_mps"] == pytest.approx(20.0 + 0.08 + 2 + 0.001)  # the mean of the three
    assert record["summary"]["lane_changes"] == 3  # a count: summed
    evals = pd.read_csv(tmp_path / "evals.csv")
    assert len(evals) == 24 and sorted(set(evals["eval_seed"])) == [2001, 2002, 2003]
    assert "evaluation seeds 2001, 2002, 2003, which no training or selection saw" in (tmp_path / "report.md"
                                                                                        ).read_text()  # fmt: skip


def test_pooled_summaries_sum_counts_and_average_the_rest() -> None:
    pooled = records.pool_summaries([{"mean_speed_mps": 10.0, "collisions": 0, "teleports": 1, "scenario": "free"},
                                   {"mean_speed_mps": 14.0, "collisions": 2, "teleports": 0, "scenario": "free"}])
    assert pooled == {"mean_speed_mps": 12.0, "collisions": 2, "teleports": 1, "scenario": "free"}
    assert records.pool_summaries([]) == {}


def test_a_pooled_summary_passes_the_record_check() -> None:
    """Lane changes per vehicle is pooled as a ratio of the summed counts, not averaged: an averaged one (0.5286 for
    386 changes of 735 vehicles) made a resumed quick sweep call its own records edited and rerun them."""
    from coopsumo.studies.engine.records import implausible

    runs = [{"lane_changes": 200, "departed": 350, "lane_changes_per_vehicle": 200 / 350},
            {"lane_changes": 186, "departed": 385, "lane_changes_per_vehicle": 186 / 385}]
    pooled = records.pool_summaries(runs)
    assert pooled["lane_changes_per_vehicle"] == 386 / 735
    assert implausible(pooled) is None
    averaged = dict(pooled, lane_changes_per_vehicle=(200 / 350 + 186 / 385) / 2)
    assert implausible(averaged) is not None  # the check that fired on the averaged ratio


def test_a_record_that_is_not_its_cells_is_rerun(tmp_path: Path, faked_train: list[str],
                                                 capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """A fresh probe (issue 82): records whose policy, load or trained speed had been edited were reused, and the
    edit reached runs.csv and alpha*. Each field copied from the cell's spec must be the spec's, and the training's
    summary kept beside it plausible."""
    assert s2.run_sweep(s2_plan.PROFILES["tiny"], tmp_path, progress=False, n_boot=20)["cells_ok"] == 8
    first = pd.read_csv(tmp_path / "alpha_star.csv")
    cells = tmp_path / "cells"
    bad = {"L2_T2_a8_s1": lambda r: {**r, "policy": "zzz"}, "L2_T2_a8_s2": lambda r: {**r, "load": "x"},
           "L2_T2_a0_s1": lambda r: {**r, "train_summary": {**(r["train_summary"] or {}), "mean_speed_mps": 999.0}},
           "L2_T2_a0_s2": lambda r: {**r, "resumed_from_step": -7}, "L2_T4_a0_s1": lambda r: {**r, "seed": 3}}
    for key, spoil in bad.items():
        path = cells / f"{key}.json"
        path.write_text(json.dumps(spoil(json.loads(path.read_text()))))
    capsys.readouterr()
    del faked_train[1:]
    meta = s2.run_sweep(s2_plan.PROFILES["tiny"], tmp_path, progress=False, n_boot=20)
    err = capsys.readouterr().err
    assert sorted(faked_train[1:]) == sorted(bad)  # exactly the spoiled cells ran again
    for key in bad:
        assert sum(f"cell {key}: record" in line and line.endswith("rerunning it") for line in err.splitlines()) == 1
    assert meta["cells_ok"] == 8 and meta["cells_run"] == len(bad)
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "alpha_star.csv"), first)
    assert set(pd.read_csv(tmp_path / "runs.csv")["policy"]) == {"dqn"}
