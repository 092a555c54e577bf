"""`coopsumo train` / `python -m coopsumo.train`: the command line of a training (its flags, their checks, the
folder it works in and the run) around agents/train.py's loop."""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from coopsumo.agents.tb_log import TensorBoardFlag
from coopsumo.agents.training_files import foreign_entry
from coopsumo.config import (
    MAX_LANES,
    MIN_LANES,
    REWARD_WEIGHT_MAX,
    ControlConfig,
    DemandConfig,
    RewardConfig,
    RoadConfig,
    SimConfig,
    TrainConfig,
    first_difference,
)
from coopsumo.dqn_config import DQN_PRESETS, LEARNER_FLAGS, DQNConfig
from coopsumo.errors import ConfigError, UsageError
from coopsumo.files import read_json
from coopsumo.owners import STORE_NAME as STORE_NAME
from coopsumo.owners import owned_problem
from coopsumo.run_dirs import (
    check_no_outside_link,
    check_out_path,
    check_run_dir,
    finish_run_dir,
    finished_run,
    lock_path,
    out_lock,
    release_lock,
    retrain_folder,
    try_lock,
)
from coopsumo.runio import STOP_SIGNALS, Parser, run_cli, signals_deferred, stop_on_signals, stop_reported
from coopsumo.validation import (
    MAX_STEPS,
    alpha,
    alpha_list,
    check_t_up,
    default_model_out,
    integer,
    model_out_dir,
    number,
    seed,
    steps,
    t_up_list,
    t_up_type,
)


def check_new_training(out: Path) -> None:
    """A new training (no --resume) never overwrites a training it would have to start over on: UsageError when
    `out` holds an interrupted one (its checkpoint.pt, or that of a new training a coopsumo before this rule was
    building beside a finished one, retrain_folder) or a finished one (its model.pt). A folder it starts over in (an
    interrupted training's without a checkpoint) must hold only what a training writes, no link, and a config.json
    of a training (training_files.foreign_entry, config_problem; issue 82, probe 8, J5: a user's config.json was
    replaced and notes.txt listed in the finished marker as the training's own)."""
    if (out / "checkpoint.pt").exists() or (retrain_folder(out.resolve()) / "checkpoint.pt").exists():
        raise UsageError(f"--out {out}: there is an interrupted training here: --resume, or another --out")
    if (out / "model.pt").exists() or finished_run(out, "train"):
        raise UsageError(f"--out {out}: there is a finished training here, which a new one would replace: another "
                         "--out, or remove the folder yourself")  # fmt: skip
    if out.is_dir() and (problem := foreign_entry(out) or config_problem(out)) is not None:
        raise UsageError(f"--out {out} {problem}, and is left alone (a new training there would replace it, write "
                         "through it or list it as its own): move it away or pick another --out")  # fmt: skip


def config_problem(out: Path) -> str | None:
    """Why the config.json of the training folder `out` is not one a training wrote (a phrase), or None: it records
    no training's configuration (a user's {"mine": 1}, which a new training would replace). A training writes it whole
    (files.write_atomic) before its first checkpoint; none there is fine."""
    path = out / "config.json"
    if not os.path.lexists(path):
        return None
    try:
        recorded = read_json(path)
    except (OSError, ValueError):
        recorded = None
    if isinstance(recorded, dict) and isinstance(recorded.get("config"), dict):
        return None
    return "holds config.json, which records no training's configuration"


def store_problem(out: Path) -> str | None:
    """Why `train` may not write `out`, or None: it lies inside a study's folder, the model store (a store model's
    folder, through a study's model link too) or another run's folder (owners.owned_problem)."""
    return owned_problem(out, f"--out {out}")


