"""Typed, frozen configuration. Built once at an entry point, passed down, saved beside results.

Every field carries its unit in its name or docstring. Paper values are marked "paper";
the project's own choices are listed in the "Deviations and choices" table of docs/model.md.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from coopsumo.errors import UsageError
from coopsumo.validation import (
    ALPHA_MAX,
    ALPHA_MIN,
    LEARNER_LIMITS,
    MAX_FCD_PERIOD_S,
    MAX_GUI_DELAY_MS,
    MAX_REPLAY,
    MAX_STEPS,
    MAX_T_UP_S,
    SEED_MAX,
    int_problem,
    limits_problem,
    min_t_up_s,
    number_name,
    number_problem,
    type_problem,
)

MIN_LANES = 2
MAX_LANES = 6
OBSERVATIONS = ("paper", "v2x")
"""what a learner can read (DQNConfig.observation)"""
PAPER_ALPHAS = (0.0, 0.125, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 24.0, 32.0, 48.0)
"""the paper's alpha grid, eq. (12); an alpha-conditioned training draws its alphas from it"""


DEMAND_STREAM, ACCIDENT_STREAM, POLICY_STREAM = 1, 2, 3
"""the independent random streams of one run's seed: the upstream demand, the accident's draws, the policy's"""


def rng_stream(seed: int, stream: int) -> np.random.Generator:
    """Random stream `stream` of the run seeded `seed` (numpy's SeedSequence of [seed, stream]): one seed feeds
    the demand, the accident and the policy without one's draws shifting another's."""
    return np.random.default_rng([seed, stream])


class ConfigError(UsageError):
    """A configuration value is outside what the model supports (a usage error)."""


