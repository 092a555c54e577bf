"""The learner's updates in a second process (agents/update_worker.py): the same model bit for bit as the serial
loop, a resume that stays exact, and a worker that dies ending the training in one line with a checkpoint."""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from coopsumo.agents.dqn import Learner
from coopsumo.agents.model_file import load_model
from coopsumo.agents.update_worker import LearnerProcessError, UpdateWorker
from coopsumo.dqn_config import PAPER_DQN, DQNConfig
from tests.test_dqn import random_transitions, run_steps, same, weights

ROOT = Path(__file__).resolve().parent.parent


def _attached(cfg: DQNConfig, seed: int) -> Learner:
    learner = Learner(cfg, seed)
    learner.attach(UpdateWorker(cfg, learner.online, learner.target, learner.optimizer))
    return learner


@pytest.mark.parametrize("conditioned", [False, True])
def test_worker_learns_exactly_what_the_serial_learner_learns(conditioned: bool) -> None:
    cfg = dataclasses.replace(PAPER_DQN, replay_size=64, batch_size=8, learn_start_steps=0, target_sync_steps=3,
                              learn_every=1, updates_per_learn=2, double_dqn=True, loss="huber",
                              alpha_conditioned=conditioned, alpha_relabel=0.5 if conditioned else 0.0)  # fmt: skip
    serial, piped = Learner(cfg, 4), _attached(cfg, 4)

    def drive(learner: Learner, seed: int, steps: int) -> None:
        if not conditioned:
            run_steps(learner, np.random.default_rng(seed), steps)
            return
        rng = np.random.default_rng(seed)
        for _ in range(steps):  # alphas travel in the slots too
            t = random_transitions(rng, 5)
            alphas = rng.choice([0.0, 8.0], 5).astype(np.float32)
            t["actions"] = learner.act(t["grids"], t["features"], explore=True, alphas=alphas)
            learner.observe(**t, alphas=alphas, lane_changes=(rng.random(5) < 0.3).astype(np.float32))
            learner.step()

    try:
        for learner in (serial, piped):
            drive(learner, 9, 12)
        assert piped.updates == serial.updates > 0
        assert same(weights(piped.online), weights(serial.online))
        assert piped.take_losses() == serial.take_losses()
        state = piped.state_dict()  # the worker's target network and optimiser, fetched
        assert same(list(state["target"].values()), list(serial.target.state_dict().values()))
        assert state["optimizer"]["state"].keys() == serial.optimizer.state_dict()["state"].keys()
        piped.detach()  # and taken back: the learner goes on alone, still in step with the serial one
        assert piped.worker is None
        assert same(weights(piped.target), weights(serial.target))
        for learner in (serial, piped):
            drive(learner, 10, 4)
        assert same(weights(piped.online), weights(serial.online))
    finally:
        if piped.worker is not None:
            piped.worker.close()


def test_a_dead_worker_is_reported_in_one_line() -> None:
    cfg = dataclasses.replace(PAPER_DQN, replay_size=64, batch_size=8, learn_start_steps=0, learn_every=1)
    learner = _attached(cfg, 0)
    worker = learner.worker
    assert isinstance(worker, UpdateWorker)
    try:
        learner.observe(**random_transitions(np.random.default_rng(0), 16))
        assert worker.process.pid is not None
        os.kill(worker.process.pid, signal.SIGKILL)
        worker.process.join(timeout=10)
        with pytest.raises(LearnerProcessError, match=r"^the learner process died \(killed by signal 9\)$"):
            for _ in range(3):  # the first send may still fit in the pipe; a wait cannot succeed
                learner.step()
                learner.wait()
    finally:
        worker.close()


def test_a_ctrl_c_while_the_worker_starts_reaches_the_training(monkeypatch: pytest.MonkeyPatch) -> None:
    """A signal sent while the worker process starts is held until it has started, then delivered here (the
    training checkpoints on it); the worker lives on."""
    import multiprocessing.process

    got: list[int] = []
    real_start = multiprocessing.process.BaseProcess.start

    def start(self: multiprocessing.process.BaseProcess) -> None:
        os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C lands in the middle of the start
        real_start(self)

    monkeypatch.setattr(multiprocessing.process.BaseProcess, "start", start)
    old = signal.signal(signal.SIGINT, lambda signum, _frame: got.append(signum))
    try:
        learner = _attached(dataclasses.replace(PAPER_DQN, replay_size=64, batch_size=8), 0)
        for _ in range(100):  # the handler runs between bytecodes once the signal is unblocked
            if got:
                break
            time.sleep(0.01)
        worker = learner.worker
        assert isinstance(worker, UpdateWorker) and worker.process.is_alive()
        worker.close()
    finally:
        signal.signal(signal.SIGINT, old)
    assert got == [signal.SIGINT]


