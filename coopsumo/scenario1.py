"""`python -m coopsumo.scenario1` (`make scenario1`): the accident-bottleneck study of section IV.A.

1. trains (or reuses) the alpha = 0 and alpha = 8 models in free flow, in parallel;
2. runs every policy (the two DQNs and the baselines) in the accident scenario, per seed;
3. writes results/scenario1/: run folders (with SUMO's fcd.xml and tripinfo.xml), fig4_time_space.png,
   fig5_flow_density.png, summary.csv and report.md; with a display, gui_jam.png: sumo-gui's view of
   the jam at the bottleneck, replayed through TraCI.
"""

from __future__ import annotations

import json
import math
import multiprocessing as mp
import os
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from tqdm import tqdm

from coopsumo import view
from coopsumo.config import (
    AccidentConfig,
    ControlConfig,
    DemandConfig,
    OutputConfig,
    RewardConfig,
    RoadConfig,
    SimConfig,
    TrainConfig,
    to_dict,
)
from coopsumo.runio import Parser, UsageError, run_cli, start_parent_watch, versions, write_json

ALPHAS = (0.0, 8.0)
BASELINES = ("keep", "greedy", "mobil:p=0.5", "sumo")
FIG4_LANE = 0  # the paper's "lane 1" taken as the rightmost lane, SUMO index 0
SLOW_MPS = 5.0
RECOVERY_MPS = 15.0
STOP_GO_UPSTREAM_M = 1000.0
GUI_RUN = "dqn_alpha8"  # the run sumo-gui shows: the cooperative model, first seed
GUI_SHOT = "gui_jam.png"
JAM_SHARE = 0.9  # the screenshot step: the first time the view holds this share of its most slow vehicles


@dataclass(frozen=True)
class Plan:
    """Sizes of the study (paper scale by default; --quick shrinks every count)."""

    lanes: int = 3
    t_up_s: float = DemandConfig.t_up_s
    train_steps: int = 90_000
    steps: int = 90_000
    accident_start: int = AccidentConfig.start_step
    accident_steps: int = AccidentConfig.duration_steps
    seeds: tuple[int, ...] = (1, 2, 3)
    train_seed: int = 0
    trajectory_every: int = 5
    loop_period_s: float = 60.0
    baselines: tuple[str, ...] = BASELINES
    fcd_period_s: float = 5.0
    """period of SUMO's fcd.xml in every run folder (s): about 40 MB per paper-scale run"""
    tripinfo: bool = True
    """write SUMO's tripinfo.xml in every run folder"""

    def outputs(self) -> OutputConfig:
        """SUMO's output files of every accident run."""
        return OutputConfig(fcd_period_s=self.fcd_period_s, tripinfo=self.tripinfo)

    @staticmethod
    def quick() -> Plan:
        return Plan(train_steps=3000, steps=6000, accident_start=1000, accident_steps=3000, seeds=(1, 2),
                    loop_period_s=30.0)  # fmt: skip


def train_config(plan: Plan, alpha: float) -> TrainConfig:
    """The free-flow training of one model."""
    sim = SimConfig(
        road=RoadConfig(lanes=plan.lanes, loop_period_s=plan.loop_period_s),
        demand=DemandConfig(t_up_s=plan.t_up_s),
        reward=RewardConfig(alpha=alpha),
        steps=plan.train_steps,
        seed=plan.train_seed,
        policy="dqn",
    )
    return TrainConfig(sim=sim, eval_steps=0)


def accident_config(plan: Plan, policy: str, seed: int) -> SimConfig:
    return SimConfig(
        road=RoadConfig(lanes=plan.lanes, loop_period_s=plan.loop_period_s),
        demand=DemandConfig(t_up_s=plan.t_up_s),
        accident=AccidentConfig(enabled=True, start_step=plan.accident_start, duration_steps=plan.accident_steps),
        steps=plan.steps,
        seed=seed,
        policy=policy,
    )


# -- jobs run in worker processes (one SUMO per process) -------------------------------------
_WORKER_COUNTER: Any = None  # shared step counter of the pool, set by _init_worker


def _init_worker(counter: Any, parent_pid: int) -> None:
    global _WORKER_COUNTER
    _WORKER_COUNTER = counter
    start_parent_watch(parent_pid)


