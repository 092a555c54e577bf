"""Tests of coopsumo.agents.stacked (issue 77, items 1 and 2): K QNetworks updated as one. The stacked forward pass
against QNetwork's; a member's training, bit for bit, the same in a group of 8 as alone (and a mixing of members
caught); members left out of a step; checkpoints; members in and out of Learner's formats; Adam against torch's.
No SUMO."""

from __future__ import annotations

import dataclasses
import io
from collections.abc import Iterator

import pytest
import torch

from coopsumo.agents.dqn import QNetwork, learn, make_optimizer, optimizer_step, sync_target
from coopsumo.agents.replay import GRID_SHAPE, N_ACTIONS, ReplayBatch
from coopsumo.agents.stacked import StackedBatch, StackedLearner, adam_step, stack_batches
from coopsumo.dqn_config import DQN_PRESETS, DQNConfig

DEFAULT = DQN_PRESETS["default"]
CONDITIONED = dataclasses.replace(DEFAULT, alpha_conditioned=True)


@pytest.fixture(autouse=True)
def one_thread() -> Iterator[None]:
    """A member's bits are the same in any group on one torch thread (a product split over threads may differ)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def networks(cfg: DQNConfig, k: int, seed: int = 0) -> list[QNetwork]:
    torch.manual_seed(seed)
    return [QNetwork(cfg.speed_scale_mps, cfg.dueling, cfg.observation, cfg.alpha_conditioned) for _ in range(k)]


def random_batch(gen: torch.Generator, cfg: DQNConfig, size: int = 64) -> ReplayBatch:
    """A minibatch as ReplayBuffer.sample draws it: 0/1 grids, speed errors and v2x features, some actions closed."""
    width = networks(cfg, 1)[0].n_features
    mask = torch.rand(size, N_ACTIONS, generator=gen) < 0.6
    mask[:, -1] = True  # 'none' always open

    def grids() -> torch.Tensor:
        return (torch.rand(size, *GRID_SHAPE, generator=gen) < 0.2).float()

    return ReplayBatch(
        grids=grids(), features=torch.randn(size, width, generator=gen) * 3,
        actions=torch.randint(0, 4, (size,), generator=gen), rewards=torch.randn(size, generator=gen),
        next_grids=grids(), next_features=torch.randn(size, width, generator=gen) * 3,
        dones=(torch.rand(size, generator=gen) < 0.1).float(), next_mask=mask,
        alphas=torch.rand(size, generator=gen) * 8 if cfg.alpha_conditioned else None)  # fmt: skip


def member_equal(a: StackedLearner, i: int, b: StackedLearner, j: int) -> bool:
    """Member i of a and member j of b hold the same bits: weights, target, Adam moments, steps."""
    buffers = ["_weights", "_exp_avg", "_exp_avg_sq"]
    same = [torch.equal(a.online[i], b.online[j]), torch.equal(a.target[i], b.target[j]), a.steps[i] == b.steps[j]]
    for name in buffers[1:]:
        x, y = getattr(a, name), getattr(b, name)
        same.append(x is None and y is None or x is not None and y is not None and torch.equal(x[i], y[j]))
    return all(same)


# -- the forward pass ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("cfg", [DEFAULT, DQN_PRESETS["paper"], CONDITIONED], ids=["default", "paper", "conditioned"])
@pytest.mark.parametrize("k", [1, 3, 8])
def test_the_stacked_forward_is_each_networks(cfg: DQNConfig, k: int) -> None:
    nets = networks(cfg, k, seed=k)
    group = StackedLearner(cfg, [n.state_dict() for n in nets])
    gen = torch.Generator().manual_seed(k)
    batches = [random_batch(gen, cfg, 33) for _ in range(k)]
    stacked, _ = stack_batches(batches)
    q = group.q_values(stacked.grids, stacked.features, stacked.alphas)
    assert q.shape == (k, 33, N_ACTIONS)
    with torch.no_grad():
        for i, (net, b) in enumerate(zip(nets, batches, strict=True)):
            expected = net(b.grids, b.features) if b.alphas is None else net(b.grids, b.features, b.alphas)
            assert (q[i] - expected).abs().max() <= 1e-6
    # the target networks start as the online ones
    assert torch.equal(group.q_values(stacked.grids, stacked.features, stacked.alphas, target=True), q)


def test_a_member_out_of_the_group_is_a_qnetwork_again() -> None:
    """member_state's weights load into QNetwork (its exact names and shapes) and give its Q-values; set_member
    takes them back bit for bit."""
    nets = networks(DEFAULT, 3)
    group = StackedLearner(DEFAULT, [n.state_dict() for n in nets])
    gen = torch.Generator().manual_seed(5)
    for _ in range(3):
        group.learn(stack_batches([random_batch(gen, DEFAULT) for _ in range(3)])[0])
    b = random_batch(gen, DEFAULT)
    q = group.q_values(b.grids.expand(3, *b.grids.shape), b.features.expand(3, *b.features.shape))
    for k in range(3):
        state = group.member_state(k)
        net = networks(DEFAULT, 1)[0]
        net.load_state_dict(state["online"])  # strict: every name and shape
        assert list(state["online"]) == list(net.state_dict())
        with torch.no_grad():
            assert (net(b.grids, b.features) - q[k]).abs().max() <= 1e-6
        assert not torch.equal(net.state_dict()["fc1.weight"], nets[k].state_dict()["fc1.weight"])  # it learned
        again = StackedLearner(DEFAULT, [nets[0].state_dict()])
        again.set_member(0, state["online"], state["target"], state["optimizer"])
        assert member_equal(group, k, again, 0)


# -- a member's result does not depend on its group ----------------------------------------------------------------


def train_alone_and_together(cfg: DQNConfig, k: int, updates: int,
                             seed: int) -> tuple[StackedLearner, list[StackedLearner]]:  # fmt: skip
    """A group of k and k groups of one from the same networks, on the same minibatches, the targets synced every 25
    updates; every update's losses compared."""
    nets = networks(cfg, k, seed)
    group = StackedLearner(cfg, [n.state_dict() for n in nets])
    alone = [StackedLearner(cfg, [n.state_dict()]) for n in nets]
    gen = torch.Generator().manual_seed(seed)
    for update in range(updates):
        batches = [random_batch(gen, cfg) for _ in range(k)]
        losses = group.learn(stack_batches(batches)[0])
        for i, (one, b) in enumerate(zip(alone, batches, strict=True)):
            assert torch.equal(one.learn(stack_batches([b])[0]), losses[i : i + 1]), (update, i)
        if update % 25 == 24:
            group.sync_target()
            for one in alone:
                one.sync_target()
    return group, alone


