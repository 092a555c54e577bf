"""`coopsumo adaptive`: alpha=adaptive against the best fixed alpha on scenario II's conditions, with the same
alpha-conditioned models (`coopsumo adaptive-fit` fits the rule on them: adaptive_fit).

ROOT is a finished `coopsumo scenario2 --conditioned` folder. Every (condition, seed) model of the folder is driven
once more with dqn:PATH,alpha=adaptive on each of its evaluations' condition, seed and steps. Each is a cell of the
shared runner (record ROOT/cells/adaptive_<key>_s<E>.json, run folder ROOT/evals/<key>/eval_adaptive_s<E>/, both
reused when finished); ROOT/adaptive_runs.csv holds one row per (condition, seed), its evaluations pooled, and
ROOT/adaptive.md compares it, paired by seed, with the best fixed alpha (alpha*, chosen on these same models and
evaluations: an oracle the adaptive rule has to match) and with alpha 0 (adaptive_alpha_report).
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import pandas as pd

from coopsumo.config import OutputConfig, to_dict
from coopsumo.errors import UsageError
from coopsumo.runio import Parser, run_cli
from coopsumo.studies.engine.cells import add_cell_flags, failed_keys, run_cells
from coopsumo.studies.engine.records import CellRecords, failed_exit
from coopsumo.studies.engine.run_folders import study_root
from coopsumo.studies.engine.runner import check_backend
from coopsumo.studies.followups.adaptive_alpha_report import report
from coopsumo.studies.followups.adaptive_fit import read_sweep
from coopsumo.studies.scenario2.plan import conditioned_key

PROG = "adaptive"
REQUIRED = ("mean_speed_mps", "lane_changes_per_vehicle", "collisions", "teleports")
"""summary values a stored record must hold as finite numbers to be reused, and the ones adaptive_runs.csv keeps"""
RECORDS = CellRecords(("key", "lanes", "t_up_s", "seed", "eval_seed", "out"))
failed_record = RECORDS.failed


def cell_specs(root: Path, runs: pd.DataFrame) -> list[dict[str, Any]]:
    """One cell per (condition, seed, evaluation seed): its model driven at alpha=adaptive on that evaluation's
    condition, seed and steps (the sweep's own evaluations); UsageError when the sweep's record or model of one is
    missing or was made by an earlier version."""
    from coopsumo.config import sim_config_from_dict

    specs = []
    for (lanes, t_up, seed), group in runs.groupby(["lanes", "t_up_s", "seed"]):
        key = conditioned_key(int(lanes), float(t_up), int(seed))
        record, model = root / "cells" / f"{group['key'].iloc[0]}.json", (root / "train" / key / "model.pt").resolve()
        try:
            evals = [sim_config_from_dict(c) for c in json.loads(record.read_text())["config"]["evals"]]
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise UsageError(f"record {record} cannot be read ({type(err).__name__}): run `coopsumo scenario2 "
                             f"--profile quick --conditioned --out {root}` again") from None  # fmt: skip
        if not model.is_file():
            raise UsageError(f"{model} is missing: run `coopsumo scenario2 --profile quick --conditioned --out {root}` "
                             "again")
        for ev in evals:
            cfg = replace(ev, policy=f"dqn:{model},alpha=adaptive", reward=replace(ev.reward, alpha=0.0))
            specs.append({"key": f"adaptive_{key}_s{ev.seed}", "lanes": int(lanes), "t_up_s": float(t_up),
                          "seed": int(seed), "eval_seed": ev.seed, "out": f"evals/{key}/eval_adaptive_s{ev.seed}",
                          "config": to_dict(cfg)})  # fmt: skip
    return specs


def run_cell(spec: dict[str, Any], root: str) -> dict[str, Any]:
    """Drive one model at alpha=adaptive into ROOT/<out> (a finished run of the same configuration, made after the
    model, is reused); never raises (records.run_recorded)."""
    return RECORDS.run(spec, lambda record: record.update(summary=_drive(spec, Path(root) / spec["out"])))


def _drive(spec: dict[str, Any], out: Path) -> dict[str, Any]:
    import torch

    from coopsumo.policy_spec import model_file, split_dqn_spec
    from coopsumo.studies.engine.run_folders import reusable_run, simulate_into

    torch.set_num_threads(1)
    model = Path(model_file(split_dqn_spec(spec["config"]["policy"])[0]))
    if reusable_run(out, spec["config"], OutputConfig(), model, prog=PROG):
        summary = json.loads((out / "summary.json").read_text())
        return {k: v for k, v in summary.items() if k != "policy"}
    return simulate_into(spec["config"], out, out.parent.name)


def drive(specs: list[dict[str, Any]], root: Path, workers: int = 2, backend: str = "local",
          address: str | None = None, progress: bool = True) -> list[dict[str, Any]]:  # fmt: skip
    """Run the adaptive cells (cell_specs) of the sweep in root, reusing the finished ones; every cell's record."""
    from coopsumo.config import sim_config_from_dict

    roads = [sim_config_from_dict(s["config"]).road for s in specs]
    return run_cells(specs, root, run_cell, failed_record, prog=PROG, required=REQUIRED, roads=roads,
                     workers=workers, backend=backend, address=address, progress=progress,
                     desc="alpha=adaptive runs")  # fmt: skip


def adaptive_table(records: list[dict[str, Any]]) -> pd.DataFrame:
    """adaptive_runs.csv: one row per (condition, seed) of the finished cells' records, its evaluation seeds pooled
    as the sweep pools a model's (records.pool_summaries: collisions and teleports summed, the rest
    averaged)."""
    from coopsumo.studies.engine.records import pool_summaries

    rows = []
    for (lanes, t_up, seed), group in pd.DataFrame(records).groupby(["lanes", "t_up_s", "seed"], sort=True):
        pooled = pool_summaries([{k: r["summary"].get(k) for k in REQUIRED + ("adaptive_alpha_mean",)}
                                 for r in group.to_dict("records")])  # fmt: skip
        rows.append({"lanes": lanes, "t_up_s": t_up, "seed": seed, "mean_speed_mps": pooled["mean_speed_mps"],
                     "lane_changes_per_vehicle": pooled["lane_changes_per_vehicle"],
                     "adaptive_alpha_mean": pooled.get("adaptive_alpha_mean"), "collisions": pooled["collisions"],
                     "teleports": pooled["teleports"], "eval_runs": len(group)})  # fmt: skip
    return pd.DataFrame(rows)


def build_parser() -> Parser:
    p = Parser(prog="coopsumo adaptive",
               description="alpha=adaptive against the best fixed alpha on the conditions of a `scenario2 "
                           "--conditioned` sweep, with the same models.")  # fmt: skip
    p.add_argument("root", type=Path, metavar="ROOT", help="a finished `coopsumo scenario2 --conditioned` folder")
    add_cell_flags(p)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def body() -> int:
        check_backend(args.backend, args.address)
        runs, star = read_sweep(args.root)
        specs = cell_specs(args.root, runs)
        with study_root(args.root, "scenario2"):  # a scenario2 sweep's folder: its lock held, its ownership checked
            records = drive(specs, args.root, args.workers, args.backend, args.address, progress=not args.quiet)
            if failed := failed_keys(records):
                return failed_exit(PROG, failed, len(records), args.root)
            table = adaptive_table(records)
            table.to_csv(args.root / "adaptive_runs.csv", index=False)
            (args.root / "adaptive.md").write_text(report(args.root, runs, star.set_index(["lanes", "t_up_s"]), table))
        print(f"{PROG}: report {args.root / 'adaptive.md'}")
        return 0

    return run_cli(PROG, body)


if __name__ == "__main__":
    sys.exit(main())
