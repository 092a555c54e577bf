"""Seed robustness of learned policies (the learning study's `make learning` report): pure tables on its runs.

Every learner row is judged per training seed, not only on its mean: every model meets every evaluation seed (its
measures pooled over them) and is compared with each baseline's mean over the same seeds; the worst seed is shown
beside the mean.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from coopsumo.agents.training_logs import log_table
from coopsumo.report.markdown import md_table


def alpha0_runs(runs: pd.DataFrame, variant: str) -> pd.DataFrame:
    """The finished alpha = 0 models of a variant, one row per training seed."""
    ok = runs[(runs["status"] == "ok") & (runs["kind"] == "train")]
    mine = ok[(ok["variant"] == variant) & (ok["alpha"].fillna(0) == 0)]
    return mine.drop_duplicates("seed").sort_values("seed")


def paired_gaps(runs: pd.DataFrame, variant: str, other: str, metric: str = "mean_speed_mps") -> pd.Series:
    """metric(variant at alpha 0) - metric(other), one per model (by training seed): the model's measure pooled over
    the evaluation seeds minus the other's mean over them. Another learner's models are paired by training seed; a
    baseline (one run per evaluation seed) is its mean, the same for every model."""
    ok = runs[runs["status"] == "ok"]
    mine = alpha0_runs(runs, variant).set_index("seed")[metric]
    others = ok[ok["variant"] == other]
    if (others["kind"] == "train").any():
        return (mine - alpha0_runs(runs, other).set_index("seed")[metric]).dropna()
    if others.empty:
        return mine.iloc[:0]
    return (mine - float(others[metric].mean())).dropna()


def robustness_table(runs: pd.DataFrame, variants: list[str], baselines: list[str]) -> pd.DataFrame:
    """One row per variant at alpha 0: mean, sd and worst seed of the mean speed (m/s), lane changes per vehicle,
    and for each baseline the seed-paired gap (mean, worst) and the number of seeds below it."""
    rows = []
    for variant in variants:
        mine = alpha0_runs(runs, variant)
        if mine.empty:
            continue
        worst = mine.loc[mine["mean_speed_mps"].idxmin()]
        row: dict[str, object] = {
            "variant": variant, "seeds": len(mine),
            "speed_mean": mine["mean_speed_mps"].mean(), "speed_sd": mine["mean_speed_mps"].std(),
            "worst_speed": worst["mean_speed_mps"], "worst_seed": int(worst["seed"]),
            "worst_lane_changes": worst["lane_changes_per_vehicle"],
            "lane_changes_mean": mine["lane_changes_per_vehicle"].mean(),
            "lane_changes_max": mine["lane_changes_per_vehicle"].max(),
        }  # fmt: skip
        for base in baselines:
            gaps = paired_gaps(runs, variant, base)
            row[f"{base}_gap_mean"] = gaps.mean() if len(gaps) else math.nan
            row[f"{base}_gap_min"] = gaps.min() if len(gaps) else math.nan
            row[f"{base}_below"] = int((gaps < 0).sum())
        rows.append(row)
    return pd.DataFrame(rows)


def per_seed_table(runs: pd.DataFrame, variants: list[str], baselines: list[str]) -> pd.DataFrame:
    """Mean speed (m/s) and lane changes per vehicle of every alpha = 0 model and baseline, by training seed."""
    ok = runs[runs["status"] == "ok"]
    rows = []
    for variant in [*variants, *baselines]:
        mine = alpha0_runs(runs, variant) if variant in variants else ok[ok["variant"] == variant]
        for _, r in mine.iterrows():
            rows.append({"variant": variant, "seed": int(r["seed"]),
                         "mean_speed_mps": r["mean_speed_mps"],
                         "lane_changes_per_vehicle": r["lane_changes_per_vehicle"]})  # fmt: skip
    return pd.DataFrame(rows)


def markdown(table: pd.DataFrame, baselines: list[str]) -> list[str]:
    """The robustness table as markdown lines."""
    head = ["variant", "seeds", "mean speed (m/s)", "worst seed: speed (lane changes / veh)",
            "lane changes / veh (mean, max)"]  # fmt: skip
    head += [f"vs `{b}`: gap mean, worst (seeds below)" for b in baselines]
    lines = []
    for _, r in table.iterrows():
        cells = [f"`{r['variant']}`", str(r["seeds"]), f"{r['speed_mean']:.2f} ± {r['speed_sd']:.2f}",
                 f"{r['worst_speed']:.2f} ({r['worst_lane_changes']:.2f}), seed {r['worst_seed']}",
                 f"{r['lane_changes_mean']:.2f}, {r['lane_changes_max']:.2f}"]  # fmt: skip
        for b in baselines:
            gap = r[f"{b}_gap_mean"]
            cells.append("-" if math.isnan(gap) else f"{gap:+.2f}, {r[f'{b}_gap_min']:+.2f} ({r[f'{b}_below']})")
        lines.append(cells)
    return md_table(head, lines).split("\n")


def seed_matrix_markdown(per_seed: pd.DataFrame) -> list[str]:
    """Speed (lane changes per vehicle) per training seed: one row per policy, one column per seed."""
    if per_seed.empty:
        return []
    seeds = sorted(per_seed["seed"].unique())
    lines = []
    for variant, group in per_seed.groupby("variant", sort=False):
        by = group.set_index("seed")
        cells = [f"{by.loc[s, 'mean_speed_mps']:.2f} ({by.loc[s, 'lane_changes_per_vehicle']:.2f})"
                 if s in by.index else "-" for s in seeds]  # fmt: skip
        lines.append([f"`{variant}`", *cells])
    return md_table(["policy", *(f"seed {s}" for s in seeds)], lines).split("\n")


def training_seeds_figure(root: Path, runs: pd.DataFrame, variants: list[str], out_path: Path) -> Path:
    """Per variant at alpha 0, one line per training seed: mean speed and lane changes during training."""
    from coopsumo.report.plots import new_figure, save_figure

    def logged(variant: str) -> bool:  # a variant that drives another's models has no training logs of its own
        keys = alpha0_runs(runs, variant)["key"]
        return any((root / "train" / str(k) / "train_log.csv").exists() for k in keys)

    shown = [v for v in variants if logged(v)]
    fig = new_figure(9.0, 2.6 * max(len(shown), 1))
    axes = np.atleast_2d(fig.subplots(max(len(shown), 1), 2, squeeze=False))
    for row, variant in zip(axes, shown, strict=False):
        for _, r in alpha0_runs(runs, variant).iterrows():
            log = log_table(root / "train" / str(r["key"]) / "train_log.csv")  # checked: RecordError naming it
            if log is None:
                continue
            label = f"seed {int(r['seed'])}: {r['mean_speed_mps']:.2f} m/s"
            row[0].plot(log["step"], log["mean_speed_mps"], lw=0.9, label=label)
            row[1].plot(log["step"], log["lane_changes"] / log["vehicles"].clip(lower=1), lw=0.9)
        row[0].set_title(f"{variant}: speed while training (m/s)", fontsize=9)
        row[1].set_title(f"{variant}: lane changes per 1,000 steps / vehicles", fontsize=9)
        row[0].legend(fontsize=6, title="greedy evaluation", title_fontsize=6)
    for ax in axes[-1]:
        ax.set_xlabel("training step")
    fig.tight_layout()
    return save_figure(fig, out_path)


def conditioned_table(runs: pd.DataFrame, variant: str, reference: str) -> pd.DataFrame:
    """Per alpha: `variant` (one model per seed for every alpha) minus `reference` (one model per alpha and seed),
    paired by training seed (same evaluation seed): mean, worst and best of the speed and lane-change differences,
    and the reference's seed sd (the spread the target compares with). Only alphas both have on a common seed."""
    ok = runs[runs["status"] == "ok"].drop_duplicates("key")
    rows = []
    for alpha in sorted(set(ok.loc[ok["variant"] == variant, "alpha"].dropna())):
        a = ok[(ok["variant"] == variant) & (ok["alpha"] == alpha)].set_index("seed")
        b = ok[(ok["variant"] == reference) & (ok["alpha"] == alpha)].set_index("seed")
        seeds = a.index.intersection(b.index)
        if len(seeds) == 0:
            continue
        dv = a.loc[seeds, "mean_speed_mps"] - b.loc[seeds, "mean_speed_mps"]
        dl = a.loc[seeds, "lane_changes_per_vehicle"] - b.loc[seeds, "lane_changes_per_vehicle"]
        sd_v = float(b["mean_speed_mps"].std()) if len(b) > 1 else float("nan")
        sd_l = float(b["lane_changes_per_vehicle"].std()) if len(b) > 1 else float("nan")
        rows.append({"alpha": float(alpha), "seeds": len(seeds),
                     "speed_cond": float(a.loc[seeds, "mean_speed_mps"].mean()),
                     "speed_ref": float(b.loc[seeds, "mean_speed_mps"].mean()),
                     "d_speed_mean": float(dv.mean()), "d_speed_min": float(dv.min()), "d_speed_max": float(dv.max()),
                     "ref_speed_sd": sd_v,
                     "lc_cond": float(a.loc[seeds, "lane_changes_per_vehicle"].mean()),
                     "lc_ref": float(b.loc[seeds, "lane_changes_per_vehicle"].mean()),
                     "d_lc_mean": float(dl.mean()), "ref_lc_sd": sd_l,
                     "within_spread": bool(abs(dv.mean()) <= sd_v) if math.isfinite(sd_v) else False,
                     "not_behind": bool(dv.mean() >= -sd_v) if math.isfinite(sd_v) else False})  # fmt: skip
    return pd.DataFrame(rows)


