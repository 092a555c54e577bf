"""`coopsumo scenario1 --merge P1,P2,... --out DIR`: one scenario I study of many models per alpha from parts that
each ran a few whole models (issue 78: a study longer than a session runs in parts, each part's records committed).
A part is a finished scenario I study folder (its plan.json and runs.csv); the parts must share one plan and one
learner but for their training seeds, which may not overlap, and their baseline runs (the same policies on the
same seeds) must agree to the last digit (the fitted wave speed to FIT_RTOL). The merge writes runs.csv (the
baselines once, every part's models), summary.csv, plan.json (the parts named), claim_a.md and fig_thrashing.png
when the plan has alphas 0 and 8, and a short report.md; nothing is written when a part is refused."""

from __future__ import annotations

import math
import os
import re
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from coopsumo.config import first_difference, results_view, to_dict
from coopsumo.dqn_config import dqn_config_from_dict
from coopsumo.errors import ConfigError, UsageError
from coopsumo.files import read_json, read_json_object, write_json
from coopsumo.owners import owned_problem
from coopsumo.provenance import versions
from coopsumo.report.markdown import md_table
from coopsumo.run_dirs import study_root
from coopsumo.studies.engine.run_folders import profile_study, recorded_profile
from coopsumo.studies.scenario1.measures import aggregate
from coopsumo.studies.scenario1.plan import Plan, learners, model_label, recorded_plan
from coopsumo.study_tables import SCENARIO1_RUNS, SCENARIO1_SUMMARY, csv_header

MERGED = "merge.json"
"""the merged folder's record of its parts: a rerun of the same merge may write over it, nothing else may"""
OWN_FILES = ("runs.csv", "summary.csv", "plan.json", "report.md", "claim_a.md", "fig_thrashing.png", MERGED)
"""what a merge writes into its folder"""
OWN = (MERGED, *OWN_FILES[:-1])
"""the same, its record first: the names of a merged folder's study (run_dirs.check_study_root)"""


PLAN_LISTS: dict[str, Any] = {"presets": str, "alphas": (int, float), "train_seeds": int, "t_ups": (int, float),
                              "seeds": int}
"""the plan.json lists a merge reads, and the type of their items"""


def _part(folder: Path) -> tuple[dict[str, Any], pd.DataFrame]:
    """A part's plan.json (as written) and runs.csv (checked against its schema); UsageError naming what is wrong."""
    recorded = read_json_object(folder / "plan.json")
    if recorded is None or not isinstance(recorded.get("plan"), dict) or not isinstance(recorded.get("learners"),
                                                                                        dict):  # fmt: skip
        raise UsageError(f"--merge: {folder} holds no scenario I plan.json (give finished scenario I study folders)")
    for key, kind in PLAN_LISTS.items():
        values = recorded["plan"].get(key)
        if not isinstance(values, list) or not values or not all(
                isinstance(v, kind) and not isinstance(v, bool) and (kind is str or math.isfinite(v)) for v in values):
            what = {str: "names", int: "integers"}.get(kind, "numbers")
            raise UsageError(f"--merge: {folder}/plan.json: plan.{key} must be a non-empty list of {what}, got "
                             f"{str(values)[:40]}")  # fmt: skip
    known = learners()
    for name, learner in recorded["learners"].items():
        try:
            dqn_config_from_dict(learner).validate()
        except (UsageError, TypeError, ValueError) as err:
            raise UsageError(f"--merge: {folder}/plan.json: learner {name}: {err}") from None
        if name in known and (where := first_difference(learner, to_dict(known[name]), "learner")):
            raise UsageError(f"--merge: {folder}/plan.json records another learner {name} than the one it names "
                             f"trains ({where}): made by another version, or edited")  # fmt: skip
    for key, value in recorded["plan"].items():
        if isinstance(value, (int, float)) and not isinstance(value, bool) and not (math.isfinite(value) and
                                                                                     value >= 0):  # fmt: skip
            raise UsageError(f"--merge: {folder}/plan.json: plan.{key} must be a finite number >= 0, got {value}")
    try:  # by the rules a profile's fields get: no 9 lanes, no steps "x" (issue 82, probe 7, I8)
        plan = recorded_plan(folder / "plan.json", recorded["plan"])
    except ConfigError as err:
        raise UsageError(f"--merge: {err}") from None
    if not (folder / "runs.csv").is_file():
        raise UsageError(f"--merge: {folder} has no runs.csv: the part has not finished")
    try:
        if problem := SCENARIO1_RUNS.columns_problem(csv_header(folder / "runs.csv")):  # as written (probe 17, TR2)
            raise UsageError(f"--merge: {folder}/runs.csv {problem}")
        runs = SCENARIO1_RUNS.read(folder / "runs.csv")
    except ValueError as err:
        raise UsageError(f"--merge: {folder}/runs.csv: {err}") from None
    if problem := values_problem(plan, runs) or derived_problem(folder, plan, runs):
        raise UsageError(f"--merge: {folder}/runs.csv {problem}")
    return recorded, runs