def _bump(n: int) -> None:
    if _WORKER_COUNTER is not None:
        with _WORKER_COUNTER.get_lock():
            _WORKER_COUNTER.value += n


def train_job(cfg_dict: dict[str, Any], out: str) -> str:
    """Train one model into `out`."""
    import torch

    from coopsumo.config import train_config_from_dict
    from coopsumo.train import train

    torch.set_num_threads(1)
    train(train_config_from_dict(cfg_dict), Path(out), progress=False, on_steps=_bump)
    return out


def sim_job(cfg_dict: dict[str, Any], out: str, trajectory_every: int, outputs: dict[str, Any] | None = None) -> str:
    """Run one simulation into the run folder `out` (written atomically); outputs: an OutputConfig as a dict."""
    import torch

    from coopsumo.config import sim_config_from_dict
    from coopsumo.policies import make_policy
    from coopsumo.runio import discard_run_dir, finish_run_dir, start_run_dir
    from coopsumo.simulate import run

    torch.set_num_threads(1)
    cfg = sim_config_from_dict(cfg_dict)
    policy = make_policy(cfg.policy, np.random.default_rng([cfg.seed, 3]))
    tmp = start_run_dir(Path(out))
    try:
        run(cfg, policy, tmp, trajectories=True, progress=False, trajectory_every=trajectory_every, on_steps=_bump,
            outputs=OutputConfig(**outputs) if outputs else None)  # fmt: skip
    except BaseException:
        discard_run_dir(tmp)
        raise
    finish_run_dir(tmp, Path(out))
    return out


def gui_run(cfg: SimConfig, shot: Path) -> dict[str, list[Any]]:
    """Run cfg's simulation in sumo-gui (through TraCI, so in this process) to its last step and save
    sumo-gui's screenshot of that step to shot. Returns that step's vehicles (vid, lane, pos_m, speed_mps)."""
    import tempfile

    from coopsumo.config import GuiConfig
    from coopsumo.policies import make_policy
    from coopsumo.simulate import run

    policy = make_policy(cfg.policy, np.random.default_rng([cfg.seed, 3]))
    gui = GuiConfig(screenshot=str(shot.resolve()), screenshot_step=cfg.steps)
    with tempfile.TemporaryDirectory(prefix="gui-run-") as tmp:
        run(cfg, policy, Path(tmp), trajectories=True, label="sumo-gui screenshot", trajectory_every=cfg.steps, gui=gui)
        last = pd.read_parquet(Path(tmp) / "trajectories.parquet")
    return {k: last[k].tolist() for k in ("vid", "lane", "pos_m", "speed_mps")}


def _same_config(path: Path, cfg: dict[str, Any]) -> bool:
    """True when path (config.json) records exactly this configuration."""
    try:
        return bool(json.loads(path.read_text())["config"] == json.loads(json.dumps(cfg)))
    except (OSError, ValueError, KeyError):
        return False


def _reusable_run(out: Path, cfg: SimConfig, outputs: OutputConfig) -> bool:
    """True when out holds a finished run of cfg with the SUMO output files `outputs` asks for."""
    if not ((out / "summary.json").exists() and _same_config(out / "config.json", to_dict(cfg))):
        return False
    try:
        recorded = json.loads((out / "config.json").read_text()).get("sumo_outputs")
    except (OSError, ValueError):
        return False
    files = (["fcd.xml"] if outputs.fcd_period_s > 0 else []) + (["tripinfo.xml"] if outputs.tripinfo else [])
    return recorded == to_dict(outputs) and all((out / f).exists() for f in files)


def jam_step(traj: pd.DataFrame, cfg: SimConfig) -> int | None:
    """The step sumo-gui photographs: the first recorded step whose view (VIEW_UPSTREAM_M before the
    bottleneck) holds JAM_SHARE of the most vehicles slower than SLOW_MPS it ever holds; None if never any."""
    acc = cfg.accident
    near = traj["pos_m"].between(acc.x_m - view.VIEW_UPSTREAM_M, acc.x_m) & (traj["speed_mps"] < SLOW_MPS)
    counts = traj[near].groupby("time_s").size()
    if counts.empty:
        return None
    t = float(counts.index[counts >= JAM_SHARE * counts.max()][0])
    return int(round(t / cfg.control.dt_s))


