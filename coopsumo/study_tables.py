"""Scenario I's and scenario II's tables (runs.csv, summary.csv, evals.csv; scenario II's
sweep.json too), declared as record_schemas declares the
others (a sibling, so that neither module passes 500 lines): each column's type and physical or logical limits, checked
before a study writes its tables (Table.check_frame) and where a table is read back (Table.read), so that a table
outside them is refused in one line naming the file, the row and the column.

A summary's columns follow from its table of runs: every measure's mean (the measure's limits; blank only where the
measure may be), standard deviation (>= 0, blank for one run) and count (a whole number >= 0).
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from coopsumo.config import MAX_LANES, MIN_LANES
from coopsumo.provenance import package_version
from coopsumo.record_schemas import (
    CELL_RECORD,
    CELL_STATUSES,
    LANE_CAPACITY_VEH_H,
    LIST,
    MAPPING,
    MEASURES,
    PER_VEHICLE,
    POLITENESS,
    SEED,
    SHARE,
    SPEED,
    SPEED_MAX_MPS,
    T_UP,
    THROUGHPUT,
    TTS_MAX_VEH_H,
    Field,
    Integer,
    Number,
    Schema,
    Table,
    Text,
)
from coopsumo.report.bottleneck import REGIMES
from coopsumo.validation import ALPHA_MAX, ALPHA_MIN

COUNT = Integer(0)
TRAVEL_TIME = Number(0.0, unit="s", blank_ok=True)
"""a mean travel time: none when no vehicle arrived"""
NEVER = Number(0.0, unit="s after the accident's start", blank_ok=True)
"""a time after the accident's start of something that may never happen (a recovery, a spill to the entrance)"""
VEH_H = Number(0.0, TTS_MAX_VEH_H, unit="veh-h")
WAVE_KMH = SPEED_MAX_MPS * 3.6
"""a wave's front moves no faster than a vehicle, either way (km/h)"""

SCENARIO1_MEASURES = (
    Field("tts_veh_h", VEH_H),
    Field("delay_veh_h", Number(-TTS_MAX_VEH_H, TTS_MAX_VEH_H, unit="veh-h")),  # below 0: faster than v_exp's mean
    Field("waiting_veh_h", VEH_H),
    Field("discharge_veh_h", Number(0.0, MAX_LANES * LANE_CAPACITY_VEH_H, unit="veh/h", blank_ok=True)),
    Field("system_recovery_s", NEVER),
    Field("recovery_time_s", NEVER),
    Field("waves", COUNT),
    Field("wave_speed_kmh", Number(-WAVE_KMH, WAVE_KMH, unit="km/h", blank_ok=True)),  # no wave: none
    Field("slow_regions", COUNT),
    Field("wave_onset_share", Number(0.0, 1.0, blank_ok=True)),  # no loop interval with a speed: none
    Field("queue_m", Number(0.0, unit="m")),
    Field("spilled_s", NEVER),
    Field("waiting_at_end_veh", COUNT),
    Field("mean_speed_mps", SPEED),
    Field("mean_travel_time_s", TRAVEL_TIME),
    Field("throughput_veh_per_h", THROUGHPUT),
    Field("lane_changes_per_vehicle", PER_VEHICLE),
    Field("queue_lane_changes_per_vehicle", PER_VEHICLE),
    Field("collisions", COUNT),
    Field("teleports", COUNT),
)
"""scenario I's measures of one accident run (scenario1.measures.run_metrics), each summarised in summary.csv"""


