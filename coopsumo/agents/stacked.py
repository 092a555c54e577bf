"""K lane-changing DQNs updated as one (issue 77): their weights stacked (agents/stacked_net.py), one forward pass,
one backward pass and one optimiser step for all K per update.

A member is a QNetwork of one DQNConfig (agents/dqn.py) with the same loss, target, gradient clipping and optimiser as
Learner, each operation batched over the members and none reducing across them, so that a member's result does not
depend on its group: member k trained in a group of 8 is, bit for bit, the member trained alone in a group of one on
the same minibatches (one torch thread; tests/test_stacked.py). A member left out of a step (its replay still
filling) keeps its weights, optimiser state and step count, and the others' results do not depend on its rows. A
group of one is not Learner bit for bit: its products are batched matrix products, not torch's convolution and
linear layers (docs/performance.md says how far apart they are).

The gradients land in a (K, width) buffer (the parameters' .grad are its views), so that a member's gradient norm,
its Adam step (at its own step count) and its target sync are each one operation over rows.
"""

from __future__ import annotations

import copy
import ctypes
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import nn

from coopsumo.agents.dqn import QNetwork, make_optimizer
from coopsumo.agents.replay import ReplayBatch
from coopsumo.agents.stacked_net import (
    Layout,
    conv_patches,
    network_weights,
    q_from_patches,
    stacked_q_values,
    stacked_weights,
)
from coopsumo.dqn_config import DQNConfig

_LAYOUT_WARNING = "grad and param do not obey the gradient layout contract"
"""torch's warning for a .grad that is a view of a wider buffer: it is accumulated in place all the same"""


def hold_freed_memory() -> bool:
    """Ask glibc's malloc to keep freed memory for reuse in this process (True if it could): the megabyte-sized
    temporaries of a stacked update otherwise go back to the system and fault in afresh at every update (1,200-2,600
    page faults an update of a group of 8, up to a fifth of its CPU; docs/performance.md). For a process that runs
    stacked updates (the update worker): its heap then keeps its largest size, tens of MB."""
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # malloc.h
    return bool(libc.mallopt(m_mmap_threshold, 32 * 2**20) and libc.mallopt(m_trim_threshold, 2**30))


def adam_step(params: torch.Tensor, grads: torch.Tensor, exp_avg: torch.Tensor, exp_avg_sq: torch.Tensor,
              steps: Sequence[int], lr: float, scratch: torch.Tensor | None = None) -> None:  # fmt: skip
    """torch.optim.Adam's step with its defaults (betas 0.9, 0.999, eps 1e-8, no weight decay, amsgrad or maximize)
    in place on rows (n, width), row i at its own step count steps[i] (this step's, from 1): torch's for-loop Adam's
    operations in its order, its scalars one float32 number per row (the bias corrections in Python floats, as
    torch's). scratch: (2, n, width) or larger, for the intermediate rows (None: new tensors)."""
    beta1, beta2, eps = 0.9, 0.999, 1e-8
    n = params.shape[0]
    denom, numer = (torch.empty(2, *params.shape) if scratch is None else scratch)[:, :n]
    step_size = torch.tensor([-(lr / (1 - beta1**s)) for s in steps], dtype=params.dtype).unsqueeze(1)
    bias_correction2_sqrt = torch.tensor([(1 - beta2**s) ** 0.5 for s in steps], dtype=params.dtype).unsqueeze(1)
    exp_avg.lerp_(grads, 1 - beta1)
    exp_avg_sq.mul_(beta2).addcmul_(grads, grads, value=1 - beta2)
    torch.sqrt(exp_avg_sq, out=denom).div_(bias_correction2_sqrt).add_(eps)
    torch.mul(exp_avg, step_size, out=numer)
    params.addcdiv_(numer, denom)  # torch: params + (-step_size * exp_avg) / denom


@dataclass(frozen=True)
class StackedBatch:
    """K minibatches of B transitions, member k's in row k: ReplayBatch's fields with a leading K."""

    grids: torch.Tensor
    features: torch.Tensor
    actions: torch.Tensor
    rewards: torch.Tensor
    next_grids: torch.Tensor
    next_features: torch.Tensor
    dones: torch.Tensor
    next_mask: torch.Tensor
    alphas: torch.Tensor | None = None