def conditioned_markdown(table: pd.DataFrame, variant: str, reference: str) -> list[str]:
    """The conditioned-against-per-alpha section of a report."""
    if table.empty:
        return []
    lines = [f"## One network for every alpha: `{variant}` against per-alpha `{reference}` models", "",
             f"`{variant}`: one model per training seed, driven at each alpha; `{reference}`: one model per alpha and "
             "seed. Differences are paired by training seed (the same evaluation demand). Target: the mean speed "
             f"difference within the per-alpha models' seed sd at every alpha.", ""]  # fmt: skip
    head = ["alpha", "seeds", "speed conditioned / per-alpha (m/s)", "difference: mean [worst, best]",
            "per-alpha seed sd", "lane changes / veh conditioned / per-alpha", "difference", "per-alpha seed sd",
            "within spread", "not behind by more"]  # fmt: skip
    rows = [[f"{r['alpha']:g}", str(r["seeds"]), f"{r['speed_cond']:.2f} / {r['speed_ref']:.2f}",
             f"{r['d_speed_mean']:+.2f} [{r['d_speed_min']:+.2f}, {r['d_speed_max']:+.2f}]", f"{r['ref_speed_sd']:.2f}",
             f"{r['lc_cond']:.2f} / {r['lc_ref']:.2f}", f"{r['d_lc_mean']:+.2f}", f"{r['ref_lc_sd']:.2f}",
             "yes" if r["within_spread"] else "no", "yes" if r["not_behind"] else "no"]
            for r in table.to_dict("records")]  # fmt: skip
    lines += md_table(head, rows).split("\n")
    met, level = int(table["within_spread"].sum()), int(table["not_behind"].sum())
    lines += ["", f"Within the per-alpha seed spread at {met} of {len(table)} alphas; not behind by more than it at "
              f"{level} of {len(table)} (ahead by more at {level - met}); for one training per seed instead of "
              f"{len(table)}.", ""]  # fmt: skip
    return lines


