"""The learner's settings (DQNConfig) and its presets. Each setting has one home, its field: the default, the
docstring, and in the field's metadata (`setting`) its command-line flag and help, its limits or choices, and the
value a configuration stored before the field existed means. The flags of `coopsumo train`, the checks and the
reading of old configurations are generated from them."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from typing import Any

from coopsumo.errors import ConfigError
from coopsumo.field_rules import float_flag, int_flag, integer, number
from coopsumo.validation import (
    ALPHA_MAX,
    ALPHA_MIN,
    MAX_REPLAY,
    MAX_STEPS,
    MAX_T_UP_S,
    SEED_MAX,
    from_fields,
    limits_problem,
    number_problem,
    type_problem,
)

OBSERVATIONS = ("paper", "v2x")
"""what a learner can read (DQNConfig.observation)"""
NO_VALUE = object()
"""a setting's `before` when every stored configuration has the field"""


def setting(default: Any, flag: str | None = None, *, help: str = "", limits: tuple[Any, ...] | None = None,
            choices: tuple[str, ...] | None = None, before: Any = NO_VALUE) -> Any:
    """A learner field with its metadata: `flag` (None: not a flag of `coopsumo train`) and its `help`; `limits`
    (lowest, highest[, lowest excluded[, highest excluded]]) or `choices`; `before`, what a stored configuration
    without the field means (the field was added after it was written)."""
    low_open, high_open = (tuple(limits[2:]) + (False, False))[:2] if limits else (False, False)
    meta = {"flag": flag, "help": help, "choices": choices, "before": before,
            "limits": (limits[0], limits[1], low_open, high_open) if limits else None}  # fmt: skip
    return field(default=default, metadata=meta)


VALIDATION_SEED = 900_000
"""first seed of the model-selection runs (DQNConfig.validation_seed): far above every study's evaluation seeds"""
MIN_ACCIDENT_VALIDATION_STEPS = 600
"""shortest accident validation run (steps of 0.1 s): the accident holds from step 50, so a queue forms"""


