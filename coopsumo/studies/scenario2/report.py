"""Scenario II's report: the tables of alpha* and p*, the paper's trends in words, the figures and report.md,
from the table of runs (scenario2_measures).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from coopsumo.files import write_atomic, write_text_atomic
from coopsumo.report.markdown import md_table, num
from coopsumo.studies.scenario2.measures import (
    PlaneFit,
    PlaneFitError,
    alpha_star_table,
    fit_plane,
    mobil_p_star_table,
    paper_cost_estimate,
    plane_bootstrap,
    policy_rows,
    side_by_side_table,
    withhold_incomplete,
)
from coopsumo.studies.scenario2.plan import PROFILES, Profile
from coopsumo.studies.scenario2.text import ALPHA_STAR_FIGURE, condition_label, trend_verdict
from coopsumo.validation import number_name


def trend_statements(fit: PlaneFit, boot: dict[str, float]) -> list[str]:
    """Plain statements of whether the paper's two trends hold (b1 < 0, b2 < 0), decided on the 90% bootstrap
    interval over models when there is one."""
    out = []
    for coef, name, trend, unit in (
        (fit.b1, "b1", "alpha* grows as T_up shrinks (higher inflow)", "per s of T_up"),
        (fit.b2, "b2", "alpha* grows as the lane count shrinks", "per lane"),
    ):
        low, high = (boot[f"{name}_p05"], boot[f"{name}_p95"]) if boot else (None, None)
        verdict = trend_verdict(coef, low, high)
        text = (f"**{verdict}**: the paper's trend \"{trend}\" needs {name} < 0; "
                f"here {name} = {coef:+.3f} {unit}")  # fmt: skip
        if boot:
            text += (f" (bootstrap over seeds: {name} < 0 in {boot[f'{name}_negative_share']:.0%} of "
                     f"{boot['replicates']} replicates, 90% interval [{low:+.3f}, {high:+.3f}])")  # fmt: skip
        if verdict == "Cannot decide":
            text += "; the interval includes 0, so more models per condition would be needed to tell"
        out.append(text + ".")
    return out


def write_outputs(root: Path, runs: pd.DataFrame, profile: Profile, meta: dict[str, Any], n_boot: int) -> None:
    """alpha_star.csv, the two figures, mobil_p_star.csv (with MOBIL cells) and report.md from the runs table; a
    condition with a failed cell gets no alpha* (or p*): withhold_incomplete."""
    from coopsumo.report.plots_sweep import alpha_label, alpha_star_lanes_figure, speed_heatmap_figure

    table, boots = alpha_star_table(policy_rows(runs, "dqn"), profile.alphas, profile.seeds, n_boot=n_boot)
    table = withhold_incomplete(table, "alpha_star")
    write_atomic(root / "alpha_star.csv", lambda tmp: table.to_csv(tmp, index=False))
    side = None
    if "mobil" in profile.policies:
        p_table = mobil_p_star_table(policy_rows(runs, "mobil"), profile.mobil_ps, profile.eval_seeds)
        p_table = withhold_incomplete(p_table, "p_star")
        write_atomic(root / "mobil_p_star.csv", lambda tmp: p_table.to_csv(tmp, index=False))
        side = side_by_side_table(table, p_table)
    fit: PlaneFit | None = None
    boot: dict[str, float] = {}
    plane_note = ""
    solved = table[np.isfinite(table["alpha_star"].astype(float))]
    try:
        fit = fit_plane(solved["t_up_s"], solved["lanes"], solved["alpha_star"])
        boot = plane_bootstrap(solved, boots)
    except PlaneFitError as err:
        plane_note = f"No plane fitted: {err}."
    figures = {}
    if len(solved):
        alpha_star_lanes_figure(table, profile.alphas, root / ALPHA_STAR_FIGURE,
                                (fit.b0, fit.b1, fit.b2) if fit else None, boots, note=plane_note)  # fmt: skip
        figures["alpha_star"] = ALPHA_STAR_FIGURE
        speeds = table.set_index([pd.Index([condition_label(r.lanes, r.t_up_s) for r in table.itertuples()])])
        speeds = speeds[[f"speed_mps_alpha{number_name(a)}" for a in profile.alphas]]
        speeds.columns = list(profile.alphas)
        speed_heatmap_figure(speeds, table["alpha_star"].tolist(), root / "fig6_speed_heatmap.png")
        figures["heatmap"] = "fig6_speed_heatmap.png"
    if profile.name != "paper" and "dqn" in profile.policies:
        meta["paper_cost_estimate"] = paper_cost_estimate(runs, profile.train_steps, PROFILES["paper"])
    meta["plane"] = asdict(fit) if fit else {"error": plane_note}
    meta["plane_bootstrap"] = boot
    write_text_atomic(root / "report.md", report_text(runs, table, fit, boot, plane_note, profile, meta, figures,
                                                      alpha_label, side))  # fmt: skip


def side_by_side_text(side: pd.DataFrame, alpha_label: Any) -> str:
    """The table of alpha* beside p* and one sentence counting the conditions where alpha* is faster."""
    header = ["lanes", "T_up (s)", "α*", "v(α*) (m/s)", "p*", "v(p*) (m/s)", "v(α*) − v(p*) (m/s)"]
    rows = [[str(r["lanes"]), f"{r['t_up_s']:g}",
             alpha_label(r["alpha_star"]) if math.isfinite(r["alpha_star"]) else "–",
             num(r["alpha_star_speed_mps"]), num(r["p_star"], "{:g}"), num(r["p_star_speed_mps"]),
             num(r["difference_mps"], "{:+.2f}")] for r in side.to_dict("records")]  # fmt: skip
    compared = side[np.isfinite(side["difference_mps"])]
    wins = int((compared["difference_mps"] > 0).sum())
    if compared.empty:
        sentence = "No condition has both an alpha* and a p*, so the two cannot be compared."
    else:
        sentence = (f"The best learned policy (alpha*) beats the best MOBIL politeness (p*) on {wins} of "
                    f"{len(compared)} conditions (higher mean speed over the same seeds).")  # fmt: skip
    return f"{md_table(header, rows)}\n\n{sentence}"


def _eval_text(profile: Profile) -> str:
    """How the models are evaluated, for the report."""
    seeds = profile.eval_seeds
    which = f"seed {seeds[0]}" if len(seeds) == 1 else f"seeds {', '.join(map(str, seeds))}"
    return (f"on evaluation {which}, which no training saw (training seeds {', '.join(map(str, profile.seeds))}). "
            f"**The trained model is the unit:** {len(profile.seeds)} models per condition and alpha, each driven on "
            f"every evaluation seed; a model's value is its mean over them, and every mean, win share and bootstrap "
            "below is over models.")


def _sep(value: Any) -> str:
    """A neighbour separation flag for the report: yes, no, or – (no neighbour)."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return "yes" if bool(value) else "no"


