"""`python -m coopsumo.train`: train the shared lane-changing DQN in free flow (scenario II).

Every vehicle is an agent; all share one network and one replay memory. Writes into --out:
config.json, train_log.csv (one row per logging window), model.pt, and the greedy
evaluation's summary.json (its SUMO files in eval/). Ctrl-C or SIGTERM saves
checkpoint.pt and exits; --resume continues it exactly (the world is rebuilt by replaying
the recorded actions, then the learner's saved state takes over).
"""

from __future__ import annotations

import csv
import os
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

from coopsumo.config import (
    DemandConfig,
    DQNConfig,
    RewardConfig,
    RoadConfig,
    SimConfig,
    TrainConfig,
    to_dict,
    train_config_from_dict,
)
from coopsumo.dqn import Learner, save_model
from coopsumo.dqn_policy import DQNPolicy
from coopsumo.observation import Observation
from coopsumo.runio import Parser, UsageError, run_cli, versions, write_json
from coopsumo.world import StepOutcome, World

LOG_FIELDS = (
    "step", "sim_time_s", "td_loss", "r_speed", "r_lane_change", "r_flow", "reward", "epsilon",
    "mean_speed_mps", "vehicles", "lane_changes", "lane_changes_rejected", "collisions", "teleports", "wall_s",
)  # fmt: skip


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

    def add(self, out: StepOutcome, speeds: np.ndarray) -> None:
        self.r_speed += float(out.reward.speed.sum())
        self.r_lane_change += float(out.reward.lane_change.sum())
        self.r_flow += float(out.reward.flow.sum())
        self.samples += len(out.nums)
        self.speed_sum += float(speeds.sum())
        self.vehicle_steps += len(speeds)
        self.lane_changes += int(out.lane_change_started.sum())
        self.rejected += int(out.rejected.sum())


