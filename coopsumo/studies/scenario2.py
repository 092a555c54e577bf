"""`python -m coopsumo.scenario2` (`make scenario2`): the alpha sweep of section IV.B (paper Fig. 6).

For every condition (lane count, upstream departure interval T_up) and every lane-change
penalty alpha, a model is trained in free flow and evaluated greedily on the same condition
(`train.train` does both), repeated over seeds. alpha* is the alpha with the best mean
travelling speed over seeds; its uncertainty is given by per-seed win shares and a bootstrap
over seeds. A plane alpha* = b0 + b1 T_up + b2 lanes is fitted over the conditions.

With `--policies dqn,mobil`, MOBIL cells (lanes, T_up, politeness p, seed) are added: no training,
one run of `mobil:p=P` on the same condition, seed and step count as a DQN cell's evaluation. p* is
the p with the best mean speed over seeds; the report puts alpha* and p* side by side.

Every (lanes, T_up, alpha, seed) is one "cell", run in its own worker process (libsumo allows
one SUMO per process), on a local process pool or on Ray. Each finished cell is written
atomically to OUT/cells/<key>.json the moment it ends; a rerun skips finished cells and
retries failed ones; a training interrupted by SIGTERM/SIGINT is resumed from its checkpoint.

Outputs in OUT (default results/scenario2): sweep.json, cells/, train/<key>/, runs.csv,
alpha_star.csv, fig6_alpha_star.png, fig6_speed_heatmap.png, report.md; with MOBIL cells also
mobil/<key>/ and mobil_p_star.csv.

On a Ray cluster (--address), every node needs this package (same versions) and OUT must be on a
filesystem shared by all nodes: the workers write the training folders, the driver the cell records.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from coopsumo.config import (
    DQN_PRESETS,
    MAX_LANES,
    MIN_LANES,
    ControlConfig,
    DemandConfig,
    RewardConfig,
    RoadConfig,
    SimConfig,
    TrainConfig,
    to_dict,
)
from coopsumo.runio import Parser, UsageError, run_cli, versions, write_json
from coopsumo.studies.runner import (
    add_backend_flags,
    as_failed,
    blank_record,
    cell_path,
    check_backend,
    checked_record,
    execute,
    failed_exit,
    make_backend,
    read_record,
    reusable_keys,
    run_recorded,
    sigterm_interrupts,
    simulate_into,
    train_resuming,
)
from coopsumo.studies.stats import (
    CRITERION,
    PlaneFit,
    PlaneFitError,
    alpha_star_table,
    fit_plane,
    mobil_p_star_table,
    plane_bootstrap,
    policy_rows,
    side_by_side_table,
)
from coopsumo.validation import (
    alpha_list,
    integer,
    min_t_up_s,
    number_list,
    number_name,
    out_dir,
    seed_count,
    steps,
    t_up_note,
    workers,
)
from coopsumo.validation import parse_number as parse_number  # '1/8' -> 0.125, kept in this module's interface

PAPER_ALPHAS = (0.0, 0.125, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 24.0, 32.0, 48.0)
"""eq. (12) of the paper"""
QUICK_ALPHAS = (0.0, 0.125, 0.25, 0.5, 1.0, 2.0, 8.0)
"""the paper's small values and where the default learner's lane changes fall to none (results/learning)"""
NOMINAL_CAPACITY_VEH_H_PER_LANE = 1800.0
"""capacity used to place the T_up grid: load 1 means T_up = 3600 / (lanes * 1800) s (near capacity)"""
"""the paper's criterion for alpha*: mean travelling speed"""
METRIC_COLUMNS = (
    "steps", "sim_seconds", "departed", "arrived", "insertion_blocked", "insertion_pending_at_end",
    "collisions", "teleports", "lane_changes", "lane_changes_rejected", "lane_changes_per_vehicle",
    "mean_speed_mps", "mean_travel_time_s", "throughput_veh_per_h",
    "train_mean_speed_mps", "train_lane_changes", "train_collisions", "train_updates",
)  # fmt: skip
"""Deterministic columns of runs.csv (same seed -> same value on any backend)."""
REQUIRED_SUMMARY = (CRITERION, "collisions", "teleports")
"""summary values a stored cell record must hold as finite numbers to be reused (runner.record_problem)"""
TRAIN_COLUMNS = {
    "train_mean_speed_mps": "mean_speed_mps",
    "train_lane_changes": "lane_changes",
    "train_collisions": "collisions",
    "train_updates": "updates",
}
"""runs.csv columns taken from the training run's train_summary.json"""
COUNT_COLUMNS = frozenset(("steps", "departed", "arrived", "insertion_blocked", "insertion_pending_at_end",
                           "collisions", "teleports", "lane_changes", "lane_changes_rejected", "train_lane_changes",
                           "train_collisions", "train_updates"))  # fmt: skip
KEY_COLUMNS = ("key", "lanes", "t_up_s", "load", "alpha", "seed")
RECORD_KEYS = (*KEY_COLUMNS, "policy", "p")
"""coordinates copied from a cell's spec into its record: policy "dqn" (p None) or "mobil" (alpha None)"""
POLICIES = ("dqn", "mobil")
"""a cell whose worker process died this many times is recorded as failed"""


