"""What the Gymnasium and PettingZoo environments share: spaces, per-vehicle views, the World's lifetime.

No physics here: everything comes from coopsumo.sim.world (which uses physics, observation, reward).
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces

from coopsumo.agents.policies import Policy, make_policy
from coopsumo.config import POLICY_STREAM, ControlConfig, SimConfig, rng_stream
from coopsumo.errors import ConfigError
from coopsumo.sim.observation import N_CELLS, N_FRAMES, N_SIDES, Observation
from coopsumo.sim.physics import ACTION_NAMES
from coopsumo.sim.world import StepOutcome, World
from coopsumo.validation import MAX_STEPS

GRID_SHAPE = (N_FRAMES, N_SIDES, N_CELLS)
"""(frames, lanes, cells) of one vehicle's occupancy grids (the same as coopsumo.agents.dqn.GRID_SHAPE)"""
N_ACTIONS = len(ACTION_NAMES)
SEED_LIMIT = 2**31 - 1
"""seeds drawn for unseeded resets lie in [0, SEED_LIMIT) (SUMO's --seed is a C int)"""


def observation_space() -> spaces.Dict:
    """The paper's state (eq. 2): 3 frames x 3 lanes x 20 cells of 0/1 occupancy, and 3 speed errors (m/s)."""
    return spaces.Dict(
        {
            "grids": spaces.Box(0, 1, GRID_SHAPE, np.uint8),
            "speed_err": spaces.Box(-np.inf, np.inf, (GRID_SHAPE[0],), np.float32),
        }
    )


def action_space() -> spaces.Discrete:
    """0 left, 1 right, 2 speedup, 3 none (coopsumo.sim.physics)."""
    return spaces.Discrete(N_ACTIONS)


def shown(value: Any) -> str:
    """repr(value) on one line, at most 80 characters (for messages)."""
    text = repr(value).replace("\n", " ")
    return text if len(text) <= 80 else f"{text[:77]}..."


def int_param(name: str, value: Any, low: int, high: int = MAX_STEPS) -> int:
    """The constructor parameter `name` as an int from low to high; a ConfigError (a ValueError) naming the
    parameter and the value passed otherwise. A bool (True is not 1), a float (3.0 too), a string or None is not
    an integer; a numpy integer is."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or not low <= value <= high:
        raise ConfigError(f"{name} must be an integer from {low} to {high}, got {shown(value)}")
    return int(value)


def sim_config(cfg: Any) -> SimConfig:
    """The constructor parameter `cfg`: a SimConfig, or the default one for None; ConfigError otherwise."""
    if cfg is None:
        return SimConfig()
    if not isinstance(cfg, SimConfig):
        raise ConfigError(f"cfg must be a coopsumo.config.SimConfig or None, got {type(cfg).__name__} {shown(cfg)}")
    return cfg


def path_param(name: str, value: Any) -> str | None:
    """The constructor parameter `name` as a path string (from a non-empty str or a Path), or None; ConfigError
    otherwise."""
    if value is None:
        return None
    if not isinstance(value, str | Path) or value == "":
        raise ConfigError(f"{name} must be a file path (str or pathlib.Path) or None, got {shown(value)}")
    return str(value)


def check_episode(started: bool, ended: bool) -> None:
    """RuntimeError unless an episode is running: step() before reset() (or after close() or a failed reset()),
    or after the episode ended (the agent, or every agent, terminated or truncated)."""
    if not started:
        raise RuntimeError("no episode is running: call reset() before step() (also after close() or a failed reset())")
    if ended:
        raise RuntimeError("the episode has ended: call reset() to start a new one")


def check_action(action: Any, who: str = "action") -> int:
    """`action` as an int 0-3 (0 left, 1 right, 2 speedup, 3 none). Anything that is not one integer is a
    TypeError naming `who` and the value: a bool (True is not "right"), a float, None, a string, an array of
    any shape but () (a 0-d integer array or numpy integer is accepted); an integer outside 0-3 a ValueError."""
    value = action[()] if isinstance(action, np.ndarray) and action.shape == () else action
    if isinstance(value, np.ndarray):
        raise TypeError(f"{who} must be one integer 0-3, got an array of shape {value.shape}: {action!r}")
    if isinstance(value, bool | np.bool_) or not isinstance(value, int | np.integer):
        raise TypeError(f"{who} must be an integer 0-3 (0 left, 1 right, 2 speedup, 3 none), got "
                        f"{type(value).__name__} {action!r}")  # fmt: skip
    if not 0 <= int(value) < N_ACTIONS:
        raise ValueError(f"{who} must be 0 (left), 1 (right), 2 (speedup) or 3 (none), got {action!r}")
    return int(value)


def vehicle_observation(obs: Observation, row: int) -> dict[str, np.ndarray]:
    """One vehicle's state as fresh arrays (never views of the batch)."""
    return {
        "grids": np.array(obs.grids[row], dtype=np.uint8),
        "speed_err": np.array(obs.speed_err[row], dtype=np.float32),
    }


def step_info(out: StepOutcome, row: int) -> dict[str, Any]:
    """Reward components and what happened to one vehicle during a step, as plain Python values."""
    return {
        "vehicle": int(out.nums[row]),
        "reward_speed": float(out.reward.speed[row]),
        "reward_lane_change": float(out.reward.lane_change[row]),
        "reward_flow": float(out.reward.flow[row]),
        "q_t": float(out.q_t),
        "lane_change_started": bool(out.lane_change_started[row]),
        "rejected": bool(out.rejected[row]),
        "arrived": bool(out.arrived[row]),
    }


def background_policy(spec: str, seed: int, control: ControlConfig) -> Policy:
    """A policy from its spec (coopsumo.agents.policies.make_policy), MOBIL included; its RNG is derived from seed."""
    if spec == "mobil" or spec.startswith("mobil:"):
        from coopsumo.agents.mobil import MobilPolicy

        return MobilPolicy.from_spec(spec, control)
    return make_policy(spec, rng_stream(seed, POLICY_STREAM))


def run_seed(seed: int | None, rng: np.random.Generator | None) -> int:
    """The SimConfig seed of an episode: `seed` itself when given (checked: an integer, not a bool, in range), else
    the next draw of rng."""
    if seed is None:
        if rng is None:
            raise ValueError("need a generator to draw a seed from")
        return int(rng.integers(SEED_LIMIT))
    if isinstance(seed, bool) or not (isinstance(seed, int | np.integer) and 0 <= seed <= SEED_LIMIT):
        raise ValueError(f"seed must be an integer in [0, {SEED_LIMIT}], got {seed!r}")
    return int(seed)


class WorldSlot:
    """At most one open World at a time, in a temporary run folder owned by the environment.

    libsumo allows one SUMO per process, so open() closes the previous World first; close()
    closes SUMO and removes the folder. Never closed from __del__: the owner calls close().
    """

    def __init__(self) -> None:
        self.world: World | None = None
        self._tmp: tempfile.TemporaryDirectory[str] | None = None

    def open(self, cfg: Any) -> World:
        self.close_world()
        if self._tmp is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="coopsumo-env-")
        world = World(cfg, Path(self._tmp.name))
        try:
            world.__enter__()
        except BaseException:
            world.__exit__(None, None, None)
            raise
        self.world = world
        return world

    def close_world(self) -> None:
        world, self.world = self.world, None
        if world is not None:
            world.__exit__(None, None, None)

    def close(self) -> None:
        try:
            self.close_world()
        finally:
            tmp, self._tmp = self._tmp, None
            if tmp is not None:
                tmp.cleanup()
