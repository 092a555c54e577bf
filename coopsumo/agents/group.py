"""A group of trainings of one learner whose gradient updates run together (issue 77): one update process serves
them all (agents/update_worker.serve_group, the stacked learner), each training in a process of its own with its
world, replay, random streams and model selection, writing its own folder exactly as a lone `train` would; a
model's bits do not depend on its group (tests/test_group.py). A member that fails fails alone: the others go on.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from coopsumo.config import TrainConfig
from coopsumo.errors import ConfigError, first_line
from coopsumo.runio import children_start_deaf


@dataclass(frozen=True)
class MemberResult:
    """How one member's training ended: its summary (train's return), or the one line of its error."""

    out: Path
    summary: dict[str, Any] | None
    error: str | None = None


def group_problem(cfgs: list[TrainConfig]) -> str | None:
    """Why these trainings cannot share an update process, or None: one learner (every DQNConfig setting equal; the
    seeds, alphas, demands and lane counts may differ), stacked_updates on."""
    if not cfgs:
        return "a group needs at least one training"
    first = cfgs[0].dqn
    if not first.stacked_updates:
        return "a group's trainings need stacked_updates (the stacked learner)"
    for i, cfg in enumerate(cfgs[1:], start=1):
        if cfg.dqn != first:
            return f"training {i} has another learner than training 0: a group shares one learner's settings"
    return None


def _member(cfg: TrainConfig, out: Path, ticket: Any, resume: bool, result: Connection) -> None:
    """A member's process: train (or resume) into out as a member of the group; send its MemberResult."""
    import torch

    from coopsumo.agents.train import train
    from coopsumo.runio import steady_streams, thread_lock_for_bars

    torch.set_num_threads(1)  # as a study's training: its decisions on one thread
    steady_streams()  # a closed or broken stderr: its bars write to nothing (issue 82, probe 16, T3)
    thread_lock_for_bars()
    try:
        outcome = MemberResult(out, train(cfg, out, resume=resume, progress=False, learner_process=True, group=ticket))
    except BaseException as err:  # its own failure, told in one line; the others go on
        outcome = MemberResult(out, None, f"{type(err).__name__}: {first_line(err)}")
    tell(result, outcome)


def tell(result: Connection, outcome: MemberResult) -> None:
    """Send a member's outcome to the group's process and close the pipe; nothing when that process has gone (a
    Ctrl-C stopped it, and the member's traceback of a broken pipe was the one more line, 2026-12-03)."""
    try:
        result.send(outcome)
    except OSError:  # no one is left to tell
        pass
    finally:
        result.close()


def train_group(cfgs: list[TrainConfig], outs: list[Path], resume: bool | Sequence[bool] = False) -> list[MemberResult]:
    """Train cfgs[i] into outs[i] as one group (ConfigError when group_problem finds one), resuming member i's
    checkpoint where resume (or resume[i]) is true; returns each member's result in order. A member's process that
    dies without a word is reported by its exit code."""
    resumes = [resume] * len(cfgs) if isinstance(resume, bool) else list(resume)
    if problem := group_problem(cfgs):
        raise ConfigError(problem)
    from coopsumo.agents.update_worker import start_group

    updates, tickets = start_group(cfgs[0].dqn, len(cfgs))
    ctx = multiprocessing.get_context("spawn")
    members = []
    for cfg, out, ticket, again in zip(cfgs, outs, tickets, resumes, strict=True):
        mine, theirs = ctx.Pipe(duplex=False)
        process = ctx.Process(target=_member, args=(cfg, out, ticket, again, theirs), name="coopsumo-member")
        with children_start_deaf():  # a Ctrl-C is this process's: it stops the members (SIGTERM: their checkpoints)
            process.start()
        theirs.close()
        ticket.conn.close()  # the member holds its end now: the update process sees it leave
        members.append((process, mine, out))
    results = []
    try:
        for process, mine, out in members:
            try:
                results.append(mine.recv())
            except EOFError:
                process.join()
                results.append(MemberResult(out, None, f"its process ended without a result (exit {process.exitcode})"))
            process.join()
    finally:
        for process, mine, _ in members:
            if process.is_alive():
                process.terminate()
                process.join()
            mine.close()
        updates.join(timeout=10)
        if updates.is_alive():
            updates.kill()
            updates.join()
    return results
