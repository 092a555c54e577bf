"""The reports' one markdown writer: a table from its head and rows of cells already formatted, and a number as the
reports print it ("–" for a missing or infinite value)."""

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
