"""Scenario II redrawn: a finished sweep's tables, figures and report.md from its own records, nothing trained or
run; or one sweep merged from its parts, run one lane count at a time. Apart from both reports (scenario2_report for
the per-alpha profiles, scenario2_gate_report for the lane-network ones) so that neither imports the other."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

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


Part = tuple[dict[str, Any], pd.DataFrame, pd.DataFrame]
"""a finished sweep's sweep.json, runs.csv and evals.csv"""


def read_parts(parts: list[Path]) -> list[Part]:
    """The finished sweeps to merge (merge_parts), checked: UsageError when a part is missing a file, is not a
    finished lane-network sweep, differs from the first in anything but its lanes, or repeats another's lanes."""
    metas, tables = [], []
    for part in parts:
        try:
            meta = json.loads((part / "sweep.json").read_text())
            runs, evals = pd.read_csv(part / "runs.csv"), pd.read_csv(part / "evals.csv")
        except (OSError, ValueError) as err:
            raise UsageError(f"--merge: {part} is not a finished scenario2 sweep ({err.__class__.__name__}: "
                             f"{getattr(err, 'strerror', None) or err})") from None  # fmt: skip
        if "wall_seconds" not in meta or not meta.get("profile", {}).get("lane_networks"):
            raise UsageError(f"--merge: {part} is not a finished sweep of a lane-network profile (full, check, paper)")
        metas.append(meta)
        tables.append((runs, evals))
    first = {k: v for k, v in metas[0]["profile"].items() if k != "lanes"}
    lanes: list[int] = []
    for part, meta in zip(parts, metas, strict=True):
        if {k: v for k, v in meta["profile"].items() if k != "lanes"} != first:
            raise UsageError(f"--merge: {part} was run with another profile than {parts[0]} (only --lanes may differ)")
        if overlap := set(lanes) & set(meta["profile"]["lanes"]):
            raise UsageError(f"--merge: {part} repeats lanes {sorted(overlap)} of another part")
        lanes += meta["profile"]["lanes"]
    return [(m, t[0], t[1]) for m, t in zip(metas, tables, strict=True)]


def merge_parts(parts: list[Path], read: list[Part], out: Path) -> dict[str, Any]:
    """One sweep in `out` from its finished parts (read_parts): sweeps of one lane-network profile run with
    different --lanes (a study longer than a session runs one lane count at a time). Their runs.csv and evals.csv
    are concatenated, sweep.json records the profile with every part's lanes and each part's folder, lanes, time and
    versions, and the tables, figures and report are drawn as rewrite_outputs draws them."""
    metas, tables = [r[0] for r in read], [(r[1], r[2]) for r in read]
    lanes = [n for m in metas for n in m["profile"]["lanes"]]
    merged = {**metas[0], "profile": {**metas[0]["profile"], "lanes": sorted(lanes)}}
    merged["conditions"] = sorted((c for m in metas for c in m["conditions"]), key=lambda c: (c["lanes"],
                                                                                              -c["t_up_s"]))
    for name in MERGED_SUMS:
        total = sum(m[name] for m in metas)
        merged[name] = round(total, 1) if isinstance(total, float) else total
    merged["failed_cells"] = [k for m in metas for k in m.get("failed_cells", [])]
    merged["trainings"] = sum(int(m["trainings"]) for m in metas)
    merged["parts"] = [{"folder": str(part), "lanes": m["profile"]["lanes"], "wall_seconds": m["wall_seconds"],
                        "workers": m["workers"], "versions": m["versions"]}
                       for part, m in zip(parts, metas, strict=True)]  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    pd.concat([t[0] for t in tables], ignore_index=True).to_csv(out / "runs.csv", index=False)
    pd.concat([t[1] for t in tables], ignore_index=True).to_csv(out / "evals.csv", index=False)
    write_json(out / "sweep.json", merged)
    return rewrite_outputs(out)
