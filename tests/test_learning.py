"""The learning design: feasible-action mask, decision interval, double-DQN target, presets, learner flags."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import assert_refused_in_one_line, main_here
from torch import nn

from coopsumo.agents.decisions import ActionHold, follow_up, is_decision_step, offered
from coopsumo.agents.dqn import Learner, ReplayBatch, epsilon_at, epsilon_greedy, td_targets
from coopsumo.config import SimConfig, TrainConfig, results_view, to_dict
from coopsumo.dqn_config import DQN_PRESETS, PAPER_DQN, DQNConfig, dqn_config_from_dict
from coopsumo.errors import ConfigError
from coopsumo.sim import physics
from coopsumo.sim.observation import Observation
from coopsumo.sim.physics import LEFT, NONE, RIGHT, SPEEDUP

ROOT = Path(__file__).resolve().parent.parent
Layout = Callable[..., Observation]


# --- the mask on hand-made layouts --------------------------------------------------------------


def test_mask_road_edges(observation_of: Layout) -> None:
    obs = observation_of(lane=[0, 2, 1], pos=[100.0, 300.0, 500.0], speed=[20.0] * 3, v_exp=[25.0] * 3)
    assert obs.feasible.tolist() == [
        [True, False, True, True],  # rightmost lane: no right
        [False, True, True, True],  # leftmost lane of 3: no left
        [True, True, True, True],  # middle lane, empty road: both
    ]


def test_mask_lane_change_under_way(observation_of: Layout) -> None:
    obs = observation_of(lane=[1], pos=[100.0], speed=[20.0], v_exp=[25.0], other_lane=[2])
    assert obs.feasible[0].tolist() == [False, False, True, True]


def test_mask_unsafe_and_safe_gaps(observation_of: Layout) -> None:
    cfg = physics.ControlConfig()
    v = 20.0
    need = cfg.lc_min_gap_m + cfg.lc_headway_s * v  # 12 m ahead for the changer at 20 m/s
    # vehicle 0 in lane 0; a leader in lane 1 just too close (gap need - 0.5), one in lane 1 far enough for vehicle 2
    obs = observation_of(lane=[0, 1, 0], pos=[100.0, 100.0 + 4.0 + need - 0.5, 400.0],
                         speed=[v, v, v], v_exp=[25.0] * 3)  # fmt: skip
    assert not obs.feasible[0, LEFT]
    assert obs.feasible[2, LEFT]  # nobody near in lane 1 around x = 400
    obs = observation_of(lane=[0, 1], pos=[100.0, 100.0 + 4.0 + need + 0.5], speed=[v, v], v_exp=[25.0] * 2)
    assert obs.feasible[0, LEFT]
    # a follower in the target lane that is too close behind
    obs = observation_of(lane=[0, 1], pos=[100.0, 100.0 - 4.0 - need + 0.5], speed=[v, v], v_exp=[25.0] * 2)
    assert not obs.feasible[0, LEFT]


def test_mask_is_what_the_controller_accepts(observation_of: Layout) -> None:
    """For every vehicle and side: feasible == target exists & not busy & lane_change_safe (the world's rule)."""
    rng = np.random.default_rng(0)
    cfg = physics.ControlConfig()
    n = 60
    lane = rng.integers(0, 4, n)
    pos = np.sort(rng.uniform(0, 600, n))
    speed = rng.uniform(0, 30, n)
    other = np.where(rng.random(n) < 0.2, np.clip(lane + rng.choice([-1, 1], n), 0, 3), -1)
    obs = observation_of(lane=lane.tolist(), pos=pos.tolist(), speed=speed.tolist(), v_exp=[30.0] * n,
                         n_lanes=4, other_lane=other.tolist())  # fmt: skip
    for action, side in ((LEFT, 0), (RIGHT, 2)):
        safe = physics.lane_change_safe(obs.around.lead_gap[:, side], obs.around.follow_gap[:, side], obs.speed,
                                        obs.around.follow_speed[:, side], cfg)  # fmt: skip
        expected = obs.around.exists[:, side] & ~obs.busy & safe
        np.testing.assert_array_equal(obs.feasible[:, action], expected)
    assert obs.feasible[:, [SPEEDUP, NONE]].all()
    assert 0 < obs.feasible[:, LEFT].sum() < n  # the layout has both cases


# --- exploration and targets with the mask ------------------------------------------------------


def test_masked_epsilon_greedy_never_picks_an_infeasible_action() -> None:
    rng = np.random.default_rng(0)
    q = np.tile([9.0, 8.0, 0.0, 0.0], (20_000, 1))  # left and right look best
    mask = np.ones((20_000, 4), bool)
    mask[:, LEFT] = False
    mask[::2, RIGHT] = False
    for eps in (0.0, 0.3, 1.0):
        actions = epsilon_greedy(q, eps, rng, mask)
        assert mask[np.arange(len(actions)), actions].all()
    actions = epsilon_greedy(q, 1.0, rng, mask)  # uniform over the feasible ones
    odd = actions[1::2]
    shares = np.bincount(odd, minlength=4)[1:] / len(odd)
    assert np.all(np.abs(shares - 1 / 3) < 0.02)
    greedy = epsilon_greedy(q, 0.0, rng, mask)
    assert (greedy[1::2] == RIGHT).all() and (greedy[::2] == SPEEDUP).all()


def test_epsilon_schedule() -> None:
    cfg = dataclasses.replace(DQNConfig(), epsilon_start=1.0, epsilon_end=0.1, epsilon_decay_steps=100)
    assert epsilon_at(0, cfg) == 1.0
    assert epsilon_at(50, cfg) == pytest.approx(0.55)
    assert epsilon_at(100, cfg) == pytest.approx(0.1) and epsilon_at(10_000, cfg) == pytest.approx(0.1)
    assert epsilon_at(5_000, PAPER_DQN) == pytest.approx(0.1)


class FixedQ(nn.Module):
    """A stand-in network returning given Q-values for each row (keyed by speed_err[:, 0])."""

    def __init__(self, table: dict[int, list[float]]):
        super().__init__()
        self.table = table

    def forward(self, grids: torch.Tensor, speed_err: torch.Tensor) -> torch.Tensor:
        return torch.tensor([self.table[int(k)] for k in speed_err[:, 0].tolist()], dtype=torch.float32)


def _batch(next_mask: list[list[bool]], dones: list[float]) -> ReplayBatch:
    n = len(dones)
    return ReplayBatch(
        grids=torch.zeros(n, 3, 3, 20), features=torch.zeros(n, 3), actions=torch.zeros(n, dtype=torch.int64),
        rewards=torch.tensor([1.0] * n), next_grids=torch.zeros(n, 3, 3, 20),
        next_features=torch.tensor([[float(i)] * 3 for i in range(n)]),
        dones=torch.tensor(dones), next_mask=torch.tensor(next_mask),
    )  # fmt: skip


def test_td_target_plain_double_and_masked_max() -> None:
    online = FixedQ({0: [5.0, 0.0, 1.0, 2.0], 1: [0.0, 0.0, 3.0, 1.0]})
    target = FixedQ({0: [1.0, 9.0, 4.0, 2.0], 1: [7.0, 0.0, 2.0, 6.0]})
    all_ok = [[True] * 4, [True] * 4]
    gamma = 0.5
    # plain DQN: max of the target network
    plain = td_targets(online, target, _batch(all_ok, [0.0, 0.0]), gamma, double=False)  # type: ignore[arg-type]
    assert plain.tolist() == pytest.approx([1 + 0.5 * 9.0, 1 + 0.5 * 7.0])
    # double DQN: the online argmax (left for row 0, speedup for row 1), valued by the target
    double = td_targets(online, target, _batch(all_ok, [0.0, 0.0]), gamma, double=True)  # type: ignore[arg-type]
    assert double.tolist() == pytest.approx([1 + 0.5 * 1.0, 1 + 0.5 * 2.0])
    # masked: left and right infeasible in both next states
    masked = [[False, False, True, True]] * 2
    m_plain = td_targets(online, target, _batch(masked, [0.0, 0.0]), gamma, double=False)  # type: ignore[arg-type]
    assert m_plain.tolist() == pytest.approx([1 + 0.5 * 4.0, 1 + 0.5 * 6.0])
    m_double = td_targets(online, target, _batch(masked, [0.0, 0.0]), gamma, double=True)  # type: ignore[arg-type]
    assert m_double.tolist() == pytest.approx([1 + 0.5 * 2.0, 1 + 0.5 * 2.0])  # online picks none, then speedup
    # a terminal transition does not bootstrap
    done = td_targets(online, target, _batch(all_ok, [1.0, 0.0]), gamma, double=True)  # type: ignore[arg-type]
    assert done.tolist()[0] == pytest.approx(1.0)


# --- decision interval --------------------------------------------------------------------------


def test_decision_is_held_for_exactly_k_steps() -> None:
    k = 4
    hold = ActionHold(k)
    nums = np.array([0, 1, 2, 3])
    decided = np.array([LEFT, RIGHT, SPEEDUP, NONE])
    seen = []
    for step in range(2 * k):
        d = decided if hold.is_decision_step(step) else None
        if step == k:
            d = np.array([NONE, NONE, LEFT, SPEEDUP])
        seen.append(hold.actions(nums, d))
    seen_a = np.array(seen)
    np.testing.assert_array_equal(seen_a[0], decided)
    np.testing.assert_array_equal(seen_a[1:k], np.tile([SPEEDUP, SPEEDUP, SPEEDUP, NONE], (k - 1, 1)))
    np.testing.assert_array_equal(seen_a[k], [NONE, NONE, LEFT, SPEEDUP])
    np.testing.assert_array_equal(seen_a[k + 1 :], np.tile([NONE, NONE, SPEEDUP, SPEEDUP], (k - 1, 1)))
    # exactly one lane-change request per decision
    assert ((seen_a == LEFT) | (seen_a == RIGHT)).sum(axis=0).tolist() == [1, 1, 1, 0]
    assert [is_decision_step(s, k) for s in range(6)] == [True, False, False, False, True, False]
    assert follow_up(np.array([LEFT, RIGHT, SPEEDUP, NONE])).tolist() == [SPEEDUP, SPEEDUP, SPEEDUP, NONE]


def test_a_vehicle_that_has_not_decided_speeds_up() -> None:
    hold = ActionHold(10)
    hold.actions(np.array([0]), np.array([NONE]))
    np.testing.assert_array_equal(hold.actions(np.array([0, 5000]), None), [NONE, SPEEDUP])


def test_none_is_withheld_below_the_restart_speed(observation_of: Layout) -> None:
    obs = observation_of(lane=[0, 1, 2], pos=[100.0, 300.0, 500.0], speed=[0.0, 0.99, 1.0], v_exp=[25.0] * 3)
    assert offered(obs.feasible, obs.speed, False, 0.0) is None  # the paper: every action at every speed
    plain = offered(obs.feasible, obs.speed, False, 1.0)
    assert plain is not None and plain.tolist() == [[True, True, True, False], [True, True, True, False],
                                                    [True, True, True, True]]  # fmt: skip
    masked = offered(obs.feasible, obs.speed, True, 1.0)
    assert masked is not None
    np.testing.assert_array_equal(masked[:, :3], obs.feasible[:, :3])  # lane changes as the controller says
    assert masked[:, NONE].tolist() == [False, False, True] and masked[:, SPEEDUP].all()
    np.testing.assert_array_equal(offered(obs.feasible, obs.speed, True, 0.0), obs.feasible)


def _net_preferring(action: int, second: int) -> torch.nn.Module:
    """A plain Q-network whose Q-values are 1 for `action`, 0.5 for `second`, 0 else, whatever it sees."""
    from coopsumo.agents.dqn import QNetwork

    net = QNetwork(30.0)
    with torch.no_grad():
        net.out.weight.zero_()
        net.out.bias.zero_()
        net.out.bias[action] = 1.0
        net.out.bias[second] = 0.5
    return net


def test_a_standing_vehicle_of_a_model_that_prefers_none_speeds_up(observation_of: Layout) -> None:
    from coopsumo.agents.dqn_policy import DQNPolicy

    obs = observation_of(lane=[0, 1], pos=[100.0, 300.0], speed=[0.0, 20.0], v_exp=[25.0] * 2)
    literal = DQNPolicy(_net_preferring(NONE, SPEEDUP), action_mask=True, restart_below_mps=0.0)  # type: ignore[arg-type]
    assert literal.act(obs).tolist() == [NONE, NONE]
    guarded = DQNPolicy(_net_preferring(NONE, SPEEDUP), action_mask=True, restart_below_mps=1.0)  # type: ignore[arg-type]
    assert guarded.act(obs).tolist() == [SPEEDUP, NONE]



def test_a_model_driven_with_restart_withholds_none_below_that_speed(tmp_path: Path, observation_of: Layout) -> None:
    """dqn:PATH,restart=R replaces the model's own threshold: R 50 (above every expected speed) never chooses
    'none', so the model chooses lanes only; the threshold is recorded beside the other driven settings."""
    from coopsumo.agents.dqn_policy import DQNPolicy
    from coopsumo.agents.model_file import save_model

    path = tmp_path / "m.pt"
    learner = dataclasses.replace(DQNConfig(), dueling=False, observation="paper")  # what _net_preferring is
    save_model(path, _net_preferring(NONE, SPEEDUP), {"config": to_dict(TrainConfig(dqn=learner))})  # type: ignore[arg-type]
    obs = observation_of(lane=[0, 1, 2], pos=[100.0, 300.0, 500.0], speed=[0.5, 4.0, 20.0], v_exp=[25.0] * 3)
    assert DQNPolicy.from_spec(f"dqn:{path}").act(obs).tolist() == [SPEEDUP, NONE, NONE]  # the model's own: 1 m/s
    assert DQNPolicy.from_spec(f"dqn:{path},restart=5").act(obs).tolist() == [SPEEDUP, SPEEDUP, NONE]
    lanes_only = DQNPolicy.from_spec(f"dqn:{path},restart=50")
    assert lanes_only.act(obs).tolist() == [SPEEDUP] * 3
    assert (lanes_only.trained_on or {})["driven_restart_below_mps"] == 50.0


def test_a_lane_change_must_beat_staying_by_the_change_margin(observation_of: Layout) -> None:
    from coopsumo.agents.decisions import with_change_margin
    from coopsumo.agents.dqn_policy import DQNPolicy

    q = np.array([[1.0, 0.2, 0.5, 0.0], [3.0, 0.0, 0.5, 0.0]])
    assert with_change_margin(q, 0.0) is q
    np.testing.assert_array_equal(with_change_margin(q, 1.0), [[0.0, -0.8, 0.5, 0.0], [2.0, -1.0, 0.5, 0.0]])
    # on a free three-lane road (both changes feasible), Q(left) = 1 beats Q(speed-up) = 0.5 by 0.5
    obs = observation_of(lane=[1], pos=[300.0], speed=[20.0], v_exp=[25.0])
    assert obs.feasible[0].all()
    plain = DQNPolicy(_net_preferring(LEFT, SPEEDUP), action_mask=True)  # type: ignore[arg-type]
    assert plain.act(obs).tolist() == [LEFT]
    below = DQNPolicy(_net_preferring(LEFT, SPEEDUP), action_mask=True, change_margin=0.6)  # type: ignore[arg-type]
    assert below.act(obs).tolist() == [SPEEDUP]
    above = DQNPolicy(_net_preferring(LEFT, SPEEDUP), action_mask=True, change_margin=0.4)  # type: ignore[arg-type]
    assert above.act(obs).tolist() == [LEFT]
    # training ignores the margin: the learner's own choice is the plain argmax
    learner = Learner(dataclasses.replace(DQNConfig(), change_margin=0.6, epsilon_start=0.0, epsilon_end=0.0), 0)
    learner.online = _net_preferring(LEFT, SPEEDUP)  # type: ignore[assignment]
    assert learner.act(obs.grids, obs.speed_err, explore=True).tolist() == [LEFT]


def test_no_return_withholds_only_the_change_back_for_its_seconds(observation_of: Layout) -> None:
    from coopsumo.agents.decisions import no_return
    from coopsumo.agents.dqn_policy import DQNPolicy

    mask = np.ones((4, 4), bool)
    since, last = np.array([1.0, 1.0, 5.0, 1.0]), np.array([LEFT, RIGHT, LEFT, -1])
    expected = [[True, False], [False, True], [True, True], [True, True]]  # back withheld, onward offered
    np.testing.assert_array_equal(no_return(mask, since, last, 3.0)[:, [LEFT, RIGHT]], expected)
    assert no_return(mask, since, last, 0.0) is mask

    def drive(noreturn: float, lane_before: int, lane_after: int) -> list[int]:
        """A model that prefers left, then right: it changes left from lane_before, then decides 4 more rounds."""
        policy = DQNPolicy(_net_preferring(LEFT, RIGHT), decision_interval=10, action_mask=True)  # type: ignore[arg-type]
        policy.no_return_s = noreturn
        first = observation_of(lane=[lane_before], pos=[300.0], speed=[20.0], v_exp=[25.0])
        assert policy.act(first).tolist() == [LEFT]
        changing = observation_of(lane=[lane_after], pos=[300.0], speed=[20.0], v_exp=[25.0],
                                  other_lane=[lane_before])  # fmt: skip
        assert policy.act(changing)[0] not in (LEFT, RIGHT)  # the controller's mask: no change during a change
        after = observation_of(lane=[lane_after], pos=[300.0], speed=[20.0], v_exp=[25.0])
        return [int(policy.act(after)[0]) for _ in range(4)]

    # in the leftmost lane only the change back (right) is left: withheld 1 and 2 s after the change, not at 3 s
    assert drive(0.0, 1, 2) == [RIGHT] * 4
    assert drive(3.0, 1, 2) == [SPEEDUP, SPEEDUP, RIGHT, RIGHT]  # Q ties at 0: the first of speed-up and none
    assert drive(3.0, 0, 1) == [LEFT] * 4  # onward is never withheld


def test_no_return_is_a_learner_setting_a_model_file_carries(tmp_path: Path) -> None:
    """DQNConfig.no_return_s (train --no-return S): the saved model drives with it, dqn:PATH,noreturn=S replaces
    it, and a training differing only there trains the same weights (only model selection drives with it)."""
    from coopsumo.agents.dqn import QNetwork
    from coopsumo.agents.dqn_policy import DQNPolicy
    from coopsumo.agents.model_file import save_model
    from coopsumo.agents.selection import trained_part
    from coopsumo.config import TrainConfig, results_view, to_dict
    from coopsumo.dqn_config import dqn_config_from_dict

    dq = dataclasses.replace(DQNConfig(), no_return_s=5.0)
    dq.validate()
    net = QNetwork(30.0, dueling=dq.dueling, observation=dq.observation)
    save_model(tmp_path / "model.pt", net, {"config": to_dict(TrainConfig(dqn=dq))})
    policy = DQNPolicy.from_file(str(tmp_path / "model.pt"))
    assert policy.no_return_s == 5.0 and policy.trained_on is not None and policy.trained_on["no_return_s"] == 5.0
    assert DQNPolicy.from_spec(f"dqn:{tmp_path / 'model.pt'},noreturn=0").no_return_s == 0.0
    assert trained_part(to_dict(dq)) == trained_part(to_dict(DQNConfig()))
    old = {k: v for k, v in json.loads(json.dumps(to_dict(DQNConfig()))).items() if k != "no_return_s"}
    assert dqn_config_from_dict(old).no_return_s == 0.0  # a model saved before the setting: none
    before = dataclasses.replace(DQNConfig(), no_return_s=0.0)  # stored models keep theirs: none, not today's 10 s
    assert results_view(old) == results_view(json.loads(json.dumps(to_dict(before))))
    assert results_view(old) != results_view(json.loads(json.dumps(to_dict(DQNConfig()))))
    with pytest.raises(ConfigError, match="no_return_s"):
        dataclasses.replace(DQNConfig(), no_return_s=-1.0).validate()


def test_no_lane_change_is_chosen_in_a_queue(observation_of: Layout) -> None:
    from coopsumo.agents.decisions import no_change_in_queue
    from coopsumo.agents.dqn_policy import DQNPolicy

    mask = np.ones((3, 4), bool)
    speed = np.array([1.0, 4.99, 5.0])
    expected = [[False, False], [False, False], [True, True]]
    np.testing.assert_array_equal(no_change_in_queue(mask, speed, 5.0)[:, [LEFT, RIGHT]], expected)
    assert no_change_in_queue(mask, speed, 0.0) is mask
    assert no_change_in_queue(mask, speed, 5.0)[:, [SPEEDUP, NONE]].all()  # staying is always offered
    slow = observation_of(lane=[1], pos=[300.0], speed=[3.0], v_exp=[25.0])
    fast = observation_of(lane=[1], pos=[300.0], speed=[20.0], v_exp=[25.0])
    for below, in_queue, moving in ((0.0, LEFT, LEFT), (5.0, SPEEDUP, LEFT)):
        policy = DQNPolicy(_net_preferring(LEFT, SPEEDUP), decision_interval=10, action_mask=True)  # type: ignore[arg-type]
        policy.queue_below_mps = below
        assert policy.act(slow).tolist() == [in_queue], below
        policy = DQNPolicy(_net_preferring(LEFT, SPEEDUP), decision_interval=10, action_mask=True)  # type: ignore[arg-type]
        policy.queue_below_mps = below
        assert policy.act(fast).tolist() == [moving], below

def test_a_saved_model_drives_with_its_own_queue_rule_and_a_spec_replaces_it(tmp_path: Path,
                                                                               observation_of: Layout) -> None:
    """A learner's queue rule (DQNConfig.queue_below_mps, 5 in the default) drives a model from its file; the paper
    preset and a model saved before the field have none; dqn:PATH,queue=V replaces it."""
    from coopsumo.agents.dqn_policy import DQNPolicy
    from coopsumo.agents.model_file import save_model

    slow = observation_of(lane=[1], pos=[300.0], speed=[3.0], v_exp=[25.0])
    queue5 = dataclasses.replace(DQNConfig(), queue_below_mps=5.0)
    for name, learner, below in (("queue5", queue5, 5.0), ("default", DQNConfig(), 5.0), ("paper", PAPER_DQN, 0.0)):
        path = tmp_path / f"{name}.pt"
        learner = dataclasses.replace(learner, dueling=False, observation="paper", action_mask=True, change_margin=0.0)
        save_model(path, _net_preferring(LEFT, SPEEDUP), {"config": to_dict(TrainConfig(dqn=learner))})  # type: ignore[arg-type]
        policy = DQNPolicy.from_spec(f"dqn:{path}")
        assert policy.queue_below_mps == below and (policy.trained_on or {})["queue_below_mps"] == below
        assert policy.act(slow).tolist() == [SPEEDUP if below else LEFT], name
        assert DQNPolicy.from_spec(f"dqn:{path},queue=2").act(slow).tolist() == [LEFT]  # 3 m/s is not below 2
    from coopsumo.agents.selection import snapshot_policy

    assert snapshot_policy(str(tmp_path / "queue5.pt")).queue_below_mps == 0.0  # model selection ignores it
    stored = to_dict(queue5)
    del stored["queue_below_mps"]
    assert dqn_config_from_dict(stored).queue_below_mps == 0.0


@pytest.mark.parametrize("bad", ["-1", "nan", "abc"])
def test_a_bad_queue_flag_is_a_one_line_usage_error(tmp_path: Path, bad: str) -> None:
    out = tmp_path / "run"
    res = subprocess.run([sys.executable, "-m", "coopsumo.train", "--steps", "50", "--out", str(out), "--queue-below",
                          bad], capture_output=True, text=True, cwd=ROOT, check=False)  # fmt: skip
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "--queue-below" in lines[0] and "Traceback" not in res.stderr
    assert not out.exists()


@pytest.mark.parametrize("bad", [-0.1, float("nan"), float("inf")])
def test_a_bad_change_margin_is_refused(bad: float) -> None:
    with pytest.raises(ConfigError, match="change_margin"):
        dataclasses.replace(DQNConfig(), change_margin=bad).validate()


def test_a_learner_stored_before_the_margin_and_the_v2x_state_loads_as_it_was() -> None:
    stored = to_dict(DQNConfig())
    del stored["change_margin"], stored["observation"]
    loaded = dqn_config_from_dict(stored)
    assert loaded.change_margin == 0.0 and loaded.observation == "paper"
    assert results_view(stored) == results_view(to_dict(loaded))  # so stored runs still match


# --- presets and configuration ------------------------------------------------------------------


def test_paper_preset_is_literal() -> None:
    p = DQN_PRESETS["paper"]
    assert (p.decision_interval_steps, p.action_mask, p.double_dqn, p.loss) == (1, False, False, "mse")
    assert (p.optimizer, p.lr, p.gamma, p.replay_size) == ("sgd", 0.01, 0.9, 2000)
    assert (p.epsilon_start, p.epsilon_end, p.epsilon_decay_steps) == (0.1, 0.1, 0)
    assert (p.target_sync_steps, p.batch_size, p.learn_every, p.updates_per_learn) == (500, 64, 4, 1)
    assert p.restart_below_mps == 0.0 and DQNConfig().restart_below_mps == 1.0  # paper: "none" keeps a zero speed
    assert DQN_PRESETS["default"] == DQNConfig() and DQNConfig().preset == "default"


def test_train_flags_resolve_the_preset_and_override_fields() -> None:
    from coopsumo.agents.train_cli import build_parser, config_from_args

    cfg = config_from_args(build_parser().parse_args(["--preset", "paper"]))
    assert cfg.dqn == PAPER_DQN
    cfg = config_from_args(build_parser().parse_args(["--preset", "paper", "--decision-interval", "5",
                                                      "--action-mask", "--loss", "huber"]))  # fmt: skip
    assert cfg.dqn == dataclasses.replace(PAPER_DQN, decision_interval_steps=5, action_mask=True, loss="huber")
    cfg = config_from_args(build_parser().parse_args(["--no-double-dqn"]))
    assert cfg.dqn == dataclasses.replace(DQNConfig(), double_dqn=False)


def test_legacy_learner_dict_is_the_paper_setup() -> None:
    from coopsumo.dqn_config import dqn_config_from_dict

    old = {"lr": 0.01, "gamma": 0.9, "replay_size": 2000, "batch_size": 64, "target_sync_steps": 500,
           "greedy_prob": 0.9, "learn_every_steps": 4, "learn_start_steps": 200, "optimizer": "sgd",
           "grad_clip_norm": 10.0, "speed_scale_mps": 110 / 3.6, "store_per_step": 16,
           "exit_transition": "drop"}  # fmt: skip
    cfg = dqn_config_from_dict(old)
    assert cfg.decision_interval_steps == 1 and not cfg.action_mask
    assert cfg.epsilon_start == pytest.approx(0.1) and cfg.learn_every == 4
    written_before_the_rule = {k: v for k, v in dataclasses.asdict(DQNConfig()).items() if k != "restart_below_mps"}
    assert dqn_config_from_dict(written_before_the_rule).restart_below_mps == 0.0  # such models drove without it
    with pytest.raises(ConfigError, match="warp_drive"):
        dqn_config_from_dict({**dataclasses.asdict(DQNConfig()), "warp_drive": 1})


@pytest.mark.parametrize(
    "args, fragment",
    [
        (["--decision-interval", "0"], "decision-interval"),
        (["--decision-interval", "-3"], "decision-interval"),
        (["--replay-size", "-1"], "replay-size"),
        (["--updates-per-decision", "0"], "updates-per-decision"),
        (["--store-per-decision", "0"], "store-per-decision"),
        (["--target-sync", "0"], "target-sync"),
        (["--epsilon-start", "1.5"], "epsilon-start"),
        (["--epsilon-end", "nan"], "epsilon-end"),
        (["--epsilon-decay-steps", "-5"], "epsilon-decay-steps"),
        (["--lr", "inf"], "lr"),
        (["--gamma", "-0.1"], "gamma"),
        (["--restart-below", "-1"], "restart-below"),
        (["--preset", "fastest"], "preset"),
    ],
)
def test_bad_learner_flags_are_one_line_usage_errors(
    tmp_path: Path, args: list[str], fragment: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """python -m coopsumo.train's main, in this process (the one-line refusal of a command run as a process:
    tests/test_bad_inputs.py)."""
    from coopsumo import train

    out = tmp_path / "run"
    code, _, err = main_here(train.main, ["--steps", "50", "--out", str(out), *args], capsys)
    assert_refused_in_one_line(code, err, out, fragment)


def test_train_config_validate_checks_the_learner() -> None:
    with pytest.raises(ConfigError, match="decision_interval_steps"):
        TrainConfig(sim=SimConfig(steps=10), dqn=dataclasses.replace(DQNConfig(), decision_interval_steps=0)).validate()


# --- in SUMO --------------------------------------------------------------------------------------


def _one_per_lane(obs: Observation, wanted: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Actions asking for the `wanted` changes, at most one vehicle per target lane (others speed up)."""
    actions = np.full(len(obs), SPEEDUP, np.int64)
    taken: set[int] = set()
    for i in rng.permutation(np.flatnonzero(wanted >= 0)):
        target = int(obs.lane[i] + (1 if wanted[i] == LEFT else -1))
        if target not in taken:
            taken.add(target)
            actions[i] = wanted[i]
    return actions


@pytest.mark.sumo
def test_in_sumo_masked_in_changes_are_accepted_and_masked_out_ones_refused(
    tmp_path: Path, make_sim_config: Callable[..., SimConfig]
) -> None:
    from coopsumo.sim.world import World

    cfg = make_sim_config(lanes=3, t_up_s=0.6, steps=1500, seed=4)
    rng = np.random.default_rng(0)
    asked_in = asked_out = 0
    with World(cfg, tmp_path, observe_grids=False) as world:
        for step in range(cfg.steps):
            obs = world.observe()
            pick_feasible = step % 2 == 0
            side = rng.choice([LEFT, RIGHT], len(obs))
            ok = obs.feasible[np.arange(len(obs)), side]
            wanted = np.where((ok == pick_feasible) & (rng.random(len(obs)) < 0.3), side, -1)
            actions = _one_per_lane(obs, wanted, rng)
            out = world.apply(actions)
            asking = (actions == LEFT) | (actions == RIGHT)
            if pick_feasible:
                asked_in += int(asking.sum())
                assert not out.rejected[asking].any(), f"a masked-in change was refused at step {step}"
                assert out.lane_change_started[asking].all()
            else:
                asked_out += int(asking.sum())
                assert out.rejected[asking].all() and not out.lane_change_started.any()
        summary = world.summary()
    assert asked_in > 100 and asked_out > 100
    assert summary["collisions"] == 0 and summary["teleports"] == 0


@pytest.mark.sumo
def test_in_sumo_a_held_lane_change_starts_exactly_one_change(
    tmp_path: Path, make_sim_config: Callable[..., SimConfig]
) -> None:
    from coopsumo.sim.world import World

    k = 10
    cfg = make_sim_config(lanes=3, t_up_s=1.0, steps=1200, seed=2)
    hold = ActionHold(k)
    started_at: list[int] = []
    requests_between = 0
    with World(cfg, tmp_path, observe_grids=False) as world:
        for step in range(cfg.steps):
            obs = world.observe()
            decide = hold.is_decision_step(step)
            want = np.where(obs.lane == 0, LEFT, RIGHT)  # always ask to change lane
            actions = hold.actions(obs.nums, want if decide else None)
            if not decide:
                requests_between += int(((actions == LEFT) | (actions == RIGHT)).sum())
            out = world.apply(actions)
            started_at += [step] * int(out.lane_change_started.sum())
        summary = world.summary()
    assert requests_between == 0
    assert started_at and all(s % k == 0 for s in started_at)
    assert summary["collisions"] == 0 and summary["teleports"] == 0


def test_in_sumo_a_model_that_prefers_none_stands_for_good_only_without_the_restart_rule(tmp_path: Path) -> None:
    """Behind the accident, vehicles of a 'none'-loving model stop; with the paper's rule they stay stopped
    after their leader leaves (SUMO teleports them), with the default rule they move on."""
    from coopsumo.agents.dqn_policy import DQNPolicy
    from coopsumo.agents.rollout import run
    from coopsumo.config import AccidentConfig

    cfg = SimConfig(accident=AccidentConfig(enabled=True, start_step=0, duration_steps=1500), steps=2500, seed=3,
                    policy="dqn", time_to_teleport_s=30.0)  # fmt: skip
    out = {}
    for restart in (0.0, 1.0):
        policy = DQNPolicy(_net_preferring(NONE, SPEEDUP), decision_interval=10, action_mask=True,  # type: ignore[arg-type]
                           restart_below_mps=restart)  # fmt: skip
        run_dir = tmp_path / f"restart{restart:g}"
        run_dir.mkdir()
        out[restart] = run(cfg, policy, run_dir, progress=False)
    assert out[0.0]["teleports"] > 0
    assert out[1.0]["teleports"] == 0 and out[1.0]["collisions"] == 0 and out[0.0]["collisions"] == 0


def test_dueling_head_and_its_model_file(tmp_path: Path) -> None:
    from coopsumo.agents.dqn import QNetwork
    from coopsumo.agents.model_file import load_model, save_model

    torch.manual_seed(0)
    net = QNetwork(30.0, dueling=True)
    grids, err = torch.rand(6, 3, 3, 20).round(), torch.randn(6, 3)
    q = net(grids, err)
    with torch.no_grad():
        x = net.fc2(net.fc1(torch.cat([net.conv2(net.conv1(grids).relu()).relu().flatten(1), err / 30.0], 1))
                    .relu()).relu()  # fmt: skip
        adv = net.out(x)
        expected = net.value(x) + adv - adv.mean(dim=1, keepdim=True)
    torch.testing.assert_close(q, expected)
    save_model(tmp_path / "m.pt", net, {})
    loaded, _ = load_model(tmp_path / "m.pt")
    assert loaded.dueling
    torch.testing.assert_close(loaded(grids, err), q)
    plain = QNetwork(30.0)
    assert not plain.dueling and not hasattr(plain, "value")
