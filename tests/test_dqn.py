"""Tests of coopsumo.agents.dqn: network shape, replay memory, exploration, update, learner, model files. No SUMO."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from coopsumo.agents.dqn import (
    GRID_SHAPE,
    N_ACTIONS,
    Learner,
    QNetwork,
    ReplayBatch,
    ReplayBuffer,
    dqn_update,
    epsilon_greedy,
    make_optimizer,
    sync_target,
)
from coopsumo.agents.model_file import ModelFileError, load_model, save_model
from coopsumo.dqn_config import PAPER_DQN, DQNConfig
from coopsumo.sim.observation import Observation, n_features

ROOT = Path(__file__).resolve().parent.parent

SMALL_CFG = dataclasses.replace(
    PAPER_DQN, replay_size=64, batch_size=8, learn_start_steps=0, target_sync_steps=3, learn_every=1
)


def random_transitions(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    """n random transitions as the numpy arrays ReplayBuffer.add_batch takes."""
    return {
        "grids": (rng.random((n, *GRID_SHAPE)) < 0.2).astype(np.float32),
        "features": rng.normal(-3.0, 3.0, (n, 3)).astype(np.float32),
        "actions": rng.integers(0, N_ACTIONS, n),
        "rewards": rng.normal(0.0, 1.0, n).astype(np.float32),
        "next_grids": (rng.random((n, *GRID_SHAPE)) < 0.2).astype(np.float32),
        "next_features": rng.normal(-3.0, 3.0, (n, 3)).astype(np.float32),
        "dones": (rng.random(n) < 0.1).astype(np.float32),
    }


def tagged_transitions(first: int, n: int) -> dict[str, np.ndarray]:
    """n transitions whose reward, action and grids all encode the id first, first+1, ..."""
    ids = np.arange(first, first + n)
    grids = np.zeros((n, *GRID_SHAPE), dtype=np.uint8)
    grids[:, 0, 0, 0] = ids % 2
    return {
        "grids": grids,
        "features": np.repeat(ids[:, None], 3, axis=1).astype(np.float32),
        "actions": ids % N_ACTIONS,
        "rewards": ids.astype(np.float32),
        "next_grids": grids,
        "next_features": np.repeat(-ids[:, None], 3, axis=1).astype(np.float32),
        "dones": np.zeros(n, dtype=np.float32),
    }


def weights(net: torch.nn.Module) -> list[torch.Tensor]:
    return [p.detach().clone() for p in net.parameters()]


def same(a: list[torch.Tensor], b: list[torch.Tensor]) -> bool:
    return all(torch.equal(x, y) for x, y in zip(a, b, strict=True))


def run_steps(learner: Learner, rng: np.random.Generator, steps: int) -> list[np.ndarray]:
    """Drive the learner like a simulation: act, observe 5 transitions, step. Returns the actions taken."""
    taken = []
    for _ in range(steps):
        t = random_transitions(rng, 5)
        actions = learner.act(t["grids"], t["features"], explore=True)
        taken.append(actions)
        t["actions"] = actions
        learner.observe(**t)
        learner.step()
    return taken


# --- network ---------------------------------------------------------------------------------


def test_weight_shapes_match_table_ii() -> None:
    net = QNetwork(speed_scale_mps=30.0)
    shapes = {name: tuple(p.shape) for name, p in net.named_parameters() if name.endswith("weight")}
    assert sorted(shapes.values()) == sorted([(16, 3, 2, 2), (32, 16, 2, 2), (500, 163), (100, 500), (4, 100)])


def test_forward_output_shape() -> None:
    net = QNetwork(speed_scale_mps=30.0)
    q = net(torch.zeros(7, *GRID_SHAPE), torch.zeros(7, 3))
    assert q.shape == (7, N_ACTIONS)


def test_a_dqn_policy_decides_on_one_torch_thread_as_the_studies_do() -> None:
    """A second thread can change the last bit of a Q-value (so a near-tie's choice): DQNPolicy takes one thread,
    the thread count of every study cell, so that `simulate` repeats a study's run exactly on any machine."""
    from coopsumo.agents.dqn_policy import DQNPolicy

    torch.manual_seed(3)
    net = QNetwork(speed_scale_mps=30.0).eval()
    grids, features = (torch.rand(7, *GRID_SHAPE) < 0.3).float(), torch.randn(7, net.n_features)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        with torch.no_grad():
            two = net(grids, features)
        DQNPolicy(net)
        assert torch.get_num_threads() == 1
        with torch.no_grad():
            one = net(grids, features)
        assert torch.allclose(one, two, rtol=1e-5, atol=1e-6)  # the same network, at most last-bit differences
    finally:
        torch.set_num_threads(before)


def test_speed_errors_are_divided_by_the_scale() -> None:
    torch.manual_seed(0)
    net_a = QNetwork(speed_scale_mps=10.0)
    net_b = QNetwork(speed_scale_mps=1.0)
    net_b.load_state_dict(net_a.state_dict())
    grids = torch.ones(2, *GRID_SHAPE)
    speed = torch.tensor([[-5.0, -3.0, 1.0], [2.0, 0.0, -8.0]])
    assert torch.allclose(net_a(grids, speed), net_b(grids, speed / 10.0))


# --- replay memory ---------------------------------------------------------------------------


def stored_rewards(buf: ReplayBuffer) -> set[int]:
    batch = buf.sample(2000, np.random.default_rng(0))
    # every field of a sampled row must belong to the same transition
    ids = batch.rewards.numpy().astype(int)
    assert np.array_equal(batch.actions.numpy(), ids % N_ACTIONS)
    assert np.array_equal(batch.features.numpy()[:, 2], ids)
    assert np.array_equal(batch.next_features.numpy()[:, 0], -ids)
    assert np.array_equal(batch.grids.numpy()[:, 0, 0, 0], ids % 2)
    return set(ids.tolist())


def test_replay_wraps_around_keeping_the_newest() -> None:
    buf = ReplayBuffer(capacity=5)
    buf.add_batch(**tagged_transitions(0, 3))
    assert len(buf) == 3
    assert stored_rewards(buf) == {0, 1, 2}
    buf.add_batch(**tagged_transitions(3, 4))
    assert len(buf) == 5
    assert stored_rewards(buf) == {2, 3, 4, 5, 6}


def test_replay_batch_larger_than_capacity_keeps_its_tail() -> None:
    buf = ReplayBuffer(capacity=5)
    buf.add_batch(**tagged_transitions(0, 2))
    buf.add_batch(**tagged_transitions(2, 12))
    assert len(buf) == 5
    assert stored_rewards(buf) == {9, 10, 11, 12, 13}
    buf.add_batch(**tagged_transitions(14, 1))
    assert stored_rewards(buf) == {10, 11, 12, 13, 14}


def test_replay_rejects_wrong_shapes() -> None:
    buf = ReplayBuffer(capacity=5)
    t = tagged_transitions(0, 3)
    t["grids"] = t["grids"][:, :, :, :10]
    with pytest.raises(ValueError, match="grids"):
        buf.add_batch(**t)


def test_replay_sample_types() -> None:
    buf = ReplayBuffer(capacity=10)
    buf.add_batch(**random_transitions(np.random.default_rng(1), 4))
    batch = buf.sample(6, np.random.default_rng(0))
    assert isinstance(batch, ReplayBatch)
    assert batch.grids.shape == (6, *GRID_SHAPE) and batch.grids.dtype == torch.float32
    assert batch.actions.dtype == torch.int64
    assert batch.dones.dtype == torch.float32


# --- exploration -----------------------------------------------------------------------------


def test_epsilon_greedy_fully_greedy_is_argmax() -> None:
    rng = np.random.default_rng(0)
    q = rng.normal(size=(500, N_ACTIONS))
    actions = epsilon_greedy(q, 0.0, rng)
    assert actions.dtype == np.int64
    assert np.array_equal(actions, q.argmax(axis=1))


def test_epsilon_greedy_never_greedy_is_uniform() -> None:
    rng = np.random.default_rng(0)
    q = np.tile([0.0, 0.0, 5.0, 0.0], (40_000, 1))
    counts = np.bincount(epsilon_greedy(q, 1.0, rng), minlength=N_ACTIONS) / 40_000
    assert np.all(np.abs(counts - 0.25) < 0.015)


def test_epsilon_greedy_mixture() -> None:
    rng = np.random.default_rng(0)
    q = np.tile([0.0, 0.0, 5.0, 0.0], (40_000, 1))
    share = np.mean(epsilon_greedy(q, 0.1, rng) == 2)
    assert abs(share - (0.9 + 0.1 / N_ACTIONS)) < 0.01


# --- update and learner ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "optimizer, lr, updates, ratio",
    [("adam", 1e-3, 50, 0.2), ("sgd", 0.01, 200, 0.95)],  # sgd at lr 0.01: the paper's (slower) setting
)
def test_dqn_update_lowers_td_loss_on_a_fixed_batch(optimizer: str, lr: float, updates: int, ratio: float) -> None:
    torch.manual_seed(0)
    online, target = QNetwork(30.0), QNetwork(30.0)
    sync_target(online, target)
    opt = make_optimizer(online, DQNConfig(lr=lr, optimizer=optimizer))
    buf = ReplayBuffer(capacity=64)
    buf.add_batch(**random_transitions(np.random.default_rng(0), 64))
    batch = buf.sample(32, np.random.default_rng(1))
    target_before = weights(target)
    losses = [dqn_update(online, target, opt, batch, 0.9, 10.0) for _ in range(updates)]
    assert losses[-1] < ratio * losses[0]
    assert np.mean(losses[-10:]) < np.mean(losses[:10])
    assert same(weights(target), target_before)


