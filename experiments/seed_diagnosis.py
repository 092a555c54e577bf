"""Why some training seeds fail: what each trained model's greedy choices rest on.

For every model of a learning-study folder (OUT/train/<key>/model.pt), drive it greedily on its evaluation
seed for --steps steps and record, at every decision of every vehicle, its Q-values and the actions offered.
Beside the training log, this says whether a model's lane changes come from clear Q-value margins or from
near-ties, and when during training its lane changing grew.

    python experiments/seed_diagnosis.py results/learning --steps 3000

Writes OUT/diagnosis.csv (one row per model) and prints it.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from coopsumo.agents.dqn_policy import DQNPolicy
from coopsumo.agents.rollout import run
from coopsumo.config import sim_config_from_dict
from coopsumo.sim.observation import Observation, network_features
from coopsumo.sim.physics import LEFT, NONE, RIGHT, SPEEDUP


class RecordingPolicy(DQNPolicy):
    """DQNPolicy that also keeps, per decision, the Q-values, the offered actions and the vehicle's speed."""

    def __init__(self, base: DQNPolicy) -> None:
        super().__init__(base.net, base.name, base.decision_interval, base.action_mask, base.restart_below_mps)
        self.rows: list[np.ndarray] = []

    def act(self, obs: Observation) -> np.ndarray:
        actions = super().act(obs)
        if len(obs):
            from coopsumo.agents.decisions import offered

            mask = offered(obs.feasible, obs.speed, self.action_mask, self.restart_below_mps)
            mask = np.ones((len(obs), 4), bool) if mask is None else mask
            feats = network_features(obs, self.net.observation, self.net.speed_scale_mps)
            with torch.no_grad():
                q = self.net(torch.from_numpy(obs.grids).float(), torch.from_numpy(feats)).numpy()
            self.rows.append(np.column_stack([q, mask, actions, obs.speed - obs.v_exp]))
        return actions


def diagnose(model_dir: Path, eval_cfg: dict[str, Any], steps: int) -> dict[str, Any]:
    """Q-value margins of one model's greedy decisions on its evaluation seed, and its training log's course."""
    base = DQNPolicy.from_file(str(model_dir / "model.pt"))
    policy = RecordingPolicy(base)
    sim = replace(sim_config_from_dict(eval_cfg), steps=steps, policy=f"dqn:{model_dir / 'model.pt'}")
    with tempfile.TemporaryDirectory() as tmp:
        summary = run(sim, policy, Path(tmp), progress=False)
    d = np.concatenate(policy.rows)
    q, mask, action = d[:, :4], d[:, 4:8].astype(bool), d[:, 8].astype(int)
    changes_offered = mask[:, LEFT] | mask[:, RIGHT]
    q_change = np.where(mask[:, [LEFT, RIGHT]], q[:, [LEFT, RIGHT]], -np.inf).max(axis=1)
    q_stay = np.where(mask[:, [SPEEDUP, NONE]], q[:, [SPEEDUP, NONE]], -np.inf).max(axis=1)
    margin = (q_change - q_stay)[changes_offered]  # > 0: a lane change is chosen
    chose_change = np.isin(action, [LEFT, RIGHT])
    log = pd.read_csv(model_dir / "train_log.csv")
    lc_rate = log["lane_changes"] / log["vehicles"].clip(lower=1)
    tenth = max(len(log) // 10, 1)
    return {
        "eval_speed_mps": summary["mean_speed_mps"],
        "eval_lane_changes_per_vehicle": summary["lane_changes_per_vehicle"],
        "decisions": len(d),
        "change_offered_share": float(changes_offered.mean()),
        "change_chosen_share_of_offered": float(chose_change[changes_offered].mean()),
        "margin_median": float(np.median(margin)),
        "margin_abs_median": float(np.median(np.abs(margin))),
        "chosen_change_margin_median": float(np.median(margin[margin > 0])) if (margin > 0).any() else float("nan"),
        "near_tie_share": float((np.abs(margin) < 0.05 * np.abs(q_stay[changes_offered]).mean()).mean()),
        "q_stay_mean": float(q_stay.mean()),
        "speedup_share": float((action == SPEEDUP).mean()),
        "train_lc_rate_first10pct": float(lc_rate[:tenth].mean()),
        "train_lc_rate_last10pct": float(lc_rate[-tenth:].mean()),
        "train_speed_last10pct": float(log["mean_speed_mps"][-tenth:].mean()),
        "td_loss_last10pct": float(pd.to_numeric(log["td_loss"], errors="coerce")[-tenth:].mean()),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("root", type=Path, help="a learning-study folder (with cells/ and train/)")
    p.add_argument("--steps", type=int, default=3000, help="greedy steps per model on its evaluation seed")
    p.add_argument("--alpha0-only", action="store_true", help="only the alpha = 0 models")
    p.add_argument("--variants", default=None, help="only these variants (comma-separated)")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    rows = []
    for cell in sorted((args.root / "cells").glob("*.json")):
        rec = json.loads(cell.read_text())
        if rec.get("kind") != "train" or rec.get("status") != "ok" or (args.alpha0_only and rec["alpha"] != 0):
            continue
        if args.variants and rec["variant"] not in args.variants.split(","):
            continue
        model_dir = args.root / "train" / rec.get("train_key", rec["key"])
        row = {"key": rec["key"], "variant": rec["variant"], "alpha": rec["alpha"], "seed": rec["seed"]}
        row.update(diagnose(model_dir, rec["config"]["eval"], args.steps))
        rows.append(row)
        print(pd.DataFrame([row]).to_string(index=False, header=len(rows) == 1), file=sys.stderr)
    table = pd.DataFrame(rows)
    table.to_csv(args.root / "diagnosis.csv", index=False)
    with pd.option_context("display.width", 250, "display.max_columns", 30):
        print(table.round(3).to_string(index=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
