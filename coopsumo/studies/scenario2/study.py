"""`coopsumo scenario2` (`make scenario2`): the alpha sweep of section IV.B (paper Fig. 6).

The default profile `full` (and `paper`, and `tiny` for the tests) trains one model per alpha, lane count and
training seed on that lane count's demands (taken from the model store when it holds it) and drives it greedily at
every condition (lane count, upstream departure interval T_up) of the lane count, on every evaluation seed, demands no
training saw; a model's value is its mean over them. `check` trains one alpha-conditioned network per lane count and
seed beside per-alpha models, and drives it at every alpha. `keep`, `greedy` and MOBIL (per politeness p) run on the
same evaluation seeds, every speed is measured once the road is full (`tiny`: over the whole run), and the report
(scenario2_gate_report) judges per condition whether the learner is fit to be asked (the gate) before alpha*'s
trends, a plane alpha* = b0 + b1 T_up + b2 lanes, are fitted over the conditions that pass it. The per-alpha design
(a model per condition, alpha and seed; the profiles `quick` and the old `tiny`) was retired on 2026-12-03: run it at
commit plan.RETIRED_PER_ALPHA.

Every model at one condition (lanes, T_up, alpha, seed), and every run of a policy that needs no training, is one
"cell", run in its own worker process (libsumo allows one SUMO per process), on a local process pool or on Ray; the
cells of one model wait for its training. Each finished cell is written atomically to
OUT/cells/<key>.json the moment it ends; a rerun skips finished cells and retries failed ones; a training interrupted
by SIGTERM/SIGINT is resumed from its checkpoint.

Outputs in OUT (default results/scenario2): sweep.json, cells/, train/<model>/, evals/<key>/, runs.csv, evals.csv,
alpha_star.csv, gate.csv, fig6_alpha_star_lanes.png, fig6_speed_heatmap.png, report.md; with MOBIL cells also
mobil/<key>/ and mobil_p_star.csv, with keep and greedy baselines/<key>/.

On a Ray cluster (--address), every node needs this package (same versions) and OUT must be on a
filesystem shared by all nodes: the workers write the training folders, the driver the cell records.

The plan (profiles, cells, keys) is scenario2_plan, the measures scenario2_measures and scenario2_gate, the report
scenario2_gate_report; this module runs the plan's cells on the shared runner and is the command.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from dataclasses import asdict
from functools import partial
from pathlib import Path
from typing import Any

import pandas as pd

from coopsumo.config import RoadConfig
from coopsumo.dqn_config import DQN_PRESETS
from coopsumo.errors import UsageError
from coopsumo.files import read_csv, write_atomic, write_json
from coopsumo.provenance import versions
from coopsumo.runio import Parser, run_cli
from coopsumo.studies.engine.catalogue import (
    OWN_PROFILE,
    PlanFlag,
    add_plan_flags,
    at_least,
    numbers,
    own_profile,
    plan_from_flags,
    profile_arg,
)
from coopsumo.studies.engine.cells import Cell, CellKind, Run, Study, Train
from coopsumo.studies.engine.records import (
    CellRecords,
    failed_exit,
)
from coopsumo.studies.engine.run_folders import (
    default_out,
    run_places,
    simulate_into,
    study_root,
)
from coopsumo.studies.engine.runner import add_backend_flags, check_backend
from coopsumo.studies.scenario2.gate_report import console_lines, write_lane_outputs
from coopsumo.studies.scenario2.measures import KEY_COLUMNS, evals_table, runs_table
from coopsumo.studies.scenario2.plan import (
    CLASSICAL,
    CRITERION,
    DEFAULT_PROFILE,
    EVAL_SEED_BASE,
    FULL_ROAD,
    LANE_LIST,
    MAX_LANE_DEMANDS,
    NOMINAL_CAPACITY_VEH_H_PER_LANE,
    POLICIES,
    PROFILE_HELP,
    PROFILES,
    T_UP_LIST,
    Profile,
    cell_specs,
    condition_rows,
    eval_seeds,
    lane_train_config,
    learner_of,
    own_profiles,
    train_folder,
)
from coopsumo.studies.scenario2.redraw import merge_command, recorded_sweep, sweep_study
from coopsumo.studies.scenario2.text import condition_label
from coopsumo.study_tables import SCENARIO2_EVALS, SCENARIO2_RUNS, SWEEP
from coopsumo.validation import (
    MOBIL_P_LIST,
    alpha_list,
    default_model_out,
    integer,
    model_out_dir,
    name_list,
    number_name,
    seed_count,
    steps,
    workers,
)
from coopsumo.validation import parse_number as parse_number  # '1/8' -> 0.125, kept in this module's interface

REQUIRED_SUMMARY = (CRITERION, "collisions", "teleports", "steps")
"""summary values a stored cell record must hold as finite numbers to be reused (records.record_problem); its steps
make it a run's summary, judged as one (records.runs_problem)"""
RECORD_KEYS = (*KEY_COLUMNS, "policy", "p")
"""coordinates copied from a cell's spec into its record: policy "dqn" (p None) or "mobil" (alpha None)"""


