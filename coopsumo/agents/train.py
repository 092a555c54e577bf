"""`python -m coopsumo.train`: train the shared lane-changing DQN in free flow (scenario II).

Every vehicle is an agent; all share one network and one replay memory. Writes into --out:
config.json, train_log.csv (one row per logging window), model.pt, and the greedy
evaluation's summary.json (its SUMO files in eval/). Ctrl-C or SIGTERM saves
checkpoint.pt and exits; --resume continues it exactly (the world is rebuilt by replaying
the recorded actions, then the learner's saved state takes over). An existing non-empty --out is used
only if this command wrote it (its .coopsumo-run.json, runio.check_run_dir).

--alpha-conditioned trains one network for every alpha: alpha is an input, and all vehicles share one alpha
drawn from the paper's grid every alpha_period_steps (training_alpha); the world's own reward alpha is 0 and
the trainer charges the drawn alpha per lane change started.
"""

from __future__ import annotations

import argparse
import csv
import functools
import json
import shutil
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from coopsumo.agents import selection
from coopsumo.agents.decisions import ActionHold, offered
from coopsumo.agents.dqn import N_ACTIONS, Learner, save_model
from coopsumo.agents.dqn_policy import DQNPolicy
from coopsumo.agents.episodes import episode_bounds, episode_config, episodic
from coopsumo.agents.file_checks import checkpoint_problem, ended_training, prepare_resume
from coopsumo.agents.tb_log import TensorBoardFlag, open_log
from coopsumo.config import (
    DQN_PRESETS,
    MAX_LANES,
    MIN_LANES,
    OBSERVATIONS,
    PAPER_ALPHAS,
    ConfigError,
    ControlConfig,
    DemandConfig,
    DQNConfig,
    RewardConfig,
    RoadConfig,
    SimConfig,
    TrainConfig,
    results_view,
    to_dict,
    train_config_from_dict,
)
from coopsumo.runio import (
    Parser,
    UsageError,
    check_out_path,
    check_run_dir,
    discard_run_dir,
    finish_run_dir,
    finished_run,
    first_line,
    mark_run_dir,
    out_lock,
    retrain_folder,
    run_cli,
    versions,
    write_atomic,
    write_json,
)
from coopsumo.sim.observation import Observation, network_features
from coopsumo.sim.world import StepOutcome, World
from coopsumo.validation import MAX_STEPS, alpha, check_t_up, integer, number, out_dir, seed, steps, t_up_list

LOG_FIELDS = (
    "step", "sim_time_s", "td_loss", "r_speed", "r_lane_change", "r_flow", "reward", "epsilon",
    "mean_speed_mps", "vehicles", "lane_changes", "lane_changes_rejected", "collisions", "teleports", "wall_s",
    "alpha",
)  # fmt: skip
"""train_log.csv's columns; alpha: the reward's alpha at the window's last step (drawn, when conditioned)"""

ALPHA_STREAM = 0x414C5048
"""random stream of a conditioned training's alpha draws (with the seed and the period's index)"""


