"""Issue 67, read-back checks that look inside, for cell records: a scenario II (or ablation) record whose summary
or one of its evaluations was edited is not what its evaluations pool to and is rerun, with one line. An intact
record is reused and left as it was."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from coopsumo.studies import scenario2
from coopsumo.studies.records import cell_path, checked_record, reusable_keys
from coopsumo.studies.scenario2_plan import PROFILES, cell_specs


# -- a scenario II record against its own evaluations -------------------------------------------------------------
def _evaluation(seed: int, speed: float, departed: int, changes: int) -> dict[str, Any]:
    """One evaluation's summary as scenario II keeps it (simulate's summary with the loops' means and its seed)."""
    return {"steps": 700, "sim_seconds": 70.0, "departed": departed, "arrived": departed - 9, "collisions": 0,
            "teleports": 0, "lane_changes": changes, "lane_changes_per_vehicle": changes / departed,
            "mean_speed_mps": speed, "mean_travel_time_s": 48.5 + seed,
            "throughput_veh_per_h": (departed - 9) * 3600 / 70,
            "passing_taken_share": float("nan"), "loop_flow_veh_h_per_lane": 410.5, "loop_occupancy_pct": 2.25,
            "policy": "dqn:train/L2_T4_a0_s1/model.pt", "scenario": "free", "eval_seed": seed}  # fmt: skip


@pytest.fixture
def dqn_spec() -> dict[str, Any]:
    return next(s for s in cell_specs(PROFILES["quick"]) if s.get("policy") != "mobil")


def _record(spec: dict[str, Any]) -> dict[str, Any]:
    """The record of a finished scenario II DQN cell, as _evaluate fills it: three evaluations and their pool."""
    evals = [_evaluation(1, 21.6, 40, 12), _evaluation(11, 22.1, 42, 9), _evaluation(21, 20.9, 39, 15)]
    pooled = {k: v for k, v in scenario2.pool_summaries(evals).items() if k != "eval_seed"}
    return {**scenario2.RECORDS.new(spec), "status": "ok", "eval_summaries": evals, "summary": pooled,
            "train_summary": {"wall_seconds": 3.0}}  # fmt: skip


def _set(key: str, value: Any) -> Callable[[dict[str, Any]], None]:
    return lambda record: record["summary"].update({key: value})


def _set_eval(i: int, key: str, value: Any) -> Callable[[dict[str, Any]], None]:
    return lambda record: record["eval_summaries"][i].update({key: value})


RECORD_CASES: dict[str, tuple[Callable[[dict[str, Any]], None], str]] = {
    "summary speed 21.6 -> 30.0": (_set("mean_speed_mps", 30.0), "mean_speed_mps = 30, but its 3 evaluations pool"),
    "an evaluation's speed edited": (_set_eval(0, "mean_speed_mps", 30.0), "mean_speed_mps = 21.5333"),
    "a collision added to an evaluation": (_set_eval(2, "collisions", 1), "collisions = 0, but"),
    "lane changes scaled in both": (lambda r: r["summary"].update(lane_changes=72, lane_changes_per_vehicle=72 / 121),
                                    "lane_changes = 72"),
    "the loops' flow edited": (_set("loop_flow_veh_h_per_lane", 999.0), "loop_flow_veh_h_per_lane = 999"),
    "an evaluation dropped": (lambda r: r["eval_summaries"].pop(), "its 2 evaluations pool"),
    "an impossible evaluation": (_set_eval(1, "mean_speed_mps", -2.0), "evaluation 2 of 3 with mean_speed_mps = -2"),
    "evaluations not a list": (lambda r: r.update(eval_summaries={"mean_speed_mps": 21.6}), "not a list"),
    "no evaluations": (lambda r: r.update(eval_summaries=[]), "not a list of summaries"),
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


def test_an_intact_record_is_reused_untouched(dqn_spec: dict[str, Any], tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    mobil = next(s for s in cell_specs(replace(PROFILES["tiny"], policies=("dqn", "mobil")))
                 if s.get("policy") == "mobil")  # fmt: skip
    for spec, record in ((dqn_spec, _record(dqn_spec)),
                         (mobil, {**scenario2.RECORDS.new(mobil), "status": "ok",
                                  "summary": _evaluation(1, 21.6, 40, 12)})):  # fmt: skip
        cell_path(tmp_path, spec["key"]).parent.mkdir(exist_ok=True)
        cell_path(tmp_path, spec["key"]).write_text(json.dumps(record))
    before = {p.name: p.read_bytes() for p in (tmp_path / "cells").iterdir()}
    assert reusable_keys(tmp_path, [dqn_spec, mobil], "scenario2", scenario2.REQUIRED_SUMMARY) == {dqn_spec["key"],
                                                                                                    mobil["key"]}
    assert capsys.readouterr().err == ""
    assert {p.name: p.read_bytes() for p in (tmp_path / "cells").iterdir()} == before
    assert checked_record(_record(dqn_spec), scenario2.REQUIRED_SUMMARY)["status"] == "ok"