# -- the plan ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Profile:
    """Grid and step counts of one sweep."""

    name: str
    lanes: tuple[int, ...]
    loads: tuple[float, ...]
    """inflow as a share of lanes x 1,800 veh/h; T_up = 3600 / (load x lanes x 1800) s, 2 decimals"""
    alphas: tuple[float, ...]
    seeds: tuple[int, ...]
    train_steps: int
    """training steps (0.1 s) per cell"""
    eval_steps: int
    """greedy evaluation steps per cell"""
    t_up_s: tuple[float, ...] = ()
    """if set, this fixed T_up list (s) replaces the load grid for every lane count"""
    policies: tuple[str, ...] = ("dqn",)
    """"dqn" (train and evaluate per alpha) and/or "mobil" (evaluate MOBIL per politeness p, no training)"""
    mobil_ps: tuple[float, ...] = (0.0, 0.25, 0.5, 1.0)
    """MOBIL politeness grid, used when "mobil" is in policies"""
    preset: str = "default"
    """the learner preset of every DQN cell (config.DQN_PRESETS)"""

    def conditions(self) -> list[tuple[int, float, float]]:
        """(lanes, T_up s, load) of every condition, by lanes then decreasing T_up."""
        out = []
        for n in self.lanes:
            if self.t_up_s:
                pairs = [(t, load_of(n, t)) for t in self.t_up_s]
            else:
                pairs = [(t_up_for(n, load), load) for load in self.loads]
            out += [(n, t, load) for t, load in sorted(pairs, reverse=True)]
        return out

    def n_cells(self) -> int:
        per_condition = len(self.alphas) if "dqn" in self.policies else 0
        per_condition += len(self.mobil_ps) if "mobil" in self.policies else 0
        return len(self.conditions()) * per_condition * len(self.seeds)


def t_up_for(lanes: int, load: float) -> float:
    """T_up (s, 2 decimals) giving `load` x lanes x 1,800 veh/h."""
    return round(3600.0 / (load * lanes * NOMINAL_CAPACITY_VEH_H_PER_LANE), 2)


def load_of(lanes: int, t_up_s: float) -> float:
    return round(3600.0 / (t_up_s * lanes * NOMINAL_CAPACITY_VEH_H_PER_LANE), 4)


PROFILES = {
    "tiny": Profile("tiny", lanes=(2,), loads=(0.25, 0.5), alphas=(0.0, 8.0), seeds=(1, 2),
                    train_steps=300, eval_steps=300, mobil_ps=(0.0, 1.0)),
    "quick": Profile("quick", lanes=(2, 3, 4), loads=(0.25, 0.5, 0.75, 1.0), alphas=QUICK_ALPHAS,
                     seeds=(1, 2, 3), train_steps=8000, eval_steps=3000),
    "paper": Profile("paper", lanes=(2, 3, 4, 5, 6), loads=(0.2, 0.4, 0.6, 0.8, 1.0), alphas=PAPER_ALPHAS,
                     seeds=tuple(range(1, 11)), train_steps=90_000, eval_steps=9000),
}  # fmt: skip


def cell_key(lanes: int, t_up_s: float, alpha: float, seed: int) -> str:
    return f"L{lanes}_T{number_name(t_up_s)}_a{number_name(alpha)}_s{seed}"


def mobil_key(lanes: int, t_up_s: float, p: float, seed: int) -> str:
    return f"L{lanes}_T{number_name(t_up_s)}_mobil_p{number_name(p)}_s{seed}"


def train_config(lanes: int, t_up_s: float, alpha: float, seed: int, profile: Profile) -> TrainConfig:
    """Scenario II training (free flow) plus the greedy evaluation on the same condition."""
    sim = SimConfig(
        road=RoadConfig(lanes=lanes),
        demand=DemandConfig(t_up_s=t_up_s),
        reward=RewardConfig(alpha=alpha),
        steps=profile.train_steps,
        seed=seed,
        policy="dqn",
    )
    return TrainConfig(sim=sim, dqn=DQN_PRESETS[profile.preset], eval_steps=profile.eval_steps)


def mobil_config(lanes: int, t_up_s: float, p: float, seed: int, profile: Profile) -> SimConfig:
    """A MOBIL cell: one run of mobil:p=P in free flow, like a DQN cell's evaluation (condition, seed, steps)."""
    return SimConfig(
        road=RoadConfig(lanes=lanes),
        demand=DemandConfig(t_up_s=t_up_s),
        steps=profile.eval_steps,
        seed=seed,
        policy=f"mobil:p={p}",
    )


def cell_specs(profile: Profile) -> list[dict[str, Any]]:
    """One JSON-ready spec per cell: key, coordinates and the full configuration as a dict.

    A DQN cell's configuration is a TrainConfig, a MOBIL cell's a SimConfig.
    """
    specs = []

    def add(key: str, lanes: int, t_up: float, load: float, seed: int, policy: str,
            alpha: float | None, p: float | None, cfg: TrainConfig | SimConfig) -> None:  # fmt: skip
        cfg.validate()
        specs.append({"key": key, "lanes": lanes, "t_up_s": t_up, "load": load, "alpha": alpha, "seed": seed,
                      "policy": policy, "p": p, "config": json.loads(json.dumps(to_dict(cfg)))})  # fmt: skip

    for lanes, t_up, load in profile.conditions():
        if "dqn" in profile.policies:
            for alpha in profile.alphas:
                for seed in profile.seeds:
                    add(cell_key(lanes, t_up, alpha, seed), lanes, t_up, load, seed, "dqn", alpha, None,
                        train_config(lanes, t_up, alpha, seed, profile))  # fmt: skip
        if "mobil" in profile.policies:
            for p in profile.mobil_ps:
                for seed in profile.seeds:
                    add(mobil_key(lanes, t_up, p, seed), lanes, t_up, load, seed, "mobil", None, p,
                        mobil_config(lanes, t_up, p, seed, profile))  # fmt: skip
    return specs


