"""The reports' one markdown writer: a table from its head and rows of cells already formatted, a number as the
reports print it ("–" for a missing or infinite value), and an estimate with its interval."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any


def md_table(head: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    """A markdown table: the head, its rule, a line per row (no trailing newline)."""
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def num(x: Any, fmt: str = "{:.2f}") -> str:
    return "–" if x is None or (isinstance(x, float) and not math.isfinite(x)) else fmt.format(x)


def interval(point: float, low: float, high: float, fmt: str = "{:.2f}") -> str:
    """An estimate and its interval as the reports print them, "1.23 [0.98, 1.51]"; "-" for a missing one (NaN)."""
    if math.isnan(point):
        return "-"
    return f"{fmt.format(point)} [{fmt.format(low)}, {fmt.format(high)}]"
