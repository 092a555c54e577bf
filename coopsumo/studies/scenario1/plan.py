"""Scenario I's plan: the study's sizes (Plan, its profiles read from experiments_data/scenario1.toml), the
configuration of every training and accident run, and the names of models, policies and run folders. No SUMO here;
scenario1/study.py runs the plan.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, NamedTuple, get_type_hints

from coopsumo.config import (
    MAX_LANES,
    MIN_LANES,
    AccidentConfig,
    ControlConfig,
    DemandConfig,
    OutputConfig,
    RewardConfig,
    RoadConfig,
    SimConfig,
    TrainConfig,
)
from coopsumo.dqn_config import DQN_PRESETS, DQNConfig
from coopsumo.errors import ConfigError
from coopsumo.policy_spec import PolicySpecError, model_file, parse_policy, split_dqn_spec
from coopsumo.studies.engine.catalogue import DATA, Entry, Rule, read_profiles
from coopsumo.studies.engine.model_store import FIRST_TRAIN_SEED
from coopsumo.studies.engine.run_folders import default_out
from coopsumo.validation import (
    ALPHA_LIST,
    MAX_FCD_PERIOD_S,
    MAX_STEPS,
    MAX_T_UP_S,
    MOBIL_P_LIST,
    SEED_LIST,
    accident_problem,
    integer,
    min_t_up_s,
    number,
    number_name,
    steps,
    t_up_note,
    t_up_rule,
)


@dataclass(frozen=True)
class Plan:
    """Sizes of the study: one profile (PROFILES, read from scenario1.toml)."""

    lanes: int
    t_ups: tuple[float, ...]
    """demands of the accident runs: upstream departure interval T_up (s)"""
    train_t_up_s: float
    """demand of the free-flow trainings (s); the models are trained once and meet every demand"""
    train_steps: int
    steps: int
    accident_start: int
    accident_steps: int
    seeds: tuple[int, ...]
    """evaluation seeds: every model and baseline meets each"""
    train_seeds: tuple[int, ...]
    """one model per training seed, preset and alpha: the unit of replication"""
    trajectory_every: int
    loop_period_s: float
    baselines: tuple[str, ...]
    mobil_ps: tuple[float, ...]
    alphas: tuple[float, ...]
    presets: tuple[str, ...]
    """learner presets (config.DQN_PRESETS) whose models are trained and run, side by side"""
    fcd_period_s: float
    """period of SUMO's fcd.xml in every run folder (s)"""
    tripinfo: bool
    """write SUMO's tripinfo.xml in every run folder"""
    profile: str
    """the profile's name: it names the results folder (study_out) and the study's records"""

    def outputs(self) -> OutputConfig:
        """SUMO's output files of every accident run."""
        return OutputConfig(fcd_period_s=self.fcd_period_s, tripinfo=self.tripinfo)

    def baseline_policies(self) -> tuple[str, ...]:
        """keep and greedy, MOBIL at every politeness, then SUMO's own models."""
        first = tuple(b for b in self.baselines if b != "sumo")
        mobils = tuple(f"mobil:p={number_name(p)}" for p in self.mobil_ps)
        return first + mobils + tuple(b for b in self.baselines if b == "sumo")


class Run(NamedTuple):
    """One accident run of the study: its policy label, demand (s), evaluation seed, folder, configuration, and the
    training seed of its model (None for a baseline)."""

    label: str
    t_up: float
    seed: int
    out: Path
    cfg: SimConfig
    train_seed: int | None = None

    @property
    def key(self) -> str:
        """The run's cell key: run_t<T_up>_<label>[_m<training seed>]_seed<k>."""
        model = "" if self.train_seed is None else f"_m{self.train_seed}"
        return f"run_t{number_name(self.t_up)}_{self.label}{model}_seed{self.seed}"


def model_name(preset: str, alpha: float, train_seed: int) -> str:
    """Folder of a model under models/, a link into the model store (the default preset keeps the plain
    alpha<A> name): alpha<A>_m<training seed>."""
    base = f"alpha{number_name(alpha)}" if preset == "default" else f"{preset}_alpha{number_name(alpha)}"
    return f"{base}_m{train_seed}"


def model_label(preset: str, alpha: float) -> str:
    """A learned policy's name in tables (every training seed of it): dqn_alpha<A>."""
    return "dqn_" + (f"alpha{number_name(alpha)}" if preset == "default" else f"{preset}_alpha{number_name(alpha)}")


def label_for(policy: str) -> str:
    """Short name of a policy in tables and folders: dqn_<model folder> for a model (then _a<alpha> or _adaptive
    for an alpha-conditioned one's alpha), py_<class> for a class of one's own, sb3_<zip's name> for a
    Stable-Baselines3 model, else the spec."""
    spec = parse_policy(policy)
    if spec.name == "dqn":
        path, alpha = split_dqn_spec(policy)
        tail = "" if alpha is None else "_" + (alpha if isinstance(alpha, str) else f"a{number_name(alpha)}")
        return "dqn_" + Path(model_file(path)).parent.name + tail
    if spec.name == "py":
        return f"py_{spec.class_name}"
    if spec.name == "sb3" and spec.model is not None:
        name = Path(spec.model).name.removesuffix(".zip")
        return "sb3_" + (Path(spec.model).parent.name if name == "model" else name)
    return policy.replace(":", "_").replace("=", "")


