"""The learning study's tables, figures and report.md (pure functions of its records)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from coopsumo.agents.conditioning import CONDITIONED_FIELDS
from coopsumo.agents.training_logs import log_table
from coopsumo.dqn_config import DQNConfig
from coopsumo.files import write_atomic, write_text_atomic
from coopsumo.report.markdown import md_table
from coopsumo.studies.followups import robustness
from coopsumo.studies.learning.plan import (
    BASELINES,
    CHAIN_LENGTH,
    EVAL_SEED_OFFSET,
    METRICS,
    VARIANT_NAMES,
    VARIANTS,
    Profile,
    eval_seeds,
    learner_of,
    train_steps,
)
from coopsumo.study_tables import LEARNING_RUNS, LEARNING_SUMMARY


def per_alpha_twin(variant: str, candidates: tuple[str, ...]) -> str | None:
    """The variant among candidates that trains the conditioned `variant`'s learner at one alpha: every
    conditioned-only setting (conditioning.CONDITIONED_FIELDS) at its default; None when there is none."""
    default = DQNConfig()
    twin = replace(learner_of(variant), preset="default", **{f: getattr(default, f) for f in CONDITIONED_FIELDS})
    return next((n for n, _, c in VARIANTS if c == twin and n in candidates), None)


# -- tables ----------------------------------------------------------------------------------------
def runs_table(records: list[dict[str, Any]]) -> pd.DataFrame:
    """One tidy row per cell: coordinates, status, the evaluation metrics, training cost."""
    rows = []
    for r in records:
        s = r.get("summary") or {}
        t = r.get("train_summary") or {}
        row = {k: r.get(k) for k in ("key", "kind", "part", "variant", "alpha", "seed", "eval_seed", "status")}
        row.update({m: s.get(m) for m in METRICS})
        row.update(train_mean_speed_mps=t.get("mean_speed_mps"), train_lane_changes=t.get("lane_changes"),
                   train_wall_s=t.get("wall_seconds"), train_steps_per_s=t.get("steps_per_second"),
                   train_updates=t.get("updates"), cell_wall_s=r.get("cell_wall_s"))  # fmt: skip
        rows.append(row)
    table = pd.DataFrame(rows)
    for m in (*METRICS, "alpha", "train_mean_speed_mps", "train_wall_s", "train_steps_per_s", "cell_wall_s"):
        table[m] = pd.to_numeric(table[m], errors="coerce").astype(float)
    return table


def summarise(runs: pd.DataFrame, by: list[str]) -> pd.DataFrame:
    """Mean, standard deviation and count over seeds of every metric, per group."""
    ok = runs[runs["status"] == "ok"]
    cols = [*METRICS, "train_wall_s"]
    agg = ok.groupby(by, dropna=False, sort=False)[cols].agg(["mean", "std", "count"])
    agg.columns = [f"{m}_{stat}" for m, stat in agg.columns]
    return agg.reset_index()


def is_monotone_decreasing(means: np.ndarray, sds: np.ndarray) -> bool:
    """True when no step up of the means exceeds the larger of the two neighbours' standard deviations."""
    for i in range(len(means) - 1):
        rise = means[i + 1] - means[i]
        if rise > max(np.nan_to_num(sds[i]), np.nan_to_num(sds[i + 1])):
            return False
    return True


# -- figures ---------------------------------------------------------------------------------------
def training_curves_figure(root: Path, runs: pd.DataFrame, out_path: Path) -> Path:
    """Mean speed during training (exploring) per log window, mean over seeds, one line per variant."""
    from coopsumo.report.plots import new_figure, save_figure

    fig = new_figure(9.0, 4.5)
    axes = fig.subplots(1, 2)
    ok = runs[(runs["status"] == "ok") & (runs["part"] == "ablation")]
    for i, (variant, group) in enumerate(ok.groupby("variant", sort=False)):
        style = {"color": f"C{i % 10}", "linestyle": "-" if i < 10 else "--"}  # 10 colours: the rest dashed
        logs = []
        for key in group["key"]:  # each checked as a reused training's was (RecordError naming file and column)
            if (log := log_table(root / "train" / key / "train_log.csv")) is not None:
                logs.append(log.set_index("step"))
        if not logs:
            continue
        speed = pd.concat([lg["mean_speed_mps"] for lg in logs], axis=1).mean(axis=1)
        lc = pd.concat([lg["lane_changes"] / lg["vehicles"].clip(lower=1) for lg in logs], axis=1).mean(axis=1)
        axes[0].plot(speed.index, speed.to_numpy(), label=str(variant), **style)
        axes[1].plot(lc.index, lc.to_numpy(), label=str(variant), **style)
    axes[0].set_xlabel("training step")
    axes[0].set_ylabel("mean speed while training (m/s)")
    axes[1].set_xlabel("training step")
    axes[1].set_ylabel("lane changes per 1,000 steps / vehicles on road")
    if axes[0].get_lines():
        axes[0].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    return save_figure(fig, out_path)


