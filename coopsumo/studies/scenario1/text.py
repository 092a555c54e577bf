"""Scenario I's report in words: the definitions of its measures, where the deviations are listed, how the models
were trained and what the study cost (scenario1_report puts them in report.md)."""

from __future__ import annotations

import os
from pathlib import Path

from coopsumo.files import read_json
from coopsumo.studies.engine.groups import group_cpu_s
from coopsumo.studies.scenario1.measures import FIELD_DT_S, FIELD_DX_M, MIN_MODELS, N_BOOT, RECOVERY_MPS, SLOW_MPS
from coopsumo.studies.scenario1.plan import Plan

MODEL_DOC = "docs/model.md"
"""the one table of the project's deviations from the paper and its choices, in the source checkout"""


def deviations_text(root: Path) -> str:
    """The report's pointer to the deviations and choices: they are one table, in the checkout's docs/model.md,
    linked relative to the report when the report is inside that checkout."""
    from coopsumo.sim.network import checkout_root

    where = f"`{MODEL_DOC}` of the coopsumo source (section \"Deviations and choices\")"
    checkout = checkout_root()
    if checkout is not None and root.resolve().is_relative_to(checkout):
        target = os.path.relpath(checkout / MODEL_DOC, root.resolve())
        where = f"[{MODEL_DOC}]({target}#deviations-and-choices)"
    return (f"The paper's silences and this project's choices (simulator, Newell parameters, road, demand, accident, "
            f"measures, learner) are listed once, in {where}.")


DEFINITIONS = f"""- **Total time spent** (TTS, the headline): vehicle-hours on the road plus vehicle-hours waiting to
  enter, over the whole run. Vehicle k is due to enter at k T_up; it waits from then until it appears on the road. All
  policies meet the same due times, so a policy cannot look good by keeping vehicles off the road.
  **Delay**: TTS minus the time the distance driven would take at 85 km/h (the mean expected speed).
- **Discharge**: vehicles per hour past the first loops downstream of the bottleneck (1,400 m, all lanes), over
  the loop intervals inside the accident window (SUMO's E1 output).
- **System recovery**: seconds from the accident's start to the first 30 s bin from which, to the end of the run,
  the space-mean speed in the 200 m before the bottleneck is above {RECOVERY_MPS:g} m/s AND at most one vehicle
  per lane waits to enter. "never" when that does not happen; in paired differences a "never" counts as the
  run's end (a lower bound). **On-road recovery** is the speed condition alone (the earlier studies' measure).
- **Stop-and-go waves** (moving jams): the space-mean speed field over all lanes from the entrance to the
  bottleneck, in cells of {FIELD_DX_M:g} m x {FIELD_DT_S:g} s; its connected regions (8-neighbours) below
  {SLOW_MPS:g} m/s lasting at least 20 s are slow regions (after Ji et al. 2024, arXiv 2409.00326, who identify
  waves as regions of the speed field below a critical speed of 10-20 mph). A region is a wave when its
  downstream front travels at least 100 m upstream, at a least-squares speed of -5 km/h or faster: a moving
  jam, whose front propagates upstream, where a bottleneck queue's front stays at the bottleneck (Kerner and
  Rehborn 1996). A wave that touches the standing queue merges with it and is not counted. Tests show the
  measure on known cases: hand-made waves (counted, with their speed), steady congestion and free flow (quiet),
  and a real SUMO disturbance (counted, moving upstream; no wave without it).
- **Queue reach**: the largest distance from the bottleneck to the furthest-upstream vehicle slower than
  {SLOW_MPS:g} m/s after the accident's start. **Regime**: "on the road" if at most one vehicle per lane ever
  waits to enter; "reaches the entrance, clears" if more do but not at the end; else "still waiting at the end".
- **Lane changes in a queue**: lane changes per vehicle made below {SLOW_MPS:g} m/s (a vehicle's lane differs from
  its previous trajectory sample's while it moves that slowly): a change takes 4 s across both lanes, so one made
  where the traffic stands holds up two queues.
- **Verdicts**: the trained model is the unit of replication. Differences (cooperative minus non-cooperative) are
  paired on evaluation seeds, and models of two alphas on their training seed; the 95% interval is a two-level
  percentile bootstrap ({N_BOOT:,} resamples) that draws models, then evaluation seeds within each drawn model, so
  it includes the spread between models (one level, over seeds, when neither policy is learned). "Helps" or
  "hurts" only when the interval of the TTS difference excludes 0, and only with at least {MIN_MODELS} models;
  otherwise "cannot decide", with about how many models (or seeds) the measured spread would need. Beside each
  interval: for how many models the difference has the verdict's sign."""


def training_text(plan: Plan) -> str:
    """How the models were trained: each learner preset's own training demand (a mix of demands, with accidents in
    a share of its episodes or none, or free flow at one demand), named per preset when the plan has several."""
    from coopsumo.studies.scenario1.plan import learners

    def where(preset: str) -> str:
        dqn = learners()[preset]
        if not dqn.train_t_ups:
            return f"free flow at T_up = {plan.train_t_up_s:g} s"
        accidents = f"{dqn.accident_share:.0%} of them with an accident" if dqn.accident_share else "no accident"
        t_ups = ", ".join(f"{t:g}" for t in dqn.train_t_ups)
        return f"episodes of {dqn.episode_steps:,} steps at T_up drawn from {t_ups} s, {accidents}"

    if len(plan.presets) == 1:
        return f"trained {plan.train_steps:,} steps ({where(plan.presets[0])})"
    return f"trained {plan.train_steps:,} steps (" + "; ".join(f"`{p}`: {where(p)}" for p in plan.presets) + ")"


def _training_seconds(summary: Path) -> float:
    """A training's compute: its share of its group's CPU seconds (engine/groups.py), else its wall seconds (a lone
    training keeps about one core busy)."""
    share = group_cpu_s(summary.parent)
    return share if share is not None else float(read_json(summary).get("wall_seconds", 0.0))


def timing_note(wall_s: float, models_reused: int, models: int, runs_reused: int, runs: int,
                train_files: list[Path], run_cpu: dict[float, list[float]], workers: int = 2) -> str:  # fmt: skip
    """Wall time of this invocation, what it reused, the compute its parts recorded (trainings: wall time of each, or
    for a model trained in a group its share of the group's CPU time; runs: CPU time per demand, which does not grow
    when the machine is shared) and the from-scratch estimate: all of it spread over `workers` cores."""
    train_s = [_training_seconds(f) for f in train_files if f.exists()]
    per = {t: sum(v) for t, v in run_cpu.items()}
    text = f"Wall time of this invocation: {wall_s / 60:.1f} min"
    if models_reused or runs_reused:
        text += f" (reused {models_reused} of {models} models and {runs_reused} of {runs} runs)"
    train_text = f"{min(train_s) / 60:.1f}-{max(train_s) / 60:.1f} min each" if train_s else "none recorded"
    text += (f". Compute recorded by the parts: {len(train_s)} trainings, {train_text}; accident runs "
             f"{sum(per.values()) / 60:.1f} core-min of CPU time in all, per demand: "
             + ", ".join(f"T_up {t:g} s {s / 60:.1f} core-min ({s / max(len(run_cpu[t]), 1):.0f} s per run)"
                         for t, s in per.items()) + ".")  # fmt: skip
    total = (sum(train_s) + sum(per.values())) / 60
    text += (f" From scratch on {workers} cores, the parts add up to about {total / workers:.0f} min ({total:.0f} "
             "core-min), before the report's figures.")
    return text

