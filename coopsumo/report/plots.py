"""Figures written as PNG files: time-space diagrams (paper Fig. 4) and flow-density (Fig. 5).

Figures are drawn with matplotlib's object API on an explicit Agg canvas: no pyplot, no
global backend switch, no display needed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure

SPEED_VMIN_MPS = 0.0
SPEED_VMAX_MPS = 31.0
SPEED_CMAP = "RdYlGn"
DPI = 120


def new_figure(width_in: float, height_in: float) -> Figure:
    """A Figure attached to an Agg canvas (size in inches)."""
    fig = Figure(figsize=(width_in, height_in))
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, out_path: str | Path) -> Path:
    """Write fig as PNG to out_path (creating its folder), whole (files.write_atomic: never into whatever entry holds
    the name, a named pipe say), and return the path."""
    from coopsumo.files import write_atomic

    path = Path(out_path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, lambda tmp: fig.savefig(tmp, dpi=DPI, format="png"))
    return path


def subsample_times(traj: pd.DataFrame, max_points: int) -> pd.DataFrame:
    """Keep every k-th distinct time_s value, with the smallest k giving at most max_points rows."""
    if len(traj) <= max_points:
        return traj
    times, rank = np.unique(traj["time_s"].to_numpy(dtype=float), return_inverse=True)
    k = math.ceil(len(traj) / max_points)
    kept = traj[rank % k == 0]
    while len(kept) > max_points and k < len(times):
        k += 1
        kept = traj[rank % k == 0]
    return kept


def time_space_figure(
    trajs: dict[str, pd.DataFrame],
    lane: int,
    out_path: str | Path,
    accident_window_s: tuple[float, float] | None,
    x_bottleneck_m: float | None,
    title_lane: str,
    max_points_per_panel: int = 400_000,
) -> Path:
    """Time-space diagram of one lane: one panel per label, position (m) against time (s).

    Each panel shows the trajectory samples with lane == lane (SUMO index), coloured by
    speed (m/s, fixed scale 0-31, one shared colorbar), thinned to at most
    max_points_per_panel points by keeping every k-th time step. The accident window
    (s) is shaded and the bottleneck position (m) drawn dashed, when given. title_lane
    names the lane in the title (e.g. "lane 1"). Writes a PNG and returns its path.
    """
    if not trajs:
        raise ValueError("time_space_figure needs at least one trajectory table")
    norm = Normalize(vmin=SPEED_VMIN_MPS, vmax=SPEED_VMAX_MPS)
    n = len(trajs)
    fig = new_figure(4.8 * n + 1.2, 4.8)
    axes = fig.subplots(1, n, sharex=True, sharey=True, squeeze=False)[0]
    for ax, (label, traj) in zip(axes, trajs.items(), strict=True):
        on_lane = subsample_times(traj[traj["lane"] == lane], max_points_per_panel)
        ax.scatter(
            on_lane["time_s"],
            on_lane["pos_m"],
            c=on_lane["speed_mps"],
            cmap=SPEED_CMAP,
            norm=norm,
            s=2.0,
            marker=".",
            linewidths=0,
            rasterized=True,
        )
        _mark_accident(ax, accident_window_s, x_bottleneck_m)
        ax.set_title(f"{label}: {title_lane}")
        ax.set_xlabel("time (s)")
    axes[0].set_ylabel("position (m)")
    mappable = ScalarMappable(norm=norm, cmap=SPEED_CMAP)
    fig.colorbar(mappable, ax=list(axes), label="speed (m/s)", fraction=0.04, pad=0.02)
    return save_figure(fig, out_path)


def _mark_accident(ax: Axes, window_s: tuple[float, float] | None, x_bottleneck_m: float | None) -> None:
    """Shade the accident window (s) and draw the bottleneck position (m) dashed."""
    if window_s is not None:
        ax.axvspan(window_s[0], window_s[1], color="0.5", alpha=0.15, linewidth=0, zorder=0, label="accident")
    if x_bottleneck_m is not None:
        ax.axhline(x_bottleneck_m, color="k", linestyle="--", linewidth=0.8, label="bottleneck")


def flow_density_figure(fd: dict[str, pd.DataFrame], out_path: str | Path) -> Path:
    """Flow (veh/h/lane) against density (veh/km/lane): one panel per policy label, in its colour,
    over every other policy's points in grey (one shared cloud would hide all but the last policy).

    fd maps a label to a flow_density table (columns density_veh_km, flow_veh_h); rows with
    a NaN are skipped. Writes a PNG and returns its path.
    """
    if not fd:
        raise ValueError("flow_density_figure needs at least one flow_density table")
    points = {label: table[["density_veh_km", "flow_veh_h"]].dropna() for label, table in fd.items()}
    cols = min(3, len(points))
    rows = math.ceil(len(points) / cols)
    fig = new_figure(3.4 * cols, 2.9 * rows)
    axes = fig.subplots(rows, cols, sharex=True, sharey=True, squeeze=False).ravel()
    x_max = max([float(p["density_veh_km"].max()) for p in points.values() if len(p)] + [1.0])
    y_max = max([float(p["flow_veh_h"].max()) for p in points.values() if len(p)] + [1.0])
    for i, (ax, (label, own)) in enumerate(zip(axes, points.items(), strict=False)):
        for other_label, other in points.items():
            if other_label != label:
                ax.scatter(other["density_veh_km"], other["flow_veh_h"], s=4, color="0.85", linewidths=0)
        ax.scatter(own["density_veh_km"], own["flow_veh_h"], s=6, alpha=0.6, color=f"C{i % 10}", linewidths=0)
        ax.set_title(label, fontsize=10)
        ax.set_xlim(0, x_max * 1.05)
        ax.set_ylim(0, y_max * 1.05)
        ax.grid(True, alpha=0.3)
    for ax in axes[len(points) :]:
        ax.set_visible(False)
    for ax in axes[(rows - 1) * cols :]:
        ax.set_xlabel("density (veh/km/lane)")
    for ax in axes[::cols]:
        ax.set_ylabel("flow (veh/h/lane)")
    fig.tight_layout()
    return save_figure(fig, out_path)


def bin_means(series: pd.Series, start_s: float, bin_s: float) -> pd.Series:
    """Mean of a time-indexed series (s) over bins of bin_s from start_s, indexed by bin start; a bin with no
    sample is left out (the bins of analysis.section_speed_bins)."""
    k = np.floor((series.index.to_numpy(dtype=float) - start_s) / bin_s)
    means = series.groupby(k).mean()
    return pd.Series(means.to_numpy(dtype=float), index=start_s + bin_s * means.index.to_numpy(dtype=float))


def recovery_figure(
    speeds: dict[str, pd.Series],
    backlogs: dict[str, pd.Series],
    out_path: str | Path,
    accident_window_s: tuple[float, float],
    threshold_mps: float,
    front: Sequence[str] = (),
    bin_s: float = 30.0,
) -> Path:
    """Two panels over time (s), one step line per policy label: the space-mean speed (m/s) before the bottleneck
    (a Series per bin of bin_s, indexed by bin start) with the recovery threshold dashed, and the insertion backlog
    (vehicles waiting to enter, a Series indexed by time) averaged over the same bins, so that a count flickering
    between 0 and 1 is a line near 0.5, not a band. The labels in `front` are drawn thick and on top, the others
    thin, dashed and behind them. The accident window is shaded. The legend, which names the threshold line and the
    shaded window too, stands right of the panels, where it hides no line. Writes a PNG, returns its path."""
    if not speeds:
        raise ValueError("recovery_figure needs at least one speed series")
    fig = new_figure(12.0, 6.4)
    top, bottom = fig.subplots(2, 1, sharex=True)
    for i, (label, series) in enumerate(speeds.items()):
        shown = label in front
        style = {"color": f"C{i % 10}", "label": label, "where": "post", "zorder": 3 if shown else 2,
                 "linewidth": 1.8 if shown else 1.0, "linestyle": "-" if shown else "--"}  # fmt: skip
        top.step(series.index, series.to_numpy(), **style)
        if label in backlogs:
            start = float(series.index[0]) if len(series) else 0.0
            b = bin_means(backlogs[label], start, bin_s)
            bottom.step(b.index, b.to_numpy(), **style)
    for ax in (top, bottom):
        ax.axvspan(*accident_window_s, color="0.5", alpha=0.15, linewidth=0, zorder=0,
                   label="accident window" if ax is top else None)  # fmt: skip
        ax.grid(True, alpha=0.3)
    top.axhline(threshold_mps, color="k", linestyle=":", linewidth=0.8, label=f"{threshold_mps:g} m/s: recovered above")
    top.set_ylabel("speed before the bottleneck (m/s)")
    top.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    bottom.set_ylabel(f"vehicles waiting to enter\n(mean over {bin_s:g} s)")
    bottom.set_xlabel("time (s)")
    fig.tight_layout()
    return save_figure(fig, out_path)


def lane_segments(traj: pd.DataFrame, lane: int) -> tuple[np.ndarray, np.ndarray]:
    """The line pieces of Fig. 4: ((n, 2, 2) array of [(t0, x0), (t1, x1)] in s and m, (n,) speed at the start in
    m/s) joining each vehicle's consecutive samples while both are on `lane` (SUMO index). A vehicle's line breaks
    where it leaves the lane or a sample is missing (a gap over 1.5 times the sampling interval, the smallest
    time step within one vehicle)."""
    part = traj.sort_values(["vid", "time_s"], kind="stable")
    t = part["time_s"].to_numpy(dtype=float)
    x = part["pos_m"].to_numpy(dtype=float)
    vid = part["vid"].to_numpy()
    on = part["lane"].to_numpy() == lane
    same = vid[1:] == vid[:-1]
    dt = np.diff(t)
    steps = dt[same & (dt > 0)]
    step = float(steps.min()) if len(steps) else 1.0
    joined = same & on[1:] & on[:-1] & (dt > 0) & (dt <= 1.5 * step)
    segments = np.stack([np.column_stack([t[:-1], x[:-1]]), np.column_stack([t[1:], x[1:]])], axis=1)[joined]
    speed = part["speed_mps"].to_numpy(dtype=float)[:-1][joined]
    return segments.reshape(-1, 2, 2), speed


def trajectory_windows_figure(
    trajs: dict[str, pd.DataFrame],
    lane: int,
    windows: dict[str, tuple[float, float]],
    out_path: str | Path,
    x_bottleneck_m: float | None,
    title_lane: str,
) -> Path:
    """Partial trajectories as in the paper's Fig. 4: one row per label, one column per named time window (s).

    Each vehicle's samples on `lane` (SUMO index) inside the window are drawn as one line, coloured by speed
    (m/s, fixed scale 0-31, one shared colorbar); a line breaks where the vehicle leaves the lane. Writes a PNG.
    """
    from matplotlib.collections import LineCollection

    if not trajs or not windows:
        raise ValueError("trajectory_windows_figure needs at least one trajectory table and one window")
    norm = Normalize(vmin=SPEED_VMIN_MPS, vmax=SPEED_VMAX_MPS)
    fig = new_figure(5.2 * len(windows) + 1.2, 3.6 * len(trajs))
    axes = fig.subplots(len(trajs), len(windows), squeeze=False)
    for r, (label, traj) in enumerate(trajs.items()):
        for c, (name, (t0, t1)) in enumerate(windows.items()):
            ax = axes[r, c]
            part = traj[(traj["time_s"] >= t0) & (traj["time_s"] <= t1)]
            x = part["pos_m"].to_numpy(dtype=float)
            segments, seg_speed = lane_segments(part, lane)
            lines = LineCollection(list(segments), cmap=SPEED_CMAP, norm=norm, linewidths=0.7)
            lines.set_array(seg_speed)
            ax.add_collection(lines)
            ax.set_xlim(t0, t1)
            ax.set_ylim(0.0, max(float(x.max()) if len(x) else 1.0, x_bottleneck_m or 0.0) * 1.02)
            if x_bottleneck_m is not None:
                ax.axhline(x_bottleneck_m, color="k", linestyle="--", linewidth=0.8)
            ax.set_title(f"{label}, {name}: {title_lane}", fontsize=9)
            ax.set_xlabel("time (s)")
            ax.set_ylabel("position (m)")
    fig.subplots_adjust(hspace=0.35)  # room for each row's title below the time axis of the row above
    fig.colorbar(ScalarMappable(norm=norm, cmap=SPEED_CMAP), ax=list(axes.ravel()), label="speed (m/s)",
                 fraction=0.03, pad=0.02)  # fmt: skip
    return save_figure(fig, out_path)


def demand_figure(table: pd.DataFrame, value: str, ylabel: str, out_path: str | Path) -> Path:
    """One line per policy of `value` against the inflow (veh/h), with its interval as error bars.

    table: columns policy, t_up_s, value, value + "_lo", value + "_hi". Writes a PNG, returns its path.
    """
    if table.empty:
        raise ValueError("demand_figure needs at least one row")
    fig = new_figure(8.0, 5.0)
    ax = fig.subplots()
    for i, (policy, rows) in enumerate(table.groupby("policy", sort=False)):
        rows = rows.sort_values("t_up_s", ascending=False)
        q = 3600.0 / rows["t_up_s"].to_numpy(dtype=float)
        mid = rows[value].to_numpy(dtype=float)
        lo, hi = rows[value + "_lo"].to_numpy(dtype=float), rows[value + "_hi"].to_numpy(dtype=float)
        err = np.vstack([mid - lo, hi - mid])
        ax.errorbar(q + (i - len(table["policy"].unique()) / 2) * 8.0, mid, yerr=np.abs(err), marker="o", ms=4,
                    capsize=3, linewidth=1.2, color=f"C{i % 10}", label=str(policy))  # fmt: skip
    ax.set_xlabel("inflow (veh/h; points of one demand are spread a little to be seen)")
    ax.set_ylabel(ylabel)
    ax.set_yscale("log")
    ax.grid(True, alpha=0.3, which="both")
    ax.legend(fontsize=8, ncol=2)
    fig.tight_layout()
    return save_figure(fig, out_path)


def difference_figure(panels: dict[str, pd.DataFrame], ylabel: str, out_path: str | Path) -> Path:
    """Paired differences a - b with their intervals, one panel per named table (columns a, b, t_up_s, diff, lo,
    hi, as scenario1_measures.difference_table gives them): the demands on the x axis by inflow, one marker per
    pair side by side within a demand, a linear y axis with the zero line. Empty tables get no panel (a note when
    every table is empty). Writes a PNG, returns its path."""
    shown = {title: table for title, table in panels.items() if not table.empty}
    fig = new_figure(6.4 * max(len(shown), 1), 4.8)
    axes = fig.subplots(1, max(len(shown), 1), squeeze=False)[0]
    if not shown:
        axes[0].text(0.5, 0.5, "no pairs to compare", ha="center", va="center", transform=axes[0].transAxes)
    for ax, (title, table) in zip(axes, shown.items(), strict=False):
        t_ups = sorted(table["t_up_s"].unique(), reverse=True)  # by inflow, lowest first
        pairs = list(dict.fromkeys(zip(table["a"], table["b"], strict=True)))
        width = 0.8 / len(pairs)
        for j, (a, b) in enumerate(pairs):
            rows = table[(table["a"] == a) & (table["b"] == b)]
            x = np.array([t_ups.index(t) for t in rows["t_up_s"]]) + (j - (len(pairs) - 1) / 2) * width
            mid = rows["diff"].to_numpy(dtype=float)
            err = np.abs(np.vstack([mid - rows["lo"].to_numpy(dtype=float), rows["hi"].to_numpy(dtype=float) - mid]))
            ax.errorbar(x, mid, yerr=err, fmt="o", ms=5, capsize=3, color=f"C{j % 10}", label=f"{a} - {b}")
        ax.axhline(0.0, color="k", linewidth=0.9)
        ax.set_xticks(range(len(t_ups)), [f"T_up {t:g} s\n{3600 / t:.0f} veh/h" for t in t_ups])
        ax.set_xlim(-0.6, len(t_ups) - 0.4)
        ax.set_title(title, fontsize=10)
        ax.set_ylabel(ylabel)
        ax.grid(True, axis="y", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, out_path)


def thrashing_figure(panels: dict[float, dict[str, pd.DataFrame]], keep_tts: dict[float, float], threshold: float,
                     out_path: str | Path) -> Path:  # fmt: skip
    """Every model, one panel per demand (T_up): its queue lane changes per vehicle (x) against its total time spent
    (y), one colour per learned policy (panels[t_up][label]: columns qlc, tts_veh_h), `keep`'s total time spent as
    a horizontal line and the thrashing threshold as a vertical one."""
    fig = new_figure(4.2 * max(len(panels), 1), 3.8)
    colours = ("tab:blue", "tab:red", "tab:green", "tab:purple")
    for i, (t_up, models) in enumerate(panels.items()):
        ax = fig.add_subplot(1, max(len(panels), 1), i + 1)
        for colour, (label, table) in zip(colours, models.items(), strict=False):
            ax.scatter(table["qlc"], table["tts_veh_h"], s=18, color=colour, alpha=0.8, label=label)
        if t_up in keep_tts:
            ax.axhline(keep_tts[t_up], color="black", linestyle="--", linewidth=1, label="keep")
        ax.axvline(threshold, color="grey", linestyle=":", linewidth=1, label="thrashing above")
        ax.set_title(f"T_up = {t_up:g} s ({3600 / t_up:,.0f} veh/h)")
        ax.set_xlabel("queue lane changes per vehicle (model mean)")
        if i == 0:
            ax.set_ylabel("total time spent (veh-h, model mean)")
            ax.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, out_path)
