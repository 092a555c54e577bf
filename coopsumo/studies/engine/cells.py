"""A study's cells through the shared runner (coopsumo.studies.engine.runner) in one call, and the options that
choose where.

run_cells reuses every cell whose stored record can be trusted (records.reusable_keys), builds the road networks once
in this process (not in every worker), runs the other cells on local processes or Ray (runner.execute, one progress
bar, SIGTERM stops the workers) and returns every cell's record as the study may count it (records.checked_record).
The studies that only drive or measure (regime_map, accident_seeds) call it instead of
repeating those steps; the learning study, the protocol and scenario II, which choose and order their own cells,
call run_todo.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from coopsumo.config import RoadConfig
from coopsumo.files import read_json
from coopsumo.runio import Parser
from coopsumo.studies.engine.records import cell_path, checked_record, copied_wrong, reusable_keys
from coopsumo.studies.engine.runner import (
    CellFn,
    FailedRecord,
    add_backend_flags,
    execute,
    make_backend,
    sigterm_interrupts,
)
from coopsumo.validation import workers as workers_flag


def add_cell_flags(parser: Parser) -> None:
    """--workers, --backend, --address and --quiet, as every study has them."""
    parser.add_argument("--workers", type=workers_flag, default=2, help="parallel processes")
    add_backend_flags(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run_cells(specs: Sequence[dict[str, Any]], root: Path, cell_fn: CellFn, failed_record: FailedRecord, *,
              prog: str, required: Sequence[str], roads: Iterable[RoadConfig] = (), workers: int = 2,
              backend: str = "local", address: str | None = None, progress: bool = True,
              desc: str = "cells") -> list[dict[str, Any]]:  # fmt: skip
    """Run the cells of `specs` not finished in root (their records in ROOT/cells/) and return every cell's record,
    in the order of specs; a record whose status is not "ok" names a cell that failed.

    required: the summary values a stored record must hold as finite numbers to be reused; roads: the networks the
    cells drive on, built here before any worker starts.
    """
    root = root.resolve()
    done = reusable_keys(root, specs, prog, required)
    todo = [s for s in specs if s["key"] not in done]
    return run_todo(todo, specs, root, cell_fn, failed_record, required=required, roads=roads, workers=workers,
                    backend=backend, address=address, progress=progress, desc=desc)


def todo_cells(root: Path, specs: Sequence[dict[str, Any]], prog: str, required: Sequence[str]) -> list[dict[str, Any]]:
    """The cells of `specs` the study root `root` has still to run, in their order: every cell but those whose record
    is reusable (records.reusable_keys, with the summary fields `required`), whose training's link still leads to its
    model (model_store.repointed_trainings) and that model is one a training would reuse
    (trainings.unusable_trainings), whose copy of its training's summary is its training's file
    (records.copied_wrong) and whose training's logs read back (spoiled_logs: the studies that draw them, learning
    and protocol); ROOT/cells is made first (UsageError naming `root` when it cannot be)."""
    from coopsumo.errors import UsageError
    from coopsumo.studies.engine.model_store import repointed_trainings
    from coopsumo.studies.engine.trainings import spoiled_logs, unusable_trainings

    try:
        (root / "cells").mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise UsageError(f"cannot write output folder {root}: {err.strerror}") from None
    done = reusable_keys(root, specs, prog, required)
    done -= repointed_trainings(root, [s for s in specs if s["key"] in done], prog)  # linked elsewhere
    done -= unusable_trainings(root, [s for s in specs if s["key"] in done], prog)  # its model deleted, swapped
    done -= copied_wrong(root, [s for s in specs if s["key"] in done], prog)  # not its training's summary (J10)
    done -= spoiled_logs(root, [s for s in specs if s["key"] in done], prog)  # its figures and diagnosis draw them
    return [s for s in specs if s["key"] not in done]


def run_todo(todo: Sequence[dict[str, Any]], specs: Sequence[dict[str, Any]], root: Path, cell_fn: CellFn,
             failed_record: FailedRecord, *, required: Sequence[str], roads: Iterable[RoadConfig] = (),
             workers: int = 2, backend: str = "local", address: str | None = None, progress: bool = True,
             desc: str = "cells") -> list[dict[str, Any]]:  # fmt: skip
    """run_cells for a study that chose and ordered its cells to run itself (`todo`, in priority order, among all its
    `specs`; the others finished ok before): the same steps, every cell's record returned in the order of specs."""
    root = root.resolve()
    if any(isinstance(s.get("config"), dict) and "train" in s["config"] for s in specs):
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
