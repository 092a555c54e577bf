"""Passing chances (coopsumo/sim/passing.py): pure functions, no SUMO; one run in SUMO for the summary's keys."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from coopsumo.sim.passing import PassingCount, passing_chances
from coopsumo.sim.physics import LEFT, RIGHT, Neighbours

INF = np.inf


def _around(lead_gap: list[list[float]], lead_speed: list[list[float]], exists: list[list[bool]]) -> Neighbours:
    """Leaders in the left, own and right lane of each vehicle; followers far away."""
    n = len(lead_gap)
    far = np.full((n, 3), INF)
    return Neighbours(np.array(lead_gap, float), np.array(lead_speed, float), np.full((n, 3), -1), far,
                      np.zeros((n, 3)), np.full((n, 3), -1), np.array(exists, bool))  # fmt: skip


def test_a_vehicle_is_held_only_below_its_speed_behind_a_near_leader_and_open_only_where_it_may_pass() -> None:
    speed = np.array([15.0, 15.0, 19.0, 15.0, 15.0, 15.0])
    v_exp = np.full(6, 20.0)
    around = _around(
        lead_gap=[[INF, 30.0, 40.0],  # 0: held; left lane empty and offered -> open
                  [INF, 80.0, INF],  # 1: its leader is far: not held
                  [INF, 30.0, INF],  # 2: only 1 m/s below its speed: not held
                  [20.0, 30.0, 20.0],  # 3: held; both side leaders as slow as its own: not open
                  [INF, 30.0, 20.0],  # 4: held; left empty but not offered, right leader faster but not offered
                  [50.0, 30.0, 20.0]],  # 5: held; the left lane is off the road
        lead_speed=[[0.0, 14.0, 14.0], [0.0, 14.0, 0.0], [0.0, 14.0, 0.0], [14.5, 14.0, 14.0], [0.0, 14.0, 18.0],
                    [20.0, 14.0, 14.0]],
        exists=[[True] * 3, [True] * 3, [True] * 3, [True] * 3, [True] * 3, [False, True, True]],
    )  # fmt: skip
    feasible = np.ones((6, 4), bool)
    feasible[4, [LEFT, RIGHT]] = False
    held, open_ = passing_chances(speed, v_exp, around, feasible)
    assert held.tolist() == [True, False, False, True, True, True]
    assert open_.tolist() == [True, False, False, False, False, False]
    feasible[4, RIGHT] = True  # the right lane's leader is 4 m/s faster than its own: open once offered
    assert passing_chances(speed, v_exp, around, feasible)[1].tolist() == [True, False, False, False, True, False]


def test_a_change_counts_as_taken_only_after_an_open_sample_and_before_the_next() -> None:
    count = PassingCount(every=10)
    nums = np.array([3, 5, 8])
    count.sample(0, nums, np.array([True, True, False]), np.array([True, True, False]))
    count.changed(np.array([8]))  # 8 had no open lane
    count.sample(5, nums, np.array([True, True, True]), np.array([True, True, True]))  # not a sample step
    count.changed(np.array([5]))
    count.changed(np.array([5]))  # counted once
    count.sample(10, nums, np.array([True, False, False]), np.array([False, False, False]))
    count.changed(np.array([3]))  # 3's chance was at step 0: gone by step 10
    out = count.summary()
    assert count.samples == 6 and count.held == 3 and count.open == 2 and count.taken == 1
    assert out == {"held_share": 0.5, "passing_open_share": pytest.approx(2 / 6), "passing_taken_share": 0.5}
    assert math.isnan(PassingCount(10).summary()["passing_taken_share"])


@pytest.mark.sumo
def test_keep_never_takes_a_chance_and_greedy_does(tmp_path: Path) -> None:
    """In SUMO, free flow near capacity: `keep` is held with lanes open and never changes; `greedy` takes some of
    its chances and is held less."""
    from coopsumo.agents.policies import make_policy
    from coopsumo.agents.rollout import run
    from coopsumo.config import DemandConfig, SimConfig

    out = {}
    for policy in ("keep", "greedy"):
        cfg = SimConfig(demand=DemandConfig(t_up_s=1.0), steps=1500, seed=3, policy=policy)
        (tmp_path / policy).mkdir()
        out[policy] = run(cfg, make_policy(policy, np.random.default_rng(3)), tmp_path / policy, progress=False)
    keep, greedy = out["keep"], out["greedy"]
    assert keep["passing_open_share"] > 0 and keep["passing_taken_share"] == 0.0
    assert 0 < greedy["passing_taken_share"] <= 1 and greedy["held_share"] < keep["held_share"]