def noise_floor_text(table: pd.DataFrame) -> str:
    """How many conditions have an alpha* that is distinguishable from its neighbours in the alpha grid (of the
    conditions that have an alpha*)."""
    if table.empty or "distinct" not in table:
        return ""
    if "alpha_star" in table:
        table = table[np.isfinite(table["alpha_star"].astype(float))]
    if table.empty:
        return ""
    n = len(table)
    both = int(table["distinct"].astype(bool).sum())
    flags = table[["separated_below", "separated_above"]].map(lambda v: v is True or v == 1.0)
    one = int(flags.any(axis=1).sum())
    return (f"**Noise floor**: alpha* is distinguishable from both its neighbours in the alpha grid in {both} of {n} "
            f"conditions, from at least one of them in {one} (yes: the 90% bootstrap interval over seeds of the "
            "seed-paired speed difference to that neighbour lies above 0; –: alpha* is at the grid's edge). In the "
            "other conditions the seeds cannot tell alpha* from the alphas next to it.")  # fmt: skip


def cost_text(cost: dict[str, float]) -> str:
    """The report's section on what the paper profile would cost (an extrapolation, said so)."""
    if not cost:
        return ""
    paper = PROFILES["paper"]
    return f"""
## What the paper profile would cost (extrapolated)

Measured here: wall seconds per training step = {cost["train_s_per_step_a"] * 1e3:.2f} ms
{cost["train_s_per_step_b_per_veh_h"] * 1e6:+.3f} us per veh/h of inflow, per evaluation step
{cost["eval_s_per_step_a"] * 1e3:.2f} ms {cost["eval_s_per_step_b_per_veh_h"] * 1e6:+.3f} us per veh/h
(least squares over this sweep's cells, 2 cells at a time on this machine). Extrapolated to the paper
profile ({cost["cells"]:,.0f} cells, {cost.get("trainings", cost["cells"]):,.0f} trainings of
{paper.train_steps:,} steps and {cost.get("evaluations", cost["cells"]):,.0f} evaluations of
{paper.eval_steps:,} steps; inflows up to
{cost["max_paper_inflow_veh_h"]:,.0f} veh/h, measured only up to {cost["max_measured_inflow_veh_h"]:,.0f}):
**{cost["core_hours"]:,.0f} core-hours**, i.e. about {cost["machine_days"]:.1f} days on this machine's
{cost["machine_cores"]:.0f} cores and about {cost["cluster_hours"]:.1f} h on a Ray cluster of
{cost["cluster_cpus"]:.0f} CPUs (`--backend ray --address ...`; perfect scaling assumed, not measured).
"""