@dataclass(frozen=True)
class RoadConfig:
    """The straight highway."""

    lanes: int = 3
    """number of lanes, 2-6"""
    length_m: float = 2000.0
    """road length (m): the accident at 1300 m plus 700 m of recovery downstream"""
    lane_width_m: float = 3.2
    """lane width (m)"""
    speed_limit_mps: float = 33.34
    """SUMO lane speed limit (m/s); above the largest expected speed (110 km/h)"""
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
    decision_interval_steps: int = 10
    """steps of 0.1 s between two decisions of a vehicle (paper: 1, a decision every step)"""
    action_mask: bool = True
    """offer left/right only when the controller would accept them (choice, exploration, target max)"""
    double_dqn: bool = True
    """double DQN target: the online network picks the next action, the target network values it"""
    dueling: bool = True
    """dueling head: Q = V + A - mean(A) on top of Table II's FC 100 (paper: a plain 4-output layer)"""
    loss: str = "huber"
    """'mse' (paper eq. 8) or 'huber' (smooth L1, delta 1)"""
    lr: float = 1e-3
    """learning rate (paper: 0.01)"""
    optimizer: str = "adam"
    """'sgd' (paper: stochastic gradient descent) or 'adam'"""
    gamma: float = 0.9
    """discount per decision round (paper: 0.9 per 0.1 s step)"""
    n_step: int = 1
    """returns over n decision rounds of one vehicle, bootstrapped with gamma^n (agents/nstep; 1: the paper's)"""
    replay_size: int = 20_000
    """replay memory (transitions; paper: 2,000)"""
    batch_size: int = 64
    """minibatch size (transitions)"""
    learn_every: int = 1
    """decision rounds between two learning phases (paper setup: 4)"""
    updates_per_learn: int = 2
    """gradient updates in one learning phase (paper setup: 1)"""
    target_sync_steps: int = 2000
    """environment steps between target-network syncs (paper: 500). Default 2,000: the protocol
    (results/learner_protocol_f05q_ts2k10) measured it against 500"""
    epsilon_start: float = 0.1
    """exploration probability at the start (paper: 0.1, the greedy action with probability 0.9)"""
    epsilon_end: float = 0.1
    """exploration probability after epsilon_decay_steps"""
    epsilon_decay_steps: int = 0
    """environment steps of the linear decay from epsilon_start to epsilon_end (0: constant epsilon_start)"""
    learn_start_steps: int = 200
    """no update before this many environment steps"""
    grad_clip_norm: float = 10.0
    """gradient-norm clip"""
    speed_scale_mps: float = 110.0 / 3.6
    """speed errors are divided by this before entering the network (m/s)"""
    store_per_decision: int = 16
    """at most this many vehicles' transitions are stored per decision round (random subset)"""
    exit_transition: str = "drop"
    """a vehicle's last transition when it leaves the road: 'drop' it, or store it as 'terminal'"""
    restart_below_mps: float = 1.0
    """'none' is not offered to a vehicle slower than this (m/s): a standing vehicle that keeps its speed
    would stand for good and block its lane (0: off; paper: 'none' keeps any speed, zero included)"""
    change_margin: float = 1.0
    """when the trained model drives (evaluation, simulate, studies), a lane change is chosen only when its Q-value
    beats the best of speed-up and none by more than this (Q units; 0: plain argmax, the paper's). Training ignores it:
    the same seed gives the same weights whatever the margin"""
    observation: str = "v2x"
    """what the network reads: 'paper' (3 frames of the 3 x 20 m occupancy grid and the speed errors) or 'v2x'
    (those plus each side lane's nearest leader and follower within 200 m: gap and speed; see v2x_features).
    Default v2x: the learner protocol (results/learner_protocol_v2x*) measured it against the paper's state"""
    alpha_conditioned: bool = False
    """one network for every alpha: alpha is an input (log(1 + alpha) beside the speed errors), training draws it
    from conditioned_alphas for all vehicles every alpha_period_steps; it drives at any alpha (not in the paper)"""
    alpha_period_steps: int = 3000
    """conditioned training: environment steps between two draws of the shared alpha (3,000 = 5 simulated minutes)"""
    alpha_relabel: float = 0.5
    """conditioned training: share of each minibatch given another alpha of PAPER_ALPHAS, its reward recomputed from
    the stored lane changes (r = r_speed + r_flow - alpha x lane changes)"""
    alpha_draw_max: float = 48.0
    """conditioned training: the alphas drawn and relabelled to are those of PAPER_ALPHAS up to this one (48: all
    twelve, the paper's grid; 8: the eight up to scenario I's and II's largest, `conditioned8` of the learning study)"""
    select_every_steps: int = 15_000
    """model selection: every this many training steps (and at the last) the weights are validated greedily on
    held-out demand and model.pt is the best of them (agents/selection.py); 0: model.pt is the last weights (paper)"""
    validation_seed: int = VALIDATION_SEED
    """model selection: validation run i uses seed validation_seed + i (disjoint from training and study seeds)"""
    validation_t_ups: tuple[float, ...] = (2.0, 1.5, 1.0)
    """model selection: the free-flow demands T_up (s) of the validation runs, one run each"""
    validation_steps: int = 3000
    """model selection: steps of 0.1 s of each validation run"""
    validation_accident_steps: int = 6000
    """model selection: when > 0, each validation demand also gets a run of this many steps through an accident (held
    from 1/12 of the run for 5/6 of it), so that a snapshot that thrashes in a queue is not chosen; 0: free flow only
    (default 6,000: measured against free flow only in results/learner_protocol_accval)"""
    validation_queue: bool = False
    """model selection: the snapshots are validated with the queue rule (queue_below_mps) on, as the model will
    drive; False: without it, as training (not in the paper)"""
    validation_alphas: tuple[float, ...] = ()
    """model selection of an alpha-conditioned training: every validation run is driven at each of these alphas and
    the score is the mean over all; empty: at the training's own alpha (0 in the studies) alone"""
    train_t_ups: tuple[float, ...] = (2.0, 1.5, 1.0)
    """training demand: each episode's T_up (s) drawn from these (agents/episodes.py); empty: the run's own T_up
    (train --t-up T trains at T alone)"""
    accident_share: float = 0.5
    """training demand: the share of episodes with an accident (position, start and length drawn)"""
    episode_steps: int = 9000
    """training demand: steps of one episode when train_t_ups or accident_share is set (a fresh world each)"""
    weights_ema: float = 0.0
    """the weights that drive (validation snapshots, model.pt, model_last.pt) are an exponential moving average of
    the online network's, updated after every gradient update with this decay: average = d * average + (1 - d) *
    online (0: off, the online weights themselves, the paper's). Training itself is unchanged: the vehicles act
    and learn with the online network, so the same seed trains the same online weights with or without it"""
    followers_weight: float = 0.5
    """reward shaping for training (not in the paper): each step a vehicle's reward also gets this times the mean
    speed reward r_v of the vehicles behind it within followers_m in the lanes it occupies, so that slowing the
    traffic behind (a lane change into a queue, crawling) costs it; 0: the paper's reward. Model selection and
    every report score the paper's reward"""
    followers_m: float = 50.0
    """reward shaping: the window behind a vehicle whose followers' speed reward it shares (m)"""
    queue_below_mps: float = 5.0
    """when the trained model drives (evaluation, simulate, studies), no lane change is chosen by a vehicle slower
    than this (m/s; 0: none, the paper's): a change takes 4 s across both lanes, so one made where the traffic
    stands holds up two queues. Training and model selection ignore it (measured so: learner_protocol_followers05;
    dqn:PATH,queue=V replaces it)"""
    no_return_s: float = 10.0
    """when the trained model drives (and model selection, as it drives), for this many s after a vehicle's lane
    change the change back into the lane it left is not chosen (0: the paper's; dqn:PATH,noreturn=S replaces it)"""

    def validate(self) -> None:
        """Raise ConfigError naming the first bad value."""
        if problem := type_problem(self):  # read back from a file, a field may hold anything
            raise ConfigError(problem)
        positive_ints = ("decision_interval_steps", "replay_size", "batch_size", "learn_every", "updates_per_learn",
                         "target_sync_steps", "store_per_decision")  # fmt: skip
        for name in positive_ints:
            if getattr(self, name) <= 0:
                raise ConfigError(f"{name} must be positive, got {getattr(self, name)}")
        if self.replay_size > MAX_REPLAY:
            raise ConfigError(f"replay_size must be at most {MAX_REPLAY:,} (about 0.4 GB), got {self.replay_size}")
        if self.batch_size > self.replay_size:
            raise ConfigError(f"batch_size {self.batch_size} must be at most replay_size {self.replay_size} "
                              "(a larger batch never fills, so nothing would be learned)")  # fmt: skip
        for name in ("learn_start_steps", "epsilon_decay_steps"):
            if getattr(self, name) < 0:
                raise ConfigError(f"{name} must be >= 0, got {getattr(self, name)}")
        if not (math.isfinite(self.lr) and self.lr > 0):
            raise ConfigError(f"lr must be a positive number, got {self.lr}")
        if not 0 <= self.gamma < 1:
            raise ConfigError(f"gamma must be in [0, 1), got {self.gamma}")
        for name in ("epsilon_start", "epsilon_end"):
            if not 0 <= getattr(self, name) <= 1:
                raise ConfigError(f"{name} must be in [0, 1], got {getattr(self, name)}")
        if not (math.isfinite(self.restart_below_mps) and self.restart_below_mps >= 0):
            raise ConfigError(f"restart_below_mps must be a number >= 0, got {self.restart_below_mps}")
        if not (math.isfinite(self.grad_clip_norm) and self.grad_clip_norm > 0):
            raise ConfigError(f"grad_clip_norm must be a positive number, got {self.grad_clip_norm}")
        choices = {"loss": ("mse", "huber"), "optimizer": ("sgd", "adam"), "exit_transition": ("drop", "terminal"),
                   "preset": tuple(DQN_PRESETS), "observation": OBSERVATIONS}  # fmt: skip
        for name, allowed in choices.items():
            if getattr(self, name) not in allowed:
                raise ConfigError(f"{name} must be one of {', '.join(allowed)}, got {getattr(self, name)!r}")
        if problem := limits_problem(self, LEARNER_LIMITS):  # every number finite and bounded
            raise ConfigError(problem)
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


