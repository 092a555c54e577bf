"""`coopsumo diagnose`: why some training seeds fail: what each trained model's greedy choices rest on.

For every model of a learning-study folder (`coopsumo learning --out ROOT`: each finished training's record in
ROOT/cells/, its model in ROOT/train/<key>/model.pt), drive it greedily on its own evaluation seed (1000 + its
training seed) for --steps steps and record, at every decision of every vehicle, its Q-values and the actions
offered. Beside the training log, this says
whether a model's lane changes come from clear Q-value margins or from near-ties, and when during training its lane
changing grew (diagnosis_measures). Each model is a cell of the shared runner (record
ROOT/cells/diagnosis_<key>.json, reused on a rerun while the model file holds the same bytes); writes
ROOT/diagnosis.csv (one row per model) and prints it.
"""

from __future__ import annotations

import sys
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from coopsumo.agents.decisions import offered
from coopsumo.agents.dqn_policy import DQNPolicy
from coopsumo.config import sim_config_from_dict
from coopsumo.errors import UsageError
from coopsumo.runio import Parser, run_cli
from coopsumo.sim.observation import Observation, network_features
from coopsumo.studies.engine.cells import add_cell_flags, failed_keys, run_cells
from coopsumo.studies.engine.records import CellRecords, failed_exit, model_fields
from coopsumo.studies.engine.run_folders import study_root
from coopsumo.studies.engine.runner import check_backend
from coopsumo.studies.followups.diagnosis_measures import COLUMNS, decision_measures, training_course
from coopsumo.studies.learning.models import finished_trainings
from coopsumo.studies.learning.plan import own_eval, variant_list
from coopsumo.validation import MAX_STEPS, integer

PROG = "diagnose"
REQUIRED = ("eval_speed_mps", "decisions")
"""summary values a stored record must hold as finite numbers to be reused"""
RECORDS = CellRecords(("key", "cell", "variant", "alpha", "seed", "train_key"))
"""a cell's record: the learning study's training cell it diagnoses (cell, its coordinates, its folder under train/)"""
failed_record = RECORDS.failed


class RecordingPolicy(DQNPolicy):
    """DQNPolicy that also keeps, per decision of every vehicle, the Q-values, the offered actions and the action
    (without a change margin: the choices as the Q-values make them; an alpha-conditioned network at base's alpha)."""

    def __init__(self, base: DQNPolicy) -> None:
        super().__init__(base.net, base.name, base.decision_interval, base.action_mask, base.restart_below_mps,
                         alpha=base.alpha, rule=base.rule, lanes=base.lanes)  # fmt: skip
        self.rows: list[np.ndarray] = []

    def act(self, obs: Observation) -> np.ndarray:
        actions = super().act(obs)
        if len(obs):
            mask = offered(obs.feasible, obs.speed, self.action_mask, self.restart_below_mps)
            mask = np.ones((len(obs), 4), bool) if mask is None else mask
            feats = network_features(obs, self.net.observation, self.net.speed_scale_mps)
            inputs = [torch.from_numpy(obs.grids).float(), torch.from_numpy(feats)]
            if self.alpha is not None:
                inputs.append(torch.full((len(obs),), float(self.alpha)))
            with torch.no_grad():
                q = self.net(*inputs).numpy()
            self.rows.append(np.column_stack([q, mask, actions, obs.speed - obs.v_exp]))
        return actions


def diagnose(model_dir: Path, eval_cfg: dict[str, Any], steps: int) -> dict[str, Any]:
    """Q-value margins of one model's greedy decisions on its evaluation seed (an alpha-conditioned model at the
    evaluation's alpha), and its training log's course."""
    from coopsumo.agents.rollout import run

    sim = replace(sim_config_from_dict(eval_cfg), steps=steps, policy=f"dqn:{model_dir / 'model.pt'}")
    base = DQNPolicy.from_file(str(model_dir / "model.pt"))
    if base.net.conditioned:
        base.drive_at(sim.reward.alpha, sim.road.lanes)
    policy = RecordingPolicy(base)
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        summary = run(sim, policy, Path(tmp), progress=False)
    if not policy.rows:
        raise RuntimeError(f"the model made no decision in {steps} steps")
    return {"eval_speed_mps": summary["mean_speed_mps"],
            "eval_lane_changes_per_vehicle": summary["lane_changes_per_vehicle"],
            **decision_measures(np.concatenate(policy.rows)),
            **training_course(pd.read_csv(model_dir / "train_log.csv"))}  # fmt: skip


