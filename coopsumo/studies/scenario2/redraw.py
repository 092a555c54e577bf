"""Scenario II redrawn: a finished sweep's tables, figures and report.md from its own records, nothing trained or
run; or one sweep merged from its parts, run one lane count at a time. Apart from both reports (scenario2_report for
the per-alpha profiles, scenario2_gate_report for the lane-network ones) so that neither imports the other."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, NamedTuple

import pandas as pd

from coopsumo.errors import UsageError
from coopsumo.files import write_json
from coopsumo.studies.engine.run_folders import study_root
from coopsumo.studies.scenario2.gate_report import console_lines, write_lane_outputs
from coopsumo.studies.scenario2.plan import Profile
from coopsumo.studies.scenario2.report import write_outputs
from coopsumo.validation import split_list


def rewrite_outputs(root: Path) -> dict[str, Any]:
    """Redraw a finished sweep's tables, figures and report.md from its runs.csv and sweep.json alone, nothing
    trained or run (a committed folder keeps no cells/, so rerunning its command would train every cell again);
    the bootstraps are seeded, so the numbers come out as they were; a lane-network profile's (full, check) from its
    evals.csv too (scenario2_gate_report). Returns sweep.json's new content."""
    meta = json.loads((root / "sweep.json").read_text())
    fields: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in meta["profile"].items()}
    profile = Profile(**fields)
    runs, n_boot = pd.read_csv(root / "runs.csv"), int(meta["bootstrap_replicates"])
    if profile.lane_networks:
        write_lane_outputs(root, runs, pd.read_csv(root / "evals.csv"), profile, meta, n_boot)
    else:
        write_outputs(root, runs, profile, meta, n_boot)
    write_json(root / "sweep.json", meta)
    return meta


MERGED_SUMS = ("cells_run", "wall_seconds", "cell_wall_seconds_sum", "cell_cpu_seconds_sum")
"""sweep.json values a merged sweep adds up over its parts (the work each part did)"""


class Part(NamedTuple):
    """A finished sweep to merge: its folder and its sweep.json, runs.csv and evals.csv."""

    folder: Path
    meta: dict[str, Any]
    runs: pd.DataFrame
    evals: pd.DataFrame


SPLIT_BY = ("lanes", "alphas", "check_alphas")
"""profile fields in which the parts of one sweep may differ: a part is some lane counts at some alphas"""
TIMING = ("wall_seconds", "train_wall_seconds", "cell_wall_s", "cell_cpu_s", "steps_per_second", "sumo_step_share")
"""runs.csv and evals.csv columns that say how fast a run went, not what it gave"""


def read_parts(folders: list[Path]) -> list[Part]:
    """The finished sweeps to merge (merge_parts), checked: UsageError when a part is missing a file, is not a
    finished lane-network sweep, has tables that disagree with its sweep.json (another number of cells, another lane
    count), differs from the first in anything but its lanes and alphas, or when together the parts do not make one
    grid (every lane count at every alpha, once) or two parts of one lane count differ in their classical runs
    or their learner."""
    parts = []
    for folder in folders:
        try:
            meta = json.loads((folder / "sweep.json").read_text())
            runs, evals = pd.read_csv(folder / "runs.csv"), pd.read_csv(folder / "evals.csv")
        except (OSError, ValueError) as err:
            raise UsageError(f"--merge: {folder} is not a finished scenario2 sweep ({err.__class__.__name__}: "
                             f"{getattr(err, 'strerror', None) or err})") from None  # fmt: skip
        if "wall_seconds" not in meta or not meta.get("profile", {}).get("lane_networks"):
            raise UsageError(f"--merge: {folder} is not a finished sweep of a lane-network profile (full, check, "
                             "paper)")  # fmt: skip
        lanes = set(meta["profile"]["lanes"])
        if len(runs) != meta.get("cells") or not {*runs.get("lanes", []), *evals.get("lanes", [])} <= lanes:
            raise UsageError(f"--merge: {folder}'s runs.csv and evals.csv do not agree with its sweep.json "
                             f"({len(runs)} rows for {meta.get('cells')} cells of lanes {sorted(lanes)})")  # fmt: skip
        parts.append(Part(folder, meta, runs, evals))
    first = {k: v for k, v in parts[0].meta["profile"].items() if k not in SPLIT_BY}
    grid: set[tuple[int, float]] = set()
    for part in parts:
        if {k: v for k, v in part.meta["profile"].items() if k not in SPLIT_BY} != first:
            raise UsageError(f"--merge: {part.folder} was run with another profile than {parts[0].folder} (only "
                             "--lanes and --alphas may differ)")  # fmt: skip
        cells = {(n, a) for n in part.meta["profile"]["lanes"] for a in part.meta["profile"]["alphas"]}
        if overlap := grid & cells:
            n, a = min(overlap)
            raise UsageError(f"--merge: {part.folder} repeats lanes {n} at alpha {a:g} of another part")
        grid |= cells
    lanes, alphas = {n for n, _ in grid}, {a for _, a in grid}
    if missing := {(n, a) for n in lanes for a in alphas} - grid:
        n, a = min(missing)
        raise UsageError(f"--merge: no part holds lanes {n} at alpha {a:g}: the parts do not make one grid")
    _one_of_each([part.runs for part in parts], ["key"], "runs.csv")
    _one_of_each([part.evals for part in parts], ["key", "eval_seed"], "evals.csv")
    _learners([part.meta for part in parts])
    return parts