def training_alpha(seed: int, step: int, period_steps: int) -> float:
    """The alpha all vehicles share at training step `step` of a conditioned training: one of PAPER_ALPHAS, drawn
    uniformly and afresh every period_steps, a pure function of (seed, step // period_steps) so a resume
    replays it exactly."""
    return _alpha_draw(seed, step // period_steps)


@functools.lru_cache(maxsize=256)
def _alpha_draw(seed: int, period: int) -> float:
    """The alpha of period `period` of a conditioned training seeded `seed` (training_alpha)."""
    return float(PAPER_ALPHAS[np.random.default_rng([seed, ALPHA_STREAM, period]).integers(len(PAPER_ALPHAS))])


CHECKPOINT_KEYS = ("config", "step", "learner", "action_counts", "actions", "window")
"""what every checkpoint.pt holds"""


class ResumeDiverged(RuntimeError):
    """Replaying a checkpoint's recorded actions did not rebuild the same world."""


class Interrupted(Exception):
    """Training stopped by a signal after saving a checkpoint."""

    def __init__(self, signum: int, step: int):
        super().__init__(f"interrupted at step {step}")
        self.signum = signum
        self.step = step


@dataclass
class Window:
    """Sums over one logging window."""

    loss: list[float] = field(default_factory=list)
    r_speed: float = 0.0
    r_lane_change: float = 0.0
    r_flow: float = 0.0
    samples: int = 0
    speed_sum: float = 0.0
    vehicle_steps: int = 0
    lane_changes: int = 0
    rejected: int = 0

    def add(self, out: StepOutcome, speeds: np.ndarray, lane_change_penalty: np.ndarray) -> None:
        """One step: its outcome, the speeds on the road (m/s), and the lane-change reward the learner got."""
        self.r_speed += float(out.reward.speed.sum())
        self.r_lane_change += float(lane_change_penalty.sum())
        self.r_flow += float(out.reward.flow.sum())
        self.samples += len(out.nums)
        self.speed_sum += float(speeds.sum())
        self.vehicle_steps += len(speeds)
        self.lane_changes += int(out.lane_change_started.sum())
        self.rejected += int(out.rejected.sum())


def transitions(
    prev: Observation,
    prev_features: np.ndarray,
    actions: np.ndarray,
    reward_sum: np.ndarray,
    arrived: np.ndarray,
    now: Observation,
    now_features: np.ndarray,
    exit_transition: str,
    prev_mask: np.ndarray,
    now_mask: np.ndarray,
    change_sum: np.ndarray,
) -> tuple[np.ndarray, ...]:
    """(grids, features, actions, rewards, next_grids, next_features, dones, next_mask, lane_changes) of the last
    interval.

    prev: the last decision round's observation, its network features (observation.network_features) and its
    `actions`; now: this round's observation and features;
    prev_mask, now_mask: the actions offered in them (decisions.offered; all True when nothing is withheld).
    reward_sum, change_sum: rewards and lane changes started over the interval, indexed by vehicle number;
    arrived: numbers of the
    vehicles that left the road during it. Vehicles present in both rounds give ordinary transitions;
    vehicles that left are dropped or stored as terminal (next state = last state, masked by done).
    """
    _, i_prev, i_now = np.intersect1d(prev.nums, now.nums, assume_unique=True, return_indices=True)
    reward = reward_sum[prev.nums]
    changes = change_sum[prev.nums]
    g, e = prev.grids[i_prev], prev_features[i_prev]
    ng, ne = now.grids[i_now], now_features[i_now]
    a, r, c = actions[i_prev], reward[i_prev], changes[i_prev]
    nm = now_mask[i_now]
    done = np.zeros(len(i_prev), np.float32)
    gone_rows = np.isin(prev.nums, arrived)
    if exit_transition == "terminal" and gone_rows.any():
        gone = np.flatnonzero(gone_rows)
        g, e = np.concatenate([g, prev.grids[gone]]), np.concatenate([e, prev_features[gone]])
        ng, ne = np.concatenate([ng, prev.grids[gone]]), np.concatenate([ne, prev_features[gone]])
        a, r = np.concatenate([a, actions[gone]]), np.concatenate([r, reward[gone]])
        c = np.concatenate([c, changes[gone]])
        nm = np.concatenate([nm, prev_mask[gone]])
        done = np.concatenate([done, np.ones(len(gone), np.float32)])
    return g, e, a, r.astype(np.float32), ng, ne, done, nm, c.astype(np.float32)


def _all_if_none(mask: np.ndarray | None, obs: Observation) -> np.ndarray:
    """mask, or every action offered to every vehicle of obs when it is None."""
    return np.ones((len(obs), N_ACTIONS), bool) if mask is None else mask


@dataclass
class Pending:
    """What the trainer carries between decision rounds (rebuilt by replay on resume)."""

    prev: Observation | None = None
    """the last decision round's observation"""
    prev_features: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.float32))
    """its network features (observation.network_features)"""
    prev_actions: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """the actions decided then"""
    reward_sum: np.ndarray = field(default_factory=lambda: np.zeros(1024))
    """rewards since each vehicle's last decision, by vehicle number"""
    change_sum: np.ndarray = field(default_factory=lambda: np.zeros(1024))
    """lane changes started since each vehicle's last decision, by vehicle number"""
    prev_alpha: float = 0.0
    """the alpha of the last decision round (a conditioned training's draw)"""
    arrived: list[np.ndarray] = field(default_factory=list)
    """numbers of vehicles that left the road since the last decision round"""

    def _grow(self, nums: np.ndarray) -> None:
        if len(nums) and int(nums.max()) >= len(self.reward_sum):
            extra = max(int(nums.max()) + 1, 2 * len(self.reward_sum)) - len(self.reward_sum)
            self.reward_sum = np.concatenate([self.reward_sum, np.zeros(extra)])
            self.change_sum = np.concatenate([self.change_sum, np.zeros(extra)])

    def start_interval(self, obs: Observation, features: np.ndarray, actions: np.ndarray, alpha: float) -> None:
        """A decision round at `alpha`: remember it and zero the sums of the vehicles that decided."""
        self._grow(obs.nums)
        self.reward_sum[obs.nums] = 0.0
        self.change_sum[obs.nums] = 0.0
        self.prev, self.prev_features, self.prev_actions, self.arrived = obs, features, actions, []
        self.prev_alpha = alpha

    def add_rewards(self, nums: np.ndarray, rewards: np.ndarray, changes: np.ndarray) -> None:
        self._grow(nums)
        self.reward_sum[nums] += rewards
        self.change_sum[nums] += changes


