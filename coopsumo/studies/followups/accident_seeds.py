"""`coopsumo accident-seeds`: every training seed's learned model through scenario I's accident, beside the baselines
on the same seeds.

Takes the alpha = A models of the given variants from learning-study folders (`coopsumo learning --out ROOT`: each
finished training's record in ROOT/cells/, its model in ROOT/train/<key>/model.pt, one per training seed s) and runs
each through scenario I's default accident (3 lanes, closure decaying over steps 2,000-12,000 of 20,000) at every
demand of --t-up, on accident seed ACCIDENT_SEED_OFFSET + s: a demand the model never trained on. keep, greedy and
MOBIL p = 0 run on the same seeds. A variant with a change margin drives a copy of its model that carries the margin
(OUT/models/); an alpha-conditioned variant's model is driven at each alpha of --alphas (dqn:PATH,alpha=A) and, with
--adaptive, at alpha=adaptive too (alpha chosen every loop period from the loops: agents/adaptive.py), which the
report sets against every fixed alpha, paired by seed. Every run is a cell of the shared runner (accident_runs),
reused on a rerun. Writes OUT/runs.csv (scenario I's measures per run) and OUT/report.md (accident_seeds_report).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import pandas as pd

from coopsumo.config import ControlConfig, SimConfig, to_dict
from coopsumo.errors import UsageError
from coopsumo.files import read_json, write_atomic, write_json, write_text_atomic
from coopsumo.provenance import versions
from coopsumo.run_dirs import check_out_path, check_study_place
from coopsumo.run_dirs import study_root as claim_study_root
from coopsumo.runio import Parser, run_cli
from coopsumo.studies.engine.cells import add_cell_flags
from coopsumo.studies.engine.model_store import store_for
from coopsumo.studies.engine.records import failed_exit, model_fields
from coopsumo.studies.engine.runner import check_backend
from coopsumo.studies.followups.accident_seeds_report import report
from coopsumo.studies.learning.models import finished_trainings
from coopsumo.studies.learning.plan import variant_list
from coopsumo.studies.scenario1 import accident_runs
from coopsumo.studies.scenario1.plan import DEFAULT_PROFILE, PROFILES, Plan, accident_config
from coopsumo.study_tables import ACCIDENT_SEEDS_RUNS
from coopsumo.validation import (
    MAX_STEPS,
    alpha_list,
    default_model_out,
    integer,
    model_out_dir,
    number_name,
    seed_count,
    t_up_list,
)

ACCIDENT_SEED_OFFSET = 2000
"""a model trained on seed s meets the accident on seed ACCIDENT_SEED_OFFSET + s (baselines too)"""
BASELINES = ("keep", "greedy", "mobil:p=0")
OUTPUTS = ("plan.json", "cells", "runs", "models", "runs.csv", "report.md")
"""the names the study writes at the top of its results folder, its plan file first (run_dirs.check_study_root)"""
PROG = "accident-seeds"


def models(root: Path, variants: tuple[str, ...], alphas: tuple[float, ...], seeds: int) -> list[dict[str, Any]]:
    """(variant, alpha, seed, model path, change margin, conditioned) of every finished training of the learning
    study in root that is asked for: a variant of `variants`, an alpha of `alphas`, a training seed below `seeds`."""
    return [{"variant": t["variant"], "alpha": t["alpha"], "seed": t["seed"], "model": t["model"],
             "margin": float(t["config"].get("drive", {}).get("change_margin", 0.0)),
             "conditioned": t["learner"].alpha_conditioned}
            for t in finished_trainings(root, PROG, variants, alphas, seeds)]  # fmt: skip


def driving_copy(model: Path, margin: float, folder: Path) -> Path:
    """model.pt as it is, with change_margin set in its learner settings: the file a user would get from
    `train --change-margin M` (training ignores the margin), driven with that margin by `dqn:PATH`. Written afresh
    each time, from the model as it is now (a model replaced by an older file is caught too)."""
    from coopsumo.agents.model_file import load_model, save_model

    out = folder / f"{model.parent.name}_margin{number_name(margin)}.pt"
    net, meta = load_model(model)
    meta["config"]["dqn"]["change_margin"] = margin
    folder.mkdir(parents=True, exist_ok=True)
    save_model(out, net, meta)
    return out.resolve()


def check_copyable(model: Path) -> None:
    """UsageError (one line) unless the model a margin variant drives through its copy (driving_copy) can be read:
    checked before the study writes anything."""
    from coopsumo.agents.model_file import ModelFileError, load_model

    try:
        load_model(model)
    except ModelFileError as err:
        first = str(err).splitlines()[0].split(". ")[0] if str(err) else type(err).__name__
        raise UsageError(f"{first[:300]}; train it again (`coopsumo learning`) or leave its variant out") from None


def drivers(found: list[dict[str, Any]], adaptive: bool, models_dir: Path) -> list[dict[str, Any]]:
    """Who drives: the baselines on every seed, each model on its own training seed (at its alpha; with adaptive,
    each conditioned model once more at alpha=adaptive). Margin variants' copies are written to models_dir."""
    out: list[dict[str, Any]] = [{"label": b, "variant": b, "alpha": None, "policy": b, "only": None}
                                 for b in BASELINES]  # fmt: skip
    adaptive_models: dict[Path, dict[str, Any]] = {}
    for m in found:
        model = driving_copy(m["model"], m["margin"], models_dir) if m["margin"] else m["model"]
        alpha = number_name(m["alpha"])
        out.append({"label": f"{m['variant']}_alpha{alpha}_train{m['seed']}", "variant": m["variant"],
                    "alpha": m["alpha"], "only": m["seed"], "source": m["model"],
                    "policy": f"dqn:{model}" + (f",alpha={alpha}" if m["conditioned"] else "")})  # fmt: skip
        if adaptive and m["conditioned"]:
            adaptive_models.setdefault(model, m)
    for model, m in adaptive_models.items():
        out.append({"label": f"{m['variant']}_adaptive_train{m['seed']}", "variant": f"{m['variant']}_adaptive",
                    "alpha": None, "only": m["seed"], "source": m["model"],
                    "policy": f"dqn:{model},alpha=adaptive"})  # fmt: skip
    return out