def run_cell(spec: dict[str, Any], root: str) -> dict[str, Any]:
    """Diagnose one model; never raises (records.run_recorded)."""
    model_dir = Path(root) / "train" / spec["train_key"]
    return RECORDS.run(
        spec, lambda record: record.update(summary=diagnose(model_dir, spec["config"]["eval"], spec["config"]["steps"]))
    )


def cell_specs(root: Path, steps: int, variants: tuple[str, ...] | None, alpha0_only: bool) -> list[dict[str, Any]]:
    """One cell per finished training of the learning study in root (of `variants`, at alpha 0 with alpha0_only);
    UsageError when root is not a learning-study folder, a model is missing or no training is left."""
    specs = []
    for t in finished_trainings(root, PROG, variants, (0.0,) if alpha0_only else None):
        try:
            own = own_eval(t["config"], t["seed"])  # the model's evaluation on its own seed
            sim_config_from_dict(own)  # one this version can drive
        except (KeyError, TypeError, ValueError, StopIteration) as err:
            raise UsageError(f"the record of training {t['key']} in {root} has no usable evaluation "
                             f"({type(err).__name__} {err})") from None  # fmt: skip
        specs.append({"key": f"diagnosis_{t['key']}", "cell": t["key"], "variant": t["variant"], "alpha": t["alpha"],
                      "seed": t["seed"], "train_key": t["model"].parent.name, **model_fields(t["model"]),
                      "config": {"eval": own, "steps": steps}})  # fmt: skip
    if not specs:
        raise UsageError(f"no finished trainings{' of ' + ','.join(variants) if variants else ''}"
                         f"{' at alpha 0' if alpha0_only else ''} in {root}")  # fmt: skip
    return specs


def build_parser() -> Parser:
    p = Parser(prog="coopsumo diagnose",
               description="What each model of a learning study rests on: the Q-value margins of its greedy "
                           "choices on its evaluation seed, beside its training log.")  # fmt: skip
    p.add_argument("root", type=Path, metavar="ROOT", help="a learning-study folder (`coopsumo learning --out ROOT`)")
    p.add_argument("--steps", type=integer(100, MAX_STEPS), default=3000,
                   help="greedy steps per model on its evaluation seed")  # fmt: skip
    p.add_argument("--alpha0-only", action="store_true", help="only the alpha = 0 models")
    p.add_argument("--variants", default=None, help="only these variants, comma-separated (default: every variant)")
    add_cell_flags(p)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def body() -> int:
        variants = None if args.variants is None else variant_list("--variants", args.variants)
        check_backend(args.backend, args.address)
        specs = cell_specs(args.root, args.steps, variants, args.alpha0_only)
        with study_root(args.root, "ablation"):  # a learning study's folder: its lock held, its ownership checked
            roads = [sim_config_from_dict(s["config"]["eval"]).road for s in specs]
            records = run_cells(specs, args.root, run_cell, failed_record, prog=PROG, required=REQUIRED,
                                roads=roads, workers=args.workers, backend=args.backend,
                                address=args.address, progress=not args.quiet, desc="models")  # fmt: skip
            if failed := failed_keys(records):
                return failed_exit(PROG, failed, len(records), args.root)
            table = pd.DataFrame([{"key": r["cell"], "variant": r["variant"], "alpha": r["alpha"], "seed": r["seed"],
                                   **{c: r["summary"][c] for c in COLUMNS}} for r in records])  # fmt: skip
            table.to_csv(args.root / "diagnosis.csv", index=False)
        with pd.option_context("display.width", 250, "display.max_columns", 30):
            print(table.round(3).to_string(index=False))
        return 0

    return run_cli(PROG, body)


if __name__ == "__main__":
    sys.exit(main())