@dataclass(frozen=True)
class DQNConfig:
    """The learner. Field defaults are the project's default design; PAPER_DQN holds the paper's values.

    A "decision round" is one step on which vehicles decide: every decision_interval_steps steps.
    """

    preset: str = "default"
    """name of the preset these values started from ('default' or 'paper'); flags may override fields"""
    decision_interval_steps: int = setting(10, "--decision-interval", limits=(1, 600),
        help="steps of 0.1 s between a vehicle's decisions (paper: 1); a lane change starts on the decision step, "
             "then the vehicle asks to speed up; rewards of the interval are summed into one transition")
    """steps of 0.1 s between two decisions of a vehicle (paper: 1, a decision every step)"""
    action_mask: bool = setting(True, "--action-mask",
        help="offer left/right only when the controller would accept them")
    """offer left/right only when the controller would accept them (choice, exploration, target max)"""
    double_dqn: bool = setting(True, "--double-dqn", help="double DQN target")
    """double DQN target: the online network picks the next action, the target network values it"""
    dueling: bool = setting(True, "--dueling", help="dueling Q head (value + advantages)")
    """dueling head: Q = V + A - mean(A) on top of Table II's FC 100 (paper: a plain 4-output layer)"""
    loss: str = setting("huber", "--loss", choices=("mse", "huber"), help="TD loss (paper: mse)")
    """'mse' (paper eq. 8) or 'huber' (smooth L1, delta 1)"""
    lr: float = setting(1e-3, "--lr", limits=(0.0, 1.0, True), help="learning rate")
    """learning rate (paper: 0.01)"""
    optimizer: str = setting("adam", "--optimizer", choices=("sgd", "adam"), help="optimizer (paper: sgd)")
    """'sgd' (paper: stochastic gradient descent) or 'adam'"""
    gamma: float = setting(0.9, "--gamma", limits=(0.0, 1.0, False, True),
        help="discount per decision round (paper: 0.9 per 0.1 s step)")
    """discount per decision round (paper: 0.9 per 0.1 s step)"""
    replay_size: int = setting(20_000, "--replay-size", limits=(1, MAX_REPLAY), help="replay memory (transitions)")
    """replay memory (transitions; paper: 2,000)"""
    batch_size: int = setting(64, "--batch-size", limits=(1, MAX_REPLAY), help="minibatch (transitions)")
    """minibatch size (transitions)"""
    learn_every: int = setting(1, "--learn-every", limits=(1, MAX_STEPS),
        help="decision rounds between learning phases")
    """decision rounds between two learning phases (paper setup: 4)"""
    updates_per_learn: int = setting(2, "--updates-per-decision", limits=(1, 1000),
        help="gradient updates per learning phase")
    """gradient updates in one learning phase (paper setup: 1)"""
    target_sync_steps: int = setting(2000, "--target-sync", limits=(1, MAX_STEPS),
        help="steps of 0.1 s between target-network syncs")
    """environment steps between target-network syncs (paper: 500). Default 2,000: the protocol
    (results/learner_protocol_f05q_ts2k10) measured it against 500"""
    epsilon_start: float = setting(0.1, "--epsilon-start", limits=(0.0, 1.0),
        help="exploration probability at the start")
    """exploration probability at the start (paper: 0.1, the greedy action with probability 0.9)"""
    epsilon_end: float = setting(0.1, "--epsilon-end", limits=(0.0, 1.0),
        help="exploration probability after the decay")
    """exploration probability after epsilon_decay_steps"""
    epsilon_decay_steps: int = setting(0, "--epsilon-decay-steps", limits=(0, MAX_STEPS),
        help="steps of the linear epsilon decay (0: constant)")
    """environment steps of the linear decay from epsilon_start to epsilon_end (0: constant epsilon_start)"""
    learn_start_steps: int = setting(200, limits=(0, MAX_STEPS))
    """no update before this many environment steps"""
    grad_clip_norm: float = setting(10.0, limits=(0.0, 1e6, True))
    """gradient-norm clip"""
    speed_scale_mps: float = setting(110.0 / 3.6, limits=(0.0, 1000.0, True))
    """speed errors are divided by this before entering the network (m/s)"""
    store_per_decision: int = setting(16, "--store-per-decision", limits=(1, MAX_REPLAY),
        help="transitions stored per decision round (random subset)")
    """at most this many vehicles' transitions are stored per decision round (random subset)"""
    restart_below_mps: float = setting(1.0, "--restart-below", limits=(0.0, 100.0),
        help="'none' is not offered below this speed (m/s; 0: off)")
    """'none' is not offered to a vehicle slower than this (m/s): a standing vehicle that keeps its speed
    would stand for good and block its lane (0: off; paper: 'none' keeps any speed, zero included)"""
    change_margin: float = setting(1.0, "--change-margin", limits=(0.0, 1e6), before=0.0,
        help="when the model drives, a lane change is chosen only when its Q-value beats staying by more than this"
             " (0: plain argmax); training ignores it, model selection drives the snapshots with it")
    """when the trained model drives (evaluation, simulate, studies), a lane change is chosen only when its Q-value
    beats the best of speed-up and none by more than this (Q units; 0: plain argmax, the paper's). Training ignores it:
    the same seed gives the same weights whatever the margin"""
    observation: str = setting("v2x", "--observation", choices=OBSERVATIONS, before='paper',
        help="what the network reads: 'paper' (3 x 20 m occupancy grids and speed errors) or 'v2x' (those plus "
             "each side lane's nearest leader and follower within 200 m: gap and speed)")
    """what the network reads: 'paper' (3 frames of the 3 x 20 m occupancy grid and the speed errors) or 'v2x'
    (those plus each side lane's nearest leader and follower within 200 m: gap and speed; see v2x_features).
    Default v2x: the learner protocol (results/learner_protocol_v2x*) measured it against the paper's state"""
    alpha_conditioned: bool = setting(False, "--alpha-conditioned", before=False,
        help="one network for every alpha: alpha is an input, drawn from the paper's 12 values for all vehicles "
             "every --alpha-period steps; drive it with --policy dqn:PATH,alpha=A (not with --alpha)")
    """one network for every alpha: alpha is an input (log(1 + alpha) beside the speed errors), training draws it
    from conditioned_alphas for all vehicles every alpha_period_steps; it drives at any alpha (not in the paper)"""
    alpha_period_steps: int = setting(3000, "--alpha-period", limits=(1, MAX_STEPS), before=3000,
        help="conditioned training: steps of 0.1 s between two alpha draws")
    """conditioned training: environment steps between two draws of the shared alpha (3,000 = 5 simulated minutes)"""
    alpha_relabel: float = setting(0.5, "--alpha-relabel", limits=(0.0, 1.0), before=0.5,
        help="conditioned training: share of each minibatch learned at another alpha (reward recomputed)")
    """conditioned training: share of each minibatch given another alpha of PAPER_ALPHAS, its reward recomputed from
    the stored lane changes (r = r_speed + r_flow - alpha x lane changes)"""
    alpha_draw_max: float = setting(48.0, "--alpha-draw-max", limits=(0.0, 1e6), before=48.0,
        help="conditioned training: draw and relabel only the paper's alphas up to this one (48: all twelve)")
    """conditioned training: the alphas drawn and relabelled to are those of PAPER_ALPHAS up to this one (48: all
    twelve, the paper's grid; 8: the eight up to scenario I's and II's largest, `conditioned8` of the learning study)"""
    select_every_steps: int = setting(15_000, "--select-every", limits=(0, MAX_STEPS), before=0,
        help="model selection: every this many steps (and at the last) validate the weights greedily on held-out "
             "free-flow demand; model.pt is the best, model_last.pt the last weights (0: model.pt is the last "
             "weights, the paper's)")
    """model selection: every this many training steps (and at the last) the weights are validated greedily on
    held-out demand and model.pt is the best of them (agents/selection.py); 0: model.pt is the last weights (paper)"""
    validation_seed: int = setting(
        VALIDATION_SEED, "--validation-seed", limits=(0, SEED_MAX - 10), before=VALIDATION_SEED,
        help="model selection: validation run i uses seed VALIDATION_SEED + i (must not meet the training seed)")
    """model selection: validation run i uses seed validation_seed + i (disjoint from training and study seeds)"""
    validation_t_ups: tuple[float, ...] = setting((2.0, 1.5, 1.0), "--validation-t-up", before=(2.0, 1.5, 1.0),
        help="model selection: comma-separated demands T_up (s), one run each")
    """model selection: the free-flow demands T_up (s) of the validation runs, one run each"""
    validation_steps: int = setting(3000, "--validation-steps", limits=(100, MAX_STEPS), before=3000,
        help="model selection: steps of 0.1 s of each validation run")
    """model selection: steps of 0.1 s of each validation run"""
    validation_accident_steps: int = setting(6000, "--validation-accident-steps", limits=(0, MAX_STEPS), before=0,
        help="model selection: also validate each demand through an accident, a run of this many steps (0: free "
             "flow only)")
    """model selection: when > 0, each validation demand also gets a run of this many steps through an accident (held
    from 1/12 of the run for 5/6 of it), so that a snapshot that thrashes in a queue is not chosen; 0: free flow only
    (default 6,000: measured against free flow only in results/learner_protocol_accval)"""
    validation_alphas: tuple[float, ...] = setting((), "--validation-alphas", before=(),
        help="model selection of a conditioned training: comma-separated alphas each validation run is driven at, "
             "the score their mean (empty: the training's alpha alone)")
    """model selection of an alpha-conditioned training: every validation run is driven at each of these alphas and
    the score is the mean over all; empty: at the training's own alpha (0 in the studies) alone"""
    validation_screen: int = setting(1, "--validation-screen", limits=(0, 10), before=0,
        help="model selection in two stages: every snapshot is first judged on the runs (free flow, and the "
             "accident when on) of the last N demands of --validation-t-up, the densest as listed; the "
             "--validation-finalists best then on every run (0, or N not fewer than the demands: every snapshot on "
             "every run)")
    """model selection in two stages (issue 77): every snapshot is first validated on the runs of the last N
    validation demands (validation_t_ups as listed, light to dense: the densest; the same runs, seeds included, as in
    the full validation), and only the validation_finalists best of them on every run, model.pt the best of those;
    0, or N not fewer than the validation demands: every snapshot on every run"""
    validation_finalists: int = setting(2, "--validation-finalists", limits=(1, 100), before=2,
        help="model selection with --validation-screen N: how many of the best screened snapshots run every "
             "validation run")
    """model selection in two stages: how many snapshots, best screened first, are validated on every run"""
    train_t_ups: tuple[float, ...] = setting((2.0, 1.5, 1.0), "--train-t-up", before=(),
        help="training demand: comma-separated T_up (s); each episode of --episode-steps draws one (empty: --t-up "
             "throughout)")
    """training demand: each episode's T_up (s) drawn from these (agents/episodes.py); empty: the run's own T_up
    (train --t-up T trains at T alone)"""
    accident_share: float = setting(0.5, "--accident-share", limits=(0.0, 1.0), before=0.0,
        help="training demand: share of episodes (0-1) with an accident whose position, start and length are drawn")
    """training demand: the share of episodes with an accident (position, start and length drawn)"""
    episode_steps: int = setting(9000, "--episode-steps", limits=(1000, MAX_STEPS), before=9000,
        help="training demand: steps of one episode (a fresh world each)")
    """training demand: steps of one episode when train_t_ups or accident_share is set (a fresh world each)"""
    stacked_updates: bool = setting(True, "--stacked-updates", before=False,
        help="the gradient updates by the stacked learner (agents/stacked.py), in an update process that serves a "
             "group of trainings at once (a lone training is a group of one): cheaper per model; other last bits")
    """the gradient updates by the stacked learner (issue 77; agents/stacked.py): the same loss, targets, clipping and
    Adam as torch's layers, computed as batched matrix products over a group's networks, in an update process that
    serves every training of a group (agents/update_worker.serve_group; a lone training is a group of one, and a
    model's bits do not depend on its group). Not the default's bits: weights agree within about 1e-6 after an
    update and part later, as after any change of arithmetic (docs/performance.md)"""
    followers_weight: float = setting(0.5, "--followers-weight", limits=(0.0, 100.0), before=0.0,
        help="reward shaping: add this times the mean speed reward of the vehicles behind within --followers-m in "
             "the lanes a vehicle occupies (0: the paper's reward)")
    """reward shaping for training (not in the paper): each step a vehicle's reward also gets this times the mean
    speed reward r_v of the vehicles behind it within followers_m in the lanes it occupies, so that slowing the
    traffic behind (a lane change into a queue, crawling) costs it; 0: the paper's reward. Model selection and
    every report score the paper's reward"""
    followers_m: float = setting(50.0, "--followers-m", limits=(0.0, 1000.0, True), before=50.0,
        help="reward shaping: the window behind a vehicle (m)")
    """reward shaping: the window behind a vehicle whose followers' speed reward it shares (m)"""
    queue_below_mps: float = setting(5.0, "--queue-below", limits=(0.0, 100.0), before=0.0,
        help="driving (not training): no lane change is chosen by a vehicle slower than this (m/s; 0: none)")
    """when the trained model drives (evaluation, simulate, studies), no lane change is chosen by a vehicle slower
    than this (m/s; 0: none, the paper's): a change takes 4 s across both lanes, so one made where the traffic
    stands holds up two queues. Training and model selection ignore it (measured so: learner_protocol_followers05;
    dqn:PATH,queue=V replaces it)"""
    no_return_s: float = setting(10.0, "--no-return", limits=(0.0, 600.0), before=0.0,
        help="driving and model selection (not training): for this many s after a lane change, the change back is "
             "not chosen (s; 0: none)")
    """when the trained model drives (and model selection, as it drives), for this many s after a vehicle's lane
    change the change back into the lane it left is not chosen (0: the paper's; dqn:PATH,noreturn=S replaces it)"""

    def validate(self) -> None:
        """Raise ConfigError naming the first bad value."""
        if problem := type_problem(self):  # read back from a file, a field may hold anything
            raise ConfigError(problem)
        for name, allowed in {**LEARNER_CHOICES, "preset": tuple(DQN_PRESETS)}.items():
            if getattr(self, name) not in allowed:
                raise ConfigError(f"{name} must be one of {', '.join(allowed)}, got {getattr(self, name)!r}")
        if problem := limits_problem(self, LEARNER_LIMITS):  # every number finite and bounded
            raise ConfigError(problem)
        if self.batch_size > self.replay_size:
            raise ConfigError(f"batch_size {self.batch_size} must be at most replay_size {self.replay_size} "
                              "(a larger batch never fills, so nothing would be learned)")  # fmt: skip
        if 0 < self.validation_accident_steps < MIN_ACCIDENT_VALIDATION_STEPS:
            raise ConfigError(f"validation_accident_steps must be 0 (none) or at least {MIN_ACCIDENT_VALIDATION_STEPS} "
                              f"(a queue needs time to form), got {self.validation_accident_steps}")  # fmt: skip
        for name, may_be_empty in (("validation_t_ups", False), ("train_t_ups", True)):
            ts = getattr(self, name)
            if not isinstance(ts, tuple) or (not ts and not may_be_empty) or len(ts) > 10 or len(set(ts)) != len(ts) \
                    or any(isinstance(t, bool) or not isinstance(t, (int, float)) or not 0.1 <= t <= MAX_T_UP_S
                           for t in ts):  # fmt: skip
                raise ConfigError(f"{name} must be {'0' if may_be_empty else '1'} to 10 distinct demands T_up from "
                                  f"0.1 to {MAX_T_UP_S:g} s, got {ts!r}")  # fmt: skip
        va = self.validation_alphas
        if not isinstance(va, tuple) or len(va) > 10 or len(set(va)) != len(va) or (va and not self.alpha_conditioned) \
                or any(number_problem(a, ALPHA_MIN, ALPHA_MAX) for a in va):  # fmt: skip
            raise ConfigError(f"validation_alphas must be up to 10 distinct alphas from {ALPHA_MIN:g} to "
                              f"{ALPHA_MAX:g}, and only for an alpha-conditioned learner, got {va!r}")  # fmt: skip


