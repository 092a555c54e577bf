"""Figures of the scenario II alpha sweep (paper Fig. 6) written as PNG files.

`alpha_surface_figure`: alpha* against T_up and lane count with the fitted plane
alpha* = b0 + b1 T_up + b2 lanes (3D scatter + plane). `speed_heatmap_figure`: mean speed
over (alpha, condition). Figures and PNG files come from plots.py's helpers (Agg canvas, same DPI).
"""

from __future__ import annotations

from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.patches import Rectangle
from numpy.typing import ArrayLike

from coopsumo.report.plots import new_figure, save_figure


def alpha_label(alpha: float) -> str:
    """1/8 for 0.125, 24 for 24.0."""
    frac = Fraction(alpha).limit_denominator(64)
    return str(frac.numerator) if frac.denominator == 1 else f"{frac.numerator}/{frac.denominator}"


def alpha_surface_figure(
    t_up_s: ArrayLike,
    lanes: ArrayLike,
    alpha_star: ArrayLike,
    plane: tuple[float, float, float] | None,
    out_path: str | Path,
    note: str = "",
) -> Path:
    """Red points (T_up, lanes, alpha*) and, when `plane` = (b0, b1, b2) is given, the plane.

    `note` is printed under the title (e.g. why no plane was fitted). Returns the PNG path.
    """
    t = np.asarray(t_up_s, float)
    n = np.asarray(lanes, float)
    a = np.asarray(alpha_star, float)
    if not (len(t) == len(n) == len(a)) or len(t) == 0:
        raise ValueError("alpha_surface_figure needs equally long, non-empty t_up_s, lanes and alpha_star")
    fig = new_figure(7.0, 5.6)
    ax = fig.add_subplot(1, 1, 1, projection="3d")
    if plane is not None:
        b0, b1, b2 = plane
        tt, nn = np.meshgrid(np.linspace(t.min(), t.max(), 12), np.linspace(n.min(), n.max(), 12))
        ax.plot_surface(tt, nn, b0 + b1 * tt + b2 * nn, color="tab:blue", alpha=0.25, linewidth=0)
        ax.plot_wireframe(tt, nn, b0 + b1 * tt + b2 * nn, color="tab:blue", alpha=0.35, linewidth=0.4,
                          rstride=3, cstride=3)  # fmt: skip
        fitted = b0 + b1 * t + b2 * n
        for ti, ni, ai, fi in zip(t, n, a, fitted, strict=True):
            ax.plot([ti, ti], [ni, ni], [fi, ai], color="0.4", linewidth=0.6)
    ax.scatter(t, n, a, color="red", s=28, depthshade=False, label=r"$\alpha^*$")
    ax.set_xlabel(r"$T_{up}$ (s)")
    ax.set_ylabel("lanes")
    ax.set_zlabel(r"$\alpha^*$")
    ax.set_yticks(sorted(set(n.tolist())))
    title = r"$\alpha^*$ by inflow interval and lane count"
    if plane is not None:
        b0, b1, b2 = plane
        title += "\n" + rf"plane: $\alpha^*$ = {b0:.2f} {b1:+.2f} $T_{{up}}$ {b2:+.2f} lanes"
    if note:
        title += "\n" + note
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    return save_figure(fig, out_path)


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
