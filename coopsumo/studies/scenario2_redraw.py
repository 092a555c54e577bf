"""Scenario II redrawn: a finished sweep's tables, figures and report.md from its own records, nothing trained or
run. Apart from both reports (scenario2_report for the per-alpha profiles, scenario2_gate_report for the lane-network
ones) so that neither imports the other."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd

from coopsumo.runio import write_json
from coopsumo.studies.scenario2_gate_report import write_lane_outputs
from coopsumo.studies.scenario2_plan import Profile
from coopsumo.studies.scenario2_report import write_outputs


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
