"""Issue 67, read-back checks that look inside, for cell records: a scenario II record whose summary or one of its
evaluations was edited is not what its evaluations pool to and is rerun; a run folder of scenario I's accident runs
(the regime map; the retired accident-seeds' too) is redone, with one line, when its files cannot be trusted; a
scenario II record whose train/ link was pointed at another model is rerun, the link put back. An intact record is
reused and left as it was."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
import test_scenario2

from coopsumo.studies.engine.records import (
    cell_path,
    checked_record,
    copied_wrong,
    pool_summaries,
    reusable_keys,
)
from coopsumo.studies.scenario2 import study as scenario2
from coopsumo.studies.scenario2.plan import PROFILES, cell_specs


# -- a scenario II record against its own evaluations -------------------------------------------------------------
def _evaluation(seed: int, speed: float, departed: int, changes: int, run: dict[str, Any]) -> dict[str, Any]:
    """One evaluation's summary as scenario II keeps it (simulate's summary with the loops' means and its seed), of a
    run of the SimConfig dict `run` (its steps and seconds; a loop flow its departures give: records.runs_problem)."""
    sim_s = run["steps"] * run["control"]["dt_s"]
    return {"steps": run["steps"], "sim_seconds": sim_s, "departed": departed, "arrived": departed - 9,
            "collisions": 0, "teleports": 0, "lane_changes": changes, "lane_changes_per_vehicle": changes / departed,
            "mean_speed_mps": speed, "mean_travel_time_s": sim_s / 2 + seed / 100,
            "throughput_veh_per_h": (departed - 9) * 3600 / sim_s,
            "passing_taken_share": float("nan"), "loop_flow_veh_h_per_lane": 90.5, "loop_occupancy_pct": 2.25,
            "policy": "dqn:train/L2_a0_s1/model.pt", "scenario": "free", "eval_seed": seed}  # fmt: skip


@pytest.fixture
def dqn_spec() -> dict[str, Any]:
    return next(s for s in cell_specs(PROFILES["full"]) if s.get("policy") == "dqn")


def _record(spec: dict[str, Any]) -> dict[str, Any]:
    """The record of a finished scenario II DQN cell, as _evaluate fills it: three evaluations and their pool."""
    runs = spec["config"]["evals"]
    evals = [_evaluation(1, 21.6, 40, 12, runs[0]), _evaluation(11, 22.1, 42, 9, runs[1]),
             _evaluation(21, 20.9, 39, 15, runs[2])]  # fmt: skip
    pooled = {k: v for k, v in pool_summaries(evals).items() if k != "eval_seed"}
    return {**scenario2.RECORDS.new(spec), "status": "ok", "eval_summaries": evals, "summary": pooled,
            "train_summary": dict(TRAINED)}  # fmt: skip


TRAINED = {"steps": 300, "departed": 40, "mean_speed_mps": 20.0, "lane_changes": 12, "collisions": 0, "updates": 20,
           "wall_seconds": 3.0, "steps_per_second": 100.0}  # fmt: skip
"""a training's summary as a record keeps it (the values runs.csv copies among them)"""


def _set(key: str, value: Any) -> Callable[[dict[str, Any]], None]:
    return lambda record: record["summary"].update({key: value})


def _set_eval(i: int, key: str, value: Any) -> Callable[[dict[str, Any]], None]:
    return lambda record: record["eval_summaries"][i].update({key: value})


def _both(key: str, value: Any) -> Callable[[dict[str, Any]], None]:
    """Every evaluation's `key` set to value and the summary to what they pool to (the probe's tcell.py): a record
    that agrees with itself, its values outside the limits runs.csv is checked by."""

    def edit(record: dict[str, Any]) -> None:
        for one in record["eval_summaries"]:
            one[key] = value
        record["summary"][key] = pool_summaries(record["eval_summaries"])[key]

    return edit


