"""The training loop of the shared lane-changing DQN (`coopsumo train`: its command line in agents/train_cli.py).

Every vehicle is an agent; all share one network and one replay memory. Writes into --out: config.json,
train_log.csv (one row per logging window), model.pt, and the greedy evaluation's summary.json (its SUMO files in
eval/). Ctrl-C or SIGTERM saves checkpoint.pt and exits; --resume continues it exactly (the world is rebuilt by
replaying the recorded actions, then the learner's saved state takes over). An existing non-empty --out is used only
if this command wrote it (its .coopsumo-run.json, run_dirs.check_run_dir).

--alpha-conditioned trains one network for every alpha: alpha is an input, and all vehicles share one alpha
drawn from the paper's grid every alpha_period_steps (training_alpha); the world's own reward alpha is 0 and
the trainer charges the drawn alpha per lane change started.
"""

from __future__ import annotations

import csv
import shutil
import signal
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from coopsumo.agents import selection
from coopsumo.agents.conditioning import conditioned_alphas, training_alpha
from coopsumo.agents.decisions import ActionHold, offered
from coopsumo.agents.dqn import Learner
from coopsumo.agents.dqn_policy import DQNPolicy
from coopsumo.agents.episodes import episode_bounds, episode_config, episodic
from coopsumo.agents.file_checks import ended_training, prepare_resume, resume_problem
from coopsumo.agents.model_file import load_error_text, save_model
from coopsumo.agents.tb_log import LOG_FIELDS, Window, open_log
from coopsumo.agents.training_files import foreign_entry
from coopsumo.agents.transitions import Pending, all_if_none, transitions
from coopsumo.agents.update_worker import GroupTicket, LearnerProcessError, attach_updates
from coopsumo.config import TrainConfig, first_difference, to_dict, train_config_from_dict
from coopsumo.errors import ConfigError, UsageError, first_line
from coopsumo.files import read_json, write_atomic, write_json
from coopsumo.provenance import versions
from coopsumo.run_dirs import check_no_outside_link, finished_run, mark_run_dir
from coopsumo.runio import Stop, raise_swallowed_stop, signals_deferred
from coopsumo.sim.observation import Observation, network_features
from coopsumo.sim.world import StepOutcome, World

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