def values_problem(plan: Plan, runs: pd.DataFrame) -> str | None:
    """Why a part's runs.csv holds a row no run of its plan gives though each value is inside its column's limits
    (study_tables.SCENARIO1_RUNS), as words after the file, or None: a queue longer than the road, a delay or a
    waiting time above the total time spent, more total time spent than every vehicle its demand sends being on the
    road the whole run (issue 82, probe 8, J7: a 999,999 m queue on a 2 km road, a delay above the total time spent,
    5e5 veh-h in a 20 s run were merged; a wave onset share without a counted wave is a real run's), or a value
    _run_bounds refuses (probe 13, F7)."""
    from coopsumo.config import ControlConfig, RoadConfig

    sim_s = plan.steps * ControlConfig().dt_s
    road_m = RoadConfig().length_m
    for i, row in enumerate(runs.to_dict("records"), start=1):
        most = (sim_s / float(row["t_up_s"]) + 1.0) * plan.lanes * sim_s / 3600.0
        checks = ((row["queue_m"] > road_m + 1.0, f"queue_m = {row['queue_m']:g}, longer than the {road_m:g} m road"),
                  (row["delay_veh_h"] > row["tts_veh_h"] + 1e-9, "delay_veh_h above its tts_veh_h"),
                  (row["waiting_veh_h"] > row["tts_veh_h"] + 1e-9, "waiting_veh_h above its tts_veh_h"),
                  (row["tts_veh_h"] > most, f"tts_veh_h = {row['tts_veh_h']:g}, more than its demand's vehicles "
                                            f"spend in a {sim_s:g} s run ({most:.3g})"),
                  *_run_bounds(plan, row))  # fmt: skip
        if why := next((text for bad, text in checks if bad), None):  # NaN compares False: a blank value passes
            return f"row {i} has {why}"
    return None


def _run_bounds(plan: Plan, row: dict[str, Any]) -> list[tuple[bool, str]]:
    """(whether the row breaks it, why) for each limit a run of `plan` sets on the row: a mean speed above the road's
    speed limit and the fastest desired speed, more lane changes per vehicle than one after another in the run (a
    change takes control.t_change_s), more vehicles waiting at the end than its demand sends, more waves or slow
    regions than cells of the speed field they are found in (measures.FIELD_DT_S by FIELD_DX_M on each lane), a
    horizon after the accident's start that is not its plan's (issue 82, probe 13, F7: 60 m/s, 500 lane changes per
    vehicle, 1e5 vehicles waiting, 1e6 waves, a horizon of 99999 s in a 30 s run were merged); a recovery or a spill
    after the run's end, more lane changes in a queue than lane changes (probe 14, F3: a recovery of 500 s in a 25 s
    horizon, queue lane changes 2 beside none, were merged)."""
    from coopsumo.config import ControlConfig, DemandConfig, RoadConfig
    from coopsumo.studies.scenario1.measures import FIELD_DT_S, FIELD_DX_M

    control, road, lanes = ControlConfig(), RoadConfig(), plan.lanes
    sim_s = plan.steps * control.dt_s
    fastest = max(road.speed_limit_mps, DemandConfig().v_exp_max_kmh / 3.6)
    turns = sim_s / control.t_change_s + 1.0
    sends = (sim_s / float(row["t_up_s"]) + 1.0) * lanes
    cells = lanes * math.ceil(sim_s / FIELD_DT_S) * math.ceil(road.length_m / FIELD_DX_M)
    horizon = (plan.steps - plan.accident_start) * control.dt_s
    bounds = [(row["mean_speed_mps"] > fastest + 0.01, f"mean_speed_mps = {row['mean_speed_mps']:g}, above any "
                                                       f"vehicle's speed on its road ({fastest:g} m/s)"),
              (row["waiting_at_end_veh"] > sends, f"waiting_at_end_veh = {row['waiting_at_end_veh']:g}, more than its "
                                                  f"demand sends in a {sim_s:g} s run ({sends:.3g})"),
              (not abs(row["horizon_after_start_s"] - horizon) <= 1e-6,
               f"horizon_after_start_s = {row['horizon_after_start_s']:g}, not its plan's {horizon:g} s")]
    bounds += [(row[c] > turns, f"{c} = {row[c]:g}, more than one vehicle can make one after another in a "
                                f"{sim_s:g} s run ({turns:g})")
               for c in ("lane_changes_per_vehicle", "queue_lane_changes_per_vehicle")]  # fmt: skip
    bounds += [(row[c] > cells, f"{c} = {row[c]:g}, more than the {cells} cells of the speed field they are found in")
               for c in ("waves", "slow_regions")]  # fmt: skip
    bounds += [(row[c] > horizon + 1e-6, f"{c} = {row[c]:g}, after its run's end ({horizon:g} s after the accident's "
                                         "start): no run measures it there")
               for c in ("recovery_time_s", "system_recovery_s", "spilled_s")]  # fmt: skip
    bounds += [(row["queue_lane_changes_per_vehicle"] > row["lane_changes_per_vehicle"] + 1e-9,
                f"queue_lane_changes_per_vehicle = {row['queue_lane_changes_per_vehicle']:g} above its "
                f"lane_changes_per_vehicle = {row['lane_changes_per_vehicle']:g}: the changes in a queue are some of "
                "its lane changes")]  # fmt: skip
    return bounds