def training_folder(out: Path) -> Path:
    """The folder `train --resume --out OUT` continues: OUT, or the folder beside it (retrain_folder) in which a
    coopsumo before check_new_training built a new training over a finished one; that training replaces OUT when
    it has finished. UsageError when that folder is not such a training (retrain_problem): OUT and it are kept."""
    work = retrain_folder(out.resolve())
    if not (work / "checkpoint.pt").exists():
        return out
    if problem := retrain_problem(out, work):
        raise UsageError(f"{work} beside --out {out} {problem}, so it is not the new training of {out} an earlier "
                         f"coopsumo left there; both are left alone: move it away (to continue it, rename it and give "
                         "that name to --resume --out)")  # fmt: skip
    return work


def retrain_problem(out: Path, work: Path) -> str | None:
    """Why the folder `work` beside `out` (retrain_folder) is not a new training of `out` that an earlier coopsumo
    built there, or None: it is a link (the training it leads to is someone's own), or its config.json does not
    record the training `out`'s config.json records (another training moved or copied there)."""
    if work.is_symlink():
        return f"is a link to {work.resolve()}"
    configs = []
    for folder in (out, work):
        try:
            configs.append(read_json(folder / "config.json")["config"])
        except (OSError, ValueError, KeyError, TypeError):
            return f"has no readable config.json to compare with {out}'s" if folder == work else \
                f"holds a training while {out} has no readable config.json"
    if (where := first_difference(configs[1], configs[0])) is not None:
        return f"holds another training than {out} (first at {where})"
    return None


def default_out(cfg: TrainConfig) -> Path:
    s = cfg.sim
    alpha = "cond" if cfg.dqn.alpha_conditioned else f"{s.reward.alpha:g}"
    return Path("results") / "train" / f"lanes{s.road.lanes}_alpha{alpha}_tup{s.demand.t_up_s:g}_seed{s.seed}"


PRESET_TEXT = {
    "default": "the project's measured design",
    "paper": "the paper's literal learner",
    "alpha_only": "the default's machinery with alpha as its only cooperative mechanism, for claim (a)",
}
"""what --help says of each learner preset (dqn_config.DQN_PRESETS)"""


def flag_form(flag: str, value: Any) -> str:
    """A learner setting as its flag takes it: a list comma-separated (2,1.5,1; an empty one 'empty'), a switch as
    the flag that sets it (--dueling, --no-dueling), a whole float without its '.0', anything else as str()."""
    if isinstance(value, bool):
        return flag if value else f"--no-{flag.removeprefix('--')}"
    if isinstance(value, tuple):
        return ",".join(flag_form(flag, v) for v in value) or "empty"
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return str(value)


def preset_defaults(flag: str, name: str) -> str:
    """A learner flag's default in --help: the default preset's value, then each other preset's where it differs."""
    default = flag_form(flag, getattr(DQN_PRESETS["default"], name))
    others = [f"{preset}: {form}" for preset, cfg in DQN_PRESETS.items()
              if preset != "default" and (form := flag_form(flag, getattr(cfg, name))) != default]  # fmt: skip
    return "; ".join([f"default preset: {default}", *others])


def add_learner_flags(p: Parser) -> None:
    """--preset and one flag per learner setting (unset flags keep the preset's value)."""
    p.add_argument("--preset", choices=tuple(DQN_PRESETS), default="default",
                   help="learner preset: " + "; ".join(f"'{name}' ({PRESET_TEXT[name]})" for name in DQN_PRESETS))
    for flag, name, kind, text in LEARNER_FLAGS:
        help_text = f"{text} ({preset_defaults(flag, name)})"
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
    if name == "validation_alphas" and isinstance(value, str):
        return alpha_list(flag, value) if value.strip() else ()
    return value


