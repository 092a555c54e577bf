"""The learning study's plan: its learner variants, profiles, configurations and cells (studies/learning/study.py runs
them, studies/learning/report.py reports them)."""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from typing import Any

from coopsumo.agents.conditioning import CONDITIONED8V, world_alpha
from coopsumo.config import DemandConfig, RewardConfig, RoadConfig, SimConfig, TrainConfig, to_dict
from coopsumo.dqn_config import PAPER_DQN, DQNConfig
from coopsumo.errors import UsageError
from coopsumo.validation import name_list, number_name

EVAL_SEED_OFFSET = 1000
"""the evaluation seeds are EVAL_SEED_OFFSET + s for every training seed s of the profile (demands no training saw);
every model meets all of them"""
BASELINES = ("keep", "greedy", "mobil:p=0", "mobil:p=0.5")
METRICS = ("mean_speed_mps", "lane_changes_per_vehicle", "lane_changes_rejected", "teleports", "collisions",
           "throughput_veh_per_h", "mean_travel_time_s")  # fmt: skip
REQUIRED_SUMMARY = ("mean_speed_mps", "lane_changes_per_vehicle", "teleports", "collisions")
"""summary values a stored cell record must hold as finite numbers to be reused (records.record_problem)"""


def _variants() -> list[tuple[str, str, DQNConfig]]:
    """(name, what it adds, learner): a chain from the paper's learner to the default design, each
    variant the previous one plus one change, then single changes on top of the default."""
    chain: list[tuple[str, str, dict[str, Any]]] = [
        ("paper", "the paper-literal learner (--preset paper)", {}),
        ("interval", "+ a decision every 10 steps (1 s), rewards summed over it", {"decision_interval_steps": 10}),
        ("mask", "+ feasible-action masking (choice, exploration, target max)", {"action_mask": True}),
        ("double_huber", "+ double DQN target and Huber loss", {"double_dqn": True, "loss": "huber"}),
        ("adam", "+ Adam at lr 1e-3 instead of SGD at 0.01", {"optimizer": "adam", "lr": 1e-3}),
        ("replay", "+ replay 20,000 and 2 updates every decision round (not 1 every 4)",
         {"replay_size": 20_000, "learn_every": 1, "updates_per_learn": 2}),
        ("dueling", "+ a dueling Q head (V + A - mean A)", {"dueling": True}),
        ("restart", "+ 'none' withheld below 1 m/s (a standing vehicle must speed up)", {"restart_below_mps": 1.0}),
        ("margin", "+ driven with a change margin of 1: a lane change only when its Q-value beats staying by more "
         "than 1 (the `restart` models: training ignores the margin)", {"change_margin": 1.0}),
        ("select", "+ model.pt chosen on held-out demand: validated greedily every 15,000 steps, the best kept",
         {"select_every_steps": 15_000}),
        ("v2x", "+ the v2x state: each side lane's nearest leader and follower within 200 m (gap, speed), the own "
         "speed, expected speed and lane-change flag", {"observation": "v2x"}),
        ("mix", "+ trained where it is used: episodes of 9,000 steps at a T_up drawn from 2, 1.5 and 1 s, half of "
         "them with an accident",
         {"train_t_ups": (2.0, 1.5, 1.0), "accident_share": 0.5, "episode_steps": 9000}),
        ("accval", "+ model.pt chosen through an accident too: each snapshot also driven 6,000 steps through an "
         "accident at T_up 2, 1.5 and 1 s (the `mix` trainings, judged again)",
         {"validation_accident_steps": 6000}),
        ("followers", "+ half the weight on the speed of the traffic behind in the reward (--followers-weight 0.5)",
         {"followers_weight": 0.5}),
        ("queue", "+ driven with no lane change below 5 m/s (the `followers` models: training ignores it)",
         {"queue_below_mps": 5.0}),
        ("target", "+ the target network synced every 2,000 steps instead of 500 (about 400 updates instead of 100)",
         {"target_sync_steps": 2000}),
        ("noreturn", "+ no change back for 10 s after a lane change, when model.pt is chosen and when it drives (the "
         "default preset)", {"no_return_s": 10.0}),
    ]  # fmt: skip
    extras: list[tuple[str, str, dict[str, Any]]] = [
        ("eps_decay", "`noreturn` + epsilon decaying linearly 1.0 -> 0.05 over the first 20% of training",
         {"epsilon_start": 1.0, "epsilon_end": 0.05, "epsilon_decay_steps": 18_000}),
        ("store_all", "`noreturn` + every transition of a decision round stored (not 16 at random)",
         {"store_per_decision": 1000}),
        ("margin2", "the `noreturn` trainings with a change margin of 2 instead of 1 (model.pt chosen and driven with "
         "it)", {"change_margin": 2.0}),
        ("conditioned", "`noreturn` with alpha an input: one alpha-conditioned model per seed (train "
         "--alpha-conditioned), driven at each alpha (dqn:PATH,alpha=A)", {"alpha_conditioned": True}),
        ("conditioned8", "`conditioned` trained on the paper's alphas up to 8 (the eight of 0-8 drawn and relabelled "
         "to, not all twelve up to 48; train --alpha-conditioned --alpha-draw-max 8)",
         {"alpha_conditioned": True, "alpha_draw_max": 8.0}),
        ("conditioned8v", "`conditioned8` with model.pt chosen at alphas 0, 1 and 8 (every validation run driven at "
         "each, the score their mean; train --validation-alphas 0,1,8), not at alpha 0 alone", CONDITIONED8V),
        ("conditioned8v_2x", "`conditioned8v` trained twice the study's steps: one network learns every alpha, each "
         "per-alpha model one (five of them cost five trainings)", CONDITIONED8V),
    ]  # fmt: skip
    out = []
    cfg = PAPER_DQN
    for name, text, change in chain:
        cfg = replace(cfg, **change)
        out.append((name, text, replace(cfg, preset="paper" if name == "paper" else "default")))
    for name, text, change in extras:
        out.append((name, text, replace(cfg, **change, preset="default")))
    return out


