"""Scenario I's report: the figures, sumo-gui's screenshot of the jam (scenario1_gui), the tables per demand, the
verdicts in words and report.md, from the table of runs (scenario1_measures) and the run folders.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import pandas as pd

from coopsumo.config import SimConfig, as_data
from coopsumo.files import read_json, write_atomic, write_text_atomic
from coopsumo.provenance import versions
from coopsumo.report.markdown import md_table
from coopsumo.studies.engine.stats import models_needed
from coopsumo.studies.scenario1.gui import drop_shown, gui_section
from coopsumo.studies.scenario1.horizon import fig4, horizon_outputs
from coopsumo.studies.scenario1.measures import (
    COUNTED,
    METRICS,
    MIN_MODELS,
    MIN_PAIRS,
    RECOVERY_MPS,
    WINDOW_S,
    aggregate,
    compare,
    cooperative_alpha,
    demand_table,
    difference_table,
)
from coopsumo.studies.scenario1.plan import PAPER_PROFILE, Plan, Run, label_for, model_label, study_out
from coopsumo.studies.scenario1.text import DEFINITIONS, deviations_text, training_text
from coopsumo.study_tables import SCENARIO1_RUNS
from coopsumo.validation import number_name

FIG4_LANE = 0  # the paper's "lane 1" taken as the rightmost lane, SUMO index 0
GUI_ALPHA = 8.0  # sumo-gui shows the paper's cooperative model (first preset, first seed, highest demand)
RECOVERY_LINE = f"dotted: {RECOVERY_MPS:g} m/s, the speed above which the road counts as recovered"
"""what the recovery figures' dotted line is, in their caption"""
TTS_DIFFERENCE_LABEL = "total time spent, a - b (veh-h): lower is better for a"
"""fig_tts_difference.png's axis: which way is better, on the figure itself"""


def counted(n: int, word: str) -> str:
    """'1 seed', '5 seeds': a count and its noun, singular for one."""
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def _fmt(fmt: str, mean: float, std: float) -> str:
    if mean is None or (isinstance(mean, float) and math.isnan(mean)):
        return "never"
    text = fmt.format(mean)
    if std is not None and not (isinstance(std, float) and math.isnan(std)):
        text += " ± " + fmt.format(std)
    return text


def report_table(agg: pd.DataFrame) -> str:
    """One markdown table of one demand's aggregate: a row per policy."""
    rows = []
    for _, r in agg.iterrows():
        cells = [_fmt(fmt, r[f"{m}_mean"], r[f"{m}_std"])
                 + (f" ({int(r[f'{m}_n'])}/{int(r['seeds'])})" if m in COUNTED and 0 < r[f"{m}_n"] < r["seeds"] else "")
                 for m, _, fmt in METRICS]  # fmt: skip
        rows.append([str(r["policy"]), *cells])
    return md_table(["policy", *(label for _, label, _ in METRICS)], rows)


def regime_table(rows: pd.DataFrame, regimes: Sequence[str]) -> str:
    """Per demand: where the queue went (runs per regime over every policy and seed), keep's queue reach and
    when the queue reached the entrance."""
    head = ["T_up (s)", "inflow (veh/h)", *(f"runs: {r}" for r in regimes), "keep: queue reach (m)",
            "keep: reached the entrance (s after start)"]  # fmt: skip
    lines = []
    for t_up, group in rows.groupby("t_up_s", sort=False):
        counts = [int((group["regime"] == r).sum()) for r in regimes]
        keep = group[group["policy"] == "keep"]
        reach = _fmt("{:.0f}", keep["queue_m"].mean(), keep["queue_m"].std(ddof=1)) if len(keep) else "-"
        spilled = keep["spilled_s"].dropna()
        spill = f"{spilled.mean():.0f} ({len(spilled)}/{len(keep)} seeds)" if len(spilled) else "never"
        spill = spill if len(keep) else "-"
        lines.append([f"{t_up:g}", f"{3600 / t_up:.0f}", *map(str, counts), reach, spill])
    return md_table(head, lines)


def _direction(ci: tuple[float, float, float], lower_is_better: bool = True) -> str:
    mean, lo, hi = ci
    if not math.isfinite(mean):
        return "no data"
    if lo > 0 or hi < 0:
        better = (hi < 0) == lower_is_better
        return "helps" if better else "hurts"
    return "cannot decide"


