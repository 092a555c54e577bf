"""Scenario I's measures: every measure of one accident run (run_metrics reads its folder), their aggregates over
seeds, the seed-paired comparisons with bootstrap intervals, and the choices the report makes from them (the
cooperative alpha, Fig. 4's demand and windows, the sumo-gui step). Pure functions on tables; no SUMO, no text.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from coopsumo.config import SimConfig
from coopsumo.files import read_json
from coopsumo.sim import view
from coopsumo.studies.engine.stats import hierarchical_bootstrap

SLOW_MPS = 5.0
RECOVERY_MPS = 15.0
WAVE_LOOKBACK_S = 120.0
FIELD_DT_S = 5.0
FIELD_DX_M = 25.0
"""cells of the space-time speed field the wave measure reads (s, m)"""
COOPERATIVE_LC_SHARE = 0.1
"""a model is "cooperative, not simply keep" when it makes at least this share of alpha = 0's lane changes"""
N_BOOT = 10_000
BOOT_SEED = 12345
MIN_PAIRS = 3
"""fewer seed pairs than this give no verdict: a bootstrap over one or two seeds is no interval"""
JAM_SHARE = 0.9  # the screenshot step: the first time the view holds this share of its most slow vehicles
WINDOW_S = 600.0
"""length of each partial-trajectory window of Fig. 4 (s)"""


def run_metrics(run_dir: Path, cfg: SimConfig, sample_s: float) -> dict[str, Any]:
    """Every scenario I measure of one accident run (trajectories sampled every sample_s seconds)."""
    from coopsumo.report import bottleneck as bn
    from coopsumo.report.analysis import read_detectors, recovery_time_s, section_speed_bins, stop_and_go_waves

    summary = read_json(run_dir / "summary.json")
    traj = pd.read_parquet(run_dir / "trajectories.parquet")
    det = read_detectors(run_dir / "detectors.xml")
    acc, dt, lanes = cfg.accident, cfg.control.dt_s, cfg.road.lanes
    start_s = acc.start_step * dt
    end_s = (acc.start_step + acc.duration_steps) * dt
    run_end_s = cfg.steps * dt
    counts = bn.occupancy_counts(traj, cfg.demand.t_up_s)
    waiting = counts["waiting"]
    v_ref = cfg.demand.v_exp_mean_kmh / 3.6
    tts = bn.run_time_spent(traj, cfg.demand.t_up_s, sample_s, v_ref)
    section = section_speed_bins(traj, acc.x_m - 200.0, acc.x_m, start_s, 30.0)
    on_road = recovery_time_s(traj, acc.x_m, start_s, threshold_mps=RECOVERY_MPS)
    system = bn.system_recovery_s(section, waiting, start_s, RECOVERY_MPS, lanes)
    reach = bn.queue_reach(traj, waiting, acc.x_m, start_s, SLOW_MPS, lanes)
    waves = bn.wave_summary(bn.lane_jams(traj, acc.x_m, run_end_s, FIELD_DT_S, FIELD_DX_M, slow_mps=SLOW_MPS))
    onsets = stop_and_go_waves(det, acc.x_m, slow_mps=SLOW_MPS, fast_mps=RECOVERY_MPS, lookback_s=WAVE_LOOKBACK_S)
    departed = max(summary["departed"], 1)
    return {
        "tts_veh_h": tts["tts_veh_h"],
        "delay_veh_h": tts["delay_veh_h"],
        "waiting_veh_h": tts["waiting_veh_h"],
        "discharge_veh_h": bn.discharge_veh_h(det, acc.x_m, start_s, end_s),
        "system_recovery_s": system,
        "recovery_time_s": on_road,
        "waves": waves["waves"],
        "wave_speed_kmh": waves["wave_speed_kmh"],
        "slow_regions": waves["slow_regions"],
        "wave_onset_share": onsets["wave_share"],
        "queue_m": reach["queue_m"],
        "spilled_s": reach["spilled_s"],
        "regime": reach["regime"],
        "waiting_at_end_veh": float(waiting.iloc[-1]) if len(waiting) else 0.0,
        "mean_speed_mps": summary["mean_speed_mps"],
        "mean_travel_time_s": summary["mean_travel_time_s"],
        "throughput_veh_per_h": summary["throughput_veh_per_h"],
        "lane_changes_per_vehicle": summary["lane_changes"] / departed,
        "queue_lane_changes_per_vehicle": bn.queue_lane_changes(traj, SLOW_MPS) / departed,
        "collisions": summary["collisions"],
        "teleports": summary["teleports"],
        "horizon_after_start_s": run_end_s - start_s,
    }