T95 = (6.314, 2.920, 2.353, 2.132, 2.015, 1.943, 1.895, 1.860, 1.833, 1.812, 1.796, 1.782, 1.771, 1.761, 1.753)
"""Student's t 0.95 quantile for 1-15 degrees of freedom (a two-sided 90% interval); 1.645 beyond"""


def paired_interval(diffs: np.ndarray) -> tuple[float, float, float]:
    """Mean of seed-paired differences and its two-sided 90% t-interval (lo, hi); nan bounds for one seed."""
    d = np.asarray(diffs, float)
    d = d[np.isfinite(d)]
    if len(d) == 0:
        return math.nan, math.nan, math.nan
    if len(d) == 1:
        return float(d[0]), math.nan, math.nan
    t = T95[len(d) - 2] if len(d) - 1 <= len(T95) else 1.645
    half = t * float(d.std(ddof=1)) / math.sqrt(len(d))
    return float(d.mean()), float(d.mean()) - half, float(d.mean()) + half


def chain_steps(runs: pd.DataFrame, chain: list[str], metric: str = "mean_speed_mps") -> pd.DataFrame:
    """What each change of the chain did at alpha 0: variant minus the variant before it, paired by training seed
    (the same seed's models meet the same evaluation demand). One row per step with both finished on a seed: the
    mean difference, its 90% t-interval over models, and how many models the change made better (higher metric),
    the worst model's difference and the variant's own worst model."""
    rows = []
    for before, after in zip(chain[:-1], chain[1:], strict=True):
        a = alpha0_runs(runs, after).set_index("seed")[metric]
        b = alpha0_runs(runs, before).set_index("seed")[metric]
        diff = (a - b).dropna()
        if diff.empty:
            continue
        mean, low, high = paired_interval(diff.to_numpy(float))
        rows.append({"variant": after, "before": before, "models": len(diff), "diff_mean": mean, "diff_low": low,
                     "diff_high": high, "better": int((diff > 0).sum()), "diff_min": float(diff.min()),
                     "worst": float(a.min())})  # fmt: skip
    return pd.DataFrame(rows)


def chain_markdown(steps: pd.DataFrame) -> list[str]:
    """The chain_steps table as markdown lines, with a sentence on what an interval over 3 models can say."""
    if steps.empty:
        return []
    rows = []
    for _, r in steps.iterrows():
        interval = "" if math.isnan(r["diff_low"]) else f" [{r['diff_low']:+.2f}, {r['diff_high']:+.2f}]"
        rows.append([f"`{r['before']}` -> `{r['variant']}`", f"{r['diff_mean']:+.2f}{interval}",
                     f"{r['better']} of {r['models']}", f"{min(r['diff_min'], 0.0):+.2f}", f"{r['worst']:.2f}"])
    lines = md_table(["change", "mean speed: after minus before (m/s), 90% interval over models", "models faster",
                      "largest loss of one model (m/s)", "worst model after (m/s)"], rows).split("\n")  # fmt: skip
    decided = steps[(steps["diff_low"] > 0) | (steps["diff_high"] < 0)]
    lines += ["", f"An interval that excludes 0 (a change that decidedly helped or hurt on these models): "
              f"{', '.join(f'`{v}`' for v in decided['variant']) or 'none'}. With {int(steps['models'].max())} "
              "models per variant the intervals are wide; a change whose models split is undecided, not neutral."]
    return lines