_FIELDS = dataclasses.fields(DQNConfig)
LEARNER_LIMITS: dict[str, tuple[Any, Any, bool, bool]] = {f.name: f.metadata["limits"] for f in _FIELDS
                                                          if f.metadata.get("limits")}  # fmt: skip
"""every number of the learner: (lowest, highest, lowest excluded, highest excluded), from its field"""
LEARNER_CHOICES: dict[str, tuple[str, ...]] = {f.name: f.metadata["choices"] for f in _FIELDS
                                               if f.metadata.get("choices")}  # fmt: skip
"""every word setting of the learner and its choices, from its field"""
ADDED_FIELDS: dict[str, Any] = {f.name: list(v) if isinstance(v := f.metadata["before"], tuple) else v
                                for f in _FIELDS if f.metadata.get("before", NO_VALUE) is not NO_VALUE}  # fmt: skip
"""fields added after results were stored, with the value (as JSON holds it) a configuration without them means
(config.results_view drops them at that value, so a stored run still matches the configuration it was made with)"""
RETIRED_FIELDS: dict[str, Any] = {"n_step": 1, "validation_queue": False, "weights_ema": 0.0, "exit_transition": "drop"}
"""learner settings tried and not adopted, retired (issue 80; their code runs at commit RETIRED_AT), with the one value
a stored configuration may still hold: it means what it meant (dropped when read, and by config.results_view, so a
stored model keeps its identity); any other value is refused in one line"""
RETIRED_AT = "eaffea4"
"""the last commit with the retired settings' code"""
IMPLIED_FIELDS: dict[str, Any] = {**ADDED_FIELDS, **RETIRED_FIELDS}
"""every field a stored configuration may hold or lack at its implied value (config.results_view drops it there)"""
FLAG_TYPES: dict[str, Any] = {"bool": bool, "int": int_flag, "float": float_flag}
"""a field's annotation -> its flag's type (any other, a tuple: a str flag holding a comma-separated list)"""


