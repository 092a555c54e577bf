"""A study's cells: what each does, typed, the one function that does it, and all of them through the shared runner
(coopsumo.studies.engine.runner) in one call, with the options that choose where.

run_todo runs a study's cells still to run: it builds the road networks once in this process (not in every worker),
trains the stacked learner's models as groups, runs the cells on local processes or Ray (runner.execute, one progress
bar, SIGTERM stops the workers) and returns every cell's record as the study may count it (records.checked_record).
The protocol, scenario II, scenario I (its trainings and accident runs) and scenario I's accident runs alone (the
regime map) are each a `Study` whose run does the steps of a study from its cells to
its record (their reuse checks and cell order the study's fields).

What a cell does: its model trained into the model store (or
taken from it) and driven on its runs, or runs of a policy that needs no training, or a training alone.

A study maps each of its cells' specs (dicts: their key, coordinates and configuration as data, which its record keeps;
a cell that trains also its TrainConfig as the plan typed it, `training`) to a frozen `Cell` in the worker (its `work`);
`CellKind.run_cell` runs it (`perform`) into the cell's record: `Train` names the training (typed, as the plan made it:
the model store takes its digest at its edge), the folder of the study that links to it and the drive settings the model
is driven with (its policy string: dqn_policy, which agents/dqn_policy.DQNPolicy.from_spec reads onto the loaded
policy); each `Run` is one simulation (a typed SimConfig) into its run folder, measured by the cell's `measure`
(default: the run's own summary, run_folders.simulate_into; scenario II adds its loop flow and full-road speed, the
protocol its accident's measures). A pooled cell keeps each run's summary with its evaluation seed and pools them
(records.pool_summaries); any other keeps its one run's.
"""

from __future__ import annotations

import errno
import os
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from coopsumo.config import RoadConfig, SimConfig, TrainConfig, as_data, to_dict
from coopsumo.files import read_json, read_json_object
from coopsumo.policy_spec import DRIVES
from coopsumo.studies.engine.records import (
    CellRecords,
    cell_path,
    checked_record,
    copied_wrong,
    folder_problem,
    pool_summaries,
    read_record,
    reusable_keys,
)
from coopsumo.studies.engine.run_folders import simulate_into
from coopsumo.studies.engine.runner import (
    CellFn,
    FailedRecord,
    execute,
    make_backend,
    sigterm_interrupts,
)
from coopsumo.validation import number_name

Check = Callable[[Path, Sequence[dict[str, Any]], str], set[str]]
"""a reuse check: (the study root, cells whose records are otherwise reusable, the command) -> the keys to rerun, each
with one line saying why"""


def drawn_logs(root: Path, specs: Sequence[dict[str, Any]], prog: str) -> set[str]:
    """trainings.spoiled_logs: the check of the study that draws its trainings' logs (the protocol)."""
    from coopsumo.studies.engine.trainings import spoiled_logs

    return spoiled_logs(root, specs, prog)


def todo_cells(root: Path, specs: Sequence[dict[str, Any]], prog: str, required: Sequence[str],
               checks: Sequence[Check] = (drawn_logs,),
               made: Callable[[dict[str, Any]], dict[str, Any]] | None = None) -> list[dict[str, Any]]:  # fmt: skip
    """The cells of `specs` the study root `root` has still to run, in their order: every cell but those whose record
    is reusable (records.reusable_keys, with the summary fields `required` and what `made` says a record holds),
    whose training's link still leads to its model (model_store.repointed_trainings) and that model is one a training
    would reuse (trainings.unusable_trainings), whose copy of its training's summary is its training's file
    (records.copied_wrong) and that the study's own `checks` pass (default drawn_logs); ROOT/cells is made first
    (UsageError naming `root` when it cannot be)."""
    from coopsumo.errors import UsageError
    from coopsumo.studies.engine.model_store import repointed_trainings
    from coopsumo.studies.engine.trainings import unusable_trainings

    try:
        (root / "cells").mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise UsageError(f"cannot write output folder {root}: {err.strerror}") from None
    done = reusable_keys(root, specs, prog, required, made)
    for check in (repointed_trainings, unusable_trainings, copied_wrong, *checks):  # linked elsewhere, deleted, ...
        done -= check(root, [s for s in specs if s["key"] in done], prog)
    return [s for s in specs if s["key"] not in done]


