"""Where the accident's queue goes, against demand: the regime map behind scenario I's default demands.

    .venv/bin/python experiments/regime_map.py --out results/regime_map

Runs `keep` (no lane changes: the reference that no policy choice blurs) through scenario I's accident at
every demand of --t-up, for two accident lengths: the default study's (10,000 steps of decaying closure in a
20,000-step run) and the paper's (50,000 of 90,000 steps, `scenario1 --full`), on the evaluation seeds of
--seeds. Every run is a cell of the shared study runner (coopsumo.studies.runner), reused on a rerun.
Writes runs.csv (scenario I's measures per run) and report.md (the regime table).
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import pandas as pd

from coopsumo.config import ControlConfig, RoadConfig, to_dict
from coopsumo.runio import Parser, run_cli, versions, write_json
from coopsumo.studies import scenario1 as s1
from coopsumo.studies.runner import study_root
from coopsumo.validation import out_dir, seed_count, t_up_list, workers

DEMANDS = "4,3,2.5,2,1.5,1.25,1"
POLICY = "keep"


def plans(seeds: int, t_ups: tuple[float, ...]) -> dict[str, s1.Plan]:
    """The two accident lengths, at the same demands and seeds."""
    chosen = {"seeds": tuple(range(1, seeds + 1)), "t_ups": t_ups}
    return {"default": replace(s1.Plan(), **chosen), "paper": replace(s1.Plan.full(), **chosen)}


def main(argv: list[str] | None = None) -> int:
    p = Parser(prog="experiments/regime_map.py", description="Scenario I's demand regimes with `keep`.")
    p.add_argument("--t-up", dest="t_ups", default=DEMANDS,
                   help=f"demands T_up (s), comma-separated (default {DEMANDS})")  # fmt: skip
    p.add_argument("--seeds", type=seed_count, default=1, help="evaluation seeds 1..N (default 1)")
    p.add_argument("--workers", type=workers, default=2, help="parallel processes (default 2)")
    p.add_argument("--out", type=out_dir, default=Path("results/regime_map"), help="results folder")
    args = p.parse_args(argv)

    def body() -> int:
        t_ups = t_up_list("--t-up", args.t_ups, ControlConfig().dt_s)
        with study_root(args.out, "regime_map"):  # path, lock, ownership and marker of the results folder
            return run(plans(args.seeds, t_ups), args.out, args.workers)

    return run_cli("regime_map", body)


def run(by_length: dict[str, s1.Plan], root: Path, n_workers: int) -> int:
    from coopsumo.sim.network import build_net
    from coopsumo.studies.runner import execute, make_backend, reusable_keys, sigterm_interrupts
    from coopsumo.studies.scenario1_measures import run_metrics

    start = time.perf_counter()
    root.mkdir(parents=True, exist_ok=True)
    write_json(root / "plan.json", {"plans": {k: to_dict(v) for k, v in by_length.items()}, "versions": versions()})
    cells: list[tuple[str, s1.Plan, float, int, Any, dict[str, Any]]] = []
    for length, plan in by_length.items():
        for t_up in plan.t_ups:
            for seed in plan.seeds:
                cfg = s1.accident_config(plan, POLICY, seed, t_up)
                folder = f"runs/{length}/t{t_up:g}/{POLICY}_seed{seed}"
                spec = {"key": f"{length}_t{t_up:g}_seed{seed}", "kind": "run", "label": POLICY, "seed": seed,
                        "t_up_s": t_up, "out": folder, "after": None, "config": to_dict(cfg),
                        "trajectory_every": plan.trajectory_every, "outputs": to_dict(plan.outputs())}  # fmt: skip
                cells.append((length, plan, t_up, seed, cfg, spec))
    done = reusable_keys(root, [c[5] for c in cells], "regime_map", ("mean_speed_mps", "collisions", "teleports"))
    todo = [c[5] for c in cells if c[5]["key"] not in done]
    if todo:
        build_net(RoadConfig())
        backend = make_backend("local", n_workers, None, s1.run_cell)
        try:
            with sigterm_interrupts():
                counts = execute(todo, root.resolve(), backend, len(cells), len(cells) - len(todo), progress=True,
                                 failed_record=s1.failed_record, desc=f"{len(todo)} accident runs")  # fmt: skip
        finally:
            backend.close()
        if counts["failed"]:
            print(f"regime_map: error: {counts['failed']} runs failed; records in {root / 'cells'}", file=sys.stderr)
            return 1
    rows = []
    for length, plan, t_up, seed, cfg, spec in cells:
        m = run_metrics(root / spec["out"], cfg, plan.trajectory_every * cfg.control.dt_s)
        acc = cfg.accident
        rows.append({"accident": length, "accident_steps": acc.duration_steps, "run_steps": cfg.steps,
                     "t_up_s": t_up, "inflow_veh_h": 3600 / t_up, "seed": seed, **m})  # fmt: skip
    table = pd.DataFrame(rows)
    table.to_csv(root / "runs.csv", index=False)
    write_report(root, table, time.perf_counter() - start)
    print(f"regime_map: done; report: {root / 'report.md'}")
    return 0


def write_report(root: Path, table: pd.DataFrame, wall_s: float) -> None:
    lines = [
        "# Scenario I: where the accident's queue goes, against demand",
        "",
        f"`{POLICY}` (no lane changes) through scenario I's accident (3 lanes, x = 1,300 m, stuck ratio decaying "
        "1 -> 0), at two accident lengths: the default study's (steps 2,000-12,000 of a 20,000-step run) and the "
        "paper's (steps 20,000-70,000 of 90,000). Made by `experiments/regime_map.py`; measures as in "
        "`results/scenario1/report.md` (regime: \"on the road\" when at most one vehicle per lane ever waits to "
        "enter; queue reach: the farthest upstream end of the slow queue standing at the bottleneck).",
        "",
        "| accident | T_up (s) | inflow (veh/h) | seed | regime | queue reach (m) | reached the entrance (s after "
        "start) | waiting at the end (veh) | system recovery (s after start) | total time spent (veh-h) | "
        "discharge (veh/h) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for _, r in table.iterrows():
        spilled = "never" if pd.isna(r["spilled_s"]) else f"{r['spilled_s']:.0f}"
        rec = "never" if pd.isna(r["system_recovery_s"]) else f"{r['system_recovery_s']:.0f}"
        lines.append(f"| {r['accident']} | {r['t_up_s']:g} | {r['inflow_veh_h']:.0f} | {r['seed']} | {r['regime']} | "
                     f"{r['queue_m']:.0f} | {spilled} | {r['waiting_at_end_veh']:.0f} | {rec} | "
                     f"{r['tts_veh_h']:.1f} | {r['discharge_veh_h']:.0f} |")  # fmt: skip
    lines += ["", f"Wall time of this invocation: {wall_s / 60:.1f} min. Versions: {versions()}.", ""]
    (root / "report.md").write_text("\n".join(lines))


if __name__ == "__main__":
    sys.exit(main())
