"""A study's cell records: what a cell is before and after it runs, and which stored records can be trusted
(their shape, their values, their plausibility)."""

from __future__ import annotations

import json
import math
import sys
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from coopsumo.config import results_view
from coopsumo.errors import why_unreadable
from coopsumo.field_rules import as_float, shown
from coopsumo.files import read_json, read_json_object, temporaries_of
from coopsumo.provenance import versions
from coopsumo.record_schemas import CELL_RECORD, RUN_SUMMARY, SPEED_MAX_MPS, SUMMARY_COUNTS, TRAIN_SUMMARY_KEYS


def blank_record(spec: dict[str, Any], fields: Sequence[str], **empty: Any) -> dict[str, Any]:
    """A cell's record before it runs: the spec's `fields`, its configuration, then `empty` (the study's own
    result fields) and no error or summary yet."""
    record = {k: spec.get(k) for k in fields}
    record.update(config=spec["config"], **empty)
    record.update(error=None, traceback=None, summary=None)
    return record


def as_failed(record: dict[str, Any], error: str) -> dict[str, Any]:
    """`record` (a blank one) as the record of a cell whose worker died or that could not run."""
    record.update(status="failed", error=error, cell_wall_s=None, cell_cpu_s=None, versions=versions())
    return record


def cpu_seconds() -> float:
    """CPU time (s) of this process and of its children that ended (a training's update worker and validation
    processes): without the children, a cell that trains would count only the world's share."""
    import resource

    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


def run_recorded(record: dict[str, Any], body: Callable[[], None]) -> dict[str, Any]:
    """Run body (which fills record) and add status, error, wall and CPU time (s, cpu_seconds: with the cell's
    children) and versions; never raises. A record outside record_schemas.CELL_RECORD is "failed", naming the field.

    status "ok", "failed" (with the error's first line and a short traceback) or "interrupted"
    (KeyboardInterrupt, also raised for SIGTERM/SIGINT while training).
    """
    start, cpu_start = time.perf_counter(), cpu_seconds()
    try:
        body()
        record["status"] = "ok"
    except KeyboardInterrupt as err:
        record.update(status="interrupted", error=f"{type(err).__name__}: {err}")
    except Exception as err:
        first = str(err).strip().splitlines()[0] if str(err).strip() else ""
        record.update(status="failed", error=f"{type(err).__name__}: {first}".rstrip(": "),
                      traceback=traceback.format_exc(limit=8))  # fmt: skip
    record["cell_wall_s"] = round(time.perf_counter() - start, 2)
    record["cell_cpu_s"] = round(cpu_seconds() - cpu_start, 2)
    record["versions"] = versions()
    if record["status"] == "ok" and (problem := CELL_RECORD.problem(record)) is not None:
        record.update(status="failed", error=f"record {problem}")  # never written as ok outside its schema
    return record


@dataclass(frozen=True)
class CellRecords:
    """The record layout of one study's cells, and the three things every study does with it.

    fields: copied from the cell's spec; empty: the study's own result fields, None until the cell has run;
    extra(spec): fields that depend on the cell (its folder, say).
    """

    fields: tuple[str, ...]
    empty: tuple[str, ...] = ()
    extra: Callable[[dict[str, Any]], dict[str, Any]] | None = None

    def new(self, spec: dict[str, Any]) -> dict[str, Any]:
        """A cell's record before it runs: what it is and where it writes; nothing measured yet."""
        record = blank_record(spec, self.fields, **dict.fromkeys(self.empty))
        if self.extra is not None:
            record.update(self.extra(spec))
        return record

    def failed(self, spec: dict[str, Any], error: str) -> dict[str, Any]:
        """The record of a cell whose worker died or that could not run (execute's failed_record)."""
        return as_failed(self.new(spec), error)

    def run(self, spec: dict[str, Any], body: Callable[[dict[str, Any]], None]) -> dict[str, Any]:
        """Run one cell in this process: body(record) fills the new record (run_recorded); never raises."""
        record = self.new(spec)
        return run_recorded(record, lambda: body(record))


