"""Scenario II's plan: the sweep's profiles (lanes, loads or T_up, alphas, MOBIL politeness, seeds, steps), the
configuration of every cell and their keys. No SUMO here; scenario2.py runs the plan.
"""

from __future__ import annotations

from dataclasses import MISSING, dataclass, fields, replace
from pathlib import Path
from typing import Any, get_type_hints

from coopsumo.config import (
    MAX_LANES,
    MIN_LANES,
    ControlConfig,
    DemandConfig,
    RewardConfig,
    RoadConfig,
    SimConfig,
    TrainConfig,
    as_data,
)
from coopsumo.dqn_config import DQN_PRESETS, DQNConfig
from coopsumo.errors import ConfigError
from coopsumo.studies.engine.catalogue import DATA, CommitRule, Entry, Rule, read_profiles
from coopsumo.validation import (
    ALPHA_LIST,
    MAX_STEPS,
    MAX_T_UP_S,
    MOBIL_P_LIST,
    SEED_LIST,
    ListRule,
    alpha,
    integer,
    min_t_up_s,
    number_name,
    seed_count,
    steps,
    t_up_rule,
)

NOMINAL_CAPACITY_VEH_H_PER_LANE = 1800.0
"""capacity used to place the T_up grid: load 1 means T_up = 3600 / (lanes * 1800) s (near capacity)"""
POLICIES = ("dqn", "mobil", "keep", "greedy")
"""the kinds of cell: a DQN model evaluated per alpha; MOBIL per politeness p, `keep` and `greedy` (no training)"""
CLASSICAL = ("mobil", "keep", "greedy")
"""the policies that need no training: one run per condition (and p) and evaluation seed"""
PER_ALPHA = "per_alpha"
"""the policy of a check profile's per-alpha model cells (Profile.check_alphas)"""
CRITERION = "mean_speed_mps"
"""the paper's criterion: mean travelling speed over the evaluation (m/s)"""
FULL_ROAD = "full_road_speed_mps"
"""mean speed once the road is full: from the time the first vehicle inserted has left the road (m/s;
scenario2_gate.full_road_speed)"""
EVAL_SEED_BASE = 2000
"""evaluation seeds are EVAL_SEED_BASE + 1, + 2, ...: demands no training of the sweep saw (training seeds are 1, 2,
...; validation seeds 900,000 and above)"""