def _alpha_star_rows(table: pd.DataFrame, alphas: list[float], alpha_label: Any) -> tuple[list[str], list[list[str]]]:
    """The alpha* table's header and rows: one row per condition."""
    header = ["lanes", "T_up (s)", "inflow (veh/h)", "load", "α*", "win share", "bootstrap support",
              "α* 90% boot.", "α* vs smaller / larger α", "spread (m/s)", "seed SE (m/s)"
              ] + [f"v(α={alpha_label(a)})" for a in alphas]  # fmt: skip
    rows = []
    for r in table.to_dict("records"):
        rows.append([str(r["lanes"]), f"{r['t_up_s']:g}", f"{r['inflow_veh_h']:.0f}", num(r["load"]),
                     "–" if not math.isfinite(r["alpha_star"]) else alpha_label(r["alpha_star"]),
                     num(r["win_share"], "{:.0%}"), num(r["boot_support"], "{:.0%}"),
                     f"{num(r['boot_alpha_p05'], '{:g}')}–{num(r['boot_alpha_p95'], '{:g}')}",
                     f"{_sep(r.get('separated_below'))} / {_sep(r.get('separated_above'))}",
                     num(r["spread_mps"]), num(r["seed_se_mps"])]
                    + [num(r[f"speed_mps_alpha{number_name(a)}"]) for a in alphas])  # fmt: skip
    return header, rows


def _plane_text(fit: PlaneFit | None, boot: dict[str, float], plane_note: str) -> str:
    """The fitted plane and the paper's two trends in words, or why they cannot be checked."""
    if fit is not None:
        return (f"Fitted plane over {fit.n} conditions (least squares on alpha*): "
                 f"**alpha\\* = {fit.b0:.3f} {fit.b1:+.3f} T_up {fit.b2:+.3f} lanes**, "
                 f"R² = {num(fit.r2, '{:.3f}')}"
                 + (" (undefined: alpha* is the same in every condition)" if not math.isfinite(fit.r2) else "")
                 + ".\n\n" + "\n\n".join(f"- {s}" for s in trend_statements(fit, boot)))  # fmt: skip
    return f"{plane_note} The paper's trends (b1 < 0, b2 < 0) cannot be checked with this grid."


