"""Typed, frozen configuration. Built once at an entry point, passed down, saved beside results.

Every field carries its unit in its name or docstring. Paper values are marked "paper";
the project's own choices are listed in the "Deviations and choices" table of docs/model.md.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from coopsumo.dqn_config import IMPLIED_FIELDS, DQNConfig, dqn_config_from_dict, validation_runs
from coopsumo.errors import ConfigError
from coopsumo.policy_spec import sumo_lc_params, sumo_models
from coopsumo.validation import (
    ALPHA_MAX,
    ALPHA_MIN,
    MAX_FCD_PERIOD_S,
    MAX_GUI_DELAY_MS,
    MAX_STEPS,
    MAX_T_UP_S,
    SEED_MAX,
    from_fields,
    int_problem,
    min_t_up_s,
    number_name,
    number_problem,
    type_problem,
)

MIN_LANES = 2
MAX_LANES = 6
PAPER_ALPHAS = (0.0, 0.125, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 24.0, 32.0, 48.0)
"""the paper's alpha grid, eq. (12); an alpha-conditioned training draws its alphas from it"""


DEMAND_STREAM, ACCIDENT_STREAM, POLICY_STREAM = 1, 2, 3
"""the independent random streams of one run's seed: the upstream demand, the accident's draws, the policy's"""


def rng_stream(seed: int, stream: int) -> np.random.Generator:
    """Random stream `stream` of the run seeded `seed` (numpy's SeedSequence of [seed, stream]): one seed feeds
    the demand, the accident and the policy without one's draws shifting another's."""
    return np.random.default_rng([seed, stream])


ROAD_LENGTH_M = (100.0, 100_000.0)
"""shortest and longest road (m): a vehicle's sight is 15 m and a loop section 200 m; 100 km is hours of driving"""
SPEED_LIMIT_MPS = (1.0, 70.0)
"""lowest and highest lane speed limit (m/s); 70 m/s is 252 km/h"""
LOOP_SPACING_M = (10.0, 10_000.0)
"""closest and farthest spacing of the loop cross-sections (m); the road must hold at least one"""
REWARD_WEIGHT_MAX = 1000.0
"""largest weight of the reward's speed and flow terms (both >= 0): as alpha's limit, far above the paper's 1"""


