"""Scenario II's gate and what the lane-network profiles add to its measures: pure functions on tables, no SUMO.

- full_road_speed: mean speed once the road is full, from a run's trajectory table (the warm-up ends when the first
  vehicle inserted has left the road), for learned and classical policies alike;
- gate_table: per condition, do the alpha-0 models beat `keep` (a two-level bootstrap: models, then evaluation
  seeds), their lane changes per vehicle against MOBIL p = 0's, and alpha*'s models against the best MOBIL p*;
- lane_change_columns: each alpha's lane changes per vehicle beside alpha*;
- trend_rows: the paper's two trends (alpha* against inflow, against lanes) as the plane's slopes over the
  conditions that pass the gate, each with its 90% interval over models and about how many models would decide it;
- check_table: alpha-conditioned networks against per-alpha models at the same conditions (the check profile);
- step_costs and core_hours: what a profile costs, from the cells' measured times.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from coopsumo.studies.engine.stats import hierarchical_bootstrap
from coopsumo.studies.scenario2.measures import PlaneFitError, fit_plane, plane_bootstrap, policy_rows
from coopsumo.studies.scenario2.plan import CLASSICAL, PER_ALPHA, Profile

LEVEL = 0.9
"""two-sided level of the gate's and the trends' intervals (a one-sided 95% test of "beats")"""
NEAR_P_STAR_MPS = 0.3
"""the issue's target: alpha*'s models within this of p*"""
CONDITION = ["lanes", "t_up_s"]


# -- the measure that starts when the road is full --------------------------------------------------------------
def full_road_speed(traj: pd.DataFrame) -> tuple[float, float]:
    """(mean speed m/s once the road is full, the time s it starts) from a trajectory table (columns time_s, vid,
    speed_mps: every vehicle on the road at each sampling time, samples equally spaced).

    The warm-up ends at the first sampling time at which the first vehicle inserted (the earliest first sample;
    ties: the smallest vid) is no longer on the road; the speed is the mean over every vehicle sample from then on,
    i.e. distance over vehicle time, as the run's mean_speed_mps is over the whole run. (nan, nan) when that vehicle
    never leaves (the run is too short) or nothing is sampled after it left."""
    if traj.empty:
        return math.nan, math.nan
    first_seen = traj.groupby("vid")["time_s"].min()
    first = first_seen.index[np.flatnonzero(first_seen.to_numpy() == first_seen.min())[0]]
    last = float(traj.loc[traj["vid"] == first, "time_s"].max())
    later = traj["time_s"].to_numpy() > last
    if not later.any():
        return math.nan, math.nan
    start = float(traj["time_s"].to_numpy()[later].min())
    return float(traj.loc[traj["time_s"] >= start, "speed_mps"].mean()), start


# -- tables of one condition ----------------------------------------------------------------------------------------
def model_seed_matrix(evals: pd.DataFrame, metric: str, policy: str = "dqn", alpha: float = 0.0) -> pd.DataFrame:
    """metric[training seed, evaluation seed] of one condition's models of `policy` at `alpha` (evals.csv rows)."""
    rows = evals[(evals["policy"] == policy) & np.isclose(evals["alpha"].astype(float), alpha)]
    return rows.pivot_table(index="seed", columns="eval_seed", values=metric, aggfunc="mean")


def classical_series(evals: pd.DataFrame, metric: str, policy: str, p: float | None = None) -> pd.Series:
    """metric by evaluation seed of one condition's runs of a policy that needs no training (MOBIL at p)."""
    rows = evals[evals["policy"] == policy]
    if p is not None:
        rows = rows[np.isclose(rows["p"].astype(float), p)]
    return rows.groupby("eval_seed")[metric].mean()


def paired_gap(models: pd.DataFrame, baseline: pd.Series, reps: int) -> tuple[float, float, float]:
    """(mean, low, high): the models' speed minus the baseline's on the same evaluation seed, with the LEVEL interval
    of the two-level bootstrap (models, then evaluation seeds: stats.hierarchical_bootstrap). NaN without data."""
    if models.empty or baseline.empty:
        return math.nan, math.nan, math.nan
    diff = models.sub(baseline.reindex(models.columns), axis=1).to_numpy(float)
    mean, low, high = hierarchical_bootstrap(diff, reps=max(reps, 1), confidence=LEVEL)
    return (mean, low, high) if reps > 0 else (mean, math.nan, math.nan)


def _mean(values: Any) -> float:
    arr = np.asarray(values, float)
    arr = arr[np.isfinite(arr)]
    return float(arr.mean()) if arr.size else math.nan