class Trainer:
    """The training loop, its log, checkpoints and resume."""

    def __init__(self, cfg: TrainConfig, out: Path, progress: bool = True,
                 on_steps: Callable[[int], None] | None = None):  # fmt: skip
        cfg.validate()
        self.on_steps = on_steps
        self.cfg = cfg
        self.out = out
        self.progress = progress
        self.learner = Learner(cfg.dqn, cfg.sim.seed)
        self.hold = ActionHold(cfg.dqn.decision_interval_steps)
        self.pending = Pending()
        self.step = 0
        self.action_log: list[np.ndarray] = []
        self.window = Window()
        self._stop_signal: int | None = None
        self.on_row: Callable[[dict[str, Any]], None] | None = None  # each train_log.csv row, by column (tb_log)
        self.validator: selection.Validator | None = None  # model selection (DQNConfig.select_every_steps)
        self.episode_start = 0  # training step of the current world's first step (agents/episodes.py)
        self._reported = 0

    # -- checkpoints -----------------------------------------------------------------------
    def checkpoint_path(self) -> Path:
        return self.out / "checkpoint.pt"

    def save_checkpoint(self) -> None:
        counts = np.array([len(a) for a in self.action_log], np.int64)
        flat = np.concatenate(self.action_log) if self.action_log else np.zeros(0, np.int64)
        state = {
            "config": to_dict(self.cfg),
            "step": self.step,
            "learner": self.learner.state_dict(),
            "action_counts": torch.from_numpy(counts),
            "actions": torch.from_numpy(flat.astype(np.int8)),
            "window": {k: v for k, v in vars(self.window).items()},
        }
        write_atomic(self.checkpoint_path(), lambda tmp: torch.save(state, tmp))  # no checkpoint.pt.tmp left behind

    @staticmethod
    def load_checkpoint(out: Path) -> dict[str, Any]:
        path = out / "checkpoint.pt"
        if not path.exists():
            done = "; the training there has finished" if finished_run(out, "train") else ""
            raise UsageError(f"nothing to resume: {path} does not exist{done}")
        try:
            state: dict[str, Any] = torch.load(path, weights_only=True)
        except Exception as err:  # a damaged file (empty, cut short, not torch's): report it in one line
            raise UsageError(f"cannot read checkpoint {path}: {first_line(err)}") from None
        if not isinstance(state, dict) or any(k not in state for k in CHECKPOINT_KEYS):
            raise UsageError(f"{path} is not a coopsumo training checkpoint")
        learner = state["learner"] if isinstance(state["learner"], dict) else {}
        dqn = state["config"].get("dqn") if isinstance(state["config"], dict) else None
        if (isinstance(dqn, dict) and "greedy_prob" in dqn) or "decisions" not in learner:
            raise UsageError(f"checkpoint {path} was written by a coopsumo before learner presets and cannot be "
                             "resumed exactly; train again without --resume")  # fmt: skip
        if problem := checkpoint_problem(state):  # types and ranges (file_checks)
            raise UsageError(f"checkpoint {path} {problem}; train again without --resume")
        return state

    @staticmethod
    def checkpoint_config(out: Path, state: dict[str, Any]) -> TrainConfig:
        """The checkpoint's training configuration; UsageError naming what does not fit this version."""
        try:
            cfg = train_config_from_dict(state["config"])
            cfg.validate()
            if state["step"] > cfg.sim.steps:
                raise ConfigError(f"step {state['step']} lies beyond the run's {cfg.sim.steps} steps")
        except ConfigError as err:
            raise UsageError(f"checkpoint {out / 'checkpoint.pt'}: {err}") from None
        return cfg

    def restore(self, state: dict[str, Any]) -> None:
        self.learner.load_state_dict(state["learner"])
        self.step = int(state["step"])
        counts = state["action_counts"].numpy()
        flat = state["actions"].numpy().astype(np.int64)
        self.action_log = list(np.split(flat, np.cumsum(counts)[:-1])) if len(counts) else []
        self.window = Window(**state["window"])
        prepare_resume(self.out, self.step)  # log rows past the checkpoint dropped, cut-short writes removed

    # -- the loop ----------------------------------------------------------------------------
    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        self._stop_signal = signum

    def run(self) -> None:
        """Train up to cfg.sim.steps; raises Interrupted after checkpointing on SIGINT/SIGTERM."""
        cfg = self.cfg
        old = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            self._loop(cfg)
        finally:
            for s, h in old.items():
                signal.signal(s, h)

    def _offered(self, obs: Observation) -> np.ndarray | None:
        """The actions offered to each vehicle of obs (decisions.offered); None: all of them."""
        dq = self.cfg.dqn
        return offered(obs.feasible, obs.speed, dq.action_mask, dq.restart_below_mps)

    def alpha_at(self, step: int) -> float:
        """The reward's alpha at training step `step`: drawn (training_alpha) when conditioned, else the run's."""
        if self.cfg.dqn.alpha_conditioned:
            return training_alpha(self.cfg.sim.seed, step, self.cfg.dqn.alpha_period_steps)
        return self.cfg.sim.reward.alpha

    def _advance(self, world: World, recorded: np.ndarray | None = None) -> tuple[StepOutcome, np.ndarray]:
        """One environment step; on a decision round, store the last interval's transitions and decide.

        recorded: the actions this step took in the run being resumed (replay: no learning, same
        bookkeeping). Returns the step's outcome and the lane-change reward each vehicle got (-alpha per change
        started; a conditioned training charges its drawn alpha, the world's alpha being 0).
        """
        dq = self.cfg.dqn
        learner = self.learner
        pend = self.pending
        alpha = self.alpha_at(self.episode_start + world.step_count)
        decide = self.hold.is_decision_step(world.step_count)
        obs = world.observe(grids=decide)
        decided = None
        if decide:
            feats = network_features(obs, dq.observation, dq.speed_scale_mps)
            mask = self._offered(obs)
            if recorded is None and pend.prev is not None:
                arrived = np.concatenate(pend.arrived) if pend.arrived else np.zeros(0, np.int64)
                prev_mask = self._offered(pend.prev)
                batch = transitions(pend.prev, pend.prev_features, pend.prev_actions, pend.reward_sum, arrived, obs,
                                    feats, dq.exit_transition, _all_if_none(prev_mask, pend.prev),
                                    _all_if_none(mask, obs), pend.change_sum)  # fmt: skip
                n = len(batch[0])
                if n:
                    keep = learner.rng.permutation(n)[: dq.store_per_decision]
                    grids, err, acts, rews, ngrids, nerr, dones, nmask, changes = (x[keep] for x in batch)
                    alphas = np.full(len(keep), pend.prev_alpha, np.float32) if dq.alpha_conditioned else None
                    learner.observe(grids, err, acts, rews, ngrids, nerr, dones, None if mask is None else nmask,
                                    alphas, changes if dq.alpha_conditioned else None)  # fmt: skip
            if recorded is None:
                own = np.full(len(obs), alpha, np.float32) if dq.alpha_conditioned else None
                decided = learner.act(obs.grids, feats, explore=True, mask=mask, alphas=own)
            else:
                decided = recorded
            pend.start_interval(obs, feats, decided, alpha)
        actions = self.hold.actions(obs.nums, decided)
        if recorded is not None and not np.array_equal(actions, recorded):
            raise ResumeDiverged(f"the replay of its recorded actions diverged at step {world.step_count}")
        out = world.apply(actions)
        started = out.lane_change_started.astype(np.float64)
        if dq.alpha_conditioned:  # the world's alpha is 0 (TrainConfig.validate): charge the drawn one
            penalty = -alpha * started
            pend.add_rewards(out.nums, out.reward.total + penalty, started)
        else:
            penalty = out.reward.lane_change
            pend.add_rewards(out.nums, out.reward.total, started)
        if out.arrived.any():
            pend.arrived.append(out.nums[out.arrived])
        if recorded is None:
            self.action_log.append(actions.astype(np.int8))
        return out, penalty

    def _loop(self, cfg: TrainConfig) -> None:
        log_path = self.out / "train_log.csv"
        new_log = self.step == 0 or not log_path.exists()
        if new_log:
            with log_path.open("w", newline="") as f:
                csv.writer(f).writerow(LOG_FIELDS)
        start = time.perf_counter()
        (self.out / "sumo").mkdir(parents=True, exist_ok=True)
        bar = tqdm(total=cfg.sim.steps, initial=self.step, desc="train", unit="step",
                   disable=not self.progress, mininterval=0.5, file=sys.stderr)  # fmt: skip
        self._reported = self.step  # steps already told to the bar and to on_steps
        with log_path.open("a", newline="") as log_file:
            log = csv.writer(log_file)
            while True:  # one episode (agents/episodes.py), or one world for the whole run
                index, first, end = episode_bounds(cfg.sim.steps, cfg.dqn, self.step)
                sim = episode_config(cfg.sim, cfg.dqn, index) if episodic(cfg.dqn) else cfg.sim
                with World(sim, self.out / "sumo") as world:
                    if first > 0 or self.step > 0:  # a new world: nothing carries over from the last one
                        self.pending, self.hold = Pending(), ActionHold(cfg.dqn.decision_interval_steps)
                    self.episode_start = first
                    replay = self.action_log[first : self.step]
                    for recorded in tqdm(replay, desc="replaying to resume", disable=not self.progress or not replay,
                                         unit="step", mininterval=0.5, file=sys.stderr):  # fmt: skip
                        self._advance(world, recorded.astype(np.int64))
                    self._episode(cfg, world, end, log, log_file, bar, start)
                    self.world_summary = world.summary()
                if self.step >= cfg.sim.steps:
                    break
        bar.close()

    def _episode(self, cfg: TrainConfig, world: World, end: int, log: Any, log_file: Any, bar: Any,
                 start: float) -> None:  # fmt: skip
        """Train in `world` up to training step `end`."""
        learner = self.learner
        while self.step < end:
            if self._stop_signal is not None:
                self.save_checkpoint()
                bar.close()
                raise Interrupted(self._stop_signal, self.step)
            decided = self.hold.is_decision_step(world.step_count)
            out, penalty = self._advance(world)
            loss = learner.step(decided)
            self.step += 1
            if self.validator is not None:
                self.validator.after_step(self.step, learner.online)
            w = self.window
            if loss is not None:
                w.loss.append(loss)
            w.add(out, world.table.speed, penalty)
            if self.step % cfg.log_every_steps == 0 or self.step == cfg.sim.steps:
                self._write_row(log, world, time.perf_counter() - start)
                log_file.flush()
                if self.on_steps is not None:
                    self.on_steps(self.step - self._reported)
                bar.update(self.step - self._reported)
                self._reported = self.step
                bar.set_postfix(v=f"{w.speed_sum / max(w.vehicle_steps, 1):.1f}",
                                r=f"{(w.r_speed + w.r_lane_change + w.r_flow) / max(w.samples, 1):.3f}",
                                lc=f"{w.lane_changes / max(w.samples, 1) * 10:.3f}/s")  # fmt: skip
                self.window = Window()
            if cfg.checkpoint_every_steps and self.step % cfg.checkpoint_every_steps == 0:
                self.save_checkpoint()

    def _write_row(self, log: Any, world: World, wall_s: float) -> None:
        w = self.window
        n = max(w.samples, 1)
        tot = world.totals
        row = [
            self.step, round(world.time_s, 1),
            float(np.mean(w.loss)) if w.loss else "",
            w.r_speed / n, w.r_lane_change / n, w.r_flow / n, (w.r_speed + w.r_lane_change + w.r_flow) / n,
            self.learner.epsilon,
            w.speed_sum / max(w.vehicle_steps, 1), len(world.table.nums),
            w.lane_changes, w.rejected, tot.collisions, tot.teleports, round(wall_s, 2),
            self.alpha_at(max(self.step - 1, 0)),
        ]  # fmt: skip
        log.writerow([f"{x:.6g}" if isinstance(x, float) else x for x in row])
        if self.on_row is not None:
            self.on_row(dict(zip(LOG_FIELDS, row, strict=True)))