RUN_FILES = ("summary.json", "trajectories.parquet", "detectors.xml")
"""what scenario I's measures of one run are derived from (measures.run_metrics)"""


def derived_problem(folder: Path, plan: Plan, runs: pd.DataFrame) -> str | None:
    """Why a row of a part's runs.csv is not what its run folder, where the part still holds it
    (runs/t<T_up>/<label>[_m<training seed>]_seed<k>), gives (measures.run_metrics, every column; FITTED ones to
    FIT_RTOL), as words after the file, or None. A part committed without its run folders is judged by
    values_problem alone; one holding only some of a run's RUN_FILES, or a file that is not a regular one, is refused
    (issue 82, probe 13, F7: collisions 3 where the run had none, a total time spent of 0.01 veh-h where its run gives
    0.069, were merged)."""
    from coopsumo.config import ControlConfig
    from coopsumo.studies.scenario1.measures import run_metrics
    from coopsumo.studies.scenario1.plan import accident_config, run_folder

    sample_s = plan.trajectory_every * ControlConfig().dt_s
    for i, row in enumerate(runs.to_dict("records"), start=1):
        model = None if pd.isna(row["train_seed"]) else int(row["train_seed"])
        run = folder / run_folder(str(row["policy"]), int(row["seed"]), float(row["t_up_s"]), model)
        there = [name for name in RUN_FILES if os.path.lexists(run / name)]
        if not there:
            continue
        if missing := [name for name in RUN_FILES if not (run / name).is_file()]:
            return f"row {i}: its run folder {run} holds no regular {missing[0]}"
        try:
            derived = run_metrics(run, accident_config(plan, "keep", int(row["seed"]), float(row["t_up_s"])), sample_s)
        except (OSError, ValueError, KeyError, TypeError) as err:
            return f"row {i}: its run folder {run} cannot be read ({type(err).__name__})"
        for column, value in derived.items():
            if not _same_value(row.get(column), value, FIT_RTOL if column in FITTED else 1e-12):
                return f"row {i} has {column} = {row.get(column)}, but its run folder {run} gives {value}: edited?"
    return None


def _same_value(a: Any, b: Any, rtol: float) -> bool:
    """A runs.csv value and the one its run gives: both blank, the same text, or numbers equal to rtol."""
    if pd.isna(a) and pd.isna(b):
        return True
    if isinstance(a, str) or isinstance(b, str) or pd.isna(a) or pd.isna(b):
        return bool(a == b)
    return math.isclose(float(a), float(b), rel_tol=rtol, abs_tol=1e-12)


def _without_seeds(plan: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in plan.items() if k != "train_seeds"}


