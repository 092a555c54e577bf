"""`python -m coopsumo.scenario1` (`make scenario1`): the accident-bottleneck study of section IV.A, across demands.

1. trains (or reuses) one model per learner preset and alpha in free flow, once;
2. runs every model and every baseline (keep, greedy, MOBIL at every politeness, SUMO's own models) through the
   accident at every demand T_up, on the same evaluation seeds;
3. writes results/scenario1/: run folders runs/t<T_up>/<policy>_seed<k>/ (with SUMO's detectors.xml, fcd.xml and
   tripinfo.xml), runs.csv, summary.csv, the figures and report.md (scenario1_report: measures, verdicts per
   demand); with a display, gui_jam.png: sumo-gui's view of the jam at the bottleneck, replayed through TraCI.
"""

from __future__ import annotations

import json
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
    results_view,
    to_dict,
)
from coopsumo.runio import Parser, UsageError, run_cli, versions, write_json
from coopsumo.sim import view
from coopsumo.studies.runner import add_backend_flags, check_backend
from coopsumo.studies.scenario1_report import SLOW_MPS, write_report
from coopsumo.validation import (
    MAX_STEPS,
    alpha_list,
    distinct_list,
    integer,
    number_name,
    out_dir,
    seed_count,
    steps,
    t_up_list,
    workers,
)

ALPHAS = (0.0, 2.0, 8.0)
"""alpha = 0 and 8 are the paper's; 2 is the largest alpha of the learning study's response whose model still
changes lanes in free flow (0.49 per vehicle; alpha = 8 makes none, i.e. it is `keep`)"""
PRESETS = ("default",)
BASELINES = ("keep", "greedy", "sumo")
MOBIL_PS = (0.0, 0.25, 0.5, 1.0)
"""MOBIL politeness values run beside the learned models: classical cooperation as the control"""
DEMANDS = (2.0, 1.5, 1.0)
"""T_up (s) of the default study: the queue stays on the road, reaches the entrance, still waits at the end"""
FIG4_LANE = 0  # the paper's "lane 1" taken as the rightmost lane, SUMO index 0
GUI_ALPHA = 8.0  # sumo-gui shows the paper's cooperative model (first preset, first seed, highest demand)
GUI_SHOT = "gui_jam.png"
JAM_SHARE = 0.9  # the screenshot step: the first time the view holds this share of its most slow vehicles
WINDOW_S = 600.0
"""length of each partial-trajectory window of Fig. 4 (s)"""


@dataclass(frozen=True)
class Plan:
    """Sizes of the study: the default profile; Plan.quick() and Plan.full() are the others."""

    lanes: int = 3
    t_ups: tuple[float, ...] = DEMANDS
    """demands of the accident runs: upstream departure interval T_up (s)"""
    train_t_up_s: float = DemandConfig.t_up_s
    """demand of the free-flow trainings (s); the models are trained once and meet every demand"""
    train_steps: int = 90_000
    steps: int = 20_000
    accident_start: int = 2_000
    accident_steps: int = 10_000
    seeds: tuple[int, ...] = (1, 2, 3)
    train_seed: int = 0
    trajectory_every: int = 5
    loop_period_s: float = 60.0
    baselines: tuple[str, ...] = BASELINES
    mobil_ps: tuple[float, ...] = MOBIL_PS
    alphas: tuple[float, ...] = ALPHAS
    presets: tuple[str, ...] = PRESETS
    """learner presets (config.DQN_PRESETS) whose models are trained and run, side by side"""
    fcd_period_s: float = 5.0
    """period of SUMO's fcd.xml in every run folder (s)"""
    tripinfo: bool = True
    """write SUMO's tripinfo.xml in every run folder"""
    profile: str = "default"

    def outputs(self) -> OutputConfig:
        """SUMO's output files of every accident run."""
        return OutputConfig(fcd_period_s=self.fcd_period_s, tripinfo=self.tripinfo)

    def baseline_policies(self) -> tuple[str, ...]:
        """keep and greedy, MOBIL at every politeness, then SUMO's own models."""
        first = tuple(b for b in self.baselines if b != "sumo")
        mobils = tuple(f"mobil:p={number_name(p)}" for p in self.mobil_ps)
        return first + mobils + tuple(b for b in self.baselines if b == "sumo")

    @staticmethod
    def quick() -> Plan:
        """2 demands, 1 seed, small step counts. The accident starts at 100 s, once the first vehicles have
        reached the bottleneck (1,300 m at about 23 m/s), so that even a shortened run holds a jam to show."""
        return Plan(t_ups=(3.0, 1.0), train_steps=3000, steps=6000, accident_start=1000, accident_steps=3000,
                    seeds=(1,), loop_period_s=30.0, profile="quick")  # fmt: skip

    @staticmethod
    def full() -> Plan:
        """The paper's accident: 90,000 steps, the stuck ratio decaying over 50,000 of them; 5 seeds."""
        return Plan(steps=90_000, accident_start=AccidentConfig.start_step,
                    accident_steps=AccidentConfig.duration_steps, t_ups=(3.0, 2.0, 1.5, 1.0), seeds=(1, 2, 3, 4, 5),
                    profile="full")  # fmt: skip


