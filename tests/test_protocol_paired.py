"""Profile.paired_with: the committed protocol study a profile pairs with is checked before any cell runs (issue 82,
probe 7, I7 and I11): a folder under results/ only, its study.json JSON by the study schema, its runs.csv by the
protocol's runs schema with each cell's row once; a bad one refused in one line naming the file (row, column), exit
2, nothing written."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
from conftest import REPO

from coopsumo.studies.protocol import report
from coopsumo.studies.protocol import study as protocol

REFERENCE = REPO / "results" / "learner_protocol_nr10"
PROFILE = """[profiles.mini]
help = "probe"
variants = ["select"]
seeds = [100]
train_steps = 300
t_ups = [1.5]
free_steps = 200
accident_steps = 300
accident_start = 50
accident_duration = 100
alpha_seeds = 0
paired_with = [["select", "{folder}", "nr10"]]
"""


@pytest.fixture
def results(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A results/ folder holding a copy of a committed protocol study's study.json and runs.csv as `ref`."""
    folder = tmp_path / "results" / "ref"
    folder.mkdir(parents=True)
    for name in ("study.json", "runs.csv"):
        shutil.copy(REFERENCE / name, folder / name)
    monkeypatch.setattr(report, "COMMITTED", tmp_path / "results")
    return folder


def _speed(folder: Path) -> None:
    runs = pd.read_csv(folder / "runs.csv")
    runs.loc[(runs["kind"] == "model") & (runs["scenario"] == "free"), "mean_speed_mps"] = 999.0
    runs.to_csv(folder / "runs.csv", index=False)


def _twice(folder: Path) -> None:
    runs = pd.read_csv(folder / "runs.csv")
    pd.concat([runs, runs.iloc[:1].assign(mean_speed_mps=5.0)]).to_csv(folder / "runs.csv", index=False)


def run(tmp_path: Path, capsys: pytest.CaptureFixture[str], folder: str) -> tuple[int, list[str], Path]:
    (tmp_path / "p.toml").write_text(PROFILE.format(folder=folder))
    out = tmp_path / "out"
    code = protocol.main(["--profile", f"{tmp_path / 'p.toml'}:mini", "--workers", "1", "--quiet", "--out", str(out)])
    return code, [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()], out


@pytest.mark.parametrize("edit, folder, words", [
    (_speed, "ref", "ref/runs.csv row 1 column mean_speed_mps must be"),
    (_twice, "ref", "ref/runs.csv rows 1 and "),
    (lambda f: (f / "study.json").write_text('{"broken'), "ref", "ref/study.json, which is not JSON"),
    (lambda f: (f / "study.json").write_text('{"learners": 3}'), "ref", "ref/study.json field learners must be"),
    (lambda f: None, "../results/ref", "p.toml: [profiles.mini] paired_with folder '../results/ref' is not a"),
    (lambda f: None, "", "p.toml: [profiles.mini] paired_with folder '' is not a folder under results/"),
], ids=["a speed of 999 m/s", "a cell's row twice", "study.json not JSON", "study.json off its schema",
        "a path out of results", "an empty path (probe 8, J19: the file was not named)"])
def test_a_bad_paired_study_is_refused_before_any_cell(edit: Callable[[Path], Any], folder: str, words: str,
                                                       results: Path, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    edit(results)
    code, err, out = run(tmp_path, capsys, folder)
    assert code == 2 and len(err) == 1 and words in err[0] and "Traceback" not in err[0], err
    assert not out.exists() and not (tmp_path / "models").exists()


def test_the_committed_pairings_and_a_good_copy_are_taken(results: Path) -> None:
    from coopsumo.studies.protocol.paired import check_paired
    from coopsumo.studies.protocol.plan import PROFILES, Profile

    check_paired(Profile("x", variants=("nr10",), paired_with=(("nr10", "ref", "nr10"),)))
    check_paired(Profile("x", variants=("nr10",), paired_with=(("nr10", "missing", "nr10"),)))  # the report's note
    for profile in PROFILES.values():
        check_paired(profile, REPO / "results")


def test_a_failed_baseline_cell_is_listed_in_the_report(tmp_path: Path) -> None:
    """Issue 82, probe 7, I10: a study with a failed baseline cell ended in `ValueError: cannot convert float NaN to
    integer` after its cells, without report.md; its table now shows "-" where the baseline has no value, and the
    failed cell is listed."""
    import json
    import math

    from coopsumo.studies.protocol.plan import PROFILES

    runs = pd.read_csv(REFERENCE / "runs.csv").reindex(columns=list(report.COLUMNS))
    failed = runs.index[runs["key"] == "keep_free_t1.5"]
    assert len(failed) == 1
    runs.loc[failed, "status"] = "failed"
    runs.loc[failed, list(report.COLUMNS[11:])] = math.nan
    models = report.per_model(runs)
    profile = PROFILES["nr10"]
    table = report.condition_stats(models, list(profile.variants), list(report.BASELINES))
    meta = json.loads((REFERENCE / "study.json").read_text())
    text = report.report_text(profile, runs, models, table, pd.DataFrame(), meta)
    assert "Failed cells (1): keep_free_t1.5" in text
    row = next(ln for ln in text.splitlines() if ln.startswith("| 1.5 | `nr10` | 10 | 20.55"))
    assert "| - |" in row and "| -, - |" in row and "nan" not in text


def test_a_users_folder_at_a_baselines_run_place_is_refused_before_any_cell(tmp_path: Path,
                                                                            capsys: pytest.CaptureFixture[str]
                                                                            ) -> None:  # fmt: skip
    """Issue 82, probe 7, I10: P/runs/keep_free_t1.5 holding a user's summary.json and notes.txt failed that cell in
    its worker (then the report's traceback); it is refused before any cell runs, as scenario I refuses one."""
    from coopsumo.studies.protocol.plan import PROFILES, cell_specs

    out = tmp_path / "P"
    key = next(s["key"] for s in cell_specs(PROFILES["tiny"]) if s["kind"] == "baseline")
    place = out / "runs" / key
    place.mkdir(parents=True)
    from coopsumo.run_dirs import mark_run_dir
    from coopsumo.studies.engine.run_folders import profile_study

    mark_run_dir(out, "protocol", finished=False, study=profile_study("tiny"))  # the study's own folder, interrupted
    (place / "summary.json").write_text('{"mine": 1}')
    (place / "notes.txt").write_text("x")
    code = protocol.main(["--profile", "tiny", "--workers", "1", "--quiet", "--out", str(out)])
    err = [ln for ln in capsys.readouterr().err.splitlines() if "error" in ln]
    assert code == 2 and len(err) == 1 and str(place) in err[0] and "not a coopsumo run folder" in err[0], err
    assert sorted(p.name for p in place.iterdir()) == ["notes.txt", "summary.json"]
    assert not list((out / "cells").glob("*.json")) and not (out / "train").exists()