def test_a_member_trained_in_a_group_of_8_is_the_member_trained_alone() -> None:
    """The default learner with a gradient clip of 0.5, so that the clipping acts on about half the updates (these
    minibatches' gradient norms are 0.3-0.8), on some members and not others; 50 updates, the targets synced twice."""
    group, alone = train_alone_and_together(dataclasses.replace(DEFAULT, grad_clip_norm=0.5), 8, 50, seed=1)
    for k, one in enumerate(alone):
        assert member_equal(group, k, one, 0), k
        assert group.steps[k] == 50
    assert not member_equal(group, 0, group, 1)


@pytest.mark.parametrize("cfg", [dataclasses.replace(DQN_PRESETS["paper"], grad_clip_norm=0.3),
                                 CONDITIONED],
                         ids=["paper-sgd-mse", "conditioned"])  # fmt: skip
def test_every_learner_setting_keeps_members_apart(cfg: DQNConfig) -> None:
    group, alone = train_alone_and_together(cfg, 3, 30, seed=2)
    assert all(member_equal(group, k, one, 0) for k, one in enumerate(alone))


def test_a_clipping_over_the_whole_group_would_be_caught(monkeypatch: pytest.MonkeyPatch) -> None:
    """The test above can fail: one gradient norm over all members (a reduction that mixes them) is caught."""

    def clip_all(self: StackedLearner) -> None:
        norm = torch.linalg.vector_norm(self._grads)
        self._grads.mul_(torch.clamp(self.cfg.grad_clip_norm / (norm + 1e-6), max=1.0))

    monkeypatch.setattr(StackedLearner, "_clip", clip_all)
    cfg = dataclasses.replace(DEFAULT, grad_clip_norm=0.05)  # so that the clipping acts
    with pytest.raises(AssertionError):
        train_alone_and_together(cfg, 4, 3, seed=3)


# -- members left out of a step --------------------------------------------------------------------------------------


