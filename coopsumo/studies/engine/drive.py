"""How a study drives a trained model: the dqn policy string of a model with its drive settings, and the model's
evaluations, each into its run folder, pooled into the cell's record.

The learning study and the protocol drive a cell's model with the cell's drive settings (its config.drive, keyed as
policy_spec.DRIVES: a change margin, a no-return window, a 'none' or queue speed) through its policy string
(cell_policy), which agents/dqn_policy.DQNPolicy.from_spec reads onto the loaded policy; scenario II and the learning
study drive a model on each of their evaluation seeds and pool the summaries (drive_pooled), scenario II measuring
each run further (its loop flow and full-road speed: the `measure` it passes).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

from coopsumo.config import SimConfig, to_dict
from coopsumo.policy_spec import DRIVES
from coopsumo.studies.engine.records import pool_summaries
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
    alpha (dqn_policy)."""
    config = spec["config"]
    conditioned = bool(config["train"]["dqn"].get("alpha_conditioned"))
    return dqn_policy(model, config.get("drive"), float(spec["alpha"]) if conditioned else None)


def drive_pooled(record: dict[str, Any], evaluations: Iterable[tuple[SimConfig, Path]], label: str,
                 measure: Measure = simulate_into) -> None:  # fmt: skip
    """Drive each evaluation (its SimConfig, whose policy names the model, and its run folder, written in place) with
    `measure` (default: the run's own summary, run_folders.simulate_into); the record's eval_summaries keeps each
    summary with its eval_seed, its summary pools them without it (records.pool_summaries)."""
    summaries = [{**measure(to_dict(ev), out, label), "eval_seed": ev.seed} for ev, out in evaluations]
    record["eval_summaries"] = summaries
    record["summary"] = {k: v for k, v in pool_summaries(summaries).items() if k != "eval_seed"}