def _trains(spec: dict[str, Any]) -> bool:
    """Whether the cell of `spec` trains (or takes) a model and drives it (its typed training: spec["training"])."""
    return spec.get("training") is not None and spec.get("kind") != "train"


def model_link(root: Path, spec: dict[str, Any]) -> Path | None:
    """Where the cell of `spec` links the model it trains: a training cell's ROOT/<out> (scenario I's, kind "train"),
    a cell's that trains and drives ROOT/train/<training> (its train_key when cells share a training); None for a
    cell that trains none."""
    if _trains(spec):
        return root / "train" / (spec.get("train_key") or spec["key"])
    return root / spec["out"] if spec.get("kind") == "train" else None


def run_todo(todo: Sequence[dict[str, Any]], specs: Sequence[dict[str, Any]], root: Path, cell_fn: CellFn,
             failed_record: FailedRecord, *, required: Sequence[str], roads: Iterable[RoadConfig] = (),
             workers: int = 2, backend: str = "local", address: str | None = None, progress: bool = True,
             desc: str = "cells") -> list[dict[str, Any]]:  # fmt: skip
    """run_cells for a study that chose and ordered its cells to run itself (`todo`, in priority order, among all its
    `specs`; the others finished ok before): the same steps, every cell's record returned in the order of specs."""
    root = root.resolve()
    if any(_trains(s) for s in specs):
        say_store(root)
    if todo:
        from coopsumo.sim.network import build_net

        for road in dict.fromkeys(roads):
            build_net(road)
        if backend == "local":  # the stacked learner's trainings first, as groups (engine/groups.py)
            from coopsumo.studies.engine.groups import train_groups, training_configs
            from coopsumo.studies.engine.model_store import store_for

            if training_configs(todo):  # a study that trains none (the regime map) has no store to ask for
                train_groups(todo, store_for(root), quiet=not progress)
        runner = make_backend(backend, workers, address, cell_fn)
        try:
            with sigterm_interrupts():
                done_keys = sorted({s["key"] for s in specs} - {s["key"] for s in todo})
                execute(todo, root, runner, len(specs), len(done_keys), progress, failed_record, desc=desc,
                        done_keys=done_keys)  # fmt: skip
        finally:
            runner.close()
    return [checked_record(read_json(cell_path(root, s["key"])), required) for s in specs]


def say_store(root: Path) -> None:
    """One line on stderr naming the model store of a study that trains (its models' home, outside its folder)."""
    from coopsumo.studies.engine.model_store import store_for

    print(f"coopsumo: model store {store_for(root).resolve()} (the study's models; `coopsumo models` lists it)",
          file=sys.stderr)  # fmt: skip


def failed_keys(records: Sequence[dict[str, Any]]) -> list[str]:
    """The cells among `records` that did not end ok."""
    return [r["key"] for r in records if r.get("status") != "ok"]


# -- how a study drives a trained model, and a cell typed -------------------------------------------------------
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
    (config.drive) and, when its training is alpha-conditioned (its dqn.alpha_conditioned), the cell's
    alpha (dqn_policy; cell_train)."""
    train = cell_train(spec, "")
    return dqn_policy(model, train.drive, train.alpha)


def cell_train(spec: dict[str, Any], folder: str, weights: str = "model.pt") -> Train:
    """The model of a study cell that trains (its typed training, spec["training"], whose data is its config.train),
    linked at ROOT/<folder>, driven from its file `weights` with the cell's drive settings (config.drive) and, when it
    is alpha-conditioned, at the cell's alpha."""
    training: TrainConfig = spec["training"]
    alpha = float(spec["alpha"]) if training.dqn.alpha_conditioned else None
    return Train(training, folder, weights=weights, drive=spec["config"].get("drive"), alpha=alpha)


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
    """A cell's model: the training `config` taken from the model store `store` (None: the study's own,
    model_store.store_for), trained there when it is not whole (the store names it by its data, config.as_data, at
    its edge); ROOT/<folder> links to it. The cell drives its file `weights` with the drive settings `drive` (a cell's
    config.drive, keyed as policy_spec.DRIVES) and, for an alpha-conditioned model, at `alpha` (dqn_policy)."""

    config: TrainConfig
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
        record["summary"] = cell.measure(as_data(config), out, cell.label)


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

    def unlike_runs(self, root: Path, specs: Sequence[dict[str, Any]], prog: str) -> set[str]:
        """The cells of `specs` (records otherwise reusable) whose record keeps a run's summary other than the
        summary.json its run folder still holds (records.folder_problem; a folder gone is not judged): each is rerun,
        with one line naming the record, the value and the file (issue 82, probe 14, F1: a mean speed of 25 m/s
        beside its run folder's 19.57 was reused)."""
        keys = set()
        for spec in specs:
            path = cell_path(root, spec["key"])
            record, cell = read_json_object(path), self.work(spec)
            if record is not None and (problem := folder_problem(record, [root / run.out for run in cell.runs])):
                print(f"{prog}: cell {spec['key']}: record {path} {problem}; rerunning it", file=sys.stderr)
                keys.add(spec["key"])
        return keys