def test_a_member_left_out_keeps_its_state_and_changes_no_other() -> None:
    """Member 1 waits 10 updates (its replay filling), then learns: while it waits, its weights, moments and step
    count stay, whatever its rows of the batch hold (NaN here); the others are as if it were not there, and it ends as
    if trained alone on its own minibatches."""
    nets = networks(DEFAULT, 3, seed=4)
    plain, poisoned = (StackedLearner(DEFAULT, [n.state_dict() for n in nets]) for _ in range(2))
    alone = [StackedLearner(DEFAULT, [n.state_dict()]) for n in nets]
    start = plain.state_dict()
    gen = torch.Generator().manual_seed(4)
    for update in range(20):
        batches: list[ReplayBatch | None] = [random_batch(gen, DEFAULT) for _ in range(3)]
        if update < 10:
            batches[1] = None
        stacked, active = stack_batches(batches)
        plain.learn(stacked, active)
        nan_rows = {n: t.clone() for n, t in vars(stacked).items() if t is not None}
        if not active[1]:
            for name in ("grids", "features", "rewards", "next_grids", "next_features"):
                nan_rows[name][1] = torch.nan
        poisoned.learn(StackedBatch(**nan_rows), active)
        for one, b in zip(alone, batches, strict=True):
            if b is not None:
                one.learn(stack_batches([b])[0])
        if update == 9:
            assert plain.steps == [10, 0, 10]
            assert plain._exp_avg is not None and plain._exp_avg_sq is not None
            assert torch.equal(plain.online[1], start["weights"][1])
            assert not plain._exp_avg[1].any() and not plain._exp_avg_sq[1].any()
            plain.sync_target(torch.tensor([False, True, False]))  # touches member 1's target only
            poisoned.sync_target(torch.tensor([False, True, False]))
            alone[1].sync_target()
            assert torch.equal(plain.target[0], start["weights"][3])
            assert torch.equal(plain.target[2], start["weights"][5])
    assert plain.steps == [20, 10, 20]
    for k in range(3):
        assert member_equal(plain, k, poisoned, k) and member_equal(plain, k, alone[k], 0), k


def test_a_step_with_no_member_changes_nothing() -> None:
    group = StackedLearner(DEFAULT, [n.state_dict() for n in networks(DEFAULT, 2)])
    before = group.state_dict()
    stacked, _ = stack_batches([random_batch(torch.Generator().manual_seed(0), DEFAULT)] * 2)
    group.learn(stacked, torch.tensor([False, False]))
    after = group.state_dict()
    assert all(torch.equal(before[n], after[n]) for n in before if n != "width")
    with pytest.raises(ValueError, match="bool"):
        group.learn(stacked, torch.tensor([1, 0]))


# -- checkpoints -----------------------------------------------------------------------------------------------------


def test_a_checkpointed_group_continues_exactly() -> None:
    """50 updates, the state through torch.save and torch.load(weights_only=True) into a fresh group, 50 more: the
    same bits as 100 straight, every member (their step counts differing: member 2 starts late)."""
    cfg = DEFAULT
    nets = networks(cfg, 3, seed=6)
    gen = torch.Generator().manual_seed(6)
    rounds = [[random_batch(gen, cfg) if i < 2 or r >= 7 else None for i in range(3)] for r in range(100)]

    def train(group: StackedLearner, rs: list[list[ReplayBatch | None]], first: int) -> None:
        for r, batches in enumerate(rs, start=first):
            group.learn(*stack_batches(batches))
            if r % 30 == 29:
                group.sync_target(torch.tensor([True, False, True]))

    straight = StackedLearner(cfg, [n.state_dict() for n in nets])
    train(straight, rounds, 0)
    first = StackedLearner(cfg, [n.state_dict() for n in nets])
    train(first, rounds[:50], 0)
    saved = io.BytesIO()
    torch.save(first.state_dict(), saved)
    saved.seek(0)
    resumed = StackedLearner(cfg, [n.state_dict() for n in networks(cfg, 3, seed=7)])  # other weights, overwritten
    resumed.load_state_dict(torch.load(saved, weights_only=True))
    train(resumed, rounds[50:], 50)
    assert straight.steps == [100, 100, 93]
    assert all(member_equal(straight, k, resumed, k) for k in range(3))
    with pytest.raises(ValueError, match="another group"):
        StackedLearner(cfg, [n.state_dict() for n in nets[:2]]).load_state_dict(first.state_dict())


# -- Learner's update, formats and optimiser -------------------------------------------------------------------------


@pytest.mark.parametrize("cfg", [DEFAULT, DQN_PRESETS["paper"], dataclasses.replace(CONDITIONED, grad_clip_norm=0.5)],
                         ids=["default", "paper-sgd-mse", "conditioned-clipped"])  # fmt: skip
