"""The alpha-conditioned network's settings: which alphas its training draws, which learner fields only it reads."""

from __future__ import annotations

from coopsumo.config import PAPER_ALPHAS, DQNConfig


def conditioned_alphas(dq: DQNConfig) -> tuple[float, ...]:
    """The alphas a conditioned training draws and relabels to: PAPER_ALPHAS up to dq.alpha_draw_max."""
    return tuple(a for a in PAPER_ALPHAS if a <= dq.alpha_draw_max)


CONDITIONED_FIELDS = ("alpha_conditioned", "alpha_period_steps", "alpha_relabel", "alpha_draw_max", "validation_alphas")
"""the learner fields of an alpha-conditioned training, which a network of one alpha ignores"""
