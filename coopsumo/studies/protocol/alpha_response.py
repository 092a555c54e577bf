"""The protocol's alpha response (Profile.alphas, alpha_seeds, alpha_variants): each alpha variant's models in free
flow at alpha 0 and at every alpha of the profile, read from its per-model table (protocol_report.per_model).

With one alpha besides 0 (the committed profiles' alpha 8) the question is whether alpha does something: lane
changes per vehicle at alpha 0 and 8. With a grid, how speed and lane changes respond to alpha: the interquartile
mean of each over the models at each alpha, with its stratified bootstrap interval, and a figure
(fig_alpha_response.png).

With two alpha variants or more, each after the first is paired with the first by training seed (the analysis plan
of the `conditioned` profile, fixed before it ran; docs/studies.md): the headline is, per seed that trained at every
alpha, its model's free-flow speed minus the first variant's of the same seed, averaged over the grid's alphas (0
included) and the demands; its mean over seeds with a 95% bootstrap interval over seeds (engine/stats,
hierarchical_bootstrap with one evaluation a model). Decided when the interval excludes 0; otherwise the report gives
about how many seeds would decide (stats.models_needed). The differences at each alpha and demand follow, uncorrected
for their number: descriptive, not a verdict.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from coopsumo.report.markdown import interval, md_table
from coopsumo.studies.engine import stats

FIGURE = "fig_alpha_response.png"
CAPTION = ("Free flow, each alpha variant's models at each alpha: the interquartile mean over models of their mean "
           "speed (left) and lane changes per vehicle (right), with its 95% stratified bootstrap interval; a colour "
           "per demand, a line style per variant. The alpha axis is evenly spaced over the profile's grid.")
"""the figure's caption in the report"""


def responders(profile: Any) -> tuple[str, ...]:
    """The variants whose alpha response the profile measures: its alpha_variants, or the judged one."""
    return tuple(profile.alpha_variants) or (profile.judged_variant(),)


def grid(profile: Any) -> tuple[float, ...]:
    """Alpha 0 and the profile's alphas."""
    return (0.0, *profile.alphas)


def _models(ok: pd.DataFrame, variant: str) -> pd.DataFrame:
    return ok[(ok["kind"] == "model") & (ok["scenario"] == "free") & (ok["variant"] == variant)]


def alpha_lines(profile: Any, ok: pd.DataFrame) -> list[str]:
    """The report's alpha sections: per responding variant with models above alpha 0, lane changes per vehicle by
    demand and alpha (mean over models, their count); with more than one alpha besides 0, also speed and lane
    changes as IQM [95% CI] over models, and the figure."""
    lines: list[str] = []
    alphas = grid(profile)
    for variant in responders(profile):
        models = _models(ok, variant)
        if not (models["alpha"] > 0).any():
            continue
        lines += [f"## Does alpha do something? (free flow, `{variant}`, lane changes per vehicle)", ""]
        rows = []
        for t_up, grp in models.groupby("t_up", sort=False):
            cells = [grp[grp["alpha"] == a]["lane_changes_per_vehicle"] for a in alphas]
            rows.append([f"{t_up:g}", *(f"{c.mean():.3f} ({len(c)})" for c in cells)])
        lines += md_table(["T_up (s)", *(f"alpha {a:g} (models)" for a in alphas)], rows).split("\n")
        lines.append("")
        if len(alphas) > 2:
            lines += _response_lines(variant, response_table(models, alphas))
    if len(alphas) > 2 and lines:
        lines += [f"![alpha response]({FIGURE})", "", CAPTION, ""]
    return lines


def response_table(models: pd.DataFrame, alphas: tuple[float, ...]) -> pd.DataFrame:
    """One row per (demand, alpha) of one variant's models: their count and, for mean speed and lane changes per
    vehicle, the IQM over models with its stratified bootstrap interval (engine/stats.iqm_interval)."""
    rows = []
    for t_up, grp in models.groupby("t_up", sort=False):
        for alpha in alphas:
            at = grp[grp["alpha"] == alpha]
            row: dict[str, Any] = {"t_up": t_up, "alpha": alpha, "models": len(at)}
            for measure in ("mean_speed_mps", "lane_changes_per_vehicle"):
                vals = at[measure].dropna().to_numpy(float)
                point, low, high = stats.iqm_interval(vals[:, None]) if len(vals) else (np.nan,) * 3
                row |= {measure: point, f"{measure}_low": low, f"{measure}_high": high}
            rows.append(row)
    return pd.DataFrame(rows)


def _ci(row: pd.Series, measure: str) -> str:
    return interval(row[measure], row[f"{measure}_low"], row[f"{measure}_high"])


def _response_lines(variant: str, table: pd.DataFrame) -> list[str]:
    rows = [[f"{r['t_up']:g}", f"{r['alpha']:g}", str(int(r["models"])), _ci(r, "mean_speed_mps"),
             _ci(r, "lane_changes_per_vehicle")] for _, r in table.iterrows()]  # fmt: skip
    head = ["T_up (s)", "alpha", "models", "mean speed (m/s), IQM [95% CI]", "lane changes per vehicle, IQM [95% CI]"]
    return [f"How `{variant}` responds to alpha (free flow, over models):", "", *md_table(head, rows).split("\n"), ""]