def alpha_response_figure(alpha_tab: pd.DataFrame, base: pd.DataFrame, out_path: Path) -> Path:
    """Lane changes per vehicle and mean speed against alpha (mean and sd over seeds), baselines as lines."""
    from coopsumo.report.plots import new_figure, save_figure

    fig = new_figure(9.0, 4.0)
    axes = fig.subplots(1, 2)
    grid = sorted(alpha_tab["alpha"].unique())
    x = np.arange(len(grid))
    for ax, metric, label in ((axes[0], "lane_changes_per_vehicle", "lane changes per vehicle"),
                              (axes[1], "mean_speed_mps", "mean speed (m/s)")):  # fmt: skip
        for variant, tab in alpha_tab.groupby("variant", sort=False):
            ax.errorbar(x[np.searchsorted(grid, tab["alpha"])], tab[f"{metric}_mean"],
                        yerr=tab[f"{metric}_std"].fillna(0), marker="o", capsize=3,
                        label=f"DQN `{variant}`")  # fmt: skip
        for _, row in base.iterrows():
            ax.axhline(row[f"{metric}_mean"], lw=0.8, ls="--", color="grey")
            ax.annotate(str(row["variant"]), (x[-1], row[f"{metric}_mean"]), fontsize=7, color="grey")
        ax.set_xticks(x, [f"{a:g}" for a in grid])
        ax.set_xlabel("alpha")
        ax.set_ylabel(label)
    if axes[0].get_lines():
        axes[0].legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, out_path)


# -- report ----------------------------------------------------------------------------------------
def _fmt(mean: float, sd: float, fmt: str = "{:.2f}") -> str:
    if mean is None or (isinstance(mean, float) and math.isnan(mean)):
        return "-"
    return fmt.format(mean) + ("" if sd is None or math.isnan(sd) else " ± " + fmt.format(sd))


def _table_rows(tab: pd.DataFrame, label: str) -> list[list[str]]:
    rows = []
    for _, r in tab.iterrows():
        rows.append([
            str(r[label]) if label != "alpha" else f"{r[label]:g}",
            _fmt(r["mean_speed_mps_mean"], r["mean_speed_mps_std"]),
            _fmt(r["lane_changes_per_vehicle_mean"], r["lane_changes_per_vehicle_std"], "{:.3f}"),
            _fmt(r["lane_changes_rejected_mean"], r["lane_changes_rejected_std"], "{:.0f}"),
            _fmt(r["teleports_mean"], r["teleports_std"], "{:.1f}"),
            _fmt(r["collisions_mean"], r["collisions_std"], "{:.1f}"),
            _fmt(r["throughput_veh_per_h_mean"], r["throughput_veh_per_h_std"], "{:.0f}"),
            _fmt(r["train_wall_s_mean"], r["train_wall_s_std"], "{:.0f}"),
            str(int(r["mean_speed_mps_count"])),
        ])  # fmt: skip
    return rows


COLUMNS = ["mean speed (m/s)", "lane changes / veh", "refused requests", "teleports", "collisions",
           "throughput (veh/h)", "training wall (s)", "seeds"]  # fmt: skip
"""the columns of the ablation's and the alpha response's tables, after the variant or alpha"""


def _longer(profile: Profile) -> str:
    """The variants of the profile trained longer, as words (empty: none)."""
    longer = [f"`{v}` {train_steps(profile, v):,}" for v in profile.variants
              if train_steps(profile, v) != profile.train_steps]  # fmt: skip
    return f" ({', '.join(longer)})" if longer else ""