def _flag_type(f: dataclasses.Field[Any]) -> Any:
    """A learner flag's type: its choices; a number field with limits, the rule of its limits (field_rules.number,
    integer), which reads the text as given: '0.99999999999999999999' is over gamma's limit, not 1.0 rounded onto it
    (issue 82, probe 13, F16); else FLAG_TYPES' (an integer or float of ASCII digits, F15)."""
    limits, kind = f.metadata.get("limits"), str(f.type)
    if f.metadata["choices"] or not limits:
        return f.metadata["choices"] or FLAG_TYPES.get(kind, str)
    low, high, low_open, high_open = limits
    if kind == "float":
        return number(low, high, low_open, high_open)
    whole = isinstance(low, int) and isinstance(high, int | None) and not (low_open or high_open)
    return integer(low, high) if kind == "int" and whole else FLAG_TYPES.get(kind, str)


LEARNER_FLAGS: tuple[tuple[str, str, Any, str], ...] = tuple(
    (f.metadata["flag"], f.name, _flag_type(f), f.metadata["help"]) for f in _FIELDS if f.metadata.get("flag"))
"""(flag, field, type or choices, help) of every learner flag of `coopsumo train`; a tuple setting is a str flag
(a comma-separated list)"""


PAPER_DQN = DQNConfig(
    preset="paper", decision_interval_steps=1, action_mask=False, double_dqn=False, dueling=False, loss="mse",
    lr=0.01, optimizer="sgd", gamma=0.9, replay_size=2000, batch_size=64, learn_every=4, updates_per_learn=1,
    epsilon_start=0.1, epsilon_end=0.1, epsilon_decay_steps=0, restart_below_mps=0.0, change_margin=0.0,
    observation="paper", select_every_steps=0, validation_accident_steps=0, train_t_ups=(), accident_share=0.0,
    followers_weight=0.0, queue_below_mps=0.0, target_sync_steps=500, no_return_s=0.0, stacked_updates=False,
    validation_screen=0,
)  # fmt: skip
"""The paper-literal learner: a decision every 0.1 s step, no mask, SGD 0.01, gamma 0.9, replay 2,000,
constant epsilon 0.1 (batch 64, one update every 4 steps: the paper is silent, as before)"""