def _cell_folder(spec: dict[str, Any]) -> dict[str, Any]:
    """A cell's folder in its record: mobil/<key>/ (run_dir) for a MOBIL cell, baselines/<key>/ for keep and greedy,
    train/<key>/ (train_dir) for a DQN's (train/<train_key>/ for a lane network's: the training it shares)."""
    if spec.get("policy") in CLASSICAL:
        return {"run_dir": f"{_classical_folder(spec)}/{spec['key']}"}
    return {"train_dir": train_folder(spec)}


def _classical_folder(spec: dict[str, Any]) -> str:
    return "mobil" if spec.get("policy") == "mobil" else "baselines"


RECORDS = CellRecords(RECORD_KEYS, ("train_dir", "resumed_from_step", "train_group_cpu_s", "train_summary",
                                   "eval_summaries"),
                      _cell_folder)  # fmt: skip
"""a cell's record: its coordinates and folder, then what its run measured"""
failed_record = RECORDS.failed


# -- one cell (runs in a worker process) ------------------------------------------------------------
def work(spec: dict[str, Any]) -> Cell:
    """What the cell of `spec` does (cells.perform runs it; never raises on failure: a record of status "ok", "failed"
    with the error, or "interrupted" by SIGTERM/SIGINT, a training's checkpoint saved, to be run again).

    A DQN cell takes its model from the model store, ROOT/train/<key>/ linking to it (for a lane network's cell
    ROOT/train/<train_key>/, the training its conditions share; trained there when missing, a matching checkpoint
    resumed), and drives it greedily on every evaluation seed into ROOT/evals/<key>/eval_[a<alpha>_]s<seed>/
    (evaluate_model; a lane network told its alpha); a MOBIL cell runs one simulation into ROOT/mobil/<key>/, a keep or
    greedy cell into ROOT/baselines/<key>/, its configuration the run's SimConfig, or {"run": SimConfig,
    "trajectory_every_steps": K} when the full-road speed is measured.
    """
    from coopsumo.config import sim_config_from_dict

    config, every = spec["config"], spec["config"].get("trajectory_every_steps", 0)
    if spec.get("policy") in CLASSICAL:
        run = Run(sim_config_from_dict(config.get("run", config)), f"{_classical_folder(spec)}/{spec['key']}")
        return Cell(runs=(run,), label=spec["key"], measure=partial(_classical_run, trajectory_every=every))
    name = spec.get("train_key", spec["key"])
    evals = [sim_config_from_dict(raw) for raw in config["evals"]]
    conditioned = spec.get("conditioned", False)  # a lane network told its alpha (every evaluation's is the cell's)
    folder = f"evals/{spec.get('evals_key', name)}"
    runs = tuple(Run(ev, f"{folder}/eval_a{number_name(ev.reward.alpha)}_s{ev.seed}" if conditioned
                     else f"{folder}/eval_s{ev.seed}") for ev in evals)  # fmt: skip
    measure = partial(evaluate_model, trajectory_every=every) if every else evaluate_model  # tests fake it
    train = Train(spec["training"], f"train/{name}", alpha=evals[0].reward.alpha if conditioned else None)
    return Cell(train, runs, spec["key"], measure, pooled=True)


