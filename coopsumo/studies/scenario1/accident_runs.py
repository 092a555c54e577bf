"""Scenario I's cell (a training into the model store or one policy through the accident into its run folder, and the
record either leaves), which the study (study.py) runs; for the runs that only drive (regime_map, the follow-up
accident_seeds) a list of accident runs on the shared runner, and scenario I's measures of a finished run.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Sequence
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

from coopsumo.config import OutputConfig, RoadConfig, SimConfig, to_dict
from coopsumo.policy_spec import policy_file
from coopsumo.run_dirs import check_run_dir
from coopsumo.studies.engine.cells import Cell, CellKind, Run, Study, Train
from coopsumo.studies.engine.records import CellRecords
from coopsumo.studies.engine.run_folders import reusable_run, simulate_into
from coopsumo.studies.scenario1.plan import Plan

# -- scenario I's cell, run by the shared runner (coopsumo.studies.engine.runner), one per worker process ----------
RECORDS = CellRecords(("key", "kind", "label", "seed", "t_up_s", "out", "after"))
"""a cell's record: a training ("train") or an accident run ("run"), its folder under the study's root"""


def work(spec: dict[str, Any]) -> Cell:
    """What the cell of `spec` does (cells.perform runs it): a training ("train") in the model store `store`
    (an interrupted training continues exactly), ROOT/<out> linking to it, or one policy through the accident ("run")
    into ROOT/<out>, written atomically (a killed run leaves no half folder)."""
    from coopsumo.config import sim_config_from_dict

    if spec["kind"] == "train":
        return Cell(Train(spec["training"], spec["out"], store=spec["store"]))
    measure = partial(simulate_into, trajectory_every=spec["trajectory_every"], outputs=OutputConfig(**spec["outputs"]),
                      atomic=True)  # fmt: skip
    return Cell(runs=(Run(sim_config_from_dict(spec["config"]), spec["out"]),), label=spec["out"], measure=measure)


CELLS = CellKind(RECORDS, work)
REQUIRED = ("mean_speed_mps", "collisions", "teleports")
"""summary values a stored record (a run's, a training's) must hold as finite numbers to be reused"""


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
            backend: str = "local", address: str | None = None, progress: bool = True,
            name: str = "") -> list[str]:  # fmt: skip
    """Run the accident runs not finished in root on the shared runner (engine/cells.Study; `name` the plan's, in its
    first line); the keys of those that failed. A run is finished when its cell record is reusable
    (records.reusable_keys) and so is its run folder (folder_reusable)."""
    roads = [RoadConfig(lanes=p.lanes, loop_period_s=p.loop_period_s) for p in plans]
    study = Study(prog, CELLS, REQUIRED, places, lambda todo: None, checks=(_unlike_folders,))
    meta = study.run(specs, root, {}, name, lambda records, meta: None, roads=roads, workers=workers, backend=backend,
                     address=address, progress=progress)  # fmt: skip
    return list(meta["failed_cells"])


def places(root: Path, spec: dict[str, Any]) -> tuple[Path, ...]:
    """A cell's run folder, checked for a user's files before any cell runs (cells.Study); a training has none (its
    folder is a link into the model store)."""
    return (root / spec["out"],) if spec["kind"] == "run" else ()


def _unlike_folders(root: Path, specs: Sequence[dict[str, Any]], prog: str) -> set[str]:
    """The runs among `specs` (records reusable) whose run folder is not (folder_reusable)."""
    return {s["key"] for s in specs if not folder_reusable(root, s, prog)}


def folder_reusable(root: Path, spec: dict[str, Any], prog: str, model: bool = False) -> bool:
    """True when the run folder of the cell `spec`, whose record is reusable, can be reused too, judged as scenario
    I judges its own before reuse (run_folders.reusable_run: its configuration, SUMO outputs, summary,
    detectors.xml, fcd.xml, tripinfo.xml and trajectories.parquet, each the file its run wrote; with `model`, the
    model it drove too: the file its policy names as it is now, run_folders.model_driven). Otherwise the run is
    redone, with one line naming the folder and why; a folder removed (no summary.json) too. UsageError when the
    folder is not the study's to run again (run_dirs.check_run_dir). Issue 82, probe 15, T3: a garbage
    detectors.xml, trajectories.parquet or summary.json ended every rerun in a traceback, and a folder removed was
    refused; probe 16, TR1: another run's file copied in was reused."""
    out = root / spec["out"]
    if (out / "summary.json").exists():
        driven = policy_file(spec["config"]["policy"]) if model else None
        return reusable_run(out, spec["config"], OutputConfig(**spec["outputs"]), None if driven is None
                            else Path(driven), prog=prog)  # fmt: skip
    check_run_dir(out.resolve(), "simulate")
    print(f"{prog}: run folder {out} has no summary.json (removed?); running it again", file=sys.stderr)
    return False


def measures(root: Path, spec: dict[str, Any], cfg: SimConfig) -> dict[str, Any]:
    """Scenario I's measures of the finished run of `spec` (scenario1_measures.run_metrics)."""
    from coopsumo.studies.scenario1.measures import run_metrics

    return run_metrics(root / spec["out"], cfg, spec["trajectory_every"] * cfg.control.dt_s)
