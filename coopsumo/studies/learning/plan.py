"""The learning study's plan: its learner variants, profiles, configurations and cells (studies/learning/study.py runs
them, studies/learning/report.py reports them)."""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any, get_type_hints

from coopsumo.agents.conditioning import world_alpha
from coopsumo.config import (
    MAX_LANES,
    MIN_LANES,
    ControlConfig,
    DemandConfig,
    RewardConfig,
    RoadConfig,
    SimConfig,
    TrainConfig,
    to_dict,
)
from coopsumo.dqn_config import DQNConfig
from coopsumo.errors import ConfigError, UsageError
from coopsumo.studies.engine.catalogue import DATA, LEARNERS, Entry, Learner, Rule, read_profiles, read_toml
from coopsumo.validation import (
    ALPHA_LIST,
    MAX_T_UP_S,
    SEED_LIST,
    integer,
    min_t_up_s,
    name_list,
    names_problem,
    number,
    number_name,
    steps,
    t_up_note,
)

EVAL_SEED_OFFSET = 1000
"""the evaluation seeds are EVAL_SEED_OFFSET + s for every training seed s of the profile (demands no training saw);
every model meets all of them"""
BASELINES = ("keep", "greedy", "mobil:p=0", "mobil:p=0.5")
METRICS = ("mean_speed_mps", "lane_changes_per_vehicle", "lane_changes_rejected", "teleports", "collisions",
           "throughput_veh_per_h", "mean_travel_time_s")  # fmt: skip
REQUIRED_SUMMARY = ("mean_speed_mps", "lane_changes_per_vehicle", "teleports", "collisions")
"""summary values a stored cell record must hold as finite numbers to be reused (records.record_problem)"""


LEARNING_FILE = DATA / "learning.toml"
"""the study's learners (names in the catalogue, learners.toml) and profiles, as data"""


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


def load_catalogue(path: Path = LEARNING_FILE, learners: dict[str, Learner] | None = None) -> tuple[
        list[tuple[str, str, DQNConfig]], int, dict[str, int], dict[str, Profile]]:  # fmt: skip
    """learning.toml's learners (its `chain`, then its other `variants`; the catalogue's, `learners`), in order, as
    (name, why, learner); how many form the chain; the learners trained longer (steps_factor); and the profiles.
    One ConfigError naming the file and the entry for an unknown field or learner, a learner named twice or one that
    drives otherwise than with model.pt and its own settings, or a profile a rule refuses."""
    learners = LEARNERS if learners is None else learners
    data = read_toml(path)
    at = Entry(path, "file")
    at.table(data, "the file", ("chain", "variants", "profiles", "default"))
    chain = at.names("chain", data.get("chain", []), tuple(learners), least=0)
    names = (*chain, *at.names("variants", data.get("variants", []), tuple(learners), least=0))
    if twice := next((n for n in names if names.count(n) > 1), None):
        raise at.error(f"learner {twice!r} is named twice (chain and variants name each learner once)")
    for name in names:
        if learners[name].weights != "model.pt" or learners[name].drive():
            raise at.error(f"learner {name!r} drives otherwise than with model.pt and its own settings; the learning "
                           "study drives a learner's model.pt as trained")  # fmt: skip
    variants = [(n, learners[n].text, learners[n].learner) for n in names]
    factors = {n: learners[n].steps_factor for n in names if learners[n].steps_factor != 1}
    built = {n: learners[n].learner for n in names}
    return variants, len(chain), factors, read_learning_profiles(path, built, factors)[0]


_DT_S = ControlConfig().dt_s
FIELD_RULES: dict[str, Rule] = {
    "train_steps": steps, "eval_steps": steps, "seeds": SEED_LIST, "alphas": ALPHA_LIST,
    "alpha_seeds": replace(SEED_LIST, least=0), "lanes": integer(MIN_LANES, MAX_LANES),
    "t_up_s": number(min_t_up_s(_DT_S), MAX_T_UP_S, note=t_up_note(_DT_S)),
}  # fmt: skip
"""the rule of each field of a profile: its flag's (--seeds N: seeds 0..N-1, up to 1,000; --alphas) or that of the
same quantity's flag elsewhere (--steps, --lanes, --t-up), so that a file takes no value a flag refuses"""