def _head(c: dict[str, Any]) -> str:
    """The verdict on total time spent: too few models or seeds to judge, else the interval's direction."""
    if 0 < c["models"] < MIN_MODELS:
        return "few models"
    if c["pairs"] < MIN_PAIRS:
        return "too few"
    return _direction(c["tts_veh_h"])


def _what_it_takes(c: dict[str, Any]) -> str:
    """Why a comparison cannot decide, and about how many models (or seeds) would, at the spread measured."""
    if c["models"]:
        need = models_needed(c["tts_model_means"])
        unit = "models"
    else:
        need = models_needed(c["tts_seed_diffs"])
        unit = "evaluation seeds"
    if need is None:
        return "the interval includes 0"
    return f"the interval includes 0; at the spread measured here it would take about {need} {unit}"


def verdict_line(c: dict[str, Any]) -> str:
    """One sentence on one comparison: its headline on total time spent (decided only when the two-level interval
    over models and seeds excludes 0), then recovery and waves."""
    mean, lo, hi = c["tts_veh_h"]
    base = c["tts_veh_h_b"]
    head = _head(c)
    word = {"helps": "**helps**", "hurts": "**hurts**",
            "cannot decide": f"**cannot decide** ({_what_it_takes(c) if head == 'cannot decide' else ''})",
            "no data": "cannot be judged",
            "too few": f"cannot be judged on {counted(c['pairs'], 'seed')} (at least {MIN_PAIRS} needed)",
            "few models": f"cannot be judged on {counted(c['models'], 'model')} (at least {MIN_MODELS} needed)",
            }[head]  # fmt: skip
    rec, rlo, rhi = c["system_recovery_s"]
    wav, wlo, whi = c["waves"]
    never = ""
    if c["never_a"] or c["never_b"]:
        never = (f"; never recovered: {c['never_a']} of {c['runs_a']} and {c['never_b']} of {c['runs_b']} runs, "
                 "counted at the run's end")  # fmt: skip
    if c["models"]:
        count = f"lower for {c['tts_fewer']} of {counted(c['models'], 'model')}, each on {counted(c['pairs'], 'seed')}"
    else:
        count = f"lower on {c['tts_fewer']} of {counted(c['pairs'], 'seed')}"
    return (
        f"`{c['a']}` against `{c['b']}` {word}: total time spent {mean:+.1f} veh-h "
        f"({100 * mean / base:+.1f}% of {base:.1f}; 95% CI {lo:+.1f} to {hi:+.1f}; {count}); system recovery "
        f"{rec:+.0f} s (CI {rlo:+.0f} to {rhi:+.0f}{never}); stop-and-go waves {wav:+.1f} (CI {wlo:+.1f} to "
        f"{whi:+.1f}); lane changes per vehicle {c['lane_changes_per_vehicle_a']:.2f} against "
        f"{c['lane_changes_per_vehicle_b']:.2f}."
    )


def verdict_word(c: dict[str, Any]) -> str:
    """The verdict on total time spent in one word or phrase (as verdict_line decides it)."""
    head = _head(c)
    if head == "few models":
        return f"{counted(c['models'], 'model')}: too few"
    if head == "too few":
        return f"{counted(c['pairs'], 'seed')}: too few"
    return head


def verdict_table(rows: pd.DataFrame, t_ups: Sequence[float], pairs: Sequence[tuple[str, str]]) -> str:
    """Every comparison at every demand in one table: the difference in total time spent (a - b, veh-h) with its
    95% interval, the count of models (or seeds) with a lower time, and the verdict."""
    lines = []
    for a, b in pairs:
        cells = []
        for t in t_ups:
            c = compare(rows, t, a, b)
            if c is None:
                cells.append("-")
                continue
            mean, lo, hi = c["tts_veh_h"]
            unit = counted(c["models"], "model") if c["models"] else counted(c["pairs"], "seed")
            cells.append(f"{mean:+.1f} [{lo:+.1f}, {hi:+.1f}], lower for {c['tts_fewer']} of {unit}: "
                         f"**{verdict_word(c)}**")  # fmt: skip
        lines.append([f"`{a}` against `{b}`", *cells])
    return ("Total time spent, a minus b (veh-h), with the 95% two-level interval over models and evaluation "
            "seeds:\n\n" + md_table(["comparison (a against b)", *(f"T_up {t:g} s" for t in t_ups)], lines))


