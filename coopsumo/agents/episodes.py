"""Training where the model is used: each episode's demand and accident drawn from the training seed.

With DQNConfig.train_t_ups or accident_share set, a training is a sequence of episodes of episode_steps steps,
each a fresh world: its demand T_up drawn uniformly from train_t_ups (the run's own T_up when empty), and with
probability accident_share an accident whose position, start and length are drawn too. Every draw is a pure
function of (training seed, episode index), so a resume replays it exactly. Episode seeds are 10,000,000 or more:
apart from every study's evaluation seeds and the validation seeds.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from coopsumo.config import AccidentConfig, SimConfig
from coopsumo.dqn_config import DQNConfig

EPISODE_STREAM = 0x45504953
"""random stream of the episode draws (with the training seed and the episode's index)"""
SEED_LOW, SEED_HIGH = 10_000_000, 2**31 - 1
ACCIDENT_X_M = (1000.0, 1600.0)
"""range of a drawn accident's position (m) on the 2,000 m road"""
ACCIDENT_START = (0.1, 0.3)
ACCIDENT_LENGTH = (0.3, 0.6)
"""ranges of a drawn accident's first step and window length, as shares of the episode"""


def episodic(dq: DQNConfig) -> bool:
    """True when the training is split into episodes with drawn demand or accidents."""
    return bool(dq.train_t_ups) or dq.accident_share > 0


def episode_config(base: SimConfig, dq: DQNConfig, index: int) -> SimConfig:
    """The world of episode `index` of a training whose world is `base` (its seed the training seed)."""
    rng = np.random.default_rng([base.seed, EPISODE_STREAM, index])
    seed = int(rng.integers(SEED_LOW, SEED_HIGH))
    t_up = float(dq.train_t_ups[int(rng.integers(len(dq.train_t_ups)))]) if dq.train_t_ups else base.demand.t_up_s
    accident = AccidentConfig()
    draw = rng.random(4)  # drawn whether or not the accident happens: the next draws never shift
    if draw[0] < dq.accident_share:
        def within(bounds: tuple[float, float], u: float) -> float:
            return bounds[0] + u * (bounds[1] - bounds[0])

        steps = dq.episode_steps
        accident = AccidentConfig(enabled=True, x_m=round(within(ACCIDENT_X_M, draw[1]), 1),
                                  start_step=int(steps * within(ACCIDENT_START, draw[2])),
                                  duration_steps=max(1, int(steps * within(ACCIDENT_LENGTH, draw[3]))))  # fmt: skip
    return replace(base, seed=seed, demand=replace(base.demand, t_up_s=t_up), accident=accident,
                   steps=dq.episode_steps)  # fmt: skip


def episode_bounds(total_steps: int, dq: DQNConfig, step: int) -> tuple[int, int, int]:
    """(episode index, first step, end step) of the episode holding training step `step` (one episode covering
    the whole run when the training is not episodic)."""
    if not episodic(dq):
        return 0, 0, total_steps
    index = step // dq.episode_steps
    start = index * dq.episode_steps
    return index, start, min(start + dq.episode_steps, total_steps)