PAPER_DQN = DQNConfig(
    preset="paper", decision_interval_steps=1, action_mask=False, double_dqn=False, dueling=False, loss="mse",
    lr=0.01, optimizer="sgd", gamma=0.9, replay_size=2000, batch_size=64, learn_every=4, updates_per_learn=1,
    epsilon_start=0.1, epsilon_end=0.1, epsilon_decay_steps=0, restart_below_mps=0.0, change_margin=0.0,
    observation="paper", select_every_steps=0, validation_accident_steps=0, train_t_ups=(), accident_share=0.0,
    followers_weight=0.0, queue_below_mps=0.0, target_sync_steps=500, no_return_s=0.0,
)  # fmt: skip
"""The paper-literal learner: a decision every 0.1 s step, no mask, SGD 0.01, gamma 0.9, replay 2,000,
constant epsilon 0.1 (batch 64, one update every 4 steps: the paper is silent, as before)"""

ALPHA_ONLY_DQN = DQNConfig(preset="alpha_only", followers_weight=0.0, queue_below_mps=0.0, no_return_s=0.0,
                           change_margin=0.0, accident_share=0.0, validation_accident_steps=0)
"""Claim (a) as the paper poses it: the default's machinery with alpha its only cooperative mechanism (no followers'
term, queue rule, change-back rule or change margin), trained and chosen in free flow at scenario I's demands"""

