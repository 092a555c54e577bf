"""Policies through scenario I's accident, for the studies that only drive (regime_map, accident_seeds): the cell of
one run (scenario I's cell function and record, so its run folder is one scenario I would write), running a list of
them on the shared runner, and scenario I's measures of a finished run.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from coopsumo.config import RoadConfig, SimConfig, to_dict
from coopsumo.studies.engine.cells import failed_keys, run_cells
from coopsumo.studies.scenario1 import study as scenario1
from coopsumo.studies.scenario1.plan import Plan

REQUIRED = ("mean_speed_mps", "collisions", "teleports")
"""summary values a stored run record must hold as finite numbers to be reused"""


def scaled(plan: Plan, factor: float) -> Plan:
    """plan with its run and its accident window (start and length) `factor` times as long (as `scenario1 --steps`
    scales them)."""
    return replace(plan, steps=max(int(plan.steps * factor), 10),
                   accident_start=max(int(plan.accident_start * factor), 1),
                   accident_steps=max(int(plan.accident_steps * factor), 1))  # fmt: skip


def run_spec(plan: Plan, cfg: SimConfig, key: str, folder: str, label: str, seed: int, t_up_s: float) -> dict[str, Any]:
    """The cell of one accident run of `plan` with configuration cfg into ROOT/<folder>."""
    return {"key": key, "kind": "run", "label": label, "seed": seed, "t_up_s": t_up_s, "out": folder, "after": None,
            "config": to_dict(cfg), "trajectory_every": plan.trajectory_every,
            "outputs": to_dict(plan.outputs())}  # fmt: skip


def run_all(specs: Sequence[dict[str, Any]], root: Path, plans: Iterable[Plan], prog: str, workers: int = 2,
            backend: str = "local", address: str | None = None, progress: bool = True) -> list[str]:  # fmt: skip
    """Run the accident runs not finished in root on the shared runner; the keys of those that failed."""
    roads = [RoadConfig(lanes=p.lanes, loop_period_s=p.loop_period_s) for p in plans]
    records = run_cells(specs, root, scenario1.run_cell, scenario1.failed_record, prog=prog, required=REQUIRED,
                        roads=roads, workers=workers, backend=backend, address=address, progress=progress,
                        desc="accident runs")  # fmt: skip
    return failed_keys(records)


def measures(root: Path, spec: dict[str, Any], cfg: SimConfig) -> dict[str, Any]:
    """Scenario I's measures of the finished run of `spec` (scenario1_measures.run_metrics)."""
    from coopsumo.studies.scenario1.measures import run_metrics

    return run_metrics(root / spec["out"], cfg, spec["trajectory_every"] * cfg.control.dt_s)
