"""The report of `coopsumo accident-seeds`: per demand and policy, total time spent and the other measures over seeds,
each policy against `keep` on the same seed, and alpha=adaptive against every fixed alpha of the same models."""

from __future__ import annotations

import pandas as pd

from coopsumo.provenance import versions
from coopsumo.report.markdown import md_table
from coopsumo.run_markers import PLANLESS_TITLES
from coopsumo.studies.followups.robustness import paired_interval


def report(table: pd.DataFrame, seed_offset: int, wall_s: float) -> str:
    """report.md of runs.csv's table (one row per demand, policy and seed); seed_offset: a model trained on seed s
    met the accident on seed seed_offset + s."""
    lines = [
        PLANLESS_TITLES["accident_seeds"],
        "",
        "Made by `coopsumo accident-seeds`: scenario I's default accident (3 lanes, closure at 1,300 m "
        "decaying over steps 2,000-12,000 of 20,000). A model trained on seed s meets the accident on seed "
        f"{seed_offset} + s; the baselines run on the same seeds. Measures as in "
        "`results/scenario1/report.md`. Paired: the policy minus `keep` on the same seed (mean, worst).",
        "",
    ]
    rows = []
    for t_up, at in table.groupby("t_up_s", sort=False):
        keep = at[at["variant"] == "keep"].set_index("seed")["tts_veh_h"]
        for (variant, alpha), g in at.groupby(["variant", at["alpha"].fillna(-1)], sort=False):
            gap = (g.set_index("seed")["tts_veh_h"] - keep).dropna()
            a = "-" if alpha < 0 else f"{alpha:g}"
            rows.append([f"{t_up:g}", f"`{variant}`", a, str(len(g)),
                         f"{g['tts_veh_h'].mean():.1f} ± {g['tts_veh_h'].std():.1f}",
                         f"{gap.mean():+.1f}, {gap.max():+.1f}",
                         f"{g['mean_speed_mps'].mean():.2f} ± {g['mean_speed_mps'].std():.2f}",
                         f"{g['lane_changes_per_vehicle'].mean():.2f}", f"{g['system_recovery_s'].mean():.0f}",
                         f"{int(g['collisions'].sum())}, {int(g['teleports'].sum())}"])  # fmt: skip
    lines.append(md_table(["T_up (s)", "policy", "alpha", "seeds", "TTS (veh-h)", "TTS - keep, paired (mean, worst)",
                           "mean speed (m/s)", "lane changes / veh", "system recovery (s)", "collisions, teleports"],
                          rows))  # fmt: skip
    lines += adaptive_lines(table)
    lines += ["", f"Wall time of this invocation: {wall_s / 60:.1f} min. Versions: {versions()}.", ""]
    return "\n".join(lines)


def adaptive_lines(table: pd.DataFrame) -> list[str]:
    """Adaptive alpha minus every fixed alpha of the same conditioned models, paired by seed: TTS and mean speed,
    mean with a 90% t-interval over seeds (empty without adaptive runs)."""
    adaptive = table[table["variant"].str.endswith("_adaptive")]
    if adaptive.empty:
        return []
    lines = ["", "## Adaptive alpha against every fixed alpha (the same conditioned models, paired by seed)", "",
             "Difference adaptive minus fixed: mean [90% t-interval over seeds]; TTS lower is better, speed higher.",
             ""]  # fmt: skip
    rows = []
    for (t_up, variant), ad in adaptive.groupby(["t_up_s", "variant"], sort=False):
        base = variant.removesuffix("_adaptive")
        fixed = table[(table["t_up_s"] == t_up) & (table["variant"] == base)]
        a = ad.set_index("seed")
        for alpha, g in fixed.groupby("alpha"):
            f = g.set_index("seed")
            seeds = a.index.intersection(f.index)
            cells = []
            for col in ("tts_veh_h", "mean_speed_mps"):
                mean, lo, hi = paired_interval((a.loc[seeds, col] - f.loc[seeds, col]).to_numpy(float))
                cells.append(f"{mean:+.2f} [{lo:+.2f}, {hi:+.2f}]")
            rows.append([f"{t_up:g}", f"`{base}`", f"{alpha:g}", str(len(seeds)), *cells,
                         f"{a.loc[seeds, 'adaptive_alpha_mean'].astype(float).mean():.2f}"])  # fmt: skip
    return lines + [md_table(["T_up (s)", "models", "fixed alpha", "seeds", "TTS difference (veh-h)",
                              "speed difference (m/s)", "adaptive's mean alpha"], rows)]  # fmt: skip
