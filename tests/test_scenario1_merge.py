"""`coopsumo scenario1 --merge`: a study of many models per alpha from parts of a few whole models each (issue 78).
The parts here are the committed results/scenario1_alpha_only_10models cut in two by training seed (100-104 and
105-109), as two invocations with those --train-seeds lists would have written them: their merge gives back the
committed study's runs, summary and claim (a) reading; every part that does not belong is refused in one line,
exit code 2, nothing written."""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
from conftest import REPO, text_difference

from coopsumo.paths import NAME_ROOM
from coopsumo.studies.scenario1 import study as s1

WHOLE = REPO / "results" / "scenario1_alpha_only_10models"
HALVES = {"p1": [100, 101, 102, 103, 104], "p2": [105, 106, 107, 108, 109]}


def make_part(tmp: Path, name: str, seeds: list[int]) -> Path:
    """The committed study's runs of these training seeds (and every baseline run), with its plan.json so seeded."""
    folder = tmp / name
    folder.mkdir()
    runs = pd.read_csv(WHOLE / "runs.csv")
    runs[runs["train_seed"].isna() | runs["train_seed"].isin(seeds)].to_csv(folder / "runs.csv", index=False)
    recorded = json.loads((WHOLE / "plan.json").read_text())
    recorded["plan"]["train_seeds"] = seeds
    (folder / "plan.json").write_text(json.dumps(recorded))
    return folder


@pytest.fixture
def parts(tmp_path: Path) -> list[Path]:
    return [make_part(tmp_path, name, seeds) for name, seeds in HALVES.items()]


def merge(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, list[str]]:
    code = s1.main(list(argv))
    return code, [line for line in capsys.readouterr().err.splitlines() if line.strip()]