@dataclass(frozen=True)
class RoadConfig:
    """The straight highway: one edge of `lanes` parallel lanes, built by netconvert (sim/network.py)."""

    lanes: int = 3
    """number of lanes, 2-6"""
    length_m: float = 2000.0
    """road length (m): the accident at 1300 m plus 700 m of recovery downstream"""
    lane_width_m: float = 3.2
    """lane width (m)"""
    speed_limit_mps: float = 33.34
    """SUMO lane speed limit (m/s); above the largest expected speed (110 km/h). A lower limit caps every
    vehicle's expected speed (sim.world.draw_vehicle): the controller drives at most at the limit"""
    loop_spacing_m: float = 200.0
    """distance between induction-loop cross-sections (m), paper: 200 m"""
    loop_period_s: float = 60.0
    """aggregation period of the loop XML output (s)"""

    def loop_positions_m(self) -> list[float]:
        """Positions of the loop cross-sections (m), every spacing, strictly inside the road."""
        n = int((self.length_m - 1e-6) // self.loop_spacing_m)
        return [self.loop_spacing_m * k for k in range(1, n + 1) if self.loop_spacing_m * k < self.length_m]


@dataclass(frozen=True)
class DemandConfig:
    """Upstream inflow."""

    t_up_s: float = 1.0
    """upstream departure interval for the whole road (s): inflow = 3600 / t_up_s veh/h"""
    v_exp_mean_kmh: float = 85.0
    """mean of the normal distribution of expected speeds (km/h)"""
    v_exp_std_kmh: float = 15.0
    """standard deviation of expected speeds (km/h)"""
    v_exp_min_kmh: float = 40.0
    """lower clip of expected speeds (km/h), paper"""
    v_exp_max_kmh: float = 110.0
    """upper clip of expected speeds (km/h), paper"""


@dataclass(frozen=True)
class ControlConfig:
    """Newell car-following, collision check and lane changes (paper section III)."""

    dt_s: float = 0.1
    """simulation step (s), paper: 90,000 steps = 2.5 h"""
    car_length_m: float = 4.0
    """L_car (m), paper"""
    newell_c_per_s: float = 1.1
    """c of eq. (9) (1/s): the slope of speed against gap near standstill"""
    newell_d: float = -0.1
    """d of eq. (9) (dimensionless); negative, so the standstill gap is -d * v_exp / c"""
    v_acc_mps: float = 0.4
    """speed-up increment per decision (m/s), paper"""
    a1: float = 2.0
    """collision check coefficient on L_car, eq. (11), paper"""
    a2_s: float = 0.5
    """collision check coefficient on speed (s), eq. (11), paper"""
    v_cc_mps: float = 1.0
    """collision check speed margin (m/s), eq. (11), paper"""
    t_change_s: float = 4.0
    """lane-change duration (s), paper"""
    lc_min_gap_m: float = 2.0
    """smallest gap (m) a lane change may leave ahead and behind, on top of the check below"""
    lc_headway_s: float = 0.5
    """time headway (s) a lane change must leave to the new leader and to the new follower"""
    vehicle_width_m: float = 1.8
    """vehicle width (m), decides which lanes a vehicle in a lane change touches"""


@dataclass(frozen=True)
class AccidentConfig:
    """The scenario I bottleneck: vehicles reaching x_m are held with a probability decaying 1 -> 0."""

    enabled: bool = False
    x_m: float = 1300.0
    """bottleneck position (m), paper"""
    start_step: int = 20_000
    """first step of the accident window"""
    duration_steps: int = 50_000
    """length of the window (steps), paper: about 50,000"""
    redraw_s: float = 1.0
    """a held vehicle is released with probability 1 - p every redraw_s seconds"""

    def hold_probability(self, step: int) -> float:
        """p(step): 1 at the window's start, decaying linearly to 0 at its end; 0 outside."""
        if not self.enabled or step < self.start_step or step >= self.start_step + self.duration_steps:
            return 0.0
        return 1.0 - (step - self.start_step) / self.duration_steps


@dataclass(frozen=True)
class RewardConfig:
    """Reward r = w_v * r_v + r_cl + w_q * q_t (eq. 5-7)."""

    alpha: float = 0.0
    """lane-change penalty, eq. (7)"""
    v_min_mps: float = 0.0
    """lower speed bound of eq. (6) (m/s)"""
    v_max_mps: float = 110.0 / 3.6
    """upper speed bound of eq. (6) (m/s): the largest expected speed"""
    flow_window_s: float = 60.0
    """window over which the loops' flow q_t is measured (s)"""
    capacity_veh_h_per_lane: float = 2000.0
    """q_t is the loops' flow divided by lanes * this capacity (veh/h per lane)"""
    w_speed: float = 1.0
    """weight of r_v (paper: 1)"""
    w_flow: float = 1.0
    """weight of q_t (paper: 1)"""


@dataclass(frozen=True)
class SimConfig:
    """One simulation run."""

    road: RoadConfig = field(default_factory=RoadConfig)
    demand: DemandConfig = field(default_factory=DemandConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    accident: AccidentConfig = field(default_factory=AccidentConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    steps: int = 9000
    """simulation steps"""
    seed: int = 0
    """one seed for Python, NumPy, torch and SUMO"""
    policy: str = "keep"
    """policy spec: keep, random, greedy, dqn:PATH, mobil:p=P, sumo"""
    time_to_teleport_s: float = 300.0
    """SUMO's --time-to-teleport (s); SUMO's default"""
    sumo_collision_check: bool = False
    """also let SUMO detect collisions (a second, independent count; costly in jams with 4 s lane changes)"""
    full_read_every_steps: int = 10
    """controlled runs read every vehicle's lane, position and speed from SUMO every this many steps (and on
    teleports) and advance the table from the commanded speeds in between (exact, checked at each read);
    1: every step (--read-every-step). SUMO's own models (policy sumo) and sumo-gui are read every step"""

    @property
    def scenario(self) -> str:
        return "accident" if self.accident.enabled else "free"

    @property
    def sumo_driver(self) -> dict[str, float] | None:
        """None when the Newell controller drives (every policy but `sumo`); the LC2013 parameters of `sumo[:...]`
        (empty for plain `sumo`) when SUMO's own models drive. The policy string is read here, so sim/ reads none."""
        return sumo_lc_params(self.policy) if sumo_models(self.policy) else None

    def validate(self) -> None:
        """Raise ConfigError naming the first bad value."""
        if problem := type_problem(self):
            raise ConfigError(problem)
        if not MIN_LANES <= self.road.lanes <= MAX_LANES:
            raise ConfigError(f"lanes must be between {MIN_LANES} and {MAX_LANES}, got {self.road.lanes}")
        if problem := physics_problem(self):  # before anything divides by them
            raise ConfigError(problem)
        limit = min_t_up_s(self.control.dt_s)
        if number_problem(self.demand.t_up_s, low=limit, high=MAX_T_UP_S):
            raise ConfigError(f"t-up must be a finite number >= {limit:g} s (one vehicle per simulation step) and "
                              f"<= {MAX_T_UP_S:g} s, got {self.demand.t_up_s}")  # fmt: skip
        if int_problem(self.steps, 1, MAX_STEPS):
            raise ConfigError(f"steps must be an integer from 1 to {MAX_STEPS}, got {self.steps}")
        if int_problem(self.seed, 0, SEED_MAX):
            raise ConfigError(f"seed must be an integer from 0 to {SEED_MAX} (SUMO's seed range), got {self.seed}")
        acc = self.accident
        if acc.enabled and (acc.start_step < 0 or acc.duration_steps < 1):
            raise ConfigError(f"the accident window must start at a step >= 0 and last >= 1 step, got start "
                              f"{acc.start_step} and {acc.duration_steps} steps")  # fmt: skip
        alpha = self.reward.alpha
        if problem := number_problem(alpha, ALPHA_MIN, ALPHA_MAX):
            raise ConfigError(f"alpha must be {problem}, got {alpha}")
        if problem := road_problem(self.road, self.accident):
            raise ConfigError(problem)
        for name in ("w_speed", "w_flow"):
            if problem := number_problem(getattr(self.reward, name), 0.0, REWARD_WEIGHT_MAX):
                raise ConfigError(f"reward weight {name} must be {problem}, got {getattr(self.reward, name)}")
        if int_problem(self.full_read_every_steps, 1, MAX_STEPS):
            raise ConfigError(f"full_read_every_steps must be an integer from 1 to {MAX_STEPS}, "
                              f"got {self.full_read_every_steps}")  # fmt: skip


SIM_LIMITS: dict[str, tuple[float, float, bool, bool]] = {
    "road.lane_width_m": (2.0, 6.0, False, False), "road.loop_period_s": (1.0, 3600.0, False, False),
    "demand.v_exp_mean_kmh": (0.0, 252.0, True, False), "demand.v_exp_std_kmh": (0.0, 100.0, False, False),
    "demand.v_exp_min_kmh": (0.0, 252.0, True, False), "demand.v_exp_max_kmh": (0.0, 252.0, True, False),
    "control.dt_s": (0.01, 1.0, False, False), "control.car_length_m": (1.0, 30.0, False, False),
    "control.newell_c_per_s": (0.0, 10.0, True, False), "control.newell_d": (-10.0, 0.0, False, False),
    "control.v_acc_mps": (0.0, 10.0, True, False), "control.a1": (0.0, 10.0, False, False),
    "control.a2_s": (0.0, 10.0, False, False), "control.v_cc_mps": (0.0, 10.0, False, False),
    "control.t_change_s": (0.1, 60.0, False, False), "control.lc_min_gap_m": (0.0, 100.0, False, False),
    "control.lc_headway_s": (0.0, 10.0, False, False), "control.vehicle_width_m": (0.5, 6.0, False, False),
    "accident.redraw_s": (0.0, 3600.0, True, False), "reward.v_min_mps": (0.0, 70.0, False, True),
    "reward.v_max_mps": (0.0, 70.0, True, False), "reward.flow_window_s": (1.0, 3600.0, False, False),
    "reward.capacity_veh_h_per_lane": (0.0, 3600.0, True, False),
}  # fmt: skip
"""(lowest, highest, lowest excluded, highest excluded) of a run's physical settings that have no flag of their own,
far around the paper's values, so that a configuration read back (a checkpoint, a config.json, a model file) cannot
divide by zero, draw with a negative spread or build a road SUMO refuses (issue 82)"""


def fastest_mps(sim: Mapping[str, Any]) -> float:
    """The fastest any vehicle drives in a run of the SimConfig dict `sim`: its road's speed limit or its fastest
    desired speed, whichever is higher (m/s); the bound of every speed a record of that run holds."""
    return max(float(sim["road"]["speed_limit_mps"]), float(sim["demand"]["v_exp_max_kmh"]) / 3.6)


def physics_problem(sim: SimConfig) -> str | None:
    """Why one of SIM_LIMITS' settings or an order between two is out of range, or None."""
    for name, (low, high, low_open, high_open) in SIM_LIMITS.items():
        part, field_name = name.split(".")
        value = getattr(getattr(sim, part), field_name)
        if problem := number_problem(value, low, high, low_open, high_open):
            return f"{name} must be {problem}, got {number_name(value)}"
    for below, above in (("demand.v_exp_min_kmh", "demand.v_exp_max_kmh"), ("reward.v_min_mps", "reward.v_max_mps")):
        values = [getattr(getattr(sim, n.split(".")[0]), n.split(".")[1]) for n in (below, above)]
        if values[0] >= values[1]:
            return f"{below} must be below {above}, got {number_name(values[0])} and {number_name(values[1])}"
    return None


def road_problem(road: RoadConfig, accident: AccidentConfig) -> str | None:
    """Why the road cannot be driven, or None: its length, speed limit or loop spacing outside their limits
    (ROAD_LENGTH_M, SPEED_LIMIT_MPS, LOOP_SPACING_M), no loop on it, or an accident (when enabled) off it."""
    for what, value, (low, high) in (("road length (m)", road.length_m, ROAD_LENGTH_M),
                                     ("speed limit (m/s)", road.speed_limit_mps, SPEED_LIMIT_MPS),
                                     ("loop spacing (m)", road.loop_spacing_m, LOOP_SPACING_M)):  # fmt: skip
        if problem := number_problem(value, low, high):
            return f"{what} must be {problem}, got {number_name(value)}"
    if not road.loop_positions_m():
        return (f"loop spacing {number_name(road.loop_spacing_m)} m leaves no loop on the "
                f"{number_name(road.length_m)} m road: it must be below the road's length")  # fmt: skip
    if accident.enabled and not 0 < accident.x_m < road.length_m:
        return (f"the accident at {number_name(accident.x_m)} m is not on the {number_name(road.length_m)} m road: "
                "it must lie above 0 and below the road's length")  # fmt: skip
    return None


@dataclass(frozen=True)
class OutputConfig:
    """SUMO's own output files of a run, opt-in. They never change the simulation (tests check it)."""

    fcd_period_s: float = 0.0
    """period of SUMO's FCD output fcd.xml (s, a multiple of the step); 0: no fcd.xml"""
    tripinfo: bool = False
    """write SUMO's tripinfo.xml: one line per vehicle that left the road"""

    def validate(self, dt_s: float) -> None:
        """Raise ConfigError naming the first bad value; dt_s is the simulation step (s)."""
        period = self.fcd_period_s
        if not (math.isfinite(period) and 0 <= period <= MAX_FCD_PERIOD_S):
            raise ConfigError(f"fcd period must be from 0 to {MAX_FCD_PERIOD_S:g} s, got {number_name(period)}")
        steps = period / dt_s
        if period > 0 and (steps < 1 - 1e-9 or abs(steps - round(steps)) > 1e-6):
            raise ConfigError(f"fcd period must be a multiple of the {dt_s:g} s step, got {number_name(period)}")


SUMO_ROOTS = {"detectors.xml": b"</detector>", "fcd.xml": b"</fcd-export>", "tripinfo.xml": b"</tripinfos>"}
"""each XML file SUMO writes into a run's folder and the closing tag it ends with once SUMO has closed it whole
(agents/rollout.check_sumo_outputs on write, studies/engine/run_checks on read)"""


@dataclass(frozen=True)
class GuiConfig:
    """A run shown live in sumo-gui (through TraCI). Nothing here changes the simulation."""

    screenshot: str = ""
    """PNG file sumo-gui saves of its view after screenshot_step ('' : no screenshot)"""
    screenshot_step: int = 0
    """the step (1..steps) whose end state the screenshot shows"""
    delay_ms: float = 0.0
    """sumo-gui's pause between two steps (ms); 0 runs as fast as it draws"""
    window_px: tuple[int, int] = (1600, 600)
    """sumo-gui window size (pixels)"""
    screenshot_px: tuple[int, int] = (1600, 320)
    """screenshot size (pixels): a strip along the road"""

    def validate(self, steps: int) -> None:
        """Raise ConfigError naming the first bad value; steps is the run's length."""
        if self.screenshot and not self.screenshot.lower().endswith(".png"):
            raise ConfigError(f"gui screenshot must be a .png file, got {self.screenshot!r}")
        if self.screenshot and not 1 <= self.screenshot_step <= steps:
            raise ConfigError(f"gui screenshot step must be between 1 and steps ({steps}), got {self.screenshot_step}")
        if not (math.isfinite(self.delay_ms) and 0 <= self.delay_ms <= MAX_GUI_DELAY_MS):
            raise ConfigError(f"gui delay must be from 0 to {MAX_GUI_DELAY_MS:g} ms, got {number_name(self.delay_ms)}")


@dataclass(frozen=True)
class TrainConfig:
    """A training run: the free-flow world, the learner, and bookkeeping."""

    sim: SimConfig = field(default_factory=lambda: SimConfig(steps=90_000, policy="dqn"))
    dqn: DQNConfig = field(default_factory=DQNConfig)
    log_every_steps: int = 1000
    """environment steps per row of train_log.csv"""
    checkpoint_every_steps: int = 10_000
    """environment steps between periodic checkpoints (also written on Ctrl-C / SIGTERM)"""
    eval_steps: int = 9000
    """steps of the greedy evaluation run after training (0: none)"""

    def validate(self) -> None:
        if problem := type_problem(self):
            raise ConfigError(problem)
        self.sim.validate()
        self.dqn.validate()
        if self.dqn.alpha_conditioned and self.sim.reward.alpha != 0:
            raise ConfigError(f"an alpha-conditioned training draws alpha itself; its reward alpha must be 0, got "
                              f"{self.sim.reward.alpha:g}")  # fmt: skip
        if int_problem(self.eval_steps, 0, MAX_STEPS):
            raise ConfigError(f"eval steps must be an integer from 0 to {MAX_STEPS}, got {self.eval_steps}")
        if self.log_every_steps < 1 or self.checkpoint_every_steps < 0:
            raise ConfigError(f"log every must be >= 1 and checkpoint every >= 0 steps, got {self.log_every_steps} "
                              f"and {self.checkpoint_every_steps}")  # fmt: skip
        dq = self.dqn
        last = dq.validation_seed + validation_runs(dq) - 1
        if dq.select_every_steps and dq.validation_seed <= self.sim.seed <= last:
            raise ConfigError(f"validation seeds {dq.validation_seed}-{last} overlap the training seed "
                              f"{self.sim.seed}: choose another validation seed")  # fmt: skip


def train_config_from_dict(d: dict[str, Any]) -> TrainConfig:
    """Inverse of to_dict for TrainConfig; a missing or unknown field is a ConfigError naming it."""
    _no_unknown(d, TrainConfig, "training")
    try:
        return TrainConfig(
            sim=sim_config_from_dict(d["sim"]),
            dqn=dqn_config_from_dict(d["dqn"]),
            log_every_steps=d["log_every_steps"],
            checkpoint_every_steps=d["checkpoint_every_steps"],
            eval_steps=d["eval_steps"],
        )
    except KeyError as err:
        raise ConfigError(f"training configuration has no {err.args[0]!r} (written by another coopsumo?)") from None


def _no_unknown(d: Any, cls: type, what: str) -> None:
    """ConfigError naming the first key of the dict d that is no field of the dataclass cls (another version's)."""
    known = {f.name for f in dataclasses.fields(cls)}
    if isinstance(d, dict) and (unknown := sorted(str(k) for k in d if k not in known)):
        raise ConfigError(f"{what} configuration has an unknown field {unknown[0]!r} (written by another coopsumo?)")


def to_dict(cfg: Any) -> dict[str, Any]:
    """A JSON-ready dict of a config dataclass."""
    return dataclasses.asdict(cfg)


def as_data(cfg: Any) -> dict[str, Any]:
    """A config dataclass as its JSON file holds it (to_dict with tuples as lists): how records, cells and the model
    store compare and name configurations."""
    return json.loads(json.dumps(dataclasses.asdict(cfg)))


SPEED_ONLY_FIELDS = frozenset({"full_read_every_steps"})
"""configuration fields that change how fast a run goes, never what it gives (recorded, ignored when a study
matches a stored run, cell or checkpoint to its configuration)"""


def results_view(d: Any) -> Any:
    """A configuration as to_dict or JSON gives it, without SPEED_ONLY_FIELDS at any depth and without IMPLIED_FIELDS
    (fields added, and fields retired) at their implied value: two runs whose views are equal give the same results
    (a run stored before such a field existed, or while a retired one did, matches too)."""
    if isinstance(d, dict):
        return {k: results_view(v) for k, v in d.items()
                if k not in SPEED_ONLY_FIELDS and not (k in IMPLIED_FIELDS and v == IMPLIED_FIELDS[k])}  # fmt: skip
    if isinstance(d, list):
        return [results_view(v) for v in d]
    return d


def first_difference(a: Any, b: Any, path: str = "config") -> str | None:
    """Where two configurations (config.results_view of each) first differ, as 'config.sim.seed: 2 != 0'; None
    when they are equal."""
    a, b = results_view(json.loads(json.dumps(a))), results_view(json.loads(json.dumps(b)))

    def walk(x: Any, y: Any, at: str) -> str | None:
        if isinstance(x, dict) and isinstance(y, dict):
            for key in sorted(set(x) | set(y)):
                if (found := walk(x.get(key), y.get(key), f"{at}.{key}")) is not None:
                    return found
            return None
        return None if x == y else f"{at}: {json.dumps(x)[:40]} != {json.dumps(y)[:40]}"

    return walk(a, b, path)


def sim_config_from_dict(d: dict[str, Any]) -> SimConfig:
    """Inverse of to_dict for SimConfig; a missing or unknown field is a ConfigError naming it."""
    _no_unknown(d, SimConfig, "simulation")
    try:
        parts = {name: from_fields(cls, d[name], name) for name, cls in (
            ("road", RoadConfig), ("demand", DemandConfig), ("control", ControlConfig), ("accident", AccidentConfig),
            ("reward", RewardConfig))}  # fmt: skip
        return SimConfig(**parts, steps=d["steps"], seed=d["seed"], policy=d["policy"],
                         time_to_teleport_s=d["time_to_teleport_s"],
                         sumo_collision_check=d.get("sumo_collision_check", False),
                         full_read_every_steps=d.get("full_read_every_steps", SimConfig.full_read_every_steps))
    except KeyError as err:
        raise ConfigError(f"simulation configuration has no {err.args[0]!r} (written by another coopsumo?)") from None
