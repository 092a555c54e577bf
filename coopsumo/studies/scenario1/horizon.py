"""Scenario I at the paper's horizon (`scenario1 --full`): the step at which the traffic upstream of the bottleneck
recovers, per model, against the paper's (about step 74,000 for alpha = 8, never for alpha = 0), and the
stop-and-go waves on Fig. 4's lane, per policy. Pure functions on the study's table of runs and the run folders'
trajectories; no SUMO.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from coopsumo.report import bottleneck as bn
from coopsumo.report.markdown import md_table
from coopsumo.studies.scenario1.measures import (
    FIELD_DT_S,
    FIELD_DX_M,
    RECOVERY_MPS,
    SLOW_MPS,
    fig4_windows,
    most_different_demand,
)
from coopsumo.studies.scenario1.plan import Plan, Run, model_label

PAPER_RECOVERY_STEP = {8.0: "about 74,000", 0.0: "never"}
"""the paper's recovery step of Fig. 4/5's runs (90,000 steps, accident from step 20,000), by alpha"""


def recovery_step(recovery_s: float, start_step: int, dt_s: float) -> float:
    """The simulation step at which the on-road speed first stays above RECOVERY_MPS: the accident's start step plus
    the recovery time (s after the start); NaN when it never does."""
    return math.nan if not math.isfinite(recovery_s) else start_step + round(recovery_s / dt_s)


def lane_waves(traj: pd.DataFrame, lane: int, x_to_m: float, t_to_s: float) -> float:
    """Stop-and-go waves (bn.lane_jams' moving jams, as run_metrics counts them over every lane) on one lane."""
    one = traj[traj["lane"] == lane]
    return bn.wave_summary(bn.lane_jams(one, x_to_m, t_to_s, FIELD_DT_S, FIELD_DX_M, slow_mps=SLOW_MPS))["waves"]


def _step_text(v: float) -> str:
    return "never" if not math.isfinite(v) else f"{v:,.0f}"


def recovery_table(rows: pd.DataFrame, t_up: float, start_step: int, dt_s: float) -> str:
    """Per learned policy, each model's recovery step (the median over its evaluation seeds, a run that never
    recovers counted as later than any: never when half or more of its runs never recover), then the mean and range
    over the models that recovered and how many did; per baseline, its runs. Steps count from the run's start (the
    accident starts at start_step)."""
    at = rows[rows["t_up_s"] == t_up].assign(
        step=lambda d: [recovery_step(v, start_step, dt_s) for v in d["recovery_time_s"]])
    at["step"] = at["step"].fillna(math.inf)
    lines = []
    for policy, g in at.groupby("policy", sort=False):
        learned = g["train_seed"].notna().all()
        per = g.groupby("train_seed")["step"].agg(lambda v: float(np.median(v))) if learned else \
            g.set_index("seed")["step"]
        done = per[np.isfinite(per.to_numpy(dtype=float))]
        cells = ", ".join(f"{'m' if learned else 's'}{int(k)}: {_step_text(v)}" for k, v in per.items())
        spread = (f"{done.mean():,.0f} [{done.min():,.0f}, {done.max():,.0f}]" if len(done) else "-")
        alpha = _alpha_of(str(policy))
        paper = PAPER_RECOVERY_STEP.get(alpha, "-") if learned and alpha is not None else "-"
        lines.append([f"`{policy}`", cells, f"{len(done)} of {len(per)}", spread, paper])
    return md_table(["policy", "recovery step of each model (median over its seeds) or run", "models or runs recovered",
                     "mean [min, max] of those", "the paper"], lines)  # fmt: skip


def _alpha_of(label: str) -> float | None:
    """alpha of a learned policy's label (dqn_alpha8, dqn_alpha_only_alpha0), None for a baseline."""
    tail = label.rsplit("alpha", 1)[-1] if label.startswith("dqn_") else ""
    try:
        return float(tail)
    except ValueError:
        return None


def waves_table(wave_rows: pd.DataFrame) -> str:
    """Stop-and-go waves on Fig. 4's lane per policy and demand: mean over its runs [min, max]."""
    rows = [[f"{t_up:g}", f"`{policy}`", str(len(g)),
             f"{g['lane_waves'].mean():.1f} [{g['lane_waves'].min():.0f}, {g['lane_waves'].max():.0f}]"]
            for (t_up, policy), g in wave_rows.groupby(["t_up_s", "policy"], sort=False)]  # fmt: skip
    return md_table(["T_up (s)", "policy", "runs", "waves on the lane, mean [min, max]"], rows)


def wave_rows(runs: Sequence[tuple[str, float, int | None, int, Path]], lane: int, x_to_m: float,
              t_to_s: float) -> pd.DataFrame:  # fmt: skip
    """(policy, T_up, training seed, evaluation seed, run folder) of every run -> its waves on `lane`."""
    out = []
    for label, t_up, train_seed, seed, folder in runs:
        traj = pd.read_parquet(folder / "trajectories.parquet", columns=["time_s", "vid", "pos_m", "speed_mps", "lane"])
        out.append({"t_up_s": t_up, "policy": label, "train_seed": train_seed, "seed": seed,
                    "lane_waves": lane_waves(traj, lane, x_to_m, t_to_s)})  # fmt: skip
    return pd.DataFrame(out)


def horizon_section(rows: pd.DataFrame, t_ups: Sequence[float], start_step: int, dt_s: float, waves: pd.DataFrame,
                    lane: int) -> str:  # fmt: skip
    """The report's section on the paper's horizon: recovery steps per demand, then the waves on Fig. 4's lane."""
    parts = ["## The paper's horizon: when the traffic recovers, and the waves on Fig. 4's lane", "",
             f"The paper's measure: the step at which the mean speed over the 200 m upstream of the bottleneck "
             f"(30 s bins) first rises above {RECOVERY_MPS:g} m/s and stays there to the end of the run (the on-road "
             f"recovery). The paper reads about step 74,000 for alpha = 8 and never for alpha = 0 (its Fig. 4 and "
             f"5, one run each). Here every model is a row entry, the median over its evaluation seeds; the spread "
             f"over models is the replication the paper's single runs could not show."]  # fmt: skip
    for t_up in t_ups:
        parts += ["", f"### T_up = {t_up:g} s ({3600 / t_up:.0f} veh/h)", "",
                  recovery_table(rows, t_up, start_step, dt_s)]  # fmt: skip
    parts += ["", f"Stop-and-go waves on SUMO lane {lane} (the paper's \"lane 1\", Fig. 4's): moving jams of that "
              f"lane's own speed field (cells of {FIELD_DT_S:g} s x {FIELD_DX_M:g} m, slower than {SLOW_MPS:g} m/s, "
              "whose front travels), from the entrance to the bottleneck over the whole run.", "",
              waves_table(waves)]  # fmt: skip
    return "\n".join(parts)


def fig4(root: Path, name: str, plan: Plan, rows: pd.DataFrame, runs: Sequence[Run], shown: Sequence[str],
         lane: int) -> tuple[float, dict[str, tuple[float, float]]]:  # fmt: skip
    """Fig. 4 of the policies `shown` (their first model, first evaluation seed) into root/name, at the demand where
    the last of them and the first differ most in total time spent: (that T_up, its two windows)."""
    from coopsumo.report.plots import trajectory_windows_figure

    cfg = runs[0].cfg
    acc, dt = cfg.accident, cfg.control.dt_s
    first, first_model = plan.seeds[0], plan.train_seeds[0]
    t_up = most_different_demand(rows, shown[-1], shown[0]) if len(shown) > 1 else None
    t_up = t_up if t_up is not None else plan.t_ups[0]
    first_rows = rows[rows["train_seed"].isna() | (rows["train_seed"] == first_model)]
    windows = fig4_windows(first_rows, t_up, shown, first, acc.start_step * dt, plan.steps * dt)
    trajs = {r.label: pd.read_parquet(r.out / "trajectories.parquet") for r in runs
             if r.seed == first and r.t_up == t_up and r.label in shown and r.train_seed in (None, first_model)}
    trajectory_windows_figure(trajs, lane, windows, root / name, acc.x_m, f"SUMO lane {lane}")
    return t_up, windows


def calm_and_thrashing(rows: pd.DataFrame, t_up: float) -> list[tuple[str, int, float]]:
    """The calmest and the most thrashing learned model at demand t_up, by queue lane changes per vehicle (mean over
    its runs there): [(policy, training seed, that mean)], calmest first; one entry for one model, none without."""
    learned = rows[(rows["t_up_s"] == t_up) & rows["train_seed"].notna()]
    per = learned.groupby(["policy", "train_seed"])["queue_lane_changes_per_vehicle"].mean().sort_values(kind="stable")
    picks = list(dict.fromkeys([per.index[0], per.index[-1]])) if len(per) else []
    return [(str(policy), int(seed), float(per[(policy, seed)])) for policy, seed in picks]


def fig4_calm_thrashing(root: Path, plan: Plan, rows: pd.DataFrame, runs: Sequence[Run], lane: int) -> str:
    """Fig. 4 of the calmest and the most thrashing model (calm_and_thrashing) at the densest demand, beside `keep`,
    first evaluation seed, into root/fig4_calm_thrashing.png; the report's paragraph ("" without learned models)."""
    from coopsumo.report.plots import trajectory_windows_figure

    t_up, first = min(plan.t_ups), plan.seeds[0]
    picks = calm_and_thrashing(rows, t_up)
    if not picks:
        return ""
    cfg = runs[0].cfg
    acc, dt = cfg.accident, cfg.control.dt_s
    names: dict[tuple[str, int | None], str] = {
        (policy, seed): f"{policy} m{seed} ({kind}: {value:.2f} queue lane changes per vehicle)"
        for (policy, seed, value), kind in zip(picks, ("calm", "thrashing"), strict=False)}  # fmt: skip
    names[("keep", None)] = "keep"
    shown = [r for r in runs if r.seed == first and r.t_up == t_up and (r.label, r.train_seed) in names]
    mask = (rows["policy"] == "keep") & rows["train_seed"].isna()
    for policy, seed, _ in picks:
        mask |= (rows["policy"] == policy) & rows["train_seed"].eq(seed).fillna(False).astype(bool)
    at = rows[mask]
    windows = fig4_windows(at, t_up, [p for p, _, _ in picks] + ["keep"], first, acc.start_step * dt, plan.steps * dt)
    short: dict[tuple[str, int | None], str] = {  # the panels' titles: "alpha8 m116 (calm: 0.02/veh)"
        (policy, seed): f"{policy.rsplit('_', 1)[-1]} m{seed} ({kind}: {value:.2f}/veh)"
        for (policy, seed, value), kind in zip(picks, ("calm", "thrashing"), strict=False)}  # fmt: skip
    short[("keep", None)] = "keep"
    trajs = {short[(r.label, r.train_seed)]: pd.read_parquet(r.out / "trajectories.parquet")
             for r in sorted(shown, key=lambda r: list(names).index((r.label, r.train_seed)))}  # fmt: skip
    trajectory_windows_figure(trajs, lane, windows, root / "fig4_calm_thrashing.png", acc.x_m, f"SUMO lane {lane}")
    said = " and ".join(f"{names[(p, k)]}" for p, k, _ in picks)
    return (f"\n\n![Fig. 4, calm and thrashing](fig4_calm_thrashing.png)\n\nFig. 4 for the calmest and the most "
            f"thrashing model at T_up = {t_up:g} s, by queue lane changes per vehicle over their runs there: {said}; "
            f"beside `keep`; lane {lane}, evaluation seed {first}; windows: the jam's onset and its dissolution; each "
            "panel's title gives the model's queue lane changes per vehicle (/veh).")


def horizon_outputs(root: Path, plan: Plan, rows: pd.DataFrame, runs: Sequence[Run], lane: int) -> str:
    """The horizon section of a --full study, Fig. 4 for every learner preset after the first (the first's is
    fig4_trajectories.png): fig4_trajectories_<preset>.png, its alpha 0 and largest alpha, first model and seed; and
    Fig. 4 of the calmest and the most thrashing model (fig4_calm_thrashing)."""
    acc, dt = runs[0].cfg.accident, runs[0].cfg.control.dt_s
    waves = wave_rows([(r.label, r.t_up, r.train_seed, r.seed, r.out) for r in runs], lane, acc.x_m, plan.steps * dt)
    text = horizon_section(rows, plan.t_ups, acc.start_step, dt, waves, lane)
    for preset in plan.presets[1:]:
        name = f"fig4_trajectories_{preset}.png"
        t_up, _ = fig4(root, name, plan, rows, runs, [model_label(preset, 0.0), model_label(preset, max(plan.alphas))],
                       lane)  # fmt: skip
        text += (f"\n\n![Fig. 4, {preset}]({name})\n\nFig. 4 for the `{preset}` learner: lane {lane}, T_up = "
                 f"{t_up:g} s, the first model (training seed {plan.train_seeds[0]}) at alpha 0 and "
                 f"{max(plan.alphas):g}, evaluation seed {plan.seeds[0]}; windows as in the figure above.")  # fmt: skip
    return text + fig4_calm_thrashing(root, plan, rows, runs, lane)