def cells(who: list[dict[str, Any]], t_ups: tuple[float, ...], seeds: list[int],
          plan: Plan) -> list[tuple[dict[str, Any], SimConfig, dict[str, Any]]]:  # fmt: skip
    """(driver, configuration, cell) of every run: each demand, each driver, each of its seeds. A model's cell is
    tied to its trained model file as it is now (records.model_fields): a stored run of a model since replaced or
    cut short is run again."""
    out = []
    tied = {d["source"]: model_fields(d["source"]) for d in who if d.get("source") is not None}
    for t_up in t_ups:
        t = number_name(t_up)
        for d in who:
            for seed in seeds if d["only"] is None else [d["only"]]:
                cfg = accident_config(plan, d["policy"], ACCIDENT_SEED_OFFSET + seed, t_up)
                name = d["label"].replace(":", "_").replace("=", "")
                key = f"t{t}_{name}_seed{seed}"
                spec = accident_runs.run_spec(plan, cfg, key, f"runs/t{t}/{key}", name, seed, t_up)
                out.append((d, cfg, {**spec, **tied.get(d.get("source"), {})}))
    return out


def run_study(found: list[dict[str, Any]], t_ups: tuple[float, ...], root: Path, plan: Plan, adaptive: bool = False,
              workers: int = 2, backend: str = "local", address: str | None = None,
              progress: bool = True) -> int:  # fmt: skip
    """Run (or finish) the study in root and write runs.csv and report.md; the exit code."""
    start = time.perf_counter()
    root.mkdir(parents=True, exist_ok=True)
    write_json(root / "plan.json", {"plan": to_dict(plan), "models": [{**m, "model": str(m["model"])} for m in found],
                                    "versions": versions()})  # fmt: skip
    runs = cells(drivers(found, adaptive, root / "models"), t_ups, sorted({m["seed"] for m in found}), plan)
    specs = [spec for _, _, spec in runs]
    failed = accident_runs.run_all(specs, root, [plan], PROG, workers, backend, address, progress, plan.profile)
    if failed:
        return failed_exit(PROG, failed, len(specs), root)
    rows = []
    for d, cfg, spec in runs:
        summary = read_json(root / spec["out"] / "summary.json")
        rows.append({"variant": d["variant"], "alpha": d["alpha"], "t_up_s": spec["t_up_s"], "seed": spec["seed"],
                     "mean_speed_mps": summary["mean_speed_mps"],
                     "adaptive_alpha_mean": summary.get("adaptive_alpha_mean"),
                     "lane_changes_per_vehicle": summary["lane_changes_per_vehicle"],
                     "collisions": summary["collisions"], "teleports": summary["teleports"],
                     **accident_runs.measures(root, spec, cfg)})  # fmt: skip
    table = pd.DataFrame(rows)
    ACCIDENT_SEEDS_RUNS.check_frame(table, root / "runs.csv")  # inside its limits before it is written (study_tables)
    write_atomic(root / "runs.csv", lambda tmp: table.to_csv(tmp, index=False))
    write_text_atomic(root / "report.md", report(table, ACCIDENT_SEED_OFFSET, time.perf_counter() - start))
    print(f"{PROG}: done; report: {root / 'report.md'}")
    return 0