def test_make_optimizer() -> None:
    net = QNetwork(30.0)
    assert isinstance(make_optimizer(net, DQNConfig(optimizer="adam")), torch.optim.Adam)
    assert isinstance(make_optimizer(net, DQNConfig(optimizer="sgd")), torch.optim.SGD)
    with pytest.raises(ValueError, match="rmsprop"):
        make_optimizer(net, DQNConfig(optimizer="rmsprop"))


@pytest.mark.parametrize("optimizer, lr", [("adam", 1e-3), ("sgd", 0.01)])
def test_optimizer_step_equals_torchs_step_and_imports_no_dynamo(optimizer: str, lr: float) -> None:
    """optimizer_step skips torch's wrappers (which import torch._dynamo, 1.8 s per process): in a fresh process,
    updates and a state_dict round trip leave torch._dynamo unimported, and the weights equal torch's own step's."""
    code = f"""
import sys, numpy as np, torch
from coopsumo.agents.dqn import QNetwork, ReplayBuffer, dqn_update, make_optimizer, sync_target
from coopsumo.dqn_config import DQNConfig
sys.path.insert(0, "tests")
from test_dqn import random_transitions
from coopsumo.agents.dqn import q_values, td_targets
nets = []
for _ in range(2):
    torch.manual_seed(0)
    online, target = QNetwork(30.0), QNetwork(30.0)
    sync_target(online, target)
    nets.append((online, target, make_optimizer(online, DQNConfig(lr={lr}, optimizer={optimizer!r}))))
buf = ReplayBuffer(capacity=64)
buf.add_batch(**random_transitions(np.random.default_rng(0), 64))
batch = buf.sample(32, np.random.default_rng(1))
online, target, opt = nets[0]
for _ in range(5):
    dqn_update(online, target, opt, batch, 0.9, 10.0)
opt.load_state_dict(opt.state_dict())
dqn_update(online, target, opt, batch, 0.9, 10.0)
assert "torch._dynamo" not in sys.modules, "torch._dynamo was imported"
online2, target2, opt2 = nets[1]
for i in range(6):  # torch's own step, as before
    q = q_values(online2, batch.grids, batch.features, batch.alphas).gather(1, batch.actions.unsqueeze(1)).squeeze(1)
    loss = ((td_targets(online2, target2, batch, 0.9, False) - q) ** 2).mean()
    opt2.zero_grad(); loss.backward(); torch.nn.utils.clip_grad_norm_(online2.parameters(), 10.0); opt2.step()
    if i == 4:
        opt2.load_state_dict(opt2.state_dict())
for a, b in zip(online.state_dict().values(), online2.state_dict().values(), strict=True):
    assert torch.equal(a, b), "weights differ from torch's step"
print("ok")
"""
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=False)
    assert res.returncode == 0 and res.stdout.strip() == "ok", res.stderr[-2000:]


