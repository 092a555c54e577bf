"""`make bench`: speed figures (printed, not asserted).

- simulation throughput (steps/s) of the world alone, per policy, in free flow and in a jam;
- the controlled `keep` policy against SUMO alone on the same network, demand and seed, with the table read
  every 10 steps (the default) and every step (--read-every-step); the "jam ratio" and "free flow ratio" lines;
- training throughput (environment steps/s with learning on), and the training ratio: a default training's
  wall time over that of the same steps of the same worlds driven by `keep`;
- the three ratios of a training's own cost: the learn ratio (a default training without model selection over `keep`
  on the same worlds and steps, wall time), the greedy ratio (a default model's greedy run over `keep`'s, CPU time, in
  free flow and through the accident) and the selection share (model selection's share of a default training's wall
  time, on a schedule scaled to the bench's steps);
- observation and decision cost per vehicle per step (grids; one batched DQN forward pass).
- what SUMO's FCD output (--fcd) at scenario I's period adds to a jammed run's wall time.
- `--cluster` (alone): a study's cells on a real Ray cluster of one node, then of two (Ray's cluster_utils on this
  machine, one CPU each), beside the local backend with one and two workers: the scaling from one node to two.
"""

from __future__ import annotations

import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from coopsumo.agents.policies import make_policy
from coopsumo.agents.rollout import run
from coopsumo.config import AccidentConfig, DemandConfig, RoadConfig, SimConfig, TrainConfig
from coopsumo.dqn_config import DQN_PRESETS
from coopsumo.files import read_json
from coopsumo.runio import (
    Parser,
    Stop,
    children_start_deaf,
    environment_problem,
    stop_on_signals,
    training_stop,
    working_folder_problem,
)
from coopsumo.sim import fast
from coopsumo.sim.physics import occupancy


def bench_simulation(
    policy: str, steps: int, lanes: int = 3, t_up: float = 1.0, jam: bool = False, sumo_check: bool = False,
    read_every_step: bool = False,
) -> tuple[float, float, float]:  # fmt: skip
    """(steps/s, mean vehicles on the road, share of the wall time inside SUMO's simulationStep);
    jam: the accident holds traffic from step 100 on; read_every_step: as --read-every-step."""
    cfg = SimConfig(
        road=RoadConfig(lanes=lanes),
        demand=DemandConfig(t_up_s=t_up),
        accident=AccidentConfig(enabled=jam, start_step=100, duration_steps=50_000),
        steps=steps,
        seed=1,
        policy=policy,
        sumo_collision_check=sumo_check,
        full_read_every_steps=1 if read_every_step else SimConfig.full_read_every_steps,
    )
    with tempfile.TemporaryDirectory() as tmp:
        summary = run(cfg, make_policy(policy, np.random.default_rng(1)), Path(tmp), progress=False)
    sps, veh, share = (float(summary[k]) for k in ("steps_per_second", "mean_vehicles_on_road", "sumo_step_share"))
    return sps, veh, share


def bench_plain_vs_controlled(steps: int, jam: bool, rounds: int = 1) -> dict[str, tuple[float, float, float]]:
    """(steps per CPU second, mean vehicles on the road, share of the wall time inside SUMO's step) on one network,
    demand and seed: SUMO alone with its own models ("plain"; in the jam every lane is blocked at the bottleneck
    from step 100), the same plus reading every vehicle's lane, position and speed each step ("plain+read"),
    and the controlled `keep` policy ("keep"; the accident holds traffic from step 100), also with a full read
    every step ("keep every step"). CPU time of this process (SUMO runs in it), whole call including SUMO's
    start, so that other work on a shared machine slows neither side; the median of `rounds` rounds, each
    running the four in another order. The share is 0 for the plain runs."""
    from coopsumo.sim.sumo_session import plain_run
    from coopsumo.sim.world import departures

    cfg = SimConfig(accident=AccidentConfig(enabled=jam, start_step=100, duration_steps=50_000), steps=steps, seed=1,
                    policy="sumo")  # fmt: skip
    block = cfg.accident.start_step * cfg.control.dt_s if jam else None

    def plain(read: bool) -> tuple[float, float]:
        with tempfile.TemporaryDirectory() as tmp:
            return plain_run(cfg, Path(tmp), departures(cfg), block, read_table=read)[1], 0.0

    def keep(every_step: bool) -> tuple[float, float]:
        _, veh, share = bench_simulation("keep", steps, jam=jam, read_every_step=every_step)
        return veh, share

    runs = {"plain": lambda: plain(False), "plain+read": lambda: plain(True), "keep": lambda: keep(False),
            "keep every step": lambda: keep(True)}  # fmt: skip
    rates: dict[str, list[float]] = {name: [] for name in runs}
    last: dict[str, tuple[float, float]] = {}
    names = list(runs)
    for r in range(rounds):
        for name in names[r % len(names) :] + names[: r % len(names)]:
            start = time.process_time()
            last[name] = runs[name]()
            rates[name].append(steps / (time.process_time() - start))
    return {name: (float(np.median(rates[name])), *last[name]) for name in names}