class Trainer:
    """The training loop, its log, checkpoints and resume."""

    def __init__(self, cfg: TrainConfig, out: Path, progress: bool = True,
                 on_steps: Callable[[int], None] | None = None, learner_process: bool = False,
                 group: GroupTicket | None = None):  # fmt: skip
        cfg.validate()
        self.learner_process = learner_process  # the updates in a second process (update_worker), same result
        self.group = group  # a member of a group of stacked trainings (update_worker.start_group; None: alone)
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
        self._run_step = 0  # the step run() started at
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
        learner = self.learner.state_dict()  # waits for a worker's updates: their losses belong to this window
        self.window.loss.extend(self.learner.take_losses())
        state = {
            "config": to_dict(self.cfg),
            "step": self.step,
            "learner": learner,
            "action_counts": torch.from_numpy(counts),
            "actions": torch.from_numpy(flat.astype(np.int8)),
            "window": {k: v for k, v in vars(self.window).items()},
        }
        write_atomic(self.checkpoint_path(), lambda tmp: torch.save(state, tmp))

    def drop_checkpoint(self) -> None:
        """Remove checkpoint.pt. A file named like a temporary a killed write of it left stays: it may be a user's
        (issue 82, probe 8, J23; probe 12, N3: a user's .checkpoint.pt.ABCDEFGH.tmp was deleted)."""
        self.checkpoint_path().unlink(missing_ok=True)

    @staticmethod
    def load_checkpoint(out: Path) -> dict[str, Any]:
        path = out / "checkpoint.pt"
        if not path.is_file():  # missing, or a pipe or a device (reading it would wait for a writer)
            done = "; the training there has finished" if finished_run(out, "train") else ""
            raise UsageError(f"cannot read checkpoint {path}: it is not a regular file" if path.exists()
                             else f"nothing to resume: {path} does not exist{done}")  # fmt: skip
        try:
            with warnings.catch_warnings():  # torch warns about a pickle of another protocol before it refuses it
                warnings.simplefilter("ignore")
                state: dict[str, Any] = torch.load(path, weights_only=True)
        except Exception as err:  # a damaged file (empty, cut short, not torch's): report it in one line
            text = first_line(err)  # never torch's advice to load the file with weights_only=False, which is unsafe
            text = "not a file of tensors torch can read safely" if "weights_only" in str(err).lower() else text
            raise UsageError(f"cannot read checkpoint {path}: {text}") from None
        if not isinstance(state, dict) or any(k not in state for k in CHECKPOINT_KEYS):
            raise UsageError(f"{path} is not a coopsumo training checkpoint")
        learner = state["learner"] if isinstance(state["learner"], dict) else {}
        dqn = state["config"].get("dqn") if isinstance(state["config"], dict) else None
        if (isinstance(dqn, dict) and "greedy_prob" in dqn) or "decisions" not in learner:
            raise UsageError(f"checkpoint {path} was written by a coopsumo before learner presets and cannot be "
                             "resumed exactly; train again without --resume")  # fmt: skip
        if (problem := foreign_entry(out)) is not None:  # at any depth, a link too (training_files; probe 8, J4, J6)
            raise UsageError(f"--out {out} {problem}: move it out, then --resume")
        if problem := resume_problem(out, state):  # types and ranges, the log rows it keeps (file_checks)
            raise UsageError(f"{problem}; train again without --resume")
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
        prepare_resume(self.out, self.step)  # log rows past the checkpoint dropped

    # -- the loop ----------------------------------------------------------------------------
    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        """SIGINT/SIGTERM: checkpoint after the current step (Interrupted); before the first step of this run (the
        update worker's start, the world's, a resume's replay) stop at once: the checkpoint on disk is this state."""
        self._stop_signal = signum
        if self.step == self._run_step:
            raise Stop(signum)

    def run(self) -> None:
        """Train up to cfg.sim.steps; raises Interrupted after checkpointing on SIGINT/SIGTERM (runio.Stop before the
        first step: nothing new to save)."""
        cfg, learner, self._run_step = self.cfg, self.learner, self.step
        raise_swallowed_stop()  # a Ctrl-C swallowed during the imports: stopped before the first step
        old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
        try:  # the handlers go in inside the try, so that one raising at once (a stop before the first step) is undone
            for s in old:
                signal.signal(s, self._on_signal)
            attach_updates(learner, self.learner_process, self.group)
            self._loop(cfg)
        except LearnerProcessError as err:
            raise self._stopped_with(err) from None
        finally:
            self._run_step = -1  # a signal while the handlers are put back is only noted: every one is put back
            for s, h in old.items():
                signal.signal(s, signal.SIG_DFL if h is None else h)
            if learner.worker is not None:
                try:
                    learner.detach()  # the worker's target network and optimiser come back for the last checkpoint
                except LearnerProcessError as err:
                    learner.worker.close()
                    learner.worker = None
                    raise self._stopped_with(err) from None
        if self._stop_signal is not None:  # it came in the last step, after the loop's last look, or its handler ran
            self.save_checkpoint()  # only as the handlers were put back: checked once they are (it was lost there)
            raise Interrupted(self._stop_signal, self.step)

    def _stopped_with(self, err: LearnerProcessError) -> BaseException:
        """What a dead update worker means: the stop, when this process had received one (a Ctrl-C to the whole group
        can kill the worker in ways of its own, e.g. while its interpreter still starts; the last checkpoint stands),
        else the worker's error."""
        return err if self._stop_signal is None else Stop(self._stop_signal)

    def _offered(self, obs: Observation) -> np.ndarray | None:
        """The actions offered to each vehicle of obs (decisions.offered); None: all of them."""
        dq = self.cfg.dqn
        return offered(obs.feasible, obs.speed, dq.action_mask, dq.restart_below_mps)

    def alpha_at(self, step: int) -> float:
        """The reward's alpha at training step `step`: drawn (training_alpha) when conditioned, else the run's."""
        if self.cfg.dqn.alpha_conditioned:
            return training_alpha(self.cfg.sim.seed, step, self.cfg.dqn.alpha_period_steps,
                                  conditioned_alphas(self.cfg.dqn))
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
            if pend.prev is not None and recorded is None:
                *batch, _ = transitions(pend.prev, pend.prev_features, pend.prev_actions, pend.reward_sum, obs, feats,
                                        all_if_none(mask, obs), pend.change_sum)  # fmt: skip
                if len(batch[0]):
                    keep = learner.rng.permutation(len(batch[0]))[: dq.store_per_decision]
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
        learned = out.reward.total
        if dq.followers_weight > 0:  # reward shaping: the speed of the traffic behind (DQNConfig.followers_weight)
            learned = learned + dq.followers_weight * world.followers_speed_reward(out.nums, dq.followers_m)
        if dq.alpha_conditioned:  # the world's alpha is 0 (TrainConfig.validate): charge the drawn one
            penalty = -alpha * started
            pend.add_rewards(out.nums, learned + penalty, started)
        else:
            penalty = out.reward.lane_change
            pend.add_rewards(out.nums, learned, started)
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
            learner.step(decided)
            self.step += 1
            if self.validator is not None:
                self.validator.after_step(self.step, lambda: learner.online)
            w = self.window
            w.add(out, world.table.speed, penalty)
            if self.step % cfg.log_every_steps == 0 or self.step == cfg.sim.steps:
                learner.wait()  # every update of the window has its loss (a checkpoint takes them itself)
                w.loss.extend(learner.take_losses())
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


