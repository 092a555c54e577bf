"""Issue 82, probe 13: messages that were not one line or that said the wrong thing (F17, F19, F20)."""

from __future__ import annotations

from pathlib import Path

import pytest

from coopsumo.errors import UsageError
from coopsumo.runio import run_cli
from coopsumo.studies.scenario2 import redraw


def test_a_merge_parts_unparsable_table_is_one_line_naming_it(tmp_path: Path) -> None:
    """F17: pandas' ParserError text ends in a newline, which the refusal passed on ("...saw 4\\n)"); the file that
    could not be read was not named."""
    part = tmp_path / "L2b"
    part.mkdir()
    (part / "sweep.json").write_text("{}")
    (part / "runs.csv").write_text("a,b\n1,2\n")
    (part / "evals.csv").write_text("root\nx:1:2:3\nx,1,2,3\n")
    with pytest.raises(UsageError) as refused:
        redraw._read_part(part)
    text = str(refused.value)
    assert "\n" not in text and f"{part} is not a finished scenario2 sweep (evals.csv: ParserError: " in text, text


def test_a_usage_error_of_several_lines_is_printed_on_one(capsys: pytest.CaptureFixture[str]) -> None:
    """F17's class: whatever a library's text a UsageError passes on, the command's error is one line."""

    def body() -> int:
        raise UsageError("a table cannot be read (Error tokenizing data. C error: Expected 1 fields\n)\nand more\n")

    assert run_cli("scenario2", body) == 2
    err = capsys.readouterr().err
    assert err == "scenario2: error: a table cannot be read (Error tokenizing data. C error: Expected 1 fields ) and " \
                  "more\n", err
