"""The reports' one markdown writer (report.markdown)."""

from __future__ import annotations

import math

from coopsumo.report.markdown import md_table, num


def test_a_table_has_its_head_its_rule_and_a_line_per_row() -> None:
    text = md_table(["policy", "speed (m/s)"], [["keep", "20.1"], ["dqn", "22.4"]])
    assert text.split("\n") == ["| policy | speed (m/s) |", "|---|---|", "| keep | 20.1 |", "| dqn | 22.4 |"]
    assert md_table(["a"], []) == "| a |\n|---|"


def test_a_missing_or_infinite_number_is_a_dash() -> None:
    assert num(1.234) == "1.23" and num(2, "{:+.1f}") == "+2.0"
    assert num(None) == num(math.nan) == num(math.inf) == "–"