def gui_section(root: Path, run_dir: Path, label: str, cfg: SimConfig, environ: dict[str, str] | None = None) -> str:
    """The report's sumo-gui screenshot of the jam (made, or reused when the same), or a note why there is none."""
    env = os.environ if environ is None else environ
    shot = root / GUI_SHOT
    if not env.get("DISPLAY"):
        shot.unlink(missing_ok=True)  # a picture from an earlier study would not match this one
        return ("No sumo-gui screenshot: no display was available (DISPLAY is not set). Rerun the study under "
                "`xvfb-run -a -s \"-screen 0 1600x900x24\"` to get one; finished runs are reused.")  # fmt: skip
    traj = pd.read_parquet(run_dir / "trajectories.parquet")
    step = jam_step(traj, cfg)
    if step is None:
        shot.unlink(missing_ok=True)
        return f"No sumo-gui screenshot: no vehicle of {label} was slower than {SLOW_MPS:g} m/s near the bottleneck."
    gui_cfg = replace(cfg, steps=step)
    record = root / "gui_jam.json"
    try:
        done = json.loads(record.read_text())
    except (OSError, ValueError):
        done = {}
    if not (shot.exists() and done.get("config") == json.loads(json.dumps(to_dict(gui_cfg)))):
        shot.unlink(missing_ok=True)
        try:
            last = gui_run(gui_cfg, shot)
        except UsageError as err:  # DISPLAY is set but sumo-gui cannot open it: the study's results stand
            return f"No sumo-gui screenshot: {err}."
        rows = traj[np.isclose(traj["time_s"], step * cfg.control.dt_s)].sort_values("vid")
        same = last == {k: rows[k].tolist() for k in ("vid", "lane", "pos_m", "speed_mps")}
        done = {"config": to_dict(gui_cfg), "run": label, "step": step, "identical_to_run": same}
        write_json(record, done)
    p = cfg.accident.hold_probability(step)
    names = zip(view.STATE_NAMES, view.STATE_COLOUR_NAMES, strict=True)
    colours = ", ".join(f"{name} {colour}" for name, colour in names)
    same_text = "identical" if done["identical_to_run"] else "NOT identical (a bug: please report)"
    return (
        f"![sumo-gui]({GUI_SHOT})\n\nsumo-gui at step {step} (t = {step * cfg.control.dt_s:.1f} s, stuck ratio "
        f"p = {p:.2f}) of run `runs/{label}/`, made by running it again in sumo-gui through TraCI "
        f"(vehicle positions at that step {same_text} to the recorded run): the {view.VIEW_UPSTREAM_M:.0f} m "
        f"upstream of the bottleneck (red bar), traffic from left to right. Vehicles: {colours}."
    )


def run_parallel(jobs: Sequence[tuple[Callable[..., str], tuple[Any, ...], int]], workers: int, desc: str) -> None:
    """Run (function, args, steps) jobs in a process pool with one progress bar over all their steps."""
    if not jobs:
        return
    ctx = mp.get_context("spawn")
    counter = ctx.Value("q", 0)
    total = sum(steps for _, _, steps in jobs)
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_init_worker,
                             initargs=(counter, os.getpid())) as pool:  # fmt: skip
        futures: list[Future[str]] = [pool.submit(fn, *args) for fn, args, _ in jobs]
        with tqdm(total=total, desc=desc, unit="step", file=sys.stderr, mininterval=1.0) as bar:
            while not all(f.done() for f in futures):
                time.sleep(0.5)
                bar.update(min(counter.value, total) - bar.n)
            bar.update(total - bar.n)
        for f in futures:
            f.result()  # re-raise a worker's error


