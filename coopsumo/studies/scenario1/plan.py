"""Scenario I's plan: the study's sizes (Plan and its profiles), the configuration of every training and accident
run, and the names of models, policies and run folders. No SUMO here; scenario1.py runs the plan.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

from coopsumo.config import AccidentConfig, DemandConfig, OutputConfig, RewardConfig, RoadConfig, SimConfig, TrainConfig
from coopsumo.dqn_config import DQN_PRESETS, DQNConfig
from coopsumo.policy_spec import model_file, parse_policy, split_dqn_spec
from coopsumo.studies.engine.model_store import FIRST_TRAIN_SEED
from coopsumo.studies.engine.run_folders import default_out
from coopsumo.validation import number_name

ALPHAS = (0.0, 8.0)
"""the paper's two; the default learner still changes lanes at alpha = 8 (0.14-0.23 per vehicle in free flow,
results/learner_protocol_v2x_mix10), so it is not simply `keep` (the earlier learner's alpha = 8 was; alpha = 2
was then added, and is one --alphas away)"""
TRAIN_SEEDS = tuple(range(FIRST_TRAIN_SEED, FIRST_TRAIN_SEED + 5))
"""training seeds of the default: 5 models per alpha, the learner protocol's first five (model store: shared)"""
PRESETS = ("default",)
BASELINES = ("keep", "greedy", "sumo")
MOBIL_PS = (0.0, 0.5)
"""MOBIL politeness values run beside the learned models: classical cooperation as the control (0.25 and 1 are
one --mobil-p away; the default keeps the study within 90 minutes on 2 cores)"""
DEMANDS = (2.0, 1.5, 1.0)
"""T_up (s) of the default study: the queue stays on the road, reaches the entrance, still waits at the end"""


@dataclass(frozen=True)
class Plan:
    """Sizes of the study: the default profile; Plan.quick() and Plan.full() are the others."""

    lanes: int = 3
    t_ups: tuple[float, ...] = DEMANDS
    """demands of the accident runs: upstream departure interval T_up (s)"""
    train_t_up_s: float = DemandConfig.t_up_s
    """demand of the free-flow trainings (s); the models are trained once and meet every demand"""
    train_steps: int = 90_000
    steps: int = 20_000
    accident_start: int = 2_000
    accident_steps: int = 10_000
    seeds: tuple[int, ...] = (1, 2, 3, 4, 5)
    """evaluation seeds: every model and baseline meets each"""
    train_seeds: tuple[int, ...] = TRAIN_SEEDS
    """one model per training seed, preset and alpha: the unit of replication"""
    trajectory_every: int = 5
    loop_period_s: float = 60.0
    baselines: tuple[str, ...] = BASELINES
    mobil_ps: tuple[float, ...] = MOBIL_PS
    alphas: tuple[float, ...] = ALPHAS
    presets: tuple[str, ...] = PRESETS
    """learner presets (config.DQN_PRESETS) whose models are trained and run, side by side"""
    fcd_period_s: float = 5.0
    """period of SUMO's fcd.xml in every run folder (s)"""
    tripinfo: bool = True
    """write SUMO's tripinfo.xml in every run folder"""
    profile: str = "default"

    def outputs(self) -> OutputConfig:
        """SUMO's output files of every accident run."""
        return OutputConfig(fcd_period_s=self.fcd_period_s, tripinfo=self.tripinfo)

    def baseline_policies(self) -> tuple[str, ...]:
        """keep and greedy, MOBIL at every politeness, then SUMO's own models."""
        first = tuple(b for b in self.baselines if b != "sumo")
        mobils = tuple(f"mobil:p={number_name(p)}" for p in self.mobil_ps)
        return first + mobils + tuple(b for b in self.baselines if b == "sumo")

    @staticmethod
    def quick() -> Plan:
        """2 demands, 1 seed, small step counts. The accident starts at 100 s, once the first vehicles have
        reached the bottleneck (1,300 m at about 23 m/s), so that even a shortened run holds a jam to show."""
        return Plan(t_ups=(3.0, 1.0), train_steps=3000, steps=6000, accident_start=1000, accident_steps=3000,
                    seeds=(1,), train_seeds=TRAIN_SEEDS[:2], loop_period_s=30.0, profile="quick")  # fmt: skip

    @staticmethod
    def full() -> Plan:
        """The paper's accident: 90,000 steps, the stuck ratio decaying over 50,000 of them; 5 seeds."""
        return Plan(steps=90_000, accident_start=AccidentConfig.start_step,
                    accident_steps=AccidentConfig.duration_steps, t_ups=(3.0, 2.0, 1.5, 1.0), seeds=(1, 2, 3, 4, 5),
                    profile="full")  # fmt: skip


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
    """The learners a study may train, by name: config.DQN_PRESETS, then the learner protocol's variants that drive
    as they were saved (learners.toml: no drive settings, model.pt) and are not a preset under another name, such as
    `alpha_only_dense` (issue 78)."""
    from coopsumo.studies.protocol.plan import variants

    known = dict(DQN_PRESETS)
    for name, variant in variants().items():
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
    k = len(plan.train_seeds)
    if plan.presets != Plan().presets:  # another learner: never the default learner's folder, in any profile
        profile = "" if plan.profile == Plan().profile else f"{plan.profile}_"
        return Path("results") / f"scenario1_{profile}{'_'.join(plan.presets)}" \
            f"{f'_{k}models' if plan.profile == Plan().profile and k != len(TRAIN_SEEDS) else ''}"  # fmt: skip
    if plan.profile == Plan().profile and k != len(Plan().train_seeds):
        return Path("results") / f"scenario1_{k}models"
    return default_out("scenario1", plan.profile, Plan().profile)