STEPS_FACTOR = {"conditioned8v_2x": 2}
"""variants trained this many times the profile's train_steps (the others: once)"""
CHAIN_LENGTH = 17
"""the first CHAIN_LENGTH variants form the chain paper -> ... -> noreturn; the rest branch off its end (noreturn: the
default preset)"""
VARIANTS = _variants()
VARIANT_NAMES = tuple(v[0] for v in VARIANTS)


@dataclass(frozen=True)
class Profile:
    """How big the study is."""

    name: str
    train_steps: int
    eval_steps: int
    seeds: tuple[int, ...]
    variants: tuple[str, ...]
    alphas: tuple[float, ...]
    alpha_variants: tuple[str, ...] = ()
    """variants whose alpha response is measured (none given: the default learner)"""
    alpha_seeds: tuple[int, ...] = ()
    """training seeds of the alpha response at alpha > 0 (none given: seeds)"""
    lanes: int = 3
    t_up_s: float = 1.0


FULL_VARIANTS = (*VARIANT_NAMES[:CHAIN_LENGTH], "margin2", "conditioned8v")
"""the full study: the chain, the default with a margin of 2, and the alpha-conditioned network (conditioned8v: level
with conditioned8 or ahead on every seed and alpha of results/learning_conditioned)"""
CONDITIONED_VARIANTS = ("noreturn", "conditioned8", "conditioned8v", "conditioned8v_2x")
"""the per-alpha models against the alpha-conditioned network's variants"""
RESPONSE_ALPHAS = (0.0, 0.25, 1.0, 2.0, 8.0)
"""the alphas of the alpha response and of the conditioned network's comparison"""
PROFILES = {
    "full": Profile("full", 90_000, 9000, (0, 1, 2), FULL_VARIANTS, RESPONSE_ALPHAS,
                    alpha_variants=("noreturn", "conditioned8v")),
    "quick": Profile("quick", 6000, 1500, (0, 1, 2), ("paper", "noreturn"), (0.0, 1.0)),
    "conditioned": Profile("conditioned", 90_000, 9000, (0, 1, 2), CONDITIONED_VARIANTS, RESPONSE_ALPHAS,
                           alpha_variants=CONDITIONED_VARIANTS),
    "tiny": Profile("tiny", 300, 200, (0, 1), ("paper", "interval", "v2x", "margin2"), (0.0, 1.0)),
}


def learner_of(variant: str) -> DQNConfig:
    for name, _, cfg in VARIANTS:
        if name == variant:
            return cfg
    raise UsageError(f"unknown variant {variant!r}; expected one of {', '.join(VARIANT_NAMES)}")


def train_steps(profile: Profile, variant: str) -> int:
    """How many steps `variant` trains for in `profile` (STEPS_FACTOR)."""
    return profile.train_steps * STEPS_FACTOR.get(variant, 1)


def train_config(profile: Profile, dqn: DQNConfig, alpha: float, seed: int, steps: int) -> TrainConfig:
    sim = SimConfig(road=RoadConfig(lanes=profile.lanes), demand=DemandConfig(t_up_s=profile.t_up_s),
                    reward=RewardConfig(alpha=alpha), steps=steps, seed=seed, policy="dqn")  # fmt: skip
    return TrainConfig(sim=sim, dqn=dqn, eval_steps=0)


def eval_config(profile: Profile, policy: str, seed: int) -> SimConfig:
    return SimConfig(road=RoadConfig(lanes=profile.lanes), demand=DemandConfig(t_up_s=profile.t_up_s),
                     steps=profile.eval_steps, seed=seed, policy=policy)  # fmt: skip


DRIVE_FIELDS = ("change_margin", "queue_below_mps", "no_return_s")
"""learner fields that only the driving and the choice of model.pt read (config.drive)"""


