"""The lane-changing DQN (paper section II.B, Table II): network, replay memory, update, learner.

Pure torch + numpy. Observations arrive as numpy arrays for a batch of vehicles:
grids (N, 3, 3, 20) = 3 frames x 3 lanes x 20 cells of 1 m, 0/1 occupancy;
features (N, F) = actual minus expected speed for the same 3 frames (m/s), then, for the 'v2x'
observation, the v2x features (sim/observation.network_features; F = observation.n_features);
an alpha-conditioned network also reads each vehicle's alpha (N,), the lane-change penalty it drives with.
"""

from __future__ import annotations

import copy
import inspect
import math
from typing import Any, Protocol

import numpy as np
import torch
from torch import nn

from coopsumo.agents.conditioning import conditioned_alphas
from coopsumo.agents.replay import GRID_SHAPE, N_ACTIONS, ReplayBatch, ReplayBuffer
from coopsumo.config import PAPER_ALPHAS
from coopsumo.dqn_config import DQNConfig
from coopsumo.sim.observation import n_features

_CONV_OUT = 32 * 1 * 5
"""features after the two convolutions: 32 filters x 1 row x 5 columns"""


ALPHA_INPUT_SCALE = math.log1p(max(PAPER_ALPHAS))
"""log(1 + alpha) is divided by this (log 49) before entering a conditioned network: the paper's grid spans 0-1"""


def alpha_input(alpha: torch.Tensor) -> torch.Tensor:
    """The network's alpha input: log(1 + alpha) / log(49), 0 at alpha 0 and 1 at the paper's largest, 48."""
    return torch.log1p(alpha) / ALPHA_INPUT_SCALE


def seed_torch(seed: int) -> None:
    """Seed torch's global RNG."""
    torch.manual_seed(seed)


class QNetwork(nn.Module):
    """Table II: two 2x2 convolutions (stride (1, 2)), concat the 3 speed errors, FC 500, FC 100, 4 Q-values.

    dueling: the last layer is split into a state value and action advantages,
    Q = V + A - mean(A) (Wang et al. 2016); not in the paper.
    observation 'v2x': the v2x features are concatenated beside the speed errors (not in the paper).
    conditioned: alpha (alpha_input) is concatenated there too, and forward needs it (not in the paper).
    """

    def __init__(
        self, speed_scale_mps: float, dueling: bool = False, observation: str = "paper", conditioned: bool = False
    ) -> None:
        super().__init__()
        if not speed_scale_mps > 0:
            raise ValueError(f"speed_scale_mps must be positive, got {speed_scale_mps}")
        self.speed_scale_mps = float(speed_scale_mps)  # m/s; speed errors are divided by this
        self.dueling = bool(dueling)
        self.observation = observation
        self.n_features = n_features(observation)
        self.conditioned = bool(conditioned)
        self.conv1 = nn.Conv2d(GRID_SHAPE[0], 16, kernel_size=(2, 2), stride=(1, 2))
        self.conv2 = nn.Conv2d(16, 32, kernel_size=(2, 2), stride=(1, 2))
        self.fc1 = nn.Linear(_CONV_OUT + self.n_features + int(self.conditioned), 500)
        self.fc2 = nn.Linear(500, 100)
        self.out = nn.Linear(100, N_ACTIONS)
        if self.dueling:
            self.value = nn.Linear(100, 1)

    def forward(self, grids: torch.Tensor, features: torch.Tensor, alpha: torch.Tensor | None = None) -> torch.Tensor:
        """Q-values (B, 4) from grids (B, 3, 3, 20) and features (B, n_features): speed errors (m/s) first;
        alpha (B,): the lane-change penalty each row drives with, for a conditioned network only."""
        if self.conditioned != (alpha is not None):
            raise ValueError("an alpha-conditioned network needs alpha, another network takes none")
        x = torch.relu(self.conv1(grids))
        x = torch.relu(self.conv2(x))
        speed_err = features[:, : GRID_SHAPE[0]] / self.speed_scale_mps
        parts = [x.flatten(start_dim=1), speed_err, features[:, GRID_SHAPE[0] :]]
        if alpha is not None:
            parts.append(alpha_input(alpha.reshape(-1, 1).to(speed_err.dtype)))
        x = torch.cat(parts, dim=1)
        x = torch.relu(self.fc1(x))
        x = torch.relu(self.fc2(x))
        if self.dueling:
            adv = self.out(x)
            return self.value(x) + adv - adv.mean(dim=1, keepdim=True)
        return self.out(x)