def _one_of_each(tables: list[pd.DataFrame], ids: list[str], what: str) -> pd.DataFrame:
    """The parts' tables together, the runs of `keep`, `greedy` and MOBIL that two parts of one lane count both ran
    (the same `ids`) kept once; UsageError when those differ in anything but their timing (not the same code or
    seeds), or when a model's run is in two parts."""
    table = pd.concat(tables, ignore_index=True)
    twice = table[table.duplicated(ids, keep=False)]
    if (twice["policy"] == "dqn").any():
        raise UsageError(f"--merge: a model's run appears in two parts' {what}")
    differ = twice.drop(columns=[c for c in TIMING if c in twice]).drop_duplicates()
    if differ.duplicated(ids).any():
        key = differ.loc[differ.duplicated(ids), "key"].iloc[0]
        raise UsageError(f"--merge: two parts ran {key} with different results ({what}): not the same code?")
    return table.drop_duplicates(ids, keep="first").reset_index(drop=True)


def _learners(metas: list[dict[str, Any]]) -> dict[str, Any]:
    """The learner of every lane count the parts trained (sweep.json's "learner", per lane count); UsageError when
    two parts of one lane count trained with different learners."""
    learners: dict[str, Any] = {}
    for meta in metas:
        for lanes, learner in meta["learner"].items():
            if learners.setdefault(lanes, learner) != learner:
                raise UsageError(f"--merge: two parts trained {lanes.replace('_', ' ')} with different learners")
    return dict(sorted(learners.items(), key=lambda item: int(item[0].split("_")[0])))


def merge_parts(parts: list[Part], out: Path) -> dict[str, Any]:
    """One sweep in `out` from its finished parts (read_parts): sweeps of one lane-network profile run with
    different --lanes, or one lane count's alphas in two parts (a study longer than a session runs one lane count, or
    part of one, at a time). Their runs.csv and evals.csv are concatenated (a classical run two parts of one lane
    count both made, kept once), sweep.json records the profile with every part's lanes and alphas and each part's
    folder, lanes, alphas, time and versions, and the tables, figures and report are drawn as rewrite_outputs draws
    them."""
    metas = [part.meta for part in parts]
    runs = _one_of_each([part.runs for part in parts], ["key"], "runs.csv")
    evals = _one_of_each([part.evals for part in parts], ["key", "eval_seed"], "evals.csv")
    union = {k: sorted({x for m in metas for x in m["profile"][k]}) for k in SPLIT_BY}
    merged = {**metas[0], "profile": {**metas[0]["profile"], **union}, "learner": _learners(metas)}
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
    runs.to_csv(out / "runs.csv", index=False)
    evals.to_csv(out / "evals.csv", index=False)
    write_json(out / "sweep.json", merged)
    return rewrite_outputs(out)


MERGE_ALONE = ("steps", "eval_steps", "seeds", "eval_seeds", "lanes", "alphas", "t_up", "policies", "mobil_p",
               "preset")  # fmt: skip
"""options that choose what a sweep runs, which --merge (nothing run) refuses"""


def merge_command(args: Any) -> int:
    """--merge: the parts' sweep folders merged into --out (merge_parts)."""
    if given := [f"--{name.replace('_', '-')}" for name in MERGE_ALONE if getattr(args, name) is not None]:
        raise UsageError(f"--merge runs nothing: {', '.join(given)} cannot go with it")
    if args.out is None:
        raise UsageError("--merge needs --out, the merged sweep's folder")
    parts = [Path(x) for x in split_list("--merge", args.merge)]
    if any(p.resolve() == args.out.resolve() for p in parts):
        raise UsageError(f"--merge: --out {args.out} is one of the parts")
    read = read_parts(parts)  # checked before anything is written
    with study_root(args.out, "scenario2"):
        meta = merge_parts(read, args.out)
    print("\n".join(console_lines(args.out)))
    print(f"scenario2: merged {len(parts)} parts ({meta['cells']} cells, lanes "
          f"{', '.join(map(str, meta['profile']['lanes']))}); report: {args.out / 'report.md'}")  # fmt: skip
    return 0
