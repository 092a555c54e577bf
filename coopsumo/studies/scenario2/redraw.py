"""Scenario II redrawn: a finished sweep's tables, figures and report.md from its own records, nothing trained or
run; or one sweep merged from its parts, run one lane count at a time; both drawn by scenario2_gate_report."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import MISSING, asdict
from dataclasses import fields as dataclass_fields
from pathlib import Path
from typing import Any, NamedTuple, get_type_hints

import pandas as pd
from pandas.api.types import is_numeric_dtype

from coopsumo.config import fastest_mps, first_difference
from coopsumo.errors import ConfigError, NotRegularFileError, UsageError, first_line
from coopsumo.field_rules import shown
from coopsumo.files import read_csv, read_json, write_atomic, write_json
from coopsumo.studies.engine.catalogue import Entry
from coopsumo.studies.engine.records import cell_runs, implausible, pooled_problem
from coopsumo.studies.engine.run_folders import profile_study, study_root
from coopsumo.studies.engine.trainings import train_values_problem
from coopsumo.studies.scenario2.gate_report import console_lines, write_lane_outputs
from coopsumo.studies.scenario2.measures import EVAL_COLUMNS, EVAL_KEYS, KEY_COLUMNS, METRIC_COLUMNS, TRAIN_COLUMNS
from coopsumo.studies.scenario2.part_rows import rows_problem
from coopsumo.studies.scenario2.plan import (
    FULL_ROAD,
    RESPONSE_PLAN,
    RETIRED_PER_ALPHA,
    Profile,
    cell_specs,
    condition_rows,
    learner_of,
    per_alpha_sweep,
    recorded_fields,
    train_folder,
)
from coopsumo.study_tables import SCENARIO2_EVALS, SCENARIO2_RUNS, SWEEP, csv_header
from coopsumo.validation import split_list


def rewrite_outputs(root: Path) -> dict[str, Any]:
    """Redraw a finished sweep's tables, figures and report.md from its runs.csv, evals.csv and sweep.json alone,
    nothing trained or run (a committed folder keeps no cells/, so rerunning its command would train every cell
    again); the bootstraps are seeded, so the numbers come out as they were (scenario2_gate_report). Returns
    sweep.json's new content. A sweep of the retired per-alpha design (plan.per_alpha_sweep: results/archive's) is
    refused, one UsageError naming the commit that redraws it."""
    return _draw(root, read_json(root / "sweep.json"))


def _draw(root: Path, meta: dict[str, Any]) -> dict[str, Any]:
    """rewrite_outputs with the sweep's record `meta`, sweep.json written last: a merge removes its folder's first,
    so that one cut short holds none and is no finished sweep (issue 82, probe 20, O3: a merge stopped by SIGTERM
    left its tables and sweep.json without its report, and a later merge took it as a part)."""
    if per_alpha_sweep(meta["profile"]):
        raise UsageError(f"{root} holds a sweep of scenario II's per-alpha design, retired on 2026-12-03: redraw it "
                         f"at commit {RETIRED_PER_ALPHA}")  # fmt: skip
    recorded = recorded_fields(meta["profile"])
    fields: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in recorded.items()}
    profile = Profile(**fields)
    runs, n_boot = read_csv(root / "runs.csv"), int(meta["bootstrap_replicates"])
    write_lane_outputs(root, runs, read_csv(root / "evals.csv"), profile, meta, n_boot)
    write_json(root / "sweep.json", meta)
    return meta


MERGED_SUMS = ("cells_run", "wall_seconds", "cell_wall_seconds_sum", "cell_cpu_seconds_sum")
"""sweep.json values a merged sweep adds up over its parts (the work each part did)"""


class Part(NamedTuple):
    """A finished sweep to merge: its folder, its sweep.json and profile, runs.csv and evals.csv."""

    folder: Path
    meta: dict[str, Any]
    profile: Profile
    runs: pd.DataFrame
    evals: pd.DataFrame


SPLIT_BY = ("lanes", "alphas", "check_alphas")
"""profile fields in which the parts of one sweep may differ: a part is some lane counts at some alphas"""
TIMING = ("wall_seconds", "train_wall_seconds", "cell_wall_s", "cell_cpu_s", "steps_per_second", "sumo_step_share")
"""runs.csv and evals.csv columns that say how fast a run went, not what it gave"""
RUN_COLUMNS = (*KEY_COLUMNS, "policy", "p", "status", *METRIC_COLUMNS, *EVAL_COLUMNS)
"""runs.csv columns a part must hold (runs_table writes them all; its criterion, if another, too)"""
POOLED = tuple(c for c in EVAL_COLUMNS if c != "lane_changes_per_vehicle")
"""runs.csv values re-derived from the cell's rows of evals.csv (records.pool_summaries); lane changes per vehicle
pools as a ratio of counts evals.csv does not keep (records.implausible checks it against runs.csv's counts)"""


def read_parts(folders: list[Path]) -> list[Part]:
    """The finished sweeps to merge (merge_parts), checked, each refusal one UsageError line naming the part: a part
    missing a file or not a finished lane-network sweep; its sweep.json not as a sweep writes it (_meta_problem); its
    tables not its profile's cells and evaluations (_table_problem); a part run with another profile than the first
    in anything but its lanes and alphas; parts that together do not make one grid (every lane count at every
    alpha, once); two parts of one lane count that differ in their classical runs or their learner; then, each part
    against itself, a learner other than the one its profile trains and a runs.csv that is not what its evals.csv
    pools to (_check_pooled)."""
    parts = [_read_part(folder) for folder in folders]
    first = _shared(parts[0].profile)
    grid: set[tuple[int, float]] = set()
    for part in parts:
        if (other := _shared(part.profile)) != first:
            field = next(k for k in first if first[k] != other[k])
            raise UsageError(f"--merge: {part.folder} was run with another profile than {parts[0].folder} ({field} "
                             f"{json.dumps(other[field])[:60]}, not {json.dumps(first[field])[:60]}; only --lanes and "
                             "--alphas may differ)")  # fmt: skip
        cells = {(n, a) for n in part.profile.lanes for a in part.profile.alphas}
        if overlap := grid & cells:
            n, a = min(overlap)
            raise UsageError(f"--merge: {part.folder} repeats lanes {n} at alpha {a:g} of another part")
        grid |= cells
    lanes, alphas = {n for n, _ in grid}, {a for _, a in grid}
    if missing := {(n, a) for n in lanes for a in alphas} - grid:
        n, a = min(missing)
        raise UsageError(f"--merge: no part holds lanes {n} at alpha {a:g}: the parts do not make one grid")
    _one_of_each([(part.folder, part.runs) for part in parts], ["key"], "runs.csv")
    _one_of_each([(part.folder, part.evals) for part in parts], ["key", "eval_seed"], "evals.csv")
    _learners(parts)
    for part in parts:
        if where := first_difference(part.meta["learner"], learner_of(part.profile), "learner"):
            raise UsageError(f"--merge: {part.folder}'s sweep.json records another learner than its profile "
                             f"{part.profile.name} trains ({where}): made by another version, or edited")  # fmt: skip
        _check_pooled(part)
    return parts


def _shared(profile: Profile) -> dict[str, Any]:
    """A part's profile but the fields in which parts differ (SPLIT_BY), its defaults filled in."""
    return {k: v for k, v in asdict(profile).items() if k not in SPLIT_BY}


def _read_part(folder: Path) -> Part:
    """One part read and checked against itself before anything is written (_part_profile, _meta_problem,
    _table_problem)."""
    name = "sweep.json"
    try:
        meta = read_json(folder / name)
        name = "runs.csv"
        runs, runs_header = read_csv(folder / name), csv_header(folder / name)
        name = "evals.csv"
        evals, evals_header = read_csv(folder / name), csv_header(folder / name)
    except NotRegularFileError as err:  # a named pipe: refused, not waited on (issue 82, fifth probe, G4)
        raise UsageError(f"--merge: {folder} is not a finished scenario2 sweep ({err})") from None
    except (OSError, ValueError) as err:  # the file named, pandas' message in one line (it ends in a newline: F17)
        raise UsageError(f"--merge: {folder} is not a finished scenario2 sweep ({name}: {err.__class__.__name__}: "
                         f"{getattr(err, 'strerror', None) or first_line(err)})") from None  # fmt: skip
    for name, header, schema in (("runs.csv", runs_header, SCENARIO2_RUNS), ("evals.csv", evals_header,
                                                                             SCENARIO2_EVALS)):  # fmt: skip
        if problem := schema.columns_problem(header):  # only the columns a sweep writes (probe 16, TR2)
            raise UsageError(f"--merge: {folder / name} {problem}")
    profile = _part_profile(folder, meta)
    if "dqn" not in profile.policies:  # its tables lack the learner's columns: say so, not "not as a sweep writes it"
        raise UsageError(f"--merge: {folder} is a sweep of {', '.join(profile.policies)} only (its profile's "
                         "policies): a merge joins the learner's (dqn) cells over lanes and alphas, and this part has "
                         "none; merge sweeps whose policies include dqn")  # fmt: skip
    if not profile.trajectory_every_steps:  # no trajectories, no full-road speed: a sweep writes no such columns
        runs, evals = (t.assign(**{c: float("nan") for c in (FULL_ROAD, "full_road_from_s") if c not in t})
                       for t in (runs, evals))  # fmt: skip
    try:
        specs = cell_specs(profile)
    except (ValueError, ArithmeticError, LookupError) as err:  # ConfigError, a load of 0, an unknown preset
        raise UsageError(f"--merge: {folder}'s sweep.json holds a profile no sweep runs ({type(err).__name__}: "
                         f"{err})") from None  # fmt: skip
    if problem := _meta_problem(meta, profile, len(specs)) or _table_problem(meta, profile, specs, runs, evals) \
            or _speed_problem(specs, runs, evals) or _train_problem(specs, runs) or rows_problem(specs, runs):
        raise UsageError(f"--merge: {folder}'s {problem}")
    return Part(folder, meta, profile, runs, evals)


def _part_profile(folder: Path, meta: Any) -> Profile:
    """The profile a part's sweep.json records, each field of Profile's type (catalogue.Entry: an integer where a
    float belongs is taken as that float); UsageError unless it is an object of a finished sweep, not of the retired
    per-alpha design (plan.per_alpha_sweep)."""
    recorded = meta.get("profile") if isinstance(meta, dict) else None
    if not isinstance(recorded, dict):
        what = f"its profile is {json.dumps(recorded)[:40]}" if isinstance(meta, dict) else "it is not a JSON object"
        raise UsageError(f"--merge: {folder} is not a finished scenario2 sweep (sweep.json: {what})")
    if "wall_seconds" not in meta or per_alpha_sweep(recorded):
        raise UsageError(f"--merge: {folder} is not a finished sweep of a lane-network profile (full, check, "
                         "paper)")  # fmt: skip
    fields = recorded_fields(recorded)
    hints = get_type_hints(Profile)
    at = Entry(folder / "sweep.json", "profile")
    required = [f.name for f in dataclass_fields(Profile) if f.default is MISSING]
    try:
        at.table(fields, "the profile", tuple(hints))
        if missing := [k for k in required if k not in fields]:
            raise at.error(f"has no {missing[0]}")
        profile = Profile(**{k: at.value(k, v, hints[k]) for k, v in fields.items()})
        if problem := RESPONSE_PLAN.problem(profile.response_plan):  # its report calls the reading confirmatory
            raise at.error(f"response_plan {problem}")
        return profile
    except ConfigError as err:
        raise UsageError(f"--merge: {err}") from None


def _meta_problem(meta: dict[str, Any], profile: Profile, cells: int) -> str | None:
    """Why a part's sweep.json is not what a finished sweep of `profile` (`cells` cells) writes, as a phrase after
    "<part>'s", or None: outside record_schemas.SWEEP (its counts and times of the wrong type or range, its failed
    cells not a list of keys), no learner of every lane count, conditions other than the profile's, another number of
    cells or trainings."""
    if (problem := SWEEP.problem(meta)) is not None:  # types and ranges (record_schemas)
        return f"sweep.json {problem}"
    learner = meta.get("learner")
    if not isinstance(learner, dict) or set(learner) != {f"{n}_lanes" for n in profile.lanes}:
        return (f"sweep.json has learner = {json.dumps(learner)[:40]}, not the learner of each of its lanes "
                f"{list(profile.lanes)}")  # fmt: skip
    if meta.get("conditions") != condition_rows(profile):
        return (f"sweep.json has conditions = {json.dumps(meta.get('conditions'))[:40]}, not those of its profile "
                f"({len(condition_rows(profile))} conditions of lanes {list(profile.lanes)})")  # fmt: skip
    for name, planned in (("cells", cells), ("trainings", profile.n_trainings())):
        if meta[name] != planned:
            return f"sweep.json has {name} = {meta[name]}, but its profile makes {planned}"
    if meta["cells_ok"] + meta["cells_failed"] != meta["cells"]:
        return (f"sweep.json has cells_ok = {meta['cells_ok']} and cells_failed = {meta['cells_failed']}, which do "
                f"not add up to its cells = {meta['cells']}")  # fmt: skip
    if meta["criterion"] != profile.criterion:
        return f"sweep.json has criterion = {json.dumps(meta['criterion'])[:40]}, not its profile's {profile.criterion}"
    return None


def _table_problem(meta: dict[str, Any], profile: Profile, specs: list[dict[str, Any]], runs: pd.DataFrame,
                   evals: pd.DataFrame) -> str | None:  # fmt: skip
    """Why a part's runs.csv and evals.csv are not the tables of its profile's cells `specs`, as a phrase after
    "<part>'s", or None: a column missing; not one runs.csv row per cell, with the cell's coordinates; statuses other
    than sweep.json's failed cells; a trained cell's ok row without its training's measures (a blank train_*); not
    one evals.csv row per evaluation of each successful cell (a DQN model's every evaluation seed, a classical
    run's one), with its cell's coordinates, and none of a failed cell."""
    for name, table, columns in (("runs.csv", runs, (*RUN_COLUMNS, profile.criterion)), ("evals.csv", evals,
                                 (*EVAL_KEYS, *EVAL_COLUMNS))):  # fmt: skip
        if missing := [c for c in dict.fromkeys(columns) if c not in table.columns]:
            more = f" and {len(missing) - 1} more" if len(missing) > 1 else ""
            return f"{name} has no {missing[0]} column{more}: not as a sweep writes it"
        numbers = [table[c] for c in columns if c not in ("key", "policy", "status")]
        if text := [c for c in numbers if len(c) and not is_numeric_dtype(c)]:  # (an empty table reads as text)
            column = text[0]
            bad = column[column.map(_no_number) & column.notna()]  # pandas' to_numeric: OverflowError at 400 digits
            value = shown(bad.iloc[0] if len(bad) else column.iloc[0])
            return f"{name} has {column.name} = {value}, not a number: edited?"
    planned = {s["key"]: s for s in specs}
    if len(runs) != len(specs) or set(runs["key"]) != set(planned):
        extra = sorted(set(map(str, runs["key"])) - set(planned))
        twice = sorted(map(str, runs.loc[runs["key"].duplicated(), "key"]))
        which = (f"{extra[0]}, not one of its cells" if extra else f"{twice[0]} twice" if twice
                 else f"no row of cell {min(set(planned) - set(runs['key']))}")  # fmt: skip
        return f"runs.csv holds {len(runs)} rows for the {len(specs)} cells of its profile ({which})"
    rows = {r["key"]: r for r in runs.to_dict("records")}
    for key, spec in planned.items():
        cell = {**spec, **_made(spec)}
        if (field := _differs(rows[key], cell, (*KEY_COLUMNS[1:], "policy", "p", "train_dir"))) is not None:
            return f"runs.csv row {key} has {field} = {rows[key][field]}, not its cell's {cell[field]}"
        if rows[key]["status"] == "ok" and _differs(rows[key], cell, ("steps",)) is not None:
            return f"runs.csv row {key} has steps = {rows[key]['steps']}, not the {cell['steps']} of its evaluations"
        if rows[key]["status"] == "ok" and cell["train_dir"] and (blank := [c for c in TRAIN_COLUMNS
                                                                             if _blank(rows[key].get(c))]):  # fmt: skip
            return f"runs.csv row {key} has {blank[0]} blank, but its cell trains ({cell['train_dir']})"
    failed = sorted(k for k, r in rows.items() if r["status"] != "ok")
    if failed != sorted(meta["failed_cells"]) or meta["cells_failed"] != len(failed):
        return (f"runs.csv has {len(failed)} cells not ok ({', '.join(failed[:2]) or 'none'}), but sweep.json "
                f"{meta['cells_failed']} failed ({', '.join(meta['failed_cells'][:2]) or 'none'})")  # fmt: skip
    seeds = evals.groupby("key")["eval_seed"].apply(sorted).to_dict()
    for key, spec in planned.items():
        want = sorted(ev["seed"] for ev in spec["config"]["evals"]) if "evals" in spec["config"] else [spec["seed"]]
        have = seeds.get(key, []) if rows[key]["status"] == "ok" else []
        if seeds.get(key, []) != have or have != want:
            state = "ok" if rows[key]["status"] == "ok" else "not ok"
            return (f"evals.csv holds evaluation seeds {have or seeds.get(key) or 'none'} of cell {key} ({state}), "
                    f"not {want if state == 'ok' else 'none'}: cut short or edited?")  # fmt: skip
    if unknown := sorted(set(map(str, evals["key"])) - set(planned)):
        return f"evals.csv holds evaluations of {unknown[0]}, not one of its cells"
    for e in evals.to_dict("records"):
        if (field := _differs(e, rows[e["key"]], ("lanes", "t_up_s", "load", "policy", "alpha", "p"))) is not None:
            return f"evals.csv has {field} = {e[field]} in an evaluation of {e['key']}, not its runs.csv row's"
    for name, table, schema in (("runs.csv", runs, SCENARIO2_RUNS), ("evals.csv", evals, SCENARIO2_EVALS)):
        if (problem := schema.frame_problem(table)) is not None:  # every number inside its limits (record_schemas)
            return f"{name} {problem}"
    return None


def _speed_problem(specs: list[dict[str, Any]], runs: pd.DataFrame, evals: pd.DataFrame) -> str | None:
    """Why a part's runs.csv or evals.csv gives a speed no vehicle drives on its cell's road (above the road's
    speed limit and the fastest desired speed), or a full-road speed without the moment it is measured from, as a
    phrase after "<part>'s", or None (issue 82, probe 8, J15: 60 m/s on a 33.34 m/s road, in both tables alike)."""
    fastest = {spec["key"]: fastest_mps(cell_runs(spec["config"])[0]) for spec in specs}
    for name, table in (("runs.csv", runs), ("evals.csv", evals)):
        for row in table.to_dict("records"):
            for column in ("mean_speed_mps", FULL_ROAD):
                if float(row.get(column, 0.0)) > fastest[row["key"]] + 0.01:  # NaN compares False
                    return (f"{name} has {column} = {row[column]} for {row['key']}, above any vehicle's speed on its "
                            f"road ({fastest[row['key']]:g} m/s)")  # fmt: skip
            if pd.isna(row.get(FULL_ROAD)) != pd.isna(row.get("full_road_from_s")):
                return f"{name} has {FULL_ROAD} and full_road_from_s of {row['key']} not both given: edited?"
    return None


def _train_problem(specs: list[dict[str, Any]], runs: pd.DataFrame) -> str | None:
    """Why a successful row of a part's runs.csv holds what no run of its cell gives, as a phrase after "<part>'s",
    or None: training columns its training cannot give (trainings.train_values_problem: a speed above the road's, more
    updates or lane changes than its steps allow) or a DQN cell's decision interval not its learner's (issue 82,
    probe 13, F6: each was merged; a rate of 1e9 steps/s is beyond record_schemas' steps_per_second)."""
    trains = {s["key"]: s["config"]["train"] for s in specs if "train" in s["config"]}
    for row in runs.to_dict("records"):
        if row.get("status") != "ok" or (config := trains.get(row["key"])) is None:
            continue
        values = {name: row.get(column) for column, name in TRAIN_COLUMNS.items()}
        if (found := train_values_problem(values, config)) is not None:
            column = next(c for c, name in TRAIN_COLUMNS.items() if name == found[0])
            return f"runs.csv row {row['key']} has {column} = {row[column]:g}, {found[1]}"
        want, got = config["dqn"]["decision_interval_steps"], row.get("decision_interval_steps")
        if not _no_number(got) and float(got) != want:
            return f"runs.csv row {row['key']} has decision_interval_steps = {got:g}, not its learner's {want}"
    return None


def _made(spec: dict[str, Any]) -> dict[str, Any]:
    """What a cell's runs.csv row holds by its plan: its training folder (a DQN cell's the relative link
    train/<training>, plan.train_folder; a classical run's none) and its steps (its evaluations' together)."""
    return {"train_dir": train_folder(spec), "steps": sum(int(run["steps"]) for run in cell_runs(spec["config"]))}


def _differs(row: dict[str, Any], cell: dict[str, Any], names: Sequence[str]) -> str | None:
    """The first of `names` whose value in the table row is not the cell's (None and NaN alike), or None."""
    for name in names:
        a, b = row.get(name), cell.get(name)
        if _blank(a) and _blank(b):
            continue
        if _blank(a) or _blank(b) or (a != b and not (isinstance(a, int | float) and isinstance(b, int | float)
                                                      and float(a) == float(b))):  # fmt: skip
            return name
    return None


def _no_number(value: Any) -> bool:
    """True for a table's cell that is no finite number: a text, a number too large for a float (400 digits)."""
    try:
        return not math.isfinite(float(value))
    except (TypeError, ValueError, OverflowError):
        return True


def _blank(value: Any) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value))