ALPHA_ONLY_DQN = DQNConfig(preset="alpha_only", followers_weight=0.0, queue_below_mps=0.0, no_return_s=0.0,
                           change_margin=0.0, accident_share=0.0, validation_accident_steps=0,
                           stacked_updates=False, validation_screen=0)
"""Claim (a) as the paper poses it: the default's machinery with alpha its only cooperative mechanism (no followers'
term, queue rule, change-back rule or change margin), trained and chosen in free flow at scenario I's demands"""

DQN_PRESETS: dict[str, DQNConfig] = {"default": DQNConfig(), "paper": PAPER_DQN, "alpha_only": ALPHA_ONLY_DQN}
"""name -> learner configuration"""



def validation_runs(dq: DQNConfig) -> int:
    """Validation runs per snapshot (seeds validation_seed + i): per demand, free flow and (when asked) an accident."""
    return len(dq.validation_t_ups) * (2 if dq.validation_accident_steps else 1)


def dqn_config_from_dict(d: dict[str, Any]) -> DQNConfig:
    """Inverse of to_dict for DQNConfig; a field it does not know is a ConfigError naming it.

    A dict written before presets existed (it has greedy_prob) describes the paper-literal learner.
    """
    d = dict(d)
    for name, only in RETIRED_FIELDS.items():  # retired: its one value means what it meant, another is refused
        if name in d and json.dumps(d.pop(name)) != json.dumps(only):
            raise ConfigError(f"learner setting {name} was retired (issue 80): only {json.dumps(only)} is read; "
                              f"such a learner trains at commit {RETIRED_AT}")  # fmt: skip
    if "greedy_prob" in d:  # written by a version before presets: the paper setup with its own values
        legacy = {"greedy_prob", "learn_every_steps", "store_per_step"}
        eps = 1.0 - float(d["greedy_prob"])
        base = dataclasses.replace(
            PAPER_DQN,
            epsilon_start=eps,
            epsilon_end=eps,
            learn_every=d.get("learn_every_steps", PAPER_DQN.learn_every),
            store_per_decision=d.get("store_per_step", PAPER_DQN.store_per_decision),
        )
        d = {k: v for k, v in d.items() if k not in legacy}
        return dataclasses.replace(base, **d)
    d.setdefault("dueling", False)  # written before the dueling head existed: the plain head
    d.setdefault("restart_below_mps", 0.0)  # written before the standing rule: 'none' offered at any speed
    for name, implied in ADDED_FIELDS.items():  # written before the field existed: what it meant then
        d.setdefault(name, implied)
    for name in ("validation_t_ups", "train_t_ups", "validation_alphas"):
        if isinstance(d[name], list):  # JSON has no tuples
            d[name] = tuple(d[name])
    return from_fields(DQNConfig, d, "learner")


