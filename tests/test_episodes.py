"""Training where the model is used (agents/episodes.py): each episode's demand and accident drawn from the seed."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import pytest

from coopsumo.agents.episodes import ACCIDENT_X_M, SEED_LOW, episode_bounds, episode_config, episodic
from coopsumo.config import SimConfig
from coopsumo.dqn_config import PAPER_DQN, DQNConfig

ROOT = Path(__file__).resolve().parent.parent
MIX = dataclasses.replace(DQNConfig(), train_t_ups=(2.0, 1.5, 1.0), accident_share=0.5, episode_steps=9000)


def test_the_draw_is_a_pure_function_of_seed_and_episode() -> None:
    base = SimConfig(seed=4, steps=90_000, policy="dqn")
    worlds = [episode_config(base, MIX, i) for i in range(200)]
    assert worlds == [episode_config(base, MIX, i) for i in range(200)]
    assert worlds != [episode_config(dataclasses.replace(base, seed=5), MIX, i) for i in range(200)]
    assert {w.demand.t_up_s for w in worlds} == {2.0, 1.5, 1.0}
    assert len({w.seed for w in worlds}) == 200 and min(w.seed for w in worlds) >= SEED_LOW
    crashes = [w.accident for w in worlds if w.accident.enabled]
    assert 70 < len(crashes) < 130  # about half of 200
    assert all(ACCIDENT_X_M[0] <= a.x_m <= ACCIDENT_X_M[1] for a in crashes)
    assert all(0 < a.start_step and a.start_step + a.duration_steps < 9000 for a in crashes)
    assert len({(a.x_m, a.start_step, a.duration_steps) for a in crashes}) == len(crashes)
    assert all(w.steps == 9000 and w.road == base.road for w in worlds)


def test_without_a_mix_the_training_is_one_world() -> None:
    one_world = dataclasses.replace(DQNConfig(), train_t_ups=(), accident_share=0.0)
    assert not episodic(one_world) and not episodic(PAPER_DQN)  # the paper trains in free flow at one demand
    assert episodic(DQNConfig())  # the default trains on the mix
    assert episode_bounds(90_000, one_world, 12_345) == (0, 0, 90_000)
    assert episode_bounds(90_000, MIX, 12_345) == (1, 9000, 18_000)
    assert episode_bounds(10_000, MIX, 9500) == (1, 9000, 10_000)
    share_zero = dataclasses.replace(MIX, accident_share=0.0)
    assert not any(episode_config(SimConfig(seed=1), share_zero, i).accident.enabled for i in range(50))


@pytest.mark.parametrize(
    "args, fragment",
    [
        (["--accident-share", "1.5"], "--accident-share"),
        (["--accident-share", "-0.1"], "--accident-share"),
        (["--accident-share", "nan"], "--accident-share"),
        (["--train-t-up", ""], "--train-t-up"),
        (["--train-t-up", "1,,2"], "--train-t-up"),
        (["--train-t-up", "0"], "--train-t-up"),
        (["--train-t-up", "-2"], "--train-t-up"),
        (["--episode-steps", "10"], "--episode-steps"),
    ],
)
def test_bad_mix_flags_are_one_line_usage_errors(tmp_path: Path, args: list[str], fragment: str) -> None:
    out = tmp_path / "run"
    res = subprocess.run([sys.executable, "-m", "coopsumo.train", "--steps", "50", "--out", str(out), *args],
                         capture_output=True, text=True, cwd=ROOT, check=False)  # fmt: skip
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and fragment in lines[0] and "Traceback" not in res.stderr
    assert not out.exists()