CELLS = CellKind(RECORDS, work)
run_cell = CELLS.run_cell


def evaluate_model(config: dict[str, Any], out: Path, label: str, trajectory_every: int = 0) -> dict[str, Any]:
    """One greedy evaluation (a SimConfig dict whose policy names the model) into out, as a DQN cell drives each
    (work): its summary, with the run's mean loop flow (veh/h per lane) and occupancy (%) from SUMO's
    detectors.xml; with trajectory_every, trajectories sampled every that many steps and the full-road speed measured
    on them (full_road_measures)."""
    from coopsumo.report.analysis import read_detectors

    summary = simulate_into(config, out, label, trajectory_every=trajectory_every)
    det = read_detectors(out / "detectors.xml")
    summary.update(loop_flow_veh_h_per_lane=round(float(det["flow_veh_h"].mean()), 2),
                   loop_occupancy_pct=round(float(det["occupancy_pct"].mean()), 4))  # fmt: skip
    if trajectory_every:
        summary.update(full_road_measures(out))
    return summary


def full_road_measures(out: Path) -> dict[str, float | None]:
    """The run folder's full-road speed and when it starts (scenario2_gate.full_road_speed on its
    trajectories.parquet); None each when the run ended before the first vehicle inserted had left the road."""
    from coopsumo.studies.scenario2.gate import full_road_speed

    speed, start = full_road_speed(pd.read_parquet(out / "trajectories.parquet", columns=["time_s", "vid",
                                                                                          "speed_mps"]))
    if not math.isfinite(speed):
        return {FULL_ROAD: None, "full_road_from_s": None}
    return {FULL_ROAD: round(speed, 6), "full_road_from_s": round(start, 3)}


def _classical_run(config: dict[str, Any], out: Path, label: str, trajectory_every: int = 0) -> dict[str, Any]:
    """One run of a MOBIL, keep or greedy cell: its summary, with trajectory_every its full-road speed too."""
    summary = simulate_into(config, out, label, trajectory_every=trajectory_every)
    if trajectory_every:
        summary.update(full_road_measures(out))
    return summary


def _order(todo: list[dict[str, Any]]) -> None:
    """Sort the cells to run, in place: the busiest roads first and the short runs of MOBIL, keep and greedy last
    (a shorter tail); a lane network's cells that wait for its training ("after") behind those that start one."""
    todo.sort(key=lambda s: (s.get("policy") in CLASSICAL, "after" in s, -s["lanes"] * s["load"]))


def _sweep_meta(profile: Profile, cells: int, backend_name: str, address: str | None, workers: int,
                n_boot: int) -> dict[str, Any]:  # fmt: skip
    """sweep.json before the cells run: the profile, its learner, the conditions and how the sweep runs."""
    return {
        "profile": asdict(profile),
        "learner": learner_of(profile),
        "conditions": condition_rows(profile),
        "cells": cells,
        "trainings": profile.n_trainings(),
        "criterion": profile.criterion,
        "nominal_capacity_veh_h_per_lane": NOMINAL_CAPACITY_VEH_H_PER_LANE,
        "backend": backend_name,
        "address": address,
        "workers": workers,
        "bootstrap_replicates": n_boot,
        "versions": versions(),
    }


def _places(root: Path, spec: dict[str, Any]) -> list[Path]:
    """A cell's run folders (a user's files there refused before any cell runs; issue 82, probe 7, I1): a DQN
    cell's evaluations under evals/<key>/, a MOBIL, keep or greedy cell's one run."""
    if spec.get("policy") in CLASSICAL:
        return [root / _classical_folder(spec) / spec["key"]]
    return run_places(root / "evals" / spec.get("evals_key", spec.get("train_key", spec["key"])), nested=True)


