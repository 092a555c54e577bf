"""The learner protocol's plan: its learners, profiles and cells (studies/protocol/study.py runs them).

A variant is a training (its learner) plus which weights drive: `model.pt` (the validated best, when the learner
selects) or `model_last.pt` (the last weights). Every model meets every condition on the same evaluation seeds.
The variants and profiles are data (coopsumo/experiments_data/learners.toml and protocol.toml, inside the package so
that an installed wheel has them too); this module reads and checks them and makes the cells.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, fields, replace
from functools import partial
from itertools import product
from pathlib import Path, PurePath
from typing import Any, get_type_hints

from coopsumo.agents.conditioning import world_alpha
from coopsumo.agents.selection import LAST_MODEL, selecting
from coopsumo.config import (
    MAX_LANES,
    MIN_LANES,
    AccidentConfig,
    ControlConfig,
    DemandConfig,
    RewardConfig,
    RoadConfig,
    SimConfig,
    TrainConfig,
    as_data,
    to_dict,
)
from coopsumo.dqn_config import MIN_ACCIDENT_VALIDATION_STEPS, DQNConfig
from coopsumo.errors import ConfigError
from coopsumo.studies.engine.catalogue import (
    DATA,
    LEARNERS,
    LEARNERS_FILE,
    CommitRule,
    Entry,
    Learner,
    Rule,
    load_learners,
    read_profiles,
)
from coopsumo.studies.engine.model_store import FIRST_TRAIN_SEED, model_id
from coopsumo.validation import (
    ALPHA_MAX,
    ALPHA_MIN,
    MAX_SEEDS,
    SEED_LIST,
    SEED_MAX,
    ListRule,
    accident_problem,
    integer,
    names_problem,
    number_name,
    steps,
    t_up_rule,
)

EVAL_SEED = 5000
"""evaluation run of condition i uses seed EVAL_SEED + i (free flow) or EVAL_SEED + 100 + i (accident), each plus
one of the profile's eval_offsets"""
TRAIN_SEED = FIRST_TRAIN_SEED
"""first training seed of the protocol (the committed learning studies used 0-8)"""
BASELINES = ("keep", "greedy", "mobil:p=0")
DEMANDS = (2.0, 1.5, 1.0)
TRAJECTORY_EVERY = 5
"""accident runs record trajectories every 5 steps (0.5 s) for total time spent, as scenario I's do"""
QUEUE_MPS = 5.0
"""a lane change made below this speed (m/s) is made in a queue (scenario I's SLOW_MPS): the thrashing measure"""
REQUIRED = ("mean_speed_mps", "lane_changes_per_vehicle", "collisions", "teleports")
PROFILES_FILE = DATA / "protocol.toml"
Variant = Learner
"""a variant the protocol judges: a learner of the catalogue (engine/learners.py)"""


@dataclass(frozen=True)
class Profile:
    name: str
    variants: tuple[str, ...]
    seeds: tuple[int, ...] = tuple(range(TRAIN_SEED, TRAIN_SEED + 10))
    train_steps: int = 90_000
    t_ups: tuple[float, ...] = DEMANDS
    free_steps: int = 6000
    accident_steps: int = 20_000
    accident_start: int = 2000
    accident_duration: int = 10_000
    alpha_seeds: int = 3
    """models per alpha of `alphas` of each alpha variant (the first seeds', free flow only): does alpha do
    something?"""
    alphas: tuple[float, ...] = (8.0,)
    """the alphas besides 0 of the alpha response (each above 0)"""
    alpha_variants: tuple[str, ...] = ()
    """the variants whose alpha response is measured (empty: the judged one); an alpha-conditioned one trains once a
    seed and drives at each alpha"""
    lanes: int = 3
    eval_offsets: tuple[int, ...] = (0,)
    """each is added to every evaluation seed, one evaluation per offset (10: seeds 5010+i and 5110+i): every model
    and baseline meets each condition on len(eval_offsets) seeds, and the report judges each by its mean over them"""
    judged: str = ""
    """the variant whose targets and alpha response the report gives (empty: the first; the others are paired
    against the first)"""
    paired_with: tuple[tuple[str, str, str], ...] = ()
    """(a variant here, a committed protocol report's folder under results/ or results/history/, a variant there):
    the report pairs the two by training seed when that study ran the same seeds, demands and step counts with
    today's learner of that variant (protocol_report.committed_pair_lines), so that trainings made once need not be
    made again"""
    plan: str = ""
    """the commit of the analysis plan fixed before the profile's models ran (docs/studies.md), which the report
    quotes; empty: none (the report's reading is the protocol's own tables)"""

    def judged_variant(self) -> str:
        return self.judged or self.variants[0]