def read_learning_profiles(path: Path, built: dict[str, DQNConfig],
                           factors: dict[str, int]) -> tuple[dict[str, Profile], Any]:  # fmt: skip
    """The `[profiles.NAME]` tables of `path` (engine/catalogue.read_profiles; its chain and variants the study reads
    itself), naming the variants `built` (trained `factors` times longer), each checked: its fields' types and rules
    (FIELD_RULES; variants and alpha_variants as --variants: known, none twice), a training seed that is an
    evaluation seed, a training the learner or the simulation refuses. The profiles and the file's default (or
    None)."""
    profiles, _, default = read_profiles(path, SETTABLE, partial(_profile, built=built, factors=factors),
                                         default_needed=False, others=("chain", "variants"))  # fmt: skip
    return profiles, default


SETTABLE = tuple(k for k in get_type_hints(Profile) if k != "name")
"""what a profile of learning.toml may set (besides its `help`)"""


def _profile(at: Entry, name: str, settings: dict[str, Any], built: dict[str, DQNConfig],
             factors: dict[str, int]) -> Profile:  # fmt: skip
    hints = get_type_hints(Profile)
    try:
        profile = Profile(name, **{k: at.value(k, v, hints[k], FIELD_RULES.get(k)) for k, v in settings.items()})
    except TypeError as err:
        raise at.error(f"is not a whole profile ({err})") from None
    if unknown := [v for v in (*profile.variants, *profile.alpha_variants) if v not in built]:
        raise at.error(f"unknown variant {unknown[0]!r}")
    for key, least in (("variants", 1), ("alpha_variants", 0)):
        if problem := names_problem(getattr(profile, key), tuple(built), least):
            raise at.error(f"{key} {problem}")
    evaluation = {EVAL_SEED_OFFSET + s for s in profile.seeds}
    if shared := sorted(set((*profile.seeds, *profile.alpha_seeds)) & evaluation):
        raise at.error(f"seeds: training seed {shared[0]} is also an evaluation seed ({EVAL_SEED_OFFSET} + each "
                       "of seeds); a model is judged only on seeds it never trained on")  # fmt: skip
    try:
        for variant in dict.fromkeys((*profile.variants, *profile.alpha_variants)):
            n_steps = profile.train_steps * factors.get(variant, 1)
            train_config(profile, built[variant], 0.0, profile.seeds[0], n_steps).validate()
        eval_config(profile, "keep", EVAL_SEED_OFFSET + profile.seeds[0]).validate()
    except ConfigError as err:
        raise at.error(f"makes a run the simulation refuses: {err}") from None
    return profile


def own_profiles(path: Path) -> tuple[dict[str, Profile], str | None]:
    """The profiles of a file of one's own (`--profile PATH.toml[:NAME]`: `[profiles.NAME]` tables as in
    learning.toml, naming its variants; its `default` optional), checked as the packaged ones are, and its default
    or None. A file of one's own has no chain or variants of its own: the study's are learning.toml's."""
    if {"chain", "variants"} & set(read_toml(path)):
        raise ConfigError(f"{path}: a profile file of one's own names learning.toml's learners; it has no chain or "
                          "variants of its own (only [profiles.NAME] tables and a default)")  # fmt: skip
    return read_learning_profiles(path, {n: c for n, _, c in VARIANTS}, STEPS_FACTOR)


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
    read: dict[str, Any] = {"queue_below_mps": 0.0,
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


VARIANTS, CHAIN_LENGTH, STEPS_FACTOR, PROFILES = load_catalogue()
"""the study's variants (name, why, learner), in order; the first CHAIN_LENGTH form the chain paper -> ... ->
noreturn, the rest branch off its end; the variants trained STEPS_FACTOR times the profile's train_steps; and the
profiles (learning.toml)"""
VARIANT_NAMES = tuple(v[0] for v in VARIANTS)