# -- the plan ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Profile:
    """Grid and step counts of one sweep: per lane count and training seed, one model per alpha (alpha_models) or one
    alpha-conditioned network (with per-alpha models beside it at check_alphas), trained on the lane count's demands
    (its conditions' T_ups), chosen on held-out demand of them and evaluated at every condition of the lane count
    (lane_train_config). The per-alpha design (a model per condition, alpha and seed: the profiles quick and the
    old tiny, `lane_networks = false`) was retired on 2026-12-03 (RETIRED_PER_ALPHA)."""

    name: str
    lanes: tuple[int, ...]
    loads: tuple[float, ...]
    """inflow as a share of lanes x 1,800 veh/h; T_up = 3600 / (load x lanes x 1800) s, 2 decimals"""
    alphas: tuple[float, ...]
    seeds: tuple[int, ...]
    """training seeds: one model per seed (per lane count and alpha)"""
    train_steps: int
    """training steps (0.1 s) per model"""
    eval_steps: int
    """greedy evaluation steps per cell"""
    t_up_s: tuple[float, ...] = ()
    """if set, this fixed T_up list (s) replaces the load grid for every lane count"""
    policies: tuple[str, ...] = ("dqn",)
    """"dqn" (train and evaluate per alpha), "mobil" (evaluate MOBIL per politeness p, no training), "keep",
    "greedy" """
    mobil_ps: tuple[float, ...] = (0.0, 0.25, 0.5, 1.0)
    """MOBIL politeness grid, used when "mobil" is in policies"""
    preset: str = "default"
    """the learner preset of every DQN cell (config.DQN_PRESETS)"""
    conditioned: bool = False
    """always false, kept because sweep.json records it: one alpha-conditioned training per condition and seed
    (`scenario2 --conditioned`) was retired on 2026-12-02; run it at commit dd78f46"""
    eval_seeds: tuple[int, ...] = (EVAL_SEED_BASE + 1,)
    """evaluation seeds: every model (and MOBIL) is evaluated greedily on each of them; none is a training seed"""
    alpha_draw_max: float = 32.0
    """conditioned networks: the alphas drawn and relabelled to in training are PAPER_ALPHAS up to this one"""
    validation_alphas: tuple[float, ...] = (0.0, 1.0, 8.0)
    """conditioned networks: model selection drives every validation run at each of these alphas (their mean
    scores)"""
    alpha_models: bool = False
    """one model per alpha instead of one alpha-conditioned network (per lane count and training seed, trained at
    that alpha alone on the lane count's demands and chosen at it): the design the check's criterion leaves
    (results/scenario2_check: the conditioned network fell below the per-alpha models at alpha 8)"""
    check_alphas: tuple[float, ...] = ()
    """conditioned networks: per-alpha models beside them, the same learner trained at each of these alphas alone
    (same demands, selection at that alpha), one per lane count and training seed, evaluated at every condition"""
    eval_loads: tuple[float, ...] = ()
    """if set, only the conditions of these loads are evaluated (the models still train on every load's T_up: they
    are the same models as a profile without it); ignored with t_up_s"""
    trajectory_every_steps: int = 0
    """evaluation runs record trajectories every this many steps, from which FULL_ROAD is measured; 0: not"""
    criterion: str = CRITERION
    """the speed alpha*, p*, the gate and the trends are judged on (CRITERION or FULL_ROAD)"""
    response_plan: str = ""
    """the commit that fixed claim (b)'s analysis plan before this profile's models were trained (the report then
    calls its response reading confirmatory); empty: the reading is exploratory (scenario2.response_report)"""

    def conditions(self) -> list[tuple[int, float, float]]:
        """(lanes, T_up s, load) of every condition evaluated, by lanes then decreasing T_up: the grid's, or those of
        eval_loads."""
        grid = self.grid()
        if self.eval_loads and not self.t_up_s:
            return [c for c in grid if c[2] in self.eval_loads]
        return grid

    def grid(self) -> list[tuple[int, float, float]]:
        """(lanes, T_up s, load) of every condition of the grid (a lane network trains on its lane count's)."""
        out = []
        for n in self.lanes:
            if self.t_up_s:
                pairs = [(t, load_of(n, t)) for t in self.t_up_s]
            else:
                pairs = [(t_up_for(n, load), load) for load in self.loads]
            out += [(n, t, load) for t, load in sorted(pairs, reverse=True)]
        return out

    def n_cells(self) -> int:
        per_condition = len(self.alphas) * len(self.seeds) if "dqn" in self.policies else 0
        per_condition += len(self.check_alphas) * len(self.seeds) if "dqn" in self.policies else 0
        per_condition += len(self.mobil_ps) * len(self.eval_seeds) if "mobil" in self.policies else 0
        per_condition += sum(p in self.policies for p in ("keep", "greedy")) * len(self.eval_seeds)
        return len(self.conditions()) * per_condition

    def n_trainings(self) -> int:
        """Models trained (or taken from the model store): per lane count and seed, one per alpha (alpha_models)
        or the network and one per check alpha."""
        if "dqn" not in self.policies:
            return 0
        return len(self.lanes) * len(self.seeds) * self.trainings_per_lane_seed()

    def trainings_per_lane_seed(self) -> int:
        """The models of one lane count and training seed (one per alpha with alpha_models, else the conditioned
        network and one per check alpha)."""
        return len(self.alphas) if self.alpha_models else 1 + len(self.check_alphas)

    def lane_t_ups(self, lanes: int) -> tuple[float, ...]:
        """The T_ups (s) of the grid's conditions of `lanes` lanes, from the lightest load: a lane network's demands
        (evaluated or not: eval_loads)."""
        return tuple(t for n, t, _ in self.grid() if n == lanes)


