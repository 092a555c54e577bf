"""The moving average of the weights (DQNConfig.weights_ema): what drives is the average, training is unchanged,
the update worker keeps the same average bit for bit, and a resume carries it."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from coopsumo.agents.dqn import Learner, QNetwork, update_average
from coopsumo.agents.update_worker import UpdateWorker
from coopsumo.dqn_config import PAPER_DQN, DQNConfig
from tests.test_dqn import run_steps, same, weights

ROOT = Path(__file__).resolve().parent.parent
CFG = dataclasses.replace(PAPER_DQN, replay_size=64, batch_size=8, learn_start_steps=0, target_sync_steps=3,
                          learn_every=1, updates_per_learn=2, double_dqn=True, loss="huber")  # fmt: skip


def test_update_average_is_the_exponential_moving_average() -> None:
    a, b = QNetwork(30.0), QNetwork(30.0)
    before = weights(a)
    update_average(a, b, 0.75)
    for x0, x, y in zip(before, weights(a), weights(b), strict=True):
        assert torch.allclose(x, 0.75 * x0 + 0.25 * y)
    update_average(a, b, 0.0)  # decay 0: the online weights themselves
    assert same(weights(a), weights(b))


def test_the_average_drives_and_training_is_unchanged() -> None:
    plain, averaged = Learner(CFG, 4), Learner(dataclasses.replace(CFG, weights_ema=0.9), 4)
    assert plain.average is None and plain.driving is plain.online
    assert same(weights(averaged.average), weights(averaged.online))  # it starts at the initial weights
    taken = [run_steps(learner, np.random.default_rng(9), 12) for learner in (plain, averaged)]
    assert all(np.array_equal(x, y) for x, y in zip(*taken, strict=True))  # the vehicles act with the online net
    assert averaged.updates == plain.updates > 0
    assert same(weights(averaged.online), weights(plain.online))
    assert averaged.driving is averaged.average
    assert not same(weights(averaged.average), weights(averaged.online))


def test_the_worker_keeps_the_same_average_and_a_resume_carries_it() -> None:
    cfg = dataclasses.replace(CFG, weights_ema=0.9)
    serial, piped = Learner(cfg, 4), Learner(cfg, 4)
    piped.attach(UpdateWorker(cfg, piped.online, piped.target, piped.optimizer, piped.average))
    try:
        for learner in (serial, piped):
            run_steps(learner, np.random.default_rng(9), 12)
        assert same(weights(piped.average), weights(serial.average))
        state = piped.state_dict()
    finally:
        piped.detach()
    resumed = Learner(cfg, 99)
    resumed.load_state_dict(state)
    for learner in (serial, resumed):
        run_steps(learner, np.random.default_rng(10), 5)
    assert same(weights(resumed.average), weights(serial.average))
    with pytest.raises(ValueError, match="moving average"):  # a state without it cannot resume an averaging learner
        Learner(cfg, 4).load_state_dict({k: v for k, v in Learner(CFG, 4).state_dict().items()})


def test_the_decay_is_checked() -> None:
    for bad in (1.0, -0.1, float("nan")):
        with pytest.raises(ValueError, match="weights_ema"):
            DQNConfig(weights_ema=bad, stacked_updates=False).validate()
    DQNConfig(weights_ema=0.999, stacked_updates=False).validate()
    with pytest.raises(ValueError, match="stacked_updates cannot keep a moving average"):
        DQNConfig(weights_ema=0.999).validate()  # the default's stacked learner keeps no average


@pytest.mark.parametrize("value", ["1", "-0.5", "abc"])
def test_a_bad_decay_is_one_line_and_exit_2(tmp_path: Path, value: str) -> None:
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "coopsumo.train", "--weights-ema", value, "--steps", "100",
                           "--out", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "--weights-ema" in lines[0], proc.stderr
    assert not out.exists()


@pytest.mark.sumo
def test_a_training_with_the_average_learns_the_same_and_keeps_the_average(tmp_path: Path) -> None:
    from coopsumo.agents.model_file import load_model
    from coopsumo.agents.train import train
    from coopsumo.config import SimConfig, TrainConfig

    cfg = TrainConfig(sim=SimConfig(steps=400, seed=7, policy="dqn"), eval_steps=0, log_every_steps=200)
    cfg = dataclasses.replace(cfg, dqn=dataclasses.replace(cfg.dqn, select_every_steps=200, validation_steps=100,
                                                              validation_t_ups=(1.0,), validation_accident_steps=0,
                                                              stacked_updates=False))  # torch's updates keep it
    runs = {}
    for decay in (0.0, 0.99):
        out = tmp_path / f"ema_{decay}"
        train(dataclasses.replace(cfg, dqn=dataclasses.replace(cfg.dqn, weights_ema=decay)), out, progress=False,
              learner_process=decay > 0)  # the average kept in the worker and in the serial loop
        runs[decay] = out

    def log(folder: Path) -> list[str]:  # every column but the wall time: the same training
        rows = (folder / "train_log.csv").read_text().splitlines()
        return [",".join(r.split(",")[:14] + r.split(",")[15:]) for r in rows]

    assert log(runs[0.0]) == log(runs[0.99])
    last = {d: load_model(runs[d] / "model_last.pt")[0].state_dict() for d in runs}
    assert not all(torch.equal(last[0.0][k], last[0.99][k]) for k in last[0.0])  # the average, not the online net
    assert (runs[0.0] / "validation.csv").read_text() != (runs[0.99] / "validation.csv").read_text()
