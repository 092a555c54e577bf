"""The train command: a short real training run, reproducibility, interrupt and resume, bad input."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest
import torch
from conftest import assert_refused_in_one_line, main_here

from coopsumo.agents.model_file import load_model
from coopsumo.agents.train import train
from coopsumo.config import SimConfig, TrainConfig
from coopsumo.dqn_config import DQN_PRESETS, DQNConfig

pytestmark = pytest.mark.sumo
ROOT = Path(__file__).resolve().parent.parent


def _cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "coopsumo.train", *args]


def _weights(path: Path) -> dict[str, torch.Tensor]:
    net, _ = load_model(path)
    return {k: v.clone() for k, v in net.state_dict().items()}


def _same(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_short_training_loads_and_drives_safely(tmp_path: Path) -> None:
    cfg = TrainConfig(sim=SimConfig(steps=1500, seed=3, policy="dqn"), eval_steps=800, log_every_steps=500)
    run = tmp_path / "train"  # the drive below may not write inside the model's folder
    summary = train(cfg, run, progress=False)
    assert (run / "model.pt").exists()
    log = (run / "train_log.csv").read_text().splitlines()
    assert log[0].startswith("step,sim_time_s,td_loss,r_speed,r_lane_change,r_flow")
    assert len(log) == 1 + 3  # a row per 500 steps
    net, meta = load_model(run / "model.pt")
    assert meta["config"]["sim"]["seed"] == 3 and "torch" in meta["versions"]
    # the greedy evaluation drove the trained model through SUMO
    assert summary["steps"] == 800 and summary["departed"] > 0
    assert summary["collisions"] == 0
    # and the model drives a simulation from the command line
    out = tmp_path / "drive"
    res = subprocess.run(
        [sys.executable, "-m", "coopsumo.simulate", "--policy", f"dqn:{run / 'model.pt'}", "--steps", "600",
         "--lanes", "3", "--out", str(out), "--quiet"],
        capture_output=True, text=True, cwd=ROOT, check=False,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    driven = json.loads((out / "summary.json").read_text())
    assert driven["collisions"] == 0 and driven["teleports"] == 0
    assert summary["teleports"] == 0
    # a model is driven with the decision interval it was trained with
    assert cfg.dqn.decision_interval_steps == 10
    assert driven["decision_interval_steps"] == summary["decision_interval_steps"] == 10


@pytest.mark.parametrize("preset", ["default", "paper", "v2x", "conditioned"])
def test_same_seed_same_weights(tmp_path: Path, preset: str) -> None:
    """Trainings of 400 steps (updates from step 200; the conditioned alpha drawn twice), the paper's 700 (its target
    network synced at step 500)."""
    dqn = replace(DQNConfig(), observation="v2x") if preset == "v2x" else DQN_PRESETS.get(preset, DQNConfig())
    steps = 700 if preset == "paper" else 400
    if preset == "conditioned":
        dqn = replace(dqn, alpha_conditioned=True, alpha_period_steps=200)
    cfg = TrainConfig(sim=SimConfig(steps=steps, seed=5, policy="dqn"), dqn=dqn, eval_steps=0)
    train(cfg, tmp_path / "a", progress=False)
    train(cfg, tmp_path / "b", progress=False)
    assert _same(_weights(tmp_path / "a" / "model.pt"), _weights(tmp_path / "b" / "model.pt"))
    other = TrainConfig(sim=SimConfig(steps=steps, seed=6, policy="dqn"), dqn=dqn, eval_steps=0)
    train(other, tmp_path / "c", progress=False)
    assert not _same(_weights(tmp_path / "a" / "model.pt"), _weights(tmp_path / "c" / "model.pt"))


LOG_EVERY_250 = """
import dataclasses, sys
import coopsumo.agents.train_cli as t
base = t.config_from_args
t.config_from_args = lambda args: dataclasses.replace(base(args), log_every_steps=250)
sys.exit(t.main(sys.argv[1:]))
"""
"""`python -m coopsumo.train` with a log row every 250 steps"""


@pytest.mark.parametrize("preset", ["paper", "features"])
def test_interrupt_then_resume_equals_uninterrupted(tmp_path: Path, preset: str) -> None:
    """Each state a checkpoint must keep, within 1,500 steps: `features` is the default learner (the v2x state,
    drawn demands and accidents, its updates in the second process, whose state the checkpoint asks for) with
    episodes of 1,200 steps (the cut after 1,000 lands inside one), the alpha-conditioned network's alpha schedule,
    the followers' speed in the reward and model selection all at work
    in one training (any state a resume lost would change the weights). `paper` (its replay, SGD and target network
    synced every 500 steps) in 700 steps, logged every 250 (tests/test_faults.py's driver): the cut after step 250,
    once it updates, and its target synced at 500 after the resume."""
    sig = signal.SIGTERM  # Ctrl-C (SIGINT) is exercised by tests/test_docs.py on the README's commands
    learner = {"features": ["--observation", "v2x", "--alpha-conditioned", "--alpha-period", "700",
                            "--train-t-up", "1.5,1", "--accident-share", "0.5", "--episode-steps", "1200",
                            "--select-every", "1000", "--validation-steps", "300", "--validation-t-up", "1.5",
                            "--validation-accident-steps", "600", "--followers-weight", "1", "--update-worker", "on"]
               }.get(preset, ["--preset", preset])  # fmt: skip
    steps = "1500" if preset == "features" else "700"
    args = ["--steps", steps, "--eval-steps", "0", "--seed", "2", "--quiet", *learner]

    def command(*extra: str) -> list[str]:
        return _cmd(*extra) if preset == "features" else [sys.executable, "-c", LOG_EVERY_250, *extra]

    full = tmp_path / "full"
    subprocess.run(command(*args, "--out", str(full)), check=True, cwd=ROOT, capture_output=True)
    cut = tmp_path / "cut"
    proc = subprocess.Popen(command(*args, "--out", str(cut)), cwd=ROOT, stderr=subprocess.PIPE, text=True)
    log = cut / "train_log.csv"
    deadline = time.time() + 120
    while time.time() < deadline and (not log.exists() or len(log.read_text().splitlines()) < 2):
        time.sleep(0.05)
    os.kill(proc.pid, sig)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + sig, err
    assert "Traceback" not in err and "--resume" in err
    assert (cut / "checkpoint.pt").exists() and not (cut / "model.pt").exists()
    if preset == "features":  # the checkpoint's observation is kept: another one beside --resume is refused
        other = subprocess.run(_cmd("--resume", "--out", str(cut), "--observation", "paper"), cwd=ROOT,
                               capture_output=True, text=True)  # fmt: skip
        assert other.returncode == 2 and "--observation paper differs" in other.stderr
        assert len(other.stderr.strip().splitlines()) == 1
    res = subprocess.run(_cmd("--resume", "--out", str(cut), "--quiet"), cwd=ROOT, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert not (cut / "checkpoint.pt").exists()
    assert _same(_weights(full / "model.pt"), _weights(cut / "model.pt"))
    if preset == "features":  # the resumed training validated the same snapshots to the same scores and kept the best
        assert (full / "validation.csv").read_text() == (cut / "validation.csv").read_text()
        assert _same(_weights(full / "model_last.pt"), _weights(cut / "model_last.pt"))


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize(
    "args, fragment",
    [
        (["--alpha", "-1"], "alpha"),
        (["--alpha", "nan"], "alpha"),
        (["--alpha", "inf"], "alpha"),
        (["--steps", "0"], "steps"),
        (["--lanes", "7"], "lanes"),
        (["--t-up", "0"], "t-up"),
        (["--resume"], "resume"),
        (["--gamma", "1"], "gamma"),
        (["--gamma", "nan"], "gamma"),
        (["--observation", "lidar"], "observation"),
        (["--change-margin", "-1"], "change-margin"),
        (["--n-step", "3"], "unrecognized arguments: --n-step"),  # retired (issue 80)
    ],
)
def test_bad_input_one_line_exit_2(tmp_path: Path, args: list[str], fragment: str,
                                   capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """python -m coopsumo.train's main, in this process (the one-line refusal of a command run as a process:
    tests/test_bad_inputs.py)."""
    from coopsumo import train as train_command

    out = tmp_path / "out"
    extra = [] if "--resume" in args else ["--out", str(out)]
    code, _, err = main_here(train_command.main, [*args, *extra], capsys)
    assert_refused_in_one_line(code, err, out, fragment)


def test_bad_model_files_are_usage_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """simulate's own main in this process (refused before SUMO starts; the one-line refusal of a command run as a
    process: tests/test_bad_inputs.py)."""
    from coopsumo import simulate

    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a model")
    for model in (tmp_path / "missing.pt", garbage):
        out = tmp_path / f"out_{model.stem}"
        capsys.readouterr()
        code = simulate.main(["--policy", f"dqn:{model}", "--steps", "10", "--out", str(out)])
        err = capsys.readouterr().err
        assert code == 2, err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
        assert not out.exists()