RECORD_CASES: dict[str, tuple[Callable[[dict[str, Any]], None], str]] = {
    "summary speed 21.6 -> 30.0": (_set("mean_speed_mps", 30.0), "mean_speed_mps = 30, but its 3 evaluations pool"),
    "an evaluation's speed edited": (_set_eval(0, "mean_speed_mps", 30.0), "mean_speed_mps = 21.5333"),
    "a collision added to an evaluation": (_set_eval(2, "collisions", 1), "collisions = 0, but"),
    "lane changes scaled in both": (lambda r: r["summary"].update(lane_changes=72, lane_changes_per_vehicle=72 / 121),
                                    "lane_changes = 72"),
    "the loops' flow edited": (_set("loop_flow_veh_h_per_lane", 999.0), "loop_flow_veh_h_per_lane = 999"),
    "an evaluation dropped": (lambda r: r["eval_summaries"].pop(), "its 2 evaluations pool"),
    "an impossible evaluation": (_set_eval(1, "mean_speed_mps", -2.0),
                                 "evaluation 2 of 3 with mean_speed_mps must be a finite number >= 0"),
    "evaluations not a list": (lambda r: r.update(eval_summaries={"mean_speed_mps": 21.6}), "not a list"),
    "no evaluations": (lambda r: r.update(eval_summaries=[]), "not a list of summaries"),
    # issue 82 (2026-12-02): values outside runs.csv's limits (record_schemas.MEASURES) were reused into runs.csv,
    # or stopped the study at runs.csv on every rerun
    "-5 steps a second": (_both("steps_per_second", -5.0),
                          "has summary steps_per_second must be a finite number >= 0 and <= 1e+06 (steps/s), got -5.0"),
    "a decision every 0 steps": (_both("decision_interval_steps", 0.0),
                                 "has summary decision_interval_steps must be an integer >= 1, got 0"),
    "-3 vehicles on the road": (_both("mean_vehicles_on_road", -3.0),
                                "has summary mean_vehicles_on_road must be a finite number >= 0 (vehicles), got -3.0"),
    "an occupancy of 500 %": (_both("loop_occupancy_pct", 500.0),
                              "has summary loop_occupancy_pct must be a finite number >= 0 and <= 100 (%), got 500.0"),
    "a loop flow of 1e6 veh/h": (_both("loop_flow_veh_h_per_lane", 1e6),
                                 "has summary loop_flow_veh_h_per_lane must be a finite number >= 0 and <= 3600"),
    "a wall time of -1 s": (_both("wall_seconds", -1.0), "has summary wall_seconds must be a finite number >= 0 (s)"),
    "an evaluation's wall time of -1 s": (_set_eval(1, "wall_seconds", -1.0),
                                          "has evaluation 2 of 3 with wall_seconds must be a finite number >= 0 (s)"),
    "-5 training updates": (lambda r: r["train_summary"].update(updates=-5),
                            "has train_summary updates must be an integer >= 0, got -5"),
    # the probe's F7 (c_trainsum_*, l_trainsum_text): reused, runs.csv's train_* columns came out blank
    "training updates 'many'": (lambda r: r["train_summary"].update(updates="many"),
                                'has train_summary updates = "many", not a number'),
    "training speed null": (lambda r: r["train_summary"].update(mean_speed_mps=None),
                            "has train_summary mean_speed_mps = null, not a number"),
    "training speed gone": (lambda r: r["train_summary"].pop("mean_speed_mps"),
                            "has train_summary without mean_speed_mps"),
    "train_summary null": (lambda r: r.update(train_summary=None), "has no train_summary, but its cell trains"),
    "train_summary gone": (lambda r: r.pop("train_summary"), "has no train_summary, but its cell trains"),
}  # fmt: skip


@pytest.mark.parametrize("case", RECORD_CASES)
def test_a_record_edited_against_its_evaluations_is_rerun_with_one_line(
    case: str, dqn_spec: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    edit, fragment = RECORD_CASES[case]
    path = cell_path(tmp_path, dqn_spec["key"])
    path.parent.mkdir()
    record = _record(dqn_spec)
    path.write_text(json.dumps(record))
    assert reusable_keys(tmp_path, [dqn_spec], "scenario2", scenario2.REQUIRED_SUMMARY) == {dqn_spec["key"]}
    assert capsys.readouterr().err == ""
    edit(record)
    path.write_text(json.dumps(record))
    assert reusable_keys(tmp_path, [dqn_spec], "scenario2", scenario2.REQUIRED_SUMMARY) == set()
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"scenario2: cell {dqn_spec['key']}: record {path} "), lines
    assert fragment in lines[0] and lines[0].endswith("; rerunning it"), lines
    # a cell just run whose record disagrees so counts as failed
    assert checked_record(record, scenario2.REQUIRED_SUMMARY)["status"] == "failed"