def check_parts(parts: list[tuple[Path, dict[str, Any], pd.DataFrame]]) -> None:
    """The parts make one study: one plan but for the training seeds, one learner, no training seed twice, and the
    same baseline runs to the last digit. UsageError naming the first part that differs and how."""
    first_folder, first, first_runs = parts[0]
    seen: dict[int, Path] = {}
    baselines = first_runs[first_runs["train_seed"].isna()].reset_index(drop=True)
    for folder, recorded, runs in parts:
        if _without_seeds(recorded["plan"]) != _without_seeds(first["plan"]):
            differs = sorted(k for k in set(recorded["plan"]) | set(first["plan"]) if k != "train_seeds"
                             and recorded["plan"].get(k) != first["plan"].get(k))  # fmt: skip
            raise UsageError(f"--merge: {folder}'s plan differs from {first_folder}'s in {', '.join(differs)}: the "
                             "parts of one study differ only in their training seeds")  # fmt: skip
        if results_view(recorded["learners"]) != results_view(first["learners"]):  # a retired setting at its value
            raise UsageError(f"--merge: {folder} trained another learner than {first_folder} (plan.json's learners)")
        for seed in recorded["plan"]["train_seeds"]:
            if seed in seen:
                raise UsageError(f"--merge: training seed {seed} is in {seen[seed]} and in {folder}: a model once")
            seen[seed] = folder
        if problem := rows_problem(recorded["plan"], runs):
            raise UsageError(f"--merge: {folder}/runs.csv {problem}")
        theirs = runs[runs["train_seed"].isna()].reset_index(drop=True)
        if column := baselines_differ(theirs, baselines):
            raise UsageError(f"--merge: {folder}'s baseline runs differ from {first_folder}'s in {column} (the same "
                             "policies on the same seeds must give the same runs)")  # fmt: skip


FITTED = ("wave_speed_kmh",)
"""runs.csv columns that come out of a least-squares fit (report.bottleneck's wave fronts): computed through BLAS, so
exact on one processor and equal only to FIT_RTOL on another (docs/run-folders.md); every other column is exact"""
FIT_RTOL = 1e-9


def baselines_differ(a: pd.DataFrame, b: pd.DataFrame) -> str | None:
    """Which column two parts' baseline runs differ in, or None: every column to the last digit but FITTED's, which
    agree within FIT_RTOL (parts run on different machines: measured 2.3e-13 km/h, 2026-12-02)."""
    if list(a.columns) != list(b.columns) or len(a) != len(b):
        return "their columns or number of runs"
    for column in a.columns:
        x, y = a[column], b[column]
        if column in FITTED:
            same = bool(np.allclose(x.astype(float), y.astype(float), rtol=FIT_RTOL, atol=0.0, equal_nan=True))
        else:
            same = x.equals(y)
        if not same:
            return column
    return None


def rows_problem(plan: dict[str, Any], runs: pd.DataFrame) -> str | None:
    """What is wrong with a part's rows against its plan, or None: one run per model (preset, alpha, training seed),
    demand and evaluation seed, one per baseline, demand and seed, and no other row."""
    demands = [(float(t), int(k)) for t in plan["t_ups"] for k in plan["seeds"]]
    expected = {(model_label(p, float(a)), int(m), t, k) for p in plan["presets"] for a in plan["alphas"]
                for m in plan["train_seeds"] for t, k in demands}  # fmt: skip
    baselines = sorted(set(runs.loc[runs["train_seed"].isna(), "policy"]))
    expected |= {(b, -1, t, k) for b in baselines for t, k in demands}
    found = [(str(r.policy), -1 if pd.isna(r.train_seed) else int(r.train_seed), float(r.t_up_s), int(r.seed))
             for r in runs.itertuples()]  # fmt: skip
    if len(found) != len(set(found)):
        return "holds a run twice"
    if missing := sorted(expected - set(found)):
        policy, model, t_up, seed = missing[0]
        of = "" if model < 0 else f" of training seed {model}"
        return f"lacks {len(missing)} of its plan's runs (first: {policy}{of} at T_up {t_up:g} s, seed {seed})"
    if extra := sorted(set(found) - expected):
        return f"holds {len(extra)} runs its plan does not name (first: {extra[0][0]})"
    return None