def gate_table(runs: pd.DataFrame, evals: pd.DataFrame, alpha_table: pd.DataFrame, p_table: pd.DataFrame,
               metric: str, reps: int = 2000) -> pd.DataFrame:  # fmt: skip
    """The gate, one row per condition of the DQN cells.

    beats_keep: the LEVEL interval of (alpha-0 model - keep, same evaluation seed) lies above 0 (None: no alpha-0
    model or no keep run to compare); passes: beats_keep is True, or None when it cannot be judged. Lane changes
    per vehicle: the alpha-0 models' mean (each model pooled over its evaluations) and MOBIL p = 0's mean over its
    runs, lc_share their ratio. alpha*'s models against p* (the best MOBIL p): gap, interval, near (gap >= -0.3 m/s)
    and ahead (the interval above 0)."""
    rows = []
    alpha_star = {(int(r["lanes"]), float(r["t_up_s"])): r for r in alpha_table.to_dict("records")}
    p_star = {(int(r["lanes"]), float(r["t_up_s"])): r for r in p_table.to_dict("records")} if len(p_table) else {}
    dqn_runs = policy_rows(runs, "dqn")
    for (lanes, t_up), ev in evals.groupby(CONDITION, sort=True):
        key = (int(lanes), float(t_up))
        if key not in alpha_star:
            continue
        cell_runs = runs[(runs["lanes"] == lanes) & np.isclose(runs["t_up_s"], t_up)]
        zero = model_seed_matrix(ev, metric, alpha=0.0)
        keep = classical_series(ev, metric, "keep")
        gap, low, high = paired_gap(zero, keep, reps)
        beats = None if not math.isfinite(low) else bool(low > 0)
        lc_zero = _mean(dqn_runs[(dqn_runs["lanes"] == lanes) & np.isclose(dqn_runs["t_up_s"], t_up)
                                 & np.isclose(dqn_runs["alpha"], 0.0)]["lane_changes_per_vehicle"])  # fmt: skip
        mobil = cell_runs[cell_runs["policy"] == "mobil"]
        lc_mobil = _mean(mobil[np.isclose(mobil["p"], 0.0)]["lane_changes_per_vehicle"])
        star = alpha_star[key].get("alpha_star", math.nan)
        p_row = p_star.get(key, {})
        p_best = p_row.get("p_star", math.nan)
        if math.isfinite(star) and math.isfinite(p_best):
            star_gap = paired_gap(model_seed_matrix(ev, metric, alpha=star),
                                  classical_series(ev, metric, "mobil", p_best), reps)  # fmt: skip
        else:
            star_gap = (math.nan, math.nan, math.nan)
        rows.append({
            "lanes": int(lanes), "t_up_s": float(t_up), "inflow_veh_h": round(3600.0 / float(t_up), 1),
            "load": float(cell_runs["load"].iloc[0]),
            "keep_mps": _mean(keep), "greedy_mps": _mean(classical_series(ev, metric, "greedy")),
            "alpha0_mps": _mean(zero.mean(axis=1)) if not zero.empty else math.nan, "alpha0_models": len(zero),
            "alpha0_minus_keep_mps": gap, "alpha0_minus_keep_low": low, "alpha0_minus_keep_high": high,
            "beats_keep": beats, "passes": beats,
            "alpha0_lc_per_vehicle": lc_zero, "mobil0_lc_per_vehicle": lc_mobil,
            "lc_share": lc_zero / lc_mobil if lc_mobil > 0 else math.nan,
            "alpha_star": star, "p_star": p_best, "p_star_mps": p_row.get("p_star_speed_mps", math.nan),
            "alpha_star_minus_p_star_mps": star_gap[0], "alpha_star_minus_p_star_low": star_gap[1],
            "alpha_star_minus_p_star_high": star_gap[2],
            "near_p_star": bool(star_gap[0] >= -NEAR_P_STAR_MPS) if math.isfinite(star_gap[0]) else None,
            "ahead_of_p_star": bool(star_gap[1] > 0) if math.isfinite(star_gap[1]) else None,
        })  # fmt: skip
    return pd.DataFrame(rows, columns=None if rows else ["lanes", "t_up_s", "passes"])