def run_folder(label: str, seed: int, t_up: float, train_seed: int | None = None) -> str:
    """A run's folder under the results folder: runs/t<T_up>/<label>[_m<training seed>]_seed<k>."""
    model = "" if train_seed is None else f"_m{train_seed}"
    return f"runs/t{number_name(t_up)}/{label}{model}_seed{seed}"


def learners() -> dict[str, DQNConfig]:
    """The learners a study may train, by name: config.DQN_PRESETS, then the learner catalogue's learners that drive
    as they were saved (learners.toml: no drive settings, model.pt) and are not a preset under another name, such as
    `alpha_only_dense` (issue 78)."""
    from coopsumo.studies.engine.catalogue import LEARNERS

    known = dict(DQN_PRESETS)
    for name, variant in LEARNERS.items():
        if name not in known and not variant.drive() and variant.weights == "model.pt" and \
                variant.learner not in DQN_PRESETS.values():
            known[name] = variant.learner
    return known


def train_config(plan: Plan, alpha: float, preset: str = "default", train_seed: int = FIRST_TRAIN_SEED) -> TrainConfig:
    """The training of one model with the learner preset `preset` (the learner's own training demand; the same
    configuration as the learner protocol's, so the model store holds one model for both)."""
    sim = SimConfig(
        road=RoadConfig(lanes=plan.lanes, loop_period_s=plan.loop_period_s),
        demand=DemandConfig(t_up_s=plan.train_t_up_s),
        reward=RewardConfig(alpha=alpha),
        steps=plan.train_steps,
        seed=train_seed,
        policy="dqn",
    )
    return TrainConfig(sim=sim, dqn=learners()[preset], eval_steps=0)


def accident_config(plan: Plan, policy: str, seed: int, t_up_s: float) -> SimConfig:
    """One policy through the accident at demand t_up_s (s) on seed `seed`."""
    return SimConfig(
        road=RoadConfig(lanes=plan.lanes, loop_period_s=plan.loop_period_s),
        demand=DemandConfig(t_up_s=t_up_s),
        accident=AccidentConfig(enabled=True, start_step=plan.accident_start, duration_steps=plan.accident_steps),
        steps=plan.steps,
        seed=seed,
        policy=policy,
    )


def study_out(plan: Plan) -> Path:
    """The results folder without --out: results/scenario1 (the committed profile) or results/scenario1_<profile>;
    the committed profile with another number of models per alpha (--train-seeds K) writes results/scenario1_<K>models,
    and with other learner presets results/scenario1_<presets>[_<K>models], so that a larger replication or another
    learner never replaces the committed report."""
    k, default = len(plan.train_seeds), PROFILES[DEFAULT_PROFILE]
    if plan.presets != default.presets:  # another learner: never the default learner's folder, in any profile
        profile = "" if plan.profile == DEFAULT_PROFILE else f"{plan.profile}_"
        return Path("results") / f"scenario1_{profile}{'_'.join(plan.presets)}" \
            f"{f'_{k}models' if plan.profile == DEFAULT_PROFILE and k != len(default.train_seeds) else ''}"  # fmt: skip
    if plan.profile == DEFAULT_PROFILE and k != len(default.train_seeds):
        return Path("results") / f"scenario1_{k}models"
    return default_out("scenario1", plan.profile, DEFAULT_PROFILE)


# -- the profiles, as data ---------------------------------------------------------------------------------------
PROFILES_FILE = DATA / "scenario1.toml"
"""the profiles as data: `[profiles.NAME]` tables, the `[shared.NAME]` tables they `use`, and the `default`"""
PAPER_PROFILE = "full"
"""the profile at the paper's horizon: its report adds the horizon section, and claim (a)'s reading is exploratory"""
BASELINES = ("keep", "greedy", "sumo")
"""the baselines a profile names beside MOBIL (--baseline adds policies of one's own)"""
RUN_STEPS = integer(10, MAX_STEPS)
"""steps of an accident run (--steps, a profile's steps)"""
T_UP_LIST = t_up_rule(ControlConfig().dt_s)
"""demands of the accident runs (--t-up, a profile's t_ups)"""
FIELD_RULES: dict[str, Rule] = {
    "lanes": integer(MIN_LANES, MAX_LANES), "t_ups": T_UP_LIST, "train_steps": steps, "steps": RUN_STEPS,
    "train_t_up_s": number(min_t_up_s(ControlConfig().dt_s), MAX_T_UP_S, note=t_up_note(ControlConfig().dt_s)),
    "seeds": SEED_LIST, "train_seeds": SEED_LIST, "trajectory_every": integer(1, MAX_STEPS), "mobil_ps": MOBIL_P_LIST,
    "alphas": ALPHA_LIST, "fcd_period_s": number(0, MAX_FCD_PERIOD_S, low_open=True),
}  # fmt: skip
"""the rule of each field of a profile read from a file: its flag's (--t-up, --train-steps, --steps, --mobil-p,
--alphas; seeds and train_seeds: lists of seeds, as --train-seeds S,S,...; lanes and fcd_period_s: simulate's), so
that a file takes no value the flag refuses; the accident window and the rules between fields: plan_problem"""
SETTABLE = tuple(f.name for f in fields(Plan) if f.name != "profile")
"""the fields a profile's table or its shared table sets (the profile's name is its table's)"""


