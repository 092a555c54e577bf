"""Figures of the scenario II alpha sweep (paper Fig. 6) written as PNG files.

`alpha_star_lanes_figure`: alpha* against inflow, one panel per lane count on a shared symlog axis of the
alphas tried, with its bootstrap range and the fitted plane alpha* = b0 + b1 T_up + b2 lanes.
`speed_heatmap_figure`: mean speed over (alpha, condition). `response_surface_figure`: the slope of speed over
log2(1 + alpha) per lane count and load, with its interval. Figures and PNG files come from plots.py's helpers
(Agg canvas, same DPI).
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle

from coopsumo.report.plots import new_figure, save_figure

BOOT_AREA = 260.0
"""marker area (points²) of an alpha picked by every bootstrap resample"""


def alpha_label(alpha: float) -> str:
    """1/8 for 0.125, 24 for 24.0."""
    frac = Fraction(alpha).limit_denominator(64)
    return str(frac.numerator) if frac.denominator == 1 else f"{frac.numerator}/{frac.denominator}"


def _lane_panel(ax: Any, rows: pd.DataFrame, n: int, grid: list[float], plane: tuple[float, float, float] | None,
                boot_alphas: Mapping[tuple[int, float], np.ndarray] | None) -> None:  # fmt: skip
    """One lane count's panel: alpha* per inflow, its bootstrap range and resample shares, the plane."""
    x = rows["inflow_veh_h"].to_numpy(float)
    a = rows["alpha_star"].to_numpy(float)
    solved = np.isfinite(a)
    step = float(np.diff(x).min()) if len(x) > 1 else max(float(x[0]) * 0.3, 1.0)
    if boot_alphas is not None:
        for r in rows[solved].itertuples():
            draws = np.asarray(boot_alphas.get((int(r.lanes), float(r.t_up_s)), []), float)
            draws = draws[np.isfinite(draws)]
            for alpha in grid:
                share = float(np.mean(draws == alpha)) if draws.size else 0.0
                if share > 0:
                    ax.scatter(r.inflow_veh_h, alpha, s=BOOT_AREA * share, color="0.75", edgecolor="0.5",
                               linewidth=0.4, zorder=1)  # fmt: skip
    if {"boot_alpha_p05", "boot_alpha_p95"} <= set(rows):
        lo = rows["boot_alpha_p05"].to_numpy(float)[solved]
        hi = rows["boot_alpha_p95"].to_numpy(float)[solved]
        ax.vlines(x[solved], lo, hi, color="tab:red", linewidth=1.0, alpha=0.6, zorder=2)
    if plane is not None:
        b0, b1, b2 = plane
        xs = np.linspace(x.min(), x.max(), 50)  # over the conditions measured, no further
        ax.plot(xs, b0 + b1 * 3600.0 / xs + b2 * n, color="tab:blue", linestyle="--", linewidth=1.0, zorder=2)
    ax.plot(x[solved], a[solved], color="tab:red", marker="D", markersize=6, linewidth=0.8, zorder=3)
    for xi in x[~solved]:
        ax.text(xi, 0.0, "no α*", ha="center", va="center", fontsize=7, color="0.3", rotation=90)
    ax.set_xticks(x, [f"{xi:,.0f}\n{t:g} s" for xi, t in zip(x, rows["t_up_s"], strict=True)], fontsize=7)
    ax.set_xlim(x.min() - step / 2, x.max() + step / 2)
    ax.set_title(f"{n} lanes", fontsize=9)
    ax.set_xlabel("inflow (veh/h)\nT_up (s)", fontsize=8)
    ax.grid(True, axis="y", color="0.9", linewidth=0.6)