def cell_path(root: Path, key: str) -> Path:
    return root / "cells" / f"{key}.json"


def read_record(root: Path, spec: dict[str, Any]) -> dict[str, Any] | None:
    """The stored record of this cell if it is a JSON object made with this configuration (config.results_view)."""
    record = read_json_object(cell_path(root, spec["key"]))
    if record is None or results_view(record.get("config")) != results_view(spec["config"]):
        return None
    return record


COUNTS = SUMMARY_COUNTS
"""summary values that count something: whole numbers >= 0 (record_schemas.RUN_SUMMARY)"""
POOL_SUMMED = frozenset(COUNTS) | {"sim_seconds", "wall_seconds"}
"""summary values a model's evaluations add up when pooled (counts and times); the others are averaged"""


def pool_summaries(summaries: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """One model's summary over its evaluations (one per evaluation seed): counts and times summed (POOL_SUMMED: e.g.
    collisions over all runs), lane changes per vehicle the pooled ratio (all lane changes over all departed vehicles,
    so the record stays self-consistent: implausible checks it), every other number averaged (mean speed),
    anything else taken from the first; a key missing from one evaluation is left out, a value one evaluation has
    not measured (None: scenario II's full-road speed of a run too short for it) is None: the model has none."""
    if not summaries:
        return {}
    out: dict[str, Any] = {}
    for key, first in summaries[0].items():
        values = [s.get(key) for s in summaries]
        numbers = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
        if any(v is None for v in values) and all(key in s for s in summaries):
            out[key] = None
        elif numbers:
            total = as_float(sum(values))  # type: ignore[arg-type]
            if key in POOL_SUMMED:
                out[key] = sum(values) if all(isinstance(v, int) for v in values) else total  # type: ignore[arg-type]
            else:
                out[key] = total / len(values)
        elif all(key in s for s in summaries):
            out[key] = first
    if {"lane_changes", "departed", "lane_changes_per_vehicle"} <= out.keys() and out["departed"] > 0:
        out["lane_changes_per_vehicle"] = out["lane_changes"] / out["departed"]  # the pooled ratio, as one run's
    return out


MAX_SPEED_MPS = SPEED_MAX_MPS
"""no run's speed is above this (record_schemas' limit on every recorded speed: the largest speed limit a road takes,
config.SPEED_LIMIT_MPS)"""


def implausible(summary: dict[str, Any], what: str = "summary") -> str | None:
    """Why a summary's values cannot come from a run, or None: a finite number outside record_schemas.RUN_SUMMARY's
    limits (counts negative or fractional, a speed outside 0..MAX_SPEED_MPS, a throughput above config.MAX_LANES
    lanes at a lane's capacity, a negative rate or time, a share outside 0-1), more arrivals than departures, lane
    changes per vehicle that are not the lane changes over the departures. `what` names the summary in the reason
    ("has train_summary.json mean_speed_mps must be ...")."""
    finite = {k: v for k, v in summary.items() if not k.startswith("table_")  # an integer of 400 digits is kept:
              and not (isinstance(v, bool) or not isinstance(v, int | float)  # RUN_SUMMARY's limits refuse it
                       or (isinstance(v, float) and not math.isfinite(v)))}  # fmt: skip
    if (problem := RUN_SUMMARY.problem(finite)) is not None:  # record_problem judges the values a study reads
        return f"has {what} {problem.removeprefix('field ')}"
    number = {k: as_float(v) for k, v in summary.items() if isinstance(v, int | float) and not isinstance(v, bool)}
    if number.get("arrived", 0.0) > number.get("departed", math.inf):
        return f"has {what} arrived = {number['arrived']:g} above departed = {number['departed']:g}"
    if {"lane_changes", "departed", "lane_changes_per_vehicle"} <= set(number) and number["departed"] > 0:
        ratio = number["lane_changes"] / number["departed"]
        if not math.isclose(ratio, number["lane_changes_per_vehicle"], rel_tol=1e-3, abs_tol=1e-3):
            return (f"has {what} lane_changes = {number['lane_changes']:g} for {number['departed']:g} vehicles, but "
                    f"lane_changes_per_vehicle = {number['lane_changes_per_vehicle']:g}: edited?")  # fmt: skip
    return None


def training_problem(summary: Any, what: str = "train_summary") -> str | None:
    """Why a training's summary cannot stand for its training where a study copies its values, or None: a JSON object
    holding each of record_schemas.TRAIN_SUMMARY_KEYS as a finite number, its values plausible (implausible). `what`
    names it in the reason ("has train_summary.json updates = ..., not a number")."""
    if not isinstance(summary, dict):
        return f"has {what} {json.dumps(summary)[:40]}, not a JSON object"
    for key in TRAIN_SUMMARY_KEYS:
        if key not in summary:
            return f"has {what} without {key}"
        value = summary[key]
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(as_float(value)):
            return f"has {what} {key} = {json.dumps(value)[:40]}, not a number"
    return implausible(summary, what)


def record_problem(record: Any, required: Sequence[str]) -> str | None:
    """Why a stored record cannot be trusted, or None: it must be a JSON object of status "ok" with a non-empty
    summary object whose `required` values (the ones the study reads) are finite numbers."""
    if not isinstance(record, dict):
        return f"is a JSON {type(record).__name__}, not an object"
    if "status" not in record:
        return "has no status"
    if record["status"] != "ok":
        return f"has status {json.dumps(record['status'])[:40]}, not \"ok\""
    summary = record.get("summary")
    if not isinstance(summary, dict) or not summary:
        return f"has status ok but its summary is {json.dumps(summary)[:40]}"
    for key in required:
        value = summary.get(key)
        if isinstance(value, bool) or not isinstance(value, int | float):
            return f"has summary {key} = {json.dumps(value)[:40]}, not a number"
        if not math.isfinite(as_float(value)):  # an integer of 400 digits too
            return f"has summary {key} = {shown(value)}, not a finite number"
    return implausible(summary) or pooled_problem(record) or runs_problem(record)


def cell_runs(config: dict[str, Any]) -> list[Any]:
    """The SimConfig dicts a cell's configuration drives, by the three shapes a study's cell configuration takes: a
    model cell's {"evals": [...]}, a run with trajectories {"run": SimConfig, "trajectory_every_steps": K}, or the
    SimConfig itself (issue 82, probe 13, F1: a keep or MOBIL cell of scenario II's tiny profile was read as the
    second, a KeyError out of the merge)."""
    return list(config["evals"]) if "evals" in config else [config.get("run", config)]


def runs_problem(record: dict[str, Any]) -> str | None:
    """Why a record's runs (each evaluation's summary, or its one summary) contradict themselves or the SimConfig
    each ran (its config's `evals`, or its config, a `run` in it), or None: run_checks.run_summary_problem, the rules
    scenario I applies to a run folder's summary.json (a loop flow, vehicles on the road, a throughput or a travel
    time its departures and arrivals cannot give: issue 82, probe 14, F1). A record whose configuration names no
    runs so, or whose one summary is not a run's (no steps: a study's own measures), is not judged here."""
    from coopsumo.studies.engine.run_checks import run_summary_problem

    config, evals = record.get("config"), record.get("eval_summaries")
    if not isinstance(config, dict):
        return None
    if "evals" in config and not isinstance(config["evals"], list):
        return None  # not a configuration a cell runs (results_view judges it)
    runs = cell_runs(config)
    if not runs or ("evals" in config) != isinstance(evals, list):
        return None  # not a configuration a cell runs (results_view judges it), or no evaluations kept to judge
    if not isinstance(evals, list) and "steps" not in record["summary"]:
        return None  # a study's own measures of its run (scenario I's accident), not the run's summary
    if isinstance(evals, list) and len(evals) != len(runs):
        return f"has {len(evals)} evaluations, but its configuration runs {len(runs)}"
    pairs = list(zip(evals, runs, strict=True)) if isinstance(evals, list) else [(record["summary"], runs[0])]
    for i, (summary, run) in enumerate(pairs):
        if not (isinstance(run, dict) and {"steps", "control", "road", "demand", "policy"} <= run.keys()):
            return None  # not a run's configuration: no study's cell
        try:
            problem = run_summary_problem({k: v for k, v in summary.items() if k != "policy"}, run)  # the model's
            # path, set as it ran: the record's policy is spec_problem's
        except (KeyError, TypeError, ValueError):
            return None  # a configuration spec_problem or results_view judges
        if problem is not None:
            where = f"evaluation {i + 1} of {len(pairs)} with" if isinstance(evals, list) else "summary"
            return problem.replace("has summary.json", f"has {where}", 1)
    return None


def _g(value: float) -> str:
    """value as :g prints it; an integer too large for a float shortened (field_rules.shown)."""
    return f"{value:g}" if math.isfinite(as_float(value)) else shown(value)


def _same_number(a: Any, b: Any) -> bool:
    if isinstance(a, bool) or isinstance(b, bool) or not isinstance(a, int | float) or not isinstance(b, int | float):
        return False
    a, b = as_float(a), as_float(b)  # an integer of 400 digits: inf, the same as no number a run gives
    return (math.isnan(a) and math.isnan(b)) or math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12)