@dataclasses.dataclass(frozen=True)
class ClosedTable(Table):
    """A Table whose writer writes no other columns than its fields (a `_x` field: every column ending with it) and
    `unchecked` (columns no rule judges: an error's text, a training's folder): read back, a column besides them, or
    a header naming one twice, is a table edited or written by something else, refused in one line naming the column
    (issue 82, probe 16, TR2: a part's `notes` column, and a second mean_speed_mps of 60 m/s that pandas renames
    mean_speed_mps.1, were merged into scenario II's tables). A writer's frame (check_frame) is not judged so."""

    unchecked: tuple[str, ...] = ()
    foreign: str = "no sweep writes"
    """the refusal's words for a column outside the declaration"""

    def columns_problem(self, names: Sequence[str]) -> str | None:
        """Why the header `names` (as written: a column named twice appears twice) is not one the writer writes."""
        counts = Counter(names)
        if twice := [name for name in names if counts[name] > 1]:
            return f"names the column {twice[0]} twice"
        fields = (*self.columns, *(f for fields in self.cases.values() for f in fields))
        known = {f.name for f in fields} | set(self.unchecked)
        ends = tuple(name for name in known if name.startswith("_"))
        if foreign := [name for name in names if name not in known and not (ends and name.endswith(ends))]:
            return f"has a column {self.foreign}: {foreign[0] if foreign[0].strip() else repr(foreign[0])}"
        return None

    def problem(self, names: Sequence[str], rows: Iterable[Mapping[str, Any]], complete: bool = True) -> str | None:
        if complete and (problem := self.columns_problem(names)) is not None:
            return problem
        return super().problem(names, rows, complete)


DEMAND = dataclasses.replace(T_UP, blank_ok=False)
SCENARIO1_RUNS = ClosedTable((
    Field("t_up_s", DEMAND),
    Field("policy", Text()),
    Field("train_seed", SEED),  # a baseline's: none
    Field("seed", Integer(0)),
    *SCENARIO1_MEASURES,
    Field("regime", Text(REGIMES)),
    Field("horizon_after_start_s", Number(0.0, unit="s")),
), foreign="no scenario I study writes")  # fmt: skip
"""scenario I's runs.csv (scenario1.study._runs_table): one row per accident run; a column besides these, or one named
twice, refused on reading (a merge part's `notes` was merged: issue 82, probe 17, TR2)"""


def _summarised(measures: tuple[Field, ...], count: str) -> tuple[Field, ...]:
    """Each measure's mean (its limits, as a number), standard deviation and count (columns ending `count`)."""
    out = []
    for field in measures:
        rule = field.rule
        if isinstance(rule, Integer):
            rule = Number(rule.low, rule.high, blank_ok=rule.blank_ok)
        out += [Field(f"{field.name}_mean", rule), Field(f"{field.name}_std", Number(0.0, blank_ok=True)),
                Field(f"{field.name}{count}", COUNT)]  # fmt: skip
    return tuple(out)


SCENARIO1_SUMMARY = Table((
    Field("t_up_s", DEMAND),
    Field("policy", Text()),
    *_summarised(SCENARIO1_MEASURES, "_n"),
    Field("seeds", Integer(1)),
    Field("models", COUNT),
))  # fmt: skip
"""scenario I's summary.csv (scenario1.measures.aggregate): per demand and policy, over its runs"""

ALPHA = Number(ALPHA_MIN, ALPHA_MAX, blank_ok=True)
"""a learned row's alpha; a baseline's: none"""
_FOLLOWUP_MEASURES = tuple(dataclasses.replace(f, optional=True) if f.name == "queue_lane_changes_per_vehicle" else f
                           for f in SCENARIO1_MEASURES)  # fmt: skip
"""scenario I's measures as the regime map records them (a table written before the queue's lane changes were
measured lacks that column)"""
REGIME_MAP_RUNS = Table((
    Field("accident", Text(("default", "paper"))),
    Field("accident_steps", Integer(1)),
    Field("run_steps", Integer(1)),
    Field("t_up_s", DEMAND),
    Field("inflow_veh_h", THROUGHPUT),
    Field("seed", Integer(0)),
    *_FOLLOWUP_MEASURES,
    Field("regime", Text(REGIMES)),
    Field("horizon_after_start_s", Number(0.0, unit="s")),
), key=("accident", "t_up_s", "seed"))  # fmt: skip
"""the regime map's runs.csv (scenario1.regime_map.run_study): one row per accident length, demand and seed"""