def _legend_handles(plane: tuple[float, float, float] | None,
                   boot_alphas: Mapping[tuple[int, float], np.ndarray] | None) -> list[Line2D]:  # fmt: skip
    handles = [
        Line2D([], [], color="tab:red", marker="D", markersize=6, linewidth=0.8, label=r"$\alpha^*$: best mean speed"),
        Line2D([], [], color="tab:red", alpha=0.6, linewidth=1.0, label="90% bootstrap range of $\\alpha^*$"),
    ]  # fmt: skip
    if boot_alphas is not None:
        for share in (0.25, 1.0):
            handles.append(Line2D([], [], linestyle="", marker="o", markersize=float(np.sqrt(BOOT_AREA * share)),
                                  color="0.75", markeredgecolor="0.5",
                                  label=f"{share:.0%} of bootstrap resamples pick this $\\alpha$"))  # fmt: skip
    if plane is not None:
        handles.append(Line2D([], [], color="tab:blue", linestyle="--", linewidth=1.0, label="fitted plane"))
    return handles


def alpha_star_lanes_chart(
    table: pd.DataFrame,
    alphas: Sequence[float],
    plane: tuple[float, float, float] | None = None,
    boot_alphas: Mapping[tuple[int, float], np.ndarray] | None = None,
    note: str = "",
) -> Figure:
    """alpha* against inflow, one panel per lane count sharing a symlog y axis ticked at the alphas tried (so 0
    shows).

    `table`: one row per condition with lanes, t_up_s, inflow_veh_h, alpha_star (NaN: withheld, marked
    "no alpha*") and, when present, boot_alpha_p05/boot_alpha_p95 (drawn as the 90% bootstrap range).
    `boot_alphas`: per (lanes, t_up_s), the alpha* of each bootstrap resample; grey discs then show the share
    of resamples picking each alpha (area). `plane` = (b0, b1, b2): the fitted alpha* = b0 + b1 T_up + b2 lanes,
    dashed, at each panel's lane count.
    """
    if table.empty:
        raise ValueError("alpha_star_lanes_chart needs at least one condition")
    grid = sorted(float(a) for a in alphas)
    lanes = sorted(int(n) for n in set(table["lanes"]))
    fig = new_figure(max(1.2 + 3.0 * len(lanes), 7.5), 4.4)  # one panel is still wide enough for the legend and note
    axes = fig.subplots(1, len(lanes), sharey=True, squeeze=False)[0]
    positive = [a for a in grid if a > 0]
    top = max([*grid, *table["alpha_star"].dropna().astype(float)], default=1.0)
    low = -0.35 * (min(positive) if positive else 1.0)
    for ax, n in zip(axes, lanes, strict=True):
        _lane_panel(ax, table[table["lanes"] == n].sort_values("inflow_veh_h"), n, grid, plane, boot_alphas)
    first = axes[0]
    first.set_yscale("symlog", linthresh=min(positive) if positive else 1.0, linscale=0.6)
    first.set_ylim(low, top * 1.6)
    first.set_yticks(grid, [alpha_label(a) for a in grid])
    first.minorticks_off()
    first.set_ylabel(r"$\alpha^*$ (the alphas tried)")
    handles = _legend_handles(plane, boot_alphas)
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 3), fontsize=7, frameon=False)
    title = r"$\alpha^*$ per lane count against inflow"
    if plane is not None:
        b0, b1, b2 = plane
        title += rf" (plane: $\alpha^*$ = {b0:.2f} {b1:+.2f} $T_{{up}}$ {b2:+.2f} lanes)"
    if note:
        title += "\n" + "\n".join(textwrap.wrap(note, 110))
    fig.suptitle(title, fontsize=9)
    fig.tight_layout(rect=(0, 0.09, 1, 1))
    return fig


def alpha_star_lanes_figure(
    table: pd.DataFrame,
    alphas: Sequence[float],
    out_path: str | Path,
    plane: tuple[float, float, float] | None = None,
    boot_alphas: Mapping[tuple[int, float], np.ndarray] | None = None,
    note: str = "",
) -> Path:
    """alpha_star_lanes_chart written as a PNG file; returns its path."""
    return save_figure(alpha_star_lanes_chart(table, alphas, plane, boot_alphas, note), out_path)