def test_a_group_of_one_learns_as_learner_does(cfg: DQNConfig) -> None:
    """The same loss, targets and clipping as dqn.learn, not its bits: before each of 12 updates of
    a Learner's network the group takes its state (set_member, exact), then both update on the same minibatch; the
    losses agree within 1e-6 relative, the clipped gradients within 1e-5 of their norm in 10 of the 12 updates and
    1e-2 in all (the products differ in their last bits, measured 1e-8 to 1e-7, and a last bit that moves a ReLU
    across 0 changes a unit's gradient: 1e-3 once in 180 updates; a wrong target, loss or clipping is off by 0.1 or
    more), and the optimiser step that follows is tested bit for bit (Adam below). The weights are not compared:
    Adam's step on a gradient near its eps (1e-8) turns a last-bit difference into up to a step, and a difference
    that flips a next action's argmax grows, as for any change of the bits."""
    online, target = networks(cfg, 2, seed=10)
    sync_target(online, target)
    optimizer = make_optimizer(online, cfg)
    group = StackedLearner(cfg, [online.state_dict()])
    gen = torch.Generator().manual_seed(10)
    gaps = []  # |their gradient - ours| / |theirs|, after clipping
    for update in range(12):
        b = random_batch(gen, cfg)
        group.set_member(0, online.state_dict(), target.state_dict(), optimizer.state_dict())
        loss = learn(online, target, optimizer, b, cfg)
        assert group.learn(stack_batches([b])[0]).item() == pytest.approx(loss, rel=1e-6)
        grads = group._member(group._grads, 0)
        theirs = {name: param.grad for name, param in online.named_parameters() if param.grad is not None}
        assert len(theirs) == len(grads)
        gaps.append(float(flat_norm({n: grads[n] - g for n, g in theirs.items()}) / flat_norm(theirs)))
        if update % 4 == 3:
            sync_target(online, target)
    assert max(gaps) < 1e-2 and sorted(gaps)[-3] < 1e-5, gaps


def flat_norm(tensors: dict[str, torch.Tensor]) -> torch.Tensor:
    return torch.linalg.vector_norm(torch.cat([t.reshape(-1) for t in tensors.values()]))


def test_adam_is_torchs_for_loop_adam_at_each_rows_step_count() -> None:
    """adam_step on two rows at different step counts is torch.optim.Adam (the project's make_optimizer) on each row
    alone, bit for bit."""
    gen = torch.Generator().manual_seed(8)
    rows = torch.randn(2, 256, generator=gen)
    params, exp_avg, exp_avg_sq, steps = rows.clone(), torch.zeros(2, 256), torch.zeros(2, 256), [0, 0]
    torch_params = [torch.nn.Parameter(rows[i].clone()) for i in range(2)]
    optimizers = [torch.optim.Adam([p], lr=DEFAULT.lr) for p in torch_params]
    for update in range(30):
        grads = torch.randn(2, 256, generator=gen) * 10.0 ** torch.randint(-8, 1, (2, 1), generator=gen)
        take = [0, 1] if update % 3 else [0]  # row 1 skips every third step
        for i in take:
            steps[i] += 1
            torch_params[i].grad = grads[i].clone()
            optimizer_step(optimizers[i])
        idx = torch.tensor(take)
        p, m, v = params[idx], exp_avg[idx], exp_avg_sq[idx]
        adam_step(p, grads[idx], m, v, [steps[i] for i in take], DEFAULT.lr)
        params[idx], exp_avg[idx], exp_avg_sq[idx] = p, m, v
    for i in range(2):
        assert torch.equal(params[i], torch_params[i].detach())
        assert torch.equal(exp_avg_sq[i], optimizers[i].state[torch_params[i]]["exp_avg_sq"])


def test_a_member_moves_between_learner_and_group_exactly() -> None:
    """A network trained by torch's Adam (as Learner's) enters a group with its target and optimiser state and comes
    out the same bits; the optimiser state it comes out with loads into make_optimizer's optimiser."""
    net, target = networks(DEFAULT, 2, seed=9)
    sync_target(net, target)
    optimizer = make_optimizer(net, DEFAULT)
    gen = torch.Generator().manual_seed(9)
    for _ in range(3):
        b = random_batch(gen, DEFAULT)
        net(b.grids, b.features).pow(2).mean().backward()
        optimizer_step(optimizer)
    group = StackedLearner(DEFAULT, [target.state_dict()] * 2)
    group.set_member(1, net.state_dict(), target.state_dict(), optimizer.state_dict())
    state = group.member_state(1)
    assert group.steps == [0, 3]
    for name, t in net.state_dict().items():
        assert torch.equal(state["online"][name], t) and torch.equal(state["target"][name], target.state_dict()[name])
    theirs, ours = optimizer.state_dict(), state["optimizer"]
    assert ours["param_groups"] == theirs["param_groups"]
    for i, entry in theirs["state"].items():
        assert all(torch.equal(ours["state"][i][key], t) for key, t in entry.items())
    make_optimizer(networks(DEFAULT, 1)[0], DEFAULT).load_state_dict(ours)
    assert group.member_state(0)["optimizer"]["state"] == {}  # no step taken: torch's empty state
    with pytest.raises(ValueError, match="learning rate"):
        StackedLearner(dataclasses.replace(DEFAULT, lr=0.01), [net.state_dict()]).set_member(
            0, net.state_dict(), optimizer=theirs)
