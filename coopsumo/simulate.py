"""`python -m coopsumo.simulate`: run one simulation and write its run folder.

Writes config.json, detectors.xml (SUMO's loop output), summary.json and, with
--trajectories, trajectories.parquet; with --fcd and --tripinfo SUMO's fcd.xml and tripinfo.xml.
--gui runs the same simulation in sumo-gui. Bad input: one line on stderr, exit code 2. An existing --out
is replaced only if simulate wrote it and nothing was added (run_dirs.check_run_dir); never the model's folder.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

from coopsumo.agents.policies import policy_for_run
from coopsumo.agents.rollout import run  # noqa: F401  (simulate.run: the rollout, re-exported for callers)
from coopsumo.config import (
    LOOP_SPACING_M,
    MAX_LANES,
    MIN_LANES,
    ROAD_LENGTH_M,
    SPEED_LIMIT_MPS,
    AccidentConfig,
    ControlConfig,
    DemandConfig,
    GuiConfig,
    OutputConfig,
    RoadConfig,
    SimConfig,
)
from coopsumo.errors import ConfigError, UsageError
from coopsumo.owners import owned_problem
from coopsumo.paths import out_path_problem
from coopsumo.policy_spec import KEYS, PolicySpecError, parse_policy, policy_file
from coopsumo.run_dirs import atomic_run_dir, check_apart, check_no_outside_link, check_run_dir
from coopsumo.runio import Parser, run_cli
from coopsumo.sim import network, sumo_session
from coopsumo.validation import (
    MAX_FCD_PERIOD_S,
    MAX_GUI_DELAY_MS,
    MAX_STEPS,
    check_accident,
    check_int,
    check_t_up,
    integer,
    number,
    out_dir,
    seed,
    steps,
    t_up_type,
)

SCENARIOS = ("free", "accident")
DEFAULT_STEPS = 9000
PAPER_STEPS = 90_000


def default_accident(steps: int) -> tuple[int, int]:
    """(first step, length) of the accident of a `steps`-step run when --accident-start and --accident-steps are not
    given: the paper's window, steps 20,000-70,000 of 90,000, scaled to the run (from 2/9 of it for 5/9 of it), so
    that it starts inside any run."""
    return steps * 2 // 9, max(1, steps * 5 // 9)


DQN_VALUES = {"alpha": "A|adaptive", "margin": "M", "noreturn": "S", "restart": "R", "queue": "V"}
"""the placeholder --help shows for each parameter of a dqn policy (policy_spec.KEYS["dqn"])"""
DQN_MODIFIERS = " ".join(f",{key}={DQN_VALUES.get(key, 'X')}" for key in KEYS["dqn"])


def _accident_help(what: str, index: int) -> str:
    share = ("2/9", "5/9")[index]
    paper, ours = default_accident(PAPER_STEPS)[index], default_accident(DEFAULT_STEPS)[index]
    return (f"{what} (--scenario accident; default: {share} of --steps, the paper's {paper:,} of {PAPER_STEPS:,}; "
            f"{ours:,} of the default {DEFAULT_STEPS:,})")


def build_parser() -> Parser:
    p = Parser(prog="coopsumo simulate", description="Run one SUMO highway simulation.")
    p.add_argument("--scenario", choices=SCENARIOS, default="free", help="free flow or the accident bottleneck")
    p.add_argument("--lanes", type=integer(MIN_LANES, MAX_LANES), default=3, help="number of lanes, 2-6")
    p.add_argument("--t-up", type=t_up_type(ControlConfig().dt_s), default=DemandConfig.t_up_s,
                   help="upstream departure interval (s)")  # fmt: skip
    p.add_argument("--policy", default="keep",
                   help="keep | random | greedy | mobil[:p=P,threshold=T,b_safe=B,bias=X] (MOBIL, p politeness) | "
                        "sumo[:lcCooperative=X,lcSpeedGain=Y,...] (SUMO's own Krauss and LC2013 models) | "
                        "dqn:PATH/model.pt or dqn:FOLDER (a trained model, or a training's folder holding model.pt), "
                        f"followed by any of {DQN_MODIFIERS} (alpha: for an alpha-conditioned model; the others "
                        "change how it drives; docs/model.md) | py:MODULE:CLASS (a class of your own in MODULE, a "
                        ".py file or a module name) | sb3:PATH (a Stable-Baselines3 DQN's model.zip); "
                        "docs/extending.md")  # fmt: skip
    p.add_argument("--steps", type=steps, default=DEFAULT_STEPS, help="steps of 0.1 s")
    p.add_argument("--seed", type=seed, default=0, help="seed of the demand, the policy and SUMO (0 to 2^31 - 1)")
    p.add_argument("--out", type=out_dir, required=True, help="run folder to write")
    p.add_argument("--trajectories", action="store_true", help="also write every vehicle's trajectory")
    p.add_argument("--accident-start", type=integer(0), default=None,
                   help=_accident_help("first accident step", 0))
    p.add_argument("--accident-steps", type=integer(1, MAX_STEPS), default=None,
                   help=_accident_help("its length in steps, the hold decaying from 1 to 0 over it", 1))
    add_road_flags(p)
    p.add_argument("--sumo-collision-check", action="store_true",
                   help="also count collisions with SUMO's own check (slower in jams)")  # fmt: skip
    p.add_argument("--read-every-step", action="store_true",
                   help="read every vehicle from SUMO every step (default: every 10 steps, the table advanced "
                        "exactly in between; same results)")  # fmt: skip
    p.add_argument("--fcd", action="store_true", help="also write SUMO's FCD output fcd.xml")
    p.add_argument("--fcd-period", type=number(0, MAX_FCD_PERIOD_S, low_open=True), default=None,
                   help="FCD period (s, a multiple of 0.1; default 1)")  # fmt: skip
    p.add_argument("--tripinfo", action="store_true", help="also write SUMO's tripinfo.xml")
    p.add_argument("--gui", action="store_true", help="run in sumo-gui (needs a display), vehicles coloured")
    p.add_argument("--gui-screenshot", type=Path, default=None,
                   help="PNG file for sumo-gui's screenshot, a new file (never written over), outside --out, the model "
                        "store and any study's or run's folder (default: none)")  # fmt: skip
    p.add_argument("--gui-screenshot-step", type=integer(1), default=None, help="its step (default: the last)")
    p.add_argument("--gui-delay", type=number(0, MAX_GUI_DELAY_MS), default=0.0,
                   help="sumo-gui's pause between steps (ms, at most 10,000)")  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def add_road_flags(p: Parser) -> None:
    """A road of one's own: its length, speed limit and loop spacing, the accident's position (config.RoadConfig,
    AccidentConfig; limits config.ROAD_LENGTH_M, SPEED_LIMIT_MPS, LOOP_SPACING_M; docs/extending.md)."""
    road, acc = RoadConfig(), AccidentConfig()
    p.add_argument("--road-length", type=number(*ROAD_LENGTH_M), default=road.length_m,
                   help=f"road length (m, {ROAD_LENGTH_M[0]:g} to {ROAD_LENGTH_M[1]:,g}; default {road.length_m:g})")
    p.add_argument("--speed-limit", type=number(*SPEED_LIMIT_MPS), default=road.speed_limit_mps,
                   help=f"lane speed limit (m/s, {SPEED_LIMIT_MPS[0]:g} to {SPEED_LIMIT_MPS[1]:g}; default "
                        f"{road.speed_limit_mps:g}); a limit below a vehicle's expected speed caps it")  # fmt: skip
    p.add_argument("--loop-spacing", type=number(*LOOP_SPACING_M), default=road.loop_spacing_m,
                   help=f"distance between the induction-loop cross-sections (m, {LOOP_SPACING_M[0]:g} to "
                        f"{LOOP_SPACING_M[1]:,g}, below the road's length; default {road.loop_spacing_m:g})")
    p.add_argument("--net-file", default=None,
                   help="a SUMO network of your own: refused with what the world needs (it drives only its own "
                        "straight highway; for a file that is one straight edge, the flags that build it; default: "
                        "none, the road of the flags below)")
    p.add_argument("--accident-x", type=number(0, ROAD_LENGTH_M[1], low_open=True), default=None,
                   help=f"the accident's position (m from the entrance, on the road; --scenario accident; default "
                        f"{acc.x_m:g})")  # fmt: skip


def road_from_args(args: Any) -> tuple[RoadConfig, float]:
    """The road of the flags and the accident's position (m); UsageError naming the flags when the road holds no
    loop or the accident lies beyond its end (config.road_problem states the rules)."""
    if args.net_file is not None:
        raise UsageError(f"--net-file: {network.net_file_refusal(args.net_file)}")
    road = RoadConfig(lanes=args.lanes, length_m=args.road_length, speed_limit_mps=args.speed_limit,
                      loop_spacing_m=args.loop_spacing)  # fmt: skip
    x_m = AccidentConfig.x_m if args.accident_x is None else args.accident_x
    if args.accident_x is not None and args.scenario != "accident":
        raise UsageError("--accident-x needs --scenario accident")
    if not road.loop_positions_m():
        raise UsageError(f"--loop-spacing {args.loop_spacing:g} leaves no loop on the {args.road_length:g} m road "
                         "(--road-length): it must be below the road's length")  # fmt: skip
    if args.scenario == "accident" and x_m >= road.length_m:
        given = "--accident-x" if args.accident_x is not None else "the default --accident-x"
        raise UsageError(f"--road-length {args.road_length:g} is too short for its accident: {given} {x_m:g} m must "
                         "lie below the road's end (a longer --road-length, or a smaller --accident-x)")  # fmt: skip
    return road, x_m


DEFAULT_FCD_PERIOD_S = 1.0


def outputs_from_args(args: Any, cfg: SimConfig) -> OutputConfig:
    """SUMO output files asked for on the command line (UsageError for a period without --fcd)."""
    if args.fcd_period is not None and not args.fcd:
        raise UsageError("--fcd-period needs --fcd")
    period = (DEFAULT_FCD_PERIOD_S if args.fcd_period is None else args.fcd_period) if args.fcd else 0.0
    outputs = OutputConfig(fcd_period_s=period, tripinfo=args.tripinfo)
    try:
        outputs.validate(cfg.control.dt_s)
    except ConfigError as err:
        raise UsageError(f"--fcd-period: {err}") from None
    return outputs


def screenshot_problem(shot: Path, out: Path) -> str | None:
    """Why sumo-gui may not write its screenshot at `shot` (a line naming --gui-screenshot), or None: the checks an
    output passes (a path SUMO can take, out_path_problem; no folder coopsumo owns, owners.owned_problem), and the
    rule of its own: a new file (an existing one, or a link, may be a user's or a study's: never written over), not
    inside --out `out` (the run replaces that folder whole). Issue 82, probe 7, I2."""
    flag = f"--gui-screenshot {shot}"
    if problem := out_path_problem(shot):
        return f"--gui-screenshot {problem.replace('folder path', 'path')}"
    if os.path.lexists(shot):
        what = "is a link" if shot.is_symlink() else "exists"
        return (f"{flag} {what}: the screenshot is written only as a new file, never over one (a user's or a "
                "study's); name a new file")  # fmt: skip
    if shot.resolve().is_relative_to(out.resolve()):
        return f"{flag} lies inside --out {out}, which the run writes whole; name a file outside it"
    parent = next(p for p in shot.absolute().parents if p.exists())
    if not os.access(parent, os.W_OK):  # a read-only file system too: found at the run's end (probe 15, T1)
        return f"{flag}: the folder {parent} cannot be written; name a screenshot file elsewhere"
    return owned_problem(shot, flag, "name a screenshot file elsewhere")


def gui_from_args(args: Any, cfg: SimConfig, environ: dict[str, str] | None = None) -> GuiConfig | None:
    """The sumo-gui view asked for, or None; UsageError without a display or for options without --gui."""
    env = os.environ if environ is None else environ
    if not args.gui:
        for flag, value in (("--gui-screenshot", args.gui_screenshot), ("--gui-screenshot-step",
                            args.gui_screenshot_step), ("--gui-delay", args.gui_delay or None)):  # fmt: skip
            if value is not None:
                raise UsageError(f"{flag} needs --gui")
        return None
    if args.gui_screenshot_step is not None and args.gui_screenshot is None:
        raise UsageError("--gui-screenshot-step needs --gui-screenshot")
    shot = args.gui_screenshot
    if shot is not None and shot.suffix.lower() != ".png":
        raise UsageError(f"--gui-screenshot must be a .png file, got {str(shot)!r}")
    if shot is not None and (problem := screenshot_problem(shot, args.out)):
        raise UsageError(problem)
    if args.gui_screenshot_step is not None:
        check_int("--gui-screenshot-step", args.gui_screenshot_step, 1, cfg.steps, " (a step of the run)")
    gui = GuiConfig(
        screenshot=str(shot.resolve()) if shot is not None else "",
        screenshot_step=cfg.steps if args.gui_screenshot_step is None else args.gui_screenshot_step,
        delay_ms=args.gui_delay,
    )
    gui.validate(cfg.steps)
    if not env.get("DISPLAY"):
        raise UsageError("--gui needs a display and DISPLAY is not set (without a screen: xvfb-run, see "
                         "docs/sumo-tools.md)")
    if shot is not None:
        try:
            shot.resolve().parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise UsageError(f"cannot write the screenshot {shot}: {err.strerror}") from None
    return gui


def config_from_args(args: Any) -> SimConfig:
    """The run's configuration; UsageError naming the flag for values that depend on each other."""
    check_t_up("--t-up", args.t_up, ControlConfig().dt_s)
    if args.scenario != "accident":  # like --fcd-period without --fcd: a flag that would be ignored is refused
        for flag, value in (("--accident-start", args.accident_start), ("--accident-steps", args.accident_steps)):
            if value is not None:
                raise UsageError(f"{flag} needs --scenario accident")
    start, duration = AccidentConfig.start_step, AccidentConfig.duration_steps  # free flow: not used
    if args.scenario == "accident":
        start, duration = default_accident(args.steps)
        start = start if args.accident_start is None else args.accident_start
        duration = duration if args.accident_steps is None else args.accident_steps
        check_accident(start, duration, args.steps)
    road, x_m = road_from_args(args)
    cfg = SimConfig(
        road=road,
        demand=DemandConfig(t_up_s=args.t_up),
        accident=AccidentConfig(
            enabled=args.scenario == "accident", x_m=x_m, start_step=start, duration_steps=duration
        ),
        steps=args.steps,
        seed=args.seed,
        policy=args.policy,
        sumo_collision_check=args.sumo_collision_check,
        full_read_every_steps=1 if args.read_every_step else SimConfig.full_read_every_steps,
    )
    cfg.validate()
    return cfg


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)

    def body() -> int:
        cfg = config_from_args(args)
        try:
            parse_policy(cfg.policy)  # the grammar first, before any file is looked at
        except PolicySpecError as err:
            raise UsageError(f"--policy: {err}") from None
        if (read := policy_file(cfg.policy)) is not None:  # a model or module file: never written over
            check_apart(args.out, Path(read))
        if problem := owned_problem(args.out, f"--out {args.out}"):  # a study's, the store's, a training's folder
            raise UsageError(problem)
        check_run_dir(args.out, "simulate")  # before anything is written (the screenshot's folder, the run)
        check_no_outside_link(args.out)  # a link in its own folder out to a user's file, as train refuses
        outputs = outputs_from_args(args, cfg)
        gui = gui_from_args(args, cfg)
        try:
            policy = policy_for_run(cfg)
        except UsageError as err:
            own = cfg.policy.startswith(("dqn:", "py:", "sb3:"))
            flag = "--policy" if own else f"--policy {cfg.policy}"  # a model's or module's error names it
            raise UsageError(f"{flag}: {err}") from None
        closed = sumo_session.gui_closed_errors() if gui is not None else ()
        try:
            with atomic_run_dir(args.out) as tmp:
                summary = run(cfg, policy, tmp, trajectories=args.trajectories, progress=not args.quiet,
                              outputs=outputs, gui=gui)  # fmt: skip
        except closed:
            print("simulate: sumo-gui was closed before the run ended; nothing written", file=sys.stderr)
            return 1
        keys = ("departed", "arrived", "mean_speed_mps", "lane_changes", "collisions", "teleports", "steps_per_second")
        print(" ".join(f"{k}={summary[k]:.4g}" if isinstance(summary[k], float) else f"{k}={summary[k]}" for k in keys))
        return 0

    return run_cli("simulate", body)


if __name__ == "__main__":
    sys.exit(main())
