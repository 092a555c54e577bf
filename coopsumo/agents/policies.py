"""Decision-makers: a batch of observations in, one action per vehicle out.

Every policy goes through the same controller (Newell + collision check + lane-change safety),
so they are compared on equal terms. Actions: 0 left, 1 right, 2 speedup, 3 none (sim.physics). Beside the
built-in ones: a class of the user's own (py:MODULE:CLASS, agents/user_policy.py) and a Stable-Baselines3 model
(sb3:PATH, agents/sb3_policy.py); docs/extending.md.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from coopsumo.config import POLICY_STREAM, ControlConfig, SimConfig, rng_stream
from coopsumo.policy_spec import LC_KEYS, PolicySpecError, parse_policy, sumo_lc_params
from coopsumo.sim.observation import Observation
from coopsumo.sim.physics import LEFT, RIGHT, SPEEDUP

__all__ = ["PolicySpecError", "Policy", "KeepPolicy", "RandomPolicy", "GreedyPolicy", "SumoPolicy", "make_policy",
           "policy_for_run"]


class Policy(Protocol):
    name: str
    needs_grids: bool  # False: the world may skip building occupancy grids (obs.grids are zeros)
    decision_interval: int  # act() is called every this many steps; actions are held between (decisions.py)

    def act(self, obs: Observation) -> np.ndarray:
        """One action (int64) per vehicle of the batch."""
        ...


class KeepPolicy:
    """Never changes lane; always asks to speed up (the controller caps it)."""

    name = "keep"
    needs_grids = False
    decision_interval = 1

    def act(self, obs: Observation) -> np.ndarray:
        return np.full(len(obs), SPEEDUP, dtype=np.int64)


class RandomPolicy:
    """Uniformly random actions; the safety layer must still keep everyone apart."""

    name = "random"
    needs_grids = False
    decision_interval = 1

    def __init__(self, rng: np.random.Generator):
        self.rng = rng

    def act(self, obs: Observation) -> np.ndarray:
        return self.rng.integers(0, 4, size=len(obs)).astype(np.int64)


class GreedyPolicy:
    """Selfish rule: when the car ahead holds it back, move to the adjacent lane with clearly more room.

    "Held back": own gap below `look_m` and speed below v_exp - `slack_mps`. "Clearly more room":
    the adjacent lane's gap ahead exceeds the own gap by `margin_m`. Otherwise speed up.
    """

    name = "greedy"
    needs_grids = False
    decision_interval = 1

    def __init__(self, look_m: float = 60.0, margin_m: float = 20.0, slack_mps: float = 1.0):
        self.look_m = look_m
        self.margin_m = margin_m
        self.slack_mps = slack_mps

    def act(self, obs: Observation) -> np.ndarray:
        gaps = np.where(obs.around.exists, obs.around.lead_gap, -np.inf)  # (n, 3): left, own, right
        own = gaps[:, 1]
        held = (own < self.look_m) & (obs.speed < obs.v_exp - self.slack_mps)
        left_better = gaps[:, 0] > own + self.margin_m
        right_better = gaps[:, 2] > own + self.margin_m
        go_left = held & left_better & (~right_better | (gaps[:, 0] >= gaps[:, 2]))
        go_right = held & right_better & ~go_left
        actions = np.full(len(obs), SPEEDUP, dtype=np.int64)
        actions[go_left] = LEFT
        actions[go_right] = RIGHT
        return actions


class SumoPolicy:
    """SUMO's own models in charge: its car-following (Krauss) and LC2013 lane changing.

    The Newell controller is NOT used for this policy: the world leaves speed and lane-change modes
    at SUMO's defaults and only reads the vehicles. `lc_params` are LC2013 parameters
    (lcCooperative, lcSpeedGain, ...) set on every vehicle.
    """

    name = "sumo"
    needs_grids = False
    decision_interval = 1
    LC_KEYS = LC_KEYS

    def __init__(self, lc_params: dict[str, float] | None = None):
        self.lc_params = dict(lc_params or {})

    @classmethod
    def from_spec(cls, spec: str) -> SumoPolicy:
        """Parse `sumo` or `sumo:lcCooperative=0.5,lcSpeedGain=1` (coopsumo.policy_spec)."""
        return cls(sumo_lc_params(spec))

    def act(self, obs: Observation) -> np.ndarray:
        return np.full(len(obs), SPEEDUP, dtype=np.int64)  # ignored: SUMO decides


def make_policy(spec: str, rng: np.random.Generator, control: ControlConfig | None = None, lanes: int = 3) -> Policy:
    """Build a policy from its command-line spec: keep, random, greedy, dqn:PATH[,alpha=A|adaptive],
    mobil[:p=P,...], sumo, py:MODULE:CLASS, sb3:PATH.

    `control` is the run's controller configuration (MOBIL derives its accelerations from it); `lanes` the road's
    lane count (an adaptive alpha's rule depends on it).
    """
    name = parse_policy(spec).name  # policy_spec: a malformed string fails here, whatever the policy
    if name == "keep":
        return KeepPolicy()
    if name == "random":
        return RandomPolicy(rng)
    if name == "greedy":
        return GreedyPolicy()
    if name == "dqn":
        from coopsumo.agents.dqn_policy import DQNPolicy  # torch only when a DQN is asked for

        return DQNPolicy.from_spec(spec, lanes)
    if name == "mobil":
        from coopsumo.agents.mobil import MobilPolicy

        return MobilPolicy.from_spec(spec, control)
    if name == "py":
        from coopsumo.agents.user_policy import UserPolicy

        return UserPolicy.from_spec(spec, rng)
    if name == "sb3":
        from coopsumo.agents.sb3_policy import SB3Policy  # stable_baselines3 only when such a model is asked for

        return SB3Policy.from_spec(spec)
    return SumoPolicy.from_spec(spec)


def policy_for_run(cfg: SimConfig) -> Policy:
    """The policy of a run, built once from its configuration: cfg.policy's spec, the run's policy stream of its
    seed (rng_stream(seed, POLICY_STREAM)) and the run's controller configuration (MOBIL's accelerations)."""
    return make_policy(cfg.policy, rng_stream(cfg.seed, POLICY_STREAM), cfg.control, cfg.road.lanes)