def model_spread_table(rows: pd.DataFrame, t_up: float) -> str:
    """Total time spent of each trained model at one demand (mean over its evaluation seeds): the spread between
    models that the intervals include. Empty without learned policies."""
    at = rows[(rows["t_up_s"] == t_up)]
    if "train_seed" not in at or at["train_seed"].isna().all():
        return ""
    learned = at[at["train_seed"].notna()]
    seeds = sorted(int(x) for x in learned["train_seed"].unique())
    lines = []
    for policy, g in learned.groupby("policy", sort=False):
        per = g.groupby("train_seed")["tts_veh_h"].mean()
        cells = [f"{per[k]:.1f}" if k in per.index else "-" for k in seeds]
        spread = f"{per.std(ddof=1):.1f}" if len(per) > 1 else "-"
        lines.append([str(policy), *cells, f"{per.max():.1f}", spread])
    return ("Total time spent (veh-h) of each trained model, mean over its evaluation seeds (training seeds as "
            "columns):\n\n" + md_table(["policy", *(f"model {k}" for k in seeds), "worst", "spread (sd)"], lines))


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
    spread = model_spread_table(rows, t_up)
    if spread:
        lines.append("\n" + spread)
    for key, caption in (("fig5", "Fig. 5: flow against density from every loop and interval, one panel per policy"),
                         ("recovery", "Speed before the bottleneck and vehicles waiting to enter, both per 30 s "
                                      "bin (learned policies thick, the baselines dashed behind)")):  # fmt: skip
        grey = "the other policies' points" if key == "fig5" else f"the accident window; {RECOVERY_LINE}"
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

Every run folder (`runs/t<T_up>/<policy>[_m<training seed>]_seed<k>/`) also holds SUMO's own `detectors.xml`,
`fcd.xml` (every 5 s) and `tripinfo.xml`, for SUMO's tools (`docs/sumo-tools.md` draws Fig. 4 from `fcd.xml`
with `plot_trajectories.py`).

## Definitions (chosen here; the paper gives none)

{DEFINITIONS}

## Deviations and choices

{deviations_text(root)}
{timing}