STUDY = Study("scenario2", CELLS, REQUIRED_SUMMARY, _places, _order, in_place=True, checks=(CELLS.unlike_runs,),
              made=lambda spec: {"train_dir": train_folder(spec)})  # fmt: skip
"""the sweep as the engine runs it: a record naming another cell's training rerun (made), and one whose runs are not
its run folders' (CellKind.unlike_runs; probe 14, F1)"""


def run_sweep(profile: Profile, root: Path, backend_name: str = "local", workers: int = 1,
              address: str | None = None, progress: bool = True, n_boot: int = 1000) -> dict[str, Any]:  # fmt: skip
    """Run (or finish) the sweep in `root` and write every output; returns the sweep.json content."""
    root = root.resolve()
    specs = cell_specs(profile)
    meta = _sweep_meta(profile, len(specs), backend_name, address, workers, n_boot)

    def begin() -> None:  # a finished sweep's sweep.json stays whole until its successor is (_finish)
        if not (root / "sweep.json").exists():
            write_json(root / "sweep.json", meta)

    roads = [RoadConfig(lanes=lanes) for lanes in profile.lanes]  # built once, not in workers
    return STUDY.run(specs, root, meta, profile.name, partial(_finish, root, profile), roads=roads, workers=workers,
                     backend=backend_name, address=address, progress=progress, begin=begin)  # fmt: skip


def _finish(root: Path, profile: Profile, records: list[dict[str, Any]], meta: dict[str, Any]) -> None:
    """Write the sweep's tables, figures, report and sweep.json from its cells' records, each checked against its
    schema (the limits a merge reads them by) before any is written: a refusal leaves the outputs as they were, a
    finished sweep's whole."""
    runs, evals = runs_table(records), evals_table(records)
    meta.update(cells_ok=int((runs["status"] == "ok").sum()), cells_failed=int((runs["status"] != "ok").sum()),
                failed_cells=runs.loc[runs["status"] != "ok", "key"].tolist(),
                cell_wall_seconds_sum=round(float(pd.to_numeric(runs["cell_wall_s"]).sum()), 1))
    SCENARIO2_RUNS.check_frame(runs, root / "runs.csv")  # the limits the merge reads them by (study_tables)
    SCENARIO2_EVALS.check_frame(evals, root / "evals.csv")
    SWEEP.check(meta, root / "sweep.json")
    write_atomic(root / "runs.csv", lambda tmp: runs.to_csv(tmp, index=False))
    write_atomic(root / "evals.csv", lambda tmp: evals.to_csv(tmp, index=False))
    write_lane_outputs(root, runs, evals, profile, meta, meta["bootstrap_replicates"])
    SWEEP.check(meta, root / "sweep.json")  # the schema a merge reads it by, with what the report added
    write_json(root / "sweep.json", meta)


def chosen_profile(text: str) -> Profile:
    """--profile's profile: a packaged one by name, or one of a file of one's own (PATH.toml[:NAME]: the packaged
    file's format, every profile checked as the packaged ones are; catalogue.own_profile)."""
    return PROFILES[text] if text in PROFILES else own_profile(text, own_profiles, PROFILES, "default")


def _seeds(n: int, _profile: Profile) -> dict[str, Any]:
    if n < 1:
        raise UsageError(f"seeds must be >= 1, got {n}")
    return {"seeds": tuple(range(1, n + 1))}


def _alphas(text: str, profile: Profile) -> dict[str, Any]:
    alphas = tuple(sorted(set(alpha_list("--alphas", text))))
    # a check compares the networks with per-alpha models at the alphas of the grid it keeps
    return {"alphas": alphas, "check_alphas": tuple(a for a in profile.check_alphas if a in alphas)}


def _t_ups(text: str, profile: Profile) -> dict[str, Any]:
    t_ups = tuple(sorted(set(T_UP_LIST.parse("--t-up", text))))
    if len(t_ups) > MAX_LANE_DEMANDS:
        raise UsageError(f"--t-up: profile {profile.name} trains each lane count's network on all its T_ups, at "
                         f"most {MAX_LANE_DEMANDS}; got {len(t_ups)}")  # fmt: skip
    return {"t_up_s": t_ups}


