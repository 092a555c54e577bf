"""Claim (a)'s analysis plan (issue 78, step 2; docs/studies.md, "Claim (a): the analysis plan"), fixed before the
study of many models per alpha runs: does alpha 8 against alpha 0, of one learner, change total time spent, system
recovery or stop-and-go waves through the accident? Pure functions on scenario I's table of runs (runs.csv).

- The co-primary measures (CO_PRIMARY): alpha 8 minus alpha 0 at each demand, models paired by training seed and
  runs by evaluation seed; the mean over models of each model's mean over seeds, its 95% interval and two-sided
  p-value from the two-level bootstrap (models, then seeds within each model: engine/stats.hierarchical_replicates).
  A run that never recovers counts as its horizon (measures.censored: a lower bound).
- The family: every co-primary measure at every demand (3 x 3 = 9 comparisons), Holm's step-down correction at a
  family-wise FAMILY_ALPHA on the bootstrap p-values. "Decided": Holm rejects and at least MIN_MODELS models stand
  behind the difference; its direction is its sign (lower total time, earlier recovery, fewer waves: alpha 8 helps).
- The mechanism: a model thrashes at a demand when its queue lane changes per vehicle (lane changes made below
  5 m/s), averaged over its evaluation seeds, reach THRASHING_QLC (the learner protocol's threshold). Per demand,
  the share of thrashing models per alpha with Fisher's exact test (two-sided), Holm over the demands.
- The number of models: from the first PILOT_MODELS models per alpha (lowest training seeds), each comparison's
  power (a two-sided one-sample t-test of the model means at FAMILY_ALPHA / family size, Bonferroni: conservative
  beside Holm) for the measured mean and spread between models; the study runs the smallest n in
  [MIN_PLANNED, MAX_MODELS] at which some measure reaches POWER at two demands or more, else MAX_MODELS. The report
  gives, per comparison, the smallest effect the models run could detect with POWER.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from coopsumo.studies.engine.stats import bootstrap_p, hierarchical_replicates, interval
from coopsumo.studies.protocol.thrashing import THRASHING
from coopsumo.studies.scenario1.measures import BOOT_SEED, MIN_MODELS, N_BOOT, censored, model_table, paired_differences

CO_PRIMARY = ("tts_veh_h", "system_recovery_s", "waves")
"""the co-primary measures: total time spent (veh-h), system recovery (s after the accident's start), stop-and-go
waves (per run); lower is better on each"""
FAMILY_ALPHA = 0.05
"""Holm's family-wise error rate over CO_PRIMARY x the demands (and, separately, the mechanism's tests)"""
THRASHING_QLC = THRASHING
"""queue lane changes per vehicle from which on a model thrashes (the learner protocol's threshold; issue 78: calm
models, under 0.5, beat keep by 1.5-4.2 veh-h at T_up 2 and 1.5 s; thrashing ones lost by 3 to 48)"""
PILOT_MODELS = 10
POWER = 0.9
MIN_PLANNED, MAX_MODELS = 20, 40


def hierarchical_p(diff: np.ndarray) -> tuple[float, float, float, float]:
    """(mean, low, high, two-sided p) of a (models x seeds) table of paired differences: the two-level bootstrap's
    95% interval, and twice the smaller share of its replicates on either side of 0 (at most 1)."""
    point, values = hierarchical_replicates(diff, reps=N_BOOT, seed=BOOT_SEED)
    return point, *interval(values, 0.025), bootstrap_p(values) if values.size else math.nan  # NaN without data


def holm_adjusted(p_values: pd.Series) -> pd.Series:
    """Holm's adjusted p-values (reject where adjusted <= the family-wise rate), in p_values' order."""
    order = p_values.sort_values(kind="stable")
    m = len(order)
    adjusted = np.minimum(1.0, np.maximum.accumulate([(m - i) * p for i, p in enumerate(order.to_numpy(float))]))
    return pd.Series(adjusted, index=order.index).reindex(p_values.index)


def _value(frame: pd.DataFrame, measure: str) -> pd.Series:
    if measure == "system_recovery_s":
        return censored(frame[measure], frame["horizon_after_start_s"])
    return frame[measure].astype(float)


def comparisons(rows: pd.DataFrame, a: str, b: str) -> pd.DataFrame:
    """Every co-primary measure at every demand: a minus b (diff, lo, hi, p), the models behind it, for how many
    models a is lower (`lower`), the spread between the models' mean differences (`model_sd`), Holm's adjusted p
    over the whole family and the verdict ("helps", "hurts" for a against b, or "cannot decide")."""
    out = []
    for t_up in sorted(rows["t_up_s"].unique(), reverse=True):
        at = rows[rows["t_up_s"] == t_up]
        fa, fb = at[at["policy"] == a], at[at["policy"] == b]
        if fa.empty or fb.empty:
            continue
        for measure in CO_PRIMARY:
            diff = paired_differences(model_table(fa, _value(fa, measure)), model_table(fb, _value(fb, measure)))
            means = diff.mean(axis=1).dropna()
            mean, lo, hi, p = hierarchical_p(diff.to_numpy(dtype=float))
            out.append({"t_up_s": float(t_up), "measure": measure, "diff": mean, "lo": lo, "hi": hi, "p": p,
                        "models": len(means), "lower": int((means < 0).sum()),
                        "model_sd": float(means.std(ddof=1)) if len(means) > 1 else math.nan})  # fmt: skip
    table = pd.DataFrame(out, columns=["t_up_s", "measure", "diff", "lo", "hi", "p", "models", "lower", "model_sd"])
    table["p_holm"] = holm_adjusted(table["p"]) if len(table) else []
    decided = (table["p_holm"] <= FAMILY_ALPHA) & (table["models"] >= MIN_MODELS)
    table["verdict"] = np.where(decided, np.where(table["diff"] < 0, "helps", "hurts"), "cannot decide")
    return table


def thrashing(rows: pd.DataFrame, policy: str) -> pd.DataFrame:
    """Per demand and model of policy: its queue lane changes per vehicle and total time spent, each the mean over
    its evaluation seeds, and whether it thrashes (columns t_up_s, train_seed, qlc, tts_veh_h, thrashing)."""
    runs = rows[rows["policy"] == policy]
    means = runs.groupby(["t_up_s", "train_seed"], as_index=False)[["queue_lane_changes_per_vehicle", "tts_veh_h"]]
    table = means.mean().rename(columns={"queue_lane_changes_per_vehicle": "qlc"})
    table["thrashing"] = table["qlc"] >= THRASHING_QLC
    return table


def thrashing_tests(rows: pd.DataFrame, a: str, b: str) -> pd.DataFrame:
    """Per demand: the thrashing models of a and of b (counts and totals), Fisher's exact test of the two shares
    (two-sided) and Holm's adjusted p over the demands."""
    from scipy.stats import fisher_exact

    ta, tb = thrashing(rows, a), thrashing(rows, b)
    out = []
    for t_up in sorted(set(ta["t_up_s"]) & set(tb["t_up_s"]), reverse=True):
        xa, xb = ta[ta["t_up_s"] == t_up]["thrashing"], tb[tb["t_up_s"] == t_up]["thrashing"]
        ka, kb = int(xa.sum()), int(xb.sum())
        p = float(fisher_exact([[ka, len(xa) - ka], [kb, len(xb) - kb]])[1])
        out.append({"t_up_s": float(t_up), "thrash_a": ka, "models_a": len(xa), "thrash_b": kb, "models_b": len(xb),
                    "p": p})  # fmt: skip
    table = pd.DataFrame(out, columns=["t_up_s", "thrash_a", "models_a", "thrash_b", "models_b", "p"])
    table["p_holm"] = holm_adjusted(table["p"]) if len(table) else []
    return table