def pooled_problem(record: dict[str, Any]) -> str | None:
    """Why a record's summary is not what its own evaluations pool to, or None: where it keeps them (eval_summaries,
    one per evaluation seed), each must be plausible (implausible) and every number of the summary the pooled one
    (pool_summaries), so that neither the summary nor an evaluation can be edited alone."""
    evals = record.get("eval_summaries")
    if evals is None:
        return None
    if not (isinstance(evals, list) and evals and all(isinstance(e, dict) for e in evals)):
        return f"has eval_summaries {json.dumps(evals)[:40]}, not a list of summaries"
    for i, one in enumerate(evals):
        if problem := implausible(one):
            return problem.replace("has summary", f"has evaluation {i + 1} of {len(evals)} with", 1)
    pooled, summary = pool_summaries(evals), record["summary"]
    for key, value in summary.items():
        if isinstance(value, int | float) and not isinstance(value, bool) and not _same_number(value, pooled.get(key)):
            return (f"has summary {key} = {_g(value)}, but its {len(evals)} evaluations pool to "
                    f"{json.dumps(pooled.get(key))[:20]}: edited?")  # fmt: skip
    return None


def cell_problem(record: Any, required: Sequence[str]) -> str | None:
    """Why a stored cell record cannot be trusted, or None: one of status ok whose summary record_problem accepts,
    inside record_schemas.CELL_RECORD (its envelope: key, times, configuration, the coordinates the studies share),
    with no error or traceback beside its ok,
    and a training's summary kept beside it whole and plausible (training_problem), one there whenever the cell
    trains (its configuration has a `train`): a record just run is judged so too (checked_record), so that no value
    a study's table refuses, or leaves blank, is counted as ok."""
    if problem := record_problem(record, required) or CELL_RECORD.problem(record):
        return problem
    for key in ("error", "traceback"):  # run_recorded writes none beside ok (issue 82, probe 13, F10: "boom")
        if record.get(key) not in (None, ""):
            return f"has status ok beside {key} {json.dumps(record[key])[:40]}"
    train = record.get("train_summary")  # what a study copies of its training (scenario II's runs.csv)
    if train is None:
        trains = isinstance(record.get("config"), dict) and "train" in record["config"]
        return "has no train_summary, but its cell trains" if trains else None
    return training_problem(train)


