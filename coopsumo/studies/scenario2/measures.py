"""Scenario II's measures, pure functions on tables of runs (no SUMO, no report text).

The table of runs (one row per cell, from the cells' records), and on it:
alpha* per condition (best mean speed over models, ties to the smaller alpha), its win share over models, a
bootstrap over models, the separation of alpha* from its grid neighbours (the noise floor), the best MOBIL
politeness p*, and the least-squares plane alpha* = b0 + b1 T_up + b2 lanes with its bootstrap.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from coopsumo.studies.engine.stats import interval, resample, resampled_means
from coopsumo.studies.scenario2.plan import CLASSICAL, CRITERION
from coopsumo.validation import number_name


def speed_matrix(group: pd.DataFrame, alphas: Sequence[float], seeds: Sequence[int],
                 metric: str = CRITERION, by: str = "alpha") -> np.ndarray:  # fmt: skip
    """metric[alpha, seed] of one condition's successful cells; NaN where missing or failed.

    `by` names the column of the rows' parameter: "alpha", or "p" for MOBIL cells (then alphas are p values).
    """
    ok = group[group["status"] == "ok"]
    table = ok.pivot_table(index=by, columns="seed", values=metric, aggfunc="mean")
    return table.reindex(index=list(alphas), columns=list(seeds)).to_numpy(float)


def _nanmean_rows(values: np.ndarray) -> np.ndarray:
    """Mean over the last axis ignoring NaN; NaN where a row has no value (no warning)."""
    finite = np.isfinite(values)
    n = finite.sum(axis=-1)
    total = np.where(finite, values, 0.0).sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, total / np.maximum(n, 1), np.nan)


def best_index(means: np.ndarray) -> int:
    """Index of the largest finite mean; ties go to the smallest alpha (alphas sorted ascending). -1 if none."""
    finite = np.isfinite(means)
    if not finite.any():
        return -1
    return int(np.argmax(np.where(finite, means, -np.inf)))


def win_shares(speeds: np.ndarray) -> np.ndarray:
    """Per alpha, the share of seeds on which it gives the best speed (ties share the win equally).

    speeds[alpha, seed]; seeds with no finite value are left out.
    """
    wins = np.zeros(speeds.shape[0])
    seeds = 0
    for col in speeds.T:
        finite = np.isfinite(col)
        if not finite.any():
            continue
        best = np.max(col[finite])
        winners = finite & (col == best)
        wins[winners] += 1.0 / winners.sum()
        seeds += 1
    return wins / seeds if seeds else np.full(speeds.shape[0], np.nan)


def bootstrap_best(speeds: np.ndarray, n_boot: int, rng: np.random.Generator) -> np.ndarray:
    """Index of the best alpha in each of n_boot resamples of the seeds (with replacement, paired over alphas)."""
    means = _nanmean_rows(speeds[:, resample(rng, speeds.shape[1], n_boot)])  # alpha x boot (of alpha x boot x seed)
    finite = np.isfinite(means)
    best = np.argmax(np.where(finite, means, -np.inf), axis=0)
    return np.where(finite.any(axis=0), best, -1)


def neighbour_separation(speeds: np.ndarray, best: int, n_boot: int, rng: np.random.Generator,
                         level: float = 0.9) -> tuple[bool | None, bool | None]:  # fmt: skip
    """Is alpha* (row `best` of speeds[alpha, seed]) distinguishable from its grid neighbours?

    For the next smaller and the next larger alpha: True when the lower end of the `level` two-sided bootstrap
    interval of the seed-paired mean difference v(alpha*) - v(neighbour) lies above 0 (seeds resampled with
    replacement, n_boot times); False otherwise; None where alpha* has no neighbour on that side (or no pair).
    """
    out: list[bool | None] = []
    for nb in (best - 1, best + 1):
        diff = speeds[best] - speeds[nb] if best >= 0 and 0 <= nb < speeds.shape[0] else np.zeros(0)  # no neighbour
        diff = diff[np.isfinite(diff)]
        means = resampled_means(diff, max(n_boot, 1), rng) if len(diff) else None  # no pair: no draw
        out.append(None if means is None else interval(means, (1 - level) / 2)[0] > 0)
    return out[0], out[1]


def alpha_star_table(runs: pd.DataFrame, alphas: Sequence[float] | None = None, seeds: Sequence[int] | None = None,
                     n_boot: int = 1000, boot_seed: int = 0, metric: str = CRITERION
                     ) -> tuple[pd.DataFrame, dict[tuple[int, float], np.ndarray]]:  # fmt: skip
    """alpha* per condition with its win share and bootstrap support, plus the mean speed of every alpha.

    Returns the table (one row per (lanes, t_up_s)) and, per condition, the alpha* of each bootstrap
    replicate (NaN where a replicate had no data), for the plane's bootstrap.
    """
    alphas = sorted(set(runs["alpha"])) if alphas is None else sorted(alphas)
    seeds = sorted(set(runs["seed"])) if seeds is None else list(seeds)
    rng = np.random.default_rng(boot_seed)
    sep_rng = np.random.default_rng(boot_seed + 1)  # its own stream: the bootstrap above stays as it was
    rows = []
    boots: dict[tuple[int, float], np.ndarray] = {}
    alpha_arr = np.asarray(alphas, float)
    for (lanes, t_up), group in runs.groupby(["lanes", "t_up_s"], sort=True):
        speeds = speed_matrix(group, alphas, seeds, metric)
        means = _nanmean_rows(speeds)
        n_ok = np.isfinite(speeds).sum(axis=1)
        best = best_index(means)
        shares = win_shares(speeds)
        boot = bootstrap_best(speeds, n_boot, rng) if n_boot > 0 else np.zeros(0, int)
        boot_alpha = np.where(boot >= 0, alpha_arr[np.clip(boot, 0, None)], np.nan)
        boots[(int(lanes), float(t_up))] = boot_alpha
        p05, p95 = interval(boot_alpha[np.isfinite(boot_alpha)], 0.05)
        finite_means = means[np.isfinite(means)]
        var_of_mean = np.array([np.var(r[np.isfinite(r)], ddof=1) / np.isfinite(r).sum()
                                if np.isfinite(r).sum() > 1 else np.nan for r in speeds])  # fmt: skip
        se = float(np.sqrt(var_of_mean[np.isfinite(var_of_mean)].mean())) if np.isfinite(var_of_mean).any() else np.nan
        load = group["load"].iloc[0] if "load" in group else np.nan
        below, above = neighbour_separation(speeds, best, n_boot, sep_rng)
        sides = [x for x in (below, above) if x is not None]
        row: dict[str, Any] = {
            "lanes": int(lanes), "t_up_s": float(t_up), "load": load, "inflow_veh_h": round(3600.0 / float(t_up), 1),
            "alpha_star": float(alpha_arr[best]) if best >= 0 else np.nan,
            "alpha_star_speed_mps": float(means[best]) if best >= 0 else np.nan,
            "win_share": float(shares[best]) if best >= 0 else np.nan,
            "boot_support": float(np.mean(boot == best)) if best >= 0 and n_boot > 0 else np.nan,
            "boot_alpha_p05": p05, "boot_alpha_p95": p95,
            "spread_mps": float(finite_means.max() - finite_means.min()) if finite_means.size else np.nan,
            "seed_se_mps": se,
            "separated_below": below,
            "separated_above": above,
            "distinct": bool(sides) and all(sides),
            "seeds_min": int(n_ok.min()) if len(n_ok) else 0,
            "cells_failed": int((group["status"] != "ok").sum()),
        }  # fmt: skip
        for a, m in zip(alphas, means, strict=True):
            row[f"speed_mps_alpha{number_name(a)}"] = float(m)
        for a, s in zip(alphas, shares, strict=True):
            row[f"win_share_alpha{number_name(a)}"] = float(s)
        rows.append(row)
    empty = ["lanes", "t_up_s", "load", "inflow_veh_h", "alpha_star"]
    return pd.DataFrame(rows, columns=None if rows else empty), boots


def policy_rows(runs: pd.DataFrame, policy: str) -> pd.DataFrame:
    """The rows of one policy ("dqn" or "mobil"); a table without a policy column holds DQN rows only."""
    if "policy" not in runs:
        return runs if policy == "dqn" else runs.iloc[0:0]
    return runs[runs["policy"] == policy]


def mobil_p_star_table(runs: pd.DataFrame, ps: Sequence[float] | None = None, seeds: Sequence[int] | None = None,
                       metric: str = CRITERION) -> pd.DataFrame:  # fmt: skip
    """p* per condition: the MOBIL politeness with the best mean speed over seeds (ties go to the smaller p),
    its win share over seeds, and the mean speed of every p. `runs` holds MOBIL rows (column p)."""
    ps = sorted(set(runs["p"])) if ps is None else sorted(ps)
    seeds = sorted(set(runs["seed"])) if seeds is None else list(seeds)
    rows = []
    for (lanes, t_up), group in runs.groupby(["lanes", "t_up_s"], sort=True):
        speeds = speed_matrix(group, ps, seeds, metric, by="p")
        means = _nanmean_rows(speeds)
        best = best_index(means)
        shares = win_shares(speeds)
        n_ok = np.isfinite(speeds).sum(axis=1)
        row: dict[str, Any] = {
            "lanes": int(lanes), "t_up_s": float(t_up), "load": group["load"].iloc[0],
            "inflow_veh_h": round(3600.0 / float(t_up), 1),
            "p_star": float(ps[best]) if best >= 0 else np.nan,
            "p_star_speed_mps": float(means[best]) if best >= 0 else np.nan,
            "win_share": float(shares[best]) if best >= 0 else np.nan,
            "seeds_min": int(n_ok.min()) if len(n_ok) else 0,
            "cells_failed": int((group["status"] != "ok").sum()),
        }  # fmt: skip
        for p, m in zip(ps, means, strict=True):
            row[f"speed_mps_p{number_name(p)}"] = float(m)
        rows.append(row)
    empty = ["lanes", "t_up_s", "load", "inflow_veh_h", "p_star", "p_star_speed_mps", "win_share"]
    return pd.DataFrame(rows, columns=None if rows else empty)


class PlaneFitError(ValueError):
    """The plane alpha* = b0 + b1 T_up + b2 lanes cannot be fitted to these conditions."""


@dataclass(frozen=True)
class PlaneFit:
    b0: float
    b1: float
    """per second of T_up"""
    b2: float
    """per lane"""
    r2: float
    """coefficient of determination (NaN when alpha* is the same everywhere)"""
    n: int
    """conditions used"""


def fit_plane(t_up_s: ArrayLike, lanes: ArrayLike, alpha_star: ArrayLike) -> PlaneFit:
    """Least-squares plane alpha* = b0 + b1 T_up + b2 lanes over the conditions with a finite alpha*.

    Raises PlaneFitError with fewer than 3 distinct conditions or when T_up and lanes do not span a
    plane (e.g. a single lane count).
    """
    t, n, a = (np.asarray(x, float) for x in (t_up_s, lanes, alpha_star))
    keep = np.isfinite(t) & np.isfinite(n) & np.isfinite(a)
    t, n, a = t[keep], n[keep], a[keep]
    distinct = len(set(zip(t.tolist(), n.tolist(), strict=True)))
    if distinct < 3:
        raise PlaneFitError(f"a plane needs at least 3 distinct conditions (T_up, lanes), got {distinct}")
    design = np.column_stack([np.ones_like(t), t, n])
    if np.linalg.matrix_rank(design) < 3:
        varying = "T_up" if len(set(t.tolist())) > 1 else "lanes" if len(set(n.tolist())) > 1 else "nothing"
        raise PlaneFitError(f"the conditions lie on a line (only {varying} varies): T_up and lanes need "
                            "at least 3 conditions not on one line")  # fmt: skip
    coef, *_ = np.linalg.lstsq(design, a, rcond=None)
    resid = a - design @ coef
    ss_tot = float(((a - a.mean()) ** 2).sum())
    r2 = 1.0 - float((resid**2).sum()) / ss_tot if ss_tot > 0 else float("nan")
    return PlaneFit(float(coef[0]), float(coef[1]), float(coef[2]), r2, int(len(a)))


def plane_bootstrap(table: pd.DataFrame, boots: dict[tuple[int, float], np.ndarray]) -> dict[str, float]:
    """Refit the plane on each bootstrap replicate of alpha* (seeds resampled per condition).

    Returns the share of replicates with b1 < 0 and with b2 < 0 and 90% intervals of b1 and b2.
    """
    keys = [(int(r.lanes), float(r.t_up_s)) for r in table.itertuples()]
    if not keys:
        return {}
    reps = np.vstack([boots[k] for k in keys])  # condition x replicate
    t = np.array([k[1] for k in keys])
    n = np.array([k[0] for k in keys], float)
    b1, b2 = [], []
    for col in reps.T:
        try:
            fit = fit_plane(t, n, col)
        except PlaneFitError:
            continue
        b1.append(fit.b1)
        b2.append(fit.b2)
    if not b1:
        return {}
    a1, a2 = np.array(b1), np.array(b2)
    (b1_p05, b1_p95), (b2_p05, b2_p95) = interval(a1, 0.05), interval(a2, 0.05)
    return {"replicates": len(a1), "b1_negative_share": float(np.mean(a1 < 0)),
            "b2_negative_share": float(np.mean(a2 < 0)), "b1_p05": b1_p05, "b1_p95": b1_p95, "b2_p05": b2_p05,
            "b2_p95": b2_p95}  # fmt: skip


# -- the table of runs ------------------------------------------------------------------------------------------
METRIC_COLUMNS = (
    "steps", "sim_seconds", "departed", "arrived", "insertion_blocked", "insertion_pending_at_end",
    "collisions", "teleports", "lane_changes", "lane_changes_rejected", "lane_changes_per_vehicle",
    "mean_speed_mps", "mean_travel_time_s", "throughput_veh_per_h",
    "train_mean_speed_mps", "train_lane_changes", "train_collisions", "train_updates",
)  # fmt: skip
"""Deterministic columns of runs.csv (same seed -> same value on any backend)."""
TRAIN_COLUMNS = {
    "train_mean_speed_mps": "mean_speed_mps",
    "train_lane_changes": "lane_changes",
    "train_collisions": "collisions",
    "train_updates": "updates",
}
"""runs.csv columns taken from the training run's train_summary.json"""
COUNT_COLUMNS = frozenset(("steps", "departed", "arrived", "insertion_blocked", "insertion_pending_at_end",
                           "collisions", "teleports", "lane_changes", "lane_changes_rejected", "train_lane_changes",
                           "train_collisions", "train_updates"))  # fmt: skip
