"""alpha=adaptive against the best fixed alpha on scenario II's conditions, with the same conditioned models.

    .venv/bin/python experiments/adaptive_scenario2.py results/scenario2_conditioned --fit
    .venv/bin/python experiments/adaptive_scenario2.py results/scenario2_conditioned

--fit: the adaptive rule's points from a finished `scenario2 --conditioned` folder: per condition, the mean loop
occupancy its evaluations measured (runs.csv, all alphas and seeds) and its alpha* (alpha_star.csv). Writes
ROOT/adaptive_rule.json and prints the AdaptiveRule to paste into coopsumo/agents/adaptive.py (DEFAULT_RULE).

Without --fit: every (condition, seed) model of the folder is driven once more with dqn:PATH,alpha=adaptive on its
evaluation's condition, seed and steps (train/<key>/eval_adaptive/, reused when finished), and ROOT/adaptive.md
compares it, paired by seed, with the best fixed alpha (alpha*, chosen on these same seeds: an oracle the adaptive
rule has to match) and with alpha 0.
"""

from __future__ import annotations

import json
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Any

import pandas as pd

from coopsumo.runio import Parser, UsageError, run_cli, write_json
from coopsumo.studies.robustness import paired_interval
from coopsumo.studies.scenario2_plan import conditioned_key


def fit(root: Path) -> list[tuple[int, float, float]]:
    """(lanes, mean loop occupancy %, alpha*) of every condition with an alpha*."""
    runs = pd.read_csv(root / "runs.csv")
    star = pd.read_csv(root / "alpha_star.csv")
    occ = runs[runs["status"] == "ok"].groupby(["lanes", "t_up_s"])["loop_occupancy_pct"].mean()
    rows = []
    for r in star.itertuples():
        if pd.notna(r.alpha_star) and (r.lanes, r.t_up_s) in occ.index:
            rows.append((int(r.lanes), round(float(occ[(r.lanes, r.t_up_s)]), 3), float(r.alpha_star)))
    return rows


def _drive(job: dict[str, Any]) -> dict[str, Any]:
    from coopsumo.config import OutputConfig
    from coopsumo.studies.runner import reusable_run, simulate_into

    out = Path(job["out"])
    if reusable_run(out, job["config"], OutputConfig(), prog="adaptive_scenario2"):
        return json.loads((out / "summary.json").read_text())
    return simulate_into(job["config"], out, out.parent.name)


def compare(root: Path, workers: int) -> pd.DataFrame:
    """Drive every (condition, seed) model at alpha=adaptive; one row per (condition, seed)."""
    from coopsumo.config import sim_config_from_dict, to_dict

    runs = pd.read_csv(root / "runs.csv")
    runs = runs[runs["status"] == "ok"]
    jobs = []
    for (lanes, t_up, seed), group in runs.groupby(["lanes", "t_up_s", "seed"]):
        key = conditioned_key(int(lanes), float(t_up), int(seed))
        cell = json.loads((root / "cells" / f"{group['key'].iloc[0]}.json").read_text())
        ev = sim_config_from_dict(cell["config"]["eval"])
        model = (root / "train" / key / "model.pt").resolve()
        cfg = replace(ev, policy=f"dqn:{model},alpha=adaptive", reward=replace(ev.reward, alpha=0.0))
        jobs.append({"lanes": int(lanes), "t_up_s": float(t_up), "seed": int(seed),
                     "out": str(root / "train" / key / "eval_adaptive"), "config": to_dict(cfg)})  # fmt: skip
    with ProcessPoolExecutor(workers) as pool:
        summaries = list(pool.map(_drive, jobs))
    return pd.DataFrame([{k: j[k] for k in ("lanes", "t_up_s", "seed")} | {
        "mean_speed_mps": s["mean_speed_mps"], "lane_changes_per_vehicle": s["lane_changes_per_vehicle"],
        "adaptive_alpha_mean": s.get("adaptive_alpha_mean"), "collisions": s["collisions"],
        "teleports": s["teleports"]} for j, s in zip(jobs, summaries, strict=True)])  # fmt: skip


def report(root: Path, adaptive: pd.DataFrame) -> str:
    runs = pd.read_csv(root / "runs.csv")
    runs = runs[runs["status"] == "ok"]
    star = pd.read_csv(root / "alpha_star.csv").set_index(["lanes", "t_up_s"])
    from coopsumo.agents.adaptive import DEFAULT_RULE

    rule = {"points": [list(p) for p in DEFAULT_RULE.points], "source": DEFAULT_RULE.source}
    fitted = json.loads((root / "adaptive_rule.json").read_text()) if (root / "adaptive_rule.json").exists() else None
    same = fitted is not None and fitted["points"] == rule["points"]
    lines = ["# alpha=adaptive against fixed alphas on scenario II's conditions", "",
             "Made by `experiments/adaptive_scenario2.py`. The same alpha-conditioned model of each (condition, seed) "
             "is driven at every fixed alpha (the sweep's cells) and at `alpha=adaptive` on the same evaluation "
             "demand; differences are paired by seed: mean [90% t-interval]. alpha* is the best fixed alpha on "
             "these very seeds (an oracle chosen after the fact), and the rule was fitted on these conditions: "
             "this is an in-sample check that the rule picks the right alpha, not a test on unseen traffic "
             "(scenario I's accident is that).", "",
             f"Rule driven (DEFAULT_RULE, from {rule['source']}; {len(rule['points'])} points: lanes, mean loop "
             "occupancy %, alpha*): " + "; ".join(f"({n}, {o:g} %, {a:g})" for n, o, a in rule["points"])
             + (" (the rule `--fit` wrote in adaptive_rule.json)" if same else
                " (**not** the rule fitted on this folder: a test or an older rule)"), "",
             "| lanes | T_up (s) | alpha* | adaptive's mean alpha | speed adaptive (m/s) | adaptive - alpha* (m/s) | "
             "adaptive - alpha 0 (m/s) | lane changes / veh adaptive, alpha* |", "|---|---|---|---|---|---|---|---|"]
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
    lines += ["", f"Adaptive beats the best fixed alpha (interval above 0) in {wins} of {total} conditions. "
              f"Collisions {int(adaptive['collisions'].sum())}, teleports {int(adaptive['teleports'].sum())}.", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = Parser(prog="experiments/adaptive_scenario2.py", description="alpha=adaptive on scenario II's conditions.")
    p.add_argument("root", type=Path, help="a finished `scenario2 --conditioned` folder")
    p.add_argument("--fit", action="store_true", help="fit the rule (adaptive_rule.json) and print it")
    p.add_argument("--workers", type=int, default=2)
    args = p.parse_args(argv)

    def body() -> int:
        if not (args.root / "alpha_star.csv").exists():
            raise UsageError(f"{args.root} holds no alpha_star.csv: run scenario2 --conditioned into it first")
        if args.fit:
            from coopsumo.agents.adaptive import fit_rule

            rule = fit_rule(fit(args.root), str(args.root))
            write_json(args.root / "adaptive_rule.json", {"points": rule.points, "source": rule.source})
            print(f"DEFAULT_RULE = AdaptiveRule(points={rule.points!r}, source={rule.source!r})")
            return 0
        table = compare(args.root, args.workers)
        table.to_csv(args.root / "adaptive_runs.csv", index=False)
        (args.root / "adaptive.md").write_text(report(args.root, table))
        print(f"adaptive_scenario2: report {args.root / 'adaptive.md'}")
        return 0

    return run_cli("adaptive_scenario2", body)


if __name__ == "__main__":
    sys.exit(main())