# -- the catalogue: learners.toml and protocol.toml -------------------------------------------------
SETTABLE = tuple(f.name for f in fields(Profile) if f.name != "name")
"""what a profile of protocol.toml may set (besides its `help`)"""
FIELD_RULES: dict[str, Rule] = {
    "seeds": SEED_LIST, "train_steps": steps, "t_ups": t_up_rule(ControlConfig().dt_s), "free_steps": steps,
    "accident_steps": steps, "accident_start": integer(0), "accident_duration": integer(1),
    "alpha_seeds": integer(0, MAX_SEEDS), "lanes": integer(MIN_LANES, MAX_LANES),
    "eval_offsets": ListRule(0, SEED_MAX, whole=True, most=MAX_SEEDS),
    "alphas": ListRule(ALPHA_MIN, ALPHA_MAX, low_open=True), "plan": CommitRule(),
}  # fmt: skip
"""the rule of each field of a profile: the flags' rules of the same quantities elsewhere (the studies' --seeds,
--steps, --t-up, --lanes; simulate's --accident-start and --accident-steps: profile_problem), so that a profile takes
no value a flag would refuse"""


def profile_problem(profile: Profile, known: dict[str, Variant]) -> str | None:
    """Why a profile breaks a rule between its fields, in words starting with the field at fault, or None: a variant
    named twice; the accident window outside its run (validation.accident_problem); more alpha seeds than seeds; an
    evaluation seed outside SUMO's range or one that is a training seed; a run the simulation or a learner refuses."""
    if problem := names_problem(profile.variants, tuple(known)):
        return f"variants {problem}"
    if problem := names_problem(profile.alpha_variants, profile.variants, least=0):
        return f"alpha_variants {problem} (the variants it runs)"
    if problem := accident_problem(profile.accident_start, profile.accident_duration, profile.accident_steps,
                                   "accident_start", "accident_duration"):  # fmt: skip
        return problem
    if profile.alpha_seeds > len(profile.seeds):
        return (f"alpha_seeds must be at most the number of seeds ({len(profile.seeds)}): its models are the first "
                f"seeds', got {profile.alpha_seeds}")  # fmt: skip
    evaluation = {EVAL_SEED + extra + offset + i for extra in (0, 100) for offset in profile.eval_offsets
                  for i in range(len(profile.t_ups))}  # fmt: skip
    if max(evaluation) > SEED_MAX:
        return f"eval_offsets: evaluation seed {max(evaluation)} is above {SEED_MAX} (SUMO's seed range)"
    if shared := sorted(set(profile.seeds) & evaluation):
        return (f"seeds: training seed {shared[0]} is also an evaluation seed ({EVAL_SEED} + condition + offset, "
                f"{EVAL_SEED + 100} + ... through the accident); a model is judged only on seeds it never trained on")
    try:
        for name in profile.variants:
            (cfg := train_config(profile, known[name], 0.0, profile.seeds[0])).validate()
            if known[name].weights == LAST_MODEL and not selecting(cfg):  # probe 15: its cells failed, every run
                return (f"train_steps: learner {name} drives {LAST_MODEL}, the last weights a training writes beside "
                        f"the model it selects, and a training of {profile.train_steps} step selects none (at least "
                        "2 steps)")  # fmt: skip
        for scenario in ("free", "accident"):
            eval_config(profile, scenario, 0, "keep", offset=profile.eval_offsets[0]).validate()
    except ConfigError as err:
        return f"makes a run the simulation refuses: {err}"
    return None


def load_variants(path: Path = LEARNERS_FILE) -> dict[str, Variant]:
    """Every learner of a learners.toml (engine/catalogue.load_learners)."""
    return load_learners(path)


def load_profiles(known: dict[str, Variant], path: Path = PROFILES_FILE) -> tuple[dict[str, Profile], str]:
    """The profiles of a protocol.toml and its `default` one (engine/catalogue.read_profiles); one ConfigError naming
    the file and the entry for an unknown field or variant, a judged variant or pair it does not run, a value of the
    wrong type, or a value a flag of the same quantity refuses (FIELD_RULES, profile_problem)."""
    profiles, _, default = read_profiles(path, SETTABLE, partial(_profile, known=known))
    return profiles, str(default)