def model_name(preset: str, alpha: float) -> str:
    """Folder of a model under models/ (the default preset keeps the plain alpha<A> name)."""
    return f"alpha{number_name(alpha)}" if preset == "default" else f"{preset}_alpha{number_name(alpha)}"


def model_label(preset: str, alpha: float) -> str:
    """A model's name in tables and run folders (label_for of its policy)."""
    return "dqn_" + model_name(preset, alpha)


def train_config(plan: Plan, alpha: float, preset: str = "default") -> TrainConfig:
    """The free-flow training of one model with the learner preset `preset`."""
    sim = SimConfig(
        road=RoadConfig(lanes=plan.lanes, loop_period_s=plan.loop_period_s),
        demand=DemandConfig(t_up_s=plan.train_t_up_s),
        reward=RewardConfig(alpha=alpha),
        steps=plan.train_steps,
        seed=plan.train_seed,
        policy="dqn",
    )
    return TrainConfig(sim=sim, dqn=DQN_PRESETS[preset], eval_steps=0)


def accident_config(plan: Plan, policy: str, seed: int, t_up_s: float) -> SimConfig:
    """One policy through the accident at demand t_up_s (s) on seed `seed`."""
    return SimConfig(
        road=RoadConfig(lanes=plan.lanes, loop_period_s=plan.loop_period_s),
        demand=DemandConfig(t_up_s=t_up_s),
        accident=AccidentConfig(enabled=True, start_step=plan.accident_start, duration_steps=plan.accident_steps),
        steps=plan.steps,
        seed=seed,
        policy=policy,
    )


# -- cells run by the shared runner (coopsumo.studies.runner), one per worker process -----------------------
def new_record(spec: dict[str, Any]) -> dict[str, Any]:
    """A cell's record before it runs: what it is and where it writes; nothing measured yet."""
    from coopsumo.studies.runner import blank_record

    return blank_record(spec, ("key", "kind", "label", "seed", "t_up_s", "out", "after"))


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
    """True when path (config.json) records this configuration (config.results_view)."""
    try:
        return bool(results_view(json.loads(path.read_text())["config"]) == results_view(json.loads(json.dumps(cfg))))
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
    p = Parser(prog="coopsumo scenario1", description="Scenario I: the accident bottleneck study.")
    size = p.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="2 demands, 1 seed, small step counts: a few minutes")
    size.add_argument("--full", action="store_true",
                      help="the paper's accident (90,000 steps, 50,000 of them decaying), 4 demands, "
                           "5 seeds")  # fmt: skip
    p.add_argument("--seeds", type=seed_count, default=None,
                   help="number of evaluation seeds, 1..N (default 3; quick 1; full 5)")  # fmt: skip
    p.add_argument("--t-up", dest="t_ups", default=None,
                   help="demands: T_up (s) of the accident runs, comma-separated, e.g. 3,1.5,1 "
                        f"(default {','.join(f'{t:g}' for t in DEMANDS)})")  # fmt: skip
    p.add_argument("--mobil-p", dest="mobil_ps", default=None,
                   help=f"MOBIL politeness values, comma-separated (default {','.join(f'{x:g}' for x in MOBIL_PS)})")
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
        plan = Plan.quick() if args.quick else Plan.full() if args.full else Plan()
        if args.seeds is not None:
            if args.seeds < 1:
                raise UsageError(f"seeds must be >= 1, got {args.seeds}")
            plan = replace(plan, seeds=tuple(range(1, args.seeds + 1)))
        if args.workers < 1:
            raise UsageError(f"workers must be >= 1, got {args.workers}")
        if args.t_ups is not None:
            plan = replace(plan, t_ups=t_up_list("--t-up", args.t_ups, ControlConfig().dt_s))
        if args.mobil_ps is not None:
            plan = replace(plan, mobil_ps=distinct_list("--mobil-p", args.mobil_ps, low=0.0))
        if args.train_steps is not None:
            if args.train_steps < 1:
                raise UsageError(f"train-steps must be >= 1, got {args.train_steps}")
            plan = replace(plan, train_steps=args.train_steps)
        if args.steps is not None:
            if args.steps < 10:
                raise UsageError(f"steps must be >= 10, got {args.steps}")
            scale = args.steps / plan.steps
            plan = replace(plan, steps=args.steps, accident_start=max(int(plan.accident_start * scale), 1),
                           accident_steps=max(int(plan.accident_steps * scale), 1))  # fmt: skip
        if args.alphas is not None:
            plan = replace(plan, alphas=_alpha_list(args.alphas))
        if args.presets is not None:
            plan = replace(plan, presets=_preset_list(args.presets))
        check_backend(args.backend, args.address)
        return run_study(plan, args.out, args.workers, args.backend, args.address)

    return run_cli("scenario1", body)