# -- one cell (runs in a worker process) ------------------------------------------------------------
def run_cell(spec: dict[str, Any], root: str) -> dict[str, Any]:
    """Run one cell and return its record (never raises on failure).

    A DQN cell trains and evaluates into ROOT/train/<key>/ (a matching checkpoint there is resumed
    instead of starting afresh); a MOBIL cell runs one simulation into ROOT/mobil/<key>/.
    status "ok" (with the evaluation summary), "failed" (with the error) or "interrupted"
    (SIGTERM/SIGINT: a checkpoint was saved when training, the cell is to be run again).
    """
    record = new_record(spec)
    cell = _run_mobil if spec.get("policy") == "mobil" else _run_dqn
    return run_recorded(record, lambda: cell(spec, Path(root), record))


def _run_dqn(spec: dict[str, Any], root: Path, record: dict[str, Any]) -> None:
    """Train and evaluate a DQN cell into ROOT/train/<key>/; fills `record`. A stop by signal -> KeyboardInterrupt."""
    out = root / "train" / spec["key"]
    summary, record["resumed_from_step"] = train_resuming(spec["config"], out)
    record["summary"] = {k: v for k, v in summary.items() if k != "policy"}
    record["train_summary"] = json.loads((out / "train_summary.json").read_text())


def _run_mobil(spec: dict[str, Any], root: Path, record: dict[str, Any]) -> None:
    """Run a MOBIL cell (no training: one simulation) into ROOT/mobil/<key>/; fills `record`."""
    record["summary"] = simulate_into(spec["config"], root / "mobil" / spec["key"], spec["key"])


def new_record(spec: dict[str, Any]) -> dict[str, Any]:
    """A cell's record before it runs: coordinates, configuration and its folder; nothing measured yet."""
    record = blank_record(spec, RECORD_KEYS, train_dir=None, resumed_from_step=None, train_summary=None)
    if spec.get("policy") == "mobil":
        record["run_dir"] = f"mobil/{spec['key']}"
    else:
        record["train_dir"] = f"train/{spec['key']}"
    return record


def failed_record(spec: dict[str, Any], error: str) -> dict[str, Any]:
    """The record of a cell whose worker died or whose task could not run."""
    return as_failed(new_record(spec), error)


# -- running the sweep ----------------------------------------------------------------------------


def run_sweep(profile: Profile, root: Path, backend_name: str = "local", workers: int = 1,
              address: str | None = None, progress: bool = True, n_boot: int = 1000) -> dict[str, Any]:  # fmt: skip
    """Run (or finish) the sweep in `root` and write every output; returns the sweep.json content."""
    start = time.perf_counter()
    root = root.resolve()
    try:
        (root / "cells").mkdir(parents=True, exist_ok=True)
        (root / "train").mkdir(exist_ok=True)
    except OSError as err:
        raise UsageError(f"cannot write output folder {root}: {err.strerror}") from None
    specs = cell_specs(profile)
    done_keys = reusable_keys(root, specs, "scenario2", REQUIRED_SUMMARY)
    done = [s for s in specs if s["key"] in done_keys]
    todo = [s for s in specs if s["key"] not in done_keys]
    retry = [s for s in todo if (read_record(root, s) or {}).get("status") == "failed"]
    # the busiest roads first and the short MOBIL runs last: a shorter tail
    todo.sort(key=lambda s: (s.get("policy") == "mobil", -s["lanes"] * s["load"]))
    meta = {
        "profile": asdict(profile),
        "conditions": [
            {"lanes": n, "t_up_s": t, "load": load, "inflow_veh_h": round(3600 / t, 1)}
            for n, t, load in profile.conditions()
        ],  # fmt: skip
        "cells": len(specs),
        "criterion": CRITERION,
        "nominal_capacity_veh_h_per_lane": NOMINAL_CAPACITY_VEH_H_PER_LANE,
        "backend": backend_name,
        "address": address,
        "workers": workers,
        "bootstrap_replicates": n_boot,
        "versions": versions(),
    }
    write_json(root / "sweep.json", meta)
    print(f"scenario2: profile {profile.name}: {len(specs)} cells, {len(done)} already done, {len(retry)} "
          f"failed before (retried), {len(todo)} to run on the {backend_name} backend", file=sys.stderr)  # fmt: skip
    if todo:
        from coopsumo.sim.network import build_net

        for lanes in sorted({s["lanes"] for s in todo}):
            build_net(RoadConfig(lanes=lanes))  # once here, not concurrently in the workers
        backend = make_backend(backend_name, workers, address, run_cell)
        try:
            with sigterm_interrupts():
                execute(todo, root, backend, len(specs), len(done), progress, failed_record, desc="scenario2 cells")
        finally:
            backend.close()
    records = [checked_record(json.loads(cell_path(root, s["key"]).read_text()), REQUIRED_SUMMARY) for s in specs]
    runs = runs_table(records)
    runs.to_csv(root / "runs.csv", index=False)
    wall = time.perf_counter() - start
    meta.update(wall_seconds=round(wall, 1), cells_run=len(todo), cells_ok=int((runs["status"] == "ok").sum()),
                cells_failed=int((runs["status"] != "ok").sum()),
                failed_cells=runs.loc[runs["status"] != "ok", "key"].tolist(),
                cell_wall_seconds_sum=round(float(pd.to_numeric(runs["cell_wall_s"]).sum()), 1),
                cell_cpu_seconds_sum=round(float(pd.to_numeric(runs["cell_cpu_s"]).sum()), 1))  # fmt: skip
    write_outputs(root, runs, profile, meta, n_boot)
    write_json(root / "sweep.json", meta)
    return meta