def check_recorded_config(out: Path, cfg: TrainConfig) -> None:
    """Before a resume: the folder's config.json must record the checkpoint's configuration (a checkpoint copied in
    from another training is refused in one line); a missing config.json is written again."""
    path = out / "config.json"
    try:
        recorded = read_json(path)["config"]
    except FileNotFoundError:
        write_json(path, model_meta(cfg))
        return
    except (OSError, ValueError, KeyError, TypeError):
        raise UsageError(f"{path} is unreadable or not a training's configuration; train again without "
                         "--resume") from None
    if (where := first_difference(to_dict(cfg), recorded)) is not None:
        raise UsageError(f"checkpoint {out / 'checkpoint.pt'} is another training's than {path} records (first at "
                         f"{where}): copied in?; train again without --resume")  # fmt: skip


def _begin(trainer: Trainer, cfg: TrainConfig, out: Path, resume: bool) -> None:
    """Resume from out's checkpoint (refused in one line when it does not fit its configuration), or start afresh:
    the run folder marked unfinished, config.json written, what an earlier run left removed, a step-0 checkpoint."""
    out.mkdir(parents=True, exist_ok=True)
    if resume:
        check_recorded_config(out, cfg)
        try:
            trainer.restore(Trainer.load_checkpoint(out))
        except (RuntimeError, KeyError, ValueError, TypeError, OverflowError) as err:  # weights, buffer, RNG
            text = load_error_text(err)  # torch's state_dict errors: with the first key that did not fit
            raise UsageError(f"checkpoint {trainer.checkpoint_path()} does not fit its configuration: {text}") from None
    else:
        mark_run_dir(out, "train", finished=False)
        write_json(out / "config.json", model_meta(cfg))
        for stale in ("model.pt", "summary.json", "checkpoint.pt", "train_summary.json", selection.LAST_MODEL,
                      "validation.csv"):
            (out / stale).unlink(missing_ok=True)
        shutil.rmtree(out / selection.SNAPSHOTS, ignore_errors=True)
        trainer.save_checkpoint()  # step 0: from here on, an interrupted run always has a checkpoint to resume