METRICS = (
    ("tts_veh_h", "total time spent (veh-h)", "{:.1f}"),
    ("delay_veh_h", "delay (veh-h)", "{:.1f}"),
    ("waiting_veh_h", "of it waiting to enter (veh-h)", "{:.1f}"),
    ("discharge_veh_h", "discharge during accident (veh/h)", "{:.0f}"),
    ("system_recovery_s", "system recovery (s after start)", "{:.0f}"),
    ("recovery_time_s", "on-road recovery (s after start)", "{:.0f}"),
    ("waves", "stop-and-go waves", "{:.1f}"),
    ("queue_m", "queue reach (m)", "{:.0f}"),
    ("lane_changes_per_vehicle", "lane changes / veh", "{:.2f}"),
    ("queue_lane_changes_per_vehicle", "of them in a queue (below 5 m/s) / veh", "{:.2f}"),
    ("mean_speed_mps", "mean speed on road (m/s)", "{:.2f}"),
    ("collisions", "collisions", "{:.0f}"),
    ("teleports", "teleports", "{:.0f}"),
)
COUNTED = ("system_recovery_s", "recovery_time_s")
"""measures that may never happen in a run: the table says in how many seeds they did"""
EXTRA = ("wave_speed_kmh", "slow_regions", "wave_onset_share", "mean_travel_time_s", "throughput_veh_per_h",
         "spilled_s", "waiting_at_end_veh")  # fmt: skip


def aggregate(rows: pd.DataFrame) -> pd.DataFrame:
    """Mean and standard deviation over runs (models x seeds) per demand and policy (metric_mean, metric_std,
    metric_n); `seeds` counts the runs, `models` the trained models among them (0 for a baseline)."""
    keys = [m for m, _, _ in METRICS] + [k for k in EXTRA if k in rows]
    grouped = rows.groupby(["t_up_s", "policy"], sort=False)[keys]
    out = pd.concat([grouped.mean().add_suffix("_mean"), grouped.std(ddof=1).add_suffix("_std"),
                     rows[keys].notna().groupby([rows["t_up_s"], rows["policy"]], sort=False).sum().add_suffix("_n")],
                    axis=1)  # fmt: skip
    out["seeds"] = grouped.size()
    if "train_seed" in rows:
        out["models"] = rows.groupby(["t_up_s", "policy"], sort=False)["train_seed"].nunique()
    else:
        out["models"] = 0
    return out.reset_index()


def censored(values: pd.Series, horizon: pd.Series) -> pd.Series:
    """A time that may never happen (NaN) replaced by the run's horizon: a lower bound of the true time."""
    return values.where(values.notna(), horizon)


MIN_MODELS = 3
"""a comparison of learned policies with fewer models than this gives no verdict: one model is one draw"""


def model_table(frame: pd.DataFrame, value: str | pd.Series) -> pd.DataFrame:
    """One policy's runs as a (models x evaluation seeds) table of `value` (a column name or a Series on frame's
    index); a baseline, which has no model, is one row."""
    model = frame["train_seed"].astype("Float64").fillna(-1) if "train_seed" in frame else pd.Series(-1.0, frame.index)
    values = frame[value] if isinstance(value, str) else value
    wide = pd.DataFrame({"model": model, "seed": frame["seed"], "v": values.astype(float)})
    return wide.pivot_table(index="model", columns="seed", values="v", aggfunc="first", dropna=False)


def paired_differences(ta: pd.DataFrame, tb: pd.DataFrame) -> pd.DataFrame:
    """a - b as a (models x seeds) table on the seeds both have: models of a against models of b of the same
    training seed, models against a baseline's one row, or baseline against baseline (one row)."""
    seeds = ta.columns.intersection(tb.columns)
    ta, tb = ta[seeds], tb[seeds]
    a_models, b_models = list(ta.index) != [-1], list(tb.index) != [-1]
    if a_models and b_models:
        common = ta.index.intersection(tb.index)
        return ta.loc[common] - tb.loc[common]
    if a_models:
        return ta - tb.iloc[0]
    if b_models:
        return -(tb - ta.iloc[0])
    return ta - tb


