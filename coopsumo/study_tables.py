"""Scenario I's and the learning study's tables (runs.csv, summary.csv), declared as record_schemas declares the
others (a sibling, so that neither module passes 500 lines): each column's type and physical or logical limits, checked
before a study writes its tables (Table.check_frame) and where a table is read back (Table.read), so that a table
outside them is refused in one line naming the file, the row and the column.

A summary's columns follow from its table of runs: every measure's mean (the measure's limits; blank only where the
measure may be), standard deviation (>= 0, blank for one run) and count (a whole number >= 0).
"""

from __future__ import annotations

import dataclasses

from coopsumo.config import MAX_LANES
from coopsumo.record_schemas import (
    CELL_STATUSES,
    LANE_CAPACITY_VEH_H,
    SEED,
    SPEED,
    SPEED_MAX_MPS,
    T_UP,
    TTS_MAX_VEH_H,
    Field,
    Integer,
    Number,
    Table,
    Text,
)
from coopsumo.report.bottleneck import REGIMES
from coopsumo.validation import ALPHA_MAX, ALPHA_MIN

COUNT = Integer(0)
PER_VEHICLE = Number(0.0, 1000.0, unit="per vehicle")
"""lane changes per vehicle: a few in a real run (a vehicle changes lane at most once in its 4 s manoeuvre)"""
THROUGHPUT = Number(0.0, MAX_LANES * LANE_CAPACITY_VEH_H, unit="veh/h")
"""a road's flow: at most config.MAX_LANES lanes at a lane's capacity"""
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
DEMAND = dataclasses.replace(T_UP, blank_ok=False)
SCENARIO1_RUNS = Table((
    Field("t_up_s", DEMAND),
    Field("policy", Text()),
    Field("train_seed", SEED),  # a baseline's: none
    Field("seed", Integer(0)),
    *SCENARIO1_MEASURES,
    Field("regime", Text(REGIMES)),
    Field("horizon_after_start_s", Number(0.0, unit="s")),
))  # fmt: skip
"""scenario I's runs.csv (scenario1.study._runs_table): one row per accident run"""


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

LEARNING_MEASURES = (
    Field("mean_speed_mps", SPEED),
    Field("lane_changes_per_vehicle", PER_VEHICLE),
    Field("lane_changes_rejected", COUNT),
    Field("teleports", COUNT),
    Field("collisions", COUNT),
    Field("throughput_veh_per_h", THROUGHPUT),
    Field("mean_travel_time_s", TRAVEL_TIME),
)
"""the learning study's measures of a cell (learning.plan.METRICS): its evaluations pooled"""
TRAIN_WALL = Field("train_wall_s", Number(0.0, unit="s", blank_ok=True))  # a baseline trains nothing
ALPHA = Number(ALPHA_MIN, ALPHA_MAX, blank_ok=True)
"""a learned cell's alpha; a baseline's: none"""
PARTS = ("ablation", "alpha", "baseline")
LEARNING_RUNS = Table(
    columns=(Field("key", Text()), Field("kind", Text(("train", "baseline"))), Field("part", Text(PARTS)),
             Field("variant", Text()), Field("alpha", ALPHA), Field("seed", Integer(0)), Field("eval_seed", SEED),
             Field("status", Text(CELL_STATUSES)),
             Field("train_mean_speed_mps", dataclasses.replace(SPEED, blank_ok=True)),
             Field("train_lane_changes", Integer(0, blank_ok=True)), TRAIN_WALL,
             Field("train_steps_per_s", Number(0.0, unit="steps/s", blank_ok=True)),
             Field("train_updates", Integer(0, blank_ok=True)),
             Field("cell_wall_s", Number(0.0, unit="s", blank_ok=True))),
    case="status",
    cases={"ok": LEARNING_MEASURES},
)  # fmt: skip
"""the learning study's runs.csv (learning.report.runs_table): one row per cell, its measures when ok (a failed cell's:
blank)"""
LEARNING_SUMMARY = Table((
    Field("variant", Text(blank_ok=True)),  # archived studies' alpha rows: none
    *_summarised((*LEARNING_MEASURES, TRAIN_WALL), "_count"),
    Field("part", Text(PARTS)),
    Field("alpha", ALPHA),  # the alpha response's rows only
))  # fmt: skip
"""the learning study's summary.csv (learning.report.write_outputs): per part, variant (and alpha), over its models"""

_FOLLOWUP_MEASURES = tuple(dataclasses.replace(f, optional=True) if f.name == "queue_lane_changes_per_vehicle" else f
                           for f in SCENARIO1_MEASURES)  # fmt: skip
"""scenario I's measures as the follow-ups record them (a table written before the queue's lane changes were measured
lacks that column)"""
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
"""the regime map's runs.csv (followups.regime_map.run_study): one row per accident length, demand and seed"""
ACCIDENT_SEEDS_RUNS = Table((
    Field("variant", Text()),
    Field("alpha", ALPHA),  # a baseline's and an adaptive driver's: none
    Field("t_up_s", DEMAND),
    Field("seed", Integer(0)),
    Field("adaptive_alpha_mean", ALPHA, optional=True),  # one alpha: none; a table before adaptive drivers: no column
    *_FOLLOWUP_MEASURES,
    Field("regime", Text(REGIMES)),
    Field("horizon_after_start_s", Number(0.0, unit="s")),
), key=("variant", "alpha", "t_up_s", "seed"))  # fmt: skip
"""accident-seeds' runs.csv (followups.accident_seeds.run_study): one row per driver, demand and accident seed"""
