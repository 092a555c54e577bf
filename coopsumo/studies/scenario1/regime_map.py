"""`coopsumo scenario1 --regime-map` (`make regime-map`): where the accident's queue goes, against demand; the reason
for scenario I's default demands (a profile of scenario I; until 2026-12-02 the command `coopsumo regime-map`).

Runs `keep` (no lane changes: the reference that no policy choice blurs) through scenario I's accident at every demand
of --t-up, for two accident lengths: the default study's (10,000 steps of decaying closure in a 20,000-step run) and
the paper's (50,000 of 90,000 steps, `scenario1 --full`), on the evaluation seeds 1..--seeds. Every run is a cell of
the shared runner (accident_runs: scenario I's cell and run folder), reused on a rerun. Writes OUT/runs.csv
(scenario I's measures per run) and OUT/report.md (the regime table).
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import pandas as pd

from coopsumo.config import ControlConfig, SimConfig, to_dict
from coopsumo.errors import UsageError
from coopsumo.files import write_atomic, write_json, write_text_atomic
from coopsumo.provenance import versions
from coopsumo.report.markdown import md_table
from coopsumo.run_markers import PLANLESS_TITLES
from coopsumo.studies.engine.records import failed_exit
from coopsumo.studies.engine.run_folders import study_root
from coopsumo.studies.engine.runner import check_backend
from coopsumo.studies.scenario1 import accident_runs
from coopsumo.studies.scenario1.plan import DEFAULT_PROFILE, PAPER_PROFILE, PROFILES, Plan, accident_config
from coopsumo.study_tables import REGIME_MAP_RUNS
from coopsumo.validation import number_name, t_up_list

DEMANDS = (4.0, 3.0, 2.5, 2.0, 1.5, 1.25, 1.0)
"""T_up (s): from a queue that stays on the road to one that still waits to enter when the accident ends"""
POLICY = "keep"


def plans(seeds: int, t_ups: tuple[float, ...], steps: int | None = None) -> dict[str, Plan]:
    """The two accident lengths, at the same demands and seeds; steps: the default length's run steps instead of
    20,000, every run and accident window (the paper's length too) scaled by the same factor."""
    seed_list = tuple(range(1, seeds + 1))
    by_length = {"default": replace(PROFILES[DEFAULT_PROFILE], seeds=seed_list, t_ups=t_ups),
                 "paper": replace(PROFILES[PAPER_PROFILE], seeds=seed_list, t_ups=t_ups)}  # fmt: skip
    if steps is None:
        return by_length
    factor = steps / PROFILES[DEFAULT_PROFILE].steps
    return {length: accident_runs.scaled(plan, factor) for length, plan in by_length.items()}


def cells(by_length: dict[str, Plan]) -> list[tuple[str, SimConfig, dict[str, Any]]]:
    """(accident length, configuration, cell) of every run; keys and folders as the study always wrote them."""
    out = []
    for length, plan in by_length.items():
        for t_up in plan.t_ups:
            for seed in plan.seeds:
                cfg = accident_config(plan, POLICY, seed, t_up)
                key, folder = f"{length}_t{number_name(t_up)}_seed{seed}", f"runs/{length}/t{number_name(t_up)}"
                spec = accident_runs.run_spec(plan, cfg, key, f"{folder}/{POLICY}_seed{seed}", POLICY, seed, t_up)
                out.append((length, cfg, spec))
    return out


def run_study(by_length: dict[str, Plan], root: Path, workers: int = 2, backend: str = "local",
              address: str | None = None, progress: bool = True) -> int:  # fmt: skip
    """Run (or finish) the regime map in root and write runs.csv and report.md; the exit code."""
    start = time.perf_counter()
    root.mkdir(parents=True, exist_ok=True)
    write_json(root / "plan.json", {"plans": {k: to_dict(v) for k, v in by_length.items()}, "versions": versions()})
    runs = cells(by_length)
    specs = [spec for _, _, spec in runs]
    failed = accident_runs.run_all(specs, root, by_length.values(), "scenario1", workers, backend, address, progress,
                                   "regime_map")
    if failed:
        return failed_exit("scenario1", failed, len(specs), root)
    rows = []
    for length, cfg, spec in runs:
        rows.append({"accident": length, "accident_steps": cfg.accident.duration_steps, "run_steps": cfg.steps,
                     "t_up_s": spec["t_up_s"], "inflow_veh_h": 3600 / spec["t_up_s"], "seed": spec["seed"],
                     **accident_runs.measures(root, spec, cfg)})  # fmt: skip
    table = pd.DataFrame(rows)
    REGIME_MAP_RUNS.check_frame(table, root / "runs.csv")  # inside its limits before it is written (study_tables)
    write_atomic(root / "runs.csv", lambda tmp: table.to_csv(tmp, index=False))
    write_text_atomic(root / "report.md", report(by_length, table, time.perf_counter() - start))
    print(f"scenario1 --regime-map: done; report: {root / 'report.md'}")
    return 0


def report(by_length: dict[str, Plan], table: pd.DataFrame, wall_s: float) -> str:
    """The regime table: one row per accident length, demand and seed."""
    windows = " and ".join(
        f"the {'paper' if length == 'paper' else 'default study'}'s (steps {p.accident_start:,}-"
        f"{p.accident_start + p.accident_steps:,} of a {p.steps:,}-step run)"
        for length, p in by_length.items()
    )
    lines = [
        PLANLESS_TITLES["regime_map"],
        "",
        f"`{POLICY}` (no lane changes) through scenario I's accident (3 lanes, x = 1,300 m, stuck ratio decaying "
        f"1 -> 0), at {len(by_length)} accident lengths: {windows}. Made by `coopsumo scenario1 --regime-map`; "
        "measures as in "
        '`results/scenario1/report.md` (regime: "on the road" when at most one vehicle per lane ever waits to '
        "enter; queue reach: the farthest upstream end of the slow queue standing at the bottleneck).",
        "",
    ]
    rows = []
    for _, r in table.iterrows():
        spilled = "never" if pd.isna(r["spilled_s"]) else f"{r['spilled_s']:.0f}"
        rec = "never" if pd.isna(r["system_recovery_s"]) else f"{r['system_recovery_s']:.0f}"
        rows.append([str(r["accident"]), f"{r['t_up_s']:g}", f"{r['inflow_veh_h']:.0f}", str(r["seed"]),
                     str(r["regime"]), f"{r['queue_m']:.0f}", spilled, f"{r['waiting_at_end_veh']:.0f}", rec,
                     f"{r['tts_veh_h']:.1f}", f"{r['discharge_veh_h']:.0f}"])  # fmt: skip
    lines.append(md_table(["accident", "T_up (s)", "inflow (veh/h)", "seed", "regime", "queue reach (m)",
                           "reached the entrance (s after start)", "waiting at the end (veh)",
                           "system recovery (s after start)", "total time spent (veh-h)", "discharge (veh/h)"],
                          rows))  # fmt: skip
    lines += ["", f"Wall time of this invocation: {wall_s / 60:.1f} min. Versions: {versions()}.", ""]
    return "\n".join(lines)


NOT_HERE = ("train_seeds", "mobil_ps", "train_steps", "alphas", "baselines", "presets", "merge")
"""scenario I's options that the regime map (keep only, its own demands) does not take: refused beside it"""
OUT = Path("results/regime_map")


def run_from_args(args: Any) -> int:
    """`scenario1 --regime-map` with the command line's --t-up, --seeds, --steps, --out and cell flags: checked
    (UsageError, nothing written), then run in its folder; the exit code."""
    given = [name for name in NOT_HERE if getattr(args, name) is not None]
    if given:
        flag = "--" + {"mobil_ps": "mobil-p", "baselines": "baseline", "presets": "preset"}.get(given[0], given[0])
        raise UsageError(f"--regime-map runs `{POLICY}` at its demands only: {flag.replace('_', '-')} does not apply")
    t_ups = DEMANDS if args.t_ups is None else t_up_list("--t-up", args.t_ups, ControlConfig().dt_s)
    check_backend(args.backend, args.address)
    out = OUT if args.out is None else Path(args.out)
    with study_root(out, "regime_map"):  # path, lock, ownership and marker of the results folder
        return run_study(plans(args.seeds or 1, t_ups, args.steps), out, args.workers, args.backend, args.address,
                         progress=not args.quiet)  # fmt: skip
