"""Claim (b)'s primary measure: how speed responds to alpha in each condition, and the paper's two trends on it.

Pure functions on the table of evaluations (evals.csv), no SUMO and no report text. The plan they implement is
fixed in docs/studies.md ("Claim (b): the response of speed to alpha"):

- a model's score in a condition is its full-road speed averaged over its evaluation seeds;
- a condition's response is the least-squares slope of those scores over x = log2(1 + alpha), alphas 0 to 8
  (RESPONSE_ALPHAS): m/s per doubling of 1 + alpha; negative when restraint costs speed;
- its interval is a stratified bootstrap over models: within each (lane count, alpha) the models are drawn with
  replacement, and a lane count's draw is shared by its loads, because one model drives every load of its lane
  count (the lane-network design);
- the paper's trends, on the slope: a plane slope = c0 + c_lanes lanes + c_load load over the conditions that pass
  the gate (load: inflow per lane as a share of 1,800 veh/h). The paper has alpha* rise with fewer lanes and with
  more inflow: restraint pays more there, so its slope is higher: c_lanes < 0 and c_load > 0;
- each trend's bootstrap p-value (two-sided), Holm's correction over the two at a family-wise 0.10; "holds" or
  "reversed" when the corrected test rejects, by the estimate's sign; else "cannot decide", with about how many
  models per lane count and alpha would decide it if the estimate and the spread stayed as measured.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from coopsumo.studies.engine.stats import bootstrap_p, interval, resample

RESPONSE_ALPHAS = (0.0, 0.25, 1.0, 2.0, 8.0)
"""the alphas the slope is fitted over: the paper's small values to 8; alpha 32 (where lane changes have all but
stopped) is left out, so that a study with or without it measures the same thing"""
LEVEL = 0.90
"""the two-sided level of every interval"""
FAMILY_ALPHA = 0.10
"""Holm's family-wise error rate over the two trends"""
PAPER_SIGNS = {"lanes": -1, "load": +1}
"""the sign of each trend's coefficient in the paper's direction (alpha* rises with fewer lanes, more inflow)"""
BOOT_SEED = 79
"""the response bootstrap's seed"""


def response_x(alpha: Any) -> np.ndarray:
    """The slope's abscissa: log2(1 + alpha)."""
    return np.log2(1.0 + np.asarray(alpha, float))


def model_scores(evals: pd.DataFrame, metric: str, alphas: Sequence[float] = RESPONSE_ALPHAS) -> pd.DataFrame:
    """One row per DQN model and condition: lanes, t_up_s, load, alpha, seed and its `metric` averaged over its
    evaluation seeds (column `score`), for the alphas given."""
    dqn = evals[(evals["policy"] == "dqn") & evals["alpha"].isin(list(alphas))]
    keys = ["lanes", "t_up_s", "load", "alpha", "seed"]
    out = dqn.groupby(keys, sort=True)[metric].mean().rename("score").reset_index()
    return out[np.isfinite(out["score"].astype(float))]