def _check_pooled(part: Part) -> None:
    """UsageError unless every successful cell's runs.csv values are what its rows of evals.csv pool to
    (records.pooled_problem, on POOLED) and both are values a run can give (records.implausible): neither table can
    be edited alone."""
    evals = {key: group.to_dict("records") for key, group in part.evals.groupby("key")}
    for row in part.runs.to_dict("records"):
        if row["status"] != "ok":
            continue
        runs = [{k: e[k] for k in (*POOLED, "lane_changes_per_vehicle")} for e in evals[row["key"]]]
        record = {"summary": {k: row[k] for k in POOLED}, "eval_summaries": runs}
        if problem := implausible(row) or pooled_problem(record):
            raise UsageError(f"--merge: {part.folder}'s runs.csv row {row['key']} {problem}")


def _one_of_each(tables: list[tuple[Path, pd.DataFrame]], ids: list[str], what: str) -> pd.DataFrame:
    """The parts' tables (each with its part's folder) together, the runs of `keep`, `greedy` and MOBIL that two parts
    of one lane count both ran (the same `ids`) kept once; UsageError naming both parts when those differ in anything
    but their timing (not the same code or seeds), or when a model's run is in two parts."""
    table = pd.concat([t for _, t in tables], ignore_index=True)
    owners = [folder for folder, t in tables for _ in range(len(t))]

    def both(key: str) -> str:
        held = dict.fromkeys(owners[i] for i in table.index[table["key"] == key])
        return " and ".join(map(str, held))

    twice = table[table.duplicated(ids, keep=False)]
    if (twice["policy"] == "dqn").any():
        key = twice.loc[twice["policy"] == "dqn", "key"].iloc[0]
        raise UsageError(f"--merge: a model's run ({key}) appears in two parts' {what}: {both(key)}")
    differ = twice.drop(columns=[c for c in TIMING if c in twice]).drop_duplicates()
    if differ.duplicated(ids).any():
        key = differ.loc[differ.duplicated(ids), "key"].iloc[0]
        raise UsageError(f"--merge: two parts, {both(key)}, ran {key} with different results ({what}): not the same "
                         "code?")  # fmt: skip
    return table.drop_duplicates(ids, keep="first").reset_index(drop=True)