def model_meta(cfg: TrainConfig) -> dict[str, Any]:
    return {"config": to_dict(cfg), "versions": versions()}


def evaluate(
    cfg: TrainConfig,
    policy: DQNPolicy,
    out: Path,
    progress: bool,
    on_steps: Callable[[int], None] | None = None,
    shown: Path | None = None,
) -> dict[str, Any]:
    """Greedy evaluation on the training condition (same demand seed) in out/eval; a conditioned model drives at
    the policy's alpha (train: the run's reward alpha, 0). shown: the run folder its records name (default out)."""
    from coopsumo.agents.rollout import run

    eval_dir = out / "eval"
    eval_dir.mkdir(exist_ok=True)
    spec = f"dqn:{(shown or out) / 'model.pt'}" + (f",alpha={policy.alpha:g}" if policy.alpha is not None else "")
    sim = replace(cfg.sim, steps=cfg.eval_steps, policy=spec)
    return run(sim, policy, eval_dir, progress=progress, label="evaluate", on_steps=on_steps)


def train(
    cfg: TrainConfig,
    out: Path,
    resume: bool = False,
    progress: bool = True,
    on_steps: Callable[[int], None] | None = None,
    tensorboard: bool = False,
    final: Path | None = None,
) -> dict[str, Any]:
    """Train (or resume) into `out`; returns the evaluation summary (or the training summary).

    final: the folder the results will be moved to, when `out` is a working folder (recorded paths name it).

    on_steps(n) is told of progress (training and evaluation steps), for a caller's progress bar;
    tensorboard: also write the log's scalars to out/tensorboard/ (tb_log).
    """
    trainer = Trainer(cfg, out, progress, on_steps)
    out.mkdir(parents=True, exist_ok=True)
    if resume:
        check_recorded_config(out, cfg)
        try:
            trainer.restore(Trainer.load_checkpoint(out))
        except (RuntimeError, KeyError, ValueError, TypeError) as err:  # weights, buffer or RNG of another shape
            text = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            raise UsageError(f"checkpoint {trainer.checkpoint_path()} does not fit its configuration: {text}") from None
    else:
        mark_run_dir(out, "train", finished=False)
        write_json(out / "config.json", model_meta(cfg))
        for stale in ("model.pt", "summary.json", "checkpoint.pt", "train_summary.json", selection.LAST_MODEL,
                      "validation.csv"):
            (out / stale).unlink(missing_ok=True)
        shutil.rmtree(out / selection.SNAPSHOTS, ignore_errors=True)
        trainer.save_checkpoint()  # step 0: from here on, an interrupted run always has a checkpoint to resume
    ended = ended_training(out, trainer.step, cfg.sim.steps) if resume else None  # interrupted in its evaluation
    scalars = open_log(out, tensorboard, resume, trainer.step)
    trainer.on_row = None if scalars is None else scalars.add_row
    if selection.selecting(cfg) and ended is None:
        trainer.validator = selection.Validator(out, cfg, trainer.step)
    start = time.perf_counter()
    try:
        if ended is None:
            trainer.run()
            if trainer.validator is not None:
                trainer.validator.finish()
    except ResumeDiverged as err:
        raise UsageError(f"checkpoint {trainer.checkpoint_path()} (another coopsumo or SUMO version?): {err}; "
                         "train again without --resume") from None  # fmt: skip
    finally:
        if scalars is not None:
            scalars.close()
        if trainer.validator is not None:
            trainer.validator.close()
    wall = time.perf_counter() - start
    if ended is None:
        trainer.save_checkpoint()  # the last step's, kept until the evaluation is written: a resume evaluates again
    chosen = None
    if selection.selecting(cfg):  # model.pt: the best validated snapshot; the last weights beside it
        save_model(out / selection.LAST_MODEL, trainer.learner.online, model_meta(cfg))
        chosen = selection.install_best(out)
        selection.write_table(out)
    if chosen is None:
        save_model(out / "model.pt", trainer.learner.online, model_meta(cfg))
    train_summary = ended or dict(trainer.world_summary, wall_seconds=round(wall, 2),
                                  steps_per_second=round(cfg.sim.steps / wall, 1),
                                  updates=trainer.learner.updates)  # fmt: skip
    if chosen is not None:
        train_summary = dict(train_summary, selected_step=chosen["step"], selected_score=chosen["score"],
                             last_score=selection.results(out)[-1]["score"])  # fmt: skip
        if trainer.progress:
            print(f"train: model.pt is the weights of step {chosen['step']:,} (validation score "
                  f"{chosen['score']:.4f}; last weights {train_summary['last_score']:.4f}, in {selection.LAST_MODEL})",
                  file=sys.stderr)  # fmt: skip
    write_json(out / "train_summary.json", train_summary)
    if cfg.eval_steps == 0:
        trainer.checkpoint_path().unlink(missing_ok=True)
        mark_run_dir(out, "train")
        return train_summary
    net = trainer.learner.online
    if chosen is not None:
        net = DQNPolicy.from_file(str(out / "model.pt")).net
    policy = DQNPolicy(net, decision_interval=cfg.dqn.decision_interval_steps,
                       action_mask=cfg.dqn.action_mask, restart_below_mps=cfg.dqn.restart_below_mps,
                       change_margin=cfg.dqn.change_margin,
                       alpha=cfg.sim.reward.alpha if cfg.dqn.alpha_conditioned else None)  # fmt: skip
    shutil.rmtree(out / "eval", ignore_errors=True)  # what an interrupted evaluation had written
    try:
        summary = evaluate(cfg, policy, out, progress, on_steps, shown=final)
    except KeyboardInterrupt:
        raise Interrupted(signal.SIGINT, trainer.step) from None
    write_json(out / "summary.json", summary)
    trainer.checkpoint_path().unlink(missing_ok=True)
    mark_run_dir(out, "train")
    return summary


