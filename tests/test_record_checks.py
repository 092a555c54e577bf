"""Issue 67, read-back checks that look inside, for cell records: a scenario II (or ablation) record whose summary
or one of its evaluations was edited is not what its evaluations pool to and is rerun; a cell of accident-seeds is
tied to the model file it drives (its sha256) and is rerun, with one line, when the file was replaced or cut short
since, and its run folder is redone, with one line, when its files cannot be trusted; a scenario II record whose
train/ link was pointed at another model is rerun, the link put back. An intact record is reused and left as it
was."""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
import test_scenario2
from test_study_commands import learning_folder

from coopsumo.studies.engine.records import (
    cell_path,
    checked_record,
    copied_wrong,
    model_fields,
    pool_summaries,
    reusable_keys,
)
from coopsumo.studies.followups import accident_seeds
from coopsumo.studies.scenario1 import accident_runs as scenario1_cells
from coopsumo.studies.scenario1 import plan as scenario1_plan
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


# -- a cell tied to the model file it drives ------------------------------------------------------------------------
def _swap(model: Path) -> None:
    """Another model of the same training in its place: other weights, the same configuration (it loads)."""
    import torch

    from coopsumo.agents.model_file import load_model, save_model

    net, meta = load_model(model)
    with torch.no_grad():
        for weights in net.parameters():
            weights.add_(0.01)
    save_model(model, net, meta)


