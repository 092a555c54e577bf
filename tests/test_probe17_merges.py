"""Issue 82, probe 17: `scenario1 --merge` copied a column no scenario I study writes, or a second mean_speed_mps, into
the merged table (TR2, as probe 16's TR2 for scenario II); `scenario2 --merge` took a row of status ok beside an error
text (TR3)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from coopsumo.studies.scenario1 import study as scenario1
from coopsumo.studies.scenario2 import study as scenario2

ROOT = Path(__file__).resolve().parent.parent
S1_PARTS = ROOT / "results" / "scenario1_alpha_only_dense_s"
S2_PART = ROOT / "results" / "scenario2_confirm_parts" / "L2a"


def _edit_header(path: Path, column: str, value: str) -> None:
    lines = path.read_text().splitlines()
    path.write_text("\n".join([lines[0] + f",{column}", *(line + f",{value}" for line in lines[1:])]) + "\n")


@pytest.mark.parametrize(("column", "value", "words"), [
    ("notes", "x", "has a column no scenario I study writes: notes"),
    ("mean_speed_mps", "60", "names the column mean_speed_mps twice"),
])  # fmt: skip
def test_a_scenario1_merge_part_with_a_column_of_its_own_is_refused(tmp_path: Path, column: str, value: str,
                                                                   words: str, capsys: pytest.CaptureFixture[str],
                                                                   ) -> None:  # fmt: skip
    parts = [tmp_path / name for name in ("p1", "p2")]
    for part in parts:
        shutil.copytree(S1_PARTS / part.name, part, ignore=shutil.ignore_patterns("runs"))
    _edit_header(parts[1] / "runs.csv", column, value)
    out = tmp_path / "merged"
    assert scenario1.main(["--merge", ",".join(map(str, parts)), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{parts[1]}/runs.csv {words}" in err[0], err
    assert not out.exists()


def test_a_scenario2_merge_part_row_ok_beside_an_error_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    part = tmp_path / "L2a"
    shutil.copytree(S2_PART, part)
    text = (part / "runs.csv").read_text()
    assert ",ok,," in text
    (part / "runs.csv").write_text(text.replace(",ok,,", ",ok,ValueError: boom,", 1))
    out = tmp_path / "merged"
    assert scenario2.main(["--merge", str(part), "--quiet", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "has status ok beside an error ('ValueError: boom')" in err[0], err
    assert not out.exists()