_EVALUATION = (
    *(MEASURES[name] for name in ("mean_speed_mps", "lane_changes_per_vehicle", "throughput_veh_per_h",
                                  "mean_travel_time_s", "collisions", "teleports", "loop_flow_veh_h_per_lane",
                                  "loop_occupancy_pct")),
    *(dataclasses.replace(MEASURES[name], optional=True) for name in ("full_road_speed_mps", "full_road_from_s",
                                                                       "wall_seconds")),
)  # fmt: skip
"""an evaluation's measures (record_schemas.MEASURES' rules, a cell record's summary checked by the same)"""
_COORDINATES = (
    Field("key", Text()),
    Field("lanes", Integer(MIN_LANES, MAX_LANES)),
    Field("t_up_s", Number(0.0, 3600.0, low_open=True, unit="s")),
    Field("load", Number(0.0, low_open=True)),
    Field("policy", Text()),  # dqn, mobil; per_alpha in the check profile
    Field("alpha", ALPHA),  # a MOBIL row: none
    Field("p", POLITENESS),  # a DQN row: none
)


SCENARIO2_EVALS = ClosedTable((*_COORDINATES, Field("eval_seed", Integer(0)), *_EVALUATION), key=("key", "eval_seed"),
                              unchecked=("seed",))  # the training seed: the cell's key names it
"""scenario II's evals.csv (scenario2.measures.evals_table): one row per evaluation run of a successful cell"""
_RUN_MEASURES = tuple(dataclasses.replace(MEASURES[name], optional=True)
                      for name in ("sim_seconds", "steps_per_second", "decision_interval_steps",
                                   "mean_vehicles_on_road", "sumo_collisions"))  # fmt: skip


def _trained(name: str) -> Field:
    """runs.csv's column train_<name>: the training summary's measure, by its rule (blank: none trained)."""
    rule = MEASURES[name].rule
    assert isinstance(rule, Number | Integer)
    return Field(f"train_{name}", dataclasses.replace(rule, blank_ok=True), optional=True)


_TRAINED = tuple(_trained(name) for name in ("mean_speed_mps", "lane_changes", "collisions", "updates"))
"""the training's measures runs.csv copies from a cell record's train_summary (a MOBIL row: none)"""
RUN_DIAGNOSTICS = ("table_max_dev_pos_m", "table_max_dev_speed_mps", "table_mismatch_step")
"""a run's summary's check of the advanced vehicle table against SUMO's (sim.world's _table_check; -1: not checked),
which runs.csv copies and no rule judges (records.implausible leaves them out)"""
_RUN_COUNTS = ("steps", "departed", "arrived", "insertion_blocked", "insertion_pending_at_end", "lane_changes",
               "lane_changes_rejected")  # fmt: skip
SCENARIO2_RUNS = ClosedTable((*_COORDINATES, Field("status", Text())), case="status", key=("key",), cases={"ok": (
    Field("_share", dataclasses.replace(SHARE, blank_ok=True)),  # held_share, ...; passing_taken_share: may be none
    *_EVALUATION,
    *(dataclasses.replace(MEASURES[name], optional=True) for name in _RUN_COUNTS),
    *_RUN_MEASURES,
    *_TRAINED,
    Field("train_wall_seconds", Number(0.0, unit="s", blank_ok=True), optional=True),
    *(field for field in CELL_RECORD.fields if field.name in ("cell_wall_s", "cell_cpu_s", "train_group_cpu_s",
                                                              "resumed_from_step")),
)}, unchecked=("seed", "error", "train_dir", *RUN_DIAGNOSTICS))  # fmt: skip
"""scenario II's runs.csv (scenario2.measures.runs_table): one row per cell, its pooled evaluations and its training's
measures when ok (a failed cell's numbers are blank), each by the rule its cell record is checked by"""

