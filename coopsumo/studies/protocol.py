"""`coopsumo protocol`: one protocol for judging a learner, with the trained model as the unit of replication.

Each learner variant is trained on every training seed (default 10, seeds 100-109: none of the committed studies'
nor the validation seeds); every model then drives free flow at T_up 2, 1.5 and 1 s and scenario I's accident
(closure decaying over steps 2,000-12,000 of 20,000) at the same demands, on evaluation seeds no training or
validation saw (EVAL_SEED + condition index), the same seeds for every model. `keep`, `greedy` and MOBIL p = 0 run
on those seeds too. Statistics over models (studies/stats.py, rliable): interquartile mean with a stratified
bootstrap interval, the worst model, and the probability of improvement against each baseline (protocol_report).

A variant is a training (its learner) plus which weights drive: `model.pt` (the validated best, when the learner
selects) or `model_last.pt` (the last weights). Model selection never feeds back into training, so the last
weights of a selecting training are the model the same learner without selection would have saved: one
training gives both rows. Cells run on the shared runner; a rerun reuses finished cells. Outputs in OUT
(default results/learner_protocol): cells/, train/, runs/, runs.csv, report.md and figures.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

from coopsumo.config import (
    AccidentConfig,
    DemandConfig,
    DQNConfig,
    RewardConfig,
    RoadConfig,
    SimConfig,
    TrainConfig,
    to_dict,
)
from coopsumo.runio import Parser, UsageError, run_cli, versions, write_json
from coopsumo.studies.runner import add_backend_flags, check_backend, failed_exit, study_root
from coopsumo.validation import number_name, out_dir, workers

EVAL_SEED = 5000
"""evaluation run of condition i uses seed EVAL_SEED + i (free flow) or EVAL_SEED + 100 + i (accident)"""
TRAIN_SEED = 100
"""first training seed of the protocol (the committed learning studies used 0-8)"""
BASELINES = ("keep", "greedy", "mobil:p=0")
DEMANDS = (2.0, 1.5, 1.0)
TRAJECTORY_EVERY = 5
"""accident runs record trajectories every 5 steps (0.5 s) for total time spent"""
REQUIRED = ("mean_speed_mps", "lane_changes_per_vehicle", "collisions", "teleports")


@dataclass(frozen=True)
class Variant:
    """A learner as judged: the training (its learner settings) and the weights that drive."""

    name: str
    text: str
    learner: DQNConfig
    weights: str = "model.pt"


def variants() -> dict[str, Variant]:
    """The variants the protocol knows; `select` is the default preset."""
    default = DQNConfig()
    return {v.name: v for v in (
        Variant("select", "the default: the paper's state, change margin 1, model.pt chosen on held-out demand "
                "(validated every 15,000 steps)", default),
        Variant("margin", "the previous default: the same trainings' last weights (model_last.pt), change margin 1",
                default, "model_last.pt"),
    )}  # fmt: skip


@dataclass(frozen=True)
class Profile:
    name: str
    variants: tuple[str, ...] = ("select", "margin")
    seeds: tuple[int, ...] = tuple(range(TRAIN_SEED, TRAIN_SEED + 10))
    train_steps: int = 90_000
    t_ups: tuple[float, ...] = DEMANDS
    free_steps: int = 6000
    accident_steps: int = 20_000
    accident_start: int = 2000
    accident_duration: int = 10_000
    alpha_seeds: int = 3
    """models at alpha 8 of the first variant (free flow only): does alpha do something?"""
    lanes: int = 3


PROFILES = {
    "default": Profile("default"),
    "tiny": Profile("tiny", seeds=(TRAIN_SEED, TRAIN_SEED + 1), train_steps=600, t_ups=(1.5, 1.0), free_steps=300,
                    accident_steps=600, accident_start=100, accident_duration=300, alpha_seeds=1),
}  # fmt: skip


def train_config(profile: Profile, dqn: DQNConfig, alpha: float, seed: int) -> TrainConfig:
    sim = SimConfig(road=RoadConfig(lanes=profile.lanes), reward=RewardConfig(alpha=alpha),
                    steps=profile.train_steps, seed=seed, policy="dqn")  # fmt: skip
    if profile.train_steps < dqn.select_every_steps:  # a short profile validates twice
        dqn = replace(dqn, select_every_steps=max(profile.train_steps // 2, 1), validation_steps=min(
            dqn.validation_steps, profile.free_steps))  # fmt: skip
    return TrainConfig(sim=sim, dqn=dqn, eval_steps=0)


def eval_config(profile: Profile, scenario: str, i: int, policy: str, alpha: float = 0.0) -> SimConfig:
    """The evaluation run of condition i (its demand profile.t_ups[i]) in free flow or through the accident."""
    t_up = profile.t_ups[i]
    if scenario == "free":
        return SimConfig(road=RoadConfig(lanes=profile.lanes), demand=DemandConfig(t_up_s=t_up),
                         reward=RewardConfig(alpha=alpha), steps=profile.free_steps, seed=EVAL_SEED + i,
                         policy=policy)  # fmt: skip
    return SimConfig(road=RoadConfig(lanes=profile.lanes), demand=DemandConfig(t_up_s=t_up),
                     accident=AccidentConfig(enabled=True, start_step=profile.accident_start,
                                             duration_steps=profile.accident_duration),
                     reward=RewardConfig(alpha=alpha), steps=profile.accident_steps, seed=EVAL_SEED + 100 + i,
                     policy=policy)  # fmt: skip


def cell_specs(profile: Profile) -> list[dict[str, Any]]:
    """Every cell: one per (variant, alpha, training seed, scenario, demand) and per (baseline, scenario, demand)."""
    known = variants()
    specs: list[dict[str, Any]] = []
    models: list[tuple[Variant, float, int, tuple[str, ...]]] = []
    for name in profile.variants:
        for seed in profile.seeds:
            models.append((known[name], 0.0, seed, ("free", "accident")))
    first = known[profile.variants[0]]
    for seed in profile.seeds[: profile.alpha_seeds]:
        models.append((first, 8.0, seed, ("free",)))
    for variant, alpha, seed, scenarios in models:
        cfg = train_config(profile, variant.learner, alpha, seed)
        train_key = f"a{number_name(alpha)}_seed{seed}_{_learner_tag(variant.learner)}"
        for scenario in scenarios:
            for i, t_up in enumerate(profile.t_ups):
                ev = eval_config(profile, scenario, i, "dqn", alpha)
                key = f"{variant.name}_a{number_name(alpha)}_seed{seed}_{scenario}_t{number_name(t_up)}"
                specs.append({"key": key, "kind": "model", "variant": variant.name, "alpha": alpha, "seed": seed,
                              "scenario": scenario, "t_up": t_up, "eval_seed": ev.seed, "weights": variant.weights,
                              "train_key": train_key,
                              "config": json.loads(json.dumps({"train": to_dict(cfg),
                                                               "eval": to_dict(ev)}))})  # fmt: skip
    for policy in BASELINES:
        for scenario in ("free", "accident"):
            for i, t_up in enumerate(profile.t_ups):
                ev = eval_config(profile, scenario, i, policy)
                specs.append({"key": f"{policy.replace(':', '_').replace('=', '')}_{scenario}_t{number_name(t_up)}",
                              "kind": "baseline", "variant": policy, "alpha": 0.0, "seed": None, "scenario": scenario,
                              "t_up": t_up, "eval_seed": ev.seed, "weights": None, "train_key": None,
                              "config": json.loads(json.dumps({"eval": to_dict(ev)}))})  # fmt: skip
    return specs


def _learner_tag(dqn: DQNConfig) -> str:
    """A short name of a learner for its training folder: the preset, and a digest of its settings."""
    import hashlib

    digest = hashlib.sha256(json.dumps(to_dict(dqn), sort_keys=True).encode()).hexdigest()[:8]
    return f"{dqn.preset}_{digest}"


# -- one cell (in a worker process) ----------------------------------------------------------------
FIELDS = ("key", "kind", "variant", "alpha", "seed", "scenario", "t_up", "eval_seed", "weights", "train_key")


def new_record(spec: dict[str, Any]) -> dict[str, Any]:
    from coopsumo.studies.runner import blank_record

    return blank_record(spec, FIELDS, train_summary=None)


def failed_record(spec: dict[str, Any], error: str) -> dict[str, Any]:
    from coopsumo.studies.runner import as_failed

    return as_failed(new_record(spec), error)


def run_cell(spec: dict[str, Any], root: str) -> dict[str, Any]:
    """Train (or reuse) the model, then drive it; or run a baseline. Never raises (runner.run_recorded)."""
    from coopsumo.studies.runner import run_recorded

    record = new_record(spec)
    return run_recorded(record, lambda: _run(spec, Path(root), record))


def _run(spec: dict[str, Any], root: Path, record: dict[str, Any]) -> None:
    from coopsumo.config import sim_config_from_dict
    from coopsumo.studies.runner import simulate_into, train_shared

    ev = sim_config_from_dict(spec["config"]["eval"])
    if spec["kind"] == "model":
        model_dir = root / "train" / spec["train_key"]
        record["train_summary"], _ = train_shared(spec["config"]["train"], model_dir)
        ev = replace(ev, policy=f"dqn:{(model_dir / spec['weights']).resolve()}")
    every = TRAJECTORY_EVERY if ev.accident.enabled else 0
    out = root / "runs" / spec["key"]
    summary = simulate_into(json.loads(json.dumps(to_dict(ev))), out, spec["key"], trajectory_every=every,
                            atomic=True)  # fmt: skip
    if ev.accident.enabled:
        summary["tts_veh_h"] = total_time_spent(out, ev)
        (out / "trajectories.parquet").unlink(missing_ok=True)  # measured; 10 MB a run is not kept
    record["summary"] = summary


def total_time_spent(run_dir: Path, cfg: SimConfig) -> float:
    """Total time spent on the road and waiting to enter (veh-h) of an accident run (scenario I's measure)."""
    import pandas as pd

    from coopsumo.report import bottleneck as bn

    traj = pd.read_parquet(run_dir / "trajectories.parquet")
    v_ref = cfg.demand.v_exp_mean_kmh / 3.6
    return float(bn.run_time_spent(traj, cfg.demand.t_up_s, TRAJECTORY_EVERY * cfg.control.dt_s, v_ref)["tts_veh_h"])


# -- the study -------------------------------------------------------------------------------------
def run_study(profile: Profile, root: Path, backend_name: str = "local", workers: int = 2,
              address: str | None = None, progress: bool = True) -> dict[str, Any]:  # fmt: skip
    from coopsumo.sim.network import build_net
    from coopsumo.studies import protocol_report
    from coopsumo.studies.runner import (
        cell_path,
        checked_record,
        execute,
        make_backend,
        reusable_keys,
        sigterm_interrupts,
    )

    start = time.perf_counter()
    root = root.resolve()
    try:
        (root / "cells").mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise UsageError(f"cannot write output folder {root}: {err.strerror}") from None
    specs = cell_specs(profile)
    done = reusable_keys(root, specs, "protocol", REQUIRED)
    todo = [s for s in specs if s["key"] not in done]
    # each training's first cell before any cell that would wait for it, free flow (short) before the accident
    first: dict[str, str] = {}
    for s in todo:
        if s["train_key"] is not None:
            first.setdefault(s["train_key"], s["key"])
    todo.sort(key=lambda s: (s["train_key"] is None or first[s["train_key"]] != s["key"], s["scenario"] != "free"))
    meta: dict[str, Any] = {"profile": asdict(profile), "cells": len(specs), "backend": backend_name,
                            "workers": workers, "versions": versions(),
                            "learners": {n: {"text": v.text, "weights": v.weights, "learner": to_dict(v.learner)}
                                         for n, v in variants().items() if n in profile.variants}}  # fmt: skip
    print(f"protocol: profile {profile.name}: {len(specs)} cells, {len(specs) - len(todo)} already done, "
          f"{len(todo)} to run", file=sys.stderr)  # fmt: skip
    if todo:
        build_net(RoadConfig(lanes=profile.lanes))
        backend = make_backend(backend_name, workers, address, run_cell)
        try:
            with sigterm_interrupts():
                execute(todo, root, backend, len(specs), len(specs) - len(todo), progress, failed_record,
                        desc="protocol cells")  # fmt: skip
        finally:
            backend.close()
    records = [checked_record(json.loads(cell_path(root, s["key"]).read_text()), REQUIRED) for s in specs]
    meta.update(cells_run=len(todo), wall_seconds=round(time.perf_counter() - start, 1),
                failed_cells=[r["key"] for r in records if r["status"] != "ok"],
                cell_cpu_seconds_sum=round(sum(r.get("cell_cpu_s") or 0.0 for r in records), 1))  # fmt: skip
    protocol_report.write_outputs(root, profile, records, meta)
    write_json(root / "study.json", meta)
    return meta


def build_parser() -> Parser:
    p = Parser(prog="coopsumo protocol",
               description="Judge learners: every training seed's model in free flow and through the accident "
                           "against keep, greedy and MOBIL p=0 (IQM, bootstrap intervals, probability of "
                           "improvement).")  # fmt: skip
    p.add_argument("--profile", choices=tuple(PROFILES), default="default", help="study size")
    p.add_argument("--workers", type=workers, default=2, help="parallel cells")
    add_backend_flags(p)
    p.add_argument("--out", type=out_dir, default=Path("results/learner_protocol"))
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def body() -> int:
        if args.workers <= 0:
            raise UsageError(f"--workers must be positive, got {args.workers}")
        check_backend(args.backend, args.address)
        with study_root(args.out, "protocol"):
            meta = run_study(PROFILES[args.profile], args.out, args.backend, args.workers, args.address,
                             progress=not args.quiet)  # fmt: skip
        print(f"protocol: {meta['cells']} cells in {meta['wall_seconds']:.0f} s; report: {args.out / 'report.md'}")
        return failed_exit("protocol", meta["failed_cells"], meta["cells"], args.out)

    return run_cli("protocol", body)


if __name__ == "__main__":
    sys.exit(main())