def merged_runs(parts: list[tuple[Path, dict[str, Any], pd.DataFrame]]) -> pd.DataFrame:
    """The baselines of the first part once, then every part's model runs, in the first part's order of policies
    and demands, models by training seed."""
    runs = parts[0][2]
    models = pd.concat([r[r["train_seed"].notna()] for _, _, r in parts], ignore_index=True)
    rows = pd.concat([models, runs[runs["train_seed"].isna()]], ignore_index=True)
    order = {lab: i for i, lab in enumerate(dict.fromkeys(runs["policy"]))}
    rows = rows.assign(_p=rows["policy"].map(order)).sort_values(["t_up_s", "_p", "train_seed", "seed"],
                                                                 ascending=[False, True, True, True],
                                                                 kind="stable")  # fmt: skip
    return rows.drop(columns="_p").reset_index(drop=True)


def _timing(folder: Path) -> str:
    """The part's report's line on its wall time and compute, or a dash."""
    page = folder / "report.md"
    lines = page.read_text().splitlines() if page.is_file() else []
    return next((ln for ln in lines if ln.startswith("Wall time of this invocation")), "-")


def _check_out(out: Path, folders: list[Path]) -> None:
    for folder in folders:
        if out.resolve() == folder.resolve() or folder.resolve() in out.resolve().parents:
            raise UsageError(f"--out {out} is inside the part {folder}: give a folder of its own")
    if problem := owned_problem(out, f"--out {out}"):  # in another study's, a run's folder or the model store
        raise UsageError(problem)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} is a file, not a folder")
    if out.is_dir() and (out / MERGED).exists():
        recorded = read_json_object(out / MERGED)
        before = recorded.get("parts") if recorded is not None else None
        if not isinstance(before, list) or not all(isinstance(p, str) and p for p in before) or \
                not {Path(p).resolve() for p in before} <= {f.resolve() for f in folders}:  # fmt: skip
            raise UsageError(f"--out {out} holds a merge of other parts ({MERGED}): pick another --out (a merge "
                             "may only grow by parts)")  # fmt: skip
    if out.is_dir():
        others = sorted(p.name for p in out.iterdir() if p.name not in OWN_FILES and not p.name.startswith("."))
        if others:
            raise UsageError(f"--out {out} holds other files ({', '.join(others[:3])}): a merge writes into a folder "
                             "of its own")  # fmt: skip


def merged_study(profile: str, presets: Sequence[str]) -> str:
    """Which study a merge of parts of the profile `profile` with the learner presets `presets` writes, as its
    folder's marker names it (run_dirs.check_study_root): another than a study run ("the default profile's study")."""
    return profile_study(profile, "study merged from parts", presets)