def test_two_halves_merge_into_the_whole(parts: list[Path], tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    out = tmp_path / "merged"
    code, err = merge(capsys, "--merge", ",".join(map(str, parts)), "--out", str(out))
    assert code == 0, err
    key = ["t_up_s", "policy", "train_seed", "seed"]
    mine = pd.read_csv(out / "runs.csv").sort_values(key).reset_index(drop=True)
    whole = pd.read_csv(WHOLE / "runs.csv").sort_values(key).reset_index(drop=True)
    pd.testing.assert_frame_equal(mine, whole)
    assert text_difference((WHOLE / "summary.csv").read_text(), (out / "summary.csv").read_text()) is None
    # the claim (a) reading of the whole: the same tables (the committed one is marked exploratory, this is not)
    committed, merged = ((p / "claim_a.md").read_text() for p in (WHOLE, out))
    tables = [ln for ln in committed.splitlines() if ln.startswith("| ")]
    assert tables and tables == [ln for ln in merged.splitlines() if ln.startswith("| ")]
    assert "**Exploratory**" in committed and "**Exploratory**" not in merged
    assert (out / "fig_thrashing.png").read_bytes()[:4] == b"\x89PNG"
    plan = json.loads((out / "plan.json").read_text())
    assert plan["plan"]["train_seeds"] == list(range(100, 110)) and plan["parts"] == [str(p) for p in parts]
    report = (out / "report.md").read_text()
    assert "merged from 2 parts" in report and "| `" + str(parts[1]) + "` | 105, 106, 107, 108, 109 |" in report
    assert "In all, from scratch" not in report  # the parts here have no report.md with their compute
    for part, minutes in zip(parts, (100, 70), strict=True):
        (part / "report.md").write_text("# part\n\nWall time of this invocation: 3.0 min. From scratch on 2 cores, "
                                        f"the parts add up to about {minutes // 2} min ({minutes} core-min), before "
                                        "the report's figures.\n")  # fmt: skip
    # the same merge again writes over its own files
    assert merge(capsys, "--merge", ",".join(map(str, parts)), "--out", str(out))[0] == 0
    total = "In all, from scratch: 170 core-min (2.8 core-hours), about 1.4 h on 2 cores"
    assert total in (out / "report.md").read_text()


def _plan(change: Callable[[dict[str, Any]], Any]) -> Callable[[Path], Any]:
    def edit(folder: Path) -> None:
        recorded = json.loads((folder / "plan.json").read_text())
        change(recorded)
        (folder / "plan.json").write_text(json.dumps(recorded))

    return edit


def _rows(change: Callable[[pd.DataFrame], pd.DataFrame]) -> Callable[[Path], Any]:
    def edit(folder: Path) -> None:
        change(pd.read_csv(folder / "runs.csv")).to_csv(folder / "runs.csv", index=False)

    return edit


def _first(column: str, value: float) -> Callable[[Path], Any]:
    """The part's first row's `column` set to `value`, inside the column's limits but beyond what its run gives."""
    return _rows(lambda r: r.assign(**{column: [value, *r[column][1:]]}))


def _baseline_edited(folder: Path) -> None:
    runs = pd.read_csv(folder / "runs.csv")
    runs.loc[runs["policy"] == "keep", "tts_veh_h"] += 0.001
    runs.to_csv(folder / "runs.csv", index=False)


def _baseline_shifted(column: str, relative: float) -> Callable[[Path], Any]:
    """A part's baseline runs with one column moved by `relative` of its value (where it has one)."""

    def edit(folder: Path) -> None:
        runs = pd.read_csv(folder / "runs.csv")
        rows = runs["train_seed"].isna() & runs[column].notna() & (runs[column] != 0)
        assert rows.any()
        runs.loc[rows, column] *= 1.0 + relative
        runs.to_csv(folder / "runs.csv", index=False)

    return edit


def test_a_fit_that_differs_in_its_last_digits_on_another_machine_merges(
    parts: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """2026-12-02: a part run on another processor gave wave speeds 2.3e-13 km/h off (a least-squares fit through
    BLAS), and the merge refused it; a fitted column now agrees within merge.FIT_RTOL, the others to the last digit."""
    _baseline_shifted("wave_speed_kmh", 1e-13)(parts[1])
    out = tmp_path / "merged"
    assert merge(capsys, "--merge", ",".join(map(str, parts)), "--out", str(out))[0] == 0


def test_parts_whose_learner_was_edited_alike_are_refused(parts: list[Path], tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Issue 82, probe 8, J8: both parts' plan.json edited alike (lr 0.01, or gamma and dueling) merged, and the merged
    plan.json recorded a learner its models were not trained with: each part's learner is checked against the one
    its name trains."""
    for change in ({"lr": 0.01}, {"gamma": 0.5, "dueling": False}):
        for part in parts:
            _plan(lambda r, c=change: r["learners"]["alpha_only"].update(c))(part)
        out = tmp_path / "merged"
        code, err = merge(capsys, "--merge", ",".join(map(str, parts)), "--out", str(out))
        assert code == 2 and len(err) == 1 and "records another learner alpha_only than the one it names" in err[0]
        assert not out.exists()


@pytest.mark.parametrize("edit, words", [
    (_plan(lambda r: r["plan"].update(train_seeds=[104, 105])), "training seed 104 is in"),
    (_plan(lambda r: r["plan"].update(t_ups=[2.0])), "plan differs from"),
    (_plan(lambda r: r["learners"]["alpha_only"].update(lr=0.5)), "records another learner alpha_only than the one"),
    (_baseline_edited, "baseline runs differ from"),
    (_baseline_shifted("wave_speed_kmh", 1e-6), "in wave_speed_kmh"),
    (_baseline_shifted("delay_veh_h", 1e-13), "in delay_veh_h"),
    (_rows(lambda r: r.drop(index=r.index[r["train_seed"] == 107][:1])), "lacks 1 of its plan's runs (first: "
     "dqn_alpha_only_alpha0 of training seed 107"),
    (_rows(lambda r: pd.concat([r, r.iloc[:1]])), "holds a run twice"),
    (_rows(lambda r: r.assign(train_seed=r["train_seed"].replace(109, 111))), "lacks 30 of its plan's runs"),
    (lambda f: (f / "runs.csv").unlink(), "has no runs.csv"),
    (_rows(lambda r: r.assign(queue_m=[999_999.0, *r["queue_m"][1:]])), "row 1 has queue_m = 999999, longer than"),
    (_rows(lambda r: r.assign(delay_veh_h=r["tts_veh_h"] + 0.9)), "row 1 has delay_veh_h above its tts_veh_h"),
    (_rows(lambda r: r.assign(tts_veh_h=[5e5, *r["tts_veh_h"][1:]])), "row 1 has tts_veh_h = 500000, more than"),
    (_plan(lambda r: r["plan"].update(train_seeds="105")), "plan.train_seeds must be a non-empty list of integers"),
    (_plan(lambda r: r["plan"].update(t_ups=[2.0, None])), "plan.t_ups must be"),
    (_plan(lambda r: r["plan"].update(train_seeds=[105.5])), "plan.train_seeds must be a non-empty list of integers"),
    (_plan(lambda r: r["plan"].update(steps=-1)), "plan.steps must be a finite number >= 0, got -1"),
    (_plan(lambda r: r["learners"]["alpha_only"].update(lr=float("nan"))), "learner alpha_only: lr"),
    (lambda f: (f / "plan.json").write_text("[]"), "holds no scenario I plan.json"),
    (_first("mean_speed_mps", 60.0), "row 1 has mean_speed_mps = 60, above any vehicle's speed on its road"),
    (_first("lane_changes_per_vehicle", 600.0), "row 1 has lane_changes_per_vehicle = 600, more than one vehicle can"),
    (_first("waiting_at_end_veh", 100_000), "row 1 has waiting_at_end_veh = 100000, more than its demand sends"),
    (_first("horizon_after_start_s", 99_999.0), "row 1 has horizon_after_start_s = 99999, not its plan's 1800 s"),
    (_first("waves", 1_000_000), "row 1 has waves = 1e+06, more than the"),
], ids=["a seed twice", "another plan", "another learner", "a baseline edited", "a fitted baseline beyond the "
        "tolerance", "an exact column off in its last digits", "a run missing", "a run twice",
        "a model not in its plan", "unfinished", "a queue longer than the road (probe 8, J7)",
        "a delay above the total time spent (J7)", "5e5 veh-h in a short run (J7)", "seeds a string", "a demand null",
        "a seed not whole", "steps negative", "a learner's lr NaN", "no plan", "60 m/s (probe 13, F7)",
        "600 lane changes a vehicle in 2000 s (F7)", "1e5 vehicles waiting (F7)", "a horizon beyond the run (F7)",
        "1e6 waves (F7)"])
def test_a_part_that_does_not_belong_is_refused_in_one_line(edit: Callable[[Path], Any], words: str,
                                                            parts: list[Path], tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    edit(parts[1])
    out = tmp_path / "merged"
    code, err = merge(capsys, "--merge", ",".join(map(str, parts)), "--out", str(out))
    assert code == 2 and len(err) == 1 and "error" in err[0] and words in err[0], err
    assert not out.exists()


@pytest.mark.parametrize("edit, words", [
    (_plan(lambda r: r["plan"].update(lanes=9)), "p1/plan.json: [plan] lanes must be"),
    (_plan(lambda r: r["plan"].update(steps="x")), "p1/plan.json: [plan] steps must be int, got 'x'"),
    (_plan(lambda r: r["plan"].update(lanes=True)), "p1/plan.json: [plan] lanes must be int, got True"),
    (_plan(lambda r: r["plan"].update(profile=5)), "p1/plan.json: [plan] profile must be a profile's name, got 5"),
    (_plan(lambda r: r["plan"].update(baselines=["keep", "nonsense:x=1"])), "p1/plan.json: [plan] baselines:"),
    (_plan(lambda r: r["plan"].update(colour="red")), "p1/plan.json: [plan] unknown field 'colour'"),
], ids=["9 lanes", "steps a string", "lanes true", "profile a number", "a baseline no policy", "an unknown field"])
def test_parts_whose_plan_breaks_the_plans_rules_are_refused(edit: Callable[[Path], Any], words: str,
                                                             parts: list[Path], tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Issue 82, probe 7, I8: both parts' plan.json edited alike (so they agree with each other) was merged into a
    9-lane study, steps "x"; each part's plan is checked by the rules a profile's fields get, naming file and field."""
    for part in parts:
        edit(part)
    out = tmp_path / "merged"
    code, err = merge(capsys, "--merge", ",".join(map(str, parts)), "--out", str(out))
    assert code == 2 and len(err) == 1 and words in err[0], err
    assert not out.exists()


@pytest.mark.parametrize("extra, words", [
    (["--seeds", "3"], "--merge takes only --out"),
    (["--t-up", "2"], "got --t-up"),
    ([], "needs --out"),
], ids=["seeds", "t-up", "no out"])
def test_options_a_merge_would_ignore_are_refused(extra: list[str], words: str, parts: list[Path],
                                                  capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    code, err = merge(capsys, "--merge", ",".join(map(str, parts)), *extra)
    assert code == 2 and len(err) == 1 and words in err[0], err


def test_an_out_that_is_not_the_merges_own_is_refused(parts: list[Path], tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    inside = parts[0] / "merged"
    code, err = merge(capsys, "--merge", ",".join(map(str, parts)), "--out", str(inside))
    assert code == 2 and "inside the part" in err[0] and not inside.exists()
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "notes.txt").write_text("mine")
    code, err = merge(capsys, "--merge", ",".join(map(str, parts)), "--out", str(busy))
    assert code == 2 and "holds other files (notes.txt)" in err[0]
    assert sorted(p.name for p in busy.iterdir()) == ["notes.txt"]
    longest = tmp_path / ("m" * (os.pathconf(tmp_path, "PC_NAME_MAX") - NAME_ROOM))  # probe 10, L6: its stage's
    assert merge(capsys, "--merge", ",".join(map(str, parts)), "--out", str(longest))[0] == 0  # name was too long
    merged = tmp_path / "merged"
    assert merge(capsys, "--merge", ",".join(map(str, parts)), "--out", str(merged))[0] == 0
    assert not [p for p in tmp_path.iterdir() if ".merge-" in p.name]  # staged beside it, then moved in
    before = {p.name: p.read_bytes() for p in merged.iterdir()}
    third = make_part(tmp_path, "p3", [110])
    code, err = merge(capsys, "--merge", f"{parts[0]},{third}", "--out", str(merged))
    assert code == 2 and "holds a merge of other parts" in err[0]
    grown = make_part(tmp_path, "p4", [111])  # a merge grows by parts: p1, p2 and one more
    runs = pd.read_csv(grown / "runs.csv")
    models = pd.read_csv(parts[0] / "runs.csv").query("train_seed == 100").assign(train_seed=111)
    pd.concat([runs, models]).to_csv(grown / "runs.csv", index=False)
    assert merge(capsys, "--merge", f"{parts[0]},{parts[1]},{grown}", "--out", str(merged))[0] == 0
    assert json.loads((merged / "plan.json").read_text())["plan"]["train_seeds"] == [*range(100, 110), 111]
    code, err = merge(capsys, "--merge", ",".join(map(str, parts)), "--out", str(merged))  # nor shrinks
    assert code == 2 and "may only grow by parts" in err[0]
    before = {p.name: p.read_bytes() for p in merged.iterdir()}
    code, err = merge(capsys, "--quick", "--out", str(merged))  # nor does a study take a merge's folder
    assert code == 2 and "holds a merge of scenario I parts" in err[0]
    assert {p.name: p.read_bytes() for p in merged.iterdir()} == before
    code, err = merge(capsys, "--merge", str(parts[0]), "--out", str(tmp_path / "one"))
    assert code == 2 and "at least two part folders" in err[0]
    shutil.rmtree(parts[1])
    code, err = merge(capsys, "--merge", ",".join(map(str, parts)), "--out", str(tmp_path / "gone"))
    assert code == 2 and "holds no scenario I plan.json" in err[0]


def test_a_merge_of_other_parts_from_another_working_folder_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 82, probe 7, I3: `--merge p1,p2` from the folder A, then the same words from the folder B (other parts)
    replaced A's merge, since merge.json held the strings given. The parts are recorded absolute and --out is claimed
    as a study root: its marker names the merged study, a merge of other parts is refused, nothing written."""
    out = tmp_path / "M"
    for name in ("A", "B"):
        (tmp_path / name).mkdir()
        for part, seeds in HALVES.items():
            make_part(tmp_path / name, part, seeds)
    monkeypatch.chdir(tmp_path / "A")
    assert merge(capsys, "--merge", "p1,p2", "--out", str(out))[0] == 0
    assert json.loads((out / "merge.json").read_text())["parts"] == [str(tmp_path / "A" / p) for p in HALVES]
    marker = json.loads((out / ".coopsumo-run.json").read_text())
    assert marker["kind"] == "scenario1" and marker["study"] == \
        "the default profile's study merged from parts (learner preset alpha_only)"
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    monkeypatch.chdir(tmp_path / "B")
    code, err = merge(capsys, "--merge", "p1,p2", "--out", str(out))
    assert code == 2 and len(err) == 1 and "holds a merge of other parts" in err[0], err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    monkeypatch.chdir(tmp_path / "A")  # the same parts, however named, are the same merge
    assert merge(capsys, "--merge", f"{tmp_path / 'A' / 'p2'},../A/p1", "--out", str(out))[0] == 0


def test_a_folder_of_another_study_is_refused(parts: list[Path], tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Issue 82, probe 7, I3: a folder holding only names a merge writes (plan.json, runs.csv) but marked as another
    study's, or unmarked with a study's plan.json, was written over."""
    for marker in ({"kind": "scenario1", "finished": False, "study": "the quick profile's study"},
                   {"kind": "protocol", "finished": False, "study": "the tiny profile's study"}, None):
        other = tmp_path / "other"
        shutil.rmtree(other, ignore_errors=True)
        other.mkdir()
        (other / "plan.json").write_text(json.dumps({"plan": {"profile": "quick", "presets": ["default"]}}))
        (other / "runs.csv").write_text("a,b\n1,2\n")
        if marker is not None:
            (other / ".coopsumo-run.json").write_text(json.dumps(marker))
        before = {p.name: p.read_bytes() for p in other.iterdir()}
        code, err = merge(capsys, "--merge", ",".join(map(str, parts)), "--out", str(other))
        assert code == 2 and len(err) == 1 and ("holds the quick profile's study" in err[0] or
                                                "holds a coopsumo protocol run" in err[0]), err
        assert {p.name: p.read_bytes() for p in other.iterdir()} == before


def test_a_merge_written_before_markers_is_its_own(parts: list[Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """A merged folder without a marker whose merge.json names its parts relative to the working folder it was run
    from (results/scenario1_alpha_only_dense_s/merged) is the same merge's: its README's command reruns into it."""
    from coopsumo.run_dirs import check_study_root
    from coopsumo.studies.scenario1.merge import OWN, merged_study, recorded_merge

    out = tmp_path / "merged"
    monkeypatch.chdir(tmp_path)
    assert merge(capsys, "--merge", "p1,p2", "--out", "merged")[0] == 0
    (out / ".coopsumo-run.json").unlink()
    (out / "merge.json").write_text(json.dumps({"parts": ["p1", "p2"], "train_seeds": list(range(100, 110))}))
    assert merge(capsys, "--merge", ",".join(map(str, parts)), "--out", str(out))[0] == 0
    committed = REPO / "results" / "scenario1_alpha_only_dense_s" / "merged"
    monkeypatch.chdir(REPO)
    study = merged_study("default", ["alpha_only_dense_s"])
    assert recorded_merge(committed) == study
    check_study_root(committed, "scenario1", OWN, study, recorded_merge)  # taken: nothing raised, nothing written
    named = json.loads((committed / "merge.json").read_text())["parts"]
    assert {(REPO / p).resolve() for p in named} == {committed.parent / f"p{i}" for i in range(1, 13)}
