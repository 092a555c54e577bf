"""Learned models of every training seed through scenario I's accident, beside the baselines on the same seeds.

    .venv/bin/python experiments/accident_seeds.py results/learning_v2x --variants restart,v2x --alphas 0,8

Takes the alpha = A models of the given variants from a learning-study folder (OUT/train/<key>/model.pt,
one per training seed s) and runs each through scenario I's default accident (3 lanes, closure decaying
over steps 2,000-12,000 of 20,000) at every demand of --t-up, on accident seed ACCIDENT_SEED_OFFSET + s:
a demand the model never trained on. keep, greedy and MOBIL run on the same seeds. Every run is a cell of
the shared study runner, reused on a rerun. Writes ROOT/accident/runs.csv (scenario I's measures per run)
and ROOT/accident/report.md (per policy: mean, sd and worst seed; seed-paired differences to `keep`).

An alpha-conditioned variant's model is driven at each alpha of --alphas (dqn:PATH,alpha=A), and with --adaptive
also at alpha=adaptive (alpha chosen every loop period from the loops; agents/adaptive.py); the report then
gives adaptive minus every fixed alpha, paired by seed.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import pandas as pd

from coopsumo.config import ControlConfig, RoadConfig, to_dict
from coopsumo.runio import Parser, UsageError, run_cli, versions, write_json
from coopsumo.studies import scenario1 as s1
from coopsumo.studies.ablation import learner_of, training_key
from coopsumo.validation import alpha_list, t_up_list, workers

ACCIDENT_SEED_OFFSET = 2000
"""a model trained on seed s meets the accident on seed ACCIDENT_SEED_OFFSET + s (baselines too)"""
BASELINES = ("keep", "greedy", "mobil:p=0")


def models(root: Path, variants: list[str], alphas: tuple[float, ...]) -> list[dict[str, Any]]:
    """(variant, alpha, seed, model path) of every finished training of root that is asked for."""
    found = []
    for cell in sorted((root / "cells").glob("*.json")):
        rec = json.loads(cell.read_text())
        if rec.get("kind") == "train" and rec.get("status") == "ok" and rec["variant"] in variants \
                and float(rec["alpha"]) in alphas:  # fmt: skip
            margin = float(rec["config"].get("drive", {}).get("change_margin", 0.0))
            key = training_key(learner_of(rec["variant"]), rec["variant"], float(rec["alpha"]), int(rec["seed"]))
            model = (root / "train" / key / "model.pt").resolve()
            found.append({"variant": rec["variant"], "alpha": float(rec["alpha"]), "seed": int(rec["seed"]),
                          "model": model, "margin": margin,
                          "conditioned": learner_of(rec["variant"]).alpha_conditioned})  # fmt: skip
    return found


def driving_copy(model: Path, margin: float, folder: Path) -> Path:
    """model.pt as it is, with change_margin set in its learner settings: the file a user would get from
    `train --change-margin M` (training ignores the margin), driven with that margin by `dqn:PATH`."""
    from coopsumo.agents.dqn import load_model, save_model

    net, meta = load_model(model)
    meta["config"]["dqn"]["change_margin"] = margin
    out = folder / f"{model.parent.name}_margin{margin:g}.pt"
    folder.mkdir(parents=True, exist_ok=True)
    if not out.exists():
        save_model(out, net, meta)
    return out.resolve()


def main(argv: list[str] | None = None) -> int:
    p = Parser(prog="experiments/accident_seeds.py", description="Every training seed's model through the accident.")
    p.add_argument("roots", type=Path, nargs="+", help="learning-study folders holding the models")
    p.add_argument("--variants", default="restart,v2x", help="variants whose models run (comma-separated)")
    p.add_argument("--alphas", default="0", help="alphas whose models run (comma-separated)")
    p.add_argument("--t-up", dest="t_ups", default="1.5", help="demands T_up (s), comma-separated (default 1.5)")
    p.add_argument("--seeds", type=int, default=6, help="models of training seeds 0..N-1 only (default 6)")
    p.add_argument("--workers", type=workers, default=2, help="parallel processes (default 2)")
    p.add_argument("--quick", action="store_true", help="scenario I's quick accident (6,000 steps): for tests")
    p.add_argument("--adaptive", action="store_true",
                   help="also drive every alpha-conditioned model at alpha=adaptive (chosen from the loops)")
    p.add_argument("--out", type=Path, required=True, help="results folder")
    args = p.parse_args(argv)

    def body() -> int:
        t_ups = t_up_list("--t-up", args.t_ups, ControlConfig().dt_s)
        variants = [v.strip() for v in args.variants.split(",") if v.strip()]
        found = [m for r in args.roots for m in models(r, variants, alpha_list("--alphas", args.alphas))
                 if m["seed"] < args.seeds]  # fmt: skip
        if not found:
            raise UsageError(f"no finished models of {variants} in {[str(r) for r in args.roots]}")
        if args.adaptive:
            found += [{**m, "alpha": None, "adaptive": True} for m in found if m["conditioned"] and m["alpha"] == 0]
        return run(found, t_ups, args.out, args.workers, s1.Plan.quick() if args.quick else s1.Plan())

    return run_cli("accident_seeds", body)


def run(found: list[dict[str, Any]], t_ups: tuple[float, ...], root: Path, n_workers: int, plan: s1.Plan) -> int:
    from coopsumo.sim.network import build_net
    from coopsumo.studies.runner import execute, make_backend, reusable_keys, sigterm_interrupts
    from coopsumo.studies.scenario1_measures import run_metrics

    start = time.perf_counter()
    root.mkdir(parents=True, exist_ok=True)
    write_json(root / "plan.json", {"plan": to_dict(plan), "models": [{**m, "model": str(m["model"])} for m in found],
                                    "versions": versions()})  # fmt: skip
    seeds = sorted({m["seed"] for m in found})
    runs: list[tuple[dict[str, Any], dict[str, Any]]] = []  # (what, spec)
    for t_up in t_ups:
        policies = [({"policy": b, "variant": b, "alpha": None}, b) for b in BASELINES]
        for m in found:
            if m["margin"]:
                m["model"] = driving_copy(m["model"], m["margin"], root / "models")
            spec = f"dqn:{m['model']}"
            if m.get("adaptive"):
                label, variant = f"{m['variant']}_adaptive_train{m['seed']}", f"{m['variant']}_adaptive"
                spec += ",alpha=adaptive"
            else:
                label, variant = f"{m['variant']}_alpha{m['alpha']:g}_train{m['seed']}", m["variant"]
                spec += f",alpha={m['alpha']:g}" if m["conditioned"] else ""
            policies.append(({"policy": label, "variant": variant, "alpha": m["alpha"], "only": m["seed"]}, spec))
        for what, policy in policies:
            for seed in seeds:
                if "only" in what and what["only"] != seed:
                    continue
                cfg = s1.accident_config(plan, policy, ACCIDENT_SEED_OFFSET + seed, t_up)
                name = what["policy"].replace(":", "_").replace("=", "")
                key = f"t{t_up:g}_{name}_seed{seed}"
                spec = {"key": key, "kind": "run", "label": name, "seed": seed, "t_up_s": t_up,
                        "out": f"runs/t{t_up:g}/{key}", "after": None, "config": to_dict(cfg),
                        "trajectory_every": plan.trajectory_every, "outputs": to_dict(plan.outputs())}  # fmt: skip
                runs.append(({**what, "t_up_s": t_up, "seed": seed, "cfg": cfg}, spec))
    specs = [s for _, s in runs]
    done = reusable_keys(root, specs, "accident_seeds", ("mean_speed_mps", "collisions", "teleports"))
    todo = [s for s in specs if s["key"] not in done]
    if todo:
        build_net(RoadConfig())
        backend = make_backend("local", n_workers, None, s1.run_cell)
        try:
            with sigterm_interrupts():
                counts = execute(todo, root.resolve(), backend, len(specs), len(specs) - len(todo), progress=True,
                                 failed_record=s1.failed_record, desc=f"{len(todo)} accident runs")  # fmt: skip
        finally:
            backend.close()
        if counts["failed"]:
            print(f"accident_seeds: error: {counts['failed']} runs failed; records in {root / 'cells'}",
                  file=sys.stderr)  # fmt: skip
            return 1
    rows = []
    for what, spec in runs:
        cfg = what["cfg"]
        summary = json.loads((root / spec["out"] / "summary.json").read_text())
        m = run_metrics(root / spec["out"], cfg, plan.trajectory_every * cfg.control.dt_s)
        rows.append({"variant": what["variant"], "alpha": what["alpha"], "t_up_s": what["t_up_s"],
                     "seed": what["seed"], "mean_speed_mps": summary["mean_speed_mps"],
                     "adaptive_alpha_mean": summary.get("adaptive_alpha_mean"),
                     "lane_changes_per_vehicle": summary["lane_changes_per_vehicle"],
                     "collisions": summary["collisions"], "teleports": summary["teleports"], **m})  # fmt: skip
    table = pd.DataFrame(rows)
    table.to_csv(root / "runs.csv", index=False)
    write_report(root, table, time.perf_counter() - start)
    print(f"accident_seeds: done; report: {root / 'report.md'}")
    return 0


def write_report(root: Path, table: pd.DataFrame, wall_s: float) -> None:
    lines = [
        "# Every training seed's model through scenario I's accident",
        "",
        "Made by `experiments/accident_seeds.py`: scenario I's default accident (3 lanes, closure at 1,300 m "
        "decaying over steps 2,000-12,000 of 20,000). A model trained on seed s meets the accident on seed "
        f"{ACCIDENT_SEED_OFFSET} + s; the baselines run on the same seeds. Measures as in "
        "`results/scenario1/report.md`. Paired: the policy minus `keep` on the same seed (mean, worst).",
        "",
        "| T_up (s) | policy | alpha | seeds | TTS (veh-h) | TTS - keep, paired (mean, worst) | mean speed (m/s) | "
        "lane changes / veh | system recovery (s) | collisions, teleports |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for t_up, at in table.groupby("t_up_s", sort=False):
        keep = at[at["variant"] == "keep"].set_index("seed")["tts_veh_h"]
        for (variant, alpha), g in at.groupby(["variant", at["alpha"].fillna(-1)], sort=False):
            gap = (g.set_index("seed")["tts_veh_h"] - keep).dropna()
            a = "-" if alpha < 0 else f"{alpha:g}"
            lines.append(
                f"| {t_up:g} | `{variant}` | {a} | {len(g)} | {g['tts_veh_h'].mean():.1f} ± "
                f"{g['tts_veh_h'].std():.1f} | "
                f"{gap.mean():+.1f}, {gap.max():+.1f} | {g['mean_speed_mps'].mean():.2f} ± "
                f"{g['mean_speed_mps'].std():.2f} | {g['lane_changes_per_vehicle'].mean():.2f} | "
                f"{g['system_recovery_s'].mean():.0f} | {int(g['collisions'].sum())}, {int(g['teleports'].sum())} |"
            )
    lines += adaptive_lines(table)
    lines += ["", f"Wall time of this invocation: {wall_s / 60:.1f} min. Versions: {versions()}.", ""]
    (root / "report.md").write_text("\n".join(lines))


def adaptive_lines(table: pd.DataFrame) -> list[str]:
    """Adaptive alpha minus every fixed alpha of the same conditioned models, paired by seed: TTS and mean speed,
    mean with a 90% t-interval over seeds (empty without adaptive runs)."""
    from coopsumo.studies.robustness import paired_interval

    adaptive = table[table["variant"].str.endswith("_adaptive")]
    if adaptive.empty:
        return []
    lines = ["", "## Adaptive alpha against every fixed alpha (the same conditioned models, paired by seed)", "",
             "Difference adaptive minus fixed: mean [90% t-interval over seeds]; TTS lower is better, speed higher.",
             "", "| T_up (s) | fixed alpha | seeds | TTS difference (veh-h) | speed difference (m/s) | adaptive's "
             "mean alpha |", "|---|---|---|---|---|---|"]  # fmt: skip
    for (t_up, variant), ad in adaptive.groupby(["t_up_s", "variant"], sort=False):
        base = variant.removesuffix("_adaptive")
        fixed = table[(table["t_up_s"] == t_up) & (table["variant"] == base)]
        a = ad.set_index("seed")
        for alpha, g in fixed.groupby("alpha"):
            f = g.set_index("seed")
            seeds = a.index.intersection(f.index)
            cells = []
            for col in ("tts_veh_h", "mean_speed_mps"):
                mean, lo, hi = paired_interval((a.loc[seeds, col] - f.loc[seeds, col]).to_numpy(float))
                cells.append(f"{mean:+.2f} [{lo:+.2f}, {hi:+.2f}]")
            lines.append(f"| {t_up:g} | {alpha:g} | {len(seeds)} | {cells[0]} | {cells[1]} | "
                         f"{a.loc[seeds, 'adaptive_alpha_mean'].astype(float).mean():.2f} |")  # fmt: skip
    return lines


if __name__ == "__main__":
    sys.exit(main())