def training_folder(out: Path, resume: bool, progress: bool = True) -> Path:
    """The folder a training into `out` works in: `out` itself, or, when `out` holds a finished training, a
    folder beside it (retrain_folder) that replaces `out` only once the new training has finished, so that a
    kill or a failure never loses the finished one. --resume continues whichever holds a checkpoint."""
    work = retrain_folder(out.resolve())
    if resume:
        return work if (work / "checkpoint.pt").exists() else out
    if work.exists():
        discard_run_dir(work)  # an earlier new training, killed: this one starts afresh
    if not finished_run(out, "train"):
        return out
    if progress:
        print(f"train: {out} holds a finished training; the new one is built in {work} and replaces it when it "
              "has finished", file=sys.stderr)  # fmt: skip
    return work


def check_recorded_config(out: Path, cfg: TrainConfig) -> None:
    """Before a resume: the folder's config.json must record the checkpoint's configuration (a checkpoint copied in
    from another training is refused in one line); a missing config.json is written again."""
    path = out / "config.json"
    try:
        recorded = json.loads(path.read_text())["config"]
    except FileNotFoundError:
        write_json(path, model_meta(cfg))
        return
    except (OSError, ValueError, KeyError, TypeError):
        raise UsageError(f"{path} is unreadable or not a training's configuration; train again without "
                         "--resume") from None
    view = results_view(json.loads(json.dumps(to_dict(cfg))))
    if results_view(recorded) != view:
        differ = sorted(k for k in set(view) | set(recorded) if results_view(recorded.get(k)) != view.get(k))
        raise UsageError(f"checkpoint {out / 'checkpoint.pt'} is another training's than {path} records (they differ "
                         f"in {', '.join(differ)}): copied in?; train again without --resume")  # fmt: skip