# -- tables -------------------------------------------------------------------------------------------
def runs_table(records: Sequence[dict[str, Any]]) -> pd.DataFrame:
    """One tidy row per cell: coordinates, status, error, every evaluation summary metric, bookkeeping.

    `policy` is "dqn" or "mobil"; `p` (MOBIL's politeness) is NaN for DQN rows, `alpha` NaN for MOBIL rows.
    """
    rows = []
    for r in records:
        row: dict[str, Any] = {k: r[k] for k in KEY_COLUMNS}
        row.update(policy=r.get("policy") or "dqn", p=r.get("p"), status=r["status"], error=r.get("error"))
        summary = r.get("summary") or {}
        train = r.get("train_summary") or {}
        for k in METRIC_COLUMNS:
            row[k] = train.get(TRAIN_COLUMNS[k]) if k in TRAIN_COLUMNS else summary.get(k)
        row.update({k: v for k, v in summary.items() if k not in row and k != "scenario"})
        row.update(train_wall_seconds=train.get("wall_seconds"), cell_wall_s=r.get("cell_wall_s"),
                   cell_cpu_s=r.get("cell_cpu_s"),
                   resumed_from_step=r.get("resumed_from_step"), train_dir=r.get("train_dir"))  # fmt: skip
        rows.append(row)
    table = pd.DataFrame(rows)
    for k in METRIC_COLUMNS:
        table[k] = pd.to_numeric(table[k], errors="coerce").astype("Int64" if k in COUNT_COLUMNS else float)
    for k in ("alpha", "p"):
        table[k] = pd.to_numeric(table[k], errors="coerce").astype(float)
    table["resumed_from_step"] = pd.to_numeric(table["resumed_from_step"], errors="coerce").astype("Int64")
    return table


# -- the plane ------------------------------------------------------------------------------------------


def trend_statements(fit: PlaneFit, boot: dict[str, float]) -> list[str]:
    """Plain statements of whether the paper's two trends hold (b1 < 0, b2 < 0)."""
    out = []
    for coef, name, trend, unit, key in (
        (fit.b1, "b1", "alpha* grows as T_up shrinks (higher inflow)", "per s of T_up", "b1"),
        (fit.b2, "b2", "alpha* grows as the lane count shrinks", "per lane", "b2"),
    ):
        holds = coef < 0
        text = (f"**{'Holds' if holds else 'Does not hold'}**: the paper's trend \"{trend}\" needs {name} < 0; "
                f"here {name} = {coef:+.3f} {unit}")  # fmt: skip
        if boot:
            text += (f" (bootstrap over seeds: {name} < 0 in {boot[f'{key}_negative_share']:.0%} of "
                     f"{boot['replicates']} replicates, 90% interval [{boot[f'{key}_p05']:+.3f}, "
                     f"{boot[f'{key}_p95']:+.3f}])")  # fmt: skip
        out.append(text + ".")
    return out


def paper_cost_estimate(runs: pd.DataFrame, train_steps: int, paper: Profile,
                        cluster_cpus: int = 64) -> dict[str, float]:  # fmt: skip
    """What the paper profile would cost, extrapolated from this sweep's DQN cells (labelled as such).

    The wall seconds per training step (train_steps per cell) and per evaluation step of every successful
    cell that was not resumed are fitted as a + b * inflow (veh/h) by least squares; each paper cell then
    costs its train_steps and eval_steps at its inflow. Returns the fits, the sum in core-hours, and the wall
    time on this machine's cores and on a Ray cluster of cluster_cpus CPUs (perfect scaling assumed).
    Empty when fewer than 2 such cells exist.
    """
    needed = {"status", "t_up_s", "train_wall_seconds", "wall_seconds", "steps", "resumed_from_step"}
    if not needed <= set(runs.columns):
        return {}
    dqn = policy_rows(runs, "dqn")
    ok = dqn[(dqn["status"] == "ok") & dqn["resumed_from_step"].isna()].dropna(subset=["train_wall_seconds"])
    if len(ok) < 2:
        return {}
    inflow = 3600.0 / ok["t_up_s"].to_numpy(float)
    design = np.column_stack([np.ones_like(inflow), inflow])
    train = ok["train_wall_seconds"].to_numpy(float) / train_steps
    fit_train = np.linalg.lstsq(design, train, rcond=None)[0]
    fit_eval = np.linalg.lstsq(design, ok["wall_seconds"].to_numpy(float) / ok["steps"].to_numpy(float), rcond=None)[0]
    total = 0.0
    for _, t_up, _ in paper.conditions():
        q = 3600.0 / t_up
        per_cell = paper.train_steps * (fit_train[0] + fit_train[1] * q)
        total += (per_cell + paper.eval_steps * (fit_eval[0] + fit_eval[1] * q)) * len(paper.alphas) * len(paper.seeds)
    cores = os.cpu_count() or 1
    return {
        "cells": float(len(paper.conditions()) * len(paper.alphas) * len(paper.seeds)),
        "train_s_per_step_a": float(fit_train[0]), "train_s_per_step_b_per_veh_h": float(fit_train[1]),
        "eval_s_per_step_a": float(fit_eval[0]), "eval_s_per_step_b_per_veh_h": float(fit_eval[1]),
        "core_hours": total / 3600.0, "machine_cores": float(cores), "machine_days": total / cores / 86400.0,
        "cluster_cpus": float(cluster_cpus), "cluster_hours": total / cluster_cpus / 3600.0,
        "max_measured_inflow_veh_h": float(inflow.max()),
        "max_paper_inflow_veh_h": max(3600.0 / t for _, t, _ in paper.conditions()),
    }  # fmt: skip