def _policies(text: str, _profile: Profile) -> dict[str, Any]:
    policies = set(name_list("--policies", text, POLICIES))
    return {"policies": tuple(x for x in POLICIES if x in policies)}


def _mobil_ps(text: str, profile: Profile) -> dict[str, Any]:
    if "mobil" not in profile.policies:
        raise UsageError("--mobil-p is for --policies with mobil")
    return {"mobil_ps": tuple(sorted(set(MOBIL_P_LIST.parse("--mobil-p", text))))}


PLAN_FLAGS = (
    PlanFlag(("--steps",), at_least("train_steps", "steps", bound="positive"), "training steps per cell",
             lambda f: f"{f.train_steps:,}", steps),
    PlanFlag(("--eval-steps",), at_least("eval_steps", "eval-steps", bound="positive"), "evaluation steps per cell",
             lambda f: f"{f.eval_steps:,}", steps),
    PlanFlag(("--seeds", "--train-seeds"), _seeds, "models per condition and alpha: training seeds 1..N",
             lambda f: len(f.seeds), seed_count),
    PlanFlag(("--eval-seeds",), lambda n, _: {"eval_seeds": eval_seeds(n)},
             f"evaluation seeds {EVAL_SEED_BASE + 1}..{EVAL_SEED_BASE}+N, which no training sees: every model, and "
             "MOBIL, is evaluated greedily on each", lambda f: len(f.eval_seeds), seed_count),
    PlanFlag(("--lanes",), lambda text, _: {"lanes": tuple(sorted({int(x) for x in LANE_LIST.parse("--lanes", text)}))},
             "comma-separated lane counts", lambda f: numbers(f.lanes)),
    PlanFlag(("--alphas",), _alphas, "comma-separated alphas, fractions allowed: 0,1/8,2", lambda f: numbers(f.alphas)),
    PlanFlag(("--t-up",), _t_ups, "fixed comma-separated T_up list (s) for every lane count, instead of the "
             "profile's load grid (default: the load grid)"),
    PlanFlag(("--policies",), _policies, "comma-separated: dqn (the models), mobil (one MOBIL run per politeness p "
             "and evaluation seed), keep, greedy (one run per evaluation seed; no training)",
             lambda f: ",".join(f.policies)),
    PlanFlag(("--mobil-p",), _mobil_ps, "comma-separated MOBIL politeness values", lambda f: numbers(f.mobil_ps)),
    PlanFlag(("--preset",), lambda name, _: {"preset": name}, "learner preset of the DQN cells", lambda f: f.preset,
             choices=sorted(DQN_PRESETS)),
)
"""the flags that set the profile's fields, in the order they apply (--mobil-p reads --policies')"""


def profile_from_args(args: Any) -> Profile:
    """The chosen profile with the command line's overrides applied and checked."""
    return plan_from_flags(chosen_profile(args.profile), args, PLAN_FLAGS)


def build_parser() -> Parser:
    p = Parser(prog="coopsumo scenario2", description="Scenario II: the alpha sweep over lanes and inflows.")
    p.add_argument("--profile", type=profile_arg(sorted(PROFILES)), default=DEFAULT_PROFILE,
                   help="grid, models and step counts: " + "; ".join(f"{k} ({v})" for k, v in PROFILE_HELP.items())
                   + f"; or a profile of your own in a file of scenario2.toml's format, {OWN_PROFILE} "
                   "(docs/studies.md)")  # fmt: skip
    p.add_argument("--out", type=model_out_dir, default=None,
                   help=f"results folder (default {default_out('scenario2', DEFAULT_PROFILE, DEFAULT_PROFILE)}, "
                        "another profile results/scenario2_<profile>)")  # fmt: skip
    add_backend_flags(p)
    p.add_argument("--workers", type=workers, default=os.cpu_count() or 1,
                   help="parallel cells (default: every core); with --address the cluster decides")  # fmt: skip
    add_plan_flags(p, PLAN_FLAGS, PROFILES)
    p.add_argument("--bootstrap", type=integer(0, 100_000), default=1000,
                   help="bootstrap replicates over seeds (default 1000)")  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--merge", default=None, metavar="DIR,DIR,...",
                   help="nothing run: finished sweeps of one lane-network profile, each run with its own --lanes "
                        "(a study run one lane count at a time), merged into --out with its tables and report "
                        "(default: none, the sweep is run)")  # fmt: skip
    return p