def default_out(cfg: TrainConfig) -> Path:
    s = cfg.sim
    alpha = "cond" if cfg.dqn.alpha_conditioned else f"{s.reward.alpha:g}"
    return Path("results") / "train" / f"lanes{s.road.lanes}_alpha{alpha}_tup{s.demand.t_up_s:g}_seed{s.seed}"


LEARNER_FLAGS: tuple[tuple[str, str, Any, str], ...] = (
    ("--decision-interval", "decision_interval_steps", int,
     "steps of 0.1 s between a vehicle's decisions (paper: 1); a lane change starts on the decision step, "
     "then the vehicle asks to speed up; rewards of the interval are summed into one transition"),
    ("--action-mask", "action_mask", bool, "offer left/right only when the controller would accept them"),
    ("--double-dqn", "double_dqn", bool, "double DQN target"),
    ("--dueling", "dueling", bool, "dueling Q head (value + advantages)"),
    ("--loss", "loss", ("mse", "huber"), "TD loss (paper: mse)"),
    ("--lr", "lr", float, "learning rate"),
    ("--optimizer", "optimizer", ("sgd", "adam"), "optimizer (paper: sgd)"),
    ("--gamma", "gamma", float, "discount per decision round (paper: 0.9 per 0.1 s step)"),
    ("--replay-size", "replay_size", int, "replay memory (transitions)"),
    ("--batch-size", "batch_size", int, "minibatch (transitions)"),
    ("--learn-every", "learn_every", int, "decision rounds between learning phases"),
    ("--updates-per-decision", "updates_per_learn", int, "gradient updates per learning phase"),
    ("--store-per-decision", "store_per_decision", int, "transitions stored per decision round (random subset)"),
    ("--target-sync", "target_sync_steps", int, "steps of 0.1 s between target-network syncs"),
    ("--epsilon-start", "epsilon_start", float, "exploration probability at the start"),
    ("--epsilon-end", "epsilon_end", float, "exploration probability after the decay"),
    ("--epsilon-decay-steps", "epsilon_decay_steps", int, "steps of the linear epsilon decay (0: constant)"),
    ("--restart-below", "restart_below_mps", float, "'none' is not offered below this speed (m/s; 0: off)"),
    ("--change-margin", "change_margin", float,
     "when the model drives, a lane change is chosen only when its Q-value beats staying by more than this "
     "(0: plain argmax); training ignores it"),
    ("--alpha-conditioned", "alpha_conditioned", bool,
     "one network for every alpha: alpha is an input, drawn from the paper's 12 values for all vehicles every "
     "--alpha-period steps; drive it with --policy dqn:PATH,alpha=A (not with --alpha)"),
    ("--alpha-period", "alpha_period_steps", int, "conditioned training: steps of 0.1 s between two alpha draws"),
    ("--alpha-relabel", "alpha_relabel", float,
     "conditioned training: share of each minibatch learned at another alpha (reward recomputed)"),
    ("--select-every", "select_every_steps", int,
     "model selection: every this many steps (and at the last) validate the weights greedily on held-out free-flow "
     "demand; model.pt is the best, model_last.pt the last weights (0: model.pt is the last weights, the paper's)"),
    ("--validation-seed", "validation_seed", int,
     "model selection: validation run i uses seed VALIDATION_SEED + i (must not meet the training seed)"),
    ("--validation-t-up", "validation_t_ups", str, "model selection: comma-separated demands T_up (s), one run each"),
    ("--validation-steps", "validation_steps", int, "model selection: steps of 0.1 s of each validation run"),
    ("--train-t-up", "train_t_ups", str,
     "training demand: comma-separated T_up (s); each episode of --episode-steps draws one (empty: --t-up "
     "throughout)"),
    ("--accident-share", "accident_share", float,
     "training demand: share of episodes (0-1) with an accident whose position, start and length are drawn"),
    ("--episode-steps", "episode_steps", int, "training demand: steps of one episode (a fresh world each)"),
    ("--observation", "observation", OBSERVATIONS,
     "what the network reads: 'paper' (3 x 20 m occupancy grids and speed errors) or 'v2x' (those plus each "
     "side lane's nearest leader and follower within 200 m: gap and speed)"),
)  # fmt: skip
"""(flag, DQNConfig field, type or choices, help); every flag defaults to the chosen preset's value"""