# -- outputs -------------------------------------------------------------------------------------------
def condition_label(lanes: int, t_up_s: float) -> str:
    return f"{lanes} lanes, T_up {number_name(t_up_s)} s"


def withhold_incomplete(table: pd.DataFrame, star: str) -> pd.DataFrame:
    """`table` (alpha_star_table or mobil_p_star_table) with no winner (NaN, separation None) in a condition where a
    cell failed: it would rest on fewer seeds than asked for."""
    if table.empty or "cells_failed" not in table:
        return table
    bad = table["cells_failed"] > 0
    table = table.copy()
    for col in table.columns:
        if col.startswith(star) or col in ("win_share", "boot_support", "boot_alpha_p05", "boot_alpha_p95"):
            table.loc[bad, col] = np.nan
        elif col in ("separated_below", "separated_above"):
            table[col] = table[col].astype(object)
            table.loc[bad, col] = None
        elif col == "distinct":
            table.loc[bad, col] = False
    return table


def write_outputs(root: Path, runs: pd.DataFrame, profile: Profile, meta: dict[str, Any], n_boot: int) -> None:
    """alpha_star.csv, the two figures, mobil_p_star.csv (with MOBIL cells) and report.md from the runs table; a
    condition with a failed cell gets no alpha* (or p*): withhold_incomplete."""
    from coopsumo.report.plots_sweep import alpha_label, alpha_surface_figure, speed_heatmap_figure

    table, boots = alpha_star_table(policy_rows(runs, "dqn"), profile.alphas, profile.seeds, n_boot=n_boot)
    table = withhold_incomplete(table, "alpha_star")
    table.to_csv(root / "alpha_star.csv", index=False)
    side = None
    if "mobil" in profile.policies:
        p_table = mobil_p_star_table(policy_rows(runs, "mobil"), profile.mobil_ps, profile.seeds)
        p_table = withhold_incomplete(p_table, "p_star")
        p_table.to_csv(root / "mobil_p_star.csv", index=False)
        side = side_by_side_table(table, p_table)
    fit: PlaneFit | None = None
    boot: dict[str, float] = {}
    plane_note = ""
    solved = table[np.isfinite(table["alpha_star"].astype(float))]
    try:
        fit = fit_plane(solved["t_up_s"], solved["lanes"], solved["alpha_star"])
        boot = plane_bootstrap(solved, boots)
    except PlaneFitError as err:
        plane_note = f"No plane fitted: {err}."
    figures = {}
    if len(solved):
        alpha_surface_figure(solved["t_up_s"], solved["lanes"], solved["alpha_star"],
                             (fit.b0, fit.b1, fit.b2) if fit else None, root / "fig6_alpha_star.png",
                             note=plane_note)  # fmt: skip
        figures["surface"] = "fig6_alpha_star.png"
        speeds = table.set_index([pd.Index([condition_label(r.lanes, r.t_up_s) for r in table.itertuples()])])
        speeds = speeds[[f"speed_mps_alpha{number_name(a)}" for a in profile.alphas]]
        speeds.columns = list(profile.alphas)
        speed_heatmap_figure(speeds, table["alpha_star"].tolist(), root / "fig6_speed_heatmap.png")
        figures["heatmap"] = "fig6_speed_heatmap.png"
    if profile.name != "paper" and "dqn" in profile.policies:
        meta["paper_cost_estimate"] = paper_cost_estimate(runs, profile.train_steps, PROFILES["paper"])
    meta["plane"] = asdict(fit) if fit else {"error": plane_note}
    meta["plane_bootstrap"] = boot
    (root / "report.md").write_text(report_text(runs, table, fit, boot, plane_note, profile, meta, figures,
                                                alpha_label, side))  # fmt: skip


def _md_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _num(x: Any, fmt: str = "{:.2f}") -> str:
    return "–" if x is None or (isinstance(x, float) and not math.isfinite(x)) else fmt.format(x)


def side_by_side_text(side: pd.DataFrame, alpha_label: Any) -> str:
    """The table of alpha* beside p* and one sentence counting the conditions where alpha* is faster."""
    header = ["lanes", "T_up (s)", "α*", "v(α*) (m/s)", "p*", "v(p*) (m/s)", "v(α*) − v(p*) (m/s)"]
    rows = [[str(r["lanes"]), f"{r['t_up_s']:g}",
             alpha_label(r["alpha_star"]) if math.isfinite(r["alpha_star"]) else "–",
             _num(r["alpha_star_speed_mps"]), _num(r["p_star"], "{:g}"), _num(r["p_star_speed_mps"]),
             _num(r["difference_mps"], "{:+.2f}")] for r in side.to_dict("records")]  # fmt: skip
    compared = side[np.isfinite(side["difference_mps"])]
    wins = int((compared["difference_mps"] > 0).sum())
    if compared.empty:
        sentence = "No condition has both an alpha* and a p*, so the two cannot be compared."
    else:
        sentence = (f"The best learned policy (alpha*) beats the best MOBIL politeness (p*) on {wins} of "
                    f"{len(compared)} conditions (higher mean speed over the same seeds).")  # fmt: skip
    return f"{_md_table(header, rows)}\n\n{sentence}"


