"""Scenario II's shared words and table helpers: the alpha* figure's name, a condition's label, a trend's verdict,
a markdown table and a number as the reports print them (scenario2_report and scenario2_gate_report both use them)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

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


def md_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def num(x: Any, fmt: str = "{:.2f}") -> str:
    return "–" if x is None or (isinstance(x, float) and not math.isfinite(x)) else fmt.format(x)