def _learners(parts: list[Part]) -> dict[str, Any]:
    """The learner of every lane count the parts trained (sweep.json's "learner", per lane count); UsageError naming
    both parts when two parts of one lane count trained with different learners."""
    learners: dict[str, Any] = {}
    first: dict[str, Path] = {}
    for part in parts:
        for lanes, learner in part.meta["learner"].items():
            if learners.setdefault(lanes, learner) != learner:
                raise UsageError(f"--merge: two parts, {first[lanes]} and {part.folder}, trained "
                                 f"{lanes.replace('_', ' ')} with different learners")  # fmt: skip
            first.setdefault(lanes, part.folder)
    return dict(sorted(learners.items(), key=lambda item: int(item[0].split("_")[0])))


def merge_parts(parts: list[Part], out: Path) -> dict[str, Any]:
    """One sweep in `out` from its finished parts (read_parts): sweeps of one lane-network profile run with
    different --lanes, or one lane count's alphas in two parts (a study longer than a session runs one lane count, or
    part of one, at a time). Their runs.csv and evals.csv are concatenated (a classical run two parts of one lane
    count both made, kept once), sweep.json records the profile with every part's lanes and alphas and each part's
    folder, lanes, alphas, time and versions, and the tables, figures and report are drawn as rewrite_outputs draws
    them."""
    metas = [part.meta for part in parts]
    runs = _one_of_each([(part.folder, part.runs) for part in parts], ["key"], "runs.csv")
    evals = _one_of_each([(part.folder, part.evals) for part in parts], ["key", "eval_seed"], "evals.csv")
    union = {k: sorted({x for m in metas for x in m["profile"][k]}) for k in SPLIT_BY}
    merged = {**metas[0], "profile": {**metas[0]["profile"], **union}, "learner": _learners(parts)}
    conditions = {json.dumps(c, sort_keys=True): c for m in metas for c in m["conditions"]}
    merged["conditions"] = sorted(conditions.values(), key=lambda c: (c["lanes"], -c["t_up_s"]))
    for name in MERGED_SUMS:
        total = sum(m[name] for m in metas)
        merged[name] = round(total, 1) if isinstance(total, float) else total
    merged["failed_cells"] = sorted({k for m in metas for k in m.get("failed_cells", [])})
    merged.update(cells=len(runs), cells_ok=int((runs["status"] == "ok").sum()),
                  cells_failed=len(merged["failed_cells"]))  # a classical run two parts made counts once
    merged["trainings"] = sum(int(m["trainings"]) for m in metas)
    merged["parts"] = [{"folder": str(part.folder), "lanes": part.meta["profile"]["lanes"],
                        "alphas": part.meta["profile"]["alphas"], "wall_seconds": part.meta["wall_seconds"],
                        "workers": part.meta["workers"], "versions": part.meta["versions"]}
                       for part in parts]  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    (out / "sweep.json").unlink(missing_ok=True)  # an earlier merge's: written again last (_draw)
    write_atomic(out / "runs.csv", lambda tmp: runs.to_csv(tmp, index=False))
    write_atomic(out / "evals.csv", lambda tmp: evals.to_csv(tmp, index=False))
    return _draw(out, json.loads(json.dumps(merged)))  # as read back from sweep.json (lists, not tuples)


