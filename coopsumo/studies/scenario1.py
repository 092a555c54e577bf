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
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from coopsumo.config import (
    DQN_PRESETS,
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
from coopsumo.runio import Parser, UsageError, run_cli, versions, write_json
from coopsumo.sim import view
from coopsumo.studies.runner import add_backend_flags, check_backend
from coopsumo.validation import MAX_STEPS, alpha_list, integer, out_dir, seed_count, steps, workers

ALPHAS = (0.0, 2.0, 8.0)
"""alpha = 0 and 8 are the paper's; 2 is the largest alpha of the learning study's response whose model still
changes lanes in free flow (0.49 per vehicle; alpha = 8 makes none, i.e. it is `keep`)"""
PRESETS = ("default",)
BASELINES = ("keep", "greedy", "mobil:p=0.5", "sumo")
FIG4_LANE = 0  # the paper's "lane 1" taken as the rightmost lane, SUMO index 0
SLOW_MPS = 5.0
RECOVERY_MPS = 15.0
STOP_GO_UPSTREAM_M = 1000.0
GUI_ALPHA = 8.0  # sumo-gui shows the paper's cooperative model (first preset, first seed)
COOPERATIVE_LC_SHARE = 0.1
"""a model is "cooperative, not simply keep" when it makes at least this share of alpha = 0's lane changes"""
WAVE_LOOKBACK_S = 120.0
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
    alphas: tuple[float, ...] = ALPHAS
    presets: tuple[str, ...] = PRESETS
    """learner presets (config.DQN_PRESETS) whose models are trained and run, side by side"""
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


def model_name(preset: str, alpha: float) -> str:
    """Folder of a model under models/ (the default preset keeps the plain alpha<A> name)."""
    return f"alpha{alpha:g}" if preset == "default" else f"{preset}_alpha{alpha:g}"


def model_label(preset: str, alpha: float) -> str:
    """A model's name in tables and run folders (label_for of its policy)."""
    return "dqn_" + model_name(preset, alpha)


def train_config(plan: Plan, alpha: float, preset: str = "default") -> TrainConfig:
    """The free-flow training of one model with the learner preset `preset`."""
    sim = SimConfig(
        road=RoadConfig(lanes=plan.lanes, loop_period_s=plan.loop_period_s),
        demand=DemandConfig(t_up_s=plan.t_up_s),
        reward=RewardConfig(alpha=alpha),
        steps=plan.train_steps,
        seed=plan.train_seed,
        policy="dqn",
    )
    return TrainConfig(sim=sim, dqn=DQN_PRESETS[preset], eval_steps=0)


def accident_config(plan: Plan, policy: str, seed: int) -> SimConfig:
    return SimConfig(
        road=RoadConfig(lanes=plan.lanes, loop_period_s=plan.loop_period_s),
        demand=DemandConfig(t_up_s=plan.t_up_s),
        accident=AccidentConfig(enabled=True, start_step=plan.accident_start, duration_steps=plan.accident_steps),
        steps=plan.steps,
        seed=seed,
        policy=policy,
    )


# -- cells run by the shared runner (coopsumo.studies.runner), one per worker process -----------------------
def new_record(spec: dict[str, Any]) -> dict[str, Any]:
    """A cell's record before it runs: what it is and where it writes; nothing measured yet."""
    from coopsumo.studies.runner import blank_record

    return blank_record(spec, ("key", "kind", "label", "seed", "out", "after"))


def failed_record(spec: dict[str, Any], error: str) -> dict[str, Any]:
    """The record of a cell whose worker died or whose model could not be trained."""
    from coopsumo.studies.runner import as_failed

    return as_failed(new_record(spec), error)


def run_cell(spec: dict[str, Any], root: str) -> dict[str, Any]:
    """Train one model ("train") or run one policy through the accident ("run") into ROOT/<out>; never raises."""
    from coopsumo.studies.runner import run_recorded

    record = new_record(spec)
    body = _train_cell if spec["kind"] == "train" else _run_cell
    return run_recorded(record, lambda: body(spec, Path(root) / spec["out"], record))


def _train_cell(spec: dict[str, Any], out: Path, record: dict[str, Any]) -> None:
    import torch

    from coopsumo.agents.train import train
    from coopsumo.config import train_config_from_dict

    torch.set_num_threads(1)
    record["summary"] = train(train_config_from_dict(spec["config"]), out, progress=False)


def _run_cell(spec: dict[str, Any], out: Path, record: dict[str, Any]) -> None:
    """One accident run into its run folder, written atomically (a killed run leaves no half folder)."""
    import torch

    from coopsumo.studies.runner import simulate_into

    torch.set_num_threads(1)
    record["summary"] = simulate_into(spec["config"], out, spec["out"], trajectory_every=spec["trajectory_every"],
                                      outputs=OutputConfig(**spec["outputs"]), atomic=True)  # fmt: skip


def gui_run(cfg: SimConfig, shot: Path) -> dict[str, list[Any]]:
    """Run cfg's simulation in sumo-gui (through TraCI, so in this process) to its last step and save
    sumo-gui's screenshot of that step to shot. Returns that step's vehicles (vid, lane, pos_m, speed_mps)."""
    import tempfile

    from coopsumo.agents.policies import policy_for_run
    from coopsumo.agents.rollout import run
    from coopsumo.config import GuiConfig

    policy = policy_for_run(cfg)
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


def _reusable_run(out: Path, cfg: SimConfig, outputs: OutputConfig, model: Path | None = None) -> bool:
    """True when out holds a finished run of cfg with the SUMO output files `outputs` asks for and, for a
    model's run, was made after the model file was written (a retrained model keeps its path)."""
    if not ((out / "summary.json").exists() and _same_config(out / "config.json", to_dict(cfg))):
        return False
    if model is not None and not (model.exists() and (out / "summary.json").stat().st_mtime >= model.stat().st_mtime):
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


# -- analysis ----------------------------------------------------------------------------------
def run_metrics(run_dir: Path, cfg: SimConfig) -> dict[str, Any]:
    """Summary plus on-road recovery, stop-and-go and the insertion backlog for one accident run."""
    from coopsumo.report.analysis import (
        backlog_cleared_s,
        insertion_backlog,
        read_detectors,
        recovery_time_s,
        section_speed_bins,
        stop_and_go,
        stop_and_go_waves,
    )

    summary = json.loads((run_dir / "summary.json").read_text())
    traj = pd.read_parquet(run_dir / "trajectories.parquet")
    acc = cfg.accident
    dt = cfg.control.dt_s
    release_s = acc.start_step * dt
    rec = recovery_time_s(traj, acc.x_m, release_s, threshold_mps=RECOVERY_MPS)
    sg = stop_and_go(traj, acc.x_m - STOP_GO_UPSTREAM_M, acc.x_m, slow_mps=SLOW_MPS)
    waves = stop_and_go_waves(read_detectors(run_dir / "detectors.xml"), acc.x_m, slow_mps=SLOW_MPS,
                              fast_mps=RECOVERY_MPS, lookback_s=WAVE_LOOKBACK_S)  # fmt: skip
    backlog = insertion_backlog(traj, cfg.demand.t_up_s)
    end_s = (acc.start_step + acc.duration_steps) * dt
    after = section_speed_bins(traj, acc.x_m - 200.0, acc.x_m, end_s, 30.0) if traj["time_s"].max() > end_s else None
    departed = max(summary["departed"], 1)
    return {
        "throughput_veh_per_h": summary["throughput_veh_per_h"],
        "mean_speed_mps": summary["mean_speed_mps"],
        "mean_travel_time_s": summary["mean_travel_time_s"],
        "lane_changes_per_vehicle": summary["lane_changes"] / departed,
        "recovery_time_s": rec,
        "recovery_step": acc.start_step + rec / dt if math.isfinite(rec) else float("nan"),
        "wave_share": waves["wave_share"],
        "wave_onsets": waves["n_onsets"],
        "slow_share": sg["slow_share"],
        "stops_per_vehicle": sg["stops_per_vehicle"],
        "backlog_max_veh": float(backlog.max()) if len(backlog) else 0.0,
        "backlog_cleared_s": backlog_cleared_s(backlog, release_s, cfg.road.lanes),
        "backlog_at_end_veh": summary["insertion_pending_at_end"],
        "backlog_at_accident_end_veh": float(backlog[backlog.index <= end_s].iloc[-1]) if len(backlog) else 0.0,
        "speed_after_accident_mps": float(after.median()) if after is not None and after.notna().any() else math.nan,
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
    ("recovery_step", "on-road recovery > 15 m/s (step)", "{:.0f}"),
    ("wave_share", "stop-and-go onsets / loop interval", "{:.3f}"),
    ("slow_share", "share of veh-time < 5 m/s upstream", "{:.3f}"),
    ("backlog_max_veh", "most vehicles waiting to enter", "{:.0f}"),
    ("backlog_cleared_s", "backlog cleared after accident start (s)", "{:.0f}"),
    ("collisions", "collisions", "{:.0f}"),
    ("teleports", "teleports", "{:.0f}"),
)


def aggregate(rows: pd.DataFrame) -> pd.DataFrame:
    """Mean and standard deviation over seeds per policy (columns metric_mean, metric_std)."""
    keys = [m for m, _, _ in METRICS] + ["recovery_time_s", "backlog_at_accident_end_veh", "speed_after_accident_mps"]
    grouped = rows.groupby("policy", sort=False)[keys]
    mean = grouped.mean().add_suffix("_mean")
    std = grouped.std(ddof=1).add_suffix("_std")
    out = pd.concat([mean, std], axis=1)
    out["seeds"] = grouped.size()
    finite = rows[keys].notna().groupby(rows["policy"], sort=False).sum().add_suffix("_n")
    out = pd.concat([out, finite], axis=1)
    out["recovered_runs"] = out["recovery_time_s_n"] if "recovery_time_s_n" in out else out["recovery_step_n"]
    return out.reset_index()


COUNTED = ("recovery_step", "backlog_cleared_s")
"""metrics that may never happen in a run: the table says in how many seeds they did"""


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
        cells = [_fmt(fmt, r[f"{m}_mean"], r[f"{m}_std"])
                 + (f" ({int(r[f'{m}_n'])}/{int(r['seeds'])})" if m in COUNTED and 0 < r[f"{m}_n"] < r["seeds"] else "")
                 for m, _, fmt in METRICS]  # fmt: skip
        lines.append(f"| {r['policy']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _paired(rows: pd.DataFrame, a: str, b: str, metric: str) -> tuple[float, float, int, int]:
    """Seed-paired difference a - b of a metric: (mean, sd, seeds where a < b, seeds compared)."""
    wide = rows.pivot_table(index="seed", columns="policy", values=metric, aggfunc="first")
    diff = (wide[a] - wide[b]).dropna() if a in wide and b in wide else pd.Series(dtype=float)
    sd = float(diff.std(ddof=1)) if len(diff) > 1 else float("nan")
    return float(diff.mean()) if len(diff) else float("nan"), sd, int((diff < 0).sum()), len(diff)


def verdict(rows: pd.DataFrame, agg: pd.DataFrame, coop: str, noncoop: str) -> str:
    """The paper's claim for Scenario I checked on coop against noncoop: on-road recovery, stop-and-go waves,
    mean speed and throughput, each with its spread over seeds; one headline sentence first."""
    a = agg.set_index("policy")
    if coop not in a.index or noncoop not in a.index:
        return f"`{coop}` and `{noncoop}` are not both in the study; no comparison."
    c, n = a.loc[coop], a.loc[noncoop]
    seeds = int(c["seeds"])
    c_rec, n_rec = int(c["recovery_step_n"]), int(n["recovery_step_n"])
    wave_mean, wave_sd, wave_fewer, pairs = _paired(rows, coop, noncoop, "wave_share")
    speed_mean, speed_sd, _, _ = _paired(rows, coop, noncoop, "mean_speed_mps")
    recovers = c_rec == seeds and n_rec < seeds
    calmer = pairs > 0 and wave_fewer == pairs
    if recovers and calmer:
        head = "**The claim holds here**"
    elif recovers or calmer:
        head = "**The claim holds in part**"
    else:
        head = "**The claim does not hold here**"

    def rec(row: pd.Series) -> str:
        k = int(row["recovery_step_n"])
        if k == 0:
            return f"never recovers (0 of {seeds} seeds)"
        step = _fmt("{:.0f}", row["recovery_step_mean"], row["recovery_step_std"])
        return f"recovers in {k} of {seeds} seeds, at step {step}"

    return (
        f"{head}: with `{coop}` the traffic {rec(c)}; with `{noncoop}` it {rec(n)}. Stop-and-go onsets per "
        f"upstream loop interval: {_fmt('{:.3f}', c['wave_share_mean'], c['wave_share_std'])} against "
        f"{_fmt('{:.3f}', n['wave_share_mean'], n['wave_share_std'])} (seed-paired difference "
        f"{wave_mean:+.3f} ± {wave_sd:.3f}; fewer with `{coop}` on {wave_fewer} of {pairs} seeds). Mean speed "
        f"{c['mean_speed_mps_mean']:.2f} against {n['mean_speed_mps_mean']:.2f} m/s (paired difference "
        f"{speed_mean:+.2f} ± {speed_sd:.2f} m/s), throughput {c['throughput_veh_per_h_mean']:.0f} against "
        f"{n['throughput_veh_per_h_mean']:.0f} veh/h, lane changes per vehicle "
        f"{c['lane_changes_per_vehicle_mean']:.2f} against {n['lane_changes_per_vehicle_mean']:.2f}."
    )


def cooperative_alpha(agg: pd.DataFrame, preset: str, alphas: Sequence[float]) -> float | None:
    """The largest alpha > 0 whose model still makes at least COOPERATIVE_LC_SHARE of alpha = 0's lane changes
    per vehicle in these runs: cooperative, but not simply `keep`. None if none does (or alpha = 0 is missing)."""
    a = agg.set_index("policy")
    base = model_label(preset, 0.0)
    if base not in a.index:
        return None
    floor = max(COOPERATIVE_LC_SHARE * float(a.loc[base, "lane_changes_per_vehicle_mean"]), 1e-9)
    found = [x for x in alphas if x > 0 and model_label(preset, x) in a.index
             and float(a.loc[model_label(preset, x), "lane_changes_per_vehicle_mean"]) >= floor]  # fmt: skip
    return max(found) if found else None


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
        "\"none\" at a standstill",
        "keeps the speed, zero included",
        "default learner: not offered below 1 m/s (a learned vehicle cannot stand for good); --preset paper: offered",
    ),
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


def why_text(agg: pd.DataFrame, plan: Plan) -> str:
    """Why the road recovers or not: the backlog left when the accident ends and the speed while it drains."""
    a = agg.set_index("policy")
    end_step = plan.accident_start + plan.accident_steps
    parts = [f"`{p}` {r['backlog_at_accident_end_veh_mean']:.0f} vehicles, {r['speed_after_accident_mps_mean']:.1f} m/s"
             for p, r in a.iterrows() if math.isfinite(r["speed_after_accident_mps_mean"])]  # fmt: skip
    if not parts:
        return ""
    text = (f"**Why.** When the accident ends (step {end_step}), vehicles that could not enter during the jam "
            f"are still waiting (backlog then), and after it the speed in the 200 m before the bottleneck (median "
            f"of 30 s bins) is: {'; '.join(parts)}.")  # fmt: skip
    slow = [str(p) for p, r in a.iterrows() if r["speed_after_accident_mps_mean"] < RECOVERY_MPS]
    if slow:
        text += (
            f" For {', '.join(f'`{p}`' for p in slow)}: while the backlog drains, the road is fed at its capacity "
            f"and holds the speed it has at capacity, below {RECOVERY_MPS:g} m/s; it rises above it only once the "
            "backlog is gone (the figure). So whether "
            f"a run \"recovers\" before step {plan.steps} is decided by how large a backlog the jam left, i.e. by "
            "the throughput during the accident: the backlog columns say more than the recovery step."
        )
    stalled = [str(p) for p, r in a.iterrows()
               if r["teleports_mean"] >= 10 and r["lane_changes_per_vehicle_mean"] < 0.01]  # fmt: skip
    if stalled:
        text += (f" {', '.join(f'`{p}`' for p in stalled)} make no lane change and leave vehicles standing (teleports: "
                 "SUMO removes a vehicle that stood 300 s at the head of its lane), so their backlog is the largest.")
    return text


def write_report(
    root: Path,
    plan: Plan,
    rows: pd.DataFrame,
    agg: pd.DataFrame,
    timing: str,
    figures: dict[str, str],
    gui_text: str = "",
) -> None:
    """report.md; gui_text: the sumo-gui screenshot paragraph (gui_section)."""
    acc = accident_config(plan, "keep", plan.seeds[0]).accident
    dt = ControlConfig().dt_s
    sections = []
    for preset in plan.presets:
        noncoop = model_label(preset, 0.0)
        coop_alpha = cooperative_alpha(agg, preset, plan.alphas)
        lines = [f"### Learner preset `{preset}`\n"]
        for x in (x for x in plan.alphas if x > 0):
            lines.append(f"- alpha = {x:g} against alpha = 0: " + verdict(rows, agg, model_label(preset, x), noncoop))
        if coop_alpha is None:
            lines.append(f"\nNo model with alpha > 0 makes even {COOPERATIVE_LC_SHARE:.0%} of alpha = 0's lane "
                         "changes here: every cooperative model of this preset behaves like `keep`.")  # fmt: skip
        else:
            label = model_label(preset, coop_alpha)
            lc = agg.set_index("policy").loc[label, "lane_changes_per_vehicle_mean"]
            lines.append(f"\nThe cooperative model that is not simply `keep`: **alpha = {coop_alpha:g}** "
                         f"(`{label}`, {lc:.2f} lane changes per vehicle; the largest alpha whose "
                         f"model makes at least {COOPERATIVE_LC_SHARE:.0%} of alpha = 0's lane changes).")  # fmt: skip
        sections.append("\n".join(lines))
    text = f"""# Scenario I: accident bottleneck

{plan.lanes} lanes, T_up = {plan.t_up_s:g} s ({3600 / plan.t_up_s:.0f} veh/h), {plan.steps} steps \
({plan.steps * dt / 3600:.2f} h);
accident at x = {acc.x_m:.0f} m from step {acc.start_step} for {acc.duration_steps} steps
(t = {acc.start_step * dt:.0f}-{(acc.start_step + acc.duration_steps) * dt:.0f} s), stuck ratio decaying 1 -> 0.
Models (learner presets {", ".join(f"`{p}`" for p in plan.presets)};
alpha in {{{", ".join(f"{x:g}" for x in plan.alphas)}}}) trained {plan.train_steps} steps in free flow
(seed {plan.train_seed}); evaluated greedily here on seeds
{", ".join(map(str, plan.seeds))} (same demand for every policy). Values: mean ± standard deviation over seeds.

## The paper's claim and the answer

The paper (section IV.A, Fig. 4-5): with cooperation (alpha = 8) the stop-and-go waves disappear and the
traffic recovers above 15 m/s after about 74,000 steps; without it (alpha = 0) the bottleneck remains.

{chr(10).join(sections)}

{report_table(agg)}

{why_text(agg, plan)}

Definitions (chosen here; the paper gives none):
- **On-road recovery**: the step at which the space-mean speed of the vehicles in the 200 m before the
  bottleneck, in 30 s bins from the accident's start, rises above 15 m/s and stays above it to the end
  (at least 2 bins; "never" when it does not; "(k/n)" when only k of n seeds recover, the mean is over those).
  It is measured on the road only: vehicles that could not enter during the jam are not in it.
- **Insertion backlog**: vehicles due to enter (vehicle k is due at k T_up) that are not yet on the road,
  from the trajectories every {plan.trajectory_every * dt:g} s. Reported separately, as its largest value and the
  time after the accident's start from which it stays at most one vehicle per lane ("cleared"), so that the
  recovery above is not decided by how the queued vehicles are inserted afterwards. The figure shows both.
- **Stop-and-go onsets**: the share of loop intervals ({plan.loop_period_s:g} s, every loop upstream of the
  bottleneck) whose speed is below 5 m/s while the same loop measured above 15 m/s in an interval that began
  within the previous {WAVE_LOOKBACK_S:.0f} s (an interval in which nobody passed an occupied loop counts as
  0 m/s; an empty one is skipped). Slow share: vehicle-time below 5 m/s within 1,000 m upstream.

## Figures

![recovery]({figures["recovery"]})

Recovery, seed {plan.seeds[0]}: space-mean speed in the 200 m before the bottleneck (30 s bins; dashed: 15 m/s)
and the vehicles waiting to enter, per policy; grey: the accident window.

![time-space]({figures["fig4"]})

Fig. 4: trajectories on SUMO lane {FIG4_LANE} (the paper's "lane 1"), seed {plan.seeds[0]}, coloured by speed;
the grey band is the accident window, the dashed line the bottleneck.

![flow-density]({figures["fig5"]})

Fig. 5: flow against density from every loop and {plan.loop_period_s:g} s interval, seed {plan.seeds[0]}; one
panel per policy, the other policies' points in grey behind.

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
    """Short name of a policy in tables and folders: dqn_<model folder> for a model, else the spec."""
    if policy.startswith("dqn:"):
        return "dqn_" + Path(policy[4:]).parent.name
    return policy.replace(":", "_").replace("=", "")


def _alpha_list(text: str) -> tuple[float, ...]:
    """--alphas: comma-separated alphas (validation.alpha_list; UsageError otherwise); 0 is always part of the study."""
    return tuple(sorted({0.0, *alpha_list("--alphas", text)}))


def _preset_list(text: str) -> tuple[str, ...]:
    names = tuple(dict.fromkeys(v.strip() for v in text.split(",") if v.strip()))
    unknown = [n for n in names if n not in DQN_PRESETS]
    if not names or unknown:
        raise UsageError(f"--preset must be one or more of {', '.join(DQN_PRESETS)} (comma-separated), got {text!r}")
    return names


def main(argv: list[str] | None = None) -> int:
    p = Parser(prog="python -m coopsumo.scenario1", description="Scenario I: the accident bottleneck study.")
    p.add_argument("--quick", action="store_true", help="small step counts for a first look (a few minutes)")
    p.add_argument("--seeds", type=seed_count, default=None, help="number of evaluation seeds (default 3; quick 2)")
    p.add_argument("--out", type=out_dir, default=Path("results/scenario1"), help="results folder")
    p.add_argument("--workers", type=workers, default=2, help="parallel processes (default 2)")
    add_backend_flags(p)
    p.add_argument("--train-steps", type=steps, default=None, help="override the training steps")
    p.add_argument("--steps", type=integer(10, MAX_STEPS), default=None,
                   help="override the accident run's steps (the accident window scales with it)")  # fmt: skip
    p.add_argument("--alphas", default=None,
                   help=f"alphas to train and run, comma-separated (default {','.join(f'{a:g}' for a in ALPHAS)}; "
                        "0 is always included)")  # fmt: skip
    p.add_argument("--preset", "--presets", dest="presets", default=None,
                   help="learner presets, comma-separated: default, paper, or default,paper for both side by side "
                        "(default: default)")  # fmt: skip
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
        if args.alphas is not None:
            plan = replace(plan, alphas=_alpha_list(args.alphas))
        if args.presets is not None:
            plan = replace(plan, presets=_preset_list(args.presets))
        check_backend(args.backend, args.address)
        return run_study(plan, args.out, args.workers, args.backend, args.address)

    return run_cli("scenario1", body)


def run_study(plan: Plan, root: Path, workers: int = 2, backend_name: str = "local", address: str | None = None) -> int:
    start = time.perf_counter()
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise UsageError(f"cannot write {root}: {err.strerror}") from None
    write_json(root / "plan.json", {"plan": to_dict(plan), "versions": versions()})

    # 1. cells: trainings first (the longest chains), each model's accident runs as soon as it exists, then
    #    the baselines; finished models and runs with the same configuration are reused
    specs: list[dict[str, Any]] = []
    train_keys: dict[tuple[str, float], str] = {}
    model_paths: dict[tuple[str, float], Path] = {}
    for preset in plan.presets:
        for alpha in plan.alphas:
            tcfg = train_config(plan, alpha, preset)
            name = model_name(preset, alpha)
            model_paths[preset, alpha] = root / "models" / name / "model.pt"
            train_keys[preset, alpha] = f"train_{name}"
            if model_paths[preset, alpha].exists() and _same_config(root / "models" / name / "config.json",
                                                                    to_dict(tcfg)):  # fmt: skip
                print(f"scenario1: reusing {model_paths[preset, alpha]} (same configuration)", file=sys.stderr)
                continue
            specs.append({"key": train_keys[preset, alpha], "kind": "train", "label": model_label(preset, alpha),
                          "seed": plan.train_seed, "out": f"models/{name}", "config": to_dict(tcfg)})  # fmt: skip
    n_train = len(specs)
    retrained = {spec["key"] for spec in specs}
    policies = [(f"dqn:{model_paths[k]}", train_keys[k]) for k in model_paths] + [(b, None) for b in plan.baselines]
    runs: list[tuple[str, int, Path, SimConfig]] = []
    for policy, after in policies:
        for seed in plan.seeds:
            cfg = accident_config(plan, policy, seed)
            label = label_for(policy)
            out = root / "runs" / f"{label}_seed{seed}"
            runs.append((label, seed, out, cfg))
            model = Path(policy[4:]) if policy.startswith("dqn:") else None
            if after not in retrained and _reusable_run(out, cfg, plan.outputs(), model):
                continue
            specs.append({"key": f"run_{label}_seed{seed}", "kind": "run", "label": label, "seed": seed,
                          "out": f"runs/{label}_seed{seed}", "after": after, "config": to_dict(cfg),
                          "trajectory_every": plan.trajectory_every, "outputs": to_dict(plan.outputs())})  # fmt: skip
    n_cells = len(model_paths) + len(runs)
    if specs:
        from coopsumo.sim.network import build_net
        from coopsumo.studies.runner import execute, make_backend, sigterm_interrupts

        build_net(RoadConfig(lanes=plan.lanes, loop_period_s=plan.loop_period_s))  # once here, not in the workers
        backend = make_backend(backend_name, workers, address, run_cell)
        try:
            with sigterm_interrupts():
                counts = execute(specs, root.resolve(), backend, n_cells, n_cells - len(specs), progress=True,
                                 failed_record=failed_record,
                                 desc=f"{n_train} trainings, {len(specs) - n_train} accident runs")  # fmt: skip
        finally:
            backend.close()
        if counts["failed"]:
            failed = [s["key"] for s in specs if json.loads((root / "cells" / f"{s['key']}.json").read_text())
                      ["status"] != "ok"]  # fmt: skip
            print(f"scenario1: error: {len(failed)} of {len(specs)} cells failed ({', '.join(failed)}); records in "
                  f"{root / 'cells'}; rerun the same command to retry them", file=sys.stderr)  # fmt: skip
            return 1

    # 2. tables, figures, report
    from coopsumo.report.analysis import flow_density, insertion_backlog, read_detectors, section_speed_bins
    from coopsumo.report.plots import flow_density_figure, recovery_figure, time_space_figure

    order = {lab: i for i, (lab, _, _, _) in enumerate(runs)}
    rows = pd.DataFrame([{"policy": lab, "seed": seed, **run_metrics(out, cfg)} for lab, seed, out, cfg in runs])
    rows = rows.sort_values(["policy", "seed"], key=lambda c: c.map(order) if c.name == "policy" else c,
                            kind="stable", ignore_index=True)  # fmt: skip
    rows.to_csv(root / "runs.csv", index=False)
    agg = aggregate(rows)
    agg.to_csv(root / "summary.csv", index=False)
    first = plan.seeds[0]
    cfg0 = runs[0][3]
    acc, dt = cfg0.accident, cfg0.control.dt_s
    window = (acc.start_step * dt, (acc.start_step + acc.duration_steps) * dt)
    firsts = [(lab, out) for lab, seed, out, _ in runs if seed == first]
    shown = [model_label(plan.presets[0], x) for x in plan.alphas]
    trajs = {lab: pd.read_parquet(out / "trajectories.parquet") for lab, out in firsts if lab in shown}
    time_space_figure(trajs, FIG4_LANE, root / "fig4_time_space.png", window, acc.x_m,
                      title_lane=f"SUMO lane {FIG4_LANE} (paper's lane 1)")  # fmt: skip
    fd = {lab: flow_density(read_detectors(out / "detectors.xml")) for lab, out in firsts}
    flow_density_figure(fd, root / "fig5_flow_density.png")
    speeds, backlogs = {}, {}
    for lab, out in firsts:
        traj = pd.read_parquet(out / "trajectories.parquet", columns=["time_s", "vid", "pos_m", "speed_mps"])
        speeds[lab] = section_speed_bins(traj, acc.x_m - 200.0, acc.x_m, 0.0, 30.0)
        backlogs[lab] = insertion_backlog(traj, plan.t_up_s)
    recovery_figure(speeds, backlogs, root / "fig_recovery.png", window, RECOVERY_MPS)
    gui_label = model_label(plan.presets[0], GUI_ALPHA if GUI_ALPHA in plan.alphas else max(plan.alphas))
    _, gui_seed, gui_out, gui_cfg = next(r for r in runs if r[0] == gui_label and r[1] == first)
    gui_text = gui_section(root, gui_out, f"{gui_label}_seed{gui_seed}", gui_cfg)
    wall = time.perf_counter() - start
    timing = timing_note(wall, len(model_paths) - n_train, len(model_paths), len(runs) - (len(specs) - n_train),
                         len(runs), [m.parent / "train_summary.json" for m in model_paths.values()],
                         [out / "summary.json" for _, _, out, _ in runs])  # fmt: skip
    figures = {"fig4": "fig4_time_space.png", "fig5": "fig5_flow_density.png", "recovery": "fig_recovery.png"}
    write_report(root, plan, rows, agg, timing, figures, gui_text)
    print(report_table(agg))
    print(f"scenario1: done in {wall / 60:.1f} min; report: {root / 'report.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