def run_folder(label: str, seed: int, t_up: float) -> str:
    """A run's folder under the results folder: runs/t<T_up>/<label>_seed<k>."""
    return f"runs/t{number_name(t_up)}/{label}_seed{seed}"


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
    policies: list[tuple[str, str | None]] = [(f"dqn:{model_paths[k]}", train_keys[k]) for k in model_paths]
    policies += [(b, None) for b in plan.baseline_policies()]
    runs: list[tuple[str, float, int, Path, SimConfig]] = []
    for policy, after in policies:
        for t_up in plan.t_ups:
            for seed in plan.seeds:
                cfg = accident_config(plan, policy, seed, t_up)
                label = label_for(policy)
                folder = run_folder(label, seed, t_up)
                out = root / folder
                runs.append((label, t_up, seed, out, cfg))
                model = Path(policy[4:]) if policy.startswith("dqn:") else None
                if after not in retrained and _reusable_run(out, cfg, plan.outputs(), model):
                    continue
                specs.append({"key": f"run_t{number_name(t_up)}_{label}_seed{seed}", "kind": "run", "label": label,
                              "seed": seed, "t_up_s": t_up, "out": folder, "after": after, "config": to_dict(cfg),
                              "trajectory_every": plan.trajectory_every,
                              "outputs": to_dict(plan.outputs())})  # fmt: skip
    n_cells = len(model_paths) + len(runs)
    if specs:
        from coopsumo.sim.network import build_net
        from coopsumo.studies.runner import execute, failed_exit, make_backend, sigterm_interrupts

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
            return failed_exit("scenario1", failed, len(specs), root)

    # 2. tables, figures, report
    from coopsumo.studies.scenario1_report import run_metrics

    sample_s = plan.trajectory_every * ControlConfig().dt_s
    order = {lab: i for i, lab in enumerate(dict.fromkeys(r[0] for r in runs))}
    rows = pd.DataFrame([{"t_up_s": t_up, "policy": lab, "seed": seed, **run_metrics(out, cfg, sample_s)}
                         for lab, t_up, seed, out, cfg in runs])  # fmt: skip
    rows = rows.sort_values(["t_up_s", "policy", "seed"], ascending=[False, True, True],
                            key=lambda c: c.map(order) if c.name == "policy" else c, kind="stable",
                            ignore_index=True)  # fmt: skip
    rows.to_csv(root / "runs.csv", index=False)
    wall = time.perf_counter() - start
    timing = timing_text(plan, runs, model_paths, n_train, len(specs), wall)
    write_outputs(root, plan, rows, runs, timing)
    print(f"scenario1: done in {(time.perf_counter() - start) / 60:.1f} min; report: {root / 'report.md'}")
    return 0


def comparison_pairs(plan: Plan, rows: pd.DataFrame) -> tuple[list[tuple[str, str]], float | None]:
    """The verdict's pairs (cooperative, non-cooperative): every alpha > 0 against alpha = 0 per learner preset,
    every MOBIL p > 0 against p = 0; and the first preset's cooperative alpha (the largest still changing lanes)."""
    from coopsumo.studies.scenario1_report import cooperative_alpha

    pairs = [(model_label(pr, x), model_label(pr, 0.0)) for pr in plan.presets for x in plan.alphas if x > 0]
    if 0.0 in plan.mobil_ps:
        pairs += [(label_for(f"mobil:p={number_name(x)}"), label_for("mobil:p=0")) for x in plan.mobil_ps if x > 0]
    coop = cooperative_alpha(rows, {x: model_label(plan.presets[0], x) for x in plan.alphas})
    return pairs, coop