def build_parser() -> Parser:
    p = Parser(prog="coopsumo accident-seeds",
               description="Every training seed's model of a learning study through scenario I's accident, beside "
                           "keep, greedy and MOBIL p=0 on the same seeds.")  # fmt: skip
    p.add_argument("roots", type=Path, nargs="+", metavar="ROOT",
                   help="learning-study folders holding the models (`coopsumo learning --out ROOT`)")  # fmt: skip
    p.add_argument("--variants", default="restart,v2x", help="variants whose models drive, comma-separated")
    p.add_argument("--alphas", default="0", help="alphas whose models drive (a conditioned model: the alphas it "
                                                 "drives at), comma-separated")  # fmt: skip
    p.add_argument("--t-up", dest="t_ups", default="1.5", help="demands T_up (s), comma-separated")
    p.add_argument("--seeds", type=seed_count, default=6, help="models of training seeds 0..N-1 only")
    size = p.add_mutually_exclusive_group()
    size.add_argument(
        "--quick",
        action="store_true",
        help=f"scenario I's quick accident ({PROFILES['quick'].steps:,} steps) instead of the default one",
    )
    size.add_argument("--steps", type=integer(10, MAX_STEPS), default=None,
                      help=f"steps of each accident run (default {PROFILES[DEFAULT_PROFILE].steps:,}); the "
                           "accident window scales with it")  # fmt: skip
    p.add_argument(
        "--adaptive",
        action="store_true",
        help="also drive every alpha-conditioned model at alpha=adaptive (chosen from the loops)",
    )
    p.add_argument("--out", type=model_out_dir, default=None,
                   help="results folder (default: ROOT/accident of the first ROOT)")
    add_cell_flags(p)
    return p


def check_roots(roots: list[Path]) -> None:
    """UsageError when a ROOT is given twice (as written or behind a link: `l l`, `l l/`): its every model would be
    run twice, and runs.csv refused only after the runs (issue 82, probe 4, F21)."""
    seen: dict[Path, Path] = {}
    for root in roots:
        if (first := seen.setdefault(root.resolve(), root)) is not root:
            raise UsageError(f"ROOT {root} is {first} given again: give each learning-study folder once")


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def body() -> int:
        t_ups = t_up_list("--t-up", args.t_ups, ControlConfig().dt_s)
        variants = variant_list("--variants", args.variants)
        alphas = alpha_list("--alphas", args.alphas)
        check_backend(args.backend, args.address)
        check_roots(args.roots)
        found = [m for root in args.roots for m in models(root, variants, alphas, args.seeds)]
        if not found:
            raise UsageError(f"no finished models of {','.join(variants)} at alpha {args.alphas} with a training "
                             f"seed below {args.seeds} in {', '.join(map(str, args.roots))}")  # fmt: skip
        seen: dict[tuple[str, float, int], Path] = {}
        for m in found:
            if (other := seen.setdefault((m["variant"], m["alpha"], m["seed"]), m["model"])) != m["model"]:
                raise UsageError(
                    f"{other} and {m['model']} are both the {m['variant']} model of alpha "
                    f"{m['alpha']:g} and training seed {m['seed']}: give each variant's folder once"
                )
        if args.adaptive and not any(m["conditioned"] for m in found):
            raise UsageError(f"--adaptive drives alpha-conditioned models, and none of --variants {args.variants} "
                             "is alpha-conditioned (e.g. conditioned)")  # fmt: skip
        for m in found:
            if m["margin"]:
                check_copyable(m["model"])
        plan = PROFILES["quick" if args.quick else DEFAULT_PROFILE]
        if args.steps is not None:
            plan = accident_runs.scaled(plan, args.steps / plan.steps)
        out = args.out if args.out is not None else default_model_out(args.roots[0] / "accident")
        check_out_path(out)  # its path, its place (directly in a ROOT: ROOT/accident) and its model store (the
        check_study_place(out, args.roots)  # learning study's) before anything is written (probe 7, I13)
        store_for(out)
        # path, place (not in another's folder but directly in a ROOT: ROOT/accident), lock, ownership and marker
        with claim_study_root(out, "accident_seeds", (*OUTPUTS, "*.tmp"), hosts=args.roots):
            return run_study(found, t_ups, out, plan, args.adaptive, args.workers, args.backend, args.address,
                             progress=not args.quiet)  # fmt: skip

    return run_cli(PROG, body)


if __name__ == "__main__":
    sys.exit(main())
