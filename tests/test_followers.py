"""The followers' speed in the training reward (--followers-weight): the world's term against a direct count on a
real SUMO run with lane changes, and its flags' bad values."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from coopsumo.agents.policies import make_policy
from coopsumo.config import DemandConfig, SimConfig
from coopsumo.sim.world import World

ROOT = Path(__file__).resolve().parent.parent


def direct(nums: np.ndarray, lane: np.ndarray, other: np.ndarray, pos: np.ndarray, r_v: np.ndarray,
           window_m: float) -> np.ndarray:
    """The mean r_v of the vehicles behind within window_m in each vehicle's lanes, one pair at a time."""
    out = np.zeros(len(nums))
    for i in range(len(nums)):
        mine = {int(lane[i])} | ({int(other[i])} if other[i] >= 0 else set())
        values = []
        for j in range(len(nums)):
            theirs = {int(lane[j])} | ({int(other[j])} if other[j] >= 0 else set())
            values += [r_v[j]] * sum(1 for ln in mine & theirs if pos[i] - window_m <= pos[j] < pos[i] and j != i)
        out[i] = np.mean(values) if values else 0.0
    return out


@pytest.mark.sumo
def test_the_worlds_followers_term_is_the_direct_count_on_a_run_with_lane_changes(tmp_path: Path) -> None:
    cfg = SimConfig(steps=600, seed=3, demand=DemandConfig(t_up_s=0.8), policy="random")
    policy = make_policy("random", np.random.default_rng([cfg.seed, 3]))
    checked = changers = 0
    with World(cfg, tmp_path) as world:
        for step in range(cfg.steps):
            out = world.apply(policy.act(world.observe()))
            if step % 100 != 99:
                continue
            t = world.table
            other = world._other_lane(t.nums, t.lane)
            r_v = (t.speed - world.veh.v_exp[t.nums]) / (cfg.reward.v_max_mps - cfg.reward.v_min_mps)
            want = direct(t.nums, t.lane, other, t.pos, r_v, 50.0)
            got = world.followers_speed_reward(t.nums, 50.0)
            np.testing.assert_allclose(got, want, atol=1e-12)
            # vehicles asked about that left the road get 0
            gone = np.setdiff1d(out.nums, t.nums)
            assert np.all(world.followers_speed_reward(gone, 50.0) == 0.0)
            checked += int(np.count_nonzero(want))
            changers += int(np.count_nonzero(other >= 0))
    assert checked > 100 and changers > 0  # the check saw vehicles with followers and lane changers


@pytest.mark.parametrize("args", [["--followers-weight", "-1"], ["--followers-weight", "nan"], ["--followers-m", "0"]])
def test_bad_followers_flags_are_one_line_usage_errors(tmp_path: Path, args: list[str]) -> None:
    out = tmp_path / "run"
    res = subprocess.run([sys.executable, "-m", "coopsumo.train", "--steps", "50", "--out", str(out), *args],
                         capture_output=True, text=True, cwd=ROOT, check=False)  # fmt: skip
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and args[0] in lines[0] and "Traceback" not in res.stderr
    assert not out.exists()