DQN_PRESETS: dict[str, DQNConfig] = {"default": DQNConfig(), "paper": PAPER_DQN, "alpha_only": ALPHA_ONLY_DQN}
"""name -> learner configuration"""


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

    def validate(self) -> None:
        """Raise ConfigError naming the first bad value."""
        if problem := type_problem(self):
            raise ConfigError(problem)
        if not MIN_LANES <= self.road.lanes <= MAX_LANES:
            raise ConfigError(f"lanes must be between {MIN_LANES} and {MAX_LANES}, got {self.road.lanes}")
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
        if int_problem(self.full_read_every_steps, 1, MAX_STEPS):
            raise ConfigError(f"full_read_every_steps must be an integer from 1 to {MAX_STEPS}, "
                              f"got {self.full_read_every_steps}")  # fmt: skip


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


def validation_runs(dq: DQNConfig) -> int:
    """Validation runs per snapshot (seeds validation_seed + i): per demand, free flow and (when asked) an accident."""
    return len(dq.validation_t_ups) * (2 if dq.validation_accident_steps else 1)


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


def dqn_config_from_dict(d: dict[str, Any]) -> DQNConfig:
    """Inverse of to_dict for DQNConfig; a field it does not know is a ConfigError naming it.

    A dict written before presets existed (it has greedy_prob) describes the paper-literal learner.
    """
    d = dict(d)
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
    return _from_fields(DQNConfig, d, "learner")


def _from_fields(cls: Any, d: dict[str, Any], what: str) -> Any:
    """cls(**d); a field cls does not know is a ConfigError naming it (missing fields take their defaults)."""
    if not isinstance(d, dict):
        raise ConfigError(f"{what} settings are not a mapping: {d!r}")
    unknown = sorted(set(d) - {f.name for f in dataclasses.fields(cls)})
    if unknown:
        raise ConfigError(f"unknown {what} setting {unknown[0]!r} (written by a newer coopsumo?)")
    return cls(**d)


def to_dict(cfg: Any) -> dict[str, Any]:
    """A JSON-ready dict of a config dataclass."""
    return dataclasses.asdict(cfg)


SPEED_ONLY_FIELDS = frozenset({"full_read_every_steps"})
"""configuration fields that change how fast a run goes, never what it gives (recorded, ignored when a study
matches a stored run, cell or checkpoint to its configuration)"""


ADDED_FIELDS: dict[str, Any] = {"observation": "paper", "change_margin": 0.0, "alpha_conditioned": False,
                                 "alpha_period_steps": 3000, "alpha_relabel": 0.5, "alpha_draw_max": 48.0,
                                 "select_every_steps": 0, "validation_seed": VALIDATION_SEED,
                                 "validation_t_ups": [2.0, 1.5, 1.0], "validation_steps": 3000, "train_t_ups": [],
                                 "accident_share": 0.0, "episode_steps": 9000, "validation_accident_steps": 0,
                                 "followers_weight": 0.0, "followers_m": 50.0, "queue_below_mps": 0.0,
                                 "validation_queue": False, "weights_ema": 0.0, "n_step": 1, "validation_alphas": [],
                                 "no_return_s": 0.0}
"""fields added after results were stored, with the value a configuration without them means (dropped from
results_view at that value, so a stored run still matches the configuration it was made with)"""


def results_view(d: Any) -> Any:
    """A configuration as to_dict or JSON gives it, without SPEED_ONLY_FIELDS at any depth and without ADDED_FIELDS
    at their implied value: two runs whose views are equal give the same results (a run stored before such a
    field existed matches too)."""
    if isinstance(d, dict):
        return {k: results_view(v) for k, v in d.items()
                if k not in SPEED_ONLY_FIELDS and not (k in ADDED_FIELDS and v == ADDED_FIELDS[k])}  # fmt: skip
    if isinstance(d, list):
        return [results_view(v) for v in d]
    return d


def sim_config_from_dict(d: dict[str, Any]) -> SimConfig:
    """Inverse of to_dict for SimConfig; a missing or unknown field is a ConfigError naming it."""
    try:
        parts = {name: _from_fields(cls, d[name], name) for name, cls in (
            ("road", RoadConfig), ("demand", DemandConfig), ("control", ControlConfig), ("accident", AccidentConfig),
            ("reward", RewardConfig))}  # fmt: skip
        return SimConfig(**parts, steps=d["steps"], seed=d["seed"], policy=d["policy"],
                         time_to_teleport_s=d["time_to_teleport_s"],
                         sumo_collision_check=d.get("sumo_collision_check", False),
                         full_read_every_steps=d.get("full_read_every_steps", SimConfig.full_read_every_steps))
    except KeyError as err:
        raise ConfigError(f"simulation configuration has no {err.args[0]!r} (written by another coopsumo?)") from None
