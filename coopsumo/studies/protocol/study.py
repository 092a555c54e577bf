"""`coopsumo protocol`: one protocol for judging a learner, with the trained model as the unit of replication.

Each learner variant is trained on every training seed (default 10, seeds 100-109: none of the committed studies'
nor the validation seeds); every model then drives free flow at T_up 2, 1.5 and 1 s and scenario I's accident
(closure decaying over steps 2,000-12,000 of 20,000) at the same demands, on evaluation seeds no training or
validation saw (EVAL_SEED + condition index), the same seeds for every model. `keep`, `greedy` and MOBIL p = 0 run
on those seeds too. Statistics over models (studies/engine/stats.py, rliable): interquartile mean with a stratified
bootstrap interval, the worst model, and the probability of improvement against each baseline (protocol_report).

A variant is a training (its learner) plus which weights drive: `model.pt` (the validated best, when the learner
selects) or `model_last.pt` (the last weights). Model selection never feeds back into training, so the last
weights of a selecting training are the model the same learner without selection would have saved: one
training gives both rows. The variants and profiles are data (coopsumo/experiments_data/learners.toml and
protocol.toml). Cells run on the shared runner; a rerun reuses finished cells. Outputs in OUT (default
results/learner_protocol_<profile>; without --profile, protocol_plan.CURRENT: the one judging today's default
learner): cells/, train/, runs/, runs.csv, report.md and figures.
"""

from __future__ import annotations

import sys
from dataclasses import asdict
from functools import partial
from pathlib import Path
from typing import Any

from coopsumo.config import RoadConfig, SimConfig, to_dict
from coopsumo.errors import UsageError
from coopsumo.files import write_json
from coopsumo.provenance import versions
from coopsumo.record_schemas import PROTOCOL_STUDY
from coopsumo.runio import Parser, run_cli
from coopsumo.studies.engine.catalogue import OWN_PROFILE, own_profile, profile_arg
from coopsumo.studies.engine.cells import Cell, CellKind, Run, Study
from coopsumo.studies.engine.records import CellRecords, failed_exit
from coopsumo.studies.engine.run_folders import (
    default_out,
    profile_study,
    recorded_profile,
    study_root,
)
from coopsumo.studies.engine.runner import add_backend_flags, check_backend
from coopsumo.studies.protocol.paired import check_paired
from coopsumo.studies.protocol.plan import (
    CURRENT,
    PROFILES,
    QUEUE_MPS,
    REQUIRED,
    TRAJECTORY_EVERY,
    Profile,
    cell_specs,
    own_profiles,
    variants,
)
from coopsumo.validation import default_model_out, model_out_dir, workers

# -- one cell (in a worker process) ----------------------------------------------------------------
FIELDS = ("key", "kind", "variant", "alpha", "seed", "scenario", "t_up", "eval_seed", "weights", "train_key")


RECORDS = CellRecords(FIELDS, ("train_summary",))
"""a cell's record: its coordinates and configuration, then what it measured"""
new_record, failed_record = RECORDS.new, RECORDS.failed


def work(spec: dict[str, Any]) -> Cell:
    """What the cell of `spec` does (cells.perform runs it): a model cell takes (or trains) its model in the model
    store, ROOT/train/<train_key>/ linking to it, and drives its weights with the variant's drive settings; a baseline
    cell drives its policy; either one run into ROOT/runs/<key>/ (written atomically), through the accident measured
    further (_run)."""
    from coopsumo.config import sim_config_from_dict
    from coopsumo.studies.engine.cells import cell_train

    ev = sim_config_from_dict(spec["config"]["eval"])
    train = cell_train(spec, f"train/{spec['train_key']}", spec["weights"]) if spec["kind"] == "model" else None
    return Cell(train, (Run(ev, f"runs/{spec['key']}"),), spec["key"], partial(_run, accident=ev.accident.enabled))


CELLS = CellKind(RECORDS, work)
run_cell = CELLS.run_cell


def _run(config: dict[str, Any], out: Path, label: str, accident: bool) -> dict[str, Any]:
    """One run of a cell into out (atomically): its summary and, through the accident, its measures
    (accident_measures: from its trajectories, which are then deleted: 10 MB a run is not kept)."""
    from coopsumo.config import sim_config_from_dict
    from coopsumo.studies.engine.run_folders import simulate_into

    summary = simulate_into(config, out, label, trajectory_every=TRAJECTORY_EVERY if accident else 0, atomic=True)
    if accident:
        summary.update(accident_measures(out, sim_config_from_dict(config), summary["departed"]))
        (out / "trajectories.parquet").unlink(missing_ok=True)
    return summary


def accident_measures(run_dir: Path, cfg: SimConfig, departed: int) -> dict[str, float]:
    """Scenario I's measures of an accident run from its trajectories (sampled every TRAJECTORY_EVERY steps, as
    scenario I samples them): total time spent on the road and waiting to enter (veh-h), and the lane changes made
    below QUEUE_MPS per vehicle that departed (queue_lane_changes_per_vehicle, the thrashing measure)."""
    import pandas as pd

    from coopsumo.report import bottleneck as bn

    traj = pd.read_parquet(run_dir / "trajectories.parquet")
    v_ref = cfg.demand.v_exp_mean_kmh / 3.6
    tts = bn.run_time_spent(traj, cfg.demand.t_up_s, TRAJECTORY_EVERY * cfg.control.dt_s, v_ref)["tts_veh_h"]
    return {"tts_veh_h": float(tts),
            "queue_lane_changes_per_vehicle": bn.queue_lane_changes(traj, QUEUE_MPS) / max(departed, 1)}