def q_values(net: nn.Module, grids: torch.Tensor, features: torch.Tensor, alphas: torch.Tensor | None) -> torch.Tensor:
    """net's Q-values; alphas passed only to a conditioned network (None: a network of one alpha)."""
    return net(grids, features) if alphas is None else net(grids, features, alphas)


def epsilon_at(env_steps: int, cfg: DQNConfig) -> float:
    """Exploration probability after env_steps: linear from epsilon_start to epsilon_end, then constant."""
    if cfg.epsilon_decay_steps <= 0:
        return cfg.epsilon_start
    frac = min(env_steps / cfg.epsilon_decay_steps, 1.0)
    return cfg.epsilon_start + frac * (cfg.epsilon_end - cfg.epsilon_start)


def epsilon_greedy(
    q_values: np.ndarray, epsilon: float, rng: np.random.Generator, mask: np.ndarray | None = None
) -> np.ndarray:
    """One int64 action per row of q_values (N, A): the best feasible action with probability 1 - epsilon,
    else one drawn uniformly among the feasible ones. mask (N, A) bool: feasible actions (None: all)."""
    n, n_actions = q_values.shape
    if mask is None:
        greedy = np.argmax(q_values, axis=1).astype(np.int64)
        random_actions = rng.integers(0, n_actions, size=n, dtype=np.int64)
    else:
        greedy = np.argmax(np.where(mask, q_values, -np.inf), axis=1).astype(np.int64)
        # the largest of uniform draws over the feasible entries is a uniform choice among them
        random_actions = np.argmax(np.where(mask, rng.random((n, n_actions)), -1.0), axis=1).astype(np.int64)
    take_greedy = rng.random(n) < 1.0 - epsilon
    return np.where(take_greedy, greedy, random_actions)


def td_targets(online: QNetwork, target: QNetwork, batch: ReplayBatch, gamma: float, double: bool) -> torch.Tensor:
    """r + gamma (1 - done) Q_target(s', a*) with a* the best next action among the feasible ones.

    Plain DQN: a* maximises the target network; double DQN: a* maximises the online network.
    """
    with torch.no_grad():
        next_q = q_values(target, batch.next_grids, batch.next_features, batch.alphas)
        next_q = next_q.masked_fill(~batch.next_mask, -torch.inf)
        if double:
            chooser = q_values(online, batch.next_grids, batch.next_features, batch.alphas)
            chooser = chooser.masked_fill(~batch.next_mask, -torch.inf)
            best = chooser.argmax(dim=1, keepdim=True)
            next_v = next_q.gather(1, best).squeeze(1)
        else:
            next_v = next_q.max(dim=1).values
        return batch.rewards + gamma * (1.0 - batch.dones) * next_v


def dqn_update(
    online: QNetwork,
    target: QNetwork,
    optimizer: torch.optim.Optimizer,
    batch: ReplayBatch,
    gamma: float,
    grad_clip_norm: float,
    double: bool = False,
    loss_name: str = "mse",
) -> float:
    """One gradient step on the TD error (paper eq. 8: mean squared; or Huber); returns the loss before the step."""
    q = q_values(online, batch.grids, batch.features, batch.alphas).gather(1, batch.actions.unsqueeze(1)).squeeze(1)
    td_target = td_targets(online, target, batch, gamma, double)
    if loss_name == "huber":
        loss = nn.functional.smooth_l1_loss(q, td_target)
    else:
        loss = ((td_target - q) ** 2).mean()
    optimizer.zero_grad()
    loss.backward()
    nn.utils.clip_grad_norm_(online.parameters(), grad_clip_norm)
    optimizer_step(optimizer)
    return float(loss.item())


def optimizer_step(optimizer: torch.optim.Optimizer) -> None:
    """optimizer.step() without its wrappers: torch's step first imports torch._dynamo (1.8 s of CPU per process)
    to tell eager code from compiled; this project runs eagerly only. The same arithmetic, grad off as torch's
    wrapper sets it (differentiable=False); torch is pinned (2.13)."""
    with torch.no_grad():
        inspect.unwrap(type(optimizer).step)(optimizer)


def _no_dynamo_import() -> None:
    """Fill the cache of torch's Optimizer methods that would import torch._dynamo on their first call (construction,
    zero_grad, state_dict, load_state_dict) with the plain methods, which is what that import gives when nothing is
    compiled."""
    for name in ("zero_grad", "add_param_group", "state_dict", "load_state_dict"):
        plain = inspect.unwrap(getattr(torch.optim.Optimizer, name))
        setattr(plain, "__dynamo_disable", plain)