def t_up_for(lanes: int, load: float) -> float:
    """T_up (s, 2 decimals) giving `load` x lanes x 1,800 veh/h."""
    return round(3600.0 / (load * lanes * NOMINAL_CAPACITY_VEH_H_PER_LANE), 2)


def load_of(lanes: int, t_up_s: float) -> float:
    return round(3600.0 / (t_up_s * lanes * NOMINAL_CAPACITY_VEH_H_PER_LANE), 4)


def eval_seeds(n: int) -> tuple[int, ...]:
    """The first n evaluation seeds."""
    return tuple(EVAL_SEED_BASE + i for i in range(1, n + 1))


RETIRED_PER_ALPHA = "5947d4a"
"""the commit to run and redraw the per-alpha design at (one training per condition, alpha and seed, its own report:
the profiles quick and the old tiny, `lane_networks = false`), retired on 2026-12-03"""


def per_alpha_sweep(recorded: dict[str, Any]) -> bool:
    """Whether a sweep.json's profile is of the retired per-alpha design: it records `lane_networks` false, or
    neither `lane_networks` nor `criterion` (made before the lane networks came, commit da5c5e0). The lane-network
    sweeps made before 2026-12-03 record `lane_networks` true (recorded_fields drops it); later ones record no
    `lane_networks` but a `criterion`."""
    return recorded.get("lane_networks", "criterion" in recorded) is not True


def recorded_fields(recorded: dict[str, Any]) -> dict[str, Any]:
    """A lane-network sweep.json's profile as Profile's fields: without the `lane_networks` (true) that the sweeps
    made before 2026-12-03 record."""
    return {k: v for k, v in recorded.items() if k != "lane_networks"}


PROFILES_FILE = DATA / "scenario2.toml"
"""the profiles as data: `[profiles.NAME]` tables, `[shared.NAME]` bundles they `use`, and the `default`"""
MAX_LANE_DEMANDS = 10
"""a lane network's training demands (DQNConfig.train_t_ups holds at most 10)"""
LANE_LIST = ListRule(MIN_LANES, MAX_LANES, whole=True)
"""lane counts (--lanes, a profile's lanes)"""
LOAD_LIST = ListRule(0.0, low_open=True, least=0)
"""loads (a profile's loads and eval_loads): each T_up they give is checked too (profile_problem)"""
T_UP_LIST = t_up_rule(ControlConfig().dt_s, least=0)
"""a fixed T_up list (--t-up, a profile's t_up_s; none: the load grid)"""


RESPONSE_PLAN = CommitRule()
"""a profile's response_plan: the commit of the analysis plan its response reading follows, or empty"""
FIELD_RULES: dict[str, Rule] = {
    "lanes": LANE_LIST, "loads": LOAD_LIST, "alphas": ALPHA_LIST, "seeds": SEED_LIST, "train_steps": steps,
    "eval_steps": steps, "t_up_s": T_UP_LIST, "mobil_ps": MOBIL_P_LIST, "eval_seeds": seed_count,
    "alpha_draw_max": alpha, "validation_alphas": ALPHA_LIST, "check_alphas": replace(ALPHA_LIST, least=0),
    "eval_loads": LOAD_LIST, "trajectory_every_steps": integer(0, MAX_STEPS), "response_plan": RESPONSE_PLAN,
}  # fmt: skip
"""the rule of each field of a profile read from a file: its flag's (--lanes, --alphas, --t-up, --mobil-p, --steps,
--eval-steps, --eval-seeds; seeds: --seeds N's 1 to 1,000 seeds), so that a file takes no value the flag refuses"""


