"""A study's trainings of the stacked learner (DQNConfig.stacked_updates) trained as groups before its cells run
(issue 77): the trainings its cells will ask the model store for, not yet stored, with one learner's settings, in
groups of up to GROUP_SIZE, each group one update process and a process per training (agents/group.py). Each model
lands in its own store folder exactly as a lone training would put it there (a model's bits do not depend on its
group), so the cells then find it stored and only link and drive it; a training that fails here is left to its cell,
which trains it alone and records the failure as its own. Local backend only: on Ray every cell trains its own.
"""

from __future__ import annotations

import resource
import sys
from collections.abc import Iterable, Mapping, Sequence
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from coopsumo.config import TrainConfig, as_data
from coopsumo.dqn_config import DQNConfig
from coopsumo.files import read_json, write_json
from coopsumo.studies.engine.model_store import (
    GROUP_COST,
    _locked,
    model_id,
    reselectable,
    resumable_step,
    stored_model,
)

GROUP_SIZE = 4
"""trainings per group: the stacked learner's cost per model-update falls to about 0.46 of today's at 4 and no
further beyond (docs/performance.md, "The stacked learner"), while every member is a process of its own"""


def training_configs(specs: Sequence[dict[str, Any]]) -> list[TrainConfig]:
    """The trainings the cells of `specs` ask the model store for (each cell's typed `training`), each once."""
    found: dict[str, TrainConfig] = {}
    for spec in specs:
        if (training := spec.get("training")) is not None:
            found.setdefault(model_id(as_data(training)), training)
    return list(found.values())


def groups_to_train(specs: Sequence[dict[str, Any]], store: Path, size: int = GROUP_SIZE) -> list[list[TrainConfig]]:
    """The stacked trainings of specs not whole in the store (and not a stored training's snapshots judged again),
    grouped by learner settings into groups of up to `size`, in the cells' order; a lone one is no group."""
    by_learner: dict[DQNConfig, list[TrainConfig]] = {}  # one learner a group (agents/group.group_problem)
    for cfg in training_configs(specs):
        if not cfg.dqn.stacked_updates or cfg.eval_steps != 0:
            continue
        if stored_model(as_data(cfg), store) is not None or (store.is_dir() and reselectable(cfg, store) is not None):
            continue
        by_learner.setdefault(cfg.dqn, []).append(cfg)
    groups = [configs[i: i + size] for configs in by_learner.values() for i in range(0, len(configs), size)]
    return [g for g in groups if len(g) > 1]


def children_cpu_s() -> float:
    """CPU seconds (user and system) of this process's finished children and theirs."""
    used = resource.getrusage(resource.RUSAGE_CHILDREN)
    return used.ru_utime + used.ru_stime


MAX_GROUP_CPU_S = 7 * 86_400.0
"""the most CPU seconds a model's share of its group may record (a week): more is a damaged record"""


def group_cpu_s(folder: Path) -> float | None:
    """A stored model's share of its group's CPU seconds (GROUP_COST), or None when it was trained alone or its
    record is damaged (one line naming the file, and the cost is left out): not a JSON object with a group size of
    at least 1 and a share from 0 to MAX_GROUP_CPU_S, or a share above what the group's processes could spend in its
    training's wall time (train_summary.json's wall_seconds: K worlds and one update process, at most a core each,
    make at most 2 x the wall time a member; issue 82, probe 8, J11: 600,000 s for a training of 2 s was counted)."""
    path = folder / GROUP_COST
    if not path.is_file():
        return None
    try:
        record = read_json(path)
        cost, size = record["cpu_s"], record["group_size"]
    except (OSError, ValueError, KeyError, TypeError):
        cost = size = None
    number = isinstance(cost, (int, float)) and not isinstance(cost, bool)
    why = None if number and 0.0 <= cost <= MAX_GROUP_CPU_S else f"cpu_s must be a number from 0 to " \
        f"{MAX_GROUP_CPU_S:g} s"  # fmt: skip
    if why is None and not (isinstance(size, int) and not isinstance(size, bool) and size >= 1):
        why = f"group_size must be a whole number of models, got {size!r}"
    wall = _wall_seconds(folder)
    if why is None and wall is not None and cost > 2.0 * wall + WALL_SLACK_S:
        why = f"cpu_s {cost:g} is more than its group could spend in its training's {wall:g} s"
    if why is None:
        return float(cost)
    print(f"coopsumo: {path.resolve()} is damaged ({why}): its training's cost is left out", file=sys.stderr)
    return None


