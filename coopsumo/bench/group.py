"""`coopsumo bench --learner`'s group line (issue 77): the CPU per trained model, training and model selection, of
a group of K trainings of issue 77's learner (stacked updates, agents/group.py, and the model selection in two
stages) against a lone training of the learner before it (`nr10`: its updates in an UpdateWorker, every snapshot on
every validation run). CPU time of every process involved (the trainings, their update processes, their
validations)."""

from __future__ import annotations

import tempfile
import time
from dataclasses import replace
from pathlib import Path

from coopsumo.config import TrainConfig
from coopsumo.studies.engine.groups import children_cpu_s


def _cpu_of(work: object) -> tuple[float, float]:
    """(CPU s of this process and its children, wall s) while work() runs."""
    cpu0, own0, start = children_cpu_s(), time.process_time(), time.perf_counter()
    work()  # type: ignore[operator]
    return children_cpu_s() - cpu0 + time.process_time() - own0, time.perf_counter() - start


def before_and_after(cfg: TrainConfig) -> tuple[TrainConfig, TrainConfig]:
    """cfg's learner as it was before issue 77 (no stacked updates, every snapshot on every validation run) and
    with issue 77's changes (stacked updates, screening on the densest validation demand, 2 finalists)."""
    before = replace(cfg, dqn=replace(cfg.dqn, stacked_updates=False, validation_screen=0))
    return before, replace(cfg, dqn=replace(cfg.dqn, stacked_updates=True, validation_screen=1, validation_finalists=2))


def bench_group(cfg: TrainConfig, k: int, lone: tuple[float, float] | None = None) -> dict[str, float]:
    """CPU s per model: a lone training of cfg's learner before issue 77 (updates in an UpdateWorker, on one torch
    thread as a study's training cell), and each of k trainings of it after (seeds cfg's + i) trained as one
    group; and their wall s. lone: the lone training's (CPU s, wall s) when already measured on cfg itself (bench's
    selection share trains cfg the same way), used only when cfg is the learner before, else it is trained here."""
    import torch

    from coopsumo.agents.group import train_group
    from coopsumo.agents.train import train

    torch.set_num_threads(1)  # as a study's training cell (engine/model_store.train_resuming) and a group's member

    before, after = before_and_after(cfg)
    cfgs = [replace(after, sim=replace(after.sim, seed=after.sim.seed + i)) for i in range(k)]
    with tempfile.TemporaryDirectory() as tmp:
        measured = lone if lone is not None and cfg == before else None
        lone_cpu, lone_wall = measured or _cpu_of(lambda: train(before, Path(tmp) / "lone", progress=False,
                                                                learner_process=True))  # fmt: skip
        outs = [Path(tmp) / f"member{i}" for i in range(k)]
        results: list[object] = []
        group_cpu, group_wall = _cpu_of(lambda: results.extend(train_group(cfgs, outs)))
    failed = [r for r in results if getattr(r, "error", None)]
    if failed:
        raise RuntimeError(f"a member of the benchmark's group failed: {getattr(failed[0], 'error', '')}")
    return {"lone_cpu_s": lone_cpu, "lone_wall_s": lone_wall, "group_cpu_s_per_model": group_cpu / k,
            "group_wall_s": group_wall, "k": k}  # fmt: skip


def group_lines(cfg: TrainConfig, k: int, lone: tuple[float, float] | None = None) -> list[str]:
    """The bench's lines for bench_group (lone: as there)."""
    m = bench_group(cfg, k, lone)
    steps = cfg.sim.steps
    return [f"  train (default, {steps:,} steps, selection scaled to it): lone, as before issue 77, "
            f"{m['lone_cpu_s']:.1f} CPU s ({m['lone_wall_s']:.1f} s wall); a group of {k} with stacked updates and "
            f"the two-stage selection {m['group_cpu_s_per_model']:.1f} CPU s per model ({m['group_wall_s']:.1f} s "
            f"wall for all {k})",
            f"group cost {m['group_cpu_s_per_model'] / m['lone_cpu_s']:.2f}  (CPU per trained model, training and "
            f"selection, in a group of {k} / a lone training of the learner before issue 77; target <= 0.55)"]