def transitions(
    prev: Observation, actions: np.ndarray, out: StepOutcome, now: Observation, exit_transition: str
) -> tuple[np.ndarray, ...]:
    """(grids, speed_err, actions, rewards, next_grids, next_speed_err, dones) of the last step.

    Vehicles present before and after give ordinary transitions; vehicles that left the road
    are dropped or stored as terminal (next state = last state, masked by done).
    """
    _, i_prev, i_now = np.intersect1d(prev.nums, now.nums, assume_unique=True, return_indices=True)
    reward = out.reward.total
    g, e = prev.grids[i_prev], prev.speed_err[i_prev]
    ng, ne = now.grids[i_now], now.speed_err[i_now]
    a, r = actions[i_prev], reward[i_prev]
    done = np.zeros(len(i_prev), np.float32)
    if exit_transition == "terminal" and out.arrived.any():
        gone = np.flatnonzero(out.arrived)
        g, e = np.concatenate([g, prev.grids[gone]]), np.concatenate([e, prev.speed_err[gone]])
        ng, ne = np.concatenate([ng, prev.grids[gone]]), np.concatenate([ne, prev.speed_err[gone]])
        a, r = np.concatenate([a, actions[gone]]), np.concatenate([r, reward[gone]])
        done = np.concatenate([done, np.ones(len(gone), np.float32)])
    return g, e, a, r.astype(np.float32), ng, ne, done


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
        self.step = 0
        self.action_log: list[np.ndarray] = []
        self.window = Window()
        self._stop_signal: int | None = None

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
        tmp = self.checkpoint_path().with_suffix(".pt.tmp")
        torch.save(state, tmp)
        os.replace(tmp, self.checkpoint_path())

    @staticmethod
    def load_checkpoint(out: Path) -> dict[str, Any]:
        path = out / "checkpoint.pt"
        if not path.exists():
            raise UsageError(f"nothing to resume: {path} does not exist")
        try:
            state: dict[str, Any] = torch.load(path, weights_only=True)
        except Exception as err:  # a damaged file: report it in one line
            raise UsageError(f"cannot read checkpoint {path}: {str(err).splitlines()[0]}") from None
        return state

    def restore(self, state: dict[str, Any]) -> None:
        self.learner.load_state_dict(state["learner"])
        self.step = int(state["step"])
        counts = state["action_counts"].numpy()
        flat = state["actions"].numpy().astype(np.int64)
        self.action_log = list(np.split(flat, np.cumsum(counts)[:-1])) if len(counts) else []
        self.window = Window(**state["window"])

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

    def _loop(self, cfg: TrainConfig) -> None:
        log_path = self.out / "train_log.csv"
        new_log = self.step == 0 or not log_path.exists()
        if new_log:
            with log_path.open("w", newline="") as f:
                csv.writer(f).writerow(LOG_FIELDS)
        learner = self.learner
        dq = cfg.dqn
        start = time.perf_counter()
        (self.out / "sumo").mkdir(parents=True, exist_ok=True)
        with World(cfg.sim, self.out / "sumo") as world:
            prev: Observation | None = None
            prev_actions = np.zeros(0, np.int64)
            out: StepOutcome | None = None
            replay = self.action_log[: self.step]
            for recorded in tqdm(replay, desc="replaying to resume", disable=not self.progress or not replay,
                                 unit="step", mininterval=0.5, file=sys.stderr):  # fmt: skip
                prev = world.observe()
                prev_actions = recorded
                out = world.apply(recorded)
            bar = tqdm(total=cfg.sim.steps, initial=self.step, desc="train", unit="step",
                       disable=not self.progress, mininterval=0.5, file=sys.stderr)  # fmt: skip
            reported = self.step  # steps already told to the bar and to on_steps
            with log_path.open("a", newline="") as log_file:
                log = csv.writer(log_file)
                while self.step < cfg.sim.steps:
                    if self._stop_signal is not None:
                        self.save_checkpoint()
                        bar.close()
                        raise Interrupted(self._stop_signal, self.step)
                    obs = world.observe()
                    if prev is not None and out is not None:
                        batch = transitions(prev, prev_actions, out, obs, dq.exit_transition)
                        n = len(batch[0])
                        if n:
                            keep = learner.rng.permutation(n)[: dq.store_per_step]
                            learner.observe(*(x[keep] for x in batch))
                    actions = learner.act(obs.grids, obs.speed_err, explore=True)
                    out = world.apply(actions)
                    prev, prev_actions = obs, actions
                    self.action_log.append(actions.astype(np.int8))
                    loss = learner.step()
                    self.step += 1
                    w = self.window
                    if loss is not None:
                        w.loss.append(loss)
                    w.add(out, world.table.speed)
                    if self.step % cfg.log_every_steps == 0 or self.step == cfg.sim.steps:
                        self._write_row(log, world, time.perf_counter() - start)
                        log_file.flush()
                        if self.on_steps is not None:
                            self.on_steps(self.step - reported)
                        bar.update(self.step - reported)
                        reported = self.step
                        bar.set_postfix(v=f"{w.speed_sum / max(w.vehicle_steps, 1):.1f}",
                                        r=f"{(w.r_speed + w.r_lane_change + w.r_flow) / max(w.samples, 1):.3f}",
                                        lc=f"{w.lane_changes / max(w.samples, 1) * 10:.3f}/s")  # fmt: skip
                        self.window = Window()
                    if cfg.checkpoint_every_steps and self.step % cfg.checkpoint_every_steps == 0:
                        self.save_checkpoint()
            bar.close()
            self.world_summary = world.summary()

    def _write_row(self, log: Any, world: World, wall_s: float) -> None:
        w = self.window
        n = max(w.samples, 1)
        tot = world.totals
        row = [
            self.step, round(world.time_s, 1),
            float(np.mean(w.loss)) if w.loss else "",
            w.r_speed / n, w.r_lane_change / n, w.r_flow / n, (w.r_speed + w.r_lane_change + w.r_flow) / n,
            1.0 - self.cfg.dqn.greedy_prob,
            w.speed_sum / max(w.vehicle_steps, 1), len(world.table.nums),
            w.lane_changes, w.rejected, tot.collisions, tot.teleports, round(wall_s, 2),
        ]  # fmt: skip
        log.writerow([f"{x:.6g}" if isinstance(x, float) else x for x in row])


def model_meta(cfg: TrainConfig) -> dict[str, Any]:
    return {"config": to_dict(cfg), "versions": versions()}


def evaluate(
    cfg: TrainConfig, policy: DQNPolicy, out: Path, progress: bool, on_steps: Callable[[int], None] | None = None
) -> dict[str, Any]:
    """Greedy evaluation on the training condition (same demand seed) in out/eval."""
    from coopsumo.simulate import run

    eval_dir = out / "eval"
    eval_dir.mkdir(exist_ok=True)
    sim = replace(cfg.sim, steps=cfg.eval_steps, policy=f"dqn:{out / 'model.pt'}")
    return run(sim, policy, eval_dir, progress=progress, label="evaluate", on_steps=on_steps)