def test_target_changes_only_at_sync() -> None:
    learner = Learner(SMALL_CFG, seed=0)
    learner.observe(**random_transitions(np.random.default_rng(0), 32))
    previous_target = weights(learner.target)
    for step in range(1, 8):
        loss = learner.step()
        assert loss is not None
        if step % SMALL_CFG.target_sync_steps == 0:
            assert same(weights(learner.target), weights(learner.online))
            assert not same(weights(learner.target), previous_target)
        else:
            assert same(weights(learner.target), previous_target)
            assert not same(weights(learner.online), previous_target)
        previous_target = weights(learner.target)


def test_no_update_before_learn_start_or_a_full_batch() -> None:
    cfg = dataclasses.replace(PAPER_DQN, batch_size=8, learn_start_steps=3, replay_size=64, learn_every=1)
    learner = Learner(cfg, seed=0)
    assert learner.step() is None  # empty buffer
    learner.observe(**random_transitions(np.random.default_rng(0), 8))
    assert learner.step() is None  # step 2 < learn_start_steps
    assert learner.step() is not None
    assert learner.updates == 1


def test_act_shapes_and_greedy_matches_network() -> None:
    learner = Learner(SMALL_CFG, seed=0)
    t = random_transitions(np.random.default_rng(0), 9)
    actions = learner.act(t["grids"], t["features"], explore=False)
    q = learner.online(torch.from_numpy(t["grids"]), torch.from_numpy(t["features"]))
    assert actions.dtype == np.int64 and actions.shape == (9,)
    assert np.array_equal(actions, q.argmax(dim=1).numpy())
    assert learner.act(t["grids"][:0], t["features"][:0], explore=True).shape == (0,)


