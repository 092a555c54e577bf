"""What a study's cell does, typed, and the one function that does it: a cell's model trained into the model store (or
taken from it) and driven on its runs, or runs of a policy that needs no training, or a training alone.

A study maps each of its cells' specs (JSON-ready dicts: their key, coordinates and configuration, which its record
keeps) to a frozen `Cell` in the worker (its `work`); `CellKind.run_cell` runs it (`perform`) into the cell's record:
`Train` names the training (its configuration as data: the model store takes its digest at its edge), the folder of
the study that links to it and the drive settings the model is driven with (its policy string: dqn_policy, which
agents/dqn_policy.DQNPolicy.from_spec reads onto the loaded policy); each `Run` is one simulation (a typed SimConfig)
into its run folder, measured by the cell's `measure` (default: the run's own summary, run_folders.simulate_into;
scenario II adds its loop flow and full-road speed, the protocol its accident's measures). A pooled cell keeps each
run's summary with its evaluation seed and pools them (records.pool_summaries); any other keeps its one run's.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from coopsumo.config import SimConfig, to_dict
from coopsumo.policy_spec import DRIVES
from coopsumo.studies.engine.records import CellRecords, pool_summaries
from coopsumo.studies.engine.run_folders import simulate_into
from coopsumo.validation import number_name

Measure = Callable[[dict[str, Any], Path, str], dict[str, Any]]
"""one evaluation: (its SimConfig dict, whose policy names the model; its run folder; a label) -> its summary"""


def dqn_policy(model: Path | str, drive: Mapping[str, float] | None = None, alpha: float | None = None) -> str:
    """'dqn:MODEL[,margin=M][,noreturn=S][,restart=R][,queue=V][,alpha=A]': the model file MODEL driven with the
    drive settings `drive` gives (keyed as a cell's config.drive, policy_spec.DRIVES; a setting it does not give:
    the model's own) and, for an alpha-conditioned model, at alpha. Each number as validation.number_name writes it
    (:g when that reads back exactly), so the policy sets exactly these values."""
    drive = drive or {}
    extra = "".join(f",{field}={number_name(float(drive[key]))}" for field, key, _ in DRIVES if key in drive)
    if alpha is not None:
        extra += f",alpha={number_name(float(alpha))}"
    return f"dqn:{model}{extra}"


def cell_policy(spec: dict[str, Any], model: Path) -> str:
    """The policy string a study cell drives its trained model (the file `model`) with: the cell's drive settings
    (config.drive) and, when its training is alpha-conditioned (config.train.dqn.alpha_conditioned), the cell's
    alpha (dqn_policy; cell_train)."""
    train = cell_train(spec, "")
    return dqn_policy(model, train.drive, train.alpha)


def cell_train(spec: dict[str, Any], folder: str, weights: str = "model.pt") -> Train:
    """The model of a study cell that trains (its config.train), linked at ROOT/<folder>, driven from its file
    `weights` with the cell's drive settings (config.drive) and, when it is alpha-conditioned, at the cell's alpha."""
    config = spec["config"]
    conditioned = bool(config["train"]["dqn"].get("alpha_conditioned"))
    return Train(config["train"], folder, weights=weights, drive=config.get("drive"),
                 alpha=float(spec["alpha"]) if conditioned else None)  # fmt: skip


def drive_pooled(record: dict[str, Any], evaluations: Iterable[tuple[SimConfig, Path]], label: str,
                 measure: Measure = simulate_into) -> None:  # fmt: skip
    """Drive each evaluation (its SimConfig, whose policy names the model, and its run folder, written in place) with
    `measure` (default: the run's own summary, run_folders.simulate_into); the record's eval_summaries keeps each
    summary with its eval_seed, its summary pools them without it (records.pool_summaries)."""
    summaries = [{**measure(to_dict(ev), out, label), "eval_seed": ev.seed} for ev, out in evaluations]
    record["eval_summaries"] = summaries
    record["summary"] = {k: v for k, v in pool_summaries(summaries).items() if k != "eval_seed"}


# -- a cell, typed, and the one function that runs it --------------------------------------------------------------
@dataclass(frozen=True)
class Train:
    """A cell's model: the training `config` (a TrainConfig as data) taken from the model store `store` (None: the
    study's own, model_store.store_for), trained there when it is not whole; ROOT/<folder> links to it. The cell drives
    its file `weights` with the drive settings `drive` (a cell's config.drive, keyed as policy_spec.DRIVES) and, for an
    alpha-conditioned model, at `alpha` (dqn_policy)."""

    config: dict[str, Any]
    folder: str
    store: str | None = None
    weights: str = "model.pt"
    drive: Mapping[str, float] | None = None
    alpha: float | None = None


@dataclass(frozen=True)
class Run:
    """One simulation of the cell into ROOT/<out>: its configuration, whose policy is the cell's model's when the cell
    has a Train."""

    config: SimConfig
    out: str


@dataclass(frozen=True)
class Cell:
    """What one cell does: train (or take) its model, then drive each run with `measure` (its SimConfig as a dict, its
    run folder, `label` -> its summary). pooled: the record keeps every run's summary (eval_summaries) and pools them;
    otherwise its summary is its one run's (a cell of a training alone: the training's summary)."""

    train: Train | None = None
    runs: tuple[Run, ...] = ()
    label: str = ""
    measure: Measure = simulate_into
    pooled: bool = False


TRAIN_FIELDS = ("train_summary", "resumed_from_step", "train_group_cpu_s")
"""what a record may keep of its cell's training, each filled when the study's record layout has it: the training's
summary, the step it resumed from (None: started afresh or stored whole) and its share of a group's CPU time"""


def perform(cell: Cell, root: Path, record: dict[str, Any]) -> None:
    """Run `cell` under the study's root, filling `record` (records.CellRecords.run catches what it raises)."""
    from coopsumo.studies.engine import model_store
    from coopsumo.studies.engine.groups import group_cpu_s

    runs = [(run.config, root / run.out) for run in cell.runs]
    if (train := cell.train) is not None:
        link = root / train.folder
        store = Path(train.store) if train.store is not None else model_store.store_for(root)
        summary, resumed = model_store.train_shared(train.config, link, store)
        known = {"train_summary": summary, "resumed_from_step": resumed}
        for key in TRAIN_FIELDS:
            if key in record:
                record[key] = known[key] if key in known else group_cpu_s(link)
        if not runs:
            record["summary"] = summary
            return
        policy = dqn_policy(link / train.weights, train.drive, train.alpha)
        runs = [(replace(config, policy=policy), out) for config, out in runs]
    if cell.pooled:
        drive_pooled(record, runs, cell.label, cell.measure)
    else:
        (config, out), = runs
        record["summary"] = cell.measure(json.loads(json.dumps(to_dict(config))), out, cell.label)


@dataclass(frozen=True)
class CellKind:
    """A study's cells: their record layout and the work of each (`work`: a spec -> its Cell). `run_cell` is the
    runner's cell function (runner.CellFn: in a worker process, never raises), `failed_record` its record of a cell
    that could not run."""

    records: CellRecords
    work: Callable[[dict[str, Any]], Cell] = field(repr=False)

    def run_cell(self, spec: dict[str, Any], root: str) -> dict[str, Any]:
        """Run the cell of `spec` under the study's root and return its record (never raises: CellRecords.run)."""
        return self.records.run(spec, lambda record: perform(self.work(spec), Path(root), record))

    def failed_record(self, spec: dict[str, Any], error: str) -> dict[str, Any]:
        return self.records.failed(spec, error)