def _figures_text(figures: dict[str, str]) -> str:
    """The report's figures with their captions."""
    return "\n\n".join(
        [f"![alpha* per lane count]({figures['alpha_star']})\n\nFig. 6: alpha* (red) against inflow, one panel "
         "per lane count on a shared axis of the alphas tried (symmetric log, so 0 shows); the red bar is its 90% "
         "bootstrap range over models, grey discs the share of bootstrap resamples picking each alpha (area), the "
         "dashed line the fitted plane at that lane count." if "alpha_star" in figures else "",
         f"![speed heat map]({figures['heatmap']})\n\nMean evaluation speed over seeds for every alpha and "
         "condition; colour is the gap to the condition's best, framed cells are alpha*." if "heatmap" in figures
         else ""]).strip() or "No figure: no cell succeeded."  # fmt: skip


def _mobil_texts(side: pd.DataFrame | None, profile: Profile, alpha_label: Any) -> tuple[str, str, str]:
    """MOBIL's introduction, section and note (empty when the sweep ran no MOBIL)."""
    mobil_intro, mobil_section, mobil_note = "", "", ""
    if side is not None:
        mobil_intro = (
            "\nMOBIL cells need no training: each runs `mobil:p=P` once, for p in "
            f"{{{', '.join(f'{x:g}' for x in profile.mobil_ps)}}}, on each evaluation seed, with the condition and "
            "number of steps of a DQN model's greedy evaluation (free flow). p* is the p with the best mean speed "
            "over the evaluation seeds (ties go to the smaller p); its win share is counted over them as alpha*'s "
            "is over models.\n"
        )  # fmt: skip
        mobil_section = f"\n## alpha* beside the best MOBIL politeness\n\n{side_by_side_text(side, alpha_label)}\n"
        mobil_note = ("\n- MOBIL: per condition `mobil_p_star.csv` (p*, its win share, the mean speed of every p); "
                      "each MOBIL cell's run folder: `mobil/<key>/`.")  # fmt: skip
    return mobil_intro, mobil_section, mobil_note


def _training_text(profile: Profile) -> str:
    """How the cells train and evaluate."""
    return ("Each cell trains the shared DQN in free flow (scenario II) on its condition with its alpha and training "
            f"seed, then evaluates the model greedily on the same condition {_eval_text(profile)}")


def _head_text(profile: Profile, meta: dict[str, Any], alpha_label: Any, training_text: str, mobil_intro: str) -> str:
    """The report's title, what ran and how alpha* is read."""
    alphas = list(profile.alphas)
    return f"""# Scenario II: choosing the cooperation coefficient alpha

Profile **{profile.name}**: lanes {", ".join(map(str, profile.lanes))}; {len(meta["conditions"])} conditions;
alphas {{{", ".join(alpha_label(a) for a in alphas)}}}; training seeds {", ".join(map(str, profile.seeds))};
evaluation seeds {", ".join(map(str, profile.eval_seeds))};
{profile.train_steps:,} training steps ({profile.train_steps * 0.1 / 60:.1f} min simulated) and
{profile.eval_steps:,} greedy evaluation steps per run; {meta["cells"]} cells
({meta["cells_ok"]} ok, {meta["cells_failed"]} failed). Backend {meta["backend"]}, {meta["workers"]} workers.
Wall time of this invocation: {meta["wall_seconds"] / 60:.1f} min ({meta["cells_run"]} cells run now); the cells'
own wall times sum to {meta["cell_wall_seconds_sum"] / 60:.1f} min and their CPU times to
{meta["cell_cpu_seconds_sum"] / 60:.1f} core-minutes (CPU time does not grow when the machine is shared).

{training_text} Criterion (paper): mean travelling speed
(space-mean speed of the evaluation run, `mean_speed_mps`). alpha* is the alpha with the best mean over seeds
(ties go to the smaller alpha). Uncertainty: *win share* is the share of seeds on which alpha* is the best alpha
(ties share the win); *bootstrap support* is the share of {meta["bootstrap_replicates"]} bootstrap resamples of
the seeds (paired over alphas) whose best alpha is alpha*; the 90% bootstrap range is that of the resampled alpha*.
*Spread* is the best minus the worst alpha's mean speed; *seed SE* the typical standard error of one alpha's mean.
{mobil_intro}
"""