def train(
    cfg: TrainConfig,
    out: Path,
    resume: bool = False,
    progress: bool = True,
    on_steps: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Train (or resume) into `out`; returns the evaluation summary (or the training summary).

    on_steps(n) is told of progress (training and evaluation steps), for a caller's progress bar.
    """
    trainer = Trainer(cfg, out, progress, on_steps)
    out.mkdir(parents=True, exist_ok=True)
    if resume:
        trainer.restore(Trainer.load_checkpoint(out))
    else:
        write_json(out / "config.json", model_meta(cfg))
        for stale in ("model.pt", "summary.json", "checkpoint.pt", "train_summary.json"):
            (out / stale).unlink(missing_ok=True)
    start = time.perf_counter()
    trainer.run()
    wall = time.perf_counter() - start
    save_model(out / "model.pt", trainer.learner.online, model_meta(cfg))
    train_summary = dict(trainer.world_summary, wall_seconds=round(wall, 2),
                         steps_per_second=round(cfg.sim.steps / wall, 1), updates=trainer.learner.updates)  # fmt: skip
    write_json(out / "train_summary.json", train_summary)
    trainer.checkpoint_path().unlink(missing_ok=True)
    if cfg.eval_steps == 0:
        return train_summary
    summary = evaluate(cfg, DQNPolicy(trainer.learner.online), out, progress, on_steps)
    write_json(out / "summary.json", summary)
    return summary


def default_out(cfg: TrainConfig) -> Path:
    s = cfg.sim
    return (
        Path("results") / "train" / f"lanes{s.road.lanes}_alpha{s.reward.alpha:g}_tup{s.demand.t_up_s:g}_seed{s.seed}"
    )


def build_parser() -> Parser:
    p = Parser(prog="python -m coopsumo.train", description="Train the cooperative lane-changing DQN.")
    p.add_argument("--lanes", type=int, default=3, help="number of lanes, 2-6")
    p.add_argument("--alpha", type=float, default=0.0, help="lane-change penalty of eq. (7)")
    p.add_argument("--t-up", type=float, default=DemandConfig.t_up_s, help="upstream departure interval (s)")
    p.add_argument("--steps", type=int, default=90_000, help="training steps of 0.1 s")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=None, help="run folder (default results/train/...)")
    p.add_argument("--resume", action="store_true", help="continue the interrupted run in --out")
    p.add_argument("--eval-steps", type=int, default=TrainConfig.eval_steps, help="greedy evaluation steps (0: none)")
    p.add_argument("--batch-size", type=int, default=DQNConfig.batch_size)
    p.add_argument("--learn-every", type=int, default=DQNConfig.learn_every_steps, help="steps between updates")
    p.add_argument("--replay-size", type=int, default=DQNConfig.replay_size)
    p.add_argument("--lr", type=float, default=DQNConfig.lr, help="learning rate")
    p.add_argument("--optimizer", choices=("adam", "sgd"), default=DQNConfig.optimizer)
    p.add_argument("--gamma", type=float, default=DQNConfig.gamma, help="discount per 0.1 s step (paper: 0.9)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def config_from_args(args: Any) -> TrainConfig:
    import math

    if not math.isfinite(args.alpha) or args.alpha < 0:
        raise UsageError(f"alpha must be a finite number >= 0, got {args.alpha}")
    for name in ("batch_size", "learn_every", "replay_size"):
        if getattr(args, name) <= 0:
            raise UsageError(f"{name.replace('_', '-')} must be positive, got {getattr(args, name)}")
    sim = SimConfig(
        road=RoadConfig(lanes=args.lanes),
        demand=DemandConfig(t_up_s=args.t_up),
        reward=RewardConfig(alpha=args.alpha),
        steps=args.steps,
        seed=args.seed,
        policy="dqn",
    )
    if not (math.isfinite(args.lr) and args.lr > 0):
        raise UsageError(f"lr must be a positive number, got {args.lr}")
    if not 0 <= args.gamma < 1:
        raise UsageError(f"gamma must be in [0, 1), got {args.gamma}")
    dqn = DQNConfig(batch_size=args.batch_size, learn_every_steps=args.learn_every, replay_size=args.replay_size,
                    lr=args.lr, optimizer=args.optimizer, gamma=args.gamma)  # fmt: skip
    cfg = TrainConfig(sim=sim, dqn=dqn, eval_steps=args.eval_steps)
    cfg.validate()
    return cfg


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def body() -> int:
        torch.set_num_threads(1)
        if args.resume:
            if args.out is None:
                raise UsageError("--resume needs --out pointing at the interrupted run")
            cfg = train_config_from_dict(Trainer.load_checkpoint(args.out)["config"])
        else:
            cfg = config_from_args(args)
        out = args.out or default_out(cfg)
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise UsageError(f"cannot write output folder {out}: {err.strerror}") from None
        try:
            summary = train(cfg, out, resume=args.resume, progress=not args.quiet)
        except Interrupted as stop:
            print(f"train: interrupted at step {stop.step}; checkpoint saved in {out / 'checkpoint.pt'}; "
                  f"continue with --resume --out {out}", file=sys.stderr)  # fmt: skip
            return 128 + stop.signum
        keys = ("mean_speed_mps", "lane_changes_per_vehicle", "collisions", "teleports")
        print(f"model: {out / 'model.pt'}  " + " ".join(f"{k}={summary.get(k)}" for k in keys))
        return 0

    return run_cli("train", body)


if __name__ == "__main__":
    sys.exit(main())