def recorded_merge(root: Path) -> str | None:
    """Which study the folder `root` holds by its plan.json (a merge written before its marker named the study:
    results/scenario1_alpha_only_dense_s/merged), or None when it cannot be read: a merge's when merge.json is there,
    else a study run's (run_folders.recorded_profile)."""
    if not (root / MERGED).exists():
        return recorded_profile("plan.json", "plan", "profile", presets=("plan", "presets"))(root)
    try:
        plan = read_json(root / "plan.json")["plan"]
        profile, presets = plan["profile"], plan["presets"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not isinstance(profile, str) or not isinstance(presets, list) or not all(isinstance(p, str) for p in presets):
        return None
    return merged_study(profile, presets)


def merge_parts(folders: list[Path], out: Path) -> int:
    """Check the parts, then write the merged study into out (module docstring); 0. Out is claimed as a study root
    (run_dirs.study_root: lock, ownership, a marker naming merged_study) before anything is written into it: a folder
    of another study, or a merge of other parts, is refused (issue 82, probe 7, I3)."""
    if len(folders) < 2:
        raise UsageError("--merge needs at least two part folders, comma-separated")
    if len({f.resolve() for f in folders}) != len(folders):
        raise UsageError("--merge names a part twice")
    _check_out(out, folders)
    parts = [(folder, *_part(folder)) for folder in folders]
    check_parts(parts)
    rows = merged_runs(parts)
    SCENARIO1_RUNS.check_frame(rows, out / "runs.csv")
    summary = aggregate(rows)
    SCENARIO1_SUMMARY.check_frame(summary, out / "summary.csv")
    plan = parts[0][1]["plan"]
    with study_root(out, "scenario1", OWN, merged_study(plan["profile"], plan["presets"]), recorded_merge):
        _check_out(out, folders)  # again, under the lock
        return _write_merge(parts, out, rows, summary)


def _write_merge(parts: list[tuple[Path, dict[str, Any], pd.DataFrame]], out: Path, rows: pd.DataFrame,
                 summary: pd.DataFrame) -> int:  # fmt: skip
    """Write the merged study of the checked parts (its runs and summary checked) into its claimed folder out; 0."""
    absolute = [str(folder.absolute()) for folder, _, _ in parts]  # from any working folder the same parts (I3)
    first = parts[0][1]
    seeds = sorted(s for _, recorded, _ in parts for s in recorded["plan"]["train_seeds"])
    plan_dict = {**first["plan"], "train_seeds": seeds}
    stage = Path(tempfile.mkdtemp(prefix=f".{out.name}.merge-", dir=out.parent))
    try:  # every file written beside out first, then moved in: an interrupted merge leaves out as it was
        rows.to_csv(stage / "runs.csv", index=False)
        summary.to_csv(stage / "summary.csv", index=False)
        write_json(stage / "plan.json", {"plan": plan_dict, "learners": first["learners"], "versions": versions(),
                                         "parts": absolute})  # fmt: skip
        presets, alphas = plan_dict["presets"], plan_dict["alphas"]
        claim = ""
        if 0.0 in alphas and 8.0 in alphas:
            from coopsumo.studies.scenario1.claim_a_report import write_claim_a

            found = write_claim_a(stage, rows, model_label(presets[0], 8.0), model_label(presets[0], 0.0))
            claim = (f"\n\nClaim (a) under its analysis plan: [claim_a.md](claim_a.md) ({found['planned_models']} "
                     "models per alpha planned from the first 10), `fig_thrashing.png`.")  # fmt: skip
        (stage / "report.md").write_text(report_text(parts, rows, plan_dict) + claim + "\n")
        write_json(stage / MERGED, {"parts": absolute, "train_seeds": seeds})
        for name in sorted(p.name for p in stage.iterdir() if p.name != MERGED) + [MERGED]:  # merge.json last
            os.replace(stage / name, out / name)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    print(f"scenario1: merged {len(parts)} parts ({len(seeds)} models per alpha) into {out}")
    return 0


def report_text(parts: list[tuple[Path, dict[str, Any], pd.DataFrame]], rows: pd.DataFrame,
                plan_dict: dict[str, Any]) -> str:  # fmt: skip
    """The merged study's short report: its parts with their models and compute, and the mean total time spent per
    policy and demand over every model and seed."""
    p = plan_dict
    lines = [f"# Scenario I, merged from {len(parts)} parts: {', '.join(p['presets'])}, "
             f"{len(p['train_seeds'])} models per alpha", "",
             f"Alphas {', '.join(f'{a:g}' for a in p['alphas'])}; demands T_up "
             f"{', '.join(f'{t:g}' for t in p['t_ups'])} s; {len(p['seeds'])} evaluation seeds; the baselines once "
             "(every part ran them on the same seeds, and they agree to the last digit, the fitted wave speed to a "
             "relative 1e-9).", "",
             md_table(["part", "training seeds", "its compute"],
                      [[f"`{folder}`", ", ".join(str(s) for s in recorded["plan"]["train_seeds"]), _timing(folder)]
                       for folder, recorded, _ in parts])]  # fmt: skip
    spent = [re.search(r"about \d+ min \((\d+) core-min\)", _timing(folder)) for folder, _, _ in parts]
    if all(spent):
        core_min = sum(int(m.group(1)) for m in spent if m)
        lines += ["", f"In all, from scratch: {core_min:,} core-min ({core_min / 60:.1f} core-hours), about "
                      f"{core_min / 120:.1f} h on 2 cores (each part's estimate from the runs it ran itself)."]
    table = rows.groupby(["t_up_s", "policy"], sort=False)["tts_veh_h"].agg(["mean", "std", "count"]).reset_index()
    rows = [[f"{r.t_up_s:g}", str(r.policy), f"{r.mean:.1f}", "-" if not math.isfinite(r.std) else f"{r.std:.1f}",
             str(r.count)] for r in table.itertuples()]  # fmt: skip
    lines += ["", "Total time spent (veh-h), mean over models and seeds:", "",
              md_table(["T_up (s)", "policy", "mean", "sd", "runs"], rows)]
    return "\n".join(lines)