def checked_record(record: dict[str, Any], required: Sequence[str]) -> dict[str, Any]:
    """A record just run, as the study may count it: one of status ok that cell_problem faults counts as failed."""
    problem = cell_problem(record, required) if record.get("status") == "ok" else None
    return {**record, "status": "failed", "error": f"record {problem}"} if problem else record


SPEC_CHECKED_ELSEWHERE = ("config",)
"""spec fields reusable_keys judges on their own: the configuration (another one is another cell, rerun without a
word)"""


def spec_problem(record: dict[str, Any], spec: dict[str, Any], made: dict[str, Any] | None = None) -> str | None:
    """Why a record is not its cell's, or None: every field it copied from its cell's spec (blank_record: its
    coordinates, its policy, its folders) must be the spec's, and each of `made` (what the study writes into its
    record by the cell, CellRecords.extra: scenario II's train_dir) must be there and be the same."""
    for key, value in spec.items():
        if key not in SPEC_CHECKED_ELSEWHERE and key in record and not isinstance(value, dict) and record[key] != value:
            return f"has {key} = {json.dumps(record[key])[:40]}, not its cell's {json.dumps(value)[:40]}"
    for key, value in (made or {}).items():
        if record.get(key) != value:
            return f"has {key} = {json.dumps(record.get(key))[:40]}, not its cell's {json.dumps(value)[:40]}"
    return None