def _sep(value: Any) -> str:
    """A neighbour separation flag for the report: yes, no, or – (no neighbour)."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return "yes" if bool(value) else "no"


def noise_floor_text(table: pd.DataFrame) -> str:
    """How many conditions have an alpha* that is distinguishable from its neighbours in the alpha grid (of the
    conditions that have an alpha*)."""
    if table.empty or "distinct" not in table:
        return ""
    if "alpha_star" in table:
        table = table[np.isfinite(table["alpha_star"].astype(float))]
    if table.empty:
        return ""
    n = len(table)
    both = int(table["distinct"].astype(bool).sum())
    flags = table[["separated_below", "separated_above"]].map(lambda v: v is True or v == 1.0)
    one = int(flags.any(axis=1).sum())
    return (f"**Noise floor**: alpha* is distinguishable from both its neighbours in the alpha grid in {both} of {n} "
            f"conditions, from at least one of them in {one} (yes: the 90% bootstrap interval over seeds of the "
            "seed-paired speed difference to that neighbour lies above 0; –: alpha* is at the grid's edge). In the "
            "other conditions the seeds cannot tell alpha* from the alphas next to it.")  # fmt: skip


def cost_text(cost: dict[str, float]) -> str:
    """The report's section on what the paper profile would cost (an extrapolation, said so)."""
    if not cost:
        return ""
    paper = PROFILES["paper"]
    return f"""
## What the paper profile would cost (extrapolated)

Measured here: wall seconds per training step = {cost["train_s_per_step_a"] * 1e3:.2f} ms
{cost["train_s_per_step_b_per_veh_h"] * 1e6:+.3f} us per veh/h of inflow, per evaluation step
{cost["eval_s_per_step_a"] * 1e3:.2f} ms {cost["eval_s_per_step_b_per_veh_h"] * 1e6:+.3f} us per veh/h
(least squares over this sweep's cells, 2 cells at a time on this machine). Extrapolated to the paper
profile ({cost["cells"]:,.0f} cells of
{paper.train_steps:,} training and {paper.eval_steps:,} evaluation steps; inflows up to
{cost["max_paper_inflow_veh_h"]:,.0f} veh/h, measured only up to {cost["max_measured_inflow_veh_h"]:,.0f}):
**{cost["core_hours"]:,.0f} core-hours**, i.e. about {cost["machine_days"]:.1f} days on this machine's
{cost["machine_cores"]:.0f} cores and about {cost["cluster_hours"]:.1f} h on a Ray cluster of
{cost["cluster_cpus"]:.0f} CPUs (`--backend ray --address ...`; perfect scaling assumed, not measured).
"""


