"""A merged part's runs.csv rows judged as the runs they stand for: each successful cell's row against the runs of
its configuration (their departures, arrivals and lane changes, the rules scenario I applies to a run folder and a
rerun to a cell record: run_checks.together_problem), and the rows of one training against each other (issue 82,
probe 14, F2: a loop flow, vehicles on the road or a throughput its departures and arrivals cannot give, and two sets
of training columns for one training, were merged)."""

from __future__ import annotations

import math
from typing import Any

import pandas as pd

from coopsumo.studies.engine.records import cell_runs
from coopsumo.studies.engine.run_checks import together_problem
from coopsumo.studies.scenario2.measures import TRAIN_COLUMNS


def _finite(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def rows_problem(specs: list[dict[str, Any]], runs: pd.DataFrame) -> str | None:
    """Why a successful row of a part's runs.csv cannot be its cell's runs pooled (records.pool_summaries: counts
    and seconds summed over its evaluations, the rest averaged; run_checks.together_problem on them), or why two
    rows of one training (train_dir) hold other training columns, or why a row says ok beside an error (a cell record
    saying both is rerun), as a phrase after "<part>'s", or None."""
    planned = {s["key"]: cell_runs(s["config"]) for s in specs}
    trained: dict[str, dict[str, Any]] = {}
    for row in runs.to_dict("records"):
        error = row.get("error")
        if row.get("status") == "ok" and isinstance(error, str) and error.strip():  # probe 17, TR3: merged, exit 0
            return f"runs.csv row {row['key']} has status ok beside an error ({error.strip()[:40]!r}): edited?"
        if row.get("status") != "ok" or (configs := planned.get(row["key"])) is None:
            continue
        num = {k: float(v) for k, v in row.items() if _finite(v)}
        travel = row.get("mean_travel_time_s")
        if problem := together_problem(num, float(travel) if _finite(travel) else None, configs[0], len(configs)):
            return f"runs.csv row {row['key']} {problem.replace('has summary.json', 'has', 1)}"
        if isinstance(folder := row.get("train_dir"), str) and folder:
            first = trained.setdefault(folder, row)
            for column in TRAIN_COLUMNS:
                a, b = row.get(column), first.get(column)
                if not (a == b or (pd.isna(a) and pd.isna(b))):
                    return (f"runs.csv row {row['key']} has {column} = {a:g}, but row {first['key']} of the same "
                            f"training {folder} has {b:g}: edited?")  # fmt: skip
    return None