def sync_target(online: nn.Module, target: nn.Module) -> None:
    """Copy the online network's weights into the target network."""
    target.load_state_dict(online.state_dict())


def learn(online: QNetwork, target: QNetwork, optimizer: torch.optim.Optimizer, batch: ReplayBatch,
          cfg: DQNConfig) -> float:  # fmt: skip
    """One gradient update of online with cfg's settings; returns the loss."""
    return dqn_update(online, target, optimizer, batch, cfg.gamma, cfg.grad_clip_norm, cfg.double_dqn, cfg.loss)


def make_optimizer(net: nn.Module, cfg: DQNConfig) -> torch.optim.Optimizer:
    """Adam or SGD on net's parameters with cfg.lr (step it with optimizer_step)."""
    _no_dynamo_import()
    if cfg.optimizer == "adam":
        return torch.optim.Adam(net.parameters(), lr=cfg.lr)
    if cfg.optimizer == "sgd":
        return torch.optim.SGD(net.parameters(), lr=cfg.lr)
    raise ValueError(f"unknown optimizer {cfg.optimizer!r}, expected 'adam' or 'sgd'")


class UpdateWorkerLike(Protocol):
    """What Learner needs of an update worker (agents/update_worker.UpdateWorker)."""

    losses: list[float]

    def submit(self, batches: list[ReplayBatch]) -> None: ...
    def sync(self) -> None: ...
    def wait(self) -> None: ...
    def state(self) -> dict[str, Any]: ...
    def close(self) -> None: ...