def plan_problem(plan: Plan) -> str | None:
    """Why a profile read from a file breaks a rule between its fields, in words starting with the field at fault, or
    None: an accident window outside the run (validation.accident_problem), a training seed that is an evaluation
    seed (as --train-seeds), alphas without 0 (the study's reference, which --alphas adds), or a training, accident
    run or output the simulation refuses (checked on the profile, not found after its folder is made)."""
    if problem := accident_problem(plan.accident_start, plan.accident_steps, plan.steps, "accident_start",
                                   "accident_steps"):  # fmt: skip
        return problem
    if shared := sorted(set(plan.train_seeds) & set(plan.seeds)):
        return (f"train_seeds: training seed {shared[0]} is also an evaluation seed (seeds); a model is judged only "
                "on seeds it never trained on")  # fmt: skip
    if 0.0 not in plan.alphas:
        return f"alphas must hold 0, the study's reference, got [{', '.join(map(number_name, plan.alphas))}]"
    try:
        train_config(plan, plan.alphas[0], plan.presets[0], plan.train_seeds[0]).validate()
        accident_config(plan, plan.baseline_policies()[0], plan.seeds[0], plan.t_ups[0]).validate()
        plan.outputs().validate(ControlConfig().dt_s)
    except ConfigError as err:
        return f"makes a run the simulation refuses: {err}"
    return None


def _plan(at: Entry, name: str, settings: dict[str, Any], own_baselines: bool = False) -> Plan:
    """One profile of a file from its settings, each typed and checked by its rule (FIELD_RULES, plan_problem);
    own_baselines: the baselines may add policies of one's own (a study's plan.json records --baseline's)."""
    hints, names = get_type_hints(Plan), {"baselines": BASELINES, "presets": tuple(learners())}
    if own_baselines:
        names["baselines"] = (*BASELINES, *own_policies(at, settings.get("baselines")))
    values: dict[str, Any] = {key: at.names(key, value, names[key], least=int(key == "presets")) if key in names
                              else at.value(key, value, hints[key], FIELD_RULES.get(key))
                              for key, value in settings.items()}  # fmt: skip
    if missing := [key for key in SETTABLE if key not in values]:
        raise at.error(f"needs {', '.join(missing)} (every field of a profile, its own or its shared table's)")
    plan = Plan(**values, profile=name)
    if problem := plan_problem(plan):
        raise at.error(problem)
    return plan


def own_policies(at: Entry, value: Any) -> tuple[str, ...]:
    """The policies of one's own in a recorded plan's baselines (as --baseline gives them, checked by their grammar:
    policy_spec.parse_policy), the profile's BASELINES left out; ConfigError naming the first one it refuses."""
    own = tuple(v for v in value if v not in BASELINES) if isinstance(value, list) else ()
    for text in own:
        try:
            parse_policy(text)
        except (PolicySpecError, TypeError) as err:
            raise at.error(f"baselines: {err}") from None
    return own


def recorded_plan(path: Path, settings: Any) -> Plan:
    """The plan a study recorded in its plan.json (`plan`; a merge's part, issue 82, probe 7, I8), checked by the
    rules a profile's fields get (FIELD_RULES, plan_problem, the learner presets known), its baselines with
    --baseline's policies: one ConfigError naming the file and the field ("PATH: [plan] lanes must be ...")."""
    at = Entry(path, "plan")
    at.table(settings, "plan", (*SETTABLE, "profile"))
    name = settings.get("profile")
    if not isinstance(name, str) or not name:
        raise at.error(f"profile must be a profile's name, got {name!r}")
    return _plan(at, name, {key: value for key, value in settings.items() if key != "profile"}, own_baselines=True)


def load_profiles(path: Path = PROFILES_FILE) -> tuple[dict[str, Plan], dict[str, str], str]:
    """The profiles of a scenario1.toml, what --help says of each, and the default one; one ConfigError naming the
    file and the entry for an unknown field, `use` or default, a missing field, a value of another type (an integer
    where a float belongs is taken as that float, so that a model's identity does not change), or a value its flag
    refuses (FIELD_RULES, plan_problem)."""
    return read_profiles(path, SETTABLE, _plan)


def own_profiles(path: Path) -> tuple[dict[str, Plan], str | None]:
    """The profiles of a file of one's own (`--profile PATH.toml[:NAME]`, the packaged file's format; its `default`
    optional), checked as the packaged ones are, and its default or None."""
    profiles, _, default = read_profiles(path, SETTABLE, _plan, default_needed=False)
    return profiles, default


PROFILES, PROFILE_HELP, DEFAULT_PROFILE = load_profiles()
"""the profiles (scenario1.toml), what --help says of each, and the one run when none is named (its report is
committed: results/scenario1)"""
