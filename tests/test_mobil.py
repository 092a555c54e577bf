"""Tests of coopsumo.agents.mobil: MOBIL's incentive and safety criteria on hand-made layouts, the spec
parser, and real SUMO runs near capacity (no collisions, no teleports, some lane changes)."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from coopsumo.agents.mobil import MobilPolicy, newell_accel
from coopsumo.agents.policies import PolicySpecError
from coopsumo.config import ControlConfig, DemandConfig, RoadConfig, SimConfig
from coopsumo.sim import physics
from coopsumo.sim.observation import Observation
from coopsumo.sim.physics import LEFT, RIGHT, SPEEDUP, Neighbours, newell_speed

CTRL = ControlConfig()
INF = np.inf
Layout = Callable[..., Observation]


def gap_for_speed(v: float, v_exp: float, cfg: ControlConfig = CTRL) -> float:
    """The gap (m) at which the Newell bound of eq. (9) equals v (inverse of physics.newell_speed)."""
    return (math.log(v_exp / (v_exp - v)) - cfg.newell_d) * v_exp / cfg.newell_c_per_s


def test_gap_for_speed_inverts_newell() -> None:
    assert newell_speed(np.array([gap_for_speed(20.0, 30.0)]), np.array([30.0]), CTRL)[0] == pytest.approx(20.0)


def test_newell_accel_is_one_controller_step_over_dt() -> None:
    # free road below v_exp: +v_acc per step = 4 m/s^2; at v_exp: 0; stuck behind a close slow leader: hard braking
    a = newell_accel(np.array([20.0, 30.0, 20.0]), np.array([30.0, 30.0, 30.0]), np.array([INF, INF, 10.0]),
                     np.array([0.0, 0.0, 5.0]), CTRL)  # fmt: skip
    assert a[0] == pytest.approx(CTRL.v_acc_mps / CTRL.dt_s)
    assert a[1] == pytest.approx(0.0)
    assert a[2] == pytest.approx((5.0 - CTRL.v_cc_mps - 20.0) / CTRL.dt_s)  # the collision check: v_lead - v_cc


def cut_in_layout(observation_of: Layout, follower_v_exp: float = 30.0, shift: float = 0.0) -> Observation:
    """Vehicle 0 (lane 0, 20 m/s, wants 30) follows a 20 m/s leader at its Newell gap, so it cannot speed up
    (a_c = 0); the left lane is free ahead (a~_c = +4 m/s^2). Vehicle 2 in the left lane, 26 m/s, is free now
    (+4 m/s^2 if it wants 30); behind vehicle 0 it would get a Newell bound of 25.9 m/s (a~_n = -1 m/s^2)."""
    x = 500.0 + shift
    g_c = gap_for_speed(20.0, 30.0)
    g_n = gap_for_speed(25.9, follower_v_exp)
    return observation_of(
        lane=[0, 0, 1],
        pos=[x, x + 4.0 + g_c, x - 4.0 - g_n],
        speed=[20.0, 20.0, 26.0],
        v_exp=[30.0, 20.0, follower_v_exp],
        n_lanes=2,
    )


@pytest.mark.parametrize(("p", "expected"), [(0.0, LEFT), (0.5, LEFT), (1.0, SPEEDUP)])
def test_selfish_changes_where_polite_does_not(observation_of: Layout, p: float, expected: int) -> None:
    obs = cut_in_layout(observation_of)
    policy = MobilPolicy(p=p)
    incentive, admissible = policy.incentives(obs)
    # own gain +4; the new follower goes from +4 to -1 m/s^2: d_n = -5
    assert incentive[0, 0] == pytest.approx(4.0 - 5.0 * p, abs=1e-6)
    assert admissible[0, 0]  # b_safe = 4 m/s^2 allows a~_n = -1 m/s^2
    assert policy.decide(obs)[0] == expected


def test_followers_use_their_own_expected_speed(observation_of: Layout) -> None:
    # the new follower already drives at its v_exp = 26 m/s (a_n = 0, not +4), with the gap at which it
    # would be bounded to 25.9 m/s behind vehicle 0: it loses only 1 m/s^2
    obs = cut_in_layout(observation_of, follower_v_exp=26.0)
    policy = MobilPolicy(p=1.0)
    assert policy.incentives(obs)[0][0, 0] == pytest.approx(4.0 - 1.0, abs=1e-6)
    assert policy.decide(obs)[0] == LEFT


def b_safe_layout(observation_of: Layout, follower_gap_m: float) -> Observation:
    """Vehicle 0 (lane 0, 15 m/s, wants 30) stuck behind a 15 m/s leader; the left lane is free ahead;
    vehicle 2 comes up the left lane at its v_exp = 30 m/s, `follower_gap_m` behind."""
    g_c = gap_for_speed(15.0, 30.0)
    return observation_of(
        lane=[0, 0, 1],
        pos=[500.0, 504.0 + g_c, 496.0 - follower_gap_m],
        speed=[15.0, 15.0, 30.0],
        v_exp=[30.0, 15.0, 30.0],
        n_lanes=2,
    )


def test_b_safe_forbids_a_change_that_makes_the_new_follower_brake_too_hard(observation_of: Layout) -> None:
    obs = b_safe_layout(observation_of, follower_gap_m=25.0)  # room for the controller, but a Newell bound of ~17 m/s
    a_n_after = newell_accel(np.array([30.0]), np.array([30.0]), np.array([25.0]), np.array([15.0]), CTRL)[0]
    assert a_n_after < -100.0
    assert MobilPolicy(p=0.0).act(obs)[0] == SPEEDUP  # selfish, yet b_safe = 4 m/s^2 forbids it
    assert MobilPolicy(p=0.0, b_safe=-a_n_after + 1.0).act(obs)[0] == LEFT


def test_b_safe_boundary(observation_of: Layout) -> None:
    # new follower at 30 m/s (its v_exp) would be bounded to 29.7 m/s: a~_n = -3 m/s^2
    obs = b_safe_layout(observation_of, follower_gap_m=gap_for_speed(29.7, 30.0))
    assert MobilPolicy(p=0.0, b_safe=4.0).act(obs)[0] == LEFT
    assert MobilPolicy(p=0.0, b_safe=2.0).act(obs)[0] == SPEEDUP


def test_no_change_when_nothing_is_gained(observation_of: Layout) -> None:
    g = gap_for_speed(20.0, 30.0)
    layouts = [
        observation_of(lane=[0], pos=[100.0], speed=[30.0], v_exp=[30.0], n_lanes=2),  # alone at its v_exp
        observation_of(lane=[0], pos=[100.0], speed=[20.0], v_exp=[30.0], n_lanes=2),  # alone: +4 m/s^2 anywhere
        # behind a leader, with an identical leader alongside in the next lane
        observation_of(lane=[0, 0, 1], pos=[800.0, 804.0 + g, 804.0 + g], speed=[20.0, 20.0, 20.0],
                       v_exp=[30.0, 20.0, 20.0], n_lanes=2),
    ]  # fmt: skip
    for obs in layouts:
        for p in (0.0, 0.5, 1.0):
            policy = MobilPolicy(p=p, threshold=0.0)
            assert policy.act(obs)[0] == SPEEDUP
            incentive, admissible = policy.incentives(obs)
            assert admissible[0].tolist() == [True, False]  # left is there, right is off the road
            assert incentive[0, 0] == pytest.approx(0.0, abs=1e-9)


def test_threshold_and_right_bias(observation_of: Layout) -> None:
    """Vehicle 0 in the middle lane is stuck; left is free (gain 4), right has a leader it can follow at +3.7."""
    g_c = gap_for_speed(20.0, 30.0)
    g_r = gap_for_speed(20.37, 30.0)
    obs = observation_of(
        lane=[1, 1, 0],
        pos=[500.0, 504.0 + g_c, 504.0 + g_r],
        speed=[20.0, 20.0, 20.0],
        v_exp=[30.0, 20.0, 20.0],
        n_lanes=3,
    )
    incentive, _ = MobilPolicy().incentives(obs)
    assert incentive[0] == pytest.approx([4.0, 3.7], abs=1e-6)
    assert MobilPolicy().decide(obs)[0] == LEFT
    assert MobilPolicy(bias=0.5).decide(obs)[0] == RIGHT  # right needs 3.7 > 0.1 - 0.5; left 4 - 0.6 < 3.7 + 0.4
    assert MobilPolicy(threshold=4.5).decide(obs)[0] == SPEEDUP
    assert MobilPolicy(threshold=3.8).decide(obs)[0] == LEFT


def test_polite_driver_makes_way_for_a_faster_follower() -> None:
    """Neighbours built by hand: vehicle 0 (20 m/s = its v_exp, nothing to gain) holds up vehicle 1
    (30 m/s, wants 30, braking at -10 m/s^2). Leaving to the free left lane frees vehicle 1 (+10)."""
    g_o = gap_for_speed(29.0, 30.0)
    around = Neighbours(
        # columns: left, own, right; vehicle 1 sees vehicle 0 ahead in its own lane
        lead_gap=np.array([[INF, INF, INF], [INF, g_o, INF]]),
        lead_speed=np.array([[0.0, 0.0, 0.0], [0.0, 20.0, 0.0]]),
        lead_idx=np.array([[-1, -1, -1], [-1, 0, -1]]),
        follow_gap=np.array([[INF, g_o, INF], [INF, INF, INF]]),
        follow_speed=np.array([[0.0, 30.0, 0.0], [0.0, 0.0, 0.0]]),
        follow_idx=np.array([[-1, 1, -1], [-1, -1, -1]]),
        exists=np.array([[True, True, False], [True, True, False]]),
    )
    obs = Observation(
        nums=np.array([0, 1]), grids=np.zeros((2, 3, 3, 20), np.uint8), speed_err=np.zeros((2, 3), np.float32),
        lane=np.array([0, 0]), pos=np.array([500.0, 496.0 - g_o]), speed=np.array([20.0, 30.0]),
        v_exp=np.array([20.0, 30.0]), busy=np.array([False, False]), around=around, n_lanes=2,
        feasible=physics.feasible_actions(around, np.array([False, False]), np.array([20.0, 30.0]), ControlConfig()),
    )  # fmt: skip
    incentive, _ = MobilPolicy(p=0.5).incentives(obs)
    assert incentive[0, 0] == pytest.approx(0.5 * 10.0, abs=1e-6)
    assert MobilPolicy(p=0.0).act(obs)[0] == SPEEDUP
    assert MobilPolicy(p=0.5).act(obs)[0] == LEFT


def test_only_changes_the_controller_would_accept(observation_of: Layout) -> None:
    obs = cut_in_layout(observation_of)
    assert MobilPolicy(p=0.0).act(obs)[0] == LEFT
    # already changing lane (busy): no new request
    g_c = gap_for_speed(20.0, 30.0)
    busy = observation_of(lane=[0, 0], pos=[500.0, 504.0 + g_c], speed=[20.0, 20.0], v_exp=[30.0, 20.0],
                          n_lanes=3, other_lane=[1, -1])  # fmt: skip
    assert MobilPolicy(p=0.0).act(busy)[0] == SPEEDUP
    # a vehicle alongside in the target lane: physics.lane_change_safe fails, whatever MOBIL thinks
    alongside = observation_of(lane=[0, 0, 1], pos=[500.0, 504.0 + g_c, 501.0], speed=[20.0, 20.0, 20.0],
                               v_exp=[30.0, 20.0, 20.0], n_lanes=2)  # fmt: skip
    assert MobilPolicy(p=0.0, b_safe=1e6).act(alongside)[0] == SPEEDUP
    # the leftmost lane has no left: stuck in lane 1 of 2 with a free right lane goes right, never left
    leftmost = observation_of(lane=[1, 1], pos=[500.0, 504.0 + g_c], speed=[20.0, 20.0], v_exp=[30.0, 20.0],
                              n_lanes=2)  # fmt: skip
    assert MobilPolicy(p=0.0).act(leftmost)[0] == RIGHT


def test_leader_and_follower_do_not_change_together(observation_of: Layout) -> None:
    """Regression: vehicle 0 (at its v_exp) leaves to free vehicle 1, 73.5 m behind and bounded below its
    v_exp by Newell; vehicle 1 leaves to escape vehicle 0. Each decision alone is MOBIL's, but taken
    together both land in the other lane in the same order, and did it again every 4 s (ping-pong)."""
    obs = observation_of(lane=[1, 1], pos=[600.0, 522.5], speed=[25.83, 24.37], v_exp=[25.83, 24.37], n_lanes=2)
    policy = MobilPolicy(p=1.0)
    assert policy.decide(obs).tolist() == [RIGHT, RIGHT]  # each alone would change
    assert policy.act(obs).tolist() == [RIGHT, SPEEDUP]  # the front one goes; the follower is judged again
    # next step: vehicle 0 is changing (in both lanes), vehicle 1 has nothing to gain
    during = observation_of(lane=[1, 1], pos=[602.6, 524.9], speed=[25.83, 24.37], v_exp=[25.83, 24.37],
                            n_lanes=2, other_lane=[0, -1])  # fmt: skip
    assert policy.act(during).tolist() == [SPEEDUP, SPEEDUP]
    # once the change is over, neither changes back
    after = observation_of(lane=[0, 1], pos=[700.0, 622.5], speed=[25.83, 24.37], v_exp=[25.83, 24.37], n_lanes=2)
    assert policy.act(after).tolist() == [SPEEDUP, SPEEDUP]


def test_polite_leader_goes_first(observation_of: Layout) -> None:
    # cut_in_layout at p = 0.5: the leader (at its v_exp) makes way for vehicle 0 (d_o = 0.5 * 4 > 0.1),
    # vehicle 0 wants to overtake it; only the leader goes, vehicle 0 is then free in its own lane
    obs = cut_in_layout(observation_of)
    policy = MobilPolicy(p=0.5)
    assert policy.decide(obs).tolist() == [LEFT, LEFT, SPEEDUP]
    assert policy.act(obs).tolist() == [SPEEDUP, LEFT, SPEEDUP]
    assert MobilPolicy(p=0.0).act(obs).tolist() == [LEFT, SPEEDUP, SPEEDUP]  # the selfish leader stays


def test_changes_into_one_lane_from_both_sides(observation_of: Layout) -> None:
    """Vehicles 0 (lane 0) and 2 (lane 2), each stuck behind a leader, both want the empty middle lane."""
    g = gap_for_speed(20.0, 30.0)

    def layout(x2: float) -> Observation:
        return observation_of(lane=[0, 0, 2, 2], pos=[500.0, 504.0 + g, x2, x2 + 4.0 + g],
                              speed=[20.0] * 4, v_exp=[30.0, 20.0, 30.0, 20.0], n_lanes=3)  # fmt: skip

    policy = MobilPolicy(p=0.0)
    near = layout(480.0)  # vehicle 2 would enter just behind vehicle 0: it waits a step
    assert policy.decide(near).tolist() == [LEFT, SPEEDUP, RIGHT, SPEEDUP]
    assert policy.act(near).tolist() == [LEFT, SPEEDUP, SPEEDUP, SPEEDUP]
    # with a vehicle in the middle lane between them, they do not meet there: both go
    apart = observation_of(lane=[0, 0, 2, 2, 1], pos=[500.0, 504.0 + g, 300.0, 304.0 + g, 400.0],
                           speed=[20.0] * 5, v_exp=[30.0, 20.0, 30.0, 20.0, 20.0], n_lanes=3)  # fmt: skip
    assert policy.act(apart).tolist() == [LEFT, SPEEDUP, RIGHT, SPEEDUP, SPEEDUP]


def test_batch_equals_one_layout_at_a_time(observation_of: Layout) -> None:
    a = cut_in_layout(observation_of)
    g_c = gap_for_speed(15.0, 30.0)
    # both layouts on one road, 1 km apart
    both = observation_of(
        lane=[0, 0, 1, 0, 0, 1],
        pos=[*a.pos.tolist(), 1500.0, 1504.0 + g_c, 1471.0],
        speed=[*a.speed.tolist(), 15.0, 15.0, 30.0],
        v_exp=[*a.v_exp.tolist(), 30.0, 15.0, 30.0],
        n_lanes=2,
    )
    second = b_safe_layout(observation_of, follower_gap_m=25.0)
    for p in (0.0, 1.0):
        policy = MobilPolicy(p=p)
        joint = policy.act(both)
        assert joint.dtype == np.int64
        assert joint.tolist() == [*policy.act(a).tolist(), *policy.act(second).tolist()]


def test_empty_observation(observation_of: Layout) -> None:
    empty = observation_of(lane=[], pos=[], speed=[], v_exp=[], n_lanes=3)
    actions = MobilPolicy().act(empty)
    assert actions.shape == (0,) and actions.dtype == np.int64


@pytest.mark.parametrize(
    ("spec", "values"),
    [
        ("mobil", (0.5, 0.1, 4.0, 0.0)),
        ("mobil:p=0", (0.0, 0.1, 4.0, 0.0)),
        ("mobil:p=1,threshold=0.2,b_safe=3,bias=0.05", (1.0, 0.2, 3.0, 0.05)),
        ("mobil:b_safe=6,p=0.25", (0.25, 0.1, 6.0, 0.0)),
        ("mobil:bias=-0.1", (0.5, 0.1, 4.0, -0.1)),
    ],
)
def test_from_spec(spec: str, values: tuple[float, float, float, float]) -> None:
    policy = MobilPolicy.from_spec(spec)
    assert (policy.p, policy.threshold, policy.b_safe, policy.bias) == pytest.approx(values)
    assert policy.name.startswith("mobil:p=")
    assert MobilPolicy.from_spec(policy.name).name == policy.name  # the name is a spec for the same policy


@pytest.mark.parametrize(
    "spec",
    ["mobile", "mobil:", "mobil:p", "mobil:=1", "mobil:q=1", "mobil:p=abc", "mobil:p=-1", "mobil:p=nan",
     "mobil:p=inf", "mobil:p=1,p=2", "mobil:b_safe=0", "mobil:threshold=-0.1", "mobil:p=1,", "greedy",
     "mobil:b_safe=6, p=0.25"],
)  # fmt: skip
def test_bad_spec_is_a_one_line_policy_spec_error(spec: str) -> None:
    with pytest.raises(PolicySpecError) as err:
        MobilPolicy.from_spec(spec)
    assert "\n" not in str(err.value) and str(err.value)


@pytest.mark.sumo
@pytest.mark.parametrize("lanes", [2, 5])
@pytest.mark.parametrize("p", [0.0, 0.5, 1.0])
def test_mobil_near_capacity_in_sumo(tmp_path: Path, lanes: int, p: float) -> None:
    from coopsumo.agents.rollout import run

    steps = 2000  # the road fills in ~1500 (2 lanes: 53-109 lane changes by then, p 0 to 1)
    cfg = SimConfig(
        road=RoadConfig(lanes=lanes),
        demand=DemandConfig(t_up_s=3600.0 / (lanes * 1800.0)),
        steps=steps,
        seed=1,
        policy=f"mobil:p={p:g}",
        sumo_collision_check=True,
    )
    summary = run(cfg, MobilPolicy.from_spec(cfg.policy, cfg.control), tmp_path, progress=False)
    assert summary["collisions"] == 0 and summary["sumo_collisions"] == 0
    assert summary["teleports"] == 0
    assert summary["lane_changes"] > 10


@pytest.mark.sumo
@pytest.mark.parametrize("lanes", [2, 5])
def test_sumo_models_near_capacity_in_sumo(tmp_path: Path, lanes: int) -> None:
    """The `sumo` baseline (Krauss + LC2013, no Newell controller) is safe too, by both collision counts."""
    from coopsumo.agents.policies import make_policy
    from coopsumo.agents.rollout import run

    cfg = SimConfig(
        road=RoadConfig(lanes=lanes),
        demand=DemandConfig(t_up_s=3600.0 / (lanes * 1800.0)),
        steps=2000,  # the road fills in ~1500
        seed=1,
        policy="sumo:lcCooperative=0.5",
        sumo_collision_check=True,
    )
    summary = run(cfg, make_policy(cfg.policy, np.random.default_rng(0)), tmp_path, progress=False)
    assert summary["collisions"] == 0 and summary["sumo_collisions"] == 0
    assert summary["teleports"] == 0
    assert summary["lane_changes"] > 10
    assert summary["arrived"] > 0