# -- analysis ----------------------------------------------------------------------------------
def run_metrics(run_dir: Path, cfg: SimConfig) -> dict[str, Any]:
    """Summary plus recovery time and stop-and-go for one accident run."""
    from coopsumo.analysis import recovery_time_s, stop_and_go

    summary = json.loads((run_dir / "summary.json").read_text())
    traj = pd.read_parquet(run_dir / "trajectories.parquet")
    acc = cfg.accident
    dt = cfg.control.dt_s
    release_s = acc.start_step * dt
    rec = recovery_time_s(traj, acc.x_m, release_s, threshold_mps=RECOVERY_MPS)
    sg = stop_and_go(traj, acc.x_m - STOP_GO_UPSTREAM_M, acc.x_m, slow_mps=SLOW_MPS)
    departed = max(summary["departed"], 1)
    return {
        "throughput_veh_per_h": summary["throughput_veh_per_h"],
        "mean_speed_mps": summary["mean_speed_mps"],
        "mean_travel_time_s": summary["mean_travel_time_s"],
        "lane_changes_per_vehicle": summary["lane_changes"] / departed,
        "recovery_time_s": rec,
        "slow_share": sg["slow_share"],
        "stops_per_vehicle": sg["stops_per_vehicle"],
        "collisions": summary["collisions"],
        "teleports": summary["teleports"],
        "insertion_blocked": summary["insertion_blocked"],
        "arrived": summary["arrived"],
    }


METRICS = (
    ("throughput_veh_per_h", "throughput (veh/h)", "{:.0f}"),
    ("mean_speed_mps", "mean speed (m/s)", "{:.2f}"),
    ("mean_travel_time_s", "mean travel time (s)", "{:.1f}"),
    ("lane_changes_per_vehicle", "lane changes / veh", "{:.2f}"),
    ("recovery_time_s", "recovery > 15 m/s after release start (s)", "{:.0f}"),
    ("slow_share", "share of veh-time < 5 m/s upstream", "{:.3f}"),
    ("stops_per_vehicle", "stops / veh upstream", "{:.2f}"),
    ("collisions", "collisions", "{:.0f}"),
    ("teleports", "teleports", "{:.0f}"),
)


def aggregate(rows: pd.DataFrame) -> pd.DataFrame:
    """Mean and standard deviation over seeds per policy (columns metric_mean, metric_std)."""
    keys = [m for m, _, _ in METRICS]
    grouped = rows.groupby("policy", sort=False)[keys]
    mean = grouped.mean().add_suffix("_mean")
    std = grouped.std(ddof=1).add_suffix("_std")
    out = pd.concat([mean, std], axis=1)
    out["seeds"] = grouped.size()
    recovered = rows.assign(rec=rows["recovery_time_s"].notna()).groupby("policy", sort=False)["rec"].sum()
    out["recovered_runs"] = recovered
    return out.reset_index()


def _fmt(fmt: str, mean: float, std: float) -> str:
    if mean is None or (isinstance(mean, float) and math.isnan(mean)):
        return "never"
    text = fmt.format(mean)
    if std is not None and not (isinstance(std, float) and math.isnan(std)):
        text += " ± " + fmt.format(std)
    return text


