"""Scenario II's shared words: the alpha* figure's name, a condition's label and a trend's verdict (its reports all
use them; tables and numbers are report.markdown's)."""

from __future__ import annotations

from coopsumo.validation import number_name

ALPHA_STAR_FIGURE = "fig6_alpha_star_lanes.png"
"""alpha* per lane count (alpha_star_lanes_figure)"""


def condition_label(lanes: int, t_up_s: float) -> str:
    return f"{lanes} lanes, T_up {number_name(t_up_s)} s"


def trend_verdict(coef: float, low: float | None, high: float | None) -> str:
    """'Holds' (the trend needs coef < 0), 'Reversed' or 'Cannot decide': with a bootstrap interval [low, high]
    over models, a verdict only when it excludes 0; without one (a single seed), the sign of coef."""
    if low is None or high is None:
        return "Holds" if coef < 0 else "Does not hold"
    return "Holds" if high < 0 else "Reversed" if low > 0 else "Cannot decide"