class Learner:
    """Online and target networks, optimizer, replay memory and RNG, advanced once per environment step.

    The gradient updates run here, or in an attached worker (attach), with the same result bit for bit."""

    def __init__(self, cfg: DQNConfig, seed: int) -> None:
        self.cfg = cfg
        self.worker: UpdateWorkerLike | None = None  # set by attach(): the updates run there
        # The initial weights depend on the seed only; torch's global RNG is left as it was.
        with torch.random.fork_rng(devices=[]):
            seed_torch(seed)
            self.online = QNetwork(cfg.speed_scale_mps, cfg.dueling, cfg.observation, cfg.alpha_conditioned)
            self.target = QNetwork(cfg.speed_scale_mps, cfg.dueling, cfg.observation, cfg.alpha_conditioned)
        sync_target(self.online, self.target)
        self.optimizer = make_optimizer(self.online, cfg)
        self.buffer = ReplayBuffer(cfg.replay_size, self.online.n_features, cfg.alpha_conditioned)
        self._alphas = conditioned_alphas(cfg)
        # A stream distinct from np.random.default_rng(seed), which the caller may use elsewhere.
        self.rng = np.random.default_rng([seed, 0x44514E])
        self.env_steps = 0  # environment steps seen by step()
        self.decisions = 0  # decision rounds seen by step()
        self.updates = 0  # gradient updates done (sent, with a worker)
        self._losses: list[float] = []  # mean loss of each finished round not yet taken (take_losses)

    @property
    def online(self) -> QNetwork:
        """The online network, with every update sent to a worker applied."""
        if self.worker is not None:
            self.worker.wait()
        return self._online

    @online.setter
    def online(self, net: QNetwork) -> None:
        self._online = net

    def attach(self, worker: UpdateWorkerLike) -> None:
        """Run the updates in `worker` (agents/update_worker.py) from now on; detach() takes them back."""
        self.worker = worker

    def detach(self) -> None:
        """Take the updates back into this process: the worker's target network and optimiser state are loaded
        here, its unread losses kept, and it is closed."""
        worker = self.worker
        if worker is None:
            return
        state = worker.state()
        self._losses.extend(worker.losses)
        worker.losses.clear()
        self.worker = None
        worker.close()
        self.target.load_state_dict(state["target"])
        self.optimizer.load_state_dict(state["optimizer"])

    def wait(self) -> None:
        """Block until every update sent to a worker is applied (nothing to do without one)."""
        if self.worker is not None:
            self.worker.wait()

    def take_losses(self) -> list[float]:
        """The mean loss of each update round finished since the last call, in order (a worker's rounds still
        running are not waited for)."""
        if self.worker is not None:
            self._losses.extend(self.worker.losses)
            self.worker.losses.clear()
        taken, self._losses = self._losses, []
        return taken

    @property
    def epsilon(self) -> float:
        return epsilon_at(self.env_steps, self.cfg)

    def act(
        self,
        grids: np.ndarray,
        features: np.ndarray,
        explore: bool,
        mask: np.ndarray | None = None,
        alphas: np.ndarray | None = None,
    ) -> np.ndarray:
        """int64 actions (N,) for grids (N, 3, 3, 20) and features (N, F); epsilon-greedy if explore.

        mask (N, 4) bool: the feasible actions; only those are chosen (None: all actions);
        alphas (N,): each vehicle's alpha, for a conditioned network.
        """
        if len(grids) == 0:
            return np.zeros(0, dtype=np.int64)
        with torch.no_grad():
            q = q_values(
                self.online,
                torch.as_tensor(grids, dtype=torch.float32),
                torch.as_tensor(features, dtype=torch.float32),
                None if alphas is None else torch.as_tensor(alphas, dtype=torch.float32),
            ).numpy()
        if explore:
            return epsilon_greedy(q, self.epsilon, self.rng, mask)
        if mask is not None:
            q = np.where(mask, q, -np.inf)
        return np.argmax(q, axis=1).astype(np.int64)

    def observe(
        self,
        grids: np.ndarray,
        features: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_grids: np.ndarray,
        next_features: np.ndarray,
        dones: np.ndarray,
        next_mask: np.ndarray | None = None,
        alphas: np.ndarray | None = None,
        lane_changes: np.ndarray | None = None,
    ) -> None:
        """Store N transitions in the replay memory (next_mask: feasible next actions, None: all; alphas and
        lane changes started: a conditioned learner's)."""
        self.buffer.add_batch(grids, features, actions, rewards, next_grids, next_features, dones, next_mask,
                              alphas, lane_changes)  # fmt: skip

    def step(self, decided: bool = True) -> float | None:
        """Advance one environment step; on a decision round (decided) maybe learn; maybe sync the target.

        Learning: updates_per_learn gradient updates every learn_every decision rounds, once the
        buffer holds a batch and learn_start_steps have passed; their minibatches are drawn here in either case.
        Returns the mean loss, or None (no update, or the updates were sent to a worker: take_losses).
        """
        cfg = self.cfg
        self.env_steps += 1
        losses = []
        if decided:
            self.decisions += 1
            if (
                len(self.buffer) >= cfg.batch_size
                and self.env_steps >= cfg.learn_start_steps
                and self.decisions % cfg.learn_every == 0
            ):
                batches = [self.buffer.sample(cfg.batch_size, self.rng, cfg.alpha_relabel, self._alphas)
                           for _ in range(cfg.updates_per_learn)]  # fmt: skip
                self.updates += len(batches)
                if self.worker is not None:
                    self.worker.submit(batches)
                else:
                    losses = [learn(self._online, self.target, self.optimizer, b, cfg) for b in batches]
        if self.env_steps % cfg.target_sync_steps == 0:
            if self.worker is not None:
                self.worker.sync()
            else:
                sync_target(self._online, self.target)
        if not losses:
            return None
        self._losses.append(float(np.mean(losses)))
        return self._losses[-1]

    def state_dict(self) -> dict[str, Any]:
        """A snapshot (copies) of everything needed for an exact resume; loads with torch.load(weights_only=True)."""
        remote = self.worker.state() if self.worker is not None else None  # after every round sent
        state: dict[str, Any] = {
            "online": copy.deepcopy(self.online.state_dict()),
            "target": copy.deepcopy(remote["target"] if remote else self.target.state_dict()),
            "optimizer": copy.deepcopy(remote["optimizer"] if remote else self.optimizer.state_dict()),
            "buffer": self.buffer.state_dict(),
            "numpy_rng": copy.deepcopy(self.rng.bit_generator.state),
            "torch_rng": torch.get_rng_state(),
            "env_steps": self.env_steps,
            "decisions": self.decisions,
            "updates": self.updates,
        }
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a snapshot from state_dict(), including torch's global RNG state (not while a worker is
        attached)."""
        if self.worker is not None:
            raise RuntimeError("load a learner's state before attaching a worker")
        self.online.load_state_dict(state["online"])
        self.target.load_state_dict(state["target"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.buffer.load_state_dict(state["buffer"])
        self.rng.bit_generator.state = copy.deepcopy(state["numpy_rng"])
        torch.set_rng_state(state["torch_rng"])
        self.env_steps = int(state["env_steps"])
        self.decisions = int(state["decisions"])
        self.updates = int(state["updates"])