def compare(rows: pd.DataFrame, t_up: float, a: str, b: str) -> dict[str, Any] | None:
    """Comparison of policy a against b at one demand: TTS, system recovery (never = the run's horizon), waves
    and lane changes, each as (mean a - b, 95% interval) from the two-level bootstrap over models and evaluation
    seeds (stats.hierarchical_bootstrap; over seeds alone when neither is a learned policy); None if either is
    missing. `models`: how many models stand behind the difference (0: none is learned); `tts_fewer`: for how
    many models (or seeds, without models) a spent less time; `tts_model_means`: the difference per model."""
    at = rows[rows["t_up_s"] == t_up]
    frames = {p: at[at["policy"] == p] for p in (a, b)}
    if any(f.empty for f in frames.values()):
        return None
    out: dict[str, Any] = {"a": a, "b": b}
    for key in ("tts_veh_h", "system_recovery_s", "waves", "lane_changes_per_vehicle"):
        tables = []
        for f in (frames[a], frames[b]):
            v = censored(f[key], f["horizon_after_start_s"]) if key == "system_recovery_s" else f[key]
            tables.append(model_table(f, v))
        diff = paired_differences(*tables)
        out[key] = hierarchical_bootstrap(diff.to_numpy(dtype=float), reps=N_BOOT, seed=BOOT_SEED)
        out[key + "_a"] = float(np.nanmean(tables[0][diff.columns].to_numpy(dtype=float)))
        out[key + "_b"] = float(np.nanmean(tables[1][diff.columns].to_numpy(dtype=float)))
        if key == "tts_veh_h":
            learned = list(diff.index) != [-1]
            out["models"] = len(diff) if learned else 0
            out["pairs"] = len(diff.columns)
            means = diff.mean(axis=1)
            out["tts_model_means"] = means.to_numpy(dtype=float)
            out["tts_fewer"] = int((means < 0).sum()) if learned else int((diff.iloc[0] < 0).sum())
            out["tts_seed_diffs"] = diff.iloc[0].to_numpy(dtype=float)
    out["never_a"] = int(frames[a]["system_recovery_s"].isna().sum())
    out["never_b"] = int(frames[b]["system_recovery_s"].isna().sum())
    out["runs_a"], out["runs_b"] = len(frames[a]), len(frames[b])
    return out


def difference_table(rows: pd.DataFrame, pairs: Sequence[tuple[str, str]], key: str = "tts_veh_h") -> pd.DataFrame:
    """Per comparison pair (a, b) and demand: compare()'s mean a - b of key and its 95% two-level interval, the very
    numbers the verdicts judge (for plots.difference_figure). Columns a, b, t_up_s, diff, lo, hi; a pair with a
    policy missing at a demand has no row there."""
    out = []
    for a, b in pairs:
        for t_up in rows["t_up_s"].unique():
            c = compare(rows, float(t_up), a, b)
            if c is not None:
                mean, lo, hi = c[key]
                out.append({"a": a, "b": b, "t_up_s": float(t_up), "diff": mean, "lo": lo, "hi": hi})
    return pd.DataFrame(out, columns=["a", "b", "t_up_s", "diff", "lo", "hi"])


def cooperative_alpha(rows: pd.DataFrame, labels: dict[float, str]) -> float | None:
    """The largest alpha > 0 whose model makes at least COOPERATIVE_LC_SHARE of alpha = 0's lane changes per
    vehicle over every accident run: cooperative, but not simply `keep`. None if none does. labels: alpha -> policy."""
    lc = rows.groupby("policy")["lane_changes_per_vehicle"].mean()
    if labels.get(0.0) not in lc.index:
        return None
    floor = max(COOPERATIVE_LC_SHARE * float(lc[labels[0.0]]), 1e-9)
    found = [x for x, lab in labels.items() if x > 0 and lab in lc.index and float(lc[lab]) >= floor]
    return max(found) if found else None


def most_different_demand(rows: pd.DataFrame, a: str, b: str) -> float | None:
    """The demand at which the seed-paired mean |TTS(a) - TTS(b)| relative to b's TTS is largest."""
    best, best_t = -1.0, None
    for t_up in rows["t_up_s"].unique():
        c = compare(rows, float(t_up), a, b)
        if c is None or not math.isfinite(c["tts_veh_h"][0]):
            continue
        rel = abs(c["tts_veh_h"][0]) / max(c["tts_veh_h_b"], 1e-9)
        if rel > best:
            best, best_t = rel, float(t_up)
    return best_t


def demand_table(rows: pd.DataFrame, value: str) -> pd.DataFrame:
    """Per policy and demand: the mean of value over models and seeds and its 95% two-level bootstrap interval
    (for demand_figure)."""
    out = []
    for (t_up, policy), g in rows.groupby(["t_up_s", "policy"], sort=False):
        table = model_table(g, value).to_numpy(dtype=float)
        mean, lo, hi = hierarchical_bootstrap(table, reps=N_BOOT, seed=BOOT_SEED)
        out.append({"policy": policy, "t_up_s": t_up, value: mean, value + "_lo": lo, value + "_hi": hi})
    return pd.DataFrame(out)


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