def bench_training(steps: int, preset: str = "default") -> float:
    from coopsumo.agents.train import Trainer  # torch: imported once main has checked the working folder

    cfg = TrainConfig(sim=SimConfig(steps=steps, seed=1, policy="dqn"), dqn=DQN_PRESETS[preset], eval_steps=0)
    with tempfile.TemporaryDirectory() as tmp:
        trainer = Trainer(cfg, Path(tmp), progress=False)
        start = time.perf_counter()
        trainer.run()
        return steps / (time.perf_counter() - start)


def bench_training_ratio(steps: int) -> tuple[float, float, float]:
    """training_against_keep for the default learner and schedule (validation included, no final evaluation),
    training seed 1. Wall times: the pipelined training uses both cores."""
    return training_against_keep(TrainConfig(sim=SimConfig(steps=steps, seed=1, policy="dqn"), eval_steps=0))


def training_against_keep(cfg: TrainConfig) -> tuple[float, float, float]:
    """(wall s of the training cfg with its updates in a second process, the same serially, `keep` on the same worlds
    and steps: keep_on_training_worlds)."""
    from coopsumo.agents.train import train

    walls = []
    for process in (True, False):
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            train(cfg, Path(tmp) / "train", progress=False, learner_process=process)
            walls.append(time.perf_counter() - start)
    return walls[0], walls[1], keep_on_training_worlds(cfg)


def keep_on_training_worlds(cfg: TrainConfig) -> float:
    """Wall s of `keep` driving the worlds of the training cfg (agents/episodes.py) for as many steps as it spends in
    each."""
    from coopsumo.agents.episodes import episode_bounds, episode_config, episodic

    start = time.perf_counter()
    done = 0
    while done < cfg.sim.steps:
        index, first, end = episode_bounds(cfg.sim.steps, cfg.dqn, done)
        world = episode_config(cfg.sim, cfg.dqn, index) if episodic(cfg.dqn) else cfg.sim
        with tempfile.TemporaryDirectory() as tmp:
            run(replace(world, steps=end - first, policy="keep"), make_policy("keep", np.random.default_rng(1)),
                Path(tmp), progress=False)  # fmt: skip
        done = end
    return time.perf_counter() - start


def without_selection(steps: int) -> TrainConfig:
    """A default training of `steps` steps, training seed 1, without model selection or final evaluation."""
    dqn = replace(DQN_PRESETS["default"], select_every_steps=0)
    return TrainConfig(sim=SimConfig(steps=steps, seed=1, policy="dqn"), dqn=dqn, eval_steps=0)


def bench_learn_ratio(steps: int) -> tuple[float, float, float]:
    """training_against_keep for a default training without model selection (without_selection)."""
    return training_against_keep(without_selection(steps))