def copy_problem(record: dict[str, Any], spec: dict[str, Any], root: Path) -> str | None:
    """Why the training summary a record of a cell that trains copied (train_summary) is not its training's own
    ROOT/train/<train_key or key>/train_summary.json, or None: every field the same in both. A file that cannot be
    read is judged where the cell's training is (trainings.finished_training). Issue 82, probe 8, J10: a record's
    copy edited to 25 m/s against its training's 15.33 was reused and copied into runs.csv."""
    copy, config = record.get("train_summary"), spec.get("config")
    if not (isinstance(copy, dict) and isinstance(config, dict) and "train" in config):
        return None
    path = root / "train" / str(spec.get("train_key") or spec["key"]) / "train_summary.json"
    if (own := read_json_object(path)) is None:
        return None
    for key in sorted(own.keys() | copy.keys()):
        mine, its = copy.get(key), own.get(key)
        if key not in own or key not in copy or not (mine == its or _same_number(mine, its)):
            return (f"has train_summary {key} = {json.dumps(mine)[:40]}, but its training's {path} says "
                    f"{json.dumps(its)[:40]}")  # fmt: skip
    return None


def folder_problem(record: dict[str, Any], folders: Sequence[Path]) -> str | None:
    """Why a record's runs (each evaluation's summary in eval_summaries, or its one summary) are not the summary.json
    their run folders `folders` (in the cell's order of runs) hold, or None: every number of a folder's summary
    the same in the record (the record adds the study's own measures to it). A folder without a readable
    summary.json is not judged (a committed study keeps none)."""
    evals = record.get("eval_summaries")
    runs = evals if isinstance(evals, list) else [record.get("summary")]
    if len(runs) != len(folders):
        return None  # pooled_problem and runs_problem judge the evaluations a record keeps
    for i, (run, folder) in enumerate(zip(runs, folders, strict=True)):
        if not isinstance(run, dict) or (own := read_json_object(folder / "summary.json")) is None:
            continue
        for key, value in own.items():  # a measure the run has none of (null: a travel time without arrivals) too
            number = isinstance(value, int | float) and not isinstance(value, bool)
            if (number and not _same_number(run.get(key), value)) or (value is None and run.get(key) is not None):
                where = f"evaluation {i + 1} of {len(runs)} with" if isinstance(evals, list) else "summary"
                return (f"has {where} {key} = {json.dumps(run.get(key))[:20]}, but its run folder's "
                        f"{folder / 'summary.json'} says {json.dumps(value)[:20]}")  # fmt: skip
    return None