@dataclass(frozen=True)
class Study:
    """What the engine needs of a study to run its cells and count them into its record: its name (records, lines),
    its cells' kind, the summary values a reusable record holds, the run folders of a cell to run (checked for a
    user's files before any cell runs; in_place: run folders written unmarked), the order of the cells to run (sorts
    them in place), the reuse checks beyond the engine's own (todo_cells) and what a reusable record holds beyond its
    configuration (`made`, records.reusable_keys)."""

    prog: str
    cells: CellKind
    required: Sequence[str]
    places: Callable[[Path, dict[str, Any]], Iterable[Path]]
    order: Callable[[list[dict[str, Any]]], None]
    in_place: bool = False
    checks: Sequence[Check] = (drawn_logs,)
    made: Callable[[dict[str, Any]], dict[str, Any]] | None = None

    def run(self, specs: Sequence[dict[str, Any]], root: Path, meta: dict[str, Any], profile: str,
            finish: Callable[[list[dict[str, Any]], dict[str, Any]], None], *, roads: Iterable[RoadConfig] = (),
            workers: int = 2, backend: str = "local", address: str | None = None, progress: bool = True,
            begin: Callable[[], None] | None = None) -> dict[str, Any]:  # fmt: skip
        """Run (or finish) the study of `specs` in root: a model's link where a user's folder or file is refused
        (model_store.check_link), the cells to run (todo_cells) checked and ordered, `begin()` called, the cells run,
        their records counted into `meta` (cells run, wall time, failed cells, core-seconds with the grouped
        trainings' shares), then `finish(records, meta)` writes the study's outputs and record; returns meta."""
        from time import perf_counter

        from coopsumo.studies.engine.groups import study_cpu_s
        from coopsumo.studies.engine.model_store import check_link
        from coopsumo.studies.engine.run_folders import check_run_places

        start = perf_counter()
        root = root.resolve()
        links = [link for spec in specs if (link := model_link(root, spec)) is not None]
        for link in links:  # a real folder or file where a model's link belongs is the user's: refused first
            check_link(link)
        todo = todo_cells(root, specs, self.prog, self.required, self.checks, self.made)
        folder = os.stat(root).st_ino  # the study's folder, made by todo_cells: the one its outputs go to
        check_run_places((place for s in todo for place in self.places(root, s)), in_place=self.in_place)
        retry = [s for s in todo if (read_record(root, s) or {}).get("status") == "failed"]
        self.order(todo)
        if begin is not None:
            begin()
        print(f"{self.prog}: profile {profile}: {len(specs)} cells, {len(specs) - len(todo)} already done, "
              f"{len(retry)} failed before (retried), {len(todo)} to run on the {backend} backend",
              file=sys.stderr)  # fmt: skip
        records = run_todo(todo, specs, root, self.cells.run_cell, self.cells.records.failed, required=self.required,
                           roads=roads, workers=workers, backend=backend, address=address, progress=progress,
                           desc=f"{self.prog} cells")  # fmt: skip
        meta.update(cells_run=len(todo), wall_seconds=round(perf_counter() - start, 1),
                    failed_cells=failed_keys(records),
                    cell_cpu_seconds_sum=study_cpu_s(records, links))
        if not root.is_dir() or os.stat(root).st_ino != folder:  # issue 82, probe 19, O3: moved while the cells ran
            raise OSError(errno.ESTALE, "the study's folder was moved or deleted while its cells ran (its cells are "
                          "where it went): its tables and report are not written", str(root))  # fmt: skip
        finish(records, meta)
        return meta