def given_options(parser: Parser, argv: list[str] | None) -> set[str]:
    """The options set on the command line `argv` (None: sys.argv's), whatever their values: parsed again into a
    namespace holding a mark under every name, which only the options given replace."""
    unset = object()
    names = {action.dest for action in parser._actions if action.dest != "help"}
    parsed = parser.parse_args(argv, namespace=argparse.Namespace(**dict.fromkeys(names, unset)))
    return {name for name in names if getattr(parsed, name) is not unset}


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def body() -> int:
        if args.merge is not None:
            return merge_command(args, given_options(build_parser(), argv))
        profile = profile_from_args(args)
        if args.workers < 1:
            raise UsageError(f"workers must be >= 1, got {args.workers}")
        if args.bootstrap < 0:
            raise UsageError(f"bootstrap must be >= 0, got {args.bootstrap}")
        check_backend(args.backend, args.address)
        for lanes in profile.lanes:  # a lane network's settings (e.g. at most 10 demands) checked before any folder
            lane_train_config(lanes, profile.seeds[0], profile).validate()
        default = default_out("scenario2", profile.name, DEFAULT_PROFILE)
        if args.out is None:
            args.out = default_model_out(default)
        # path, lock, ownership (another profile's sweep or a merge refused; its own resumed) and marker of the folder
        with study_root(args.out, "scenario2", sweep_study(profile), recorded_sweep,
                        f"pick another --out (the {profile.name} profile's default: {default})", trains=True,
                        profile=chosen_profile(args.profile)):
            meta = run_sweep(profile, args.out, args.backend, args.workers, args.address, not args.quiet,
                             args.bootstrap)  # fmt: skip
        if "dqn" in profile.policies:
            table = read_csv(args.out / "alpha_star.csv")
            for r in table.itertuples():
                if r.cells_failed:
                    print(f"{condition_label(r.lanes, r.t_up_s)}: no alpha* ({r.cells_failed} cells failed)")
                    continue
                print(f"{condition_label(r.lanes, r.t_up_s)}: alpha* = {r.alpha_star:g} "
                      f"(win share {r.win_share:.0%}, bootstrap {r.boot_support:.0%})")  # fmt: skip
            plane = meta.get("plane", {})
            if "b0" in plane:
                print(f"plane: alpha* = {plane['b0']:.3f} {plane['b1']:+.3f} T_up {plane['b2']:+.3f} lanes, "
                      f"R2 = {plane['r2']:.3f}")  # fmt: skip
            else:
                print(plane.get("error", ""))
            print("\n".join(console_lines(args.out)))
        if "mobil" in profile.policies:
            for r in read_csv(args.out / "mobil_p_star.csv").itertuples():
                if r.cells_failed:
                    print(f"{condition_label(r.lanes, r.t_up_s)}: no MOBIL p* ({r.cells_failed} cells failed)")
                    continue
                print(f"{condition_label(r.lanes, r.t_up_s)}: MOBIL p* = {r.p_star:g} (win share {r.win_share:.0%})")
        print(f"scenario2: {meta['cells_ok']} ok, {meta['cells_failed']} failed, "
              f"{meta['wall_seconds'] / 60:.1f} min; report: {args.out / 'report.md'}")  # fmt: skip
        return failed_exit("scenario2", meta["failed_cells"], meta["cells"], args.out)

    return run_cli("scenario2", body)


if __name__ == "__main__":
    sys.exit(main())