SWEEP_COUNTS = ("cells", "cells_ok", "cells_failed", "cells_run", "trainings", "workers", "bootstrap_replicates")
"""sweep.json values that count something: whole numbers >= 0"""
SWEEP_SECONDS = ("wall_seconds", "cell_wall_seconds_sum", "cell_cpu_seconds_sum")
"""sweep.json times (s), which a merge adds up: finite numbers >= 0"""
SWEEP = Schema((
    Field("profile", MAPPING),
    Field("learner", MAPPING),
    Field("conditions", LIST),
    *(Field(name, Integer(0)) for name in SWEEP_COUNTS),
    *(Field(name, Number(0.0, unit="s")) for name in SWEEP_SECONDS),
    Field("failed_cells", LIST),
    Field("failed_cells.*", Text()),
    Field("backend", Text()),
    Field("versions", MAPPING),
    Field("versions.*", Text()),  # provenance.versions: each a text ("not installed", "unknown" too)
    Field("versions.coopsumo", Text((package_version("coopsumo"),))),  # a sweep this coopsumo wrote, and can merge
    Field("versions.coopsumo_source", Text()),
    Field("criterion", Text()),  # its profile's (redraw._meta_problem)
    Field("nominal_capacity_veh_h_per_lane", Number(0.0, LANE_CAPACITY_VEH_H, low_open=True, unit="veh/h per lane")),
))  # fmt: skip
"""a finished scenario II sweep's sweep.json (scenario2.study.run_sweep's meta), as a merge reads a part's (its
versions those of this coopsumo, each a text: issue 82, probe 13, F14, coopsumo "9.9" and torch null were merged and
reported as "(source ?)"); what must agree with its profile (its learner per lane count, its conditions, its cell
count, its criterion) and with itself (cells_ok and cells_failed adding up to cells) is redraw._meta_problem's"""

_OPTIONAL_SHARE = dataclasses.replace(SHARE, blank_ok=True)
PROTOCOL_RUNS = Table(
    columns=(Field("key", Text()), Field("kind", Text(("model", "baseline"))), Field("variant", Text()),
             Field("alpha", ALPHA), Field("seed", SEED), Field("scenario", Text(("free", "accident"))),
             Field("t_up", DEMAND), Field("eval_seed", SEED), Field("weights", Text(blank_ok=True)),
             Field("train_key", Text(blank_ok=True)), Field("status", Text(CELL_STATUSES))),
    case="status",
    cases={"ok": (Field("mean_speed_mps", SPEED), Field("tts_veh_h", dataclasses.replace(VEH_H, blank_ok=True)),
                  Field("lane_changes_per_vehicle", PER_VEHICLE),
                  Field("queue_lane_changes_per_vehicle", dataclasses.replace(PER_VEHICLE, blank_ok=True),
                        optional=True),
                  Field("collisions", COUNT), Field("teleports", COUNT),
                  Field("selected_step", Integer(0, blank_ok=True), optional=True),
                  *(Field(name, _OPTIONAL_SHARE, optional=True)
                    for name in ("held_share", "passing_open_share", "passing_taken_share")))},
    key=("key",),
)  # fmt: skip
"""a learner protocol study's runs.csv (protocol.report.runs_table): one row per cell, its measures when ok (free flow
has no total time spent; a table of before the queue's lane changes, the selected step or the passing chances lacks
those columns), as a study paired with it reads it (protocol.paired; issue 82, probe 7, I7)"""


def csv_header(path: Path) -> list[str]:
    """A CSV file's column names as written (pandas renames the second of two alike: x, x.1), for
    ClosedTable.columns_problem."""
    from coopsumo.files import read_csv

    return [str(v) for v in read_csv(path, header=None, nrows=1, dtype=str, keep_default_na=False).iloc[0]]