# -- the study -------------------------------------------------------------------------------------
def _order(todo: list[dict[str, Any]]) -> None:
    """Each model's first cell (the one that trains it) before the others, free flow (short) before the accident."""
    todo.sort(key=lambda s: (s["train_key"] is None or "after" in s, s["scenario"] != "free"))


STUDY = Study("protocol", CELLS, REQUIRED, lambda root, s: (root / "runs" / s["key"],), _order)
"""the protocol as the engine runs it: a cell's run folder ROOT/runs/<key>/ (a user's folder there refused before any
cell runs)"""


def run_study(profile: Profile, root: Path, backend_name: str = "local", workers: int = 2,
              address: str | None = None, progress: bool = True) -> dict[str, Any]:  # fmt: skip
    from coopsumo.studies.protocol import report as protocol_report

    root = root.resolve()
    meta: dict[str, Any] = {"profile": asdict(profile), "cells": len(specs := cell_specs(profile)),
                            "backend": backend_name, "workers": workers, "versions": versions(),
                            "learners": {n: {"text": v.text, "weights": v.weights, "drive": v.drive(),
                                             "learner": to_dict(v.learner)}
                                         for n, v in variants().items() if n in profile.variants}}  # fmt: skip

    def finish(records: list[dict[str, Any]], meta: dict[str, Any]) -> None:
        PROTOCOL_STUDY.check(meta, root / "study.json")  # the schema `coopsumo history` reads it by, before any output
        protocol_report.write_outputs(root, profile, records, meta)
        write_json(root / "study.json", meta)

    return STUDY.run(specs, root, meta, profile.name, finish, roads=[RoadConfig(lanes=profile.lanes)], workers=workers,
                     backend=backend_name, address=address, progress=progress)  # fmt: skip


def default_folder(profile: str) -> Path:
    """A profile's results folder when --out is not given: results/learner_protocol_<profile>."""
    return default_out("learner_protocol", profile, committed="")


def chosen_profile(text: str) -> Profile:
    """--profile's profile: a packaged one by name, or one of a file of one's own (PATH.toml[:NAME]: protocol.toml's
    format, naming learners.toml's variants, every profile checked as the packaged ones are)."""
    return PROFILES[text] if text in PROFILES else own_profile(text, own_profiles, PROFILES, "default")


def build_parser() -> Parser:
    p = Parser(prog="coopsumo protocol",
               description="Judge learners: every training seed's model in free flow and through the accident "
                           "against keep, greedy and MOBIL p=0 (IQM, bootstrap intervals, probability of "
                           "improvement).")  # fmt: skip
    p.add_argument("--profile", type=profile_arg(tuple(PROFILES)), default=CURRENT, metavar="PROFILE",
                   help=f"which learners, on how many models (coopsumo/experiments_data/protocol.toml; "
                        f"docs/studies.md): {CURRENT} (the default) judges today's default learner; tiny takes "
                        f"a minute or two, for trying it out; the others: "
                        f"{', '.join(p for p in PROFILES if p not in (CURRENT, 'tiny'))}. The earlier profiles are "
                        "rows of results/history/README.md, each run at the commit its row names. Or a profile of "
                        f"your own in a file of protocol.toml's format naming learners.toml's variants, {OWN_PROFILE}")
    p.add_argument("--workers", type=workers, default=2, help="parallel cells")
    add_backend_flags(p)
    p.add_argument("--out", type=model_out_dir, default=None,
                   help=f"results folder (default {default_folder(CURRENT)}; another profile "
                        f"{default_folder('<profile>')})")  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def body() -> int:
        if args.workers <= 0:
            raise UsageError(f"--workers must be positive, got {args.workers}")
        profile = chosen_profile(args.profile)
        check_paired(profile)  # the studies it pairs with, before any cell runs (issue 82, probe 7, I7, I11)
        check_backend(args.backend, args.address)
        if args.out is None:
            args.out = default_model_out(default_folder(profile.name))
        # another profile's study refused, its own resumed (study.json names it in a root marked before markers did)
        with study_root(args.out, "protocol", profile_study(profile.name), recorded_profile("study.json", "profile",
                        "name", kind="protocol"), f"pick another --out (the {profile.name} profile's default: "
                        f"{default_folder(profile.name)})", trains=True, profile=profile):  # fmt: skip
            meta = run_study(profile, args.out, args.backend, args.workers, args.address,
                             progress=not args.quiet)  # fmt: skip
        print(f"protocol: {meta['cells']} cells in {meta['wall_seconds']:.0f} s; report: {args.out / 'report.md'}")
        return failed_exit("protocol", meta["failed_cells"], meta["cells"], args.out)

    return run_cli("protocol", body)


if __name__ == "__main__":
    sys.exit(main())