def power(effect: float, sd: float, n: int, level: float) -> float:
    """Power of a two-sided one-sample t-test of n model means at `level` when their mean is effect and their sd is
    sd (noncentral t); 0 when it cannot be said."""
    from scipy.stats import nct, t

    if n < 2 or not (math.isfinite(effect) and math.isfinite(sd)) or sd <= 0:
        return 0.0
    crit, shift = float(t.ppf(1 - level / 2, n - 1)), effect / sd * math.sqrt(n)
    return float(nct.sf(crit, n - 1, shift) + nct.cdf(-crit, n - 1, shift))


def models_for_power(effect: float, sd: float, level: float, target: float = POWER) -> int | None:
    """The fewest models (2 to MAX_MODELS) whose test reaches `target` power; None when MAX_MODELS do not."""
    return next((n for n in range(2, MAX_MODELS + 1) if power(effect, sd, n, level) >= target), None)


def detectable_effect(sd: float, n: int, level: float, target: float = POWER) -> float:
    """The smallest |mean difference| n models detect with `target` power at `level` (t approximation)."""
    from scipy.stats import t

    if n < 2 or not math.isfinite(sd):
        return math.nan
    return float((t.ppf(1 - level / 2, n - 1) + t.ppf(target, n - 1)) * sd / math.sqrt(n))


def pilot(rows: pd.DataFrame, a: str, b: str, models: int = PILOT_MODELS) -> pd.DataFrame:
    """comparisons() on the first `models` training seeds of each policy, with each comparison's models for POWER
    (`needed`, None beyond MAX_MODELS) at FAMILY_ALPHA / the family's size."""
    seeds = sorted(rows.loc[rows["policy"].isin([a, b]), "train_seed"].dropna().unique())[:models]
    table = comparisons(rows[rows["train_seed"].isin(seeds) | ~rows["policy"].isin([a, b])], a, b)
    level = FAMILY_ALPHA / max(len(table), 1)
    table["needed"] = [models_for_power(d, s, level) for d, s in zip(table["diff"], table["model_sd"], strict=True)]
    return table


def planned_models(pilot_table: pd.DataFrame) -> int:
    """The study's models per alpha: the smallest n in [MIN_PLANNED, MAX_MODELS] at which some measure's comparisons
    reach POWER at two demands or more (pilot's `needed`), else MAX_MODELS."""
    best = MAX_MODELS
    for _, group in pilot_table.groupby("measure"):
        needed = sorted(int(n) for n in group["needed"] if n is not None and not pd.isna(n))
        if len(needed) >= 2:
            best = min(best, max(needed[1], MIN_PLANNED))
    return best


def summary(rows: pd.DataFrame, a: str, b: str) -> dict[str, Any]:
    """Everything the plan reads: the comparisons, the mechanism's tests, the pilot and its planned models, and the
    smallest effect each comparison's models could detect."""
    table = comparisons(rows, a, b)
    level = FAMILY_ALPHA / max(len(table), 1)
    table["detectable"] = [detectable_effect(s, int(n), level) for s, n in zip(table["model_sd"], table["models"],
                                                                              strict=True)]  # fmt: skip
    first = pilot(rows, a, b)
    return {"comparisons": table, "thrashing": thrashing_tests(rows, a, b), "pilot": first,
            "planned_models": planned_models(first)}  # fmt: skip
