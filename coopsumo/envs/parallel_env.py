"""PettingZoo ParallelEnv: every vehicle on the road is an agent.

Agent names are "veh_<number>" (coopsumo's vehicle numbers, in order of scheduled departure).
An agent appears in the step after SUMO inserts its vehicle and disappears (terminated) when the
vehicle leaves the road; its last observation is repeated then. After `max_steps` simulation
steps (counted from the World's start, the steps reset() takes included) every remaining agent
is truncated. `possible_agents` is every vehicle scheduled to depart within max_steps:
veh_0 ... veh_K with K = floor(max_steps * dt / T_up), a finite superset of the agents that can
appear (vehicles whose insertion is delayed beyond the episode never become agents).

Rewards: coopsumo.sim.reward's RewardParts.total for the step the agent acted in (components in
`infos`); an agent appearing in a step gets its first observation and reward 0.0.

The episode ends when `agents` is empty: after truncation, or when the last agents terminated and
no new vehicle appeared in that step (sparse demand can empty the road before max_steps). step() after
the end (or before reset(), after close() or a failed reset()) raises RuntimeError: call reset().

reset() starts a new World (closing the previous one) and steps the empty road until the first
vehicle is on it, so `agents` is empty after reset() only when no vehicle reaches the road within
max_steps (then the episode has already ended). Seeding as in HighwayEnv: reset(seed=s)
runs with SimConfig.seed = s; an unseeded reset draws the seed from the env's generator, which
the last seeded reset re-seeded (or from fresh entropy if there was none).

decision_interval=k (the learner's --decision-interval): one step() is k simulation steps; each
agent's action is held as coopsumo.agents.decisions defines (a lane change is requested on the first
step only, then speed-up) and its rewards are summed over the steps it was on the road; the
occupancy frames are those of the decision steps. Default 1: one 0.1 s step per step().

Spaces per agent are those of coopsumo/Highway-v0: Dict(grids (3, 3, 20) uint8, speed_err (3,)
float32) and Discrete(4).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from coopsumo.agents.decisions import ActionHold
from coopsumo.config import SimConfig
from coopsumo.envs.common import (
    WorldSlot,
    action_space,
    check_action,
    check_episode,
    int_param,
    observation_space,
    run_seed,
    sim_config,
    step_info,
    vehicle_observation,
)
from coopsumo.field_rules import digits
from coopsumo.sim.observation import Observation
from coopsumo.sim.physics import SPEEDUP
from coopsumo.sim.reward import RewardParts
from coopsumo.sim.world import StepOutcome, World

DEFAULT_MAX_STEPS = 3000
AGENT_PREFIX = "veh_"


def agent_name(num: int) -> str:
    return f"{AGENT_PREFIX}{num}"


def agent_num(name: str) -> int:
    if not name.startswith(AGENT_PREFIX) or not digits(name[len(AGENT_PREFIX) :]):
        raise ValueError(f"not an agent name: {name!r}; expected {AGENT_PREFIX}<number>")
    return int(name[len(AGENT_PREFIX) :])


class HighwayParallelEnv(ParallelEnv[str, dict[str, np.ndarray], int]):
    """All vehicles as agents; see the module docstring. cfg's seed, steps and policy are replaced. A bad parameter
    is a ConfigError (a ValueError) naming it and the value passed, as in HighwayEnv."""

    metadata: dict[str, Any] = {"name": "coopsumo_highway_v0", "render_modes": [], "is_parallelizable": True}

    def __init__(
        self, cfg: SimConfig | None = None, *, max_steps: int = DEFAULT_MAX_STEPS, decision_interval: int = 1
    ) -> None:
        # every parameter checked as passed (ConfigError, a ValueError, naming it), as in HighwayEnv
        base = sim_config(cfg)
        max_steps = int_param("max_steps", max_steps, 1)
        decision_interval = int_param("decision_interval", decision_interval, 1)
        self.decision_interval = decision_interval
        self.cfg = dataclasses.replace(base, steps=max_steps, policy="agents")
        self.cfg.validate()
        self.max_steps = max_steps
        last = math.floor(max_steps * self.cfg.control.dt_s / self.cfg.demand.t_up_s + 1e-9)
        self.possible_agents: list[str] = [agent_name(k) for k in range(last + 1)]
        self.agents: list[str] = []
        self.render_mode = None
        self._obs_space = observation_space()
        self._act_space = action_space()
        self.observation_spaces = dict.fromkeys(self.possible_agents, self._obs_space)
        self.action_spaces = dict.fromkeys(self.possible_agents, self._act_space)
        self._slot = WorldSlot()
        self._seed_rng: np.random.Generator | None = None
        self._obs: Observation | None = None
        self._finished: set[int] = set()
        self._last: dict[int, dict[str, np.ndarray]] = {}  # vehicle number -> its last observation
        self._started = False  # an episode was reset (not closed since, its reset did not fail)
        self._done = False  # ... and it ended: no agent left
        self.seed_used = -1
        """SimConfig seed of the current episode"""

    def observation_space(self, agent: str) -> spaces.Space[Any]:
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Space[Any]:
        return self._act_space

    @property
    def world(self) -> World | None:
        return self._slot.world

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, dict[str, Any]]]:
        if seed is None:
            if self._seed_rng is None:
                self._seed_rng = np.random.default_rng()
            self.seed_used = run_seed(None, self._seed_rng)
        else:
            self.seed_used = run_seed(seed, None)  # a bad seed changes nothing (ValueError)
            self._seed_rng = np.random.default_rng(self.seed_used)
        self._started, self._obs, self.agents = False, None, []  # until this reset succeeds
        world = self._slot.open(dataclasses.replace(self.cfg, seed=self.seed_used))
        obs = world.observe()
        while len(obs) == 0 and world.step_count < self.max_steps - 1:
            world.apply(np.zeros(0, np.int64))
            obs = world.observe()
        self._finished = set()
        self._last = {}
        self._set_obs(obs)
        self.agents = [agent_name(n) for n in self._live(obs)]
        observations = {a: self._copy(agent_num(a)) for a in self.agents}
        infos: dict[str, dict[str, Any]] = {a: {"seed": self.seed_used} for a in self.agents}
        self._started, self._done = True, not self.agents
        return observations, infos

    @staticmethod
    def _action_batch(actions: Any, obs: Any, live: set[str]) -> np.ndarray:
        """One action per observed vehicle: a live agent's own (checked), SPEEDUP for the others."""
        if not isinstance(actions, Mapping):
            raise TypeError(f"actions must be a dict of live agent name -> action 0-3, got {type(actions).__name__} "
                            f"{actions!r:.80}")  # fmt: skip
        unknown = set(actions) - live
        missing = live - set(actions)
        if unknown or missing:
            raise ValueError(
                f"actions must cover exactly the live agents; missing {sorted(missing)[:5]}, "
                f"not live {sorted(unknown)[:5]}"
            )
        batch = np.full(len(obs), SPEEDUP, dtype=np.int64)  # vehicles that are not live agents speed up
        for row, num in enumerate(obs.nums.tolist()):
            name = agent_name(num)
            if name in live:
                batch[row] = check_action(actions[name], f"action of {name}")
        return batch

    def step(
        self, actions: dict[str, Any]
    ) -> tuple[
        dict[str, dict[str, np.ndarray]],
        dict[str, float],
        dict[str, bool],
        dict[str, bool],
        dict[str, dict[str, Any]],
    ]:
        check_episode(self._started, self._done)
        world, obs = self._slot.world, self._obs
        assert world is not None and obs is not None
        live = set(self.agents)
        batch = self._action_batch(actions, obs, live)
        out = world.apply(batch)
        if self.decision_interval > 1:
            out = self._hold(world, obs, batch, out)
        next_obs = world.observe()
        truncate = world.step_count >= self.max_steps
        self._set_obs(next_obs)
        present = set(self._live(next_obs))

        observations: dict[str, dict[str, np.ndarray]] = {}
        rewards: dict[str, float] = {}
        terminations: dict[str, bool] = {}
        truncations: dict[str, bool] = {}
        infos: dict[str, dict[str, Any]] = {}
        for row, num in enumerate(out.nums.tolist()):
            name = agent_name(num)
            if name not in live:
                continue
            gone = num not in present
            observations[name] = self._copy(num)
            rewards[name] = float(out.reward.total[row])
            terminations[name] = gone
            truncations[name] = truncate and not gone
            infos[name] = step_info(out, row)
            if gone or truncate:
                self._finished.add(num)
                del self._last[num]
        if not truncate:
            for num in sorted(present - {agent_num(a) for a in live}):
                name = agent_name(num)
                observations[name] = self._copy(num)
                rewards[name] = 0.0
                terminations[name] = truncations[name] = False
                infos[name] = {"vehicle": num, "new": True}
        self.agents = [] if truncate else [agent_name(n) for n in sorted(present)]
        self._done = not self.agents
        return observations, rewards, terminations, truncations, infos

    def close(self) -> None:
        """Close SUMO and remove the run folder; safe to call more than once."""
        self._slot.close()
        self._obs = None
        self.agents = []
        self._started = False

    def _hold(self, world: World, obs: Observation, batch: np.ndarray, first: StepOutcome) -> StepOutcome:
        """Run the rest of a decision interval with the held actions; the first step's outcome with rewards summed.

        Vehicles of `obs` that leave during the interval are marked arrived; reward components are summed
        over the steps each vehicle was on the road.
        """
        hold = ActionHold(self.decision_interval)
        hold.actions(obs.nums, batch)
        speed, lane_change, flow = (x.copy() for x in (first.reward.speed, first.reward.lane_change,
                                                        first.reward.flow))  # fmt: skip
        arrived = first.arrived.copy()
        q_t = first.q_t
        for _ in range(self.decision_interval - 1):
            if world.step_count >= self.max_steps or arrived.all():
                break
            now = world.observe(grids=False)
            out = world.apply(hold.actions(now.nums, None))
            rows = np.searchsorted(obs.nums, out.nums)
            rows_ok = (rows < len(obs.nums)) & (obs.nums[np.minimum(rows, len(obs.nums) - 1)] == out.nums)
            mine, theirs = rows[rows_ok], np.flatnonzero(rows_ok)
            speed[mine] += out.reward.speed[theirs]
            lane_change[mine] += out.reward.lane_change[theirs]
            flow[mine] += out.reward.flow[theirs]
            arrived[mine] |= out.arrived[theirs]
            q_t = out.q_t
        reward = RewardParts(speed, lane_change, flow)
        return dataclasses.replace(first, reward=reward, arrived=arrived, q_t=q_t)

    def _live(self, obs: Observation) -> list[int]:
        """Vehicles of obs that are (or become) agents: on the road and not finished before."""
        nums = [n for n in obs.nums.tolist() if n not in self._finished]
        too_late = [n for n in nums if n >= len(self.possible_agents)]
        if too_late:  # cannot happen: a vehicle on the road was scheduled before now
            raise RuntimeError(f"vehicle {too_late[0]} is not among possible_agents")
        return nums

    def _set_obs(self, obs: Observation) -> None:
        self._obs = obs
        for row, num in enumerate(obs.nums.tolist()):
            self._last[num] = vehicle_observation(obs, row)

    def _copy(self, num: int) -> dict[str, np.ndarray]:
        return {k: v.copy() for k, v in self._last[num].items()}