def _tables_text(runs: pd.DataFrame, meta: dict[str, Any], profile: Profile) -> tuple[str, str, str]:
    """The failed cells, the grid of conditions and the safety line."""
    failed = runs[runs["status"] != "ok"]
    failed_text = ("None." if failed.empty else
                   md_table(["cell", "error"], [[r.key, str(r.error).replace("|", "\\|")]
                                                 for r in failed.itertuples()]))  # fmt: skip
    grid = md_table(["lanes", "T_up (s)", "loads (share of lanes × 1,800 veh/h)"],
                     [[str(n), ", ".join(f"{c['t_up_s']:g}" for c in meta["conditions"] if c["lanes"] == n),
                       ", ".join(f"{c['load']:g}" for c in meta["conditions"] if c["lanes"] == n)]
                      for n in profile.lanes])  # fmt: skip
    ok = runs[runs["status"] == "ok"]
    safety = (f"Collisions in evaluation: {int(ok['collisions'].sum())}; teleports: {int(ok['teleports'].sum())} "
              f"(over {len(ok)} successful cells).")  # fmt: skip
    return failed_text, grid, safety


def report_text(runs: pd.DataFrame, table: pd.DataFrame, fit: PlaneFit | None, boot: dict[str, float],
                plane_note: str, profile: Profile, meta: dict[str, Any], figures: dict[str, str],
                alpha_label: Any, side: pd.DataFrame | None = None) -> str:  # fmt: skip
    """The Markdown report; `side` (alpha* beside p*) adds the MOBIL section."""
    alphas = list(profile.alphas)
    header, rows = _alpha_star_rows(table, alphas, alpha_label)
    noise = noise_floor_text(table)
    withheld = [condition_label(r["lanes"], r["t_up_s"]) for r in table.to_dict("records") if r["cells_failed"]]
    if withheld:
        noise = (f"**No alpha\\* (–) where a cell failed** ({'; '.join(withheld)}): it would rest on fewer seeds "
                 f"than asked for; see Failed cells and rerun the same command.\n\n{noise}")  # fmt: skip
    plane = _plane_text(fit, boot, plane_note)
    failed_text, grid, safety = _tables_text(runs, meta, profile)
    figs = _figures_text(figures)
    mobil_intro, mobil_section, mobil_note = _mobil_texts(side, profile, alpha_label)
    steps_note = (
        "Step counts as in the paper (90,000 training steps)." if profile.train_steps >= 90_000 else
        f"{profile.train_steps:,} training steps are far below the paper's 90,000: the models are barely trained, "
        "so alpha* here mostly reflects differences between short trainings, not the paper's effect."
    )  # fmt: skip
    return f"""{_head_text(profile, meta, alpha_label, _training_text(profile), mobil_intro)}## alpha* per condition

{md_table(header, rows)}

{noise}
{mobil_section}
## The paper's trends

{plane}

{safety}

## Figures

{figs}
{cost_text(meta.get("paper_cost_estimate") or {})}
## Grid

T_up per lane count is placed by load (inflow as a share of lanes × 1,800 veh/h): T_up = 3600 / (load × lanes
× 1800) s, rounded to 0.01 s; load 1 is near capacity (one lane carries about 1,970 veh/h in this model).
T_up is the interval between vehicles for the whole road (inflow = 3600 / T_up veh/h).

{grid}

## Failed cells

{failed_text}

Rerunning the same command retries failed cells and keeps the finished ones.

## Notes

- Runs: `runs.csv` (one row per cell, status and error; a DQN model's evaluations pooled: counts summed, every
  other metric averaged over the evaluation seeds), `evals.csv` (one row per evaluation run); per condition:
  `alpha_star.csv`; each cell's record: `cells/<key>.json`; its training folder: `train/<key>/`, a link into the
  model store, its evaluations `evals/<key>/eval_s<E>/`.{mobil_note}
- {steps_note}
- Versions: {json.dumps(meta["versions"], sort_keys=True)}.
"""
