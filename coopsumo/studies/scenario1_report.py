"""Scenario I's measures per run, their tables per demand, the verdicts and report.md (no SUMO here).

run_metrics reads one finished accident run folder; everything else works on the table of runs
(one row per demand, policy and seed).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from coopsumo.config import SimConfig
from coopsumo.validation import number_name

SLOW_MPS = 5.0
RECOVERY_MPS = 15.0
STOP_GO_UPSTREAM_M = 1000.0
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


def run_metrics(run_dir: Path, cfg: SimConfig, sample_s: float) -> dict[str, Any]:
    """Every scenario I measure of one accident run (trajectories sampled every sample_s seconds)."""
    from coopsumo.report import bottleneck as bn
    from coopsumo.report.analysis import read_detectors, recovery_time_s, section_speed_bins, stop_and_go_waves

    summary = json.loads((run_dir / "summary.json").read_text())
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
    ("mean_speed_mps", "mean speed on road (m/s)", "{:.2f}"),
    ("collisions", "collisions", "{:.0f}"),
    ("teleports", "teleports", "{:.0f}"),
)
COUNTED = ("system_recovery_s", "recovery_time_s")
"""measures that may never happen in a run: the table says in how many seeds they did"""
EXTRA = ("wave_speed_kmh", "slow_regions", "wave_onset_share", "mean_travel_time_s", "throughput_veh_per_h",
         "spilled_s", "waiting_at_end_veh")  # fmt: skip


def aggregate(rows: pd.DataFrame) -> pd.DataFrame:
    """Mean and standard deviation over seeds per demand and policy (metric_mean, metric_std, metric_n)."""
    keys = [m for m, _, _ in METRICS] + [k for k in EXTRA if k in rows]
    grouped = rows.groupby(["t_up_s", "policy"], sort=False)[keys]
    out = pd.concat([grouped.mean().add_suffix("_mean"), grouped.std(ddof=1).add_suffix("_std"),
                     rows[keys].notna().groupby([rows["t_up_s"], rows["policy"]], sort=False).sum().add_suffix("_n")],
                    axis=1)  # fmt: skip
    out["seeds"] = grouped.size()
    return out.reset_index()


def _fmt(fmt: str, mean: float, std: float) -> str:
    if mean is None or (isinstance(mean, float) and math.isnan(mean)):
        return "never"
    text = fmt.format(mean)
    if std is not None and not (isinstance(std, float) and math.isnan(std)):
        text += " ± " + fmt.format(std)
    return text


def report_table(agg: pd.DataFrame) -> str:
    """One markdown table of one demand's aggregate: a row per policy."""
    header = "| policy | " + " | ".join(label for _, label, _ in METRICS) + " |"
    lines = [header, "|" + "---|" * (len(METRICS) + 1)]
    for _, r in agg.iterrows():
        cells = [_fmt(fmt, r[f"{m}_mean"], r[f"{m}_std"])
                 + (f" ({int(r[f'{m}_n'])}/{int(r['seeds'])})" if m in COUNTED and 0 < r[f"{m}_n"] < r["seeds"] else "")
                 for m, _, fmt in METRICS]  # fmt: skip
        lines.append(f"| {r['policy']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def regime_table(rows: pd.DataFrame, regimes: Sequence[str]) -> str:
    """Per demand: where the queue went (runs per regime over every policy and seed), keep's queue reach and
    when the queue reached the entrance."""
    lines = ["| T_up (s) | inflow (veh/h) | " + " | ".join(f"runs: {r}" for r in regimes)
             + " | keep: queue reach (m) | keep: reached the entrance (s after start) |",
             "|" + "---|" * (len(regimes) + 4)]  # fmt: skip
    for t_up, group in rows.groupby("t_up_s", sort=False):
        counts = [int((group["regime"] == r).sum()) for r in regimes]
        keep = group[group["policy"] == "keep"]
        reach = _fmt("{:.0f}", keep["queue_m"].mean(), keep["queue_m"].std(ddof=1)) if len(keep) else "-"
        spilled = keep["spilled_s"].dropna()
        spill = f"{spilled.mean():.0f} ({len(spilled)}/{len(keep)} seeds)" if len(spilled) else "never"
        spill = spill if len(keep) else "-"
        lines.append(f"| {t_up:g} | {3600 / t_up:.0f} | " + " | ".join(map(str, counts)) + f" | {reach} | {spill} |")
    return "\n".join(lines)


def paired_bootstrap(diff: np.ndarray, n_boot: int = N_BOOT, seed: int = BOOT_SEED) -> tuple[float, float, float]:
    """Mean of seed-paired differences and its 95% percentile bootstrap interval over seeds (NaNs dropped).
    (nan, nan, nan) without a difference; the interval is the mean itself with one seed."""
    d = np.asarray(diff, dtype=float)
    d = d[np.isfinite(d)]
    if len(d) == 0:
        return float("nan"), float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    means = d[rng.integers(0, len(d), size=(n_boot, len(d)))].mean(axis=1)
    lo, hi = np.percentile(means, [2.5, 97.5])
    return float(d.mean()), float(lo), float(hi)


def censored(values: pd.Series, horizon: pd.Series) -> pd.Series:
    """A time that may never happen (NaN) replaced by the run's horizon: a lower bound of the true time."""
    return values.where(values.notna(), horizon)


def compare(rows: pd.DataFrame, t_up: float, a: str, b: str) -> dict[str, Any] | None:
    """Seed-paired comparison of policy a against b at one demand: TTS, system recovery (never = the run's
    horizon) and waves, each as (mean a - b, 95% bootstrap interval); None if either is missing."""
    at = rows[rows["t_up_s"] == t_up]
    wide = {p: at[at["policy"] == p].set_index("seed") for p in (a, b)}
    if any(w.empty for w in wide.values()):
        return None
    seeds = wide[a].index.intersection(wide[b].index)
    out: dict[str, Any] = {"pairs": len(seeds), "a": a, "b": b}
    for key in ("tts_veh_h", "system_recovery_s", "waves", "lane_changes_per_vehicle"):
        va, vb = wide[a].loc[seeds, key], wide[b].loc[seeds, key]
        if key == "system_recovery_s":
            va = censored(va, wide[a].loc[seeds, "horizon_after_start_s"])
            vb = censored(vb, wide[b].loc[seeds, "horizon_after_start_s"])
        out[key] = paired_bootstrap((va - vb).to_numpy(dtype=float))
        out[key + "_b"] = float(vb.mean())
        out[key + "_a"] = float(va.mean())
    out["never_a"] = int(wide[a].loc[seeds, "system_recovery_s"].isna().sum())
    out["never_b"] = int(wide[b].loc[seeds, "system_recovery_s"].isna().sum())
    out["tts_fewer"] = int((wide[a].loc[seeds, "tts_veh_h"] < wide[b].loc[seeds, "tts_veh_h"]).sum())
    return out


def _direction(ci: tuple[float, float, float], lower_is_better: bool = True) -> str:
    mean, lo, hi = ci
    if not math.isfinite(mean):
        return "no data"
    if lo > 0 or hi < 0:
        better = (hi < 0) == lower_is_better
        return "helps" if better else "hurts"
    return "no detectable difference"


def verdict_line(c: dict[str, Any]) -> str:
    """One sentence on one comparison: its headline on total time spent, then recovery and waves."""
    mean, lo, hi = c["tts_veh_h"]
    base = c["tts_veh_h_b"]
    head = _direction(c["tts_veh_h"]) if c["pairs"] >= MIN_PAIRS else "too few"
    word = {"helps": "**helps**", "hurts": "**hurts**",
            "no detectable difference": "**makes no detectable difference**", "no data": "cannot be judged",
            "too few": f"cannot be judged on {c['pairs']} seed(s) (at least {MIN_PAIRS} needed)"}[head]  # fmt: skip
    rec, rlo, rhi = c["system_recovery_s"]
    wav, wlo, whi = c["waves"]
    never = ""
    if c["never_a"] or c["never_b"]:
        never = f"; never recovered: {c['never_a']} and {c['never_b']} of {c['pairs']} seeds, counted at the run's end"
    return (
        f"`{c['a']}` against `{c['b']}` {word}: total time spent {mean:+.1f} veh-h "
        f"({100 * mean / base:+.1f}% of {base:.1f}; 95% CI {lo:+.1f} to {hi:+.1f}; lower on {c['tts_fewer']} of "
        f"{c['pairs']} seeds); system recovery {rec:+.0f} s (CI {rlo:+.0f} to {rhi:+.0f}{never}); stop-and-go waves "
        f"{wav:+.1f} (CI {wlo:+.1f} to {whi:+.1f}); lane changes per vehicle {c['lane_changes_per_vehicle_a']:.2f} "
        f"against {c['lane_changes_per_vehicle_b']:.2f}."
    )


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
    """Per policy and demand: the mean of value over seeds and its 95% bootstrap interval (for demand_figure)."""
    out = []
    for (t_up, policy), g in rows.groupby(["t_up_s", "policy"], sort=False):
        mean, lo, hi = paired_bootstrap(g[value].to_numpy(dtype=float))
        out.append({"policy": policy, "t_up_s": t_up, value: mean, value + "_lo": lo, value + "_hi": hi})
    return pd.DataFrame(out)


def timing_note(wall_s: float, models_reused: int, models: int, runs_reused: int, runs: int,
                train_files: list[Path], run_files: dict[float, list[Path]]) -> str:  # fmt: skip
    """Wall time of this invocation, what it reused, and the compute its parts recorded (per demand)."""
    train_s = [float(json.loads(f.read_text()).get("wall_seconds", 0.0)) for f in train_files if f.exists()]
    per = {t: sum(float(json.loads(f.read_text()).get("wall_seconds", 0.0)) for f in fs if f.exists())
           for t, fs in run_files.items()}  # fmt: skip
    text = f"Wall time of this invocation: {wall_s / 60:.1f} min"
    if models_reused or runs_reused:
        text += f" (reused {models_reused} of {models} models and {runs_reused} of {runs} runs)"
    text += (f". Compute recorded by the parts: trainings {', '.join(f'{t / 60:.1f}' for t in train_s)} min; accident "
             f"runs {sum(per.values()) / 60:.1f} core-min in all, per demand: "
             + ", ".join(f"T_up {t:g} s {s / 60:.1f} core-min ({s / max(len(run_files[t]), 1):.0f} s per run)"
                         for t, s in per.items()) + ".")  # fmt: skip
    return text


DEVIATIONS = (
    ("simulator", "own simulator", "Eclipse SUMO via libsumo; SUMO's car-following and lane changing off"),
    ("Newell c, d", "not given", "c = 1.1 1/s, d = -0.1, bumper-to-bumper gap; ~1,970 veh/h per lane at saturation"),
    ("road", "length not given", "2,000 m, 3.2 m lanes; loops at 200, 400, ..., 1,800 m on every lane"),
    ("v_exp", "random, clipped 40-110 km/h", "normal, mean 85 km/h, sd 15 km/h, clipped 40-110 km/h"),
    ("T_up", "not given", "interval between vehicles for the whole road; lane drawn uniformly"),
    (
        "demand of scenario I",
        "not given",
        "an axis of the study (--t-up); default 2, 1.5, 1 s. Measured with `keep` (results/regime_map): on the "
        "default accident the queue stays on the road up to T_up = 2 s (about 560 m), reaches the entrance from "
        "1.5 s (about 580 s after the accident's start; 270 s at 1 s) and has cleared by the run's end at every "
        "demand; one demand (1 s, the earlier study) hid every difference",
    ),
    (
        "accident",
        "stuck ratio p decays 1 -> 0 over ~50,000 steps",
        "a vehicle entering the 100 m before x = 1,300 m is held with probability p; a held vehicle stops at "
        "the line and, standing at the head of its queue, is re-drawn every 1 s; p linear 1 -> 0",
    ),
    (
        "accident length",
        "~50,000 of 90,000 steps",
        "default and committed study: 10,000 of 20,000 steps (200 s warm-up, 800 s after), so that 10 policies x "
        "3 demands x 5 seeds fit a session on 2 cores; `--full` (make scenario1 FULL=1) is the paper's length",
    ),
    ("release start", "not defined", "the accident's first step: p starts to fall below 1 and releases begin"),
    ("lane 1 (Fig. 4)", "not defined", "SUMO lane index 0 (the rightmost lane)"),
    ("trajectories", "-", "recorded every 5 steps (0.5 s) to keep the files small; SUMO's FCD every 5 s"),
    (
        "baselines",
        "-",
        "keep, greedy, MOBIL with politeness p in {0, 0.25, 0.5, 1} on the Newell controller; SUMO's own "
        "Krauss + LC2013",
    ),
    (
        "headline measure",
        "mean speed, recovery time (not defined)",
        "total time spent on the road and waiting to enter (veh-h): mean speed on the road ignores the vehicles "
        "a jam keeps off it",
    ),
    ("delay reference", "-", "the mean expected speed, 85 km/h, for every vehicle"),
    (
        "stop-and-go waves",
        "seen in Fig. 4, not measured",
        "moving jams: connected regions below 5 m/s of the 25 m x 5 s space-time speed field whose downstream "
        "front travels at least 100 m upstream at 5 km/h or faster",
    ),
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


DEFINITIONS = f"""- **Total time spent** (TTS, the headline): vehicle-hours on the road plus vehicle-hours waiting to
  enter, over the whole run. Vehicle k is due to enter at k T_up; it waits from then until it appears on the road. All
  policies meet the same due times, so a policy cannot look good by keeping vehicles off the road.
  **Delay**: TTS minus the time the distance driven would take at 85 km/h (the mean expected speed).
- **Discharge**: vehicles per hour past the first loops downstream of the bottleneck (1,400 m, all lanes), over
  the loop intervals inside the accident window (SUMO's E1 output).
- **System recovery**: seconds from the accident's start to the first 30 s bin from which, to the end of the run,
  the space-mean speed in the 200 m before the bottleneck is above {RECOVERY_MPS:g} m/s AND at most one vehicle
  per lane waits to enter. "never" when that does not happen; in paired differences a "never" counts as the
  run's end (a lower bound). **On-road recovery** is the speed condition alone (the earlier studies' measure).
- **Stop-and-go waves** (moving jams): the space-mean speed field over all lanes from the entrance to the
  bottleneck, in cells of {FIELD_DX_M:g} m x {FIELD_DT_S:g} s; its connected regions (8-neighbours) below
  {SLOW_MPS:g} m/s lasting at least 20 s are slow regions (after Ji et al. 2024, arXiv 2409.00326, who identify
  waves as regions of the speed field below a critical speed of 10-20 mph). A region is a wave when its
  downstream front travels at least 100 m upstream, at a least-squares speed of -5 km/h or faster: a moving
  jam, whose front propagates upstream, where a bottleneck queue's front stays at the bottleneck (Kerner and
  Rehborn 1996). A wave that touches the standing queue merges with it and is not counted. Tests show the
  measure on known cases: hand-made waves (counted, with their speed), steady congestion and free flow (quiet),
  and a real SUMO disturbance (counted, moving upstream; no wave without it).
- **Queue reach**: the largest distance from the bottleneck to the furthest-upstream vehicle slower than
  {SLOW_MPS:g} m/s after the accident's start. **Regime**: "on the road" if at most one vehicle per lane ever
  waits to enter; "reaches the entrance, clears" if more do but not at the end; else "still waiting at the end".
- **Verdicts**: seed-paired differences (cooperative minus non-cooperative) with 95% percentile bootstrap
  intervals over seeds ({N_BOOT:,} resamples). "Helps" or "hurts" only when the interval of the TTS difference
  excludes 0."""


def demand_section(rows: pd.DataFrame, agg: pd.DataFrame, t_up: float, pairs: Sequence[tuple[str, str]],
                   figures: dict[str, str]) -> str:  # fmt: skip
    """The report's part for one demand: its regime, verdict lines, table and figures."""
    at = rows[rows["t_up_s"] == t_up]
    regimes = at["regime"].value_counts()
    regime_text = ", ".join(f"{r}: {n} of {len(at)} runs" for r, n in regimes.items())
    lines = [f"### T_up = {t_up:g} s ({3600 / t_up:.0f} veh/h)\n", f"Where the queue went: {regime_text}.\n"]
    for a, b in pairs:
        c = compare(rows, t_up, a, b)
        if c is not None:
            lines.append("- " + verdict_line(c))
    lines.append("")
    lines.append(report_table(agg[agg["t_up_s"] == t_up]))
    for key, caption in (("fig5", "Fig. 5: flow against density from every loop and interval, one panel per policy"),
                         ("recovery", "Speed before the bottleneck and vehicles waiting to enter")):  # fmt: skip
        grey = "the other policies' points" if key == "fig5" else "the accident window"
        name = figures.get(f"{key}_t{number_name(t_up)}")
        if name:
            lines.append(f"\n![{key}]({name})\n\n{caption}, T_up = {t_up:g} s, first seed (grey: {grey}).")
    return "\n".join(lines)


def write_report(root: Path, header: str, claim: str, sections: list[str], regimes: str, figures_text: str,
                 gui_text: str, timing: str, versions_text: str) -> None:  # fmt: skip
    """report.md from its parts (scenario1.write_outputs makes them)."""
    text = f"""# Scenario I: accident bottleneck

{header}

## The paper's claim and the answer, per demand

The paper (section IV.A, Fig. 4-5): with cooperation (alpha = 8) the stop-and-go waves disappear and the
traffic recovers above 15 m/s after about 74,000 steps; without it (alpha = 0) the bottleneck remains. Here
it is asked at every demand, of the learned models (alpha > 0 against alpha = 0) and of MOBIL's politeness
(p > 0 against p = 0), on the headline measure total time spent, with system recovery and waves beside it.

{claim}

{chr(10).join(sections)}

## Where the queue goes: the demand regimes

{regimes}

## Figures

{figures_text}

{gui_text}

Every run folder (`runs/t<T_up>/<policy>_seed<k>/`) also holds SUMO's own `detectors.xml`, `fcd.xml` (every 5 s)
and `tripinfo.xml`, for SUMO's tools (the README draws Fig. 4 from `fcd.xml` with `plot_trajectories.py`).

## Definitions (chosen here; the paper gives none)

{DEFINITIONS}

## Deviations and choices

{deviations_table()}
{timing}

Versions: {versions_text}.
"""
    (root / "report.md").write_text(text)