FLAG_NEEDS: dict[str, tuple[str, Callable[[DQNConfig], bool]]] = {
    "--alpha-period": ("--alpha-conditioned", lambda c: c.alpha_conditioned),
    "--alpha-relabel": ("--alpha-conditioned", lambda c: c.alpha_conditioned),
    "--alpha-draw-max": ("--alpha-conditioned", lambda c: c.alpha_conditioned),
    "--validation-screen": ("--select-every N (N > 0)", lambda c: c.select_every_steps > 0),
    "--validation-finalists": ("--validation-screen N (N > 0)", lambda c: c.validation_screen > 0),
    "--validation-alphas": ("--alpha-conditioned and --select-every N (N > 0)",
                            lambda c: c.alpha_conditioned and c.select_every_steps > 0),
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
    for flag, term in (("--w-speed", "speed term r_v, eq. (5)"), ("--w-flow", "flow term q_t")):
        p.add_argument(flag, type=number(0, REWARD_WEIGHT_MAX), default=None,
                       help=f"weight of the reward's {term} (0 to {REWARD_WEIGHT_MAX:,g}; default "
                            f"{getattr(RewardConfig, flag[2:].replace('-', '_')):g}, the paper's)")  # fmt: skip
    p.add_argument("--t-up", type=t_up_type(ControlConfig().dt_s), default=None,
                   help=f"upstream departure interval (s) of the evaluation and, given, of the training (trained at "
                        f"it alone); default: {DemandConfig.t_up_s:g} s, training on the preset's demands")  # fmt: skip
    p.add_argument("--steps", type=steps, default=90_000, help="training steps of 0.1 s")
    p.add_argument("--seed", type=seed, default=0, help="seed of the demand, the learner and SUMO (0 to 2^31 - 1)")
    p.add_argument("--out", type=model_out_dir, default=None, help="run folder (default results/train/...)")
    p.add_argument("--resume", action="store_true", help="continue the interrupted run in --out")
    p.add_argument("--eval-steps", type=integer(0, MAX_STEPS), default=TrainConfig.eval_steps,
                   help="greedy evaluation steps (0: none)")  # fmt: skip
    add_learner_flags(p)
    p.add_argument("--tensorboard", action=TensorBoardFlag, help="also write TensorBoard scalars to OUT/tensorboard/")
    p.add_argument("--update-worker", choices=("auto", "on", "off"), default="auto",
                   help="on: the learner's updates in a second process while the world steps, on a second core; off: "
                        f"in this process between the world's steps; auto (default): on for trainings of "
                        f"{UPDATE_WORKER_MIN_STEPS:,} steps or more (the worker's start costs about 2 s). The model "
                        "is the same file either way")  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def config_from_args(args: Any) -> TrainConfig:
    t_up = DemandConfig.t_up_s if args.t_up is None else check_t_up("--t-up", args.t_up, ControlConfig().dt_s)
    dqn = learner_from_args(args)
    if args.t_up is not None and args.train_t_ups is None and dqn.train_t_ups:
        dqn = replace(dqn, train_t_ups=())  # an explicit --t-up: trained at that demand alone
    if dqn.alpha_conditioned and args.alpha is not None:
        raise UsageError("--alpha-conditioned trains one model for every alpha; leave --alpha out (drive the model "
                         "at an alpha with --policy dqn:PATH,alpha=A)")  # fmt: skip
    sim = SimConfig(
        road=RoadConfig(lanes=args.lanes),
        demand=DemandConfig(t_up_s=t_up),
        reward=RewardConfig(alpha=args.alpha or 0.0, w_speed=_or(args.w_speed, RewardConfig.w_speed),
                            w_flow=_or(args.w_flow, RewardConfig.w_flow)),
        steps=args.steps,
        seed=args.seed,
        policy="dqn",
    )
    cfg = TrainConfig(sim=sim, dqn=dqn, eval_steps=args.eval_steps)
    cfg.validate()
    return cfg


def _or(value: float | None, default: float) -> float:
    return default if value is None else value


UPDATE_WORKER_MIN_STEPS = 5_000
"""--update-worker auto: the shortest training given a worker. Below it the worker's start (about 2 s) costs more
than the overlap saves (about 0.6 ms per step: 9,000 steps took 13.5 s with it and 18.6 s without)"""


def uses_update_worker(choice: str, cfg: TrainConfig) -> bool:
    """Whether the training runs its updates in a second process (--update-worker)."""
    return choice == "on" or (choice == "auto" and cfg.sim.steps >= UPDATE_WORKER_MIN_STEPS)


RUN_FLAGS: tuple[tuple[str, str, Callable[[TrainConfig], Any]], ...] = (
    ("--lanes", "lanes", lambda c: c.sim.road.lanes),
    ("--alpha", "alpha", lambda c: c.sim.reward.alpha),
    ("--w-speed", "w_speed", lambda c: c.sim.reward.w_speed),
    ("--w-flow", "w_flow", lambda c: c.sim.reward.w_flow),
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


def stopped(out: Path, target: Path, created: bool, signum: int) -> int:
    """The line and exit code of a training stopped by a signal outside its loop (its setup, model selection, its
    evaluation): its checkpoint stands; before its first one, a folder this command made is removed again. A second
    signal meanwhile is only counted (runio.stop_reported)."""
    stop_reported()
    if (target / "checkpoint.pt").exists():
        print(f"train: interrupted; its checkpoint {target / 'checkpoint.pt'} stands: continue with --resume --out "
              f"{out}", file=sys.stderr)  # fmt: skip
    elif finished_run(target, "train"):
        if target != out:
            finish_run_dir(target, out, "train")
        print(f"train: interrupted as it finished; its model is whole: {out / 'model.pt'}", file=sys.stderr)
    else:
        removed = created and out.is_dir() and not (out / "model.pt").exists()
        if removed:
            shutil.rmtree(out, ignore_errors=True)  # this command made it, and nothing in it can be resumed
        print(f"train: interrupted before the training's first checkpoint; nothing to resume"
              f"{f' ({out} removed)' if removed else ''}", file=sys.stderr)  # fmt: skip
    return 128 + signum


def check_not_writing(out: Path) -> None:
    """UsageError, as out_lock gives it, when another command holds out's lock now (a training running there);
    checked before the folder's contents are judged, which a running training changes."""
    path = lock_path(out.resolve())
    if not os.path.lexists(path):  # a lock file lives only while it is held
        return
    fd = try_lock(path, "train")
    if fd is None:
        raise UsageError(f"another coopsumo command is writing {out.resolve()}; wait for it to end or pick another "
                         "--out")  # fmt: skip
    release_lock(fd, path)


def main(argv: list[str] | None = None) -> int:
    """`coopsumo train`; SIGINT and SIGTERM end it wherever it is (runio.stop_on_signals), with one line."""
    with stop_on_signals():
        return run_cli("train", lambda: _main(argv))


def _check_given_out(args: Any) -> None:
    """A given --out is checked before anything is read, written or deleted."""
    if args.out is not None and (problem := store_problem(args.out)):
        raise UsageError(problem)
    if args.out is not None:
        check_out_path(args.out)  # $COOPSUMO_NETS_DIR inside it too (paths.nets_in_out_problem)
        check_run_dir(args.out, "train")
        check_no_outside_link(args.out)
        check_not_writing(args.out)  # a training running there is not an interrupted one
        if not args.resume:
            check_new_training(args.out)
        else:
            training_folder(args.out)  # a folder beside it that is not its new training refused before torch loads
    if args.resume and args.out is None:
        raise UsageError("--resume needs --out pointing at the interrupted run")


def _config(args: Any, argv: list[str] | None) -> TrainConfig:
    """The flags' configuration, or the interrupted training's with --resume."""
    new_cfg = None if args.resume else config_from_args(args)  # bad flags refused before torch loads (~2 s)
    with signals_deferred():  # a Ctrl-C in torch's import is raised once it is done, before anything is written
        import torch

        from coopsumo.agents.train import Trainer

    torch.set_num_threads(1)
    if new_cfg is not None:
        return new_cfg
    source = training_folder(args.out)  # or an earlier version's killed new training beside a finished one
    cfg = Trainer.checkpoint_config(source, Trainer.load_checkpoint(source))
    check_resume_flags(argv, cfg)
    return cfg


def _prepare_out(args: Any, cfg: TrainConfig) -> tuple[Path, bool]:
    """The output folder, checked and made; whether this command created it."""
    out = args.out or default_model_out(default_out(cfg))  # checked as a given --out is
    check_out_path(out)  # also the default folder (a relative path when the current folder was deleted)
    if problem := store_problem(out):
        raise UsageError(problem)
    check_run_dir(out, "train")
    check_no_outside_link(out)
    if not args.resume:
        check_new_training(out)  # also the default folder
    created = not os.path.lexists(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise UsageError(f"cannot write output folder {out}: {err.strerror}") from None
    return out, created


def _train_in(args: Any, cfg: TrainConfig, out: Path, created: bool) -> int:
    """The training under out's lock; its exit code (128 + signal when stopped, resumable)."""
    from coopsumo.agents.train import Interrupted, train
    from coopsumo.agents.update_worker import LearnerProcessError

    target = out
    with out_lock(out, "train"):  # a second command writing to the same folder is refused
        try:  # under the lock: what an interrupted command removes is its own
            if not args.resume:
                check_new_training(out)  # again under the lock: another command may have trained meanwhile
            target = training_folder(out) if args.resume else out
            summary = train(cfg, target, resume=args.resume, progress=not args.quiet,
                            tensorboard=args.tensorboard, final=out,
                            learner_process=uses_update_worker(args.update_worker, cfg))  # fmt: skip
            if target != out:
                finish_run_dir(target, out, "train")
        except Interrupted as stop:
            stop_reported()  # a second signal while this line is printed and the lock released: counted (F15)
            print(f"train: interrupted at step {stop.step}; checkpoint saved in {target / 'checkpoint.pt'}; "
                  f"continue with --resume --out {out}", file=sys.stderr)  # fmt: skip
            return 128 + stop.signum
        except LearnerProcessError as err:  # the update worker died: the last periodic checkpoint stands
            if err.signum in STOP_SIGNALS:  # a Ctrl-C to the whole group that reached the worker as it started
                return stopped(out, target, created, err.signum)
            print(f"train: error: {err}; the training stopped; continue from its last checkpoint with --resume "
                  f"--out {out}", file=sys.stderr)  # fmt: skip
            return 1
        except KeyboardInterrupt as stop:  # outside the training loop (runio.Stop: setup, selection, saving)
            return stopped(out, target, created, getattr(stop, "signum", signal.SIGINT))
    for line in closing_lines(out, cfg, summary):
        print(line)
    return 0


EVAL_KEYS = ("mean_speed_mps", "lane_changes_per_vehicle", "collisions", "teleports")
"""the greedy evaluation's numbers `train` ends with"""


def closing_lines(out: Path, cfg: TrainConfig, summary: dict[str, Any]) -> list[str]:
    """What `train` ends with: where its model is, then what the model did in the greedy evaluation (its floats to
    4 significant digits, as simulate prints them) and a warning when it made no lane change there, as `keep`
    drives; with --eval-steps 0, that no evaluation ran (the training's own numbers were made while exploring)."""
    lines = [f"model: {out / 'model.pt'}"]
    if cfg.eval_steps == 0:
        lines.append(f"no evaluation ran (--eval-steps 0): what the model does is unmeasured; drive it with "
                     f"coopsumo simulate --policy dqn:{out / 'model.pt'}")  # fmt: skip
        return lines
    values = " ".join(f"{k}={v:.4g}" if isinstance(v := summary.get(k), float) else f"{k}={v}" for k in EVAL_KEYS)
    lines.append(f"greedy evaluation ({cfg.eval_steps:,} steps, {out / 'eval'}): {values}")
    if summary.get("lane_changes") == 0 and summary.get("departed", 0) > 0:
        lines.append("train: warning: 0 lane changes in the greedy evaluation: the model drove like `keep`; it learned "
                     "nothing beyond keeping its lane")  # fmt: skip
    return lines


def _main(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    _check_given_out(args)
    cfg = _config(args, argv)
    out, created = _prepare_out(args, cfg)
    return _train_in(args, cfg, out, created)


if __name__ == "__main__":
    sys.exit(main())