def lane_change_columns(alpha_table: pd.DataFrame, runs: pd.DataFrame, alphas: Sequence[float]) -> pd.DataFrame:
    """alpha_table with lc_per_vehicle_alpha<A>: each alpha's lane changes per vehicle, the mean over its models
    (each pooled over its evaluations), and alpha*'s as alpha_star_lc_per_vehicle."""
    from coopsumo.validation import number_name

    out = alpha_table.copy()
    dqn = policy_rows(runs, "dqn")
    dqn = dqn[dqn["status"] == "ok"]
    lc = dqn.groupby(["lanes", "t_up_s", "alpha"])["lane_changes_per_vehicle"].mean()
    for a in alphas:
        out[f"lc_per_vehicle_alpha{number_name(a)}"] = [
            float(lc.get((int(r.lanes), float(r.t_up_s), float(a)), math.nan)) for r in out.itertuples()]
    out["alpha_star_lc_per_vehicle"] = [
        float(lc.get((int(r.lanes), float(r.t_up_s), float(r.alpha_star)), math.nan))
        if math.isfinite(r.alpha_star) else math.nan for r in out.itertuples()]  # fmt: skip
    return out


# -- the paper's two trends --------------------------------------------------------------------------------------
def models_to_decide(coef: float, low: float, high: float, n_models: int, level: float = LEVEL) -> int | None:
    """About how many models per condition an interval at `level` needs to exclude 0, if the slope and the spread
    between models stay as measured: the interval's half-width shrinks as 1/sqrt(models). None when it already
    excludes 0, or when the slope is 0 (no number of models would)."""
    if not all(math.isfinite(x) for x in (coef, low, high)) or n_models < 1:
        return None
    if low > 0 or high < 0:
        return None
    if coef == 0:
        return None
    half = (high - low) / 2
    return max(int(math.ceil(n_models * (half / abs(coef)) ** 2)), n_models + 1)


def trend_rows(table: pd.DataFrame, boots: dict[tuple[int, float], np.ndarray], n_models: int) -> dict[str, Any]:
    """The plane alpha* = b0 + b1 T_up + b2 lanes over the conditions of `table` with an alpha* (those that pass the
    gate), its bootstrap over models (scenario2_measures.plane_bootstrap: a 90% interval) and, per slope, about
    how many models per condition would decide it. {"error": why} when no plane can be fitted."""
    solved = table[np.isfinite(table["alpha_star"].astype(float))]
    try:
        fit = fit_plane(solved["t_up_s"], solved["lanes"], solved["alpha_star"])
    except PlaneFitError as err:
        return {"error": str(err), "n": len(solved)}
    boot = plane_bootstrap(solved, boots)
    out: dict[str, Any] = {"b0": fit.b0, "b1": fit.b1, "b2": fit.b2, "r2": fit.r2, "n": fit.n, "bootstrap": boot}
    for name in ("b1", "b2"):
        low, high = boot.get(f"{name}_p05", math.nan), boot.get(f"{name}_p95", math.nan)
        out[f"{name}_models_to_decide"] = models_to_decide(getattr(fit, name), low, high, n_models)
    return out


# -- one network for every alpha against per-alpha models ------------------------------------------------------------
def check_table(runs: pd.DataFrame, alphas: Sequence[float], metric: str) -> pd.DataFrame:
    """Per condition and alpha: the alpha-conditioned networks' mean speed over models against the per-alpha models'
    (policy PER_ALPHA) spread, min to max over models; within: the networks' mean lies in it. Lane changes per
    vehicle of both beside."""
    ok = runs[runs["status"] == "ok"]
    rows = []
    for (lanes, t_up), group in ok.groupby(CONDITION, sort=True):
        for a in alphas:
            cond = group[(group["policy"] == "dqn") & np.isclose(group["alpha"], a)]
            each = group[(group["policy"] == PER_ALPHA) & np.isclose(group["alpha"], a)]
            if cond.empty or each.empty:
                continue
            mean, lo, hi = _mean(cond[metric]), float(each[metric].min()), float(each[metric].max())
            rows.append({"lanes": int(lanes), "t_up_s": float(t_up), "alpha": float(a),
                         "conditioned_mps": mean, "conditioned_models": len(cond),
                         "per_alpha_mps": _mean(each[metric]), "per_alpha_min_mps": lo, "per_alpha_max_mps": hi,
                         "per_alpha_models": len(each), "difference_mps": mean - _mean(each[metric]),
                         "within": bool(lo <= mean <= hi) if math.isfinite(mean) else None,
                         "conditioned_lc_per_vehicle": _mean(cond["lane_changes_per_vehicle"]),
                         "per_alpha_lc_per_vehicle": _mean(each["lane_changes_per_vehicle"])})  # fmt: skip
    return pd.DataFrame(rows, columns=None if rows else ["lanes", "t_up_s", "alpha", "within"])


