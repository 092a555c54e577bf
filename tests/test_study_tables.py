"""Issue 82 item 1: scenario I's and the regime map's tables (runs.csv, summary.csv) against study_tables' schemas (the
retired learning study's and accident-seeds' committed tables are frozen with it, issue 80): every committed table
passes; a value outside each column's limits is refused in one line naming the file, the row and the column, by the
writer's check (before anything is written) and by a reader (Table.read); scenario I refuses a default learner's
study beside it whose runs.csv breaks its schema before it runs a cell."""

from __future__ import annotations

import json
import math
import re
import subprocess
from dataclasses import replace
from pathlib import Path
from typing import Any

import pandas as pd
import pytest

from coopsumo import study_tables as st
from coopsumo.record_schemas import Field, Integer, Number, RecordError, Table, Text

ROOT = Path(__file__).resolve().parent.parent
SCHEMAS = {("scenario1", "runs.csv"): st.SCENARIO1_RUNS, ("scenario1", "summary.csv"): st.SCENARIO1_SUMMARY}
"""(study, table) -> its schema; a committed folder results/[archive/]<study>*/ holds the study's tables"""


def committed_tables() -> list[tuple[Path, Table]]:
    """Every committed scenario I and regime map table (the archive's too) with its schema."""
    files = subprocess.run(["git", "ls-files", "results"], cwd=ROOT, capture_output=True, text=True, check=True)
    found = []
    for name in files.stdout.split():
        path = Path(name)
        study = "scenario1" if path.parent.name.startswith("scenario1") else None
        if study is not None and (study, path.name) in SCHEMAS:
            found.append((ROOT / path, SCHEMAS[study, path.name]))
        elif path.name == "runs.csv" and path.parent.name == "regime_map":
            found.append((ROOT / path, st.REGIME_MAP_RUNS))
    return found


def test_the_committed_tables_are_found() -> None:
    names = {str(path.relative_to(ROOT)) for path, _ in committed_tables()}
    assert {"results/scenario1/runs.csv", "results/scenario1/summary.csv", "results/regime_map/runs.csv"} <= names


@pytest.mark.parametrize(("path", "schema"), committed_tables(), ids=lambda x: str(x)[len(str(ROOT)) + 1 :]
                         if isinstance(x, Path) else "")  # fmt: skip
def test_every_committed_table_passes_its_schema(path: Path, schema: Table) -> None:
    assert len(schema.read(path)) > 0


def _outside(rule: Any) -> Any:
    """A value outside `rule`'s limits (above its highest, else below its lowest), or for a text one of no choice or
    blank; None when every value is inside (a text that may be blank)."""
    if isinstance(rule, Text):
        return None if rule.blank_ok else "no such" if rule.choices else math.nan
    if isinstance(rule, Integer):
        return rule.high + 1 if rule.high is not None else rule.low - 1
    assert isinstance(rule, Number) and rule.low is not None
    return rule.high * 2 + 1 if rule.high is not None else rule.low - 1


BASES = (("scenario1/runs.csv", st.SCENARIO1_RUNS), ("scenario1/summary.csv", st.SCENARIO1_SUMMARY),
         ("regime_map/runs.csv", st.REGIME_MAP_RUNS))
"""the committed table each case starts from (its first rows, of status ok where a table has a status)"""
CASES = [(base, schema, field) for base, schema in BASES
         for field in (*schema.columns, *schema.cases.get("ok", ())) if _outside(field.rule) is not None
         and (not field.optional or field.name in pd.read_csv(ROOT / "results" / base, nrows=0).columns)]  # fmt: skip


@pytest.mark.parametrize(("base", "schema", "field"), CASES, ids=[f"{b}:{f.name}" for b, _, f in CASES])
def test_a_value_outside_a_columns_limits_is_refused_in_one_line(tmp_path: Path, base: str, schema: Table,
                                                                 field: Field) -> None:  # fmt: skip
    rows = pd.read_csv(ROOT / "results" / base).head(2)
    rows[field.name] = rows[field.name].astype(object)
    rows.loc[1, field.name] = _outside(field.rule)
    path = tmp_path / Path(base).name
    words = rf"^{path} row 2 column {field.name} must be"
    if not isinstance(field.rule, Text):  # a blank is no number outside its limits: the writer leaves it
        with pytest.raises(RecordError, match=words):
            schema.check_frame(rows, path)
        assert not path.exists()
    rows.to_csv(path, index=False)
    with pytest.raises(RecordError, match=words) as caught:
        schema.read(path)
    assert "\n" not in str(caught.value)


def test_a_word_a_missing_column_and_an_empty_table_are_refused(tmp_path: Path) -> None:
    rows = pd.read_csv(ROOT / "results" / "scenario1" / "runs.csv").head(3)
    cases = {"row 1 column mean_speed_mps must be a number (m/s), got '14.0'": rows.assign(  # read as words
                 mean_speed_mps=[14.0, 15.0, "fast"]),
             "row 1 column tts_veh_h must be a finite number": rows.assign(tts_veh_h=math.nan),
             "has no column waves": rows.drop(columns="waves"),
             "has no row": rows.head(0)}  # fmt: skip
    for words, table in cases.items():
        table.to_csv(tmp_path / "runs.csv", index=False)
        with pytest.raises(RecordError, match=f"^{re.escape(str(tmp_path / 'runs.csv'))} {re.escape(words)}"):
            st.SCENARIO1_RUNS.read(tmp_path / "runs.csv")
    (tmp_path / "runs.csv").write_text("")
    with pytest.raises(RecordError, match=r"runs.csv cannot be read as a table \(EmptyDataError\)$"):
        st.SCENARIO1_RUNS.read(tmp_path / "runs.csv")


def test_scenario1_refuses_a_bad_default_study_beside_it_before_it_runs(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """A study of another learner preset reads the default learner's runs.csv beside it for its report: a table
    outside its schema there is refused in one line, exit 2, before a cell runs or plan.json is written."""
    from coopsumo.config import to_dict
    from coopsumo.studies.scenario1 import study as scenario1
    from coopsumo.studies.scenario1.plan import study_out

    argv = ["--quick", "--preset", "alpha_only"]
    plan = scenario1.plan_from_args(scenario1.build_parser().parse_args(argv))
    beside = tmp_path / study_out(replace(plan, presets=("default",))).name
    beside.mkdir()
    (beside / "plan.json").write_text(json.dumps({"plan": to_dict(replace(plan, presets=("default",)))}))
    rows = pd.read_csv(ROOT / "results" / "scenario1" / "runs.csv").head(4)
    rows.loc[3, "mean_speed_mps"] = 99.0
    rows.to_csv(beside / "runs.csv", index=False)
    out = tmp_path / "scenario1_alpha_only"
    assert scenario1.main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"scenario1: error: {beside / 'runs.csv'} row 4 column mean_speed_mps must be a finite number >= 0 "
                   "and <= 70 (m/s), got 99.0"]  # fmt: skip
    assert not (out / "plan.json").exists() and not (out / "cells").exists()
