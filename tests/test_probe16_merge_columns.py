"""Issue 82, probe 16, TR2: `scenario2 --merge` took a part whose runs.csv or evals.csv held a column no sweep writes
(`notes`) or named a column twice (a second mean_speed_mps of 60 m/s, which pandas renames mean_speed_mps.1) and
copied it into the merged tables, exit 0; beside a part without it, the refusal blamed "different results: not the
same code?". Scenario II's tables are closed (study_tables.ClosedTable): one line naming the part, the table and the
column, exit 2, nothing written; every committed scenario II table's header passes."""

from __future__ import annotations

import csv
import hashlib
import shutil
import subprocess
from pathlib import Path

import pandas as pd
import pytest
from conftest import REPO

from coopsumo.studies.scenario2 import study as s2
from coopsumo.study_tables import SCENARIO2_EVALS, SCENARIO2_RUNS

CONFIRM = REPO / "results" / "scenario2_confirm_parts"


def _header(path: Path) -> list[str]:
    with path.open(newline="") as f:
        return next(csv.reader(f))


def test_every_committed_scenario2_table_has_only_the_columns_a_sweep_writes() -> None:
    listed = subprocess.run(["git", "ls-files", "results/*runs.csv", "results/*evals.csv"], cwd=REPO,
                            capture_output=True, text=True, check=True).stdout.split()  # fmt: skip
    tables = [REPO / f for f in listed if "scenario2" in f and Path(f).name in ("runs.csv", "evals.csv")]
    assert len(tables) >= 30, tables
    for path in tables:
        schema = SCENARIO2_RUNS if path.name == "runs.csv" else SCENARIO2_EVALS
        assert schema.columns_problem(_header(path)) is None, path


def test_a_column_no_sweep_writes_or_named_twice_is_named() -> None:
    runs, evals = _header(CONFIRM / "L2a" / "runs.csv"), _header(CONFIRM / "L2a" / "evals.csv")
    assert SCENARIO2_RUNS.columns_problem([*runs, "notes"]) == "has a column no sweep writes: notes"
    assert SCENARIO2_EVALS.columns_problem([*evals, "notes"]) == "has a column no sweep writes: notes"
    assert SCENARIO2_RUNS.columns_problem([*runs, "mean_speed_mps"]) == "names the column mean_speed_mps twice"
    assert SCENARIO2_EVALS.columns_problem([*evals, ""]) == "has a column no sweep writes: ''"
    assert SCENARIO2_RUNS.columns_problem([*runs, "queue_share"]) is None  # a share: every `_share` column's rule
    frame = pd.read_csv(CONFIRM / "L2a" / "runs.csv").assign(**{"mean_speed_mps.1": 60.0})  # pandas' renamed twin
    assert SCENARIO2_RUNS.frame_problem(frame) == "has a column no sweep writes: mean_speed_mps.1"
    SCENARIO2_RUNS.check_frame(frame.assign(notes="x"), "/never/written.csv")  # a writer's frame: not judged so


def _snapshot(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*"))}  # fmt: skip


def _notes(path: Path) -> None:
    lines = path.read_text().splitlines()
    path.write_text("\n".join([lines[0] + ",notes", *(line + ",x" for line in lines[1:])]) + "\n")


def _second_speed(path: Path) -> None:
    lines = path.read_text().splitlines()
    path.write_text("\n".join([lines[0] + ",mean_speed_mps", *(line + ",60" for line in lines[1:])]) + "\n")


EDITS = {"runs.csv notes": ("runs.csv", _notes, "has a column no sweep writes: notes"),
         "runs.csv speed twice": ("runs.csv", _second_speed, "names the column mean_speed_mps twice"),
         "evals.csv notes": ("evals.csv", _notes, "has a column no sweep writes: notes"),
         "evals.csv speed twice": ("evals.csv", _second_speed, "names the column mean_speed_mps twice")}  # fmt: skip


@pytest.mark.parametrize("case", sorted(EDITS))
def test_a_merge_refuses_a_part_with_a_column_no_sweep_writes(case: str, tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """The probe's mg_extra_col_one, mg_dup_col, mg_extra_col_evals; and mg_extra_col: two parts that both ran the
    lane count's baselines, one with the column (refused as "different results: not the same code?")."""
    name, edit, words = EDITS[case]
    parts = [shutil.copytree(CONFIRM / part, tmp_path / part) for part in ("L2a", "L2b")]
    edit(parts[1] / name)
    out = tmp_path / "merged"
    before = _snapshot(tmp_path)
    capsys.readouterr()
    code = s2.main(["--merge", ",".join(map(str, parts)), "--quiet", "--out", str(out)])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and err == [f"scenario2: error: --merge: {parts[1] / name} {words}"], err
    assert not out.exists() and _snapshot(tmp_path) == before