def _cut(model: Path) -> None:
    model.write_bytes(model.read_bytes()[: model.stat().st_size // 2])


def _older_file(model: Path) -> None:
    """Other bytes, written long before the record (a link moved to an older model keeps the path)."""
    model.write_bytes(model.read_bytes() + b"\0")
    os.utime(model, (1_000_000_000, 1_000_000_000))


MODEL_CASES: dict[str, tuple[Callable[[Path], None], str]] = {
    "swapped": (_swap, "has changed since (sha256)"),
    "truncated": (_cut, "has changed since (sha256)"),
    "replaced by an older file": (_older_file, "has changed since (sha256)"),
}


@pytest.mark.parametrize("case", MODEL_CASES)
def test_an_accident_seeds_run_of_a_changed_model_is_rerun_with_one_line(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """accident-seeds' cells carry their model's sha256; a record made with another is rerun, baselines are kept."""
    root = learning_folder(tmp_path / "learning", ("paper",))
    out = tmp_path / "acc"
    found = accident_seeds.models(root, ("paper",), (0.0,), 1)
    plan = accident_seeds.accident_runs.scaled(scenario1_plan.PROFILES["default"], 0.03)

    def specs() -> list[dict[str, Any]]:
        who = accident_seeds.drivers(found, False, out / "models")
        return [spec for _, _, spec in accident_seeds.cells(who, (3.0,), [0], plan)]

    model = found[0]["model"]
    assert [s.get("model_sha256") for s in specs()] == [None] * 3 + [model_fields(model)["model_sha256"]]
    for spec in specs():  # each cell's record as the run left it (scenario I's run cell)
        cell_path(out, spec["key"]).parent.mkdir(parents=True, exist_ok=True)
        summary = {"mean_speed_mps": 20.0, "collisions": 0, "teleports": 0}
        record = {**scenario1_cells.RECORDS.new(spec), "status": "ok", "summary": summary}
        cell_path(out, spec["key"]).write_text(json.dumps(record))
    before = {p.name: p.read_bytes() for p in (out / "cells").iterdir()}
    required = accident_seeds.accident_runs.REQUIRED
    assert reusable_keys(out, specs(), "accident-seeds", required) == {s["key"] for s in specs()}
    assert capsys.readouterr().err == ""
    change, fragment = MODEL_CASES[case]
    change(model)
    now = specs()
    assert reusable_keys(out, now, "accident-seeds", required) == {s["key"] for s in now[:3]}  # the baselines kept
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"accident-seeds: cell {now[3]['key']}: record "), lines
    assert fragment in lines[0] and str(model) in lines[0] and lines[0].endswith("; rerunning it"), lines
    assert {p.name: p.read_bytes() for p in (out / "cells").iterdir()} == before  # judging writes nothing


def test_accident_seeds_refuses_a_cut_short_model_it_drives_through_a_copy(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A margin variant drives a copy of its model that carries the margin, written from the model each time: a model
    cut short is refused in one line before anything is written (it was a traceback)."""
    root = learning_folder(tmp_path / "learning")
    model = accident_seeds.models(root, ("margin",), (0.0,), 1)[0]["model"]
    _cut(model)
    out = tmp_path / "acc"
    args = [str(root), "--variants", "margin", "--seeds", "1", "--t-up", "3", "--steps", "600", "--out", str(out)]
    assert accident_seeds.main(args) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and f"cannot read model file {model}" in lines[0] and "leave its variant out" in lines[0]
    assert not out.exists()


def _garbage(path: Path) -> None:
    path.write_text("garbage")


def _folder(path: Path) -> None:
    path.unlink()
    path.mkdir()


SPOILED_RUNS: dict[str, tuple[str, Callable[[Path], None], str]] = {  # run folder: (its file, the edit, the line)
    "t3_keep_seed0": ("detectors.xml", _garbage, "has a missing or cut-short detectors.xml"),
    "t3_greedy_seed0": ("trajectories.parquet", _garbage, "has an unreadable trajectories.parquet"),
    "t3_mobil_p0_seed0": ("trajectories.parquet", _folder, "has a trajectories.parquet that is not a regular file"),
    "t3_paper_alpha0_train0_seed0": ("summary.json", _garbage, "has an unreadable summary.json (JSONDecodeError)"),
}


def test_an_accident_seeds_rerun_redoes_a_spoiled_run_folder_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 82, probe 15, T3: a rerun reused every cell on its record alone, then read its run folder's files, and
    a garbage detectors.xml, trajectories.parquet or summary.json (or a folder in its place) ended every rerun in a
    traceback; a folder removed was refused. Now each folder is judged as scenario I judges its own before reuse
    (run_folders.reusable_run), and the run is redone with one line naming it."""
    from coopsumo.config import OutputConfig
    from coopsumo.studies.engine.run_folders import reuse_problem

    root = learning_folder(tmp_path / "learning", ("paper",))
    out = tmp_path / "acc"
    args = [str(root), "--variants", "paper", "--seeds", "1", "--t-up", "3", "--steps", "300", "--workers", "1",
            "--quiet", "--out", str(out)]  # fmt: skip
    assert accident_seeds.main(args) == 0
    runs = out / "runs" / "t3"
    err = capsys.readouterr().err  # the study's one line of what it runs
    assert sorted(p.name for p in runs.iterdir()) == sorted(SPOILED_RUNS) and err == (
        f"accident-seeds: profile default: {len(SPOILED_RUNS)} cells, 0 already done, 0 failed before (retried), "
        f"{len(SPOILED_RUNS)} to run on the local backend\n"), err
    written = {name: json.loads((runs / name / "config.json").read_text()) for name in SPOILED_RUNS}

    def whole(name: str) -> bool:  # scenario I would reuse it as it is
        run = written[name]
        return reuse_problem(runs / name, run["config"], OutputConfig(**run["sumo_outputs"])) is None

    for name, (file, spoil, _) in SPOILED_RUNS.items():
        spoil(runs / name / file)
    assert accident_seeds.main(args) == 0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if " run folder " in line]
    assert "Traceback" not in err and len(lines) == len(SPOILED_RUNS), err
    for name, (_, _, fragment) in SPOILED_RUNS.items():
        line = next(line for line in lines if f" run folder {runs / name} " in line)
        assert line.startswith(f"accident-seeds: run folder {runs / name} {fragment}"), lines
        assert line.endswith("; running it again"), lines
        assert whole(name) and (runs / name / "trajectories.parquet").is_file()
    shutil.rmtree(runs / "t3_keep_seed0")  # a folder removed outright: run again (it was refused)
    assert accident_seeds.main(args) == 0
    err = capsys.readouterr().err
    assert "Traceback" not in err and f"accident-seeds: run folder {runs / 't3_keep_seed0'} has no summary.json" in err
    assert whole("t3_keep_seed0")
    assert len(pd.read_csv(out / "runs.csv")) == len(SPOILED_RUNS)


def test_a_record_from_before_digests_is_judged_by_time(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    model = tmp_path / "model.pt"
    model.write_bytes(b"weights")
    spec = {"key": "c1", "config": {"x": 1}, **model_fields(model)}
    path = cell_path(tmp_path, "c1")
    path.parent.mkdir()
    path.write_text(json.dumps({"key": "c1", "config": {"x": 1}, "status": "ok", "summary": {"v": 1.0}}))
    os.utime(model, (1_000_000_000, 1_000_000_000))  # the model written before the record: reused
    assert reusable_keys(tmp_path, [spec], "study", ("v",)) == {"c1"}
    os.utime(model, (path.stat().st_mtime + 10, path.stat().st_mtime + 10))  # written after it: rerun
    assert reusable_keys(tmp_path, [spec], "study", ("v",)) == set()
    assert f"record {path} is older than its model {model}; rerunning it" in capsys.readouterr().err
    # the same bytes written again after the record (copied back, restored) with the digest recorded: reused
    path.write_text(json.dumps({"key": "c1", "config": {"x": 1}, "status": "ok", "summary": {"v": 1.0},
                                **model_fields(model)}))  # fmt: skip
    os.utime(model, (path.stat().st_mtime + 10, path.stat().st_mtime + 10))
    assert reusable_keys(tmp_path, [spec], "study", ("v",)) == {"c1"}
    assert capsys.readouterr().err == ""


def _copied_in(model: Path, other: Path) -> None:
    """Another learner's model file copied over this one (the probe's: default alpha 1 over the paper model)."""
    shutil.copyfile(other, model)


def _linked_to(model: Path, other: Path) -> None:
    """The study's train/<key> made a link to another training's folder."""
    shutil.rmtree(model.parent)
    model.parent.symlink_to(other.parent, target_is_directory=True)


@pytest.mark.parametrize("change", [_copied_in, _linked_to])
def test_a_model_of_another_training_is_never_driven_as_this_one(
    change: Callable[[Path, Path], None], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 82: accident-seeds drove a model swapped in from another learner as the study's; now refused in one
    line naming the file, exit code 2, nothing written."""
    root = learning_folder(tmp_path / "learning")
    margin, conditioned = (accident_seeds.models(root, (v,), (0.0,), 1)[0]["model"] for v in ("margin", "conditioned"))
    change(margin, conditioned)
    out = tmp_path / "acc"
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    code = accident_seeds.main([str(root), "--variants", "margin", "--seeds", "1", "--t-up", "3", "--steps", "600",
                                "--out", str(out), "--quiet"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert str(margin.parent) in err and ("made by another training" in err or "not to " in err), err
    assert f"not the model record {root / 'cells'}" in err, err
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before and not out.exists()


# -- a learning study's training records, as accident-seeds reads them ---------------------------------------------
@pytest.mark.parametrize(("field", "value"), [("alpha", -1.0), ("seed", 2.5), ("cell_wall_s", -3.0), ("key", 7),
                                              ("config", None)])  # fmt: skip
def test_a_training_record_outside_its_schema_is_skipped_with_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], field: str, value: Any) -> None:  # fmt: skip
    """Issue 82: accident-seeds drives a learning study's finished trainings (learning.models.finished_trainings);
    a training's record outside record_schemas.CELL_RECORD is not driven, with one line naming the file and field."""
    from coopsumo.studies.learning.models import finished_trainings

    root = learning_folder(tmp_path / "learning", ("paper",))
    assert len(finished_trainings(root, "accident-seeds")) == 1 and capsys.readouterr().err == ""
    path = next((root / "cells").glob("*.json"))
    path.write_text(json.dumps({**json.loads(path.read_text()), "cell_wall_s": 5.0, field: value}))
    assert finished_trainings(root, "accident-seeds") == []
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"accident-seeds: record {path} cannot be used (field {field} must be")
    assert err[0].endswith("; skipped"), err


@pytest.mark.parametrize(("field", "value", "fragment"), [
    ("mean_speed_mps", 999.0, "has train_summary mean_speed_mps must be a finite number >= 0 and <= 70 (m/s), got 999"),
    ("collisions", -5, "has train_summary collisions must be "),
    ("updates", "many", 'has train_summary updates = "many", not a number')])  # fmt: skip
def test_a_training_record_the_learning_study_would_rerun_is_skipped_with_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], field: str, value: Any, fragment: str) -> None:  # fmt: skip
    """Issue 82, probe 8, J14: accident-seeds drove the model of a learning record whose train_summary held 999 m/s
    (or -5 collisions), which the learning study itself reruns. Skipped by the study's own check (records.cell_problem),
    with one line naming the file and the field."""
    from coopsumo.studies.learning.models import finished_trainings

    root = learning_folder(tmp_path / "learning", ("paper",))
    assert len(finished_trainings(root, "accident-seeds")) == 1 and capsys.readouterr().err == ""
    path = next((root / "cells").glob("*.json"))
    record = json.loads(path.read_text())
    path.write_text(json.dumps({**record, "train_summary": {**record["train_summary"], field: value}}))
    assert finished_trainings(root, "accident-seeds") == []
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"accident-seeds: record {path} cannot be used ({fragment}"), err
    assert err[0].endswith("; skipped"), err


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
