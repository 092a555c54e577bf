"""The protocol's thrashing measure through the accident: per model, its lane changes made in a queue (below
plan.QUEUE_MPS) per vehicle that departed, as scenario I counts them (study.accident_measures); per learner and demand
their median and range over models and how many models thrash (issue 78: a model under THRASHING is calm).

A protocol study run before the measure existed has no such column in its runs.csv: its values read "n/a".
"""

from __future__ import annotations

import math
from typing import Any

import pandas as pd

from coopsumo.report.markdown import md_table
from coopsumo.studies.protocol.plan import BASELINES, QUEUE_MPS

MEASURE = "queue_lane_changes_per_vehicle"
THRASHING = 0.5
"""queue lane changes per vehicle from which a model thrashes (issue 78: calm models make fewer)"""
NA = "n/a"


def thrashing_rows(models: pd.DataFrame, variants: list[str]) -> list[dict[str, Any]]:
    """Per demand and learner (alpha 0, through the accident): how many models, the median, lowest and highest of
    their queue lane changes per vehicle (each model's mean over its evaluation seeds; NaN where no run recorded
    it), how many of the models that recorded it thrash, and each baseline's value."""
    frame = models if MEASURE in models else models.assign(**{MEASURE: math.nan})
    acc = frame[(frame["status"] == "ok") & (frame["alpha"] == 0) & (frame["scenario"] == "accident")]
    rows = []
    for t_up, cond in acc.groupby("t_up", sort=False):
        base = {b: _first(cond[cond["variant"] == b][MEASURE]) for b in BASELINES}
        for variant in variants:
            mine = cond[cond["variant"] == variant]
            if mine.empty:
                continue
            vals = mine[MEASURE].dropna().astype(float)
            rows.append({"t_up": float(t_up), "variant": variant, "models": len(mine), "measured": len(vals),
                         "median": float(vals.median()) if len(vals) else math.nan,
                         "low": float(vals.min()) if len(vals) else math.nan,
                         "high": float(vals.max()) if len(vals) else math.nan,
                         "thrashing": int((vals >= THRASHING).sum()), **base})  # fmt: skip
    return rows


def thrashing_lines(models: pd.DataFrame, profile: Any) -> list[str]:
    """The accident section's thrashing table (models: protocol report.per_model's table)."""
    rows = thrashing_rows(models, list(profile.variants))
    if not rows:
        return []
    head = ["T_up (s)", "learner", "models", "median [range]", f"thrashing (>= {THRASHING:g})"]
    head += [f"`{b}`" for b in BASELINES]
    lines = ["", f"### Thrashing: lane changes in the queue (below {QUEUE_MPS:g} m/s) per vehicle", "",
             "Through the accident, per model: the lane changes it made while below "
             f"{QUEUE_MPS:g} m/s per vehicle that departed (scenario I's measure, counted on the same trajectories "
             "as total time spent; a model's value is its mean over its evaluation seeds); the median and range over "
             f"the models, and how many thrash ({THRASHING:g} or more; issue 78 calls a model under {THRASHING:g} "
             "calm). The baselines' values on the same seeds beside them.", ""]  # fmt: skip
    body = []
    for r in rows:
        spread = NA if not r["measured"] else f"{r['median']:.2f} [{r['low']:.2f}, {r['high']:.2f}]"
        count = NA if not r["measured"] else f"{r['thrashing']} of {r['measured']}"
        cells = [f"{r['t_up']:g}", f"`{r['variant']}`", str(r["models"]), spread, count]
        cells += [NA if math.isnan(r[b]) else f"{r[b]:.2f}" for b in BASELINES]
        body.append(cells)
    return lines + md_table(head, body).split("\n")


def _first(values: pd.Series) -> float:
    """A baseline's value (one row per demand after report.per_model), NaN when it has none."""
    values = values.dropna()
    return float(values.iloc[0]) if len(values) else math.nan