def stack_batches(batches: Sequence[ReplayBatch | None]) -> tuple[StackedBatch, torch.Tensor]:
    """One StackedBatch of a group's minibatches and the members that take part (bool (K,)); a member's None (it
    does not learn in this step) becomes a neutral filler of the others' shape: zeros, terminal, every action open."""
    template = next((b for b in batches if b is not None), None)
    if template is None:
        raise ValueError("a stacked step needs at least one member's minibatch")
    zeros: dict[str, Any] = {name: None if t is None else torch.zeros_like(t) for name, t in vars(template).items()}
    filler = ReplayBatch(**zeros)
    filler.dones.fill_(1.0)
    filler.next_mask.fill_(True)
    rows = [filler if b is None else b for b in batches]
    stacked: dict[str, Any] = {name: None if t is None else torch.stack([getattr(b, name) for b in rows])
                               for name, t in vars(template).items()}  # fmt: skip
    return StackedBatch(**stacked), torch.tensor([b is not None for b in batches])


class StackedLearner:
    """The online and target networks, the optimiser state and the step counts of K members of one DQNConfig."""

    def __init__(self, cfg: DQNConfig, onlines: Sequence[Mapping[str, torch.Tensor]]) -> None:
        """K = len(onlines) members from QNetwork state dicts; each target starts as its online network, each
        optimiser fresh (set_member loads a member's own)."""
        if cfg.optimizer not in ("adam", "sgd"):
            raise ValueError(f"unknown optimizer {cfg.optimizer!r}, expected 'adam' or 'sgd'")
        if not onlines:
            raise ValueError("a stacked learner needs at least one member")
        self.cfg = cfg
        self.k = k = len(onlines)
        self._net = QNetwork(cfg.speed_scale_mps, cfg.dueling, cfg.observation, cfg.alpha_conditioned)
        self.layout = Layout.of(self._net)
        width = self.layout.width
        self._weights = torch.zeros(2 * k, width)  # online rows, then target rows
        self._grads = torch.zeros(k, width)
        self._exp_avg = torch.zeros(k, width) if cfg.optimizer == "adam" else None
        self._exp_avg_sq = torch.zeros(k, width) if cfg.optimizer == "adam" else None
        self._scratch = torch.zeros(2, k, width) if cfg.optimizer == "adam" else None
        self.steps = [0] * k  # the optimiser steps each member has taken
        self._online = self.layout.views(self._weights[:k])
        for name, param in self._online.items():  # leaves whose gradients accumulate into _grads' rows
            param.requires_grad_()
            param.grad = self.layout.views(self._grads)[name]
        self._both = self.layout.views(self._weights)  # online then target networks, for the next states
        for i, online in enumerate(onlines):
            self.set_member(i, online)

    @property
    def online(self) -> torch.Tensor:
        """The online weights, (K, width): row k is member k's (Layout)."""
        return self._weights[: self.k]

    @property
    def target(self) -> torch.Tensor:
        """The target networks' weights, (K, width)."""
        return self._weights[self.k :]

    def q_values(self, grids: torch.Tensor, features: torch.Tensor, alphas: torch.Tensor | None = None,
                 target: bool = False) -> torch.Tensor:  # fmt: skip
        """Q-values (K, B, 4) of every member's online (or target) network on its own rows of the inputs."""
        with torch.no_grad():
            w = self.layout.views(self.target if target else self.online)
            return stacked_q_values(w, grids, features, alphas, self.cfg.speed_scale_mps, self.cfg.dueling)

    def learn(self, batch: StackedBatch, active: torch.Tensor | None = None) -> torch.Tensor:
        """One gradient update of each member where active (bool (K,); None: all) on its own minibatch (row k of
        batch), as agents/dqn.learn updates a Learner's network; the other members' weights, optimiser state, step
        counts are left as they are, and no member's result depends on another's rows.
        Returns each member's loss before the step, (K,) (an inactive member's means nothing)."""
        rows = self._rows(active)
        losses = self._backward(batch)
        with torch.no_grad():
            self._clip()
            if rows is not None and len(rows) == 0:
                return losses
            self._optimizer_step(rows)
        return losses

    def sync_target(self, members: torch.Tensor | None = None) -> None:
        """Copy the online weights into the target network of each member where members (bool (K,); None: all)."""
        rows = self._rows(members)
        with torch.no_grad():
            _put(self.target, rows, _take(self.online, rows))

    def _rows(self, members: torch.Tensor | None) -> torch.Tensor | None:
        """The indices of a bool member mask (K,), or None for all members."""
        if members is None:
            return None
        if members.dtype != torch.bool or members.shape != (self.k,):
            raise ValueError(f"a member mask is bool of shape ({self.k},), got {members.dtype} {tuple(members.shape)}")
        return None if bool(members.all()) else members.nonzero().squeeze(1)

    def _backward(self, batch: StackedBatch) -> torch.Tensor:
        """Every member's gradient of its own TD loss (dqn.dqn_update's) into the gradient rows; the losses (K,)."""
        cfg = self.cfg
        self._grads.zero_()
        q = stacked_q_values(self._online, batch.grids, batch.features, batch.alphas, cfg.speed_scale_mps,
                             cfg.dueling).gather(2, batch.actions.unsqueeze(2)).squeeze(2)  # fmt: skip
        td_target = self._td_targets(batch)
        if cfg.loss == "huber":
            losses = nn.functional.smooth_l1_loss(q, td_target, reduction="none").mean(dim=1)
        else:
            losses = ((td_target - q) ** 2).mean(dim=1)
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=_LAYOUT_WARNING)
            losses.sum().backward()  # d(sum)/d(loss k) = 1: member k's gradient is its own loss's
        return losses.detach()

    def _td_targets(self, batch: StackedBatch) -> torch.Tensor:
        """dqn.td_targets for every member, (K, B); double DQN: the online and target networks in one pass."""
        cfg, k = self.cfg, self.k
        gamma = cfg.gamma
        with torch.no_grad():
            if cfg.double_dqn:
                patches = conv_patches(batch.next_grids)
                alphas = None if batch.alphas is None else torch.cat([batch.alphas, batch.alphas])
                both = q_from_patches(self._both, torch.cat([patches, patches]),
                                      torch.cat([batch.next_features, batch.next_features]), alphas,
                                      cfg.speed_scale_mps, cfg.dueling)  # fmt: skip
                both = both.masked_fill(~torch.cat([batch.next_mask, batch.next_mask]), -torch.inf)
                chooser, next_q = both[:k], both[k:]
                next_v = next_q.gather(2, chooser.argmax(dim=2, keepdim=True)).squeeze(2)
            else:
                next_q = stacked_q_values(self.layout.views(self.target), batch.next_grids, batch.next_features,
                                          batch.alphas, cfg.speed_scale_mps, cfg.dueling)  # fmt: skip
                next_v = next_q.masked_fill(~batch.next_mask, -torch.inf).max(dim=2).values
            return batch.rewards + gamma * (1.0 - batch.dones) * next_v

    def _clip(self) -> None:
        """nn.utils.clip_grad_norm_ per member: its gradient scaled by min(1, max norm / (its norm + 1e-6))."""
        norms = torch.linalg.vector_norm(self._grads, dim=1)
        coef = torch.clamp(self.cfg.grad_clip_norm / (norms + 1e-6), max=1.0)
        self._grads.mul_(coef.unsqueeze(1))

    def _optimizer_step(self, rows: torch.Tensor | None) -> None:
        """Adam (each member at its own step count) or plain SGD on the rows taking part."""
        members = range(self.k) if rows is None else rows.tolist()
        for i in members:
            self.steps[i] += 1
        params, grads = _take(self.online, rows), _take(self._grads, rows)
        if self._exp_avg is None or self._exp_avg_sq is None:
            params.add_(grads, alpha=-self.cfg.lr)  # torch.optim.SGD without momentum
        else:
            exp_avg, exp_avg_sq = _take(self._exp_avg, rows), _take(self._exp_avg_sq, rows)
            adam_step(params, grads, exp_avg, exp_avg_sq, [self.steps[i] for i in members], self.cfg.lr, self._scratch)
            _put(self._exp_avg, rows, exp_avg)
            _put(self._exp_avg_sq, rows, exp_avg_sq)
        _put(self.online, rows, params)

    # -- one member in Learner's formats ---------------------------------------------------------------------------

    def _member(self, buffer: torch.Tensor, k: int) -> dict[str, torch.Tensor]:
        """Row k of a (K, width) buffer as a QNetwork state dict."""
        views = self.layout.views(buffer[k : k + 1])
        return network_weights({name: v[0] for name, v in views.items()}, self.cfg.dueling)

    def _set_row(self, buffer: torch.Tensor, k: int, state: Mapping[str, torch.Tensor]) -> None:
        """Write a QNetwork-shaped state dict into row k of a (K, width) buffer."""
        self._net.load_state_dict(state)  # checks its names and shapes
        views = self.layout.views(buffer[k : k + 1])
        with torch.no_grad():
            for name, t in stacked_weights(state).items():
                views[name][0].copy_(t)

    def online_state(self, k: int) -> dict[str, torch.Tensor]:
        """Member k's online network as a QNetwork state dict (member_state's "online", without the rest)."""
        return self._member(self.online, k)

    def member_state(self, k: int) -> dict[str, Any]:
        """Member k as a Learner keeps it: "online" and "target" QNetwork state dicts, "optimizer" the state dict of
        dqn.make_optimizer's optimiser over QNetwork's parameters."""
        return {"online": self._member(self.online, k), "target": self._member(self.target, k),
                "optimizer": self._optimizer_state(k)}

    def set_member(self, k: int, online: Mapping[str, torch.Tensor], target: Mapping[str, torch.Tensor] | None = None,
                   optimizer: Mapping[str, Any] | None = None) -> None:  # fmt: skip
        """Load member k from Learner's formats (member_state's); target None: the online weights; optimizer None: a
        fresh one (no step taken)."""
        self._set_row(self.online, k, online)
        self._set_row(self.target, k, online if target is None else target)
        self._load_optimizer(k, {"state": {}} if optimizer is None else optimizer)

    def _optimizer_state(self, k: int) -> dict[str, Any]:
        template = make_optimizer(self._net, self.cfg).state_dict()
        state: dict[int, Any] = {}  # torch's: parameter index -> its state
        if self._exp_avg is not None and self._exp_avg_sq is not None and self.steps[k] > 0:
            exp_avg, exp_avg_sq = self._member(self._exp_avg, k), self._member(self._exp_avg_sq, k)
            state = {i: {"step": torch.tensor(float(self.steps[k])), "exp_avg": exp_avg[name],
                         "exp_avg_sq": exp_avg_sq[name]} for i, name in enumerate(exp_avg)}  # fmt: skip
        return {"state": state, "param_groups": copy.deepcopy(template["param_groups"])}

    def _load_optimizer(self, k: int, optimizer: Mapping[str, Any]) -> None:
        groups = optimizer.get("param_groups")
        if groups is not None and any(g["lr"] != self.cfg.lr for g in groups):
            raise ValueError(f"the optimiser state has another learning rate than {self.cfg.lr}")
        entries = optimizer["state"]
        if self._exp_avg is None or self._exp_avg_sq is None or not entries:
            self.steps[k] = 0
            for buffer in (self._exp_avg, self._exp_avg_sq):
                if buffer is not None:
                    buffer[k].zero_()
            return
        names = list(self._net.state_dict())
        steps = {float(e["step"]) for e in entries.values()}
        if sorted(entries) != list(range(len(names))) or len(steps) != 1:
            raise ValueError("an Adam state of a QNetwork holds every parameter at one step count")
        self.steps[k] = int(steps.pop())
        for buffer, key in ((self._exp_avg, "exp_avg"), (self._exp_avg_sq, "exp_avg_sq")):
            self._set_row(buffer, k, {name: entries[i][key] for i, name in enumerate(names)})

    # -- checkpoints -----------------------------------------------------------------------------------------------

    def state_dict(self) -> dict[str, Any]:
        """Everything a continued training needs (copies; torch.load(weights_only=True) reads it back)."""
        state: dict[str, Any] = {"width": self.layout.width, "weights": self._weights.clone(),
                                 "steps": torch.tensor(self.steps, dtype=torch.int64)}  # fmt: skip
        for name in ("exp_avg", "exp_avg_sq"):
            if (buffer := getattr(self, f"_{name}")) is not None:
                state[name] = buffer.clone()
        return state

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore state_dict()'s snapshot of a group of the same K and configuration."""
        if state["width"] != self.layout.width or tuple(state["weights"].shape) != tuple(self._weights.shape):
            raise ValueError(f"the state is of another group or network: weights {tuple(state['weights'].shape)}, "
                             f"this learner's {tuple(self._weights.shape)}")  # fmt: skip
        with torch.no_grad():
            self._weights.copy_(state["weights"])
            for name in ("exp_avg", "exp_avg_sq"):
                if (buffer := getattr(self, f"_{name}")) is not None:
                    if name not in state:
                        raise ValueError(f"the state has no {name}, which this learner keeps")
                    buffer.copy_(state[name])
        self.steps = [int(s) for s in state["steps"]]


def _take(buffer: torch.Tensor, rows: torch.Tensor | None) -> torch.Tensor:
    """buffer itself (rows None: every member), else a copy of the given rows."""
    return buffer if rows is None else buffer.index_select(0, rows)


def _put(buffer: torch.Tensor, rows: torch.Tensor | None, values: torch.Tensor) -> None:
    """Write _take's rows back (nothing to do when they are buffer itself)."""
    if rows is not None:
        buffer.index_copy_(0, rows, values)
    elif values.data_ptr() != buffer.data_ptr():
        buffer.copy_(values)