def as_trained(dqn: DQNConfig, steps: int) -> DQNConfig:
    """The learner as a study trains it for `steps` steps: as `coopsumo train` would, but a drive-time field at 0
    where the training never reads it (no model selection in that many steps, or a queue rule that validation leaves
    off), so that variants differing only there share one training. Where model selection drives with it, it stays:
    model.pt is the snapshot the variant's own validation chooses."""
    selects = 0 < dqn.select_every_steps < steps
    read: dict[str, Any] = {"queue_below_mps": dqn.queue_below_mps if selects and dqn.validation_queue else 0.0,
                            "change_margin": dqn.change_margin if selects else 0.0,
                            "no_return_s": dqn.no_return_s if selects else 0.0}  # fmt: skip
    return replace(dqn, **read)


def training_key(dqn: DQNConfig, variant: str, alpha: float, seed: int, steps: int) -> str:
    """The folder under train/ of the model that `variant` (learner dqn) drives at alpha on seed after `steps` of
    training. A variant differing from another only in drive-time fields that its training does not read
    (as_trained) drives that one's training."""
    trained = as_trained(dqn, steps)
    if dqn.alpha_conditioned:  # one training for every alpha
        return f"{variant}_seed{seed}"
    factor = STEPS_FACTOR.get(variant, 1)
    twin = next((n for n, _, c in VARIANTS if as_trained(c, steps) == trained and STEPS_FACTOR.get(n, 1) == factor),
                variant)  # fmt: skip
    return f"{twin}_alpha{number_name(alpha)}_seed{seed}"


def variant_list(flag: str, text: str) -> tuple[str, ...]:
    """The variant names of a comma-separated flag value; UsageError naming the flag unless all are known."""
    return name_list(flag, text, VARIANT_NAMES)


def eval_seeds(profile: Profile) -> tuple[int, ...]:
    """The evaluation seeds every model and baseline of the study meets: EVAL_SEED_OFFSET + each training seed."""
    return tuple(EVAL_SEED_OFFSET + s for s in profile.seeds)


def own_eval(config: dict[str, Any], seed: int) -> dict[str, Any]:
    """A training cell's evaluation on seed EVAL_SEED_OFFSET + its training seed (diagnose drives that one); a
    record written when each model met one evaluation holds it as config["eval"]."""
    if "eval" in config:
        return dict(config["eval"])
    return dict(next(e for e in config["evals"] if e["seed"] == EVAL_SEED_OFFSET + seed))


def cell_specs(profile: Profile, default: DQNConfig) -> list[dict[str, Any]]:
    """Every cell of the study: ablation trainings, alpha-response trainings, baselines."""
    specs: list[dict[str, Any]] = []
    seen: set[str] = set()

    def add_train(part: str, variant: str, dqn: DQNConfig, alpha: float, seed: int) -> None:
        key = f"{variant}_alpha{number_name(alpha)}_seed{seed}"
        if key in seen:
            return
        seen.add(key)
        # drive-time fields as_trained; a conditioned one draws its own alphas (conditioning.world_alpha)
        steps = train_steps(profile, variant)
        cfg = train_config(profile, as_trained(dqn, steps), world_alpha(dqn, alpha), seed, steps)
        cfg.validate()
        evals = [eval_config(profile, "dqn", e) for e in eval_seeds(profile)]
        if dqn.alpha_conditioned:
            evals = [replace(ev, reward=RewardConfig(alpha=alpha)) for ev in evals]
        config: dict[str, Any] = {"train": to_dict(cfg), "evals": [to_dict(ev) for ev in evals]}
        if drive := {f: getattr(dqn, f) for f in DRIVE_FIELDS if getattr(dqn, f)}:
            config["drive"] = drive
        specs.append({"key": key, "kind": "train", "part": part, "variant": variant, "alpha": alpha, "seed": seed,
                      "eval_seed": None, "policy": "dqn",
                      "train_key": training_key(dqn, variant, alpha, seed, steps),
                      "config": json.loads(json.dumps(config))})  # fmt: skip

    for variant in profile.variants:
        for seed in profile.seeds:
            add_train("ablation", variant, learner_of(variant), 0.0, seed)
    default_name = next((n for n, _, c in VARIANTS if c == default), "default")
    responders = [(v, learner_of(v)) for v in profile.alpha_variants] or [(default_name, default)]
    for variant, dqn in responders:
        for alpha in profile.alphas:
            for seed in profile.seeds if alpha == 0 else profile.alpha_seeds or profile.seeds:
                add_train("alpha", variant, dqn, alpha, seed)
    for policy in BASELINES:
        for seed in profile.seeds:
            ev = eval_config(profile, policy, EVAL_SEED_OFFSET + seed)
            specs.append({"key": f"{policy.replace(':', '_').replace('=', '')}_seed{seed}", "kind": "baseline",
                          "part": "baseline", "variant": policy, "alpha": None, "seed": seed,
                          "eval_seed": EVAL_SEED_OFFSET + seed, "policy": policy,
                          "config": json.loads(json.dumps({"eval": to_dict(ev)}))})  # fmt: skip
    return specs


