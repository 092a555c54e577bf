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
from coopsumo.studies.scenario2.gate_report import write_lane_outputs
from coopsumo.studies.scenario2.plan import Profile
from coopsumo.studies.scenario2.report import write_outputs


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


MERGED_SUMS = ("cells", "cells_run", "cells_ok", "cells_failed", "wall_seconds", "cell_wall_seconds_sum",
               "cell_cpu_seconds_sum")  # fmt: skip
"""sweep.json values a merged sweep adds up over its parts"""


class Part(NamedTuple):
    """A finished sweep to merge: its folder and its sweep.json, runs.csv and evals.csv."""

    folder: Path
    meta: dict[str, Any]
    runs: pd.DataFrame
    evals: pd.DataFrame


def read_parts(folders: list[Path]) -> list[Part]:
    """The finished sweeps to merge (merge_parts), checked: UsageError when a part is missing a file, is not a
    finished lane-network sweep, has tables that disagree with its sweep.json (another number of cells, another lane
    count), differs from the first in anything but its lanes, or repeats another's lanes."""
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
    first = {k: v for k, v in parts[0].meta["profile"].items() if k != "lanes"}
    seen: set[int] = set()
    for part in parts:
        if {k: v for k, v in part.meta["profile"].items() if k != "lanes"} != first:
            raise UsageError(f"--merge: {part.folder} was run with another profile than {parts[0].folder} (only "
                             "--lanes may differ)")  # fmt: skip
        if overlap := seen & set(part.meta["profile"]["lanes"]):
            raise UsageError(f"--merge: {part.folder} repeats lanes {sorted(overlap)} of another part")
        seen |= set(part.meta["profile"]["lanes"])
    return parts


def merge_parts(parts: list[Part], out: Path) -> dict[str, Any]:
    """One sweep in `out` from its finished parts (read_parts): sweeps of one lane-network profile run with
    different --lanes (a study longer than a session runs one lane count at a time). Their runs.csv and evals.csv
    are concatenated, sweep.json records the profile with every part's lanes and each part's folder, lanes, time and
    versions, and the tables, figures and report are drawn as rewrite_outputs draws them."""
    metas = [part.meta for part in parts]
    lanes = sorted(n for m in metas for n in m["profile"]["lanes"])
    merged = {**metas[0], "profile": {**metas[0]["profile"], "lanes": lanes}}
    merged["conditions"] = sorted((c for m in metas for c in m["conditions"]), key=lambda c: (c["lanes"],
                                                                                              -c["t_up_s"]))
    for name in MERGED_SUMS:
        total = sum(m[name] for m in metas)
        merged[name] = round(total, 1) if isinstance(total, float) else total
    merged["failed_cells"] = [k for m in metas for k in m.get("failed_cells", [])]
    merged["trainings"] = sum(int(m["trainings"]) for m in metas)
    merged["parts"] = [{"folder": str(part.folder), "lanes": part.meta["profile"]["lanes"],
                        "wall_seconds": part.meta["wall_seconds"], "workers": part.meta["workers"],
                        "versions": part.meta["versions"]} for part in parts]  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    pd.concat([part.runs for part in parts], ignore_index=True).to_csv(out / "runs.csv", index=False)
    pd.concat([part.evals for part in parts], ignore_index=True).to_csv(out / "evals.csv", index=False)
    write_json(out / "sweep.json", merged)
    return rewrite_outputs(out)