def test_same_seed_gives_identical_weights() -> None:
    a, b, c = Learner(SMALL_CFG, seed=3), Learner(SMALL_CFG, seed=3), Learner(SMALL_CFG, seed=4)
    assert same(weights(a.online), weights(b.online))
    assert not same(weights(a.online), weights(c.online))
    run_steps(a, np.random.default_rng(7), 10)
    run_steps(b, np.random.default_rng(7), 10)
    assert a.updates == 9  # no update at step 1: 5 transitions < batch of 8
    assert same(weights(a.online), weights(b.online))
    assert same(weights(a.target), weights(b.target))


def test_learner_leaves_torch_global_rng_alone() -> None:
    torch.manual_seed(123)
    expected = torch.rand(3)
    torch.manual_seed(123)
    Learner(SMALL_CFG, seed=0)
    assert torch.equal(torch.rand(3), expected)


@pytest.mark.parametrize("via_file", [False, True])
def test_state_dict_resume_is_exact(tmp_path: Path, via_file: bool) -> None:
    cfg = dataclasses.replace(PAPER_DQN, replay_size=40, batch_size=8, learn_start_steps=4, target_sync_steps=5)
    env_rng = np.random.default_rng(11)
    uninterrupted = Learner(cfg, seed=1)
    run_steps(uninterrupted, env_rng, 12)  # the buffer wraps around (60 transitions > 40)
    state = uninterrupted.state_dict()
    if via_file:
        torch.save(state, tmp_path / "ckpt.pt")
        state = torch.load(tmp_path / "ckpt.pt", weights_only=True)
    env_state = env_rng.bit_generator.state
    actions_a = run_steps(uninterrupted, env_rng, 9)

    resumed = Learner(cfg, seed=99)  # a different seed: everything must come from the state
    resumed.load_state_dict(state)
    env_rng.bit_generator.state = env_state
    actions_b = run_steps(resumed, env_rng, 9)

    assert all(np.array_equal(x, y) for x, y in zip(actions_a, actions_b, strict=True))
    assert same(weights(uninterrupted.online), weights(resumed.online))
    assert same(weights(uninterrupted.target), weights(resumed.target))
    assert resumed.env_steps == uninterrupted.env_steps == 21
    assert resumed.updates == uninterrupted.updates


# --- model files -----------------------------------------------------------------------------


