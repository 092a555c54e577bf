"""Gymnasium environment `coopsumo/Highway-v0`: one studied vehicle in the SUMO highway.

The episode (reset):
  1. a new World (SUMO) with SimConfig.seed = the reset seed; the previous World is closed first;
  2. `warmup_steps` steps with every vehicle driven by the background policy;
  3. the agent is the first vehicle scheduled to depart at or after the end of the warm-up
     (the smallest number k with k * T_up >= warmup_steps * dt; vehicle 0 without warm-up); the
     background keeps driving until it is on the road (it appears in observe() the step after
     SUMO inserts it, later if its insertion is blocked).

Each step: the background policy acts for every vehicle, the agent's action replaces its own,
World.apply() runs one 0.1 s step, and the reward is coopsumo.sim.reward's RewardParts.total for
the agent (components in `info`). With decision_interval=k (the learner's --decision-interval),
one env step is k steps of 0.1 s: the action is held as coopsumo.agents.decisions defines (a lane
change is requested once, then speed-up), the rewards are summed, the occupancy frames are those
of the decision steps, and the agent decides only on steps with step_count % k == 0.
Terminated when the agent leaves the road (the last
observation is repeated); truncated after `max_steps` agent steps. step() after the end (or before
reset(), after close() or a failed reset()) raises RuntimeError: call reset().

Spaces: observation Dict(grids: Box(0, 1, (3, 3, 20), uint8) = frames (oldest first) x lanes
(left, own, right) x cells, speed_err: Box(-inf, inf, (3,), float32) = v - v_exp (m/s), oldest
first); action Discrete(4): 0 left, 1 right, 2 speedup, 3 none. Stable-Baselines3's DQN takes
this Dict with its "MultiInputPolicy" (see experiments/sb3_dqn.py).

Seeding: reset(seed=s) runs SUMO and the demand with seed s; reset() without a seed draws the
episode seed from the env's np_random (so a seeded reset followed by unseeded ones repeats).
`info["seed"]` is the episode's seed. `options` is accepted and ignored.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from coopsumo.agents.decisions import ActionHold, follow_up
from coopsumo.agents.policies import Policy
from coopsumo.config import SimConfig
from coopsumo.envs.common import (
    WorldSlot,
    action_space,
    background_policy,
    check_action,
    check_episode,
    int_param,
    observation_space,
    path_param,
    run_seed,
    shown,
    sim_config,
    step_info,
    vehicle_observation,
)
from coopsumo.errors import ConfigError
from coopsumo.policy_spec import sumo_models
from coopsumo.sim.observation import Observation
from coopsumo.sim.world import World
from coopsumo.validation import MAX_STEPS

DEFAULT_WARMUP_STEPS = 300
"""30 s of traffic before the agent is chosen: a few dozen vehicles ahead of it on every lane"""
DEFAULT_MAX_STEPS = 3000
"""300 s: a vehicle at 40 km/h (the lowest expected speed) needs 180 s for the 2000 m road"""
MAX_INSERTION_WAIT_S = 600.0
"""reset() gives up if the agent vehicle is not on the road this long after its scheduled departure"""


class HighwayEnv(gym.Env[dict[str, Any], np.int64]):
    """One agent vehicle among background traffic; see the module docstring.

    cfg: the simulation (road, demand, control, reward, accident); its seed, steps and policy are
    replaced per episode. background: a policy spec for the other vehicles (keep, random, greedy,
    mobil[:...], dqn:PATH; not sumo, whose models would ignore the agent); model_path: shorthand for
    background="dqn:PATH". Default: keep. A bad parameter is a ConfigError (a ValueError) naming it and the value
    passed; a bool, float, str or None is not an integer.
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(
        self,
        cfg: SimConfig | None = None,
        *,
        warmup_steps: int = DEFAULT_WARMUP_STEPS,
        max_steps: int = DEFAULT_MAX_STEPS,
        background: str | None = None,
        model_path: str | Path | None = None,
        render_mode: str | None = None,
        decision_interval: int = 1,
    ) -> None:
        # every parameter checked as passed (ConfigError, a ValueError, naming it), before anything is derived from it
        base = sim_config(cfg)
        warmup_steps = int_param("warmup_steps", warmup_steps, 0)
        max_steps = int_param("max_steps", max_steps, 1)
        decision_interval = int_param("decision_interval", decision_interval, 1)
        total = warmup_steps + max_steps * decision_interval
        if total > MAX_STEPS:
            raise ConfigError(f"warmup_steps + max_steps * decision_interval must be at most {MAX_STEPS} simulation "
                              f"steps, got {warmup_steps} + {max_steps} * {decision_interval} = {total}")  # fmt: skip
        if render_mode is not None:
            raise ConfigError(f"render_mode must be None (HighwayEnv does not render), got {shown(render_mode)}")
        if background is not None and (not isinstance(background, str) or not background):
            raise ConfigError(f"background must be a policy spec (keep, random, greedy, mobil[:...], dqn:PATH) or "
                              f"None, got {shown(background)}")  # fmt: skip
        model = path_param("model_path", model_path)
        if background is not None and model is not None:
            raise ConfigError("give either background or model_path, not both")
        self.decision_interval = decision_interval
        self.background = background or (f"dqn:{model}" if model is not None else "keep")
        self.cfg = dataclasses.replace(base, steps=total, policy=self.background)
        self.cfg.validate()
        self.warmup_steps = warmup_steps
        self.max_steps = max_steps
        self.render_mode = render_mode
        self.observation_space = observation_space()
        self.action_space = action_space()
        background_policy(self.background, 0, self.cfg.control)  # a bad spec fails here, before SUMO starts
        if sumo_models(self.background):  # a valid spec, but SUMO's models would drive the agent too
            raise ConfigError(f"background must be a coopsumo policy, got {self.background!r}: SUMO's own models "
                              "would drive the agent's vehicle too and ignore its actions")  # fmt: skip
        self._slot = WorldSlot()
        self._policy: Policy | None = None
        self._bg_hold = ActionHold(1)
        self._obs: Observation | None = None  # the World's last observation (all vehicles)
        self._row = -1  # the agent's row in it
        self._last: dict[str, np.ndarray] | None = None  # the agent's last observation
        self._steps = 0
        self._started = False  # an episode was reset (not closed since, its reset did not fail)
        self._done = False  # ... and it ended
        self.agent_num = -1
        """vehicle number of the agent in the current episode"""

    @property
    def world(self) -> World | None:
        """The running World (None before the first reset and after close)."""
        return self._slot.world

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        if seed is not None:
            seed = run_seed(seed, None)  # a bad seed changes nothing (ValueError); a numpy integer becomes an int
        super().reset(seed=seed)
        episode_seed = run_seed(seed, self.np_random)
        self._started = False  # until this reset succeeds
        cfg = dataclasses.replace(self.cfg, seed=episode_seed)
        world = self._slot.open(cfg)
        self._policy = background_policy(self.background, episode_seed, cfg.control)
        self._bg_hold = ActionHold(self._policy.decision_interval)
        for _ in range(self.warmup_steps):
            obs = self._observe(world)
            world.apply(self._background(world, obs))
        # the first vehicle scheduled to depart at or after the end of the warm-up (num * T_up >= W * dt)
        self.agent_num = max(0, math.ceil(world.time_s / cfg.demand.t_up_s - 1e-9))
        give_up = world.step_count + round(
            (self.agent_num * cfg.demand.t_up_s - world.time_s + MAX_INSERTION_WAIT_S) / cfg.control.dt_s
        )
        obs = self._observe(world)
        # the agent's first decision comes on a decision step (step_count % decision_interval == 0)
        while not (np.any(obs.nums == self.agent_num) and world.step_count % self.decision_interval == 0):
            if world.step_count >= give_up:
                self._slot.close_world()
                raise RuntimeError(
                    f"agent vehicle {self.agent_num} was not inserted within {MAX_INSERTION_WAIT_S:g} s; "
                    "the demand is above what the road can take in"
                )
            world.apply(self._background(world, obs))
            obs = self._observe(world)
        self._set_obs(obs)
        self._steps = 0
        self._started, self._done = True, False
        info = {"vehicle": self.agent_num, "seed": episode_seed, "sim_step": world.step_count}
        return self._copy_last(), info

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        check_episode(self._started, self._done)
        world, obs, policy = self._slot.world, self._obs, self._policy
        assert world is not None and obs is not None and policy is not None
        action = check_action(action)  # TypeError/ValueError naming it: True, 1.0, None, arrays are not actions
        reward = 0.0
        info: dict[str, Any] = {}
        terminated = False
        for i in range(self.decision_interval):
            actions = self._background(world, obs)
            actions[self._row] = int(action) if i == 0 else int(follow_up(np.array([action]))[0])
            out = world.apply(actions)
            reward += float(out.reward.total[self._row])
            step = step_info(out, self._row)
            if i == 0:
                info = step
            else:
                for key in ("reward_speed", "reward_lane_change", "reward_flow"):
                    info[key] += step[key]
                info.update(q_t=step["q_t"], arrived=step["arrived"])
            next_obs = self._observe(world)
            terminated = not np.any(next_obs.nums == self.agent_num)
            if terminated:
                break
            obs = next_obs
            self._set_obs(next_obs)
        self._steps += 1
        info["sim_steps"] = i + 1
        if terminated:
            self._obs = None
        truncated = not terminated and self._steps >= self.max_steps
        self._done = terminated or truncated
        return self._copy_last(), reward, terminated, truncated, info

    def _observe(self, world: World) -> Observation:
        """The world's observation; with a decision interval, grids only on decision steps (as in training)."""
        if self.decision_interval == 1:
            return world.observe()
        step = world.step_count
        policy = self._policy
        bg_decides = policy is not None and policy.needs_grids and self._bg_hold.is_decision_step(step)
        return world.observe(grids=step % self.decision_interval == 0 or bg_decides)

    def _background(self, world: World, obs: Observation) -> np.ndarray:
        """The background policy's actions, held over its own decision interval."""
        assert self._policy is not None
        decide = self._bg_hold.is_decision_step(world.step_count)
        return self._bg_hold.actions(obs.nums, self._policy.act(obs) if decide else None)

    def close(self) -> None:
        """Close SUMO and remove the run folder; safe to call more than once."""
        self._slot.close()
        self._obs = None
        self._policy = None
        self._started = False
        super().close()

    def _set_obs(self, obs: Observation) -> None:
        self._obs = obs
        self._row = int(np.flatnonzero(obs.nums == self.agent_num)[0])
        self._last = vehicle_observation(obs, self._row)

    def _copy_last(self) -> dict[str, np.ndarray]:
        assert self._last is not None
        return {k: v.copy() for k, v in self._last.items()}