def report_text(runs: pd.DataFrame, table: pd.DataFrame, fit: PlaneFit | None, boot: dict[str, float],
                plane_note: str, profile: Profile, meta: dict[str, Any], figures: dict[str, str],
                alpha_label: Any, side: pd.DataFrame | None = None) -> str:  # fmt: skip
    """The Markdown report; `side` (alpha* beside p*) adds the MOBIL section."""
    alphas = list(profile.alphas)
    header = ["lanes", "T_up (s)", "inflow (veh/h)", "load", "α*", "win share", "bootstrap support",
              "α* 90% boot.", "α* vs smaller / larger α", "spread (m/s)", "seed SE (m/s)"
              ] + [f"v(α={alpha_label(a)})" for a in alphas]  # fmt: skip
    rows = []
    for r in table.to_dict("records"):
        rows.append([str(r["lanes"]), f"{r['t_up_s']:g}", f"{r['inflow_veh_h']:.0f}", _num(r["load"]),
                     "–" if not math.isfinite(r["alpha_star"]) else alpha_label(r["alpha_star"]),
                     _num(r["win_share"], "{:.0%}"), _num(r["boot_support"], "{:.0%}"),
                     f"{_num(r['boot_alpha_p05'], '{:g}')}–{_num(r['boot_alpha_p95'], '{:g}')}",
                     f"{_sep(r.get('separated_below'))} / {_sep(r.get('separated_above'))}",
                     _num(r["spread_mps"]), _num(r["seed_se_mps"])]
                    + [_num(r[f"speed_mps_alpha{number_name(a)}"]) for a in alphas])  # fmt: skip
    noise = noise_floor_text(table)
    withheld = [condition_label(r["lanes"], r["t_up_s"]) for r in table.to_dict("records") if r["cells_failed"]]
    if withheld:
        noise = (f"**No alpha\\* (–) where a cell failed** ({'; '.join(withheld)}): it would rest on fewer seeds "
                 f"than asked for; see Failed cells and rerun the same command.\n\n{noise}")  # fmt: skip
    if fit is not None:
        plane = (f"Fitted plane over {fit.n} conditions (least squares on alpha*): "
                 f"**alpha\\* = {fit.b0:.3f} {fit.b1:+.3f} T_up {fit.b2:+.3f} lanes**, "
                 f"R² = {_num(fit.r2, '{:.3f}')}"
                 + (" (undefined: alpha* is the same in every condition)" if not math.isfinite(fit.r2) else "")
                 + ".\n\n" + "\n\n".join(f"- {s}" for s in trend_statements(fit, boot)))  # fmt: skip
    else:
        plane = f"{plane_note} The paper's trends (b1 < 0, b2 < 0) cannot be checked with this grid."
    failed = runs[runs["status"] != "ok"]
    failed_text = ("None." if failed.empty else
                   _md_table(["cell", "error"], [[r.key, str(r.error).replace("|", "\\|")]
                                                 for r in failed.itertuples()]))  # fmt: skip
    grid = _md_table(["lanes", "T_up (s)", "loads (share of lanes × 1,800 veh/h)"],
                     [[str(n), ", ".join(f"{c['t_up_s']:g}" for c in meta["conditions"] if c["lanes"] == n),
                       ", ".join(f"{c['load']:g}" for c in meta["conditions"] if c["lanes"] == n)]
                      for n in profile.lanes])  # fmt: skip
    ok = runs[runs["status"] == "ok"]
    safety = (f"Collisions in evaluation: {int(ok['collisions'].sum())}; teleports: {int(ok['teleports'].sum())} "
              f"(over {len(ok)} successful cells).")  # fmt: skip
    figs = "\n\n".join(
        [f"![alpha* and plane]({figures['surface']})\n\nFig. 6: alpha* (red) against T_up and lane count; "
         "the plane is the least-squares fit, grey lines are residuals." if "surface" in figures else "",
         f"![speed heat map]({figures['heatmap']})\n\nMean evaluation speed over seeds for every alpha and "
         "condition; colour is the gap to the condition's best, framed cells are alpha*." if "heatmap" in figures
         else ""]).strip() or "No figure: no cell succeeded."  # fmt: skip
    mobil_intro, mobil_section, mobil_note = "", "", ""
    if side is not None:
        mobil_intro = (
            "\nMOBIL cells need no training: each runs `mobil:p=P` once, for p in "
            f"{{{', '.join(f'{x:g}' for x in profile.mobil_ps)}}}, on the same condition, seed and number of "
            "steps as a DQN cell's greedy evaluation (free flow). p* is the p with the best mean speed over seeds "
            "(ties go to the smaller p); its win share is counted as for alpha*.\n"
        )  # fmt: skip
        mobil_section = f"\n## alpha* beside the best MOBIL politeness\n\n{side_by_side_text(side, alpha_label)}\n"
        mobil_note = ("\n- MOBIL: per condition `mobil_p_star.csv` (p*, its win share, the mean speed of every p); "
                      "each MOBIL cell's run folder: `mobil/<key>/`.")  # fmt: skip
    steps_note = (
        "Step counts as in the paper (90,000 training steps)." if profile.train_steps >= 90_000 else
        f"{profile.train_steps:,} training steps are far below the paper's 90,000: the models are barely trained, "
        "so alpha* here mostly reflects differences between short trainings, not the paper's effect."
    )  # fmt: skip
    return f"""# Scenario II: choosing the cooperation coefficient alpha

Profile **{profile.name}**: lanes {", ".join(map(str, profile.lanes))}; {len(meta["conditions"])} conditions;
alphas {{{", ".join(alpha_label(a) for a in alphas)}}}; seeds {", ".join(map(str, profile.seeds))};
{profile.train_steps:,} training steps ({profile.train_steps * 0.1 / 60:.1f} min simulated) and
{profile.eval_steps:,} greedy evaluation steps per cell; {meta["cells"]} cells
({meta["cells_ok"]} ok, {meta["cells_failed"]} failed). Backend {meta["backend"]}, {meta["workers"]} workers.
Wall time of this invocation: {meta["wall_seconds"] / 60:.1f} min ({meta["cells_run"]} cells run now); the cells'
own wall times sum to {meta["cell_wall_seconds_sum"] / 60:.1f} min and their CPU times to
{meta["cell_cpu_seconds_sum"] / 60:.1f} core-minutes (CPU time does not grow when the machine is shared).

Each cell trains the shared DQN in free flow (scenario II) on its condition with its alpha and seed, then
evaluates the model greedily on the same condition and seed. Criterion (paper): mean travelling speed
(space-mean speed of the evaluation run, `mean_speed_mps`). alpha* is the alpha with the best mean over seeds
(ties go to the smaller alpha). Uncertainty: *win share* is the share of seeds on which alpha* is the best alpha
(ties share the win); *bootstrap support* is the share of {meta["bootstrap_replicates"]} bootstrap resamples of
the seeds (paired over alphas) whose best alpha is alpha*; the 90% bootstrap range is that of the resampled alpha*.
*Spread* is the best minus the worst alpha's mean speed; *seed SE* the typical standard error of one alpha's mean.
{mobil_intro}
## alpha* per condition

{_md_table(header, rows)}

{noise}
{mobil_section}
## The paper's trends

{plane}

{safety}

## Figures

{figs}
{cost_text(meta.get("paper_cost_estimate") or {})}
## Grid

T_up per lane count is placed by load (inflow as a share of lanes × 1,800 veh/h): T_up = 3600 / (load × lanes
× 1800) s, rounded to 0.01 s; load 1 is near capacity (one lane carries about 1,970 veh/h in this model).
T_up is the interval between vehicles for the whole road (inflow = 3600 / T_up veh/h).

{grid}

## Failed cells

{failed_text}

Rerunning the same command retries failed cells and keeps the finished ones.

## Notes

- Runs: `runs.csv` (one row per cell, every evaluation metric, status and error); per condition: `alpha_star.csv`;
  each cell's record: `cells/<key>.json`; its training folder: `train/<key>/`.{mobil_note}
- {steps_note}
- Versions: {json.dumps(meta["versions"])}.
"""