def profile_problem(profile: Profile) -> str | None:
    """Why a profile read from a file breaks a rule between its fields (the flags' checks of one another, and those of
    the fields no flag sets), in words starting with the field at fault, or None: a load grid that gives a T_up
    outside its limits or two loads the same T_up; loads beside t_up_s (which replaces them); eval_loads not among
    the loads; a lane network with more than MAX_LANE_DEMANDS demands; check_alphas outside the alphas or without a
    conditioned lane network; conditioned (retired); an unknown preset or criterion; the full-road criterion without
    trajectories; a training seed that is an evaluation seed; and a run of the profile the simulation refuses."""
    if profile.t_up_s and profile.loads:
        return f"loads must be [] beside t_up_s (the T_up list replaces the load grid), got {list(profile.loads)}"
    if not profile.t_up_s and not profile.loads:
        return "loads must be a list of finite numbers > 0 (or t_up_s a list of T_ups), got []"
    low = min_t_up_s(ControlConfig().dt_s)
    for lanes in profile.lanes if not profile.t_up_s else ():
        t_ups = [t_up_for(lanes, load) for load in profile.loads]
        if (bad := next((i for i, t in enumerate(t_ups) if not low <= t <= MAX_T_UP_S), None)) is not None:
            return (f"loads: load {number_name(profile.loads[bad])} gives T_up {t_ups[bad]:g} s on {lanes} lanes; a "
                    f"load must give a T_up from {low:g} to {MAX_T_UP_S:g} s on every lane count")  # fmt: skip
        if len(set(t_ups)) < len(t_ups):
            i, j = next((i, j) for j, t in enumerate(t_ups) for i in range(j) if t_ups[i] == t)
            return (f"loads {number_name(profile.loads[i])} and {number_name(profile.loads[j])} give the same T_up "
                    f"{t_ups[i]:g} s on {lanes} lanes (T_up has 2 decimals)")  # fmt: skip
    if outside := [x for x in profile.eval_loads if x not in profile.loads]:
        return f"eval_loads must be some of loads ({_numbers(profile.loads)}), got {number_name(outside[0])}"
    if (most := max(len(profile.lane_t_ups(n)) for n in profile.lanes)) > MAX_LANE_DEMANDS:
        return (f"{'t_up_s' if profile.t_up_s else 'loads'}: lane networks train each lane count's network on all its "
                f"demands, at most {MAX_LANE_DEMANDS}; got {most}")  # fmt: skip
    if profile.check_alphas and profile.alpha_models:
        return "check_alphas needs alpha_models = false (per-alpha models beside a conditioned network)"
    if outside := [x for x in profile.check_alphas if x not in profile.alphas]:
        return f"check_alphas must be some of alphas ({_numbers(profile.alphas)}), got {number_name(outside[0])}"
    if profile.conditioned:
        return ("conditioned must be false: the conditioned sweep (one network per condition and seed) was retired on "
                "2026-12-02; run it at commit dd78f46")
    if profile.preset not in DQN_PRESETS:
        return f"preset must be one of {', '.join(DQN_PRESETS)}, got {profile.preset!r}"
    if profile.criterion not in (CRITERION, FULL_ROAD):
        return f"criterion must be {CRITERION} or {FULL_ROAD}, got {profile.criterion!r}"
    if profile.criterion == FULL_ROAD and not profile.trajectory_every_steps:
        return f"criterion {FULL_ROAD} is measured on trajectories: trajectory_every_steps must be above 0"
    if shared := sorted(set(profile.seeds) & set(profile.eval_seeds)):
        return (f"seeds: training seed {shared[0]} is also an evaluation seed ({EVAL_SEED_BASE + 1} to "
                f"{EVAL_SEED_BASE} + eval_seeds); a model is judged only on seeds it never trained on")  # fmt: skip
    return _runs_problem(profile)


def _numbers(values: tuple[float, ...]) -> str:
    return ", ".join(map(number_name, values))


def _runs_problem(profile: Profile) -> str | None:
    """A run of the profile the simulation or the learner refuses, in words, or None: of each lane count, the first
    condition's training (a lane network's learner holds all its demands) and evaluation, and a classical run; checked
    on the profile, not found after its folder is made (its fields' own limits are FIELD_RULES')."""
    try:
        for lanes in profile.lanes:
            t_up = profile.lane_t_ups(lanes)[0]
            if "dqn" in profile.policies:
                _model_training(profile, lanes, profile.alphas[0], profile.seeds[0])[0].validate()
                eval_configs(lanes, t_up, profile.alphas[0], profile)[0].validate()
            if policy := next((x for x in CLASSICAL if x in profile.policies), None):
                name = f"mobil:p={profile.mobil_ps[0]}" if policy == "mobil" else policy
                classical_config(lanes, t_up, name, profile.eval_seeds[0], profile).validate()
    except ConfigError as err:
        return f"makes a run the simulation refuses: {err}"
    return None


