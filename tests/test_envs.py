"""Tests of coopsumo.envs: the official Gymnasium and PettingZoo checkers, seeded reproducibility,
closing SUMO, episodes, and the SB3 training script (skipped without stable-baselines3)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from coopsumo.agents.policies import PolicySpecError
from coopsumo.config import DemandConfig, RoadConfig, SimConfig
from coopsumo.envs import ENV_ID, HighwayEnv, HighwayParallelEnv
from coopsumo.envs.parallel_env import agent_name

REPO = Path(__file__).resolve().parent.parent
LIGHT = SimConfig(road=RoadConfig(lanes=2), demand=DemandConfig(t_up_s=4.0))
"""light traffic: few vehicles, fast steps, vehicles cross the 2000 m road in ~1000 steps"""


def test_importing_envs_registers_the_id_and_starts_no_sumo() -> None:
    code = (
        "import sys, gymnasium, coopsumo.envs\n"
        "print(coopsumo.envs.ENV_ID in gymnasium.registry, 'libsumo' in sys.modules)\n"
        "env = gymnasium.make(coopsumo.envs.ENV_ID)\n"
        "print('libsumo' in sys.modules)\n"
        "env.close()\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO)
    assert out.stdout.split() == ["True", "False", "False"]


def test_bad_arguments_fail_before_sumo_starts() -> None:
    with pytest.raises(PolicySpecError):
        HighwayEnv(background="fast")
    with pytest.raises(PolicySpecError):
        HighwayEnv(background="mobil:p=-1")
    with pytest.raises(ValueError):
        HighwayEnv(background="keep", model_path="model.pt")
    with pytest.raises(ValueError):
        HighwayEnv(max_steps=0)
    env = HighwayEnv()
    with pytest.raises(RuntimeError):
        env.step(2)
    env.close()


@pytest.mark.sumo
def test_gymnasium_check_env() -> None:
    from gymnasium.utils.env_checker import check_env

    env = gym.make(ENV_ID, warmup_steps=30, max_steps=50)
    try:
        with warnings.catch_warnings():
            # speed_err is unbounded by design (the paper's Delta v); the checker only advises bounds
            warnings.filterwarnings("ignore", message=".*observation space (minimum|maximum) value is")
            check_env(env.unwrapped)
    finally:
        env.close()


def rollout(env: HighwayEnv, seed: int, steps: int) -> list[Any]:
    """reset(seed) then `steps` actions from a fixed sequence (lane changes included)."""
    obs, info = env.reset(seed=seed)
    record: list[Any] = [obs, info]
    for action in np.random.default_rng(0).integers(0, 4, steps).tolist():
        obs, reward, terminated, truncated, info = env.step(action)
        record.append((obs, reward, terminated, truncated, info))
        if terminated or truncated:
            break
    return record


def same(a: Any, b: Any) -> bool:
    from gymnasium.utils.env_checker import data_equivalence

    return data_equivalence(a, b, exact=True)


@pytest.mark.sumo
def test_reset_seed_is_reproducible() -> None:
    env = HighwayEnv(warmup_steps=50, max_steps=80, background="random")  # a random background: its RNG too
    try:
        first = rollout(env, seed=11, steps=60)
        again = rollout(env, seed=11, steps=60)
        other = rollout(env, seed=12, steps=60)
        # unseeded resets after a seeded one repeat as well
        env.reset(seed=5)
        unseeded_1 = env.reset()
        env.reset(seed=5)
        unseeded_2 = env.reset()
    finally:
        env.close()
    assert len(first) == 62
    assert same(first, again)
    assert not same(first, other)
    assert same(unseeded_1, unseeded_2)
    assert first[1]["seed"] == 11 and other[1]["seed"] == 12
    # reward = RewardParts.total, components in info
    _, reward, _, _, info = first[5]
    assert reward == pytest.approx(info["reward_speed"] + info["reward_lane_change"] + info["reward_flow"])


@pytest.mark.sumo
def test_close_really_closes_sumo(tmp_path: Path) -> None:
    first = HighwayEnv(warmup_steps=10, max_steps=20)
    second = HighwayEnv(warmup_steps=10, max_steps=20)
    try:
        first.reset(seed=0)
        assert first.world is not None
        run_dir = first.world.run_dir
        assert run_dir.is_dir()
        with pytest.raises(RuntimeError, match="already open"):  # libsumo: one SUMO per process
            second.reset(seed=0)
        first.close()
        assert first.world is None and not run_dir.exists()
        first.close()  # closing twice is fine
        obs, _ = second.reset(seed=0)  # a second env can start now
        assert second.observation_space.contains(obs)
        second.step(2)
    finally:
        first.close()
        second.close()
    # and after both are closed, the parallel env (and then a plain World) can run
    par = HighwayParallelEnv(LIGHT, max_steps=20)
    try:
        par.reset(seed=0)
    finally:
        par.close()
    from coopsumo.sim.world import World

    with World(SimConfig(steps=5), tmp_path) as world:
        world.apply(np.zeros(len(world.observe()), np.int64))


@pytest.mark.sumo
def test_episode_ends_when_the_agent_leaves_the_road() -> None:
    env = HighwayEnv(LIGHT, warmup_steps=0, max_steps=3000, background="mobil")
    try:
        _, info = env.reset(seed=3)
        assert info["vehicle"] == 0  # no warm-up: the first vehicle is the agent
        total, steps = 0.0, 0
        while True:
            obs, reward, terminated, truncated, info = env.step(2)
            total += reward
            steps += 1
            if terminated or truncated:
                break
        assert terminated and not truncated and info["arrived"]
        assert env.observation_space.contains(obs)
        assert 300 < steps < 3000
        with pytest.raises(RuntimeError):
            env.step(2)
        # a short max_steps truncates
        env_short = env
        env_short.max_steps = 5
        env_short.reset(seed=3)
        results = [env_short.step(3) for _ in range(5)]
        assert [r[3] for r in results] == [False] * 4 + [True]
    finally:
        env.close()


@pytest.mark.sumo
def test_trained_dqn_as_background(tmp_path: Path) -> None:
    import torch

    from coopsumo.agents.dqn import QNetwork
    from coopsumo.agents.model_file import save_model
    from coopsumo.dqn_config import DQNConfig

    torch.manual_seed(0)
    save_model(tmp_path / "model.pt", QNetwork(DQNConfig().speed_scale_mps), {"note": "untrained"})
    env = gym.make(ENV_ID, model_path=str(tmp_path / "model.pt"), warmup_steps=20, max_steps=10)
    try:
        assert env.unwrapped.background == f"dqn:{tmp_path / 'model.pt'}"
        env.reset(seed=1)
        for _ in range(10):
            obs, _, terminated, truncated, _ = env.step(2)
        assert truncated and not terminated
    finally:
        env.close()


@pytest.mark.sumo
def test_pettingzoo_parallel_api() -> None:
    from pettingzoo.test import parallel_api_test

    # max_steps long enough for the first vehicles to leave the road (agents terminate and disappear)
    env = HighwayParallelEnv(LIGHT, max_steps=1100)
    try:
        with warnings.catch_warnings():
            # possible_agents is a superset (vehicles still waiting to depart at the end never appear)
            warnings.filterwarnings("ignore", message="No agents present but not all possible_agents")
            parallel_api_test(env, num_cycles=1200)
    finally:
        env.close()


@pytest.mark.sumo
def test_parallel_env_agents_come_and_go_reproducibly() -> None:
    def episode(env: HighwayParallelEnv, seed: int) -> tuple[list[Any], set[str], set[str]]:
        rng = np.random.default_rng(seed)
        obs, infos = env.reset(seed=seed)
        record: list[Any] = [obs]
        seen, finished = set(env.agents), set()
        while env.agents:
            actions = {a: int(rng.integers(0, 4)) for a in env.agents}
            obs, rewards, terms, truncs, infos = env.step(actions)
            record.append((obs, rewards, terms, truncs))
            finished |= {a for a in terms if terms[a] or truncs[a]}
            assert not finished & set(env.agents)
            seen |= set(env.agents)
        return record, seen, finished

    env = HighwayParallelEnv(LIGHT, max_steps=1100)
    try:
        first, seen, finished = episode(env, 4)
        again, _, _ = episode(env, 4)
    finally:
        env.close()
    assert same(first, again)
    assert agent_name(0) in seen and seen <= set(env.possible_agents)
    assert finished == seen  # everyone ends: arrived (terminated) or truncated at max_steps
    terminated = {a for _, _, terms, _ in first[1:] for a in terms if terms[a]}
    assert agent_name(0) in terminated  # the first vehicle left the road


@pytest.mark.sumo
def test_sb3_dqn_script(tmp_path: Path) -> None:
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "sb3"
    scratch = tmp_path / "tmpdir"  # the script's temporary folder: SB3 used to leave an empty SB3-* folder there
    scratch.mkdir()
    result = subprocess.run(
        [sys.executable, "experiments/sb3_dqn.py", "--steps", "300", "--warmup", "20", "--max-steps", "100",
         "--out", str(out)],
        capture_output=True, text=True, cwd=REPO, timeout=300, check=False, env={**os.environ, "TMPDIR": str(scratch)},
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert list(scratch.glob("SB3-*")) == []
    fields = dict(item.split("=") for item in result.stdout.split())
    assert int(fields["episodes"]) >= 2
    assert np.isfinite(float(fields["mean_episode_reward"]))
    assert (out / "model.zip").is_file() and (out / "summary.json").is_file() and (out / "config.json").is_file()
    # issue 82, probe 18, DL1: its folder was marked a simulate run's, and `simulate --out` replaced it (model.zip
    # lost), exit 0; and the script replaced a simulate run. Each refuses the other's folder now, in one line.
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    run = tmp_path / "run"
    sim = subprocess.run([sys.executable, "-m", "coopsumo", "simulate", "--steps", "20", "--quiet", "--out", str(out)],
                         capture_output=True, text=True, cwd=REPO, timeout=300, check=False)  # fmt: skip
    assert sim.returncode == 2 and sim.stderr.count("\n") == 1 and "sb3_dqn run, not a simulate run" in sim.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    sim = subprocess.run([sys.executable, "-m", "coopsumo", "simulate", "--steps", "20", "--quiet", "--out", str(run)],
                         capture_output=True, text=True, cwd=REPO, timeout=300, check=False)  # fmt: skip
    assert sim.returncode == 0, sim.stderr
    before = {p.name: p.read_bytes() for p in run.iterdir()}
    again = subprocess.run([sys.executable, "experiments/sb3_dqn.py", "--steps", "300", "--warmup", "20",
                            "--max-steps", "100", "--out", str(run)],
                           capture_output=True, text=True, cwd=REPO, timeout=300, check=False)  # fmt: skip
    assert again.returncode == 2 and "simulate run, not a sb3_dqn run" in again.stderr, again.stderr
    assert {p.name: p.read_bytes() for p in run.iterdir()} == before
    # probe 18, TR1: a model of NaN weights drove every vehicle "left", exit 0 (a dqn: model is refused)
    import stable_baselines3 as sb3
    import torch

    from coopsumo.agents.sb3_policy import SB3ModelError, SB3Policy

    model = sb3.DQN.load(out / "model.zip", device="cpu")
    with torch.no_grad():
        next(iter(model.policy.parameters())).fill_(float("nan"))
    model.save(tmp_path / "nan.zip")
    with pytest.raises(SB3ModelError, match=r"nan\.zip has non-finite values \(nan or inf\) in weights 'q_net\."):
        SB3Policy.from_spec(f"sb3:{tmp_path / 'nan.zip'}")
    assert SB3Policy.from_spec(f"sb3:{out / 'model.zip'}").name.startswith("sb3:")


@pytest.mark.sumo
def test_sb3_dqn_script_writes_its_folder_as_simulate_does(tmp_path: Path) -> None:
    """Issue 82, probe 19: sb3_dqn.py took no lock (F1: it removed a running simulate's partial folder, and a simulate
    removed its own), checked no owner (O1: it wrote inside a simulate run, a training, a study, a stored model) and
    ended on SIGTERM without a line, its partial folder left (O2). Now it writes as simulate does."""
    pytest.importorskip("stable_baselines3")
    from coopsumo.run_dirs import out_lock

    script = [sys.executable, "experiments/sb3_dqn.py", "--lanes", "2", "--warmup", "20"]
    sim = subprocess.run([sys.executable, "-m", "coopsumo", "simulate", "--steps", "20", "--quiet", "--out",
                          str(tmp_path / "run")], capture_output=True, text=True, cwd=REPO, timeout=300, check=False)
    assert sim.returncode == 0, sim.stderr
    inside = subprocess.run([*script, "--steps", "30", "--max-steps", "20", "--out", str(tmp_path / "run" / "sub")],
                            capture_output=True, text=True, cwd=REPO, timeout=300, check=False)  # fmt: skip
    assert inside.returncode == 2 and inside.stderr.count("\n") == 1, inside.stderr
    assert "the folder of a coopsumo simulate run" in inside.stderr and not (tmp_path / "run" / "sub").exists()
    busy = tmp_path / "busy"
    with out_lock(busy, "simulate"):  # another command writes there
        held = subprocess.run([*script, "--steps", "30", "--max-steps", "20", "--out", str(busy)],
                              capture_output=True, text=True, cwd=REPO, timeout=300, check=False)  # fmt: skip
    assert held.returncode == 2 and "another coopsumo command is writing" in held.stderr, held.stderr
    proc = subprocess.Popen([*script, "--steps", "100000", "--max-steps", "200", "--out", str(tmp_path / "long")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)  # fmt: skip
    end = time.monotonic() + 120
    while not list(tmp_path.glob(".long.partial-*")):
        assert proc.poll() is None and time.monotonic() < end, proc.communicate()
        time.sleep(0.05)
    time.sleep(1.0)
    proc.terminate()
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143 and err.strip().splitlines() == ["sb3_dqn: interrupted"], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no partial folder, no lock file left


def test_sb3_dqn_script_rejects_bad_input(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "experiments/sb3_dqn.py", "--lanes", "9", "--out", str(tmp_path / "x")],
        capture_output=True, text=True, cwd=REPO, timeout=120, check=False,
    )  # fmt: skip
    assert result.returncode == 2
    assert result.stderr.strip().count("\n") == 0 and "lanes" in result.stderr


@pytest.mark.sumo
def test_decision_interval_option_holds_the_action_and_sums_rewards() -> None:
    k = 10
    env = HighwayEnv(LIGHT, warmup_steps=25, max_steps=4, decision_interval=k)
    try:
        obs, info = env.reset(seed=3)
        world = env.world
        assert world is not None and world.step_count % k == 0 and info["sim_step"] == world.step_count
        before = world.step_count
        _, reward, terminated, truncated, step_info = env.step(2)
        assert world.step_count == before + k and step_info["sim_steps"] == k
        parts = step_info["reward_speed"] + step_info["reward_lane_change"] + step_info["reward_flow"]
        assert reward == pytest.approx(parts)
        for _ in range(3):
            _, _, terminated, truncated, _ = env.step(0)  # left: one request per decision, then speed-up
        assert truncated and not terminated
        assert obs["grids"].shape == (3, 3, 20)
    finally:
        env.close()
    # the same agent with speed-up held by hand in the plain env sums to the same reward
    plain = HighwayEnv(LIGHT, warmup_steps=25, max_steps=4 * k)
    try:
        plain.reset(seed=3)
        assert plain.world is not None
        while plain.world.step_count < before:
            plain.step(2)
        total = sum(plain.step(2)[1] for _ in range(k))
        assert total == pytest.approx(reward)
    finally:
        plain.close()
    with pytest.raises(ValueError, match="decision_interval"):
        HighwayEnv(LIGHT, decision_interval=0)


@pytest.mark.sumo
def test_parallel_env_decision_interval_option() -> None:
    from pettingzoo.test import parallel_api_test

    k = 5
    env = HighwayParallelEnv(LIGHT, max_steps=1100, decision_interval=k)
    try:
        parallel_api_test(env, num_cycles=300)
        env.reset(seed=2)
        assert env.world is not None
        before = env.world.step_count
        _, rewards, _, _, infos = env.step({a: 2 for a in env.agents})
        assert env.world.step_count == before + k
        some = next(iter(rewards))
        parts = infos[some]["reward_speed"] + infos[some]["reward_lane_change"] + infos[some]["reward_flow"]
        assert rewards[some] == pytest.approx(parts)
    finally:
        env.close()
    # the same k steps one at a time: each agent's rewards sum to the held step's reward
    plain = HighwayParallelEnv(LIGHT, max_steps=1100)
    try:
        plain.reset(seed=2)
        first = set(plain.agents)
        total = dict.fromkeys(first, 0.0)
        for _ in range(k):
            _, r, _, _, _ = plain.step({a: 2 for a in plain.agents})
            for a in first:
                total[a] += r.get(a, 0.0)
        assert set(rewards) >= first
        assert all(rewards[a] == pytest.approx(total[a]) for a in first)
    finally:
        plain.close()
    with pytest.raises(ValueError, match="decision_interval"):
        HighwayParallelEnv(LIGHT, decision_interval=0)