KEY_COLUMNS = ("key", "lanes", "t_up_s", "load", "alpha", "seed")
def runs_table(records: Sequence[dict[str, Any]]) -> pd.DataFrame:
    """One tidy row per cell: coordinates, status, error, every evaluation summary metric, bookkeeping.

    `policy` is "dqn" or "mobil"; `p` (MOBIL's politeness) is NaN for DQN rows, `alpha` NaN for MOBIL rows.
    """
    rows = []
    for r in records:
        row: dict[str, Any] = {k: r[k] for k in KEY_COLUMNS}
        row.update(policy=r.get("policy") or "dqn", p=r.get("p"), status=r["status"], error=r.get("error"))
        summary = r.get("summary") or {}
        train = r.get("train_summary") or {}
        for k in METRIC_COLUMNS:
            row[k] = train.get(TRAIN_COLUMNS[k]) if k in TRAIN_COLUMNS else summary.get(k)
        row.update({k: v for k, v in summary.items() if k not in row and k != "scenario"})
        row.update(train_wall_seconds=train.get("wall_seconds"), cell_wall_s=r.get("cell_wall_s"),
                   cell_cpu_s=r.get("cell_cpu_s"), train_group_cpu_s=r.get("train_group_cpu_s"),
                   resumed_from_step=r.get("resumed_from_step"), train_dir=r.get("train_dir"))  # fmt: skip
        rows.append(row)
    table = pd.DataFrame(rows)
    for k in METRIC_COLUMNS:
        table[k] = pd.to_numeric(table[k], errors="coerce").astype("Int64" if k in COUNT_COLUMNS else float)
    for k in ("alpha", "p"):
        table[k] = pd.to_numeric(table[k], errors="coerce").astype(float)
    table["resumed_from_step"] = pd.to_numeric(table["resumed_from_step"], errors="coerce").astype("Int64")
    return table