def _write_models(trainer: Trainer, cfg: TrainConfig, out: Path, wall: float, ended: dict[str, Any] | None,
                  learner_process: bool) -> tuple[dict[str, Any], dict[str, Any] | None]:  # fmt: skip
    """model.pt (the best validated snapshot when the learner selects, the last weights beside it; else the last
    weights) and train_summary.json; returns that summary and the chosen snapshot's record (None: no selection)."""
    chosen = None
    if selection.selecting(cfg):  # model.pt: the best validated snapshot; the last weights beside it
        save_model(out / selection.LAST_MODEL, trainer.learner.online, model_meta(cfg))
        chosen = selection.install_best(out)
        selection.write_table(out)
    if chosen is None:
        save_model(out / "model.pt", trainer.learner.online, model_meta(cfg))
    train_summary = ended or dict(trainer.world_summary, wall_seconds=round(wall, 2),
                                  steps_per_second=round(cfg.sim.steps / wall, 1),
                                  updates=trainer.learner.updates, learner_process=learner_process)  # fmt: skip
    if chosen is not None:
        train_summary = dict(train_summary, selected_step=chosen["step"], selected_score=chosen["score"],
                             last_score=selection.last_score(out))  # fmt: skip
        if trainer.progress:
            print(f"train: model.pt is the weights of step {chosen['step']:,} (validation score "
                  f"{chosen['score']:.4f}; last weights {train_summary['last_score']:.4f}, in {selection.LAST_MODEL})",
                  file=sys.stderr)  # fmt: skip
    write_json(out / "train_summary.json", train_summary)
    return train_summary, chosen


def _driving_policy(cfg: TrainConfig, net: Any) -> DQNPolicy:
    """The trained network as the greedy evaluation drives it: the learner's decision and driving rules."""
    return DQNPolicy(net, decision_interval=cfg.dqn.decision_interval_steps,
                       action_mask=cfg.dqn.action_mask, restart_below_mps=cfg.dqn.restart_below_mps,
                       change_margin=cfg.dqn.change_margin, queue_below_mps=cfg.dqn.queue_below_mps,
                       no_return_s=cfg.dqn.no_return_s,
                       alpha=cfg.sim.reward.alpha if cfg.dqn.alpha_conditioned else None)  # fmt: skip


def train(cfg: TrainConfig, out: Path, resume: bool = False, progress: bool = True,
          on_steps: Callable[[int], None] | None = None, tensorboard: bool = False, final: Path | None = None,
          learner_process: bool = False, group: GroupTicket | None = None) -> dict[str, Any]:  # fmt: skip
    """Train (or resume) into `out`; returns the evaluation summary (or the training summary). learner_process: the
    gradient updates run in a second process while the world steps (agents/update_worker.py; the same model file
    either way); group: as a member of a group of stacked trainings (agents/group.py). final: the folder the results
    will be moved to, when `out` is a working folder (recorded paths name it). on_steps(n) is told of progress
    (training and evaluation steps); tensorboard: also write the log's scalars to out/tensorboard/ (tb_log)."""
    check_no_outside_link(out)  # sumo/, eval/, a log file...: written through, it would write elsewhere
    learner_process = learner_process or cfg.dqn.stacked_updates or group is not None  # stacked: in its process
    trainer = Trainer(cfg, out, progress, on_steps, learner_process, group)
    _begin(trainer, cfg, out, resume)
    ended = ended_training(out, trainer.step, cfg.sim.steps) if resume else None  # interrupted in its evaluation
    scalars = open_log(out, tensorboard, resume, trainer.step)
    trainer.on_row = None if scalars is None else scalars.add_row
    if selection.selecting(cfg) and ended is None:
        trainer.validator = selection.Validator(out, cfg, trainer.step)
    start = time.perf_counter()
    try:
        if ended is None:
            trainer.run()
            trainer.save_checkpoint()  # the last step's, kept until the evaluation is written: a resume evaluates again
            if trainer.validator is not None:  # (and validates again: an interruption here loses no training)
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
    train_summary, chosen = _write_models(trainer, cfg, out, wall, ended, learner_process)
    if cfg.eval_steps == 0:
        with signals_deferred():  # a stop between the two would leave a training neither resumable nor finished
            trainer.drop_checkpoint()
            mark_run_dir(out, "train")
        return train_summary
    net = trainer.learner.online if chosen is None else DQNPolicy.from_file(str(out / "model.pt")).net
    policy = _driving_policy(cfg, net)
    shutil.rmtree(out / "eval", ignore_errors=True)  # what an interrupted evaluation had written
    try:
        summary = evaluate(cfg, policy, out, progress, on_steps, shown=final)
    except KeyboardInterrupt as stop:  # SIGINT, or runio.Stop: its signal
        raise Interrupted(getattr(stop, "signum", signal.SIGINT), trainer.step) from None
    write_json(out / "summary.json", summary)
    with signals_deferred():
        trainer.drop_checkpoint()
        mark_run_dir(out, "train")
    return summary