@pytest.mark.sumo
def test_train_in_two_processes_equals_serial(tmp_path: Path) -> None:
    from coopsumo.agents.train import train
    from coopsumo.config import SimConfig, TrainConfig

    # 800 steps: updates from step 200, 4 log rows, model selection at steps 400 and 800 (on one demand)
    cfg = TrainConfig(sim=SimConfig(steps=800, seed=7, policy="dqn"), eval_steps=0, log_every_steps=200)
    cfg = dataclasses.replace(cfg, dqn=dataclasses.replace(cfg.dqn, select_every_steps=400, validation_steps=200,
                                                              validation_t_ups=(1.5,), validation_accident_steps=0,
                                                              stacked_updates=False))  # torch's: in a process or not
    runs = {}
    for process in (True, False):
        out = tmp_path / f"process_{process}"
        summary = train(cfg, out, progress=False, learner_process=process)
        assert summary["learner_process"] is process
        runs[process] = out
    net = {k: load_model(runs[k] / "model.pt")[0].state_dict() for k in runs}
    assert net[True].keys() == net[False].keys() and all(torch.equal(net[True][k], net[False][k]) for k in net[True])

    def log(folder: Path) -> list[str]:  # every column but the wall time
        rows = (folder / "train_log.csv").read_text().splitlines()
        return [",".join(r.split(",")[:14] + r.split(",")[15:]) for r in rows]

    assert log(runs[True]) == log(runs[False]) and len(log(runs[True])) == 5
    assert (runs[True] / "validation.csv").read_text() == (runs[False] / "validation.csv").read_text()


LOG_EVERY_250 = """
import dataclasses, sys
import coopsumo.agents.train_cli as t
base = t.config_from_args
t.config_from_args = lambda args: dataclasses.replace(base(args), log_every_steps=250)
sys.exit(t.main(sys.argv[1:]))
"""
"""`coopsumo train` with a log row every 250 steps (as tests/test_faults.py's driver), so that a row is written soon
after the updates begin (step 200)"""


def _training_with_its_worker(out: Path) -> tuple[subprocess.Popen[str], list[str], list[str]]:
    """A real `train` of 800 steps with its update worker, once its log has a row (step 250, the worker updating):
    the process, its argv and the worker's pids."""
    args = [sys.executable, "-c", LOG_EVERY_250, "--steps", "800", "--eval-steps", "0", "--seed", "3",
            "--update-worker", "on", "--out", str(out), "--quiet"]  # fmt: skip
    proc = subprocess.Popen(args, cwd=ROOT, stderr=subprocess.PIPE, text=True)
    log = out / "train_log.csv"
    deadline = time.time() + 120
    while time.time() < deadline and (not log.exists() or len(log.read_text().splitlines()) < 2):
        time.sleep(0.05)
    children = subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True, text=True).stdout.split()
    assert children, "no learner process beside the training"
    return proc, args, children


@pytest.mark.sumo
def test_a_killed_worker_ends_the_training_in_one_line_and_it_resumes(tmp_path: Path) -> None:
    out = tmp_path / "run"
    proc, args, children = _training_with_its_worker(out)
    for pid in children:
        os.kill(int(pid), signal.SIGKILL)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 1, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "the learner process died (killed by signal 9)" in lines[0], err
    assert f"--resume --out {out}" in lines[0]
    assert (out / "checkpoint.pt").exists() and not (out / "model.pt").exists()
    res = subprocess.run([sys.executable, "-m", "coopsumo.train", "--resume", "--out", str(out), "--quiet"], cwd=ROOT,
                         capture_output=True, text=True)  # fmt: skip
    assert res.returncode == 0, res.stderr
    serial = tmp_path / "serial"
    subprocess.run([*args[:-3], "--out", str(serial), "--quiet", "--update-worker", "off"], cwd=ROOT, check=True,
                   capture_output=True)  # fmt: skip
    a, b = (load_model(folder / "model.pt")[0].state_dict() for folder in (out, serial))
    assert all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.sumo
def test_a_worker_that_dies_during_a_stop_ends_the_training_as_stopped(tmp_path: Path) -> None:
    """A Ctrl-C to the whole group can kill the worker in ways of its own (its interpreter still starting: exit 1 or
    an abort); when the training process got the stop too, the worker's death is that stop, not an error."""
    out = tmp_path / "run"
    proc, _, children = _training_with_its_worker(out)
    os.kill(proc.pid, signal.SIGINT)  # the stop first, then the worker's death before the checkpoint can ask it
    for pid in children:
        os.kill(int(pid), signal.SIGKILL)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGINT, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("train: interrupted") and "error" not in lines[0], err
    assert f"--resume --out {out}" in lines[0] and (out / "checkpoint.pt").exists()