EVAL_COLUMNS = ("mean_speed_mps", "lane_changes_per_vehicle", "throughput_veh_per_h", "mean_travel_time_s",
                "collisions", "teleports", "loop_flow_veh_h_per_lane", "loop_occupancy_pct", "full_road_speed_mps",
                "full_road_from_s", "wall_seconds")
"""the columns of evals.csv besides the coordinates"""
EVAL_KEYS = ("key", "lanes", "t_up_s", "load", "policy", "alpha", "p", "seed", "eval_seed")
"""the coordinates of an evaluation run in evals.csv: its cell's and its evaluation seed"""


def evals_table(records: Sequence[dict[str, Any]]) -> pd.DataFrame:
    """evals.csv: one row per evaluation run of the finished cells (a DQN model's every evaluation seed, a MOBIL,
    keep or greedy cell's one run), with the cell's key and coordinates; `seed` is the training seed (NaN for the
    policies that need no training)."""
    rows = []
    for r in records:
        if r.get("status") != "ok":
            continue
        mobil = r.get("policy") in CLASSICAL
        runs = [r.get("summary") or {}] if mobil else r.get("eval_summaries") or []
        for summary in runs:
            row = {k: r.get(k) for k in ("key", "lanes", "t_up_s", "load", "policy", "alpha", "p")}
            row.update(seed=None if mobil else r.get("seed"), eval_seed=r.get("seed") if mobil else
                       summary.get("eval_seed"), **{k: summary.get(k) for k in EVAL_COLUMNS})  # fmt: skip
            rows.append(row)
    return pd.DataFrame(rows, columns=[*EVAL_KEYS, *EVAL_COLUMNS])


def withhold_incomplete(table: pd.DataFrame, star: str) -> pd.DataFrame:
    """`table` (alpha_star_table or mobil_p_star_table) with no winner (NaN, separation None) in a condition where a
    cell failed: it would rest on fewer seeds than asked for."""
    if table.empty or "cells_failed" not in table:
        return table
    bad = table["cells_failed"] > 0
    table = table.copy()
    for col in table.columns:
        if col.startswith(star) or col in ("win_share", "boot_support", "boot_alpha_p05", "boot_alpha_p95"):
            table.loc[bad, col] = np.nan
        elif col in ("separated_below", "separated_above"):
            table[col] = table[col].astype(object)
            table.loc[bad, col] = None
        elif col == "distinct":
            table.loc[bad, col] = False
    return table