def report_table(agg: pd.DataFrame) -> str:
    header = "| policy | " + " | ".join(label for _, label, _ in METRICS) + " |"
    lines = [header, "|" + "---|" * (len(METRICS) + 1)]
    for _, r in agg.iterrows():
        cells = [_fmt(fmt, r[f"{m}_mean"], r[f"{m}_std"]) for m, _, fmt in METRICS]
        lines.append(f"| {r['policy']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def verdict(agg: pd.DataFrame, coop: str, noncoop: str) -> str:
    """A plain statement of whether the cooperative model beats the non-cooperative one."""
    a = agg.set_index("policy")
    if coop not in a.index or noncoop not in a.index:
        return "The two DQN policies are not both present; no comparison."
    c, n = a.loc[coop], a.loc[noncoop]
    better_speed = c["mean_speed_mps_mean"] > n["mean_speed_mps_mean"]
    better_tp = c["throughput_veh_per_h_mean"] > n["throughput_veh_per_h_mean"]
    fewer_sg = c["slow_share_mean"] < n["slow_share_mean"]
    parts = [
        f"mean speed {c['mean_speed_mps_mean']:.2f} vs {n['mean_speed_mps_mean']:.2f} m/s",
        f"throughput {c['throughput_veh_per_h_mean']:.0f} vs {n['throughput_veh_per_h_mean']:.0f} veh/h",
        f"slow share upstream {c['slow_share_mean']:.3f} vs {n['slow_share_mean']:.3f}",
        f"lane changes per vehicle {c['lane_changes_per_vehicle_mean']:.2f} vs "
        f"{n['lane_changes_per_vehicle_mean']:.2f}",
    ]
    wins = sum([better_speed, better_tp, fewer_sg])
    if wins == 3:
        head = f"Yes: the cooperative model ({coop}) beats the non-cooperative one ({noncoop}) on all three measures"
    elif wins == 0:
        head = f"No: the cooperative model ({coop}) does not beat the non-cooperative one ({noncoop}) on any measure"
    else:
        head = (f"Mixed: the cooperative model ({coop}) beats the non-cooperative one ({noncoop}) on {wins} of 3 "
                "measures (mean speed, throughput, slow share)")  # fmt: skip
    return head + " — " + "; ".join(parts) + " (means over seeds)."


DEVIATIONS = (
    ("simulator", "own simulator", "Eclipse SUMO via libsumo; SUMO's car-following and lane changing off"),
    ("Newell c, d", "not given", "c = 1.1 1/s, d = -0.1, bumper-to-bumper gap; ~1,970 veh/h per lane at saturation"),
    ("road", "length not given", "2,000 m, 3.2 m lanes; loops at 200, 400, ..., 1,800 m on every lane"),
    ("v_exp", "random, clipped 40-110 km/h", "normal, mean 85 km/h, sd 15 km/h, clipped 40-110 km/h"),
    ("T_up", "not given", "interval between vehicles for the whole road; lane drawn uniformly"),
    (
        "accident",
        "stuck ratio p decays 1 -> 0 over ~50,000 steps",
        "a vehicle entering the 100 m before x = 1,300 m is held with probability p; a held vehicle stops at "
        "the line and, standing at the head of its queue, is re-drawn every 1 s; p linear 1 -> 0",
    ),
    ("release start", "not defined", "the accident's first step: p starts to fall below 1 and releases begin"),
    ("lane 1 (Fig. 4)", "not defined", f"SUMO lane index {FIG4_LANE} (the rightmost lane)"),
    ("trajectories", "-", "recorded every 5 steps (0.5 s) to keep the files small; SUMO's FCD every 5 s"),
    ("baselines", "-", "keep, greedy, MOBIL (p = 0.5) on the Newell controller; SUMO's own Krauss + LC2013"),
    (
        "collisions",
        "-",
        "pairs of vehicle bodies overlapping in a lane after a step, checked every step in Python; SUMO's "
        "own check (--sumo-collision-check) agrees in the tests but is off here: it cost 45% of a jammed step",
    ),
)


def deviations_table() -> str:
    lines = ["| topic | paper | here |", "|---|---|---|"]
    lines += [f"| {a} | {b} | {c} |" for a, b, c in DEVIATIONS]
    return "\n".join(lines) + "\n"


def timing_note(
    wall_s: float,
    models_reused: int,
    models: int,
    runs_reused: int,
    runs: int,
    train_files: list[Path],
    run_files: list[Path],
) -> str:
    """Wall time of this invocation, what it reused, and the compute the reused parts recorded."""
    train_s = [float(json.loads(f.read_text()).get("wall_seconds", 0.0)) for f in train_files if f.exists()]
    run_s = sum(float(json.loads(f.read_text()).get("wall_seconds", 0.0)) for f in run_files if f.exists())
    text = f"Wall time of this invocation: {wall_s / 60:.1f} min"
    if models_reused or runs_reused:
        text += f" (reused {models_reused} of {models} models and {runs_reused} of {runs} runs)"
    text += (
        f". Compute recorded by the parts: trainings {', '.join(f'{t / 60:.1f}' for t in train_s)} min"
        f" (run in parallel); accident runs {run_s / 60:.1f} core-min."
    )
    return text


def write_report(
    root: Path, plan: Plan, agg: pd.DataFrame, timing: str, figures: dict[str, str], gui_text: str = ""
) -> None:
    """report.md; gui_text: the sumo-gui screenshot paragraph (gui_section)."""
    coop, noncoop = "dqn_alpha8", "dqn_alpha0"
    acc = accident_config(plan, "keep", plan.seeds[0]).accident
    dt = ControlConfig().dt_s
    text = f"""# Scenario I: accident bottleneck

{plan.lanes} lanes, T_up = {plan.t_up_s:g} s ({3600 / plan.t_up_s:.0f} veh/h), {plan.steps} steps \
({plan.steps * dt / 3600:.2f} h);
accident at x = {acc.x_m:.0f} m from step {acc.start_step} for {acc.duration_steps} steps
(t = {acc.start_step * dt:.0f}-{(acc.start_step + acc.duration_steps) * dt:.0f} s), stuck ratio decaying 1 -> 0.
Models trained {plan.train_steps} steps in free flow (seed {plan.train_seed}); evaluated greedily here on seeds
{", ".join(map(str, plan.seeds))} (same demand for every policy). Values: mean ± standard deviation over seeds.

## Result

{verdict(agg, coop, noncoop)}

{report_table(agg)}

Recovery: time from the start of the accident (when p starts to fall from 1, i.e. releasing begins) until the
space-mean speed in the 200 m upstream of the bottleneck, in 30 s bins, rises above 15 m/s and stays there
("never" when it does not before the end). Recovered runs per policy:
{", ".join(f"{r['policy']} {int(r['recovered_runs'])}/{int(r['seeds'])}" for _, r in agg.iterrows())}.
Stop-and-go: share of vehicle-time below 5 m/s and stops per vehicle (drops below 5 m/s) within the 1,000 m
upstream of the bottleneck.

## Figures

![time-space]({figures["fig4"]})

Fig. 4: trajectories on SUMO lane {FIG4_LANE} (the paper's "lane 1"), seed {plan.seeds[0]}, coloured by speed;
the grey band is the accident window, the dashed line the bottleneck.

![flow-density]({figures["fig5"]})

Fig. 5: flow against density from every loop and 60 s interval, seed {plan.seeds[0]}; one panel per policy,
the other policies' points in grey behind.

{gui_text}

Every run folder (`runs/<policy>_seed<k>/`) also holds SUMO's own `fcd.xml` (every {plan.fcd_period_s:g} s)
and `tripinfo.xml`, for SUMO's tools (the README draws Fig. 4 from `fcd.xml` with `plot_trajectories.py`).

## Deviations and choices

{deviations_table()}
{timing}

Versions: {json.dumps(versions())}.
"""
    (root / "report.md").write_text(text)


def label_for(policy: str) -> str:
    if policy.startswith("dqn:"):
        return Path(policy[4:]).parent.name.replace("alpha", "dqn_alpha")
    return policy.replace(":", "_").replace("=", "")


def main(argv: list[str] | None = None) -> int:
    p = Parser(prog="python -m coopsumo.scenario1", description="Scenario I: the accident bottleneck study.")
    p.add_argument("--quick", action="store_true", help="small step counts for a first look (a few minutes)")
    p.add_argument("--seeds", type=int, default=None, help="number of evaluation seeds (default 3; quick 2)")
    p.add_argument("--out", type=Path, default=Path("results/scenario1"), help="results folder")
    p.add_argument("--workers", type=int, default=2, help="parallel processes (default 2)")
    p.add_argument("--train-steps", type=int, default=None, help="override the training steps")
    p.add_argument("--steps", type=int, default=None,
                   help="override the accident run's steps (the accident window scales with it)")  # fmt: skip
    args = p.parse_args(argv)

    def body() -> int:
        plan = Plan.quick() if args.quick else Plan()
        if args.seeds is not None:
            if args.seeds < 1:
                raise UsageError(f"seeds must be >= 1, got {args.seeds}")
            plan = replace(plan, seeds=tuple(range(1, args.seeds + 1)))
        if args.workers < 1:
            raise UsageError(f"workers must be >= 1, got {args.workers}")
        if args.train_steps is not None:
            if args.train_steps < 1:
                raise UsageError(f"train-steps must be >= 1, got {args.train_steps}")
            plan = replace(plan, train_steps=args.train_steps)
        if args.steps is not None:
            if args.steps < 10:
                raise UsageError(f"steps must be >= 10, got {args.steps}")
            plan = replace(plan, steps=args.steps, accident_start=args.steps * 2 // 9,
                           accident_steps=args.steps * 5 // 9)  # fmt: skip
        return run_study(plan, args.out, args.workers)

    return run_cli("scenario1", body)


def run_study(plan: Plan, root: Path, workers: int = 2) -> int:
    start = time.perf_counter()
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise UsageError(f"cannot write {root}: {err.strerror}") from None
    write_json(root / "plan.json", {"plan": to_dict(plan), "versions": versions()})

    # 1. models
    train_jobs = []
    model_paths = {}
    for alpha in ALPHAS:
        tcfg = train_config(plan, alpha)
        model_dir = root / "models" / f"alpha{alpha:g}"
        model_paths[alpha] = model_dir / "model.pt"
        if model_paths[alpha].exists() and _same_config(model_dir / "config.json", to_dict(tcfg)):
            print(f"scenario1: reusing {model_paths[alpha]} (same configuration)", file=sys.stderr)
            continue
        train_jobs.append((train_job, (to_dict(tcfg), str(model_dir)), plan.train_steps))
    run_parallel(train_jobs, workers, "train alpha=0 and alpha=8")

    # 2. accident runs
    policies = [f"dqn:{model_paths[a]}" for a in ALPHAS] + list(plan.baselines)
    runs: list[tuple[str, int, Path, SimConfig]] = []
    sim_jobs = []
    for seed in plan.seeds:
        for policy in policies:
            cfg = accident_config(plan, policy, seed)
            out = root / "runs" / f"{label_for(policy)}_seed{seed}"
            runs.append((label_for(policy), seed, out, cfg))
            if _reusable_run(out, cfg, plan.outputs()):
                continue
            sim_jobs.append((sim_job, (to_dict(cfg), str(out), plan.trajectory_every, to_dict(plan.outputs())),
                             plan.steps))  # fmt: skip
    run_parallel(sim_jobs, workers, f"accident runs ({len(sim_jobs)})")

    # 3. tables, figures, report
    from coopsumo.analysis import flow_density, read_detectors
    from coopsumo.plots import flow_density_figure, time_space_figure

    rows = pd.DataFrame([{"policy": lab, "seed": seed, **run_metrics(out, cfg)} for lab, seed, out, cfg in runs])
    rows.to_csv(root / "runs.csv", index=False)
    agg = aggregate(rows)
    agg.to_csv(root / "summary.csv", index=False)
    first = plan.seeds[0]
    acc = runs[0][3].accident
    dt = runs[0][3].control.dt_s
    window = (acc.start_step * dt, (acc.start_step + acc.duration_steps) * dt)
    trajs = {lab: pd.read_parquet(out / "trajectories.parquet") for lab, seed, out, _ in runs
             if seed == first and lab in ("dqn_alpha0", "dqn_alpha8")}  # fmt: skip
    time_space_figure(trajs, FIG4_LANE, root / "fig4_time_space.png", window, acc.x_m,
                      title_lane=f"SUMO lane {FIG4_LANE} (paper's lane 1)")  # fmt: skip
    fd = {lab: flow_density(read_detectors(out / "detectors.xml")) for lab, seed, out, _ in runs if seed == first}
    flow_density_figure(fd, root / "fig5_flow_density.png")
    gui_label, gui_seed, gui_out, gui_cfg = next(r for r in runs if r[0] == GUI_RUN and r[1] == first)
    gui_text = gui_section(root, gui_out, f"{gui_label}_seed{gui_seed}", gui_cfg)
    wall = time.perf_counter() - start
    timing = timing_note(wall, len(ALPHAS) - len(train_jobs), len(ALPHAS), len(runs) - len(sim_jobs), len(runs),
                         [m.parent / "train_summary.json" for m in model_paths.values()],
                         [out / "summary.json" for _, _, out, _ in runs])  # fmt: skip
    write_report(root, plan, agg, timing, {"fig4": "fig4_time_space.png", "fig5": "fig5_flow_density.png"},
                 gui_text)  # fmt: skip
    print(report_table(agg))
    print(f"scenario1: done in {wall / 60:.1f} min; report: {root / 'report.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