def test_save_load_round_trip(tmp_path: Path) -> None:
    torch.manual_seed(0)
    net = QNetwork(speed_scale_mps=25.0)
    path = tmp_path / "model.pt"
    save_model(path, net, {"alpha": 0.5, "steps": 90_000, "lanes": [3]})
    loaded, meta = load_model(path)
    assert meta == {"alpha": 0.5, "steps": 90_000, "lanes": [3]}
    assert loaded.speed_scale_mps == 25.0
    grids = torch.from_numpy(random_transitions(np.random.default_rng(0), 4)["grids"])
    speed = torch.full((4, 3), -4.0)
    assert torch.equal(loaded(grids, speed), net(grids, speed))
    assert [p.name for p in tmp_path.iterdir()] == ["model.pt"]  # no temp file left behind


def test_save_model_overwrites_atomically(tmp_path: Path) -> None:
    path = tmp_path / "model.pt"
    save_model(path, QNetwork(30.0), {"version": 1})
    save_model(path, QNetwork(30.0), {"version": 2})
    assert load_model(path)[1] == {"version": 2}
    assert [p.name for p in tmp_path.iterdir()] == ["model.pt"]


def good_payload() -> dict[str, object]:
    return {
        "state_dict": QNetwork(30.0).state_dict(),
        "grid_shape": list(GRID_SHAPE),
        "n_actions": N_ACTIONS,
        "speed_scale_mps": 30.0,
        "meta": {},
    }


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "not found"),
        (b"this is not a torch file", "cannot read"),
        ({"weights": [1, 2, 3]}, "not a coopsumo model"),
        ({**good_payload(), "grid_shape": [3, 3, 30]}, "grid shape"),
        ({**good_payload(), "n_actions": 5}, "actions"),
        ({**good_payload(), "state_dict": {"fc1.weight": torch.zeros(2, 2)}}, "incompatible weights"),
    ],
    ids=["missing", "garbage", "foreign", "grid-shape", "n-actions", "weights"],
)
def test_load_model_errors(tmp_path: Path, content: object, message: str) -> None:
    path = tmp_path / "model.pt"
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        torch.save(content, path)
    with pytest.raises(ModelFileError, match=message) as info:
        load_model(path)
    assert "\n" not in str(info.value)
    assert isinstance(info.value, ValueError)


def test_dqn_policy_reuses_the_action_of_an_unchanged_input_and_recomputes_the_rest(
    observation_of: Callable[..., Observation],
) -> None:
    """DQNPolicy skips the forward pass for a vehicle whose grids and speed errors did not change;
    its actions always equal those of a plain forward pass over the whole batch."""
    from coopsumo.agents.dqn_policy import DQNPolicy

    torch.manual_seed(0)
    net = QNetwork(speed_scale_mps=10.0)
    policy = DQNPolicy(net)
    rng = np.random.default_rng(0)
    base = observation_of([0, 1, 2, 0], [10.0, 30.0, 50.0, 70.0], [5.0] * 4, [20.0] * 4)
    rows_seen: list[int] = []
    forward = net.forward

    def counting(grids: torch.Tensor, speed_err: torch.Tensor) -> torch.Tensor:
        rows_seen.append(len(grids))
        return forward(grids, speed_err)

    net.forward = counting  # type: ignore[method-assign]

    def with_input(grids: np.ndarray, speed_err: np.ndarray) -> Observation:
        return dataclasses.replace(base, grids=grids, speed_err=speed_err)

    grids = rng.integers(0, 2, size=(4, 3, 3, 20)).astype(np.uint8)
    err = rng.normal(0, 5, size=(4, 3)).astype(np.float32)
    plain = lambda g, e: forward(torch.from_numpy(g).float(), torch.from_numpy(e)).argmax(dim=1).numpy()  # noqa: E731
    np.testing.assert_array_equal(policy.act(with_input(grids, err)), plain(grids, err))
    np.testing.assert_array_equal(policy.act(with_input(grids, err)), plain(grids, err))
    assert rows_seen == [4]  # the second call needed no forward pass
    grids2, err2 = grids.copy(), err.copy()
    grids2[1, 2, 0, 5] ^= 1
    err2[3, 2] += 0.5
    np.testing.assert_array_equal(policy.act(with_input(grids2, err2)), plain(grids2, err2))
    assert rows_seen == [4, 2]  # only vehicles 1 and 3 changed