MERGE_ALONE = ("profile", "steps", "eval_steps", "seeds", "eval_seeds", "lanes", "alphas", "t_up", "policies",
               "mobil_p", "preset", "bootstrap", "workers", "backend", "address")  # fmt: skip
"""options that choose what a sweep runs or how (the parts' profile and bootstrap replicates are the merge's), which
--merge (nothing run) refuses"""


def sweep_study(profile: Profile) -> str:
    """Which study a sweep of `profile` writes, as its folder's marker names it (run_dirs.check_study_root)."""
    return profile_study(profile.name, "sweep", (profile.preset,))


def merged_study(profile: str, parts: Sequence[Path]) -> str:
    """Which study a merge of `parts` (sweeps of `profile`) writes: named by its parts' folders, their links resolved,
    in the order of their paths (a merge of other parts, or of some of them, is another study)."""
    return profile_study(profile, "sweep merged from " + ", ".join(sorted(str(p.resolve()) for p in parts)))


def recorded_sweep(root: Path) -> str | None:
    """Which study the sweep folder `root` holds by its sweep.json (a folder merged or run before its marker named
    the study: results/scenario2), or None when it cannot be read: a merge's part folders as it recorded them, a
    relative one from the working folder (the merge was run from it); a conditioned sweep (the retired `--conditioned`,
    results/archive/scenario2_conditioned) is another study than any sweep run today."""
    try:
        meta = read_json(root / "sweep.json")
        name, conditioned, parts = meta["profile"]["name"], meta["profile"].get("conditioned"), meta.get("parts")
        preset = meta["profile"].get("preset", "default")
        if parts is not None:
            return merged_study(name, [Path(part["folder"]) for part in parts]) if isinstance(name, str) else None
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    if not isinstance(name, str) or not isinstance(preset, str):
        return None
    return profile_study(name, "conditioned sweep" if conditioned else "sweep", (preset,))