def slope(x: np.ndarray, y: np.ndarray) -> float:
    """Least-squares slope of y over x; NaN with fewer than two distinct x."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    sxx = float(((x - x.mean()) ** 2).sum())
    return float(((x - x.mean()) * (y - y.mean())).sum() / sxx) if sxx > 0 else math.nan


@dataclass(frozen=True)
class Responses:
    """Every condition's slope and its bootstrap replicates (conditions in `table`'s order)."""

    table: pd.DataFrame
    """lanes, t_up_s, load, models (per alpha, the fewest), slope_mps, slope_low, slope_high"""
    replicates: np.ndarray
    """slope per condition (rows) and bootstrap replicate (columns)"""


def condition_responses(scores: pd.DataFrame, reps: int, seed: int = BOOT_SEED) -> Responses:
    """The slope per condition and its stratified bootstrap over models (one draw per lane count and alpha, shared
    by the lane count's loads). A condition needs at least two alphas, each with a model at every load of its lane
    count; the models of an alpha are those with a score at every load."""
    rng = np.random.default_rng(seed)
    rows, replicates = [], []
    for lanes, group in scores.groupby("lanes", sort=True):
        conditions = sorted({(float(t), float(q)) for t, q in zip(group["t_up_s"], group["load"], strict=True)},
                            key=lambda c: c[1])  # fmt: skip
        wide = group.pivot_table(index=["alpha", "seed"], columns="t_up_s", values="score").dropna()
        wide = wide[[t for t, _ in conditions]]
        alphas = sorted(set(wide.index.get_level_values("alpha")))
        if len(alphas) < 2:
            continue
        x_parts, y_parts, boot_parts = [], [], []
        for a in alphas:
            block = wide.xs(a, level="alpha").to_numpy(float)  # models x loads
            x_parts.append(np.full(len(block), response_x(a)))
            y_parts.append(block)
            boot_parts.append(block[resample(rng, len(block), reps)])  # reps x models x loads
        x = np.concatenate(x_parts)
        weights = (x - x.mean()) / ((x - x.mean()) ** 2).sum()
        y = np.concatenate(y_parts)  # models x loads
        boot = np.concatenate(boot_parts, axis=1)  # reps x models x loads
        point = weights @ y
        rep = np.einsum("m,rml->lr", weights, boot)  # loads x reps
        models = min(len(b) for b in y_parts)
        for i, (t_up, load) in enumerate(conditions):
            low, high = interval(rep[i], (1 - LEVEL) / 2)
            rows.append({"lanes": int(lanes), "t_up_s": t_up, "load": load, "models": models,
                         "slope_mps": float(point[i]), "slope_low": low, "slope_high": high})  # fmt: skip
            replicates.append(rep[i])
    columns = ["lanes", "t_up_s", "load", "models", "slope_mps", "slope_low", "slope_high"]
    return Responses(pd.DataFrame(rows, columns=columns), np.array(replicates).reshape(len(rows), reps))


def _design(table: pd.DataFrame) -> np.ndarray:
    return np.column_stack([np.ones(len(table)), table["lanes"].to_numpy(float), table["load"].to_numpy(float)])


def holm(p_values: dict[str, float], family_alpha: float = FAMILY_ALPHA) -> dict[str, bool]:
    """Holm's step-down test: which hypotheses are rejected at the family-wise rate."""
    rejected, m = {}, len(p_values)
    for rank, (name, p) in enumerate(sorted(p_values.items(), key=lambda kv: kv[1])):
        if p > family_alpha / (m - rank):
            rejected.update({n: False for n in p_values if n not in rejected})
            break
        rejected[name] = True
    return rejected


def models_to_decide(coef: float, low: float, high: float, n_models: int) -> int | None:
    """About how many models per lane count and alpha a LEVEL interval needs to exclude 0, if the estimate and the
    spread stay as measured (the half-width shrinks as 1/sqrt(models)); None when it already does or coef is 0."""
    if not all(math.isfinite(v) for v in (coef, low, high)) or n_models < 1 or coef == 0 or low > 0 or high < 0:
        return None
    return max(int(math.ceil(n_models * ((high - low) / 2 / abs(coef)) ** 2)), n_models + 1)


def trends(responses: Responses, kept: set[tuple[int, float]]) -> dict[str, Any]:
    """The plane slope = c0 + c_lanes lanes + c_load load over the conditions in `kept` (lanes, T_up), with each
    trend's LEVEL interval, bootstrap p, Holm's decision and verdict; {"error": why} when no plane can be fitted."""
    table = responses.table
    chosen = np.array([(int(r.lanes), float(r.t_up_s)) in kept for r in table.itertuples()], bool)
    sub = table[chosen]
    design = _design(sub)
    if len(sub) < 4 or np.linalg.matrix_rank(design) < 3:
        return {"error": "the plane needs at least 4 conditions spanning two lane counts and two loads",
                "n": int(len(sub))}  # fmt: skip
    solve = np.linalg.pinv(design)
    point = solve @ sub["slope_mps"].to_numpy(float)
    boot = solve @ responses.replicates[chosen]  # 3 x reps
    resid = sub["slope_mps"].to_numpy(float) - design @ point
    ss = float(((sub["slope_mps"] - sub["slope_mps"].mean()) ** 2).sum())
    out: dict[str, Any] = {"n": int(len(sub)), "c0": float(point[0]), "r2": 1 - float((resid**2).sum()) / ss if ss
                           else math.nan, "models": int(sub["models"].min())}  # fmt: skip
    p_values = {}
    for i, name in ((1, "lanes"), (2, "load")):
        low, high = interval(boot[i], (1 - LEVEL) / 2)
        p_values[name] = bootstrap_p(boot[i])
        out[name] = {"coef": float(point[i]), "low": low, "high": high, "p": p_values[name],
                     "paper_sign": PAPER_SIGNS[name]}  # fmt: skip
    for name, rejected in holm(p_values).items():
        entry = out[name]
        entry["decided"] = rejected
        entry["verdict"] = ("holds" if np.sign(entry["coef"]) == entry["paper_sign"] else "reversed") if rejected \
            else "cannot decide"  # fmt: skip
        entry["models_to_decide"] = None if rejected else models_to_decide(entry["coef"], entry["low"],
                                                                           entry["high"], out["models"])  # fmt: skip
    return out