def test_a_v2x_model_records_its_observation_and_reads_its_wider_input(tmp_path: Path) -> None:
    path = tmp_path / "model.pt"
    net = QNetwork(30.0, dueling=True, observation="v2x")
    assert net.n_features == n_features("v2x") > n_features("paper")
    save_model(path, net, {})
    loaded, _ = load_model(path)
    assert loaded.observation == "v2x" and loaded.n_features == net.n_features
    grids = torch.zeros(2, *GRID_SHAPE)
    feats = torch.linspace(-1, 1, 2 * net.n_features).reshape(2, -1)
    assert torch.equal(loaded(grids, feats), net(grids, feats))
    with pytest.raises(RuntimeError):  # the paper's 3 speed errors alone do not fit its first layer
        loaded(grids, feats[:, :3])


def test_a_model_without_an_observation_reads_the_papers_and_an_unknown_one_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "model.pt"
    torch.save(good_payload(), path)  # written before the v2x state: no "observation" entry
    assert load_model(path)[0].observation == "paper"
    torch.save({**good_payload(), "observation": "lidar"}, path)
    with pytest.raises(ModelFileError, match="observation 'lidar'.*newer coopsumo") as info:
        load_model(path)
    assert "\n" not in str(info.value)


def test_a_model_whose_settings_and_weights_disagree_on_the_observation_is_refused(tmp_path: Path) -> None:
    from coopsumo.agents.dqn_policy import DQNPolicy
    from coopsumo.config import TrainConfig, to_dict
    from coopsumo.errors import UsageError

    paper_cfg = to_dict(TrainConfig(dqn=dataclasses.replace(TrainConfig().dqn, observation="paper")))
    v2x_cfg = to_dict(TrainConfig(dqn=dataclasses.replace(TrainConfig().dqn, observation="v2x")))
    for weights, cfg, ok in (("v2x", v2x_cfg, True), ("paper", paper_cfg, True), ("v2x", paper_cfg, False),
                             ("paper", v2x_cfg, False)):  # fmt: skip
        path = tmp_path / f"{weights}_{cfg['dqn']['observation']}.pt"
        save_model(path, QNetwork(30.0, dueling=True, observation=weights), {"config": cfg})
        if ok:
            assert DQNPolicy.from_file(str(path)).trained_on["observation"] == weights  # type: ignore[index]
        else:
            with pytest.raises(UsageError, match="observation") as info:
                DQNPolicy.from_file(str(path))
            assert "\n" not in str(info.value)


def test_a_greedy_policy_asks_the_network_only_for_vehicles_whose_input_changed() -> None:
    """DQNPolicy keeps each vehicle's last input and action: an unchanged vehicle keeps its action without a forward
    pass; a change in its speed errors, its grids or its offered actions alone makes it decide afresh."""
    from coopsumo.agents.dqn_policy import DQNPolicy

    net = QNetwork(30.0)
    asked: list[int] = []
    forward = net.forward
    net.forward = lambda grids, feats, *a: (asked.append(len(grids)), forward(grids, feats, *a))[1]  # type: ignore[method-assign]
    policy = DQNPolicy(net, action_mask=True)
    rng = np.random.default_rng(0)
    n = 5

    def obs(grids: np.ndarray, err: np.ndarray, feasible: np.ndarray) -> Observation:
        return Observation(nums=np.arange(n), grids=grids, speed_err=err, lane=np.zeros(n, np.int64),
                           pos=np.arange(n) * 10.0, speed=np.full(n, 20.0), v_exp=np.full(n, 25.0),
                           busy=np.zeros(n, bool), around=None, n_lanes=3, feasible=feasible)  # type: ignore[arg-type]

    grids = rng.integers(0, 2, (n, 3, 3, 20)).astype(np.uint8)
    err = rng.normal(size=(n, 3)).astype(np.float32)
    feasible = np.ones((n, 4), bool)
    first = policy.act(obs(grids, err, feasible))
    assert asked == [n]
    assert np.array_equal(policy.act(obs(grids.copy(), err.copy(), feasible.copy())), first) and asked == [n]
    err2, grids2, feasible2 = err.copy(), grids.copy(), feasible.copy()
    err2[1, 2] += 0.5  # vehicle 1: its speed error
    grids2[3, 2, 1, 7] ^= 1  # vehicle 3: one cell of its newest frame
    feasible2[4, 0] = False  # vehicle 4: left no longer offered
    policy.act(obs(grids2, err2, feasible2))
    assert asked == [n, 3]
