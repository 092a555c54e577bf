"""The report of `coopsumo adaptive` (adaptive.md): alpha=adaptive against the best fixed alpha and alpha 0 on scenario
II's conditions, paired by seed, and which rule was driven."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd

from coopsumo.studies.followups.robustness import paired_interval


def fitted_points(path: Path) -> list[Any] | None:
    """The points of the rule `adaptive-fit` wrote at path; None when there is none, or it is not such a rule (not
    JSON, cut short, edited): the report then says the rule driven is not the one fitted there, instead of failing."""
    try:
        points = json.loads(path.read_text())["points"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return points if isinstance(points, list) else None


def report(root: Path, runs: pd.DataFrame, star: pd.DataFrame, adaptive: pd.DataFrame) -> str:
    """adaptive.md of a conditioned sweep in root: runs (its runs.csv, ok cells), star (alpha_star.csv indexed by
    lanes and T_up) and adaptive (one row per condition and seed driven at alpha=adaptive)."""
    from coopsumo.agents.adaptive import DEFAULT_RULE

    rule = {"points": [list(p) for p in DEFAULT_RULE.points], "source": DEFAULT_RULE.source}
    same = fitted_points(root / "adaptive_rule.json") == rule["points"]
    lines = [
        "# alpha=adaptive against fixed alphas on scenario II's conditions",
        "",
        "Made by `coopsumo adaptive`. The same alpha-conditioned model of each (condition, seed) "
        "is driven at every fixed alpha (the sweep's cells) and at `alpha=adaptive` on the same evaluation "
        "demand; differences are paired by seed: mean [90% t-interval]. alpha* is the best fixed alpha on "
        "these very seeds (an oracle chosen after the fact), and the rule was fitted on these conditions: "
        "this is an in-sample check that the rule picks the right alpha, not a test on unseen traffic "
        "(scenario I's accident is that).",
        "",
        f"Rule driven (DEFAULT_RULE, from {rule['source']}; {len(rule['points'])} points: lanes, mean loop "
        "occupancy %, alpha*): "
        + "; ".join(f"({n}, {o:g} %, {a:g})" for n, o, a in rule["points"])
        + (
            " (the rule `--fit` wrote in adaptive_rule.json)"
            if same
            else " (**not** the rule fitted on this folder: a test or an older rule)"
        ),
        "",
        "| lanes | T_up (s) | alpha* | adaptive's mean alpha | speed adaptive (m/s) | adaptive - alpha* (m/s) | "
        "adaptive - alpha 0 (m/s) | lane changes / veh adaptive, alpha* |",
        "|---|---|---|---|---|---|---|---|",
    ]
    wins = 0
    total = 0
    for (lanes, t_up), ad in adaptive.groupby(["lanes", "t_up_s"]):
        a_star = float(star.loc[(lanes, t_up), "alpha_star"])
        a = ad.set_index("seed")
        cells = []
        for i, alpha in enumerate((a_star, 0.0)):
            f = runs[(runs["lanes"] == lanes) & (runs["t_up_s"] == t_up) & (runs["alpha"] == alpha)].set_index("seed")
            seeds = a.index.intersection(f.index)
            mean, lo, hi = paired_interval((a.loc[seeds, "mean_speed_mps"] - f.loc[seeds, "mean_speed_mps"]).to_numpy())
            cells.append(f"{mean:+.2f} [{lo:+.2f}, {hi:+.2f}]")
            if i == 0:
                total += 1
                wins += int(lo > 0)
                lc_star = f.loc[seeds, "lane_changes_per_vehicle"].mean()
        lines.append(f"| {lanes} | {t_up:g} | {a_star:g} | {a['adaptive_alpha_mean'].mean():.2f} | "
                     f"{a['mean_speed_mps'].mean():.2f} | {cells[0]} | {cells[1]} | "
                     f"{a['lane_changes_per_vehicle'].mean():.2f}, {lc_star:.2f} |")  # fmt: skip
    lines += [
        "",
        f"Adaptive beats the best fixed alpha (interval above 0) in {wins} of {total} conditions. "
        f"Collisions {int(adaptive['collisions'].sum())}, teleports {int(adaptive['teleports'].sum())}.",
        "",
    ]
    return "\n".join(lines)