WALL_SLACK_S = 60.0
"""what a group member may spend beyond twice its training's wall time (its processes' start and end)"""


def _wall_seconds(folder: Path) -> float | None:
    """The training's wall time in its train_summary.json, or None when it cannot be read (its own check's)."""
    try:
        wall = read_json(folder / "train_summary.json").get("wall_seconds")
    except (OSError, ValueError, AttributeError):
        return None
    return float(wall) if isinstance(wall, (int, float)) and not isinstance(wall, bool) and wall >= 0 else None


def groups_cpu_s(folders: Iterable[Path]) -> float:
    """The CPU seconds of the models among `folders` (a study's training folders or links to the store) that were
    trained in groups, each model once: what a study's cells' own CPU time leaves out."""
    shares = [group_cpu_s(f) for f in dict.fromkeys(Path(f).resolve() for f in folders)]
    return sum(s for s in shares if s is not None)


def study_cpu_s(records: Iterable[Mapping[str, Any]], train_folders: Iterable[Path]) -> float:
    """A study's core-seconds (its record's cell_cpu_seconds_sum): its cells' own CPU time (`cell_cpu_s` of each
    record) and the share of every grouped training among `train_folders` (groups_cpu_s), to 0.1 s."""
    return round(sum(float(r.get("cell_cpu_s") or 0.0) for r in records) + groups_cpu_s(train_folders), 1)


def train_groups(specs: Sequence[dict[str, Any]], store: Path, size: int = GROUP_SIZE, quiet: bool = False) -> int:
    """Train groups_to_train's groups into the store, one group after another; returns the models trained. Each
    model's folder is locked while its group trains (a study asking for it at once waits, as for a lone training); a
    stored model trained again because it lost or spoiled a record is named in one line, quiet or not, as a lone
    training's (trainings.finished_training)."""
    from coopsumo.agents.group import train_group
    from coopsumo.owners import mark_store
    from coopsumo.studies.engine.trainings import finished_training

    groups = groups_to_train(specs, store, size)
    trained = 0
    for n, configs in enumerate(groups, start=1):
        store.mkdir(parents=True, exist_ok=True)
        data = [as_data(c) for c in configs]  # the store's names and checks
        folders = [store / model_id(c) for c in data]
        if not quiet:
            print(f"coopsumo: training group {n} of {len(groups)} ({len(configs)} models of the stacked learner, one "
                  f"update process) in the model store {store.resolve()}", file=sys.stderr)  # fmt: skip
        with ExitStack() as locks:
            for folder in sorted(folders):
                locks.enter_context(_locked(store / f".{folder.name}.lock"))
            mark_store(store)  # as it takes its first models (owners.STORE_MARK)
            for config, folder in zip(data, folders, strict=True):
                folder.mkdir(exist_ok=True)
                finished_training(folder, config)  # a stored model that lost or spoiled a record: a line naming it
            resumes = [resumable_step(c, f) is not None for c, f in zip(data, folders, strict=True)]
            before = children_cpu_s()
            results = train_group(configs, folders, resumes)
            share = (children_cpu_s() - before) / len(configs)
        for config, result, folder in zip(data, results, folders, strict=True):
            if result.error is None:
                trained += 1
                write_json(folder / GROUP_COST, {"group_size": len(configs), "cpu_s": round(share, 2)})
            elif not quiet:
                print(f"coopsumo: {model_id(config)} failed in its group ({result.error}); its cell trains it alone",
                      file=sys.stderr)  # fmt: skip
    return trained
