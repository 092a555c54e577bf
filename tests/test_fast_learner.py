"""The learner's per-step work in C (coopsumo/sim/fast.py) against its numpy definitions: a whole training driven by
the C functions and by the definitions monkeypatched in gives the same weights and the same training log.

The functions themselves are compared with their definitions on random roads in tests/test_fast.py."""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from coopsumo.agents.train import train
from coopsumo.config import AccidentConfig, SimConfig, TrainConfig
from coopsumo.dqn_config import DQNConfig
from coopsumo.sim import fast, observation, reward

pytestmark = pytest.mark.sumo

DEFINITIONS = {"followers_mean": reward.followers_mean, "snapshot": observation.snapshot}
"""fast's function -> its definition"""


def _log(folder: Path) -> list[dict[str, str]]:
    with (folder / "train_log.csv").open() as f:
        return [{k: v for k, v in row.items() if k != "wall_s"} for row in csv.DictReader(f)]


def test_a_training_is_the_same_with_the_definitions(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The default learner (the followers' term in its reward, decisions every 10 steps) through an accident with lane
    changes: the same model weights and log rows, bit for bit (the followers' term and the grids)."""
    dqn = replace(DQNConfig(), select_every_steps=0, train_t_ups=(), accident_share=0.0, learn_start_steps=100)
    sim = SimConfig(steps=1500, seed=4, policy="dqn",
                    accident=AccidentConfig(enabled=True, x_m=900.0, start_step=200, duration_steps=1000))  # fmt: skip
    cfg = TrainConfig(sim=sim, dqn=dqn, eval_steps=0, log_every_steps=250)
    weights, logs = [], []
    for name in ("fast", "definitions"):
        if name == "definitions":
            for f, definition in DEFINITIONS.items():
                monkeypatch.setattr(fast, f, definition)
        train(cfg, tmp_path / name, progress=False)
        weights.append(torch.load(tmp_path / name / "model.pt", weights_only=True)["state_dict"])
        logs.append(_log(tmp_path / name))
    assert sum(int(row["lane_changes"]) for row in logs[0]) > 20  # the policy changes lanes: the term has work to do
    assert logs[0] == logs[1]
    assert weights[0].keys() == weights[1].keys()
    assert all(torch.equal(weights[0][k], weights[1][k]) for k in weights[0])