def load_profiles(path: Path = PROFILES_FILE) -> tuple[dict[str, Profile], dict[str, str], str]:
    """The profiles of a scenario2.toml, what --help says of each, and the default one; one ConfigError naming the
    file and the entry for an unknown field, `use` or default, or a value of another type (an integer where a float
    belongs is taken as that float, so that a model's identity does not change), or a value its flag refuses
    (FIELD_RULES, profile_problem)."""
    return read_profiles(path, SETTABLE, _profile, own=("eval_seeds",))


def own_profiles(path: Path) -> tuple[dict[str, Profile], str | None]:
    """The profiles of a file of one's own (`--profile PATH.toml[:NAME]`, the packaged file's format; its `default`
    optional), checked as the packaged ones are, and its default or None."""
    profiles, _, default = read_profiles(path, SETTABLE, _profile, default_needed=False, own=("eval_seeds",))
    return profiles, default


SETTABLE = tuple(f.name for f in fields(Profile) if f.name not in ("name", "eval_seeds"))
"""the fields a profile's table or its shared table sets (eval_seeds: a profile's own, a count N)"""


def _profile(at: Entry, name: str, settings: dict[str, Any]) -> Profile:
    """One profile of a file from its settings, each typed and checked by its rule (FIELD_RULES, profile_problem)."""
    hints = get_type_hints(Profile)
    values: dict[str, Any] = {key: at.names(key, value, POLICIES) if key == "policies" else
                              at.value(key, value, hints[key], FIELD_RULES.get(key))
                              for key, value in settings.items() if key != "eval_seeds"}  # fmt: skip
    if "eval_seeds" in settings:
        values["eval_seeds"] = eval_seeds(at.value("eval_seeds", settings["eval_seeds"], int, seed_count))
    if missing := [f.name for f in fields(Profile)[1:] if f.default is MISSING and f.name not in values]:
        raise at.error(f"needs {', '.join(missing)} (a profile's fields without a default)")
    profile = Profile(name, **values)
    if problem := profile_problem(profile):
        raise at.error(problem)
    return profile


def train_folder(spec: dict[str, Any]) -> str | None:
    """A cell's training folder in its study, relative: train/<key> (a lane network's cell: train/<train_key>, the
    training its conditions share); a classical run's none."""
    return None if spec.get("policy") in CLASSICAL else f"train/{spec.get('train_key', spec['key'])}"


def cell_key(lanes: int, t_up_s: float, alpha: float, seed: int) -> str:
    return f"L{lanes}_T{number_name(t_up_s)}_a{number_name(alpha)}_s{seed}"


def mobil_key(lanes: int, t_up_s: float, p: float, seed: int) -> str:
    return f"L{lanes}_T{number_name(t_up_s)}_mobil_p{number_name(p)}_s{seed}"


def classical_key(lanes: int, t_up_s: float, policy: str, p: float | None, seed: int) -> str:
    """A cell of a policy that needs no training on evaluation seed `seed` (MOBIL at politeness p)."""
    if policy == "mobil":
        return mobil_key(lanes, t_up_s, float(p or 0.0), seed)
    return f"L{lanes}_T{number_name(t_up_s)}_{policy}_s{seed}"


def lane_key(lanes: int, seed: int, alpha: float | None = None) -> str:
    """The training folder of a lane network (alpha None) or of a check's per-alpha model, shared by its cells of
    every condition (and alpha)."""
    return f"L{lanes}_cond_s{seed}" if alpha is None else f"L{lanes}_a{number_name(alpha)}_s{seed}"


def per_alpha_key(lanes: int, t_up_s: float, alpha: float, seed: int) -> str:
    return f"L{lanes}_T{number_name(t_up_s)}_pa{number_name(alpha)}_s{seed}"