def speed_heatmap_figure(
    speeds: pd.DataFrame,
    alpha_star: Sequence[float],
    out_path: str | Path,
    unit: str = "m/s",
) -> Path:
    """Heat map of mean speed, one row per condition (index labels), one column per alpha (columns).

    Colour: speed minus the row's best (0 = best, alpha* framed in black); each cell is annotated
    with the mean speed itself. NaN cells (no successful run) stay blank. Returns the PNG path.
    """
    if speeds.empty:
        raise ValueError("speed_heatmap_figure needs at least one condition and one alpha")
    values = speeds.to_numpy(float)
    best = np.nanmax(np.where(np.isnan(values), -np.inf, values), axis=1, keepdims=True)
    rel = values - np.where(np.isfinite(best), best, np.nan)
    rows, cols = values.shape
    fig = new_figure(max(6.0, 2.8 + 0.62 * cols), max(2.8, 1.3 + 0.34 * rows))
    ax = fig.subplots()
    finite = rel[np.isfinite(rel)]
    low = float(finite.min()) if finite.size and finite.min() < 0 else -1.0
    image = ax.imshow(np.ma.masked_invalid(rel), cmap="viridis", vmin=low, vmax=0.0, aspect="auto")
    cbar = fig.colorbar(image, ax=ax, fraction=0.05, pad=0.02)
    cbar.set_label(f"gap to the row's best ({unit})")
    ax.set_xticks(range(cols), [alpha_label(float(a)) for a in speeds.columns])
    ax.set_yticks(range(rows), [str(i) for i in speeds.index])
    ax.set_xlabel(r"$\alpha$")
    font = 7 if rows * cols <= 120 else 5
    for r in range(rows):
        for c in range(cols):
            if np.isfinite(values[r, c]):
                dark = rel[r, c] < low * 0.55
                ax.text(c, r, f"{values[r, c]:.1f}", ha="center", va="center", fontsize=font,
                        color="white" if dark else "black")  # fmt: skip
    alphas = [float(a) for a in speeds.columns]
    for r, a_star in enumerate(alpha_star):
        if a_star is not None and np.isfinite(a_star) and float(a_star) in alphas:
            c = alphas.index(float(a_star))
            ax.add_patch(Rectangle((c - 0.5, r - 0.5), 1, 1, fill=False, edgecolor="black", linewidth=1.6))
    ax.set_title(r"mean speed by $\alpha$ (framed: $\alpha^*$, the best mean over seeds)", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, out_path)


def response_surface_figure(table: pd.DataFrame, out_path: str | Path, title: str) -> Path:
    """Fig. 6 read continuously: the response of speed to alpha (the slope per doubling of 1 + alpha, m/s) per
    lane count (rows) and load (columns), each cell annotated with its slope and interval; blank where none.

    table: lanes, load, slope_mps, slope_low, slope_high (response.condition_responses)."""
    if table.empty:
        raise ValueError("response_surface_figure needs at least one condition")
    lanes = sorted(int(n) for n in set(table["lanes"]))
    loads = sorted(float(q) for q in set(table["load"]))
    grid = np.full((len(lanes), len(loads)), np.nan)
    text = {}
    for r in table.itertuples():
        i, j = lanes.index(int(r.lanes)), loads.index(float(r.load))
        grid[i, j] = r.slope_mps
        text[i, j] = f"{r.slope_mps:+.2f}\n[{r.slope_low:+.2f}, {r.slope_high:+.2f}]"
    fig = new_figure(max(5.5, 2.6 + 1.25 * len(loads)), max(2.6, 1.3 + 0.62 * len(lanes)))
    ax = fig.subplots()
    bound = float(np.nanmax(np.abs(grid))) or 1.0
    image = ax.imshow(np.ma.masked_invalid(grid), cmap="RdBu", vmin=-bound, vmax=bound, aspect="auto",
                      origin="lower")  # fmt: skip
    cbar = fig.colorbar(image, ax=ax, fraction=0.05, pad=0.02)
    cbar.set_label("m/s per doubling of 1 + alpha")
    ax.set_xticks(range(len(loads)), [f"{q:g}" for q in loads])
    ax.set_yticks(range(len(lanes)), [str(n) for n in lanes])
    ax.set_xlabel("load (inflow per lane / 1,800 veh/h)")
    ax.set_ylabel("lanes")
    for (i, j), label in text.items():
        ax.text(j, i, label, ha="center", va="center", fontsize=7,
                color="white" if abs(grid[i, j]) > 0.6 * bound else "black")  # fmt: skip
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    return save_figure(fig, out_path)