# -- what it costs ----------------------------------------------------------------------------------------------
def _line(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Least-squares a + b x (b = 0 with one distinct x)."""
    if len(set(x.tolist())) < 2:
        return float(np.mean(y)), 0.0
    b, a = np.polyfit(x, y, 1)
    return float(a), float(b)


def step_costs(runs: pd.DataFrame, evals: pd.DataFrame, train_steps: int, eval_steps: int) -> dict[str, Any]:
    """Measured core-seconds per step: a training's (the cells that trained their model in this sweep, not resumed:
    their CPU time, children included, less their evaluations' wall time; a model trained in a group before the
    cells, its share of the group's CPU time), fitted a + b lanes; an evaluation run's
    (its wall time, one process), fitted a + b inflow (veh/h), for models and for the policies that need no
    training apart. Empty parts where nothing was measured."""
    out: dict[str, Any] = {}
    models = runs[runs["policy"].isin(["dqn", PER_ALPHA]) & (runs["status"] == "ok")]
    trained = models[models["resumed_from_step"].isna()] if "resumed_from_step" in models else models.iloc[0:0]
    if "train_group_cpu_s" in models:  # a model of a group: trained before the cells, its share of the group known;
        grouped = pd.to_numeric(models["train_group_cpu_s"], errors="coerce").notna()  # once per training
        trained = models[models.index.isin(trained.index) | (grouped & ~models["train_dir"].duplicated())]
    if len(trained) and "cell_cpu_s" in trained:
        per_eval = evals[evals["policy"].isin(["dqn", PER_ALPHA])].groupby("key")["wall_seconds"].sum()
        cpu = pd.to_numeric(trained["cell_cpu_s"], errors="coerce").to_numpy(float)
        spent = cpu - trained["key"].map(per_eval).fillna(0.0).to_numpy(float)
        if "train_group_cpu_s" in trained:  # trained in a group before its cell: the model's share of the group
            group = pd.to_numeric(trained["train_group_cpu_s"], errors="coerce").to_numpy(float)
            spent = np.where(np.isfinite(group), group, spent)
        keep = np.isfinite(spent) & (spent > 0)
        if keep.any():
            lanes = trained["lanes"].to_numpy(float)[keep]
            a, b = _line(lanes, spent[keep] / train_steps)
            out.update(train_a=a, train_b_per_lane=b, trainings_measured=int(keep.sum()),
                       train_core_s_by_lanes={int(n): float(np.mean(spent[keep][lanes == n])) for n in set(lanes)})
    for part, policies in (("model", ["dqn", PER_ALPHA]), ("classical", list(CLASSICAL))):
        rows = evals[evals["policy"].isin(policies)].dropna(subset=["wall_seconds"])
        if len(rows):
            a, b = _line(3600.0 / rows["t_up_s"].to_numpy(float), rows["wall_seconds"].to_numpy(float) / eval_steps)
            out.update({f"{part}_eval_a": a, f"{part}_eval_b_per_veh_h": b, f"{part}_evals_measured": len(rows)})
    return out


def core_hours(costs: dict[str, Any], profile: Profile) -> dict[str, float]:
    """The core-hours `profile` would take at the measured step costs: its trainings (lane networks and per-alpha
    models, at their lane count's training cost per step) and its evaluation runs (each at its condition's inflow);
    an evaluation part not measured takes the other's cost. Empty without a measured training cost."""
    if "train_a" not in costs or not ("model_eval_a" in costs or "classical_eval_a" in costs):
        return {}
    def fit(part: str, other: str) -> tuple[float, float]:
        name = part if f"{part}_eval_a" in costs else other
        return float(costs[f"{name}_eval_a"]), float(costs[f"{name}_eval_b_per_veh_h"])

    model, classical = fit("model", "classical"), fit("classical", "model")
    train = sum(profile.train_steps * max(costs["train_a"] + costs["train_b_per_lane"] * n, 0.0)
                * len(profile.seeds) * profile.trainings_per_lane_seed() for n in profile.lanes)  # fmt: skip
    per_condition_models = (len(profile.alphas) + len(profile.check_alphas)) * len(profile.seeds)
    per_condition_runs = (len(profile.mobil_ps) * ("mobil" in profile.policies)
                          + sum(p in profile.policies for p in ("keep", "greedy")))  # fmt: skip
    evaluation = 0.0
    for _, t_up, _ in profile.conditions():
        q = 3600.0 / t_up
        runs_s = profile.eval_steps * len(profile.eval_seeds)
        evaluation += per_condition_models * runs_s * max(model[0] + model[1] * q, 0.0)
        evaluation += per_condition_runs * runs_s * max(classical[0] + classical[1] * q, 0.0)
    return {"training_core_hours": train / 3600.0, "evaluation_core_hours": evaluation / 3600.0,
            "core_hours": (train + evaluation) / 3600.0, "trainings": float(profile.n_trainings()),
            "cells": float(profile.n_cells())}  # fmt: skip