def eval_configs(lanes: int, t_up_s: float, alpha: float, profile: Profile) -> list[SimConfig]:
    """The greedy evaluations of a model of the condition at `alpha` (policy "dqn": the cell names the model), one
    per evaluation seed: free flow, the condition's inflow, eval_steps each."""
    return [SimConfig(road=RoadConfig(lanes=lanes), demand=DemandConfig(t_up_s=t_up_s),
                      reward=RewardConfig(alpha=alpha), steps=profile.eval_steps, seed=s, policy="dqn")
            for s in profile.eval_seeds]  # fmt: skip


def at_condition(dqn: DQNConfig) -> DQNConfig:
    """The learner in free flow: no drawn demands, no accidents, none in the model selection either (scenario II has
    none); lane_learner gives it its lane count's demands."""
    return replace(dqn, train_t_ups=(), accident_share=0.0, validation_accident_steps=0)


def lane_learner(lanes: int, profile: Profile, alpha: float | None = None) -> DQNConfig:
    """The learner of a lane network (alpha None: alpha-conditioned, drawing up to alpha_draw_max, chosen at
    validation_alphas) or of a per-alpha model beside it: the preset's machinery in free flow (no accident in
    training or selection: scenario II has none), trained on the lane count's demands and chosen on held-out demand
    of them (validation seeds, which no study evaluates on)."""
    t_ups = profile.lane_t_ups(lanes)
    dqn = replace(at_condition(DQN_PRESETS[profile.preset]), train_t_ups=t_ups, validation_t_ups=t_ups)
    if alpha is not None:
        return dqn
    return replace(dqn, alpha_conditioned=True, alpha_draw_max=profile.alpha_draw_max,
                   validation_alphas=profile.validation_alphas)  # fmt: skip


def lane_train_config(lanes: int, seed: int, profile: Profile, alpha: float | None = None) -> TrainConfig:
    """The training of a lane network (alpha None) or per-alpha model of `lanes` lanes: lane_learner on episodes
    of the lane count's demands (sim's own T_up, the heaviest, only names the run)."""
    sim = SimConfig(road=RoadConfig(lanes=lanes), demand=DemandConfig(t_up_s=min(profile.lane_t_ups(lanes))),
                    reward=RewardConfig(alpha=alpha or 0.0), steps=profile.train_steps, seed=seed, policy="dqn")
    return TrainConfig(sim=sim, dqn=lane_learner(lanes, profile, alpha), eval_steps=0)


def learner_of(profile: Profile) -> dict[str, Any]:
    """The learner settings every DQN cell of the sweep trains with (recorded in sweep.json): the network's of every
    lane count (per-alpha models and a check's: the same, not conditioned)."""
    alpha = 0.0 if profile.alpha_models else None  # per-alpha models: alpha 0's learner (each its own alpha)
    return {f"{n}_lanes": as_data(lane_learner(n, profile, alpha)) for n in profile.lanes}


def condition_rows(profile: Profile) -> list[dict[str, Any]]:
    """sweep.json's conditions: every condition the profile evaluates, with its load and inflow."""
    return [{"lanes": n, "t_up_s": t, "load": load, "inflow_veh_h": round(3600 / t, 1)}
            for n, t, load in profile.conditions()]  # fmt: skip


def classical_config(lanes: int, t_up_s: float, policy: str, seed: int, profile: Profile) -> SimConfig:
    """One run of a policy that needs no training on evaluation seed `seed`, as a DQN model's evaluation there."""
    return SimConfig(road=RoadConfig(lanes=lanes), demand=DemandConfig(t_up_s=t_up_s), steps=profile.eval_steps,
                     seed=seed, policy=policy)  # fmt: skip


def _model_training(profile: Profile, lanes: int, alpha: float, seed: int) -> tuple[TrainConfig, dict[str, Any]]:
    """A DQN cell's training and what its spec says of it: the model of its alpha, lane count and seed, or the lane
    network it shares (told its alpha)."""
    if profile.alpha_models:
        return lane_train_config(lanes, seed, profile, alpha), {"train_key": lane_key(lanes, seed, alpha),
                                                                 "conditioned": False}  # fmt: skip
    return lane_train_config(lanes, seed, profile), {"train_key": lane_key(lanes, seed), "conditioned": True}


