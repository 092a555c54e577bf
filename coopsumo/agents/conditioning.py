"""The alpha-conditioned network's settings: which alphas its training draws, which learner fields only it reads."""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from coopsumo.config import PAPER_ALPHAS
from coopsumo.dqn_config import DQNConfig


def conditioned_alphas(dq: DQNConfig) -> tuple[float, ...]:
    """The alphas a conditioned training draws and relabels to: PAPER_ALPHAS up to dq.alpha_draw_max."""
    return tuple(a for a in PAPER_ALPHAS if a <= dq.alpha_draw_max)


CONDITIONED_FIELDS = ("alpha_conditioned", "alpha_period_steps", "alpha_relabel", "alpha_draw_max", "validation_alphas")
"""the learner fields of an alpha-conditioned training, which a network of one alpha ignores"""


CONDITIONED8V: dict[str, Any] = {"alpha_conditioned": True, "alpha_draw_max": 8.0, "validation_alphas": (0.0, 1.0, 8.0)}
"""the studies' conditioned network (learning study `conditioned8v`, protocol `c2x`): trained on the paper's alphas
up to 8, model.pt chosen at alphas 0, 1 and 8"""


def world_alpha(dq: DQNConfig, alpha: float) -> float:
    """The world's alpha of a training whose model drives at `alpha`: 0 for a conditioned one, which draws its own, so
    that one training serves every alpha it drives at."""
    return 0.0 if dq.alpha_conditioned else alpha


ALPHA_STREAM = 0x414C5048
"""random stream of a conditioned training's alpha draws (with the seed and the period's index)"""


def training_alpha(seed: int, step: int, period_steps: int, alphas: tuple[float, ...] = PAPER_ALPHAS) -> float:
    """The alpha all vehicles share at training step `step` of a conditioned training: one of `alphas`
    (conditioning.conditioned_alphas), drawn uniformly and afresh every period_steps, a pure function of
    (seed, step // period_steps) so a resume replays it exactly."""
    return _alpha_draw(seed, step // period_steps, alphas)


@functools.lru_cache(maxsize=256)
def _alpha_draw(seed: int, period: int, alphas: tuple[float, ...]) -> float:
    """The alpha of period `period` of a conditioned training seeded `seed` (training_alpha)."""
    return float(alphas[np.random.default_rng([seed, ALPHA_STREAM, period]).integers(len(alphas))])