def add_learner_flags(p: Parser) -> None:
    """--preset and one flag per learner setting (unset flags keep the preset's value)."""
    p.add_argument("--preset", choices=tuple(DQN_PRESETS), default="default",
                   help="learner preset: 'default' (the project's measured design) or 'paper' (literal)")  # fmt: skip
    for flag, name, kind, text in LEARNER_FLAGS:
        default = getattr(DQNConfig(), name)
        help_text = f"{text} (default preset: {default})"
        if kind is bool:
            p.add_argument(flag, dest=name, action=argparse.BooleanOptionalAction, default=None, help=help_text)
        elif isinstance(kind, tuple):
            p.add_argument(flag, dest=name, choices=kind, default=None, help=help_text)
        else:
            p.add_argument(flag, dest=name, type=kind, default=None, help=help_text)


def flag_value(flag: str, name: str, value: Any) -> Any:
    """A learner flag's value as DQNConfig holds it (a list flag's text parsed)."""
    if name in ("validation_t_ups", "train_t_ups") and isinstance(value, str):
        return t_up_list(flag, value, ControlConfig().dt_s)
    return value


FLAG_NEEDS: dict[str, tuple[str, Callable[[DQNConfig], bool]]] = {
    "--alpha-period": ("--alpha-conditioned", lambda c: c.alpha_conditioned),
    "--alpha-relabel": ("--alpha-conditioned", lambda c: c.alpha_conditioned),
    "--validation-seed": ("--select-every N (N > 0)", lambda c: c.select_every_steps > 0),
    "--validation-t-up": ("--select-every N (N > 0)", lambda c: c.select_every_steps > 0),
    "--validation-steps": ("--select-every N (N > 0)", lambda c: c.select_every_steps > 0),
    "--episode-steps": ("--train-t-up or --accident-share", lambda c: bool(c.train_t_ups) or c.accident_share > 0),
}
"""learner flags that act only beside another setting: given without it, they are refused (not silently ignored)"""


def learner_from_args(args: Any) -> DQNConfig:
    """The preset with every given learner flag applied; a bad value is a usage error naming the flag, and so is a
    flag that would do nothing without another (FLAG_NEEDS)."""
    cfg = DQN_PRESETS[args.preset]
    given = [flag for flag, name, _, _ in LEARNER_FLAGS if getattr(args, name) is not None]
    for flag, name, _, _ in LEARNER_FLAGS:
        value = flag_value(flag, name, getattr(args, name))
        if value is None:
            continue
        cfg = replace(cfg, **{name: value})
        try:
            cfg.validate()  # the fields set before were valid: an error here is this flag's
        except ConfigError as err:
            raise UsageError(f"{flag}: {err}") from None
    cfg.validate()
    for flag in given:
        if flag in FLAG_NEEDS and not FLAG_NEEDS[flag][1](cfg):
            raise UsageError(f"{flag} acts only with {FLAG_NEEDS[flag][0]}; without it, it would do nothing")
    return cfg