def fig4_windows(rows: pd.DataFrame, t_up: float, labels: Sequence[str], seed: int, start_s: float,
                 run_end_s: float) -> dict[str, tuple[float, float]]:  # fmt: skip
    """Fig. 4's two windows (s) of WINDOW_S: the jam's onset (from a minute before the accident), and its
    dissolution (centred on the mean on-road recovery of the shown runs; the run's last window if none recovers)."""
    at = rows[(rows["t_up_s"] == t_up) & (rows["seed"] == seed) & rows["policy"].isin(list(labels))]
    rec = at["recovery_time_s"].dropna()
    onset = (max(start_s - 60.0, 0.0), max(start_s - 60.0, 0.0) + WINDOW_S)
    if len(rec):
        mid = start_s + float(rec.mean())
        lo = min(max(mid - WINDOW_S / 2, 0.0), max(run_end_s - WINDOW_S, 0.0))
    else:
        lo = max(run_end_s - WINDOW_S, 0.0)
    return {"onset": onset, "dissolution": (lo, lo + WINDOW_S)}


def write_outputs(root: Path, plan: Plan, rows: pd.DataFrame, runs: list[tuple[str, float, int, Path, SimConfig]],
                  timing: str) -> None:  # fmt: skip
    """summary.csv, the figures and report.md from the table of runs."""
    from coopsumo.report.analysis import flow_density, insertion_backlog, read_detectors, section_speed_bins
    from coopsumo.report.bottleneck import REGIMES
    from coopsumo.report.plots import demand_figure, flow_density_figure, recovery_figure, trajectory_windows_figure
    from coopsumo.studies import scenario1_report as rep

    agg = rep.aggregate(rows)
    agg.to_csv(root / "summary.csv", index=False)
    pairs, coop = comparison_pairs(plan, rows)
    first = plan.seeds[0]
    cfg0 = runs[0][4]
    acc, dt = cfg0.accident, cfg0.control.dt_s
    start_s, end_s, run_end_s = acc.start_step * dt, (acc.start_step + acc.duration_steps) * dt, plan.steps * dt
    window = (start_s, end_s)
    figures: dict[str, str] = {}
    for name in [p.name for p in root.glob("fig*.png")]:
        (root / name).unlink()  # figures of an earlier study with other demands must not stay beside this one
    for t_up in plan.t_ups:
        firsts = [(lab, out) for lab, t, seed, out, _ in runs if seed == first and t == t_up]
        fd = {lab: flow_density(read_detectors(out / "detectors.xml")) for lab, out in firsts}
        tname = number_name(t_up)
        figures[f"fig5_t{tname}"] = flow_density_figure(fd, root / f"fig5_flow_density_t{tname}.png").name
        speeds, backlogs = {}, {}
        for lab, out in firsts:
            traj = pd.read_parquet(out / "trajectories.parquet", columns=["time_s", "vid", "pos_m", "speed_mps"])
            speeds[lab] = section_speed_bins(traj, acc.x_m - 200.0, acc.x_m, 0.0, 30.0)
            backlogs[lab] = insertion_backlog(traj, t_up)
        figures[f"recovery_t{tname}"] = recovery_figure(speeds, backlogs, root / f"fig_recovery_t{tname}.png",
                                                         window, rep.RECOVERY_MPS).name  # fmt: skip
    tts_table = rep.demand_table(rows, "tts_veh_h")
    demand_figure(tts_table, "tts_veh_h", "total time spent (veh-h, log scale)", root / "fig_tts_demand.png")
    noncoop = model_label(plan.presets[0], 0.0)
    shown_alpha = coop if coop is not None else max(plan.alphas)
    shown = [noncoop] + ([model_label(plan.presets[0], shown_alpha)] if shown_alpha > 0 else [])
    fig4_t = rep.most_different_demand(rows, shown[-1], noncoop) if len(shown) > 1 else None
    fig4_t = fig4_t if fig4_t is not None else plan.t_ups[0]
    windows = fig4_windows(rows, fig4_t, shown, first, start_s, run_end_s)
    trajs = {lab: pd.read_parquet(out / "trajectories.parquet") for lab, t, seed, out, _ in runs
             if seed == first and t == fig4_t and lab in shown}  # fmt: skip
    trajectory_windows_figure(trajs, FIG4_LANE, windows, root / "fig4_trajectories.png", acc.x_m,
                              f"SUMO lane {FIG4_LANE}")  # fmt: skip
    gui_label = model_label(plan.presets[0], GUI_ALPHA if GUI_ALPHA in plan.alphas else max(plan.alphas))
    gui_t = min(plan.t_ups)
    _, _, gui_seed, gui_out, gui_cfg = next(r for r in runs if r[0] == gui_label and r[2] == first and r[1] == gui_t)
    gui_text = gui_section(root, gui_out, f"t{number_name(gui_t)}/{gui_label}_seed{gui_seed}", gui_cfg)

    header = (
        f"Profile `{plan.profile}`: {plan.lanes} lanes; demands T_up = {', '.join(f'{t:g}' for t in plan.t_ups)} s "
        f"({', '.join(f'{3600 / t:.0f}' for t in plan.t_ups)} veh/h); {plan.steps} steps ({plan.steps * dt:.0f} s) "
        f"per run; the accident at x = {acc.x_m:.0f} m from step {acc.start_step} for {acc.duration_steps} steps "
        f"(t = {start_s:.0f}-{end_s:.0f} s), stuck ratio decaying 1 -> 0. Models (learner presets "
        f"{', '.join(f'`{p}`' for p in plan.presets)}; alpha in {{{', '.join(f'{x:g}' for x in plan.alphas)}}}) "
        f"trained once, {plan.train_steps} steps in free flow at T_up = {plan.train_t_up_s:g} s (seed "
        f"{plan.train_seed}); evaluated greedily on seeds {', '.join(map(str, plan.seeds))}, which no model saw; "
        f"every policy meets the same demand on the same seeds. Values: mean ± standard deviation over seeds."
    )
    if coop is None:
        claim = ("No model with alpha > 0 makes even 10% of alpha = 0's lane changes here: every cooperative model "
                 "behaves like `keep`.")  # fmt: skip
    else:
        claim = (f"The cooperative model that is not simply `keep`: **alpha = {coop:g}** (the largest alpha whose "
                 f"model makes at least 10% of alpha = 0's lane changes per vehicle over every accident run).")
    sections = [rep.demand_section(rows, agg, t, pairs, figures) for t in plan.t_ups]
    regimes = rep.regime_table(rows, REGIMES)
    figures_text = (
        f"![total time spent](fig_tts_demand.png)\n\nTotal time spent against the inflow, per policy: mean over "
        f"seeds with its 95% bootstrap interval.\n\n![Fig. 4](fig4_trajectories.png)\n\nFig. 4 as in the paper: "
        f"partial trajectories on SUMO lane {FIG4_LANE} (the paper's \"lane 1\"), one line per vehicle coloured by "
        f"speed, at T_up = {fig4_t:g} s (the demand where `{shown[-1]}` and `{noncoop}` differ most in total time "
        f"spent), seed {first}: {WINDOW_S / 60:.0f} minutes around the jam's onset "
        f"({windows['onset'][0]:.0f}-{windows['onset'][1]:.0f} s) and around its dissolution "
        f"({windows['dissolution'][0]:.0f}-{windows['dissolution'][1]:.0f} s); dashed: the bottleneck."
    )
    write_report(root, header, claim, sections, regimes, figures_text, gui_text, timing, json.dumps(versions()))
    print(rep.report_table(agg[agg["t_up_s"] == plan.t_ups[-1]]))


def timing_text(plan: Plan, runs: list[tuple[str, float, int, Path, SimConfig]],
                model_paths: dict[tuple[str, float], Path], n_train: int, n_specs: int,
                wall: float) -> str:  # fmt: skip
    from coopsumo.studies.scenario1_report import timing_note

    per: dict[float, list[Path]] = {t: [] for t in plan.t_ups}
    for _, t_up, _, out, _ in runs:
        per[t_up].append(out / "summary.json")
    return timing_note(wall, len(model_paths) - n_train, len(model_paths), len(runs) - (n_specs - n_train), len(runs),
                       [m.parent / "train_summary.json" for m in model_paths.values()], per)  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