def response_figure(profile: Any, ok: pd.DataFrame, out_path: Path) -> Path | None:
    """fig_alpha_response.png: speed and lane changes against alpha (IQM and interval over models), a colour per
    demand and a line style per variant; None (nothing drawn) unless the profile has a grid of alphas and models
    above alpha 0."""
    from coopsumo.report.plots import new_figure, save_figure

    alphas = grid(profile)
    tables = [(v, response_table(_models(ok, v), alphas)) for v in responders(profile)]
    tables = [(v, t) for v, t in tables if len(t) and (t[t["alpha"] > 0]["models"] > 0).any()]
    if len(alphas) <= 2 or not tables:
        return None
    fig = new_figure(11, 4)
    axes = fig.subplots(1, 2)
    styles = ("-", "--", ":", "-.")
    for k, (variant, table) in enumerate(tables):
        for j, (t_up, tab) in enumerate(table.groupby("t_up", sort=False)):
            x = np.searchsorted(alphas, tab["alpha"].to_numpy(float))
            for ax, measure in zip(axes, ("mean_speed_mps", "lane_changes_per_vehicle"), strict=True):
                err = [tab[measure] - tab[f"{measure}_low"], tab[f"{measure}_high"] - tab[measure]]
                ax.errorbar(x + 0.04 * k, tab[measure], yerr=err, color=f"C{j}", linestyle=styles[k % len(styles)],
                            marker="o", capsize=3, label=f"{variant}, T_up {t_up:g} s")  # fmt: skip
    for ax, words in zip(axes, ("mean speed (m/s)", "lane changes per vehicle"), strict=True):
        ax.set_xticks(range(len(alphas)), [f"{a:g}" for a in alphas])
        ax.set_xlabel("alpha")
        ax.set_ylabel(words)
        ax.ticklabel_format(axis="y", useOffset=False)  # m/s as read, not as an offset from 20.75
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, out_path)


def pairs_lines(profile: Any, ok: pd.DataFrame) -> list[str]:
    """The report's pairing of each alpha variant after the first with the first, by training seed (the module's
    docstring gives the plan)."""
    names = responders(profile)
    if len(names) < 2:
        return []
    alphas = grid(profile)
    speeds = {v: _models(ok, v).pivot_table(index="seed", columns=["alpha", "t_up"], values="mean_speed_mps")
              for v in names}  # fmt: skip
    first = speeds[names[0]]
    lines: list[str] = []
    for other in names[1:]:
        diff = speeds[other] - first
        whole = diff.dropna(axis=0, how="any")  # the seeds that trained at every alpha, in both variants
        lines += [f"## `{other}` against `{names[0]}`, paired by training seed (free flow, mean speed)", ""]
        if whole.empty or {alpha for alpha, _ in whole.columns} != set(alphas):
            lines += [f"No training seed has models of both at every alpha of {list(alphas)}: no verdict.", ""]
            continue
        if unfit := [f"`{v}` {why}" for v in (names[0], other) if (why := unfit_because(ok, v))]:
            lines += [f"No verdict (a learner unfit to answer): {'; '.join(unfit)}.", ""]
            continue
        per_seed = whole.mean(axis=1).to_numpy(float)
        point, low, high = stats.hierarchical_bootstrap(per_seed[:, None])
        lines.append(f"Headline: `{other}` minus `{names[0]}` over alphas {', '.join(f'{a:g}' for a in alphas)} and "
                     f"every demand, mean over {len(per_seed)} seeds: {point:+.2f} m/s [95% CI {low:+.2f}, "
                     f"{high:+.2f}]: {_verdict(per_seed, low, high, other, names[0])}.")  # fmt: skip
        rows = []
        for (alpha, t_up), col in diff.items():
            vals = col.dropna().to_numpy(float)
            if len(vals):
                mean, lo, hi = stats.hierarchical_bootstrap(vals[:, None])
                rows.append([f"{t_up:g}", f"{alpha:g}", str(len(vals)), interval(mean, lo, hi, "{:+.2f}"),
                             f"{vals.min():+.2f}"])  # fmt: skip
        head = ["T_up (s)", "alpha", "seeds", "difference (m/s), mean [95% CI]", "lowest seed"]
        lines += ["", "At each alpha and demand (descriptive: not corrected for their number):", "",
                  *md_table(head, rows).split("\n"), ""]  # fmt: skip
    return lines


def unfit_because(ok: pd.DataFrame, variant: str) -> str | None:
    """Why `variant`'s alpha-0 models cannot answer a question about alpha, or None: in free flow their IQM speed
    beats `keep`'s at no demand, or they make no lane change at all."""
    models = _models(ok, variant)
    models = models[models["alpha"] == 0]
    keep = ok[(ok["kind"] == "baseline") & (ok["variant"] == "keep") & (ok["scenario"] == "free")]
    if models.empty or keep.empty:
        return "has no alpha-0 models or no `keep` runs beside them in free flow"
    if not (models["lane_changes_per_vehicle"] > 0).any():
        return "makes no lane change at alpha 0"
    keep_speed = keep.groupby("t_up")["mean_speed_mps"].mean()
    beats = [stats.iqm(grp["mean_speed_mps"].to_numpy(float)[:, None]) > keep_speed.get(t_up, np.inf)
             for t_up, grp in models.groupby("t_up")]  # fmt: skip
    return None if any(beats) else "is slower than `keep` at every demand (alpha 0, free flow)"


def _verdict(per_seed: np.ndarray, low: float, high: float, other: str, first: str) -> str:
    if low > 0 or high < 0:
        return f"decided, `{other}` {'faster' if low > 0 else 'slower'}"
    needed = stats.models_needed(per_seed)
    more = f"about {needed} seeds would decide at this spread" if needed else "no number of seeds can be said"
    return f"cannot decide ({more})"