def build_parser() -> Parser:
    p = Parser(prog="coopsumo train", description="Train the cooperative lane-changing DQN.")
    p.add_argument("--lanes", type=integer(MIN_LANES, MAX_LANES), default=3, help="number of lanes, 2-6")
    p.add_argument("--alpha", type=alpha, default=None,
                   help="lane-change penalty of eq. (7), per accepted change (default 0)")  # fmt: skip
    p.add_argument("--t-up", type=number(), default=DemandConfig.t_up_s, help="upstream departure interval (s)")
    p.add_argument("--steps", type=steps, default=90_000, help="training steps of 0.1 s")
    p.add_argument("--seed", type=seed, default=0, help="seed of the demand, the learner and SUMO (0 to 2^31 - 1)")
    p.add_argument("--out", type=out_dir, default=None, help="run folder (default results/train/...)")
    p.add_argument("--resume", action="store_true", help="continue the interrupted run in --out")
    p.add_argument("--eval-steps", type=integer(0, MAX_STEPS), default=TrainConfig.eval_steps,
                   help="greedy evaluation steps (0: none)")  # fmt: skip
    add_learner_flags(p)
    p.add_argument("--tensorboard", action=TensorBoardFlag, help="also write TensorBoard scalars to OUT/tensorboard/")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def config_from_args(args: Any) -> TrainConfig:
    check_t_up("--t-up", args.t_up, ControlConfig().dt_s)
    dqn = learner_from_args(args)
    if dqn.alpha_conditioned and args.alpha is not None:
        raise UsageError("--alpha-conditioned trains one model for every alpha; leave --alpha out (drive the model "
                         "at an alpha with --policy dqn:PATH,alpha=A)")  # fmt: skip
    sim = SimConfig(
        road=RoadConfig(lanes=args.lanes),
        demand=DemandConfig(t_up_s=args.t_up),
        reward=RewardConfig(alpha=args.alpha or 0.0),
        steps=args.steps,
        seed=args.seed,
        policy="dqn",
    )
    cfg = TrainConfig(sim=sim, dqn=dqn, eval_steps=args.eval_steps)
    cfg.validate()
    return cfg


RUN_FLAGS: tuple[tuple[str, str, Callable[[TrainConfig], Any]], ...] = (
    ("--lanes", "lanes", lambda c: c.sim.road.lanes),
    ("--alpha", "alpha", lambda c: c.sim.reward.alpha),
    ("--t-up", "t_up", lambda c: c.sim.demand.t_up_s),
    ("--steps", "steps", lambda c: c.sim.steps),
    ("--seed", "seed", lambda c: c.sim.seed),
    ("--eval-steps", "eval_steps", lambda c: c.eval_steps),
    ("--preset", "preset", lambda c: c.dqn.preset),
)
"""(flag, argparse dest, its value in a TrainConfig) of the run's own flags (learner flags: LEARNER_FLAGS)"""


def check_resume_flags(argv: list[str] | None, cfg: TrainConfig) -> None:
    """--resume continues the checkpoint's run: a flag given beside it must repeat the checkpoint's value."""
    p = build_parser()
    p.set_defaults(**{dest: None for _, dest, _ in RUN_FLAGS})  # None now means "not on the command line"
    given = p.parse_args(argv)
    flags = [*RUN_FLAGS, *((flag, name, lambda c, n=name: getattr(c.dqn, n)) for flag, name, _, _ in LEARNER_FLAGS)]
    for flag, dest, stored in flags:
        value = flag_value(flag, dest, getattr(given, dest))
        if value is not None and value != stored(cfg):
            raise UsageError(f"{flag} {value} differs from the checkpoint's {stored(cfg)}: --resume continues the "
                             f"run as it was started (leave {flag} out)")  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def body() -> int:
        torch.set_num_threads(1)
        if args.out is not None:
            check_run_dir(args.out, "train")  # before anything is read, written or deleted
        if args.resume:
            if args.out is None:
                raise UsageError("--resume needs --out pointing at the interrupted run")
            work = retrain_folder(args.out.resolve())  # a new training of a finished folder, killed
            source = work if (work / "checkpoint.pt").exists() else args.out
            cfg = Trainer.checkpoint_config(source, Trainer.load_checkpoint(source))
            check_resume_flags(argv, cfg)
        else:
            cfg = config_from_args(args)
        out = args.out or default_out(cfg)
        check_out_path(out)  # also the default folder (a relative path when the current folder was deleted)
        check_run_dir(out, "train")
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise UsageError(f"cannot write output folder {out}: {err.strerror}") from None
        target = out
        try:
            with out_lock(out, "train"):  # a second command writing to the same folder is refused
                target = training_folder(out, args.resume, progress=not args.quiet)
                summary = train(cfg, target, resume=args.resume, progress=not args.quiet,
                                tensorboard=args.tensorboard, final=out)  # fmt: skip
                if target != out:
                    finish_run_dir(target, out, "train")
        except Interrupted as stop:
            print(f"train: interrupted at step {stop.step}; checkpoint saved in {target / 'checkpoint.pt'}; "
                  f"continue with --resume --out {out}", file=sys.stderr)  # fmt: skip
            return 128 + stop.signum
        except KeyboardInterrupt:  # outside the training loop (saving the model): the last checkpoint stands
            print(f"train: interrupted; continue with --resume --out {out}", file=sys.stderr)
            return 130
        keys = ("mean_speed_mps", "lane_changes_per_vehicle", "collisions", "teleports")
        print(f"model: {out / 'model.pt'}  " + " ".join(f"{k}={summary.get(k)}" for k in keys))
        return 0

    return run_cli("train", body)


if __name__ == "__main__":
    sys.exit(main())