def report_text(profile: Profile, runs: pd.DataFrame, abl: pd.DataFrame, alpha_tab: pd.DataFrame,
                base: pd.DataFrame, meta: dict[str, Any]) -> str:  # fmt: skip
    lines = [
        "# What makes the shared DQN learn: ablation and alpha response",
        "",
        f"Profile `{profile.name}`: {profile.lanes} lanes, T_up = {profile.t_up_s:g} s, free flow; each model trained "
        f"{profile.train_steps:,} steps of 0.1 s{_longer(profile)} on training seeds {list(profile.seeds)}, then "
        f"evaluated greedily for "
        f"{profile.eval_steps:,} steps on every evaluation seed {list(eval_seeds(profile))} ({EVAL_SEED_OFFSET} + "
        "each training seed: demands no training saw). A model's measures pool its evaluations (counts summed, lane "
        "changes per vehicle over all its vehicles, speeds averaged); baselines run on the same evaluation seeds. "
        "The trained model is the unit: every figure is mean ± standard deviation over models (training seeds); a "
        "baseline's is over the evaluation seeds.",
        f"{meta['cells']} cells, {meta['cells_run']} run by the last command (wall time {meta['wall_seconds']:.0f} s, "
        f"{meta['workers']} workers, {meta['backend']} backend); all cells together took "
        f"{meta.get('cell_cpu_seconds_sum', 0) / 3600:.1f} CPU hours "
        f"({meta.get('cell_wall_seconds_sum', 0) / 3600:.1f} h of cell wall time summed over cells).",
        "",
        "## Ablation: from the paper's learner to the default, one change at a time (alpha = 0)",
        "",
    ]
    for name, text, _ in VARIANTS:
        if name in profile.variants:
            lines.append(f"- `{name}`: {text}")
    lines += ["", md_table(["variant", *COLUMNS], _table_rows(abl, "variant") + _table_rows(base, "variant")), ""]
    failed = runs[runs["status"] != "ok"]
    lines += ["![training curves](fig_training_curves.png)", ""]
    lines += robustness_lines(runs, profile)
    for variant, tab in alpha_tab.groupby("variant", sort=False):
        lines += [f"## Alpha response of `{variant}`", "", md_table(["alpha", *COLUMNS], _table_rows(tab, "alpha")), ""]
        if failed.empty:
            mono = is_monotone_decreasing(tab["lane_changes_per_vehicle_mean"].to_numpy(float),
                                          tab["lane_changes_per_vehicle_std"].to_numpy(float))  # fmt: skip
            lines.append(f"Lane changes per vehicle {'fall' if mono else 'do NOT fall'} monotonically as alpha "
                         "rises (a rise larger than the seed spread counts as a break).")  # fmt: skip
            lines.append("")
    if len(alpha_tab):
        lines += ["![alpha response](fig_alpha_response.png)", ""]
    conditioned = [v for v in profile.alpha_variants if learner_of(v).alpha_conditioned]
    for variant in conditioned:
        if (ref := per_alpha_twin(variant, profile.alpha_variants)) is not None:
            lines += robustness.conditioned_markdown(robustness.conditioned_table(runs, variant, ref), variant, ref)
    if failed.empty:
        lines += target_lines(runs, meta.get("default_variant", "replay"))
    else:
        lines += [f"**No verdict** (alpha response, targets): {len(failed)} of {len(runs)} cells failed, so the "
                  "tables above rest on fewer seeds than asked for; rerun the same command to retry them.", ""]
    ok = runs[runs["status"] == "ok"]
    bad = ok[(ok["teleports"] > 0) | (ok["collisions"] > 0)]
    lines.append(f"Safety: {len(bad)} of {len(ok)} evaluations had a teleport or a collision.")
    if len(failed):
        lines.append(f"Failed cells: {', '.join(failed['key'])}.")
    lines += ["", "Reproduce: `coopsumo learning" + ("" if profile.name == "full" else f" --profile {profile.name}")
              + "` (`make learning`; finished cells are reused)."]  # fmt: skip
    return "\n".join(lines) + "\n"


def robustness_lines(runs: pd.DataFrame, profile: Profile) -> list[str]:
    """The seed-robustness section: every alpha = 0 variant judged per training seed against the baselines."""
    variants = list(profile.variants)
    table = robustness.robustness_table(runs, variants, list(BASELINES))
    if table.empty:
        return []
    per_seed = robustness.per_seed_table(runs, variants, list(BASELINES))
    return [
        "## Seed robustness at alpha = 0",
        "",
        "Every model meets every evaluation seed. Gap: the model (pooled over the evaluation seeds) minus the "
        "baseline's mean over the same seeds (m/s); worst: the training seed with the smallest gap; seeds below: how "
        "many models lost to that baseline.",
        "",
        *robustness.markdown(table, list(BASELINES)),
        "",
        f"Mean speed (m/s) and, in brackets, lane changes per vehicle of each model by training seed, pooled over "
        f"the evaluation seeds (baselines: on evaluation seed {EVAL_SEED_OFFSET} + that seed alone):",
        "",
        *robustness.seed_matrix_markdown(per_seed),
        "",
        "![training curves per seed](fig_training_seeds.png)",
        "",
        *_chain_lines(runs, profile),
    ]