def test_several_bad_records_are_each_named_once(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 82 (s2_dup_lines): a rerun with several bad records says one line for each, none twice."""
    specs = [s for s in cell_specs(PROFILES["full"]) if s.get("policy") == "dqn"][:4]
    edits = [_both("loop_occupancy_pct", 500.0), lambda r: r.update(policy="mobil"), lambda r: r.update(lanes=7),
             lambda r: r["train_summary"].update(updates=-5)]  # fmt: skip
    cell_path(tmp_path, specs[0]["key"]).parent.mkdir()
    for spec, edit in zip(specs, edits, strict=True):
        record = _record(spec)
        edit(record)
        cell_path(tmp_path, spec["key"]).write_text(json.dumps(record))
    assert reusable_keys(tmp_path, specs, "scenario2", scenario2.REQUIRED_SUMMARY) == set()
    lines = capsys.readouterr().err.splitlines()
    assert sorted(line.split(": record ")[0] for line in lines) == sorted(f"scenario2: cell {s['key']}" for s in specs)
    assert all(line.endswith("; rerunning it") for line in lines), lines


def test_an_intact_record_is_reused_untouched(dqn_spec: dict[str, Any], tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    mobil = next(s for s in cell_specs(replace(PROFILES["tiny"], policies=("dqn", "mobil")))
                 if s.get("policy") == "mobil")  # fmt: skip
    run = mobil["config"].get("run", mobil["config"])
    for spec, record in ((dqn_spec, _record(dqn_spec)),
                         (mobil, {**scenario2.RECORDS.new(mobil), "status": "ok",
                                  "summary": _evaluation(1, 21.6, 40, 12, run)})):  # fmt: skip
        cell_path(tmp_path, spec["key"]).parent.mkdir(exist_ok=True)
        cell_path(tmp_path, spec["key"]).write_text(json.dumps(record))
    before = {p.name: p.read_bytes() for p in (tmp_path / "cells").iterdir()}
    assert reusable_keys(tmp_path, [dqn_spec, mobil], "scenario2", scenario2.REQUIRED_SUMMARY) == {dqn_spec["key"],
                                                                                                    mobil["key"]}
    assert capsys.readouterr().err == ""
    assert {p.name: p.read_bytes() for p in (tmp_path / "cells").iterdir()} == before
    assert checked_record(_record(dqn_spec), scenario2.REQUIRED_SUMMARY)["status"] == "ok"


def test_a_records_training_summary_unlike_its_trainings_file_is_rerun_with_one_line(
        dqn_spec: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Issue 82, probe 8, J10: a record whose copy of its training's summary was edited (25 m/s against its training's
    train_summary.json's 15.33) was reused and copied into runs.csv. The record's copy must be its training's file,
    field for field; a training file that cannot be read is judged where the training is, not here."""
    path = cell_path(tmp_path, dqn_spec["key"])
    path.parent.mkdir()
    path.write_text(json.dumps(_record(dqn_spec)))
    own = tmp_path / "train" / str(dqn_spec.get("train_key") or dqn_spec["key"]) / "train_summary.json"
    assert copied_wrong(tmp_path, [dqn_spec], "scenario2") == set()  # no training file: judged where it is
    own.parent.mkdir(parents=True)
    own.write_text(json.dumps({**TRAINED, "mean_speed_mps": 20.000000000000004}))  # the same number, as JSON rounds
    assert copied_wrong(tmp_path, [dqn_spec], "scenario2") == set()
    assert capsys.readouterr().err == ""
    for edited, fragment in (({**TRAINED, "mean_speed_mps": 15.33}, "mean_speed_mps = 20.0, but its training's"),
                             ({**TRAINED, "selected_step": 300}, "selected_step = null, but its training's")):
        own.write_text(json.dumps(edited))
        assert copied_wrong(tmp_path, [dqn_spec], "scenario2") == {dqn_spec["key"]}
        lines = capsys.readouterr().err.splitlines()
        assert lines == [f"scenario2: cell {dqn_spec['key']}: record {path} has train_summary {fragment} {own} says "
                         f"{json.dumps(edited[fragment.split()[0]])}; rerunning it"], lines


# -- a scenario II record whose model link was moved ------------------------------------------------------------
faked_train = test_scenario2.faked_train
"""train() and the evaluations faked (no SUMO), as scenario II's own record tests run them"""


def test_a_record_naming_another_cells_training_is_rerun(tmp_path: Path, faked_train: list[str],
                                                         capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """The probe's F8 (c_traindir_other, ln_traindir_rerun): a record whose train_dir was edited to another cell's
    training was reused and copied into runs.csv, which the part's own merge then refused on every rerun. The cell
    is run again with one line naming train_dir, and runs.csv holds its own training once more."""
    root = tmp_path / "sweep"
    assert scenario2.run_sweep(PROFILES["tiny"], root, progress=False, n_boot=20)["cells_ok"] == 8
    path = cell_path(root, "L2_T2_a0_s1")
    record = json.loads(path.read_text())
    assert record["train_dir"] == "train/L2_a0_s1"
    path.write_text(json.dumps({**record, "train_dir": "train/L2_a8_s1"}))
    capsys.readouterr()
    del faked_train[1:]
    meta = scenario2.run_sweep(PROFILES["tiny"], root, progress=False, n_boot=20)
    err = [line for line in capsys.readouterr().err.splitlines() if "rerunning it" in line]
    assert err == [f'scenario2: cell L2_T2_a0_s1: record {path} has train_dir = "train/L2_a8_s1", not its '
                   'cell\'s "train/L2_a0_s1"; rerunning it'], err
    assert meta["cells_ok"] == 8 and meta["cells_run"] == 1 and faked_train[1:] == ["L2_T2_a0_s1"]
    runs = pd.read_csv(root / "runs.csv").set_index("key")
    assert runs.loc["L2_T2_a0_s1", "train_dir"] == "train/L2_a0_s1"


def test_a_sweep_reruns_a_record_whose_training_summary_was_edited(
        tmp_path: Path, faked_train: list[str], capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Issue 82, probe 8, J10 (c08): scenario II reused a record whose train_summary.mean_speed_mps was edited to 25.0
    and copied it into runs.csv beside its training's own value. The cell is run again with one line, and runs.csv
    holds its training's value once more."""
    root = tmp_path / "sweep"
    assert scenario2.run_sweep(PROFILES["tiny"], root, progress=False, n_boot=20)["cells_ok"] == 8
    path = cell_path(root, "L2_T2_a0_s1")
    record = json.loads(path.read_text())
    own = json.loads((root / record["train_dir"] / "train_summary.json").read_text())
    path.write_text(json.dumps({**record, "train_summary": {**record["train_summary"], "mean_speed_mps": 25.0}}))
    capsys.readouterr()
    del faked_train[1:]
    meta = scenario2.run_sweep(PROFILES["tiny"], root, progress=False, n_boot=20)
    err = [line for line in capsys.readouterr().err.splitlines() if "rerunning it" in line]
    assert err == [f"scenario2: cell L2_T2_a0_s1: record {path} has train_summary mean_speed_mps = 25.0, but its "
                   f"training's {root / record['train_dir'] / 'train_summary.json'} says "
                   f"{json.dumps(own['mean_speed_mps'])}; rerunning it"], err
    assert meta["cells_ok"] == 8 and meta["cells_run"] == 1 and faked_train[1:] == ["L2_T2_a0_s1"]
    runs = pd.read_csv(root / "runs.csv").set_index("key")
    assert runs.loc["L2_T2_a0_s1", "train_mean_speed_mps"] == own["mean_speed_mps"]


def test_a_train_link_pointed_at_another_model_is_rerun(tmp_path: Path, faked_train: list[str],
                                                       capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Regression (issue 67): a model's train/<model> link (into the model store) that a user pointed at another
    model was kept, and the records of its cells reused. Each cell of the model (one per condition) is run again with
    one line, and the link leads to its own model once more; the folder the user pointed it at is left as it was,
    byte for byte. Six models (tiny at three seeds), four of them pointed elsewhere."""
    root = tmp_path / "sweep"
    profile = replace(PROFILES["tiny"], seeds=(1, 2, 3))
    assert scenario2.run_sweep(profile, root, progress=False, n_boot=20)["cells_ok"] == 12
    first = pd.read_csv(root / "alpha_star.csv")
    train = root / "train"
    own = {p.name: p.resolve() for p in train.iterdir()}
    assert len(own) == 6
    mine = tmp_path / "mine"  # a training folder of the user's: another name than the store's
    shutil.copytree(own["L2_a0_s2"], mine)
    edited = tmp_path / "copy" / own["L2_a8_s2"].name  # the model's name, another training's config.json
    shutil.copytree(own["L2_a8_s2"], edited)
    config = json.loads(cell_path(root, "L2_T2_a0_s1").read_text())["config"]["train"]
    (edited / "config.json").write_text(json.dumps({"config": config}))
    pointed = {"L2_a8_s1": own["L2_a0_s1"], "L2_a0_s2": mine, "L2_a8_s2": edited, "L2_a0_s3": tmp_path / "gone"}
    for key, target in pointed.items():
        (train / key).unlink()
        (train / key).symlink_to(target, target_is_directory=True)
    before = {p: p.read_bytes() for p in [*mine.rglob("*"), *edited.parent.rglob("*")] if p.is_file()}
    capsys.readouterr()
    del faked_train[1:]
    meta = scenario2.run_sweep(profile, root, progress=False, n_boot=20)
    err = capsys.readouterr().err.splitlines()
    cells = {f"L2_T{t}_{model.removeprefix('L2_')}": model for model in pointed for t in (2, 4)}
    assert sorted(faked_train[1:]) == sorted(cells)  # exactly the cells of the models whose link was moved ran again
    for model in pointed:  # one line a model, naming its link and its cells
        lines = [line for line in err if line.startswith(f"scenario2: {train / model} ")]
        assert len(lines) == 1 and "rerunning the 2 cells of its training" in lines[0], err
        assert all(key in lines[0] for key, named in cells.items() if named == model), lines
    assert "4 already done" in "\n".join(err) and meta["cells_ok"] == 12 and meta["cells_run"] == 8
    assert {p.name: p.resolve() for p in train.iterdir()} == own
    assert {p: p.read_bytes() for p in before} == before
    pd.testing.assert_frame_equal(pd.read_csv(root / "alpha_star.csv"), first)


def _garbage(path: Path) -> None:
    path.write_text("garbage")


def _folder(path: Path) -> None:
    path.unlink()
    path.mkdir()


SPOILED_RUNS: dict[str, tuple[str, Callable[[Path], None], str]] = {  # run folder: (its file, the edit, the line)
    "default/t4/keep_seed1": ("detectors.xml", _garbage, "has a missing or cut-short detectors.xml"),
    "paper/t4/keep_seed1": ("trajectories.parquet", _folder, "has a trajectories.parquet that is not a regular file"),
}


def test_a_regime_map_rerun_redoes_a_spoiled_run_folder_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 82, probe 15, T3 (found in accident-seeds, whose accident runs were the regime map's kind): a rerun
    reused every cell on its record alone, then read its run folder's files, and a garbage detectors.xml,
    trajectories.parquet or summary.json (or a folder in its place) ended every rerun in a traceback; a folder
    removed was refused. Now each folder is judged as scenario I judges its own before reuse
    (run_folders.reusable_run), and the run is redone with one line naming it."""
    from coopsumo.config import OutputConfig
    from coopsumo.studies.engine.run_folders import reuse_problem
    from coopsumo.studies.scenario1 import study as scenario1

    out = tmp_path / "rm"
    args = ["--regime-map", "--t-up", "4", "--seeds", "1", "--steps", "600", "--workers", "1", "--quiet", "--out",
            str(out)]  # fmt: skip
    assert scenario1.main(args) == 0
    runs = out / "runs"
    capsys.readouterr()
    written = {name: json.loads((runs / name / "config.json").read_text()) for name in SPOILED_RUNS}

    def whole(name: str) -> bool:  # scenario I would reuse it as it is
        run = written[name]
        return reuse_problem(runs / name, run["config"], OutputConfig(**run["sumo_outputs"])) is None

    for name, (file, spoil, _) in SPOILED_RUNS.items():
        spoil(runs / name / file)
    assert scenario1.main(args) == 0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if " run folder " in line]
    assert "Traceback" not in err and len(lines) == len(SPOILED_RUNS), err
    for name, (_, _, fragment) in SPOILED_RUNS.items():
        line = next(line for line in lines if f" run folder {runs / name} " in line)
        assert line.startswith(f"scenario1: run folder {runs / name} {fragment}"), lines
        assert line.endswith("; running it again"), lines
        assert whole(name) and (runs / name / "trajectories.parquet").is_file()
    shutil.rmtree(runs / "default/t4/keep_seed1")  # a folder removed outright: run again (it was refused)
    assert scenario1.main(args) == 0
    err = capsys.readouterr().err
    gone = runs / "default/t4/keep_seed1"
    assert "Traceback" not in err and f"scenario1: run folder {gone} has no summary.json" in err
    assert whole("default/t4/keep_seed1")
    assert len(pd.read_csv(out / "runs.csv")) == len(SPOILED_RUNS)


def test_a_table_refused_leaves_the_finished_sweep_whole(dqn_spec: dict[str, Any], tmp_path: Path) -> None:
    """Issue 82 (s2A_train_updates_neg): a sweep stopped by its runs.csv check had rewritten its sweep.json without
    its result fields first; now every table and sweep.json are checked before any output is written."""
    from coopsumo.record_schemas import RecordError

    before = {"sweep.json": '{"cells_ok": 8}', "runs.csv": "key\nL2\n", "evals.csv": "key\nL2\n"}
    for name, text in before.items():
        (tmp_path / name).write_text(text)
    record = _record(dqn_spec)
    record["summary"]["loop_occupancy_pct"] = 500.0
    meta = scenario2._sweep_meta(PROFILES["full"], 1, "local", None, 1, 0)
    with pytest.raises(RecordError, match=r"runs.csv row 1 column loop_occupancy_pct must be"):
        scenario2._finish(tmp_path, PROFILES["full"], [record], meta)
    assert {p.name: p.read_text() for p in tmp_path.iterdir()} == before