def own_profiles(path: Path) -> tuple[dict[str, Profile], str | None]:
    """The profiles of a file of one's own (`--profile PATH.toml[:NAME]`, protocol.toml's format, naming
    learners.toml's variants; its `default` optional), checked as the packaged ones are, and its default or None."""
    profiles, _, default = read_profiles(path, SETTABLE, partial(_profile, known=variants()), default_needed=False)
    return profiles, default


def _profile(at: Entry, name: str, settings: dict[str, Any], known: dict[str, Variant]) -> Profile:
    """One profile of the file, its settings typed and checked."""
    if not settings.get("variants"):
        raise at.error("needs variants (a list of learners.toml's variants)")
    hints = get_type_hints(Profile)
    profile = Profile(name, **{key: at.value(key, value, hints[key], FIELD_RULES.get(key))
                               for key, value in settings.items()})  # fmt: skip
    named = [*profile.variants, *(p[2] for p in profile.paired_with)]
    if unknown := [v for v in named if v not in known]:
        raise at.error(f"unknown variant {unknown[0]!r} (learners.toml has {', '.join(known)})")
    if profile.judged_variant() not in profile.variants:
        raise at.error(f"judges {profile.judged!r}, which it does not run")
    if outside := [p[0] for p in profile.paired_with if p[0] not in profile.variants]:
        raise at.error(f"pairs {outside[0]!r}, which it does not run")
    if problem := next(filter(None, (folder_problem(p[1]) for p in profile.paired_with)), None):
        raise at.error(problem)  # here, naming the file (issue 82, probe 8, J19); check_paired checks it again
    if problem := profile_problem(profile, known):
        raise at.error(problem)
    return profile


def folder_problem(folder: str) -> str | None:
    """Why a paired_with folder (a path relative to results/) does not name a folder under results/, or None."""
    path = PurePath(folder)
    if not folder or path.is_absolute() or ".." in path.parts:
        return f"paired_with folder {folder!r} is not a folder under results/ (a relative path without '..')"
    return None


def variants() -> dict[str, Variant]:
    """The variants the protocol knows (learners.toml); the one of status default is the default preset."""
    return dict(_VARIANTS)


def train_config(profile: Profile, variant: Variant, alpha: float, seed: int) -> TrainConfig:
    """A model's training: the profile's steps times the variant's steps_factor (a conditioned one's world at alpha
    0: conditioning.world_alpha)."""
    dqn, n_steps = variant.learner, profile.train_steps * variant.steps_factor
    sim = SimConfig(road=RoadConfig(lanes=profile.lanes), reward=RewardConfig(alpha=world_alpha(dqn, alpha)),
                    steps=n_steps, seed=seed, policy="dqn")  # fmt: skip
    if n_steps < dqn.select_every_steps:  # a short profile validates twice
        dqn = replace(dqn, select_every_steps=max(n_steps // 2, 1), validation_steps=min(
            dqn.validation_steps, profile.free_steps))  # fmt: skip
        if dqn.validation_accident_steps:
            dqn = replace(dqn, validation_accident_steps=max(MIN_ACCIDENT_VALIDATION_STEPS, min(
                dqn.validation_accident_steps, profile.accident_steps)))  # fmt: skip
    return TrainConfig(sim=sim, dqn=dqn, eval_steps=0)


def eval_config(profile: Profile, scenario: str, i: int, policy: str, alpha: float = 0.0, offset: int = 0) -> SimConfig:
    """The evaluation run of condition i (its demand profile.t_ups[i]) in free flow or through the accident, on the
    evaluation seed of `offset` (one of profile.eval_offsets)."""
    t_up = profile.t_ups[i]
    if scenario == "free":
        return SimConfig(road=RoadConfig(lanes=profile.lanes), demand=DemandConfig(t_up_s=t_up),
                         reward=RewardConfig(alpha=alpha), steps=profile.free_steps,
                         seed=EVAL_SEED + offset + i,
                         policy=policy)  # fmt: skip
    return SimConfig(road=RoadConfig(lanes=profile.lanes), demand=DemandConfig(t_up_s=t_up),
                     accident=AccidentConfig(enabled=True, start_step=profile.accident_start,
                                             duration_steps=profile.accident_duration),
                     reward=RewardConfig(alpha=alpha), steps=profile.accident_steps,
                     seed=EVAL_SEED + 100 + offset + i,
                     policy=policy)  # fmt: skip