def _chain_lines(runs: pd.DataFrame, profile: Profile) -> list[str]:
    """The section on what each change of the chain did, model by model."""
    chain = [v for v in VARIANT_NAMES[:CHAIN_LENGTH] if v in profile.variants]
    table = robustness.chain_markdown(robustness.chain_steps(runs, chain))
    if not table:
        return []
    return ["## Each change of the chain, model by model (alpha = 0)", "",
            "Each variant's model of a training seed minus the previous variant's model of the same seed, both "
            "pooled over the same evaluation seeds.", "", *table, ""]  # fmt: skip


def paired_gap(
    runs: pd.DataFrame, variant: str, other: str, metric: str = "mean_speed_mps"
) -> tuple[float, float, int]:
    """Mean and sd over models of metric(variant, alpha 0) - metric(other) (robustness.paired_gaps)."""
    diff = robustness.paired_gaps(runs, variant, other, metric)
    sd = float(diff.std()) if len(diff) > 1 else float("nan")
    return float(diff.mean()) if len(diff) else float("nan"), sd, len(diff)


def target_lines(runs: pd.DataFrame, default_variant: str) -> list[str]:
    """The issue's targets for the default design at alpha = 0, measured over its models."""
    lines = [f"## Targets: the default design (`{default_variant}`) at alpha = 0", ""]
    mobils = [b for b in BASELINES if b.startswith("mobil")]
    ok = runs[runs["status"] == "ok"]
    best_mobil = max(mobils, key=lambda b: ok[ok["variant"] == b]["mean_speed_mps"].mean(), default=None)
    for other, goal in (("keep", 0.5), ("greedy", 0.5), (best_mobil, -0.3)):
        if other is None:
            continue
        mean, sd, n = paired_gap(runs, default_variant, other)
        if math.isnan(mean):
            continue
        verdict = "met" if mean >= goal else f"not met by {goal - mean:.2f} m/s"
        lines.append(f"- mean speed minus `{other}`: {mean:+.2f} ± {sd:.2f} m/s over {n} models "
                     f"(target {goal:+.1f}: {verdict})")  # fmt: skip
    wall = ok[(ok["variant"] == default_variant) & (ok["kind"] == "train")]["train_wall_s"]
    if len(wall):
        lines.append(f"- training wall time of one model: {wall.mean():.0f} ± {wall.std():.0f} s "
                     "(measured inside its cell, with the other workers busy beside it)")  # fmt: skip
    return [*lines, ""]


def write_outputs(root: Path, profile: Profile, records: list[dict[str, Any]], meta: dict[str, Any]) -> None:
    runs = runs_table(records)
    LEARNING_RUNS.check_frame(runs, root / "runs.csv")  # inside study_tables' limits (a failed cell's numbers: blank)
    abl = summarise(runs[runs["part"] == "ablation"], ["variant"])
    order = {n: i for i, n in enumerate(VARIANT_NAMES)}
    abl = abl.sort_values("variant", key=lambda s: s.map(order)).reset_index(drop=True)
    # the default design's alpha = 0 models are ablation cells when the default is among the variants
    responders = list(profile.alpha_variants) or [str(meta.get("default_variant"))]
    in_alpha = (runs["part"] == "alpha") | (runs["variant"].isin(responders) & (runs["alpha"] == 0))
    alpha_tab = summarise(runs[in_alpha].drop_duplicates("key"), ["variant", "alpha"])
    alpha_tab = alpha_tab.sort_values(["variant", "alpha"], kind="stable").reset_index(drop=True)
    base = summarise(runs[runs["part"] == "baseline"], ["variant"])
    summary = pd.concat([abl.assign(part="ablation"), alpha_tab.assign(part="alpha"), base.assign(part="baseline")])
    LEARNING_SUMMARY.check_frame(summary, root / "summary.csv")  # both inside their limits before either is written
    write_atomic(root / "runs.csv", lambda tmp: runs.to_csv(tmp, index=False))
    write_atomic(root / "summary.csv", lambda tmp: summary.to_csv(tmp, index=False))
    training_curves_figure(root, runs, root / "fig_training_curves.png")
    robustness.training_seeds_figure(root, runs, list(profile.variants), root / "fig_training_seeds.png")
    if len(alpha_tab):
        alpha_response_figure(alpha_tab, base, root / "fig_alpha_response.png")
    write_text_atomic(root / "report.md", report_text(profile, runs, abl, alpha_tab, base, meta))


