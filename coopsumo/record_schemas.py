"""One schema per record kind the project writes and reads back, its fields' types and physical or logical limits
declared here as data, so that the writer and every reader agree and a record outside them is refused (or redone,
where its reader redoes a bad record) in one line naming the file and the field.

Built on field_rules (the flags' own NumberRule and IntRule), not on pydantic or pandera: neither is installed (a
dependency for a few dozen lines of declarations), the records are read by pandas, torch, XML and JSON alike (pydantic
covers the JSON ones, pandera the tables only, each with multi-line error reports to reword into one line), and the
flags' rules already word a refusal the way the commands do ("must be a finite number >= 0 and <= 70, got 999").

A field is a dotted name into the record (`sim.reward.alpha`; `*` for every key or item at that level, `*_mps` for
every key ending with `_mps`) and a rule: a Number or an Integer (field_rules' bounds, plus the type), Text (a string,
maybe one of a few) or a Kind (a mapping, a list, a bool). Schema.problem checks a JSON record, Table.problem a
table's rows (Table.check_frame a pandas table before it is written), tensor_problem a checkpoint's or model's
nested tensors (bounds and wholeness; the caller gives each tensor's min, max and first entry that is not whole, so
that torch is not imported here). The limits are ones a real run never reaches; the comment of each says why.

Record kinds covered: a training checkpoint and a model file's tensors (CHECKPOINT_TENSORS, MODEL_TENSORS), a stored
model's config.json (STORE_CONFIG), a run's summary (RUN_SUMMARY) and detectors.xml intervals (DETECTOR_INTERVAL), a
learner protocol study's study.json and stats.csv (PROTOCOL_STUDY, PROTOCOL_STATS), a study's cell record
(CELL_RECORD); scenario I's, scenario II's (sweep.json too) and the regime map's tables are
declared alike in the sibling module study_tables, a run's measures by the rules here (MEASURES). Elsewhere:
scenario I's plan.json is read through its typed Plan (scenario1.merge), the studies' TOML data through the flags'
own rules (field_rules, read by catalogue.Entry).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from typing import Any

from coopsumo.config import MAX_LANES, MIN_LANES, SPEED_LIMIT_MPS
from coopsumo.errors import UsageError, why_unreadable
from coopsumo.field_rules import IntRule, NumberRule, as_float, shown
from coopsumo.validation import ALPHA_MAX, ALPHA_MIN, MOBIL_LIMITS

SPEED_MAX_MPS = SPEED_LIMIT_MPS[1]
"""no vehicle goes faster (70 m/s, 252 km/h: the largest speed limit a road takes, config.SPEED_LIMIT_MPS): a recorded
speed above it is not a measurement"""
LANE_CAPACITY_VEH_H = 3600.0
"""no lane carries more vehicles an hour: one a second (the Newell model's capacity is about 2,000, committed loops
peak at 2,160; SUMO's own models, the `sumo` baseline with its 1 s headway, count up to 47 vehicles in a minute on
one lane, 2,820 veh/h, where scenario I's queue discharges: a limit of 2,600 had those runs rerun every time)"""
WEIGHT_MAX = 1e6
"""a network weight's magnitude: trained weights stay below 10; above this the training diverged or was edited"""
REWARD_MAX = 1e6
"""a stored reward's or observed feature's magnitude: a step's reward is a few units (speed, penalty alpha <= 1000,
flow)"""
MOMENT_MAX = 1e6
"""Adam's first moment's magnitude (an average of clipped gradients); its second moment lies in [0, MOMENT_MAX^2]"""
LOSS_MAX = 1e12
"""a TD loss (Huber or squared, averaged over a batch): a TD error of REWARD_MAX squared; real losses stay below 10
(a window's and train_log.csv's; issue 82, probe 13, F4: 1e300 was resumed and logged)"""
TTS_MAX_VEH_H = 1e6
"""total time spent through the accident: at most every departure (one per lane and 0.1 s step) for the whole run"""


class RecordError(UsageError):
    """A record outside its schema: one line naming the file and the field (exit code 2, as bad input)."""


@dataclasses.dataclass(frozen=True)
class Number:
    """A finite number (not a bool) inside field_rules' bounds; `also`: values that stand for "no value" (SUMO's
    speed -1 of an interval without a vehicle); blank_ok: NaN (a table's empty cell) or None stands for one too."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    unit: str = ""
    also: tuple[float, ...] = ()
    blank_ok: bool = False

    def problem(self, value: Any) -> str | None:
        unit = f" ({self.unit})" if self.unit else ""
        if self.blank_ok and _blank(value):
            return None
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            return f"must be a number{unit}, got {_shown(value)}"
        if value in self.also:
            return None
        rule = NumberRule(self.low, self.high, self.low_open, self.high_open, unit)
        number = as_float(value)  # a 400-digit integer: +-inf, shown as the record gives it
        return rule.problem(value if isinstance(value, numbers.Integral) and math.isinf(number) else number)


@dataclasses.dataclass(frozen=True)
class Integer:
    """An integer (a whole float as a table reads it too, not a bool) from low to high; blank_ok: NaN or None stands
    for "none" (a baseline's training seed)."""

    low: int = 0
    high: int | None = None
    blank_ok: bool = False

    def problem(self, value: Any) -> str | None:
        if self.blank_ok and _blank(value):
            return None
        if isinstance(value, numbers.Integral) and not isinstance(value, bool):
            rule = IntRule(self.low, self.high)
            if math.isinf(as_float(value)):  # 400 digits: out of limits, also where no upper one is set
                return f"must be {rule.words()} (finite as a float), got {_shown(value)}"
            return rule.problem(int(value))
        number = float(value) if isinstance(value, numbers.Real) and not isinstance(value, bool) else math.nan
        if not (math.isfinite(number) and number == int(number)):
            return f"must be an integer, got {_shown(value)}"
        return IntRule(self.low, self.high).problem(int(number))


@dataclasses.dataclass(frozen=True)
class Text:
    """A string, one of `choices` when given, not empty; blank_ok: NaN or None stands for "none" (no error)."""

    choices: tuple[str, ...] = ()
    blank_ok: bool = False

    def problem(self, value: Any) -> str | None:
        if self.blank_ok and _blank(value):
            return None
        if not isinstance(value, str) or not value:
            return f"must be a text, got {_shown(value)}"
        if self.choices and value not in self.choices:
            return f"must be one of {', '.join(self.choices)}, got {_shown(value)}"
        return None


@dataclasses.dataclass(frozen=True)
class Kind:
    """A value of a Python type (a mapping, a list, a bool), its contents checked by other fields."""

    types: tuple[type, ...]
    words: str

    def problem(self, value: Any) -> str | None:
        return None if isinstance(value, self.types) else f"must be {self.words}, got {_shown(value)}"


Rule = Number | Integer | Text | Kind
MAPPING = Kind((Mapping,), "a mapping")
LIST = Kind((list, tuple), "a list")
FLAG = Kind((bool,), "true or false")
MAPPING_OR_NULL = Kind((Mapping, type(None)), "a mapping or null")


def _blank(value: Any) -> bool:
    """None, or NaN (a table's empty cell)."""
    return value is None or (isinstance(value, float) and math.isnan(value))


def _shown(value: Any) -> str:
    return shown(value)


@dataclasses.dataclass(frozen=True)
class Field:
    """One field of a record: its dotted name (`*` for every key or item at that level), rule, and whether a record
    may lack it."""

    name: str
    rule: Rule
    optional: bool = False


_MISSING = object()


def values_at(record: Any, name: str) -> Iterator[tuple[str, Any]]:
    """(the dotted name with every `*` filled in, value) of each value at `name` in the nested mappings and lists
    `record`; _MISSING where a key is absent or a level is not a mapping or list."""
    head, _, rest = name.partition(".")
    if head.startswith("*"):  # every key or item; `*_mps`: every key ending with `_mps`
        items = record.items() if isinstance(record, Mapping) else enumerate(record) \
            if isinstance(record, list | tuple) and head == "*" else ()  # fmt: skip
        for key, value in items:
            if not str(key).endswith(head[1:]):
                continue
            for where, found in values_at(value, rest) if rest else [("", value)]:
                yield (f"{key}.{where}" if where else str(key)), found
        return
    value = record.get(head, _MISSING) if isinstance(record, Mapping) else _MISSING
    if not rest or value is _MISSING:
        yield head, value
        return
    for where, found in values_at(value, rest):
        yield f"{head}.{where}", found


@dataclasses.dataclass(frozen=True)
class Schema:
    """A JSON record's fields, checked in order: the first one outside its rule is the problem."""

    fields: tuple[Field, ...]

    def problem(self, record: Any) -> str | None:
        """Why `record` breaks the schema ("field sim.reward.alpha must be a number, got 'x'"), or None."""
        if not isinstance(record, Mapping):
            return f"is not a JSON object (got {type(record).__name__})"
        for field in self.fields:
            for where, value in values_at(record, field.name):
                if value is _MISSING:
                    if field.optional:
                        continue
                    return f"has no field {where}"
                if (problem := field.rule.problem(value)) is not None:
                    return f"field {where} {problem}"
        return None

    def check(self, record: Any, path: object) -> None:
        """RecordError "PATH field ... must be ..." when `record` breaks the schema (before it is written or used)."""
        if (problem := self.problem(record)) is not None:
            raise RecordError(f"{path} {problem}")


@dataclasses.dataclass(frozen=True)
class Table:
    """A table's columns: `columns` every row has (a field named `_x` is the rule of every column whose name ends
    with it, a baseline's `keep_value` and `greedy_value`, and is not required); `cases`: the rules of columns whose
    unit depends on another column's value (`case`: the scenario, free or accident)."""

    columns: tuple[Field, ...]
    case: str = ""
    cases: Mapping[str, tuple[Field, ...]] = dataclasses.field(default_factory=dict)
    key: tuple[str, ...] = ()  # the columns that name a row: no two rows may share their values

    def problem(self, names: Sequence[str], rows: Iterable[Mapping[str, Any]], complete: bool = True) -> str | None:
        """Why the table (its column names, its rows as mappings) breaks the schema ("row 3 column iqm must be ...",
        rows counted from 1 after the header), or None. complete=False: a row may lack its case's columns (a writer
        that measured none of them)."""
        required = [f.name for f in self.columns if not f.optional and not f.name.startswith("_")]
        if missing := [name for name in required if name not in names]:
            return f"has no column {missing[0]}"
        rules = _rules(self.columns, names)
        cases = {case: {**rules, **_rules(fields, names)} for case, fields in self.cases.items()}
        lacking = {case: [f.name for f in fields if not (f.optional or f.name.startswith("_") or f.name in names)]
                   for case, fields in self.cases.items() if complete}  # fmt: skip
        count, seen = 0, dict[tuple[Any, ...], int]()
        for count, row in enumerate(rows, 1):
            if lacking.get(case := str(row.get(self.case))):
                return f"row {count} ({self.case} {case}) has no column {lacking[case][0]}"
            for name, rule in cases.get(case, rules).items():
                if name in row and (problem := rule.problem(_plain(row[name]))) is not None:
                    return f"row {count} column {name} {problem}"
            named = tuple(_plain(row.get(k)) for k in self.key)
            if self.key and named in seen:
                where = ", ".join(f"{k} {_shown(v)}" for k, v in zip(self.key, named, strict=True))
                return f"rows {seen[named]} and {count} are both the row of {where}"
            seen[named] = count
        return None if count else "has no row"

    def check(self, names: Sequence[str], rows: Iterable[Mapping[str, Any]], path: object) -> None:
        """RecordError "PATH row 3 column iqm must be ..." when the table breaks the schema."""
        if (problem := self.problem(names, rows)) is not None:
            raise RecordError(f"{path} {problem}")

    def read(self, path: Any) -> Any:
        """The table in the CSV file `path` as a pandas DataFrame, every row inside the schema; RecordError naming the
        file (and the row and column) when it cannot be read or breaks the schema."""
        from coopsumo.files import read_csv

        try:
            frame = read_csv(path)  # a regular file's: a named pipe is refused, not waited on
        except (OSError, UnicodeDecodeError, ValueError) as err:  # pandas' EmptyDataError and ParserError among them
            raise RecordError(f"{path} cannot be read as a table ({why_unreadable(err)})") from None
        self.check([str(c) for c in frame.columns], frame.to_dict("records"), path)
        return frame

    def frame_problem(self, frame: Any) -> str | None:
        """problem() of a pandas DataFrame (duck-typed: pandas is not imported here); None for one without rows (a
        study whose cells all failed writes its tables empty)."""
        return self.problem([str(c) for c in frame.columns], frame.to_dict("records")) if len(frame) else None

    def check_frame(self, frame: Any, path: object) -> None:
        """check() of a pandas DataFrame before it is written to `path`: the numbers it holds inside their limits (a
        writer leaves a value it did not measure blank, NaN or None; a reader that copies it refuses that with
        frame_problem). Nothing for a frame without rows."""
        rows = [{k: v for k, v in row.items() if v is not None and v == v} for row in frame.to_dict("records")]
        if rows and (problem := self.problem([str(c) for c in frame.columns], rows, complete=False)) is not None:
            raise RecordError(f"{path} {problem}")


def _rules(fields: Iterable[Field], names: Sequence[str]) -> dict[str, Rule]:
    """Column name -> rule: a field's own name, or every column ending with a field named `_x`."""
    out: dict[str, Rule] = {}
    for field in fields:
        out.update({n: field.rule for n in names if n.endswith(field.name)} if field.name.startswith("_")
                   else {field.name: field.rule})  # fmt: skip
    return out


def _plain(value: Any) -> Any:
    """A table's cell as Python: numpy's numbers (which pandas gives) as int or float."""
    if isinstance(value, numbers.Integral) and not isinstance(value, bool):
        return int(value)
    return float(value) if isinstance(value, numbers.Real) and not isinstance(value, bool) else value


def tensor_problem(state: Any, fields: Sequence[Field], entries: Callable[[Any], tuple[float, ...] | None]
                   ) -> str | None:  # fmt: skip
    """Why the nested mappings and lists `state` (a checkpoint, a model file) hold a tensor or number outside its
    field's Number bounds (Integer: also whole), or None. entries(value): the entries of a tensor that decide it, its
    smallest, its largest and its first that is not whole if any (None for an empty one or not a tensor); plain
    numbers are checked as they are. Absent fields are not checked here (the reader's structural checks say so)."""
    for field in fields:
        for where, value in values_at(state, field.name):
            if value is _MISSING:
                continue
            if isinstance(value, numbers.Real) and not isinstance(value, bool):
                whole = isinstance(value, numbers.Integral)  # an integer as it is: 400 digits hold no float
                deciding: tuple[Any, ...] | None = (value if whole else float(value),)
            else:
                deciding = entries(value)
            for end in deciding or ():
                if (problem := field.rule.problem(end)) is not None:
                    return f"field {where} {problem}"
    return None


# -- the schemas ---------------------------------------------------------------------------------------------
SPEED = Number(0.0, SPEED_MAX_MPS, unit="m/s")
SHARE = Number(0.0, 1.0)
WEIGHTS = Number(-WEIGHT_MAX, WEIGHT_MAX, low_open=True, high_open=True, unit="a network weight")

SUMMARY_COUNTS = ("departed", "arrived", "collisions", "teleports", "lane_changes", "lane_changes_rejected",
                  "insertion_blocked", "insertion_pending_at_end", "steps")  # fmt: skip
"""a run summary's values that count something: whole numbers >= 0"""
PER_VEHICLE = Number(0.0, 1000.0, unit="per vehicle")
"""lane changes per vehicle: a few in a real run (a vehicle changes lane at most once in its 4 s manoeuvre)"""
THROUGHPUT = Number(0.0, MAX_LANES * LANE_CAPACITY_VEH_H, unit="veh/h")
"""a road's flow: at most config.MAX_LANES lanes at a lane's capacity"""
SECONDS = Number(0.0, unit="s")
MAX_STEPS_PER_SECOND = 1e6
"""a run's simulation steps per second: a step is at least a microsecond (SUMO's step and the controller's); the
committed runs make at most about 7,500 (issue 82, probe 13, F6: a part's runs.csv with 1e9 was merged)"""
MEASURES = {field.name: field for field in (
    *(Field(name, Integer(0)) for name in SUMMARY_COUNTS),
    Field("mean_speed_mps", SPEED),
    Field("lane_changes_per_vehicle", PER_VEHICLE),
    Field("throughput_veh_per_h", THROUGHPUT),
    Field("mean_travel_time_s", Number(0.0, unit="s", blank_ok=True)),  # no vehicle arrived: none
    Field("loop_flow_veh_h_per_lane", Number(0.0, LANE_CAPACITY_VEH_H, unit="veh/h per lane", blank_ok=True)),
    Field("loop_occupancy_pct", Number(0.0, 100.0, unit="%", blank_ok=True)),  # a MOBIL cell's: not measured
    Field("full_road_speed_mps", Number(0.0, SPEED_MAX_MPS, unit="m/s", blank_ok=True)),
    Field("full_road_from_s", Number(0.0, unit="s", blank_ok=True)),
    Field("wall_seconds", SECONDS),
    Field("sim_seconds", SECONDS),
    Field("steps_per_second", Number(0.0, MAX_STEPS_PER_SECOND, unit="steps/s")),
    Field("decision_interval_steps", Integer(1)),  # a policy decides at most once a step
    Field("mean_vehicles_on_road", Number(0.0, unit="vehicles")),
    Field("sumo_collisions", Number(0.0, unit="a count, or -1: not checked", also=(-1.0,))),
    Field("updates", Integer(0)),  # a training's learner updates
    Field("selected_step", Integer(0)),  # the training step of the snapshot model.pt holds
)}  # fmt: skip
"""a run's measures by their summary key, each one's limits declared once: a run's summary (RUN_SUMMARY) and the
study tables that copy them (study_tables.SCENARIO2_RUNS, SCENARIO2_EVALS) are checked by the same rules"""
RUN_SUMMARY = Schema((
    *(dataclasses.replace(field, optional=True) for field in MEASURES.values()),
    Field("*_mps", SPEED, optional=True),
    Field("*_per_vehicle", PER_VEHICLE, optional=True),
    Field("*_veh_h", Number(0.0, unit="veh-h"), optional=True),
    Field("*_time_s", SECONDS, optional=True),
    Field("*_share", SHARE, optional=True),
))  # fmt: skip
"""a run's summary (simulate's summary.json, a cell record's summary and each of its evaluations, a training's
train_summary), its finite numbers (records.implausible leaves out the non-finite ones, which record_problem judges
where a study reads them, and the table_ diagnostics, whose -1 means "not measured"); a summary's keys are many and
grow: besides MEASURES, the rules go by suffix"""

TRAIN_SUMMARY_KEYS = ("mean_speed_mps", "lane_changes", "collisions", "updates", "wall_seconds", "steps_per_second",
                      "departed", "steps")  # fmt: skip
"""what every training's summary holds as a number (train's train_summary.json, a cell record's train_summary): the
values the studies copy into their tables (scenario II's runs.csv), the vehicles its
last world sent and that world's steps; a summary without one of them, or with a text or null there, is not a
training's (records.training_problem)"""

CELL_SECONDS_MAX = 7 * 86_400.0
"""a cell's wall or CPU time (s), its training group's share too: at most a week (the longest cells, a full
training's, take hours; issue 82, probe 13, F10: 1e300 s was reused and summed into sweep.json and report.md)"""
CELL_STATUSES = ("ok", "failed", "interrupted")
"""a cell record's status (records.run_recorded): the runner writes no other"""
SEED = Integer(0, 2**32 - 1, blank_ok=True)
"""a seed (SUMO's and numpy's range), or none (a baseline's training seed)"""
T_UP = Number(0.0, 3600.0, low_open=True, unit="s", blank_ok=True)
"""a demand's upstream departure interval: above 0, at most one departure an hour"""
POLITENESS = Number(0.0, MOBIL_LIMITS["p"][1], unit="MOBIL's politeness", blank_ok=True)
"""a MOBIL cell's politeness p, the flags' limits (validation.MOBIL_LIMITS); a DQN cell's: none"""
CELL_RECORD = Schema((
    Field("key", Text()),
    Field("kind", Text(), optional=True),  # scenario II's cells have none
    Field("status", Text(CELL_STATUSES)),
    Field("config", MAPPING),
    Field("error", Text(blank_ok=True), optional=True),
    Field("traceback", Text(blank_ok=True), optional=True),
    Field("cell_wall_s", Number(0.0, CELL_SECONDS_MAX, unit="s", blank_ok=True), optional=True),  # not run: none
    Field("cell_cpu_s", Number(0.0, CELL_SECONDS_MAX, unit="s", blank_ok=True), optional=True),
    Field("versions", MAPPING, optional=True),
    Field("train_summary", MAPPING_OR_NULL, optional=True),
    # the coordinates the studies' cells share, where a study's cells have them
    Field("seed", SEED, optional=True),
    Field("eval_seed", SEED, optional=True),
    Field("alpha", Number(ALPHA_MIN, ALPHA_MAX, blank_ok=True), optional=True),  # a MOBIL cell's: none
    Field("t_up_s", T_UP, optional=True),
    Field("t_up", T_UP, optional=True),
    Field("lanes", Integer(MIN_LANES, MAX_LANES), optional=True),
    Field("p", POLITENESS, optional=True),
    Field("model_sha256", Text(), optional=True),
    Field("load", Number(0.0, 100.0, blank_ok=True), optional=True),  # scenario II: inflow per lane / 1,800 veh/h
    Field("resumed_from_step", Integer(0, blank_ok=True), optional=True),  # scenario II: none when trained now
    Field("train_group_cpu_s", Number(0.0, CELL_SECONDS_MAX, unit="s", blank_ok=True), optional=True),
))  # fmt: skip
"""a study's cell record (records.CellRecords, records.blank_record and run_recorded; every study's cells/<key>.json)
as records.reusable_keys reads it back to decide whether the cell is done: its envelope and the coordinates the
studies share; its summary and eval_summaries are records.record_problem's (RUN_SUMMARY, the values the study reads,
each evaluation's pooled into the summary)"""

MODEL_TENSORS = (Field("state_dict.*", WEIGHTS),)
"""a model file's (model_file.save_model's) tensors"""
CHECKPOINT_TENSORS = (
    *(Field(f"learner.{net}.*", WEIGHTS) for net in ("online", "target", "average")),
    Field("learner.buffer.data.rewards", Number(-REWARD_MAX, REWARD_MAX, True, True, "a reward")),
    *(Field(f"learner.buffer.data.{name}", Number(-REWARD_MAX, REWARD_MAX, True, True, "an observed feature"))
      for name in ("features", "next_features")),  # fmt: skip
    Field("learner.buffer.data.dones", Integer(0, 1)),
    Field("learner.buffer.data.actions", Integer(0, 3)),  # whole numbers, as the memory stores them: a float action
    *(Field(f"learner.buffer.data.{name}", Integer(0, 1)) for name in ("grids", "next_grids", "next_mask")),  # of 1.5
    # was resumed as 1, a grid of 0.5 as 0 (issue 82, probe 13, F5)
    *(Field(f"window.{name}", Integer(0, 10**15)) for name in ("samples", "vehicle_steps", "lane_changes",
                                                                 "rejected")),  # fmt: skip
    Field("window.speed_sum", Number(0.0, unit="m/s summed over vehicle steps")),
    Field("window.loss.*", Number(0.0, LOSS_MAX, unit="a Huber or squared loss")),
    Field("learner.optimizer.param_groups.*.lr", Number(0.0, 1.0, low_open=True, unit="a learning rate")),
    Field("learner.optimizer.param_groups.*.betas.*", Number(0.0, 1.0, high_open=True, unit="Adam's beta")),
    Field("learner.optimizer.param_groups.*.eps", Number(0.0, 1.0, low_open=True)),
    Field("learner.optimizer.param_groups.*.weight_decay", Number(0.0, 1.0)),
    Field("learner.optimizer.param_groups.*.momentum", Number(0.0, 1.0, high_open=True)),
    Field("learner.optimizer.state.*.step", Integer(0, 10**12)),
    Field("learner.optimizer.state.*.exp_avg", Number(-MOMENT_MAX, MOMENT_MAX, True, True, "Adam's first moment")),
    Field("learner.optimizer.state.*.exp_avg_sq", Number(0.0, MOMENT_MAX**2, unit="Adam's second moment")),
    Field("learner.optimizer.state.*.momentum_buffer", Number(-MOMENT_MAX, MOMENT_MAX, True, True)),
)
"""a training checkpoint's (train.Trainer.save_checkpoint's) numbers: weights, replay memory, optimizer"""

STORE_CONFIG = Schema((
    Field("config", MAPPING),
    Field("config.sim", MAPPING),
    Field("config.dqn", MAPPING),
    Field("config.sim.seed", Integer(0, 2**31 - 1)),
    Field("config.sim.steps", Integer(1)),
    Field("config.sim.reward", MAPPING),
    Field("config.sim.reward.alpha", Number(ALPHA_MIN, ALPHA_MAX)),
    Field("config.dqn.preset", Text()),
    Field("config.dqn.alpha_conditioned", FLAG, optional=True),
))  # fmt: skip
"""a stored model's config.json (train.model_meta's): what names its store folder (model_store.model_id)"""

DETECTOR_INTERVAL = Schema((
    Field("begin", Number(0.0, unit="s")),
    Field("end", Number(0.0, unit="s")),
    Field("nVehContrib", Integer(0)),
    Field("flow", Number(0.0, unit="veh/h")),
    Field("occupancy", Number(0.0, 100.0, unit="%")),
    Field("speed", Number(0.0, SPEED_MAX_MPS, unit="m/s, or -1 without a vehicle", also=(-1.0,))),
    Field("harmonicMeanSpeed", Number(0.0, SPEED_MAX_MPS, unit="m/s, or -1 without a vehicle", also=(-1.0,)),
          optional=True),
))  # fmt: skip
"""one <interval> of SUMO's E1 loop output (detectors.xml), its attributes as numbers (a speed of -1: SUMO's "no
vehicle"); its count at most LANE_CAPACITY_VEH_H per lane over the interval (run_checks.detectors_problem)"""

PROTOCOL_STUDY = Schema((
    Field("learners", MAPPING),
    Field("learners.*", MAPPING),
    Field("learners.*.learner", MAPPING, optional=True),
    Field("learners.*.drive", MAPPING, optional=True),
    Field("learners.*.weights", Text(), optional=True),
    Field("profile", MAPPING, optional=True),
    Field("profile.eval_offsets", LIST, optional=True),
))  # fmt: skip
"""a learner protocol study's study.json (protocol.study's meta), as `coopsumo history` reads it"""

POI = Number(0.0, 1.0, unit="a probability")
PROTOCOL_STATS = Table(
    columns=(Field("scenario", Text(("free", "accident"))), Field("t_up", Number(0.0, 3600.0, True, unit="s")),
             Field("variant", Text()), Field("models", Integer(1)),
             Field("lane_changes_per_vehicle", Number(0.0, 1000.0)),
             *(Field(name, Number(0.0, TTS_MAX_VEH_H)) for name in ("iqm", "low", "high", "worst", "mean")),
             Field("keep_value", Number(0.0, TTS_MAX_VEH_H)), Field("keep_poi_low", POI), Field("greedy_poi", POI),
             Field("mobil:p=0_poi", POI),
             Field("_poi", POI), Field("_poi_low", POI), Field("_poi_high", POI), Field("_losses", Integer(0))),
    case="scenario",
    cases={"free": tuple(Field(name, SPEED) for name in ("iqm", "low", "high", "worst", "mean", "_value")),
           "accident": tuple(Field(name, Number(0.0, TTS_MAX_VEH_H, unit="veh-h"))
                             for name in ("iqm", "low", "high", "worst", "mean", "_value"))},
    key=("scenario", "t_up", "variant"),
)  # fmt: skip
"""a learner protocol study's stats.csv (protocol.report.condition_stats): per scenario, demand and learner, the IQM
and its interval over models (free flow: mean speed, m/s; accident: total time spent, veh-h), each baseline's value
and probability of improvement"""