def merge_command(args: Any, given: set[str]) -> int:
    """--merge: the parts' sweep folders merged into --out (merge_parts); `given`: the options set on the command
    line. Everything is checked before anything is written: the options, the parts (read_parts), and --out (not in a
    part; a folder that holds no other study than this merge of these parts: run_dirs.check_study_root)."""
    if refused := [f"--{name.replace('_', '-')}" for name in MERGE_ALONE if name in given]:
        raise UsageError(f"--merge runs nothing: {', '.join(refused)} cannot go with it")
    if args.out is None:
        raise UsageError("--merge needs --out, the merged sweep's folder")
    parts = [Path(x) for x in split_list("--merge", args.merge)]
    for part in parts:
        if part.resolve() == args.out.resolve():
            raise UsageError(f"--merge: --out {args.out} is one of the parts")
        if args.out.resolve().is_relative_to(part.resolve()):
            raise UsageError(f"--merge: --out {args.out} lies in the part {part}: the merged sweep writes into its own "
                             "folder")  # fmt: skip
    read = read_parts(parts)  # checked before anything is written
    study = merged_study(read[0].profile.name, parts)
    with study_root(args.out, "scenario2", study, recorded_sweep, "a merge of the same parts redraws its own folder; "
                    "pick another --out"):  # fmt: skip
        meta = merge_parts(read, args.out)
    print("\n".join(console_lines(args.out)))
    print(f"scenario2: merged {len(parts)} parts ({meta['cells']} cells, lanes "
          f"{', '.join(map(str, meta['profile']['lanes']))}); report: {args.out / 'report.md'}")  # fmt: skip
    return 0