Versions: {versions_text}.
"""
    write_text_atomic(root / "report.md", text)


PAPER_CLAIM = ("alpha 8 helps: the waves disappear and the road recovers above 15 m/s about 54,000 steps after the "
               "accident starts (Fig. 4, one run, 90,000 steps); with alpha 0 the bottleneck remains")
"""claim (a) as the paper states it, for the side-by-side table"""


def default_study(root: Path, plan: Plan) -> Path | None:
    """The default learner's scenario I beside a study of other presets: the folder the same plan with presets
    ('default',) writes by default (results/scenario1 or results/scenario1_<K>models), when it holds a runs.csv and a
    plan.json whose plan equals this one's but for the presets; None otherwise."""
    if "default" in plan.presets:
        return None
    folder = root.parent / study_out(replace(plan, presets=("default",))).name
    try:
        recorded = read_json(folder / "plan.json")["plan"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    mine = as_data(replace(plan, presets=("default",)))
    if not (folder / "runs.csv").is_file() or recorded != mine:
        return None
    return folder


def side_by_side(rows: pd.DataFrame, plan: Plan, default_rows: pd.DataFrame, default_name: str) -> str:
    """Claim (a) side by side: per demand, alpha 8 minus alpha 0 in total time spent for each learner preset of this
    study and for the default learner of the study beside it (its own models, the same demands and evaluation seeds),
    each with its 95% two-level interval, the count of models with a lower time and the verdict; then whether the
    baselines' runs, which both studies make on the same seeds, agree."""
    learners = [(pr, rows, f"`{pr}` (this study)") for pr in plan.presets]
    learners.append(("default", default_rows, f"`default` ({default_name})"))
    lines = []
    for t in plan.t_ups:
        cells = []
        for preset, frame, _ in learners:
            c = compare(frame, t, model_label(preset, 8.0), model_label(preset, 0.0))
            if c is None:
                cells.append("-")
                continue
            mean, lo, hi = c["tts_veh_h"]
            need = "" if verdict_word(c) != "cannot decide" else f"; {_what_it_takes(c).split('; ')[-1]}"
            cells.append(f"{mean:+.1f} [{lo:+.1f}, {hi:+.1f}] veh-h, lower for {c['tts_fewer']} of "
                         f"{counted(c['models'], 'model')}: **{verdict_word(c)}**{need}")  # fmt: skip
        lines.append([f"T_up {t:g} s", "alpha 8 helps", *cells])
    keys = ["t_up_s", "policy", "seed"]
    base = rows[rows["train_seed"].isna()].set_index(keys)["tts_veh_h"]
    other = default_rows[default_rows["train_seed"].isna()].set_index(keys)["tts_veh_h"]
    common = base.index.intersection(other.index)
    same = int((base.loc[common].round(9) == other.loc[common].round(9)).sum())
    return (f"The paper's claim: {PAPER_CLAIM}. Total time spent, alpha 8 minus alpha 0 (veh-h), with the 95% "
            "two-level interval over models and evaluation seeds, for each learner on its own models:\n\n"
            + md_table(["demand", "the paper", *(name for _, _, name in learners)], lines)
            + f"\n\nThe baselines' runs of the two studies (the same demands and evaluation seeds): {same} of "
              f"{len(common)} give the same total time spent.")


def comparison_pairs(plan: Plan, rows: pd.DataFrame) -> tuple[list[tuple[str, str]], float | None]:
    """The verdict's pairs (cooperative, non-cooperative): every alpha > 0 against alpha = 0 per learner preset,
    every MOBIL p > 0 against p = 0, then every learned policy against `keep` and MOBIL p = 0 (learned against
    classical); and the first preset's cooperative alpha (the largest still changing lanes)."""
    pairs = [(model_label(pr, x), model_label(pr, 0.0)) for pr in plan.presets for x in plan.alphas if x > 0]
    if 0.0 in plan.mobil_ps:
        pairs += [(label_for(f"mobil:p={number_name(x)}"), label_for("mobil:p=0")) for x in plan.mobil_ps if x > 0]
    classical = [b for b in ("keep", label_for("mobil:p=0")) if b in set(rows["policy"])]
    pairs += [(model_label(pr, x), b) for pr in plan.presets for x in plan.alphas for b in classical]
    coop = cooperative_alpha(rows, {x: model_label(plan.presets[0], x) for x in plan.alphas})
    return pairs, coop


DEMAND_FIGURE = re.compile(r"(fig5_flow_density|fig_recovery)_t[0-9.]+\.png")
"""the names of the figures drawn per demand (a user's fig_backup.png beside them stays: issue 82, probe 8, J24)"""


def _demand_figures(root: Path, plan: Plan, shown_runs: list[Run], learned: list[str]) -> dict[str, str]:
    """Fig. 5 (flow-density) and the recovery figure per demand, from the first model's first evaluation seed."""
    from coopsumo.report.analysis import flow_density, insertion_backlog, read_detectors, section_speed_bins
    from coopsumo.report.plots import flow_density_figure, recovery_figure

    acc, dt = shown_runs[0].cfg.accident, shown_runs[0].cfg.control.dt_s
    window = (acc.start_step * dt, (acc.start_step + acc.duration_steps) * dt)
    figures: dict[str, str] = {}
    drop_shown(root, [p.name for p in root.iterdir() if DEMAND_FIGURE.fullmatch(p.name) and p.is_file()])  # of an
    # earlier study with other demands: not beside this one; only these, and only those its report showed
    for t_up in plan.t_ups:
        firsts = [(r.label, r.out) for r in shown_runs if r.seed == plan.seeds[0] and r.t_up == t_up]
        fd = {lab: flow_density(read_detectors(out / "detectors.xml")) for lab, out in firsts}
        tname = number_name(t_up)
        figures[f"fig5_t{tname}"] = flow_density_figure(fd, root / f"fig5_flow_density_t{tname}.png").name
        speeds, backlogs = {}, {}
        for lab, out in firsts:
            traj = pd.read_parquet(out / "trajectories.parquet", columns=["time_s", "vid", "pos_m", "speed_mps"])
            speeds[lab] = section_speed_bins(traj, acc.x_m - 200.0, acc.x_m, 0.0, 30.0)
            backlogs[lab] = insertion_backlog(traj, t_up)
        figures[f"recovery_t{tname}"] = recovery_figure(speeds, backlogs, root / f"fig_recovery_t{tname}.png",
                                                         window, RECOVERY_MPS, learned).name  # fmt: skip
    return figures


def _header(plan: Plan, cfg0: SimConfig) -> str:
    acc, dt = cfg0.accident, cfg0.control.dt_s
    start_s, end_s = acc.start_step * dt, (acc.start_step + acc.duration_steps) * dt
    return (
        f"Profile `{plan.profile}`: {plan.lanes} lanes; demands T_up = {', '.join(f'{t:g}' for t in plan.t_ups)} s "
        f"({', '.join(f'{3600 / t:.0f}' for t in plan.t_ups)} veh/h); {plan.steps} steps ({plan.steps * dt:.0f} s) "
        f"per run; the accident at x = {acc.x_m:.0f} m from step {acc.start_step} for {acc.duration_steps} steps "
        f"(t = {start_s:.0f}-{end_s:.0f} s), stuck ratio decaying 1 -> 0. Models (learner presets "
        f"{', '.join(f'`{p}`' for p in plan.presets)}; alpha in {{{', '.join(f'{x:g}' for x in plan.alphas)}}}) "
        f"{training_text(plan)}; **{counted(len(plan.train_seeds), 'model')} per alpha** (training seeds "
        f"{', '.join(map(str, plan.train_seeds))}), each evaluated greedily on "
        f"**{counted(len(plan.seeds), 'evaluation seed')}** "
        f"({', '.join(map(str, plan.seeds))}), which no model saw; every policy meets the same demand on the same "
        f"seeds. Values in the tables: mean ± standard deviation over runs ({len(plan.train_seeds)} x "
        f"{len(plan.seeds)} for a learned policy, {len(plan.seeds)} for a baseline); Fig. 4, Fig. 5 and the "
        f"recovery figures show the first model (training seed {plan.train_seeds[0]})."
    )


def _claim(root: Path, plan: Plan, rows: pd.DataFrame, pairs: list[tuple[str, str]], coop: float | None) -> str:
    if coop is None:
        claim = ("No model with alpha > 0 makes even 10% of alpha = 0's lane changes here: every cooperative model "
                 "behaves like `keep`.")  # fmt: skip
    else:
        claim = (f"The cooperative model that is not simply `keep`: **alpha = {coop:g}** (the largest alpha whose "
                 f"model makes at least 10% of alpha = 0's lane changes per vehicle over every accident run).")
    claim += "\n\n" + verdict_table(rows, plan.t_ups, pairs)
    beside = default_study(root, plan)
    if beside is not None:
        claim += ("\n\n### Claim (a) side by side with the default learner\n\n"
                  + side_by_side(rows, plan, SCENARIO1_RUNS.read(beside / "runs.csv"), f"results/{beside.name}"))
    return claim


def _figures_text(plan: Plan, fig4_t: float, shown: list[str], windows: dict[str, tuple[float, float]]) -> str:
    return (
        f"![total time spent](fig_tts_demand.png)\n\nTotal time spent against the inflow, per policy: mean over "
        f"models and evaluation seeds with its 95% two-level bootstrap interval (models, then seeds; seeds alone "
        f"for a baseline). On this log scale a difference of a few veh-h cannot be seen: the next figure shows the "
        f"differences themselves.\n\n![difference in total time spent](fig_tts_difference.png)\n\nThe differences "
        f"the verdicts judge: total time spent a minus b (veh-h, linear scale) per demand, with its 95% two-level "
        f"interval: the numbers of the verdict table. Below the zero line a spends less time. One panel per kind of "
        f"pair: cooperative against non-cooperative, learned against classical.\n\n"
        f"![Fig. 4](fig4_trajectories.png)\n\nFig. 4 as in the paper: "
        f"partial trajectories on SUMO lane {FIG4_LANE} (the paper's \"lane 1\"), one line per vehicle coloured by "
        f"speed, at T_up = {fig4_t:g} s (the demand where `{shown[-1]}` and `{shown[0]}` differ most in total time "
        f"spent), the first model of each (training seed {plan.train_seeds[0]}), evaluation seed {plan.seeds[0]}: "
        f"{WINDOW_S / 60:.0f} minutes around the jam's onset "
        f"({windows['onset'][0]:.0f}-{windows['onset'][1]:.0f} s) and around its dissolution "
        f"({windows['dissolution'][0]:.0f}-{windows['dissolution'][1]:.0f} s); dashed: the bottleneck."
    )


def write_outputs(root: Path, plan: Plan, rows: pd.DataFrame, runs: list[Run], timing: str) -> None:
    """summary.csv, the figures and report.md from the table of runs."""
    from coopsumo.report.bottleneck import REGIMES
    from coopsumo.report.plots import demand_figure, difference_figure

    agg = aggregate(rows)
    write_atomic(root / "summary.csv", lambda tmp: agg.to_csv(tmp, index=False))
    pairs, coop = comparison_pairs(plan, rows)
    first = plan.seeds[0]
    shown_runs = [r for r in runs if r.train_seed in (None, plan.train_seeds[0])]  # the figures show the first model
    learned = sorted({r.label for r in runs if r.train_seed is not None})
    figures = _demand_figures(root, plan, shown_runs, learned)
    tts_table = demand_table(rows, "tts_veh_h")
    demand_figure(tts_table, "tts_veh_h", "total time spent (veh-h, log scale)", root / "fig_tts_demand.png")
    vs_classical = [(a, b) for a, b in pairs if a in learned and b not in learned]  # the other panel's pairs
    coop_pairs = [p for p in pairs if p not in vs_classical]
    difference_figure({"cooperative against non-cooperative": difference_table(rows, coop_pairs),
                       "learned against classical": difference_table(rows, vs_classical)},
                      TTS_DIFFERENCE_LABEL, root / "fig_tts_difference.png")  # fmt: skip
    noncoop = model_label(plan.presets[0], 0.0)
    shown_alpha = coop if coop is not None else max(plan.alphas)
    shown = [noncoop] + ([model_label(plan.presets[0], shown_alpha)] if shown_alpha > 0 else [])
    fig4_t, windows = fig4(root, "fig4_trajectories.png", plan, rows, runs, shown, FIG4_LANE)
    gui_label = model_label(plan.presets[0], GUI_ALPHA if GUI_ALPHA in plan.alphas else max(plan.alphas))
    gui_t = min(plan.t_ups)
    gui = next(r for r in shown_runs if r.label == gui_label and r.seed == first and r.t_up == gui_t)
    gui_text = gui_section(root, gui.out, str(gui.out.relative_to(root / "runs")), gui.cfg)
    sections = [demand_section(rows, agg, t, pairs, figures) for t in plan.t_ups]
    if plan.profile == PAPER_PROFILE:  # the paper's horizon: recovery steps per model, waves on lane 1
        sections.append(horizon_outputs(root, plan, rows, runs, FIG4_LANE))
    write_report(root, _header(plan, runs[0].cfg), _claim(root, plan, rows, pairs, coop), sections,
                 regime_table(rows, REGIMES), _figures_text(plan, fig4_t, shown, windows), gui_text, timing,
                 json.dumps(versions()))  # fmt: skip
    if {0.0, 8.0} <= set(plan.alphas):  # claim (a) under its analysis plan: claim_a.md, fig_thrashing.png
        from coopsumo.studies.scenario1.claim_a_report import write_claim_a

        horizon = plan.profile == PAPER_PROFILE
        write_claim_a(root, rows, model_label(plan.presets[0], 8.0), model_label(plan.presets[0], 0.0),
                      HORIZON_NOT_PLANNED if horizon else None)  # fmt: skip
    print(closing_table(agg, plan.t_ups[-1]))


HORIZON_NOT_PLANNED = ("a study at the paper's horizon (`--full`: 90,000-step runs) is not the study the plan was "
                       "fixed for (T_up 2, 1.5 and 1 s, 20,000-step runs, 40 models per alpha); its reading under the "
                       "plan's measures is exploratory")
"""why claim_a.md of a --full study is exploratory (claim_a_report.write_claim_a)"""


def closing_table(agg: pd.DataFrame, t_up: float) -> str:
    """The console's closing table: one demand's table of every policy, headed by which demand it shows."""
    return (f"scenario1: every policy at T_up = {t_up:g} s ({3600 / t_up:,.0f} veh/h), the study's last demand; mean "
            f"± sd over runs (every demand: report.md)\n" + report_table(agg[agg["t_up_s"] == t_up]))