def scaled_selection(steps: int) -> TrainConfig:
    """A default training of `steps` steps whose model selection costs what the default's costs a 90,000-step
    training: 6 snapshots, each validated on runs scaled by steps / 90,000 (accident runs at least
    MIN_ACCIDENT_VALIDATION_STEPS), so that it runs as many greedy steps per training step."""
    from coopsumo.dqn_config import MIN_ACCIDENT_VALIDATION_STEPS

    dq = DQN_PRESETS["default"]
    scale = steps / 90_000
    dq = replace(dq, select_every_steps=max(steps // 6, 1), validation_steps=max(int(dq.validation_steps * scale), 100),
                 validation_accident_steps=max(int(dq.validation_accident_steps * scale),
                                               MIN_ACCIDENT_VALIDATION_STEPS))  # fmt: skip
    return TrainConfig(sim=SimConfig(steps=steps, seed=1, policy="dqn"), dqn=dq, eval_steps=0)


def bench_selection_share(steps: int) -> tuple[float, float, float, float]:
    """(wall s of a default training with its model selection scaled to `steps` (scaled_selection), the same training
    without selection, the CPU s of the selection's processes, the CPU s of the whole training with them, this
    process's included): both with the updates in a second process. The share is 1 - without / with."""
    from coopsumo.agents.train import train
    from coopsumo.studies.engine.groups import children_cpu_s as children_cpu

    with_cfg = scaled_selection(steps)
    without_cfg = replace(with_cfg, dqn=replace(with_cfg.dqn, select_every_steps=0))
    walls, cpus = [], []
    for cfg in (with_cfg, without_cfg):
        with tempfile.TemporaryDirectory() as tmp:
            start, cpu0, own0 = time.perf_counter(), children_cpu(), time.process_time()
            train(cfg, Path(tmp) / "train", progress=False, learner_process=True)
            walls.append(time.perf_counter() - start)
            cpus.append((children_cpu() - cpu0, time.process_time() - own0))
    (kids_with, own_with), (kids_without, _) = cpus
    return walls[0], walls[1], kids_with - kids_without, kids_with + own_with


def bench_greedy_ratio(model: Path, steps: int, jam: bool, rounds: int = 1) -> tuple[float, float, float]:
    """(CPU s of `model`'s greedy run, CPU s of `keep`'s, lane changes per vehicle of the greedy run): the same world
    and seed (3 lanes, T_up 1 s; jam: the accident from step steps // 12 for 5/6 of the run), CPU time of this process
    (SUMO runs in it), the model loaded inside the timed call; the median of `rounds` rounds, in rotated order."""
    accident = AccidentConfig(enabled=jam, start_step=steps // 12, duration_steps=steps * 5 // 6)
    cfg = SimConfig(accident=accident, steps=steps, seed=2)
    times: dict[str, list[float]] = {"dqn": [], "keep": []}
    changes = 0.0
    for r in range(rounds):
        for name in ("dqn", "keep") if r % 2 == 0 else ("keep", "dqn"):
            spec = f"dqn:{model}" if name == "dqn" else "keep"
            with tempfile.TemporaryDirectory() as tmp:
                start = time.process_time()
                summary = run(replace(cfg, policy=spec), make_policy(spec, np.random.default_rng(2)), Path(tmp),
                              progress=False)  # fmt: skip
                times[name].append(time.process_time() - start)
            if name == "dqn":
                changes = float(summary["lane_changes_per_vehicle"])
    return float(np.median(times["dqn"])), float(np.median(times["keep"])), changes


def bench_model(steps: int, folder: Path) -> Path:
    """A default model for the greedy ratio: a default training of `steps` steps (seed 1, no model selection) in
    folder; returns its model.pt."""
    from coopsumo.agents.train import train

    train(without_selection(steps), folder, progress=False, learner_process=True)
    return folder / "model.pt"


def bench_decision(n_vehicles: int, repeats: int = 200) -> tuple[float, float]:
    """(grid build, DQN forward) cost in microseconds per vehicle per step."""
    rng = np.random.default_rng(0)
    lane = rng.integers(0, 3, n_vehicles)
    pos = np.sort(rng.uniform(0, 2000, n_vehicles))
    occ = occupancy(lane, pos, np.full(n_vehicles, -1))
    start = time.perf_counter()
    for _ in range(repeats):
        fast.snapshot(occ, lane, pos, 3, 4.0)
    grid_us = (time.perf_counter() - start) / repeats / n_vehicles * 1e6
    from coopsumo.agents.dqn import Learner
    from coopsumo.dqn_config import DQNConfig

    learner = Learner(DQNConfig(), 0)
    grids = rng.integers(0, 2, (n_vehicles, 3, 3, 20)).astype(np.uint8)
    err = rng.normal(size=(n_vehicles, learner.online.n_features)).astype(np.float32)
    start = time.perf_counter()
    for _ in range(repeats):
        learner.act(grids, err, explore=False)
    act_us = (time.perf_counter() - start) / repeats / n_vehicles * 1e6
    return grid_us, act_us


def bench_fcd_cost(steps: int, period_s: float, repeats: int) -> tuple[float, float, float, float, float]:
    """What --fcd adds to a jammed keep run (accident from step 100): (median extra wall time %, its lowest
    and highest value %, FCD MB per simulated hour, mean vehicles on the road). Each of `repeats` pairs
    runs `python -m coopsumo.simulate` with and without --fcd at the same time, in two processes (one per
    core on a quiet 2-core machine), so that load from other work hits both alike; who starts first alternates."""
    import subprocess

    args = ["--scenario", "accident", "--accident-start", "100", "--accident-steps", "50000", "--steps", str(steps),
            "--seed", "1", "--quiet"]  # fmt: skip
    extra: list[float] = []
    size_mb = vehicles = 0.0
    for i in range(repeats):
        with tempfile.TemporaryDirectory() as tmp:
            runs = [("plain", []), ("fcd", ["--fcd", "--fcd-period", f"{period_s:g}"])]
            with children_start_deaf():  # a Ctrl-C is this process's: it stops them (below), they print nothing
                procs = {name: subprocess.Popen([sys.executable, "-m", "coopsumo.simulate", *args, *flags, "--out",
                                                 f"{tmp}/{name}"], stdout=subprocess.DEVNULL)
                         for name, flags in (runs if i % 2 == 0 else runs[::-1])}  # fmt: skip
            try:
                if any(proc.wait() != 0 for proc in procs.values()):
                    raise RuntimeError("a bench run of coopsumo.simulate failed")
            finally:
                for proc in procs.values():
                    if proc.poll() is None:
                        proc.kill()
                        proc.wait()
            summary = {name: read_json(Path(tmp) / name / "summary.json") for name in procs}
            extra.append(100 * (summary["fcd"]["wall_seconds"] / summary["plain"]["wall_seconds"] - 1))
            size_mb = (Path(tmp) / "fcd" / "fcd.xml").stat().st_size / 1e6
            vehicles = float(summary["plain"]["mean_vehicles_on_road"])
    hours = steps * SimConfig().control.dt_s / 3600
    return float(np.median(extra)), min(extra), max(extra), size_mb / hours, vehicles


def world_lines(steps: int, quick: bool) -> None:
    """The world's lines: simulation throughput per policy, and controlled keep against plain SUMO."""
    for policy in ("keep", "random", "greedy", "mobil", "sumo"):
        sps, veh, _ = bench_simulation(policy, steps)
        print(f"  simulate --policy {policy:7s}: {sps:8.0f} steps/s  ({veh:.0f} vehicles on the road)", flush=True)
    for policy, check in (("keep", False), ("keep", True), ("mobil", False)):
        sps, veh, _ = bench_simulation(policy, steps, jam=True, sumo_check=check)
        label = f"{policy}{' + SUMO collision check' if check else ''}"
        print(f"  jammed (accident) {label:30s}: {sps:8.0f} steps/s  ({veh:.0f} vehicles on the road)", flush=True)
    ratios = {}
    for jam in (True, False):
        r = bench_plain_vs_controlled(steps, jam, rounds=1 if quick else 3)
        (p_sps, p_veh, _), (r_sps, _, _), (k_sps, k_veh, k_share), (e_sps, _, _) = (
            r["plain"], r["plain+read"], r["keep"], r["keep every step"])  # fmt: skip
        where = "jam (accident)" if jam else "free flow     "
        print(f"  {where}: steps per CPU second: plain SUMO {p_sps:6.0f} ({p_veh:.0f} veh), with a full read every "
              f"step {r_sps:6.0f}; controlled keep {k_sps:6.0f} ({k_veh:.0f} veh), with --read-every-step "
              f"{e_sps:6.0f}", flush=True)  # fmt: skip
        # SUMO's step inside the controlled run bounds the ratio: with Python costing nothing it would be this
        print(f"  {where}: SUMO's own step is {100 * k_share:.0f}% of the controlled run's wall time: ratio "
              f"ceiling {k_sps / k_share / p_sps:.2f} with zero Python cost", flush=True)  # fmt: skip
        ratios["jam" if jam else "free flow"] = (k_sps / p_sps, e_sps / p_sps)
    for name, target in (("jam", 0.5), ("free flow", 0.35)):
        new, every = ratios[name]
        print(f"{name} ratio {new:.2f}  (controlled keep / plain SUMO, steps per CPU second, same network, demand "
              f"and seed, median of {1 if quick else 3} rounds; target >= {target:g}; {every:.2f} with "
              "--read-every-step)", flush=True)  # fmt: skip


def learner_lines(steps: int, quick: bool, model: Path | None) -> None:
    """The learner's lines: training throughput, the training ratio, and the learn ratio, greedy ratio and selection
    share (a training's own cost, a learned policy's decisions and the model selection, each against keep)."""
    model_given = model is not None
    for preset in ("default", "paper"):
        sps = bench_training(steps, preset)
        print(f"  train --preset {preset:8s}     : {sps:8.0f} steps/s  -> 90,000 steps in {90000 / sps / 60:.1f} min",
              flush=True)  # fmt: skip
    ratio_steps = 900 if quick else 18_000
    pipelined, serial, keep = bench_training_ratio(ratio_steps)
    print(f"  train (default, {ratio_steps:,} steps, validation included): {pipelined:.1f} s with the updates in a "
          f"second process, {serial:.1f} s serially; keep on the same worlds {keep:.1f} s", flush=True)  # fmt: skip
    print(f"training ratio {pipelined / keep:.2f}  (default training / keep on the same worlds and steps, wall time; "
          f"target <= 1.3; {serial / keep:.2f} serially)", flush=True)  # fmt: skip
    learn, learn_serial, learn_keep = bench_learn_ratio(ratio_steps)
    print(f"  train (default, {ratio_steps:,} steps, no model selection): {learn:.1f} s with the updates in a second "
          f"process, {learn_serial:.1f} s serially; keep on the same worlds {learn_keep:.1f} s",
          flush=True)  # fmt: skip
    print(f"learn ratio {learn / learn_keep:.2f}  (default training without model selection / keep on the same worlds "
          f"and steps, wall time, updates in a second process; target <= 2.5; {learn_serial / learn_keep:.2f} "
          "serially)", flush=True)  # fmt: skip
    greedy_steps = 600 if quick else 8000
    with tempfile.TemporaryDirectory() as tmp:
        model = model or bench_model(600 if quick else 6000, Path(tmp) / "model")
        ratios = {}
        for jam in (False, True):
            dqn_cpu, keep_cpu, changes = bench_greedy_ratio(model, greedy_steps, jam, rounds=1 if quick else 3)
            where = "through the accident" if jam else "free flow"
            print(f"  greedy {where:20s}: {dqn_cpu:.1f} s of CPU, keep {keep_cpu:.1f} s ({greedy_steps:,} steps, "
                  f"{changes:.2f} lane changes per vehicle)", flush=True)  # fmt: skip
            ratios[where] = dqn_cpu / keep_cpu
    shown = "the --model given" if model_given else f"a {600 if quick else 6000:,}-step default training"
    print(f"greedy ratio {ratios['free flow']:.2f} free flow, {ratios['through the accident']:.2f} through the accident"
          f"  (greedy run of {shown} / keep's, same world and seed, CPU time; target <= 1.2)", flush=True)  # fmt: skip
    if quick:  # a selection scaled to a short training is its accident runs' floor (MIN_ACCIDENT_VALIDATION_STEPS)
        print("selection share and group cost: not in --quick (at its short trainings the model selection is its "
              "runs' minimum lengths: 80% of the time, a share that says nothing)", flush=True)  # fmt: skip
        return
    with_s, without_s, selection_cpu, total_cpu = bench_selection_share(ratio_steps)
    print(f"  train (default, {ratio_steps:,} steps, selection scaled to it): {with_s:.1f} s, without selection "
          f"{without_s:.1f} s; the selection's processes {selection_cpu:.1f} of {total_cpu:.1f} CPU s", flush=True)
    print(f"selection share {100 * (1 - without_s / with_s):.0f}%  (model selection's share of a default training's "
          f"wall time: 6 snapshots validated on runs scaled by {ratio_steps:,} / 90,000; target <= 30%; "
          f"{100 * selection_cpu / total_cpu:.0f}% of its CPU time)", flush=True)  # fmt: skip
    from coopsumo.bench.group import group_lines

    lone = (total_cpu, with_s)  # the group's lone training is the selection share's with selection
    print("\n".join(group_lines(scaled_selection(ratio_steps), 8, lone)), flush=True)


def decision_and_output_lines(steps: int, quick: bool) -> None:
    """Observation and decision cost per vehicle, and what SUMO's FCD output costs a jammed run."""
    for n in (50, 200):
        grid_us, act_us = bench_decision(n, repeats=20 if quick else 200)
        print(f"  {n:3d} vehicles: grid {grid_us:.2f} us/veh/step, DQN decision {act_us:.2f} us/veh/step", flush=True)
    from coopsumo.studies.scenario1.plan import DEFAULT_PROFILE, PROFILES

    period = PROFILES[DEFAULT_PROFILE].fcd_period_s
    extra, low, high, mb_per_h, veh = bench_fcd_cost(steps, period, repeats=1 if quick else 4)
    print(f"  --fcd every {period:g} s (scenario I), jammed keep run ({veh:.0f} vehicles): {extra:+.1f}% wall time "
          f"(median of runs side by side; {low:+.1f} to {high:+.1f}%; limit 10%), {mb_per_h:.0f} MB of fcd.xml "
          f"per simulated hour{' (--quick: runs too short to tell)' if quick else ''}", flush=True)  # fmt: skip


def model_path(text: str) -> Path:
    """--model: an existing model file (a training's folder stands for its model.pt)."""
    import argparse

    path = Path(text)
    if path.is_dir():
        path = path / "model.pt"
    from coopsumo.files import not_regular

    if kind := not_regular(path):  # /dev/zero, a named pipe: never read (issue 82, probe 7, I17c)
        raise argparse.ArgumentTypeError(f"{path} is not a regular file but {kind}")
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"no model file at {path}")
    return path.resolve()


def build_parser() -> Parser:
    parser = Parser(prog="coopsumo bench", description="Speed figures (printed, not asserted).")
    parser.add_argument("--quick", action="store_true",
                        help="short runs (600 steps; 900 for the learner's ratios), a first look: without the "
                             "selection share and the group cost, which need long trainings")
    parser.add_argument("--cluster", action="store_true",
                        help="only the Ray scaling: a study on a cluster of 1, then 2 nodes (needs the ray extra)")
    parser.add_argument("--model", type=model_path, default=None,
                        help="the model.pt of the greedy ratio (default: a 6,000-step default training made first)")
    parser.add_argument("--learner", action="store_true",
                        help="only the learner's lines: training throughput and the training, learn, greedy and "
                             "selection ratios")
    return parser


def main(argv: list[str] | None = None) -> int:
    """`coopsumo bench`; SIGINT and SIGTERM end it in one line and 128 + the signal wherever they land, a training's
    own stop too (runio.training_stop; issue 82, probe 4, F14: it was a traceback, exit code 1)."""
    with stop_on_signals():
        try:
            return _main(argv)
        except Exception as err:
            if (signum := training_stop(err)) is None:
                raise
            raise Stop(signum) from None


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.cluster and (beside := next((f for f, on in (("--learner", args.learner), ("--model", args.model))
                                         if on), None)):  # fmt: skip
        parser.error(f"--cluster runs only the Ray scaling, which {beside} has no part in (the learner's lines): "
                     "give one or the other")  # fmt: skip
    quick = args.quick
    steps = 600 if quick else 6000
    if problem := working_folder_problem() or environment_problem():  # torch cannot be loaded from a deleted folder
        parser.error(problem)
    if args.cluster:
        try:
            import ray  # noqa: F401
        except ImportError:
            parser.error("--cluster needs Ray: .venv/bin/pip install 'ray[default]'")
        from coopsumo.bench.cluster import cluster_lines

        return cluster_lines(quick)
    import torch

    torch.set_num_threads(1)
    if args.model is not None:  # read as --policy dqn: reads it, before the trainings, which take minutes
        from coopsumo.agents.model_file import ModelFileError, load_model

        try:
            load_model(args.model)
        except ModelFileError as err:
            parser.error(f"--model: {err}")
    print(f"coopsumo bench (3 lanes, T_up 1.0 s, 1 torch thread, {steps} steps a run)", flush=True)
    if not args.learner:
        world_lines(steps, quick)
    learner_lines(steps, quick, args.model)
    if not args.learner:
        decision_and_output_lines(steps, quick)
    return 0