def cell_specs(profile: Profile) -> list[dict[str, Any]]:
    """One JSON-ready spec per cell: key, coordinates and the full configuration as a dict.

    A DQN cell is one model at one condition (condition, alpha, training seed): its configuration is {"train":
    TrainConfig, "evals": [SimConfig per evaluation seed]}. The training is shared by every condition of a lane
    count (and with a conditioned network every alpha) and seed; the spec also names the training folder (train_key)
    and the cell's evaluation folder (evals_key), whether the model is told its alpha (conditioned: a network is, a
    per-alpha model, a check's of policy PER_ALPHA too, is not) and, for every cell of a training but its first, that
    first cell (after: the runner starts it once the training is done, so that no worker waits on a training another
    one runs). A MOBIL, keep or greedy cell is
    one run (condition, p, evaluation seed): its configuration a SimConfig, its seed the evaluation seed. With
    trajectory_every_steps, a DQN configuration also holds it and a run's is {"run": SimConfig,
    "trajectory_every_steps": K} (a record made without is not reused).
    """
    specs = []
    traj = {"trajectory_every_steps": profile.trajectory_every_steps} if profile.trajectory_every_steps else {}
    first_of: dict[str, str] = {}

    def add(key: str, lanes: int, t_up: float, load: float, seed: int, policy: str, alpha: float | None,
            p: float | None, cfg: TrainConfig | SimConfig | dict[str, Any], **extra: Any) -> None:  # fmt: skip
        specs.append({"key": key, "lanes": lanes, "t_up_s": t_up, "load": load, "alpha": alpha, "seed": seed,
                      "policy": policy, "p": p, **extra,
                      "config": cfg if isinstance(cfg, dict) else as_data(cfg)})  # fmt: skip

    def add_model(key: str, lanes: int, t_up: float, load: float, alpha: float, seed: int, train: TrainConfig,
                  policy: str = "dqn", **extra: Any) -> None:  # fmt: skip
        evals = eval_configs(lanes, t_up, alpha, profile)
        train.validate()
        for ev in evals:
            ev.validate()
        extra.update(evals_key=key, training=train)
        if (first := first_of.setdefault(extra["train_key"], key)) != key:
            extra["after"] = first
        config = {"train": as_data(train), "evals": [as_data(ev) for ev in evals], **traj}
        add(key, lanes, t_up, load, seed, policy, alpha, None, config, **extra)

    for lanes, t_up, load in profile.conditions():
        if "dqn" in profile.policies:
            for alpha in profile.alphas:
                for seed in profile.seeds:
                    train, extra = _model_training(profile, lanes, alpha, seed)
                    add_model(cell_key(lanes, t_up, alpha, seed), lanes, t_up, load, alpha, seed, train, **extra)
            for alpha in profile.check_alphas if not profile.alpha_models else ():
                for seed in profile.seeds:
                    add_model(per_alpha_key(lanes, t_up, alpha, seed), lanes, t_up, load, alpha, seed,
                              lane_train_config(lanes, seed, profile, alpha), PER_ALPHA,
                              train_key=lane_key(lanes, seed, alpha), conditioned=False)  # fmt: skip
        for policy in (x for x in CLASSICAL if x in profile.policies):
            for p in profile.mobil_ps if policy == "mobil" else (None,):
                for seed in profile.eval_seeds:
                    cfg = classical_config(lanes, t_up, f"mobil:p={p}" if policy == "mobil" else policy, seed, profile)
                    cfg.validate()
                    add(classical_key(lanes, t_up, policy, p, seed), lanes, t_up, load, seed, policy, None, p,
                        {"run": as_data(cfg), **traj} if traj else cfg)  # fmt: skip
    return specs


PROFILES, PROFILE_HELP, DEFAULT_PROFILE = load_profiles()
"""the profiles (scenario2.toml), what --help says of each, and the one run when none is named"""