# -- command line ------------------------------------------------------------------------------------
def profile_from_args(args: Any) -> Profile:
    """The chosen profile with the command line's overrides applied and checked."""
    profile = PROFILES[args.profile]
    if args.steps is not None:
        if args.steps <= 0:
            raise UsageError(f"steps must be positive, got {args.steps}")
        profile = replace(profile, train_steps=args.steps)
    if args.eval_steps is not None:
        if args.eval_steps <= 0:
            raise UsageError(f"eval-steps must be positive, got {args.eval_steps}")
        profile = replace(profile, eval_steps=args.eval_steps)
    if args.seeds is not None:
        if args.seeds < 1:
            raise UsageError(f"seeds must be >= 1, got {args.seeds}")
        profile = replace(profile, seeds=tuple(range(1, args.seeds + 1)))
    if args.lanes is not None:
        lanes = number_list("--lanes", args.lanes, MIN_LANES, MAX_LANES, whole=True)
        profile = replace(profile, lanes=tuple(sorted({int(x) for x in lanes})))
    if args.alphas is not None:
        alphas = alpha_list("--alphas", args.alphas)
        profile = replace(profile, alphas=tuple(sorted(set(alphas))))
    if args.t_up is not None:
        dt_s = ControlConfig().dt_s
        t_up = number_list("--t-up", args.t_up, low=min_t_up_s(dt_s), note=t_up_note(dt_s))
        profile = replace(profile, t_up_s=tuple(sorted(set(t_up))))
    if args.preset is not None:
        profile = replace(profile, preset=args.preset)
    policies = {x.strip() for x in args.policies.split(",") if x.strip()}
    if not policies or not policies <= set(POLICIES):
        raise UsageError(f"policies must be a comma-separated list of {' and '.join(POLICIES)}, got {args.policies!r}")
    profile = replace(profile, policies=tuple(x for x in POLICIES if x in policies))
    if args.mobil_p is not None:
        if "mobil" not in profile.policies:
            raise UsageError("--mobil-p is for --policies with mobil")
        ps = number_list("--mobil-p", args.mobil_p, low=0)
        profile = replace(profile, mobil_ps=tuple(sorted(set(ps))))
    return profile


def build_parser() -> Parser:
    p = Parser(prog="coopsumo scenario2", description="Scenario II: the alpha sweep over lanes and inflows.")
    p.add_argument("--profile", choices=sorted(PROFILES), default="quick",
                   help="grid and step counts: tiny (tests), quick (about 45 min on 2 cores), paper")  # fmt: skip
    p.add_argument("--out", type=out_dir, default=Path("results/scenario2"), help="results folder")
    add_backend_flags(p)
    p.add_argument("--workers", type=workers, default=os.cpu_count() or 1,
                   help="parallel cells (default: every core); with --address the cluster decides")  # fmt: skip
    p.add_argument("--steps", type=steps, default=None, help="training steps per cell (default: the profile's)")
    p.add_argument("--eval-steps", type=steps, default=None, help="evaluation steps per cell (default: the profile's)")
    p.add_argument("--seeds", type=seed_count, default=None, help="number of seeds 1..N (default: the profile's)")
    p.add_argument("--lanes", default=None, help="comma-separated lane counts (default: the profile's)")
    p.add_argument("--alphas", default=None,
                   help="comma-separated alphas, fractions allowed: 0,1/8,2 (default: the profile's)")
    p.add_argument("--t-up", default=None, help="fixed comma-separated T_up list (s) for every lane count, "
                   "instead of the profile's load grid (default: the load grid)")  # fmt: skip
    p.add_argument("--policies", default="dqn", help="comma-separated: dqn (train per alpha) and/or mobil "
                   "(one MOBIL run per politeness p, no training; default: dqn)")  # fmt: skip
    p.add_argument("--mobil-p", default=None, help="comma-separated MOBIL politeness values (default: the "
                   "profile's: 0,0.25,0.5,1; tiny 0,1)")  # fmt: skip
    p.add_argument("--preset", choices=sorted(DQN_PRESETS), default=None,
                   help="learner preset of the DQN cells (default: the profile's, default)")  # fmt: skip
    p.add_argument("--bootstrap", type=integer(0, 100_000), default=1000,
                   help="bootstrap replicates over seeds (default 1000)")  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def body() -> int:
        profile = profile_from_args(args)
        if args.workers < 1:
            raise UsageError(f"workers must be >= 1, got {args.workers}")
        if args.bootstrap < 0:
            raise UsageError(f"bootstrap must be >= 0, got {args.bootstrap}")
        check_backend(args.backend, args.address)
        meta = run_sweep(profile, args.out, args.backend, args.workers, args.address, not args.quiet, args.bootstrap)
        if "dqn" in profile.policies:
            table = pd.read_csv(args.out / "alpha_star.csv")
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
        if "mobil" in profile.policies:
            for r in pd.read_csv(args.out / "mobil_p_star.csv").itertuples():
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