def cell_specs(profile: Profile, known: dict[str, Variant] | None = None) -> list[dict[str, Any]]:
    """Every cell: one per (variant, alpha, training seed, scenario, demand, evaluation seed set) and per (baseline,
    scenario, demand, evaluation seed set); the variants are learners.toml's unless `known` gives others. Every cell
    of a model but its first (its training: a conditioned network's alphas are one) names that first cell (after: the
    runner starts it once the first is done, so that no worker waits on the lock of a training another one runs)."""
    known = variants() if known is None else known
    specs: list[dict[str, Any]] = []
    models: list[tuple[Variant, float, int, tuple[str, ...]]] = []
    for name in profile.variants:
        for seed in profile.seeds:
            models.append((known[name], 0.0, seed, ("free", "accident")))
    for name in profile.alpha_variants or (profile.judged_variant(),):
        for alpha in profile.alphas:
            for seed in profile.seeds[: profile.alpha_seeds]:
                models.append((known[name], alpha, seed, ("free",)))
    first_of: dict[str, str] = {}  # a model's first cell (by its store name): the others wait for it (after)
    for variant, alpha, seed, scenarios in models:
        cfg = train_config(profile, variant, alpha, seed)
        stored_as = model_id(as_data(cfg))  # the model's store name: cells of one model share it
        train_key = f"a{number_name(alpha)}_seed{seed}_{_learner_tag(variant.learner)}"
        if variant.steps_factor != 1:  # another training than the same learner's at the profile's steps
            train_key += f"_x{variant.steps_factor}"
        for scenario, (i, t_up), offset in product(scenarios, enumerate(profile.t_ups), profile.eval_offsets):
            ev = eval_config(profile, scenario, i, "dqn", alpha, offset)
            key = f"{variant.name}_a{number_name(alpha)}_seed{seed}_{scenario}_t{number_name(t_up)}"
            key += _set_suffix(profile, offset)
            config: dict[str, Any] = {"train": as_data(cfg), "eval": as_data(ev)}
            if variant.drive():  # part of the cell's identity: a record driven otherwise is rerun
                config["drive"] = variant.drive()
            specs.append({"key": key, "kind": "model", "variant": variant.name, "alpha": alpha, "seed": seed,
                          "scenario": scenario, "t_up": t_up, "eval_seed": ev.seed, "weights": variant.weights,
                          "train_key": train_key, "training": cfg,
                          "config": config})  # fmt: skip
            if (first := first_of.setdefault(stored_as, key)) != key:
                specs[-1]["after"] = first
    for policy in BASELINES:
        for scenario, (i, t_up), offset in product(("free", "accident"), enumerate(profile.t_ups),
                                                   profile.eval_offsets):  # fmt: skip
            ev = eval_config(profile, scenario, i, policy, offset=offset)
            key = f"{policy.replace(':', '_').replace('=', '')}_{scenario}_t{number_name(t_up)}"
            specs.append({"key": key + _set_suffix(profile, offset),
                          "kind": "baseline", "variant": policy, "alpha": 0.0, "seed": None, "scenario": scenario,
                          "t_up": t_up, "eval_seed": ev.seed, "weights": None, "train_key": None,
                          "config": {"eval": as_data(ev)}})  # fmt: skip
    return specs


def _set_suffix(profile: Profile, offset: int) -> str:
    """The cell key's suffix of an evaluation seed set: none for the profile's first (so that a profile given more
    sets keeps its cells), `_e<offset>` for the others."""
    return "" if offset == profile.eval_offsets[0] else f"_e{offset}"


def _learner_tag(dqn: DQNConfig) -> str:
    """A short name of a learner for its training folder: the preset, and a digest of its settings."""
    import hashlib

    digest = hashlib.sha256(json.dumps(to_dict(dqn), sort_keys=True).encode()).hexdigest()[:8]
    return f"{dqn.preset}_{digest}"


_VARIANTS = LEARNERS
PROFILES, CURRENT = load_profiles(_VARIANTS)
"""the protocol's profiles (protocol.toml) and the one judging today's default learner (DQNConfig()): `coopsumo
protocol` and `make protocol` run it when no profile is named (its committed report: results/learner_protocol_nr10)"""