def copied_wrong(root: Path, specs: Sequence[dict[str, Any]], prog: str) -> set[str]:
    """The cells of `specs` (records otherwise reusable, their training's link leading to its model) whose record's
    training summary is not its training's own (copy_problem): each is rerun, with one line naming the record, the
    field and the file."""
    keys = set()
    for spec in specs:
        path = cell_path(root, spec["key"])
        record = read_json_object(path)
        if record is not None and (problem := copy_problem(record, spec, root)) is not None:
            print(f"{prog}: cell {spec['key']}: record {path} {problem}; rerunning it", file=sys.stderr)
            keys.add(spec["key"])
    return keys


def reusable_keys(root: Path, specs: Sequence[dict[str, Any]], prog: str, required: Sequence[str],
                  made: Callable[[dict[str, Any]], dict[str, Any]] | None = None) -> set[str]:  # fmt: skip
    """The cells whose stored record can be reused: one cell_problem accepts, made with the cell's
    configuration, holding what made(spec) gives (spec_problem: the cell's own training folder). Every other cell
    is rerun; a record that is neither failed nor interrupted and yet not accepted (unreadable, the wrong
    shape, a bad summary, another cell's copied in) gets one line on stderr saying why. A record's temporary file
    left by a run killed (SIGKILL) while writing it is removed: it was never a record."""
    done = set()
    for spec in specs:
        path = cell_path(root, spec["key"])
        for tmp in temporaries_of(path):
            tmp.unlink(missing_ok=True)
        if path.exists() and not path.is_file():  # a pipe or a folder: reading it would wait, or fail
            print(f"{prog}: cell {spec['key']}: record {path} is not a regular file; rerunning it", file=sys.stderr)
            continue
        try:
            record = read_json(path)
        except FileNotFoundError:
            continue
        except (OSError, ValueError) as err:
            print(f"{prog}: cell {spec['key']}: record {path} is unreadable ({why_unreadable(err)}); rerunning it",
                  file=sys.stderr)  # fmt: skip
            continue
        if isinstance(record, dict) and record.get("status") in ("failed", "interrupted"):
            continue  # rerun without a word: the study counts these
        problem = cell_problem(record, required)
        if problem is None and results_view(record.get("config")) != results_view(spec["config"]):
            if record.get("key", spec["key"]) != spec["key"]:  # a record copied in from another cell
                print(f"{prog}: cell {spec['key']}: record {path} is cell {str(record['key'])[:60]}'s (copied?); "
                      "rerunning it", file=sys.stderr)  # fmt: skip
            continue  # another configuration: another cell (a changed setting reruns it without a word)
        own = made(spec) if made is not None else None
        if problem := problem or spec_problem(record, spec, own):
            print(f"{prog}: cell {spec['key']}: record {path} {problem}; rerunning it", file=sys.stderr)
        else:
            done.add(spec["key"])
    return done


def summary_problem(path: Path, required: Sequence[str]) -> str | None:
    """Why the summary.json at `path` cannot be trusted, or None: a readable JSON object whose `required` values
    are finite numbers (as record_problem asks of a cell record's summary)."""
    try:
        summary = read_json(path)
    except (OSError, ValueError) as err:
        return f"has an unreadable summary.json ({why_unreadable(err)})"
    problem = record_problem({"status": "ok", "summary": summary}, required)
    if problem is None:
        return None
    return problem.replace("has status ok but its summary is", "has summary.json").replace("has summary ",
                                                                                             "has summary.json ")


def failed_exit(prog: str, failed: Sequence[str], total: int, root: Path) -> int:
    """A study's exit code: 0, or 1 with one line on stderr naming the failed cells."""
    if not failed:
        return 0
    print(f"{prog}: error: {len(failed)} of {total} cells failed ({', '.join(failed)}); records in {root / 'cells'}; "
          "rerun the same command to retry them", file=sys.stderr)  # fmt: skip
    return 1
