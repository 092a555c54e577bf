"""Figures are written as real PNG files for small synthetic data."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from PIL import Image

from coopsumo.report.plots import flow_density_figure, subsample_times, time_space_figure

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def synthetic_traj(seed: int, n_veh: int = 30, lanes: tuple[int, ...] = (0, 1, 2)) -> pd.DataFrame:
    """Vehicles entering every 4 s on the given lanes, slowed near 1300 m between 200 and 400 s."""
    rng = np.random.default_rng(seed)
    times = np.arange(0.0, 600.0, 1.0)
    rows = []
    for i in range(n_veh):
        t0 = 4.0 * i
        pos = 0.0
        lane = lanes[i % len(lanes)]
        for t in times[times >= t0]:
            slow = 1100.0 < pos < 1300.0 and 200.0 < t < 400.0
            speed = 2.0 if slow else 25.0 + rng.normal(0.0, 2.0)
            pos += speed
            if pos > 2000.0:
                break
            rows.append((t, f"v{i}", lane, pos, speed))
    return pd.DataFrame(rows, columns=["time_s", "vid", "lane", "pos_m", "speed_mps"])


def assert_png(path: Path, min_kb: float) -> None:
    assert path.is_file()
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    assert len(data) > min_kb * 1024


def test_time_space_figure_written(tmp_path: Path) -> None:
    trajs = {"alpha=0": synthetic_traj(0), "alpha=8": synthetic_traj(1)}
    out = time_space_figure(trajs, 1, tmp_path / "figs" / "ts.png", (200.0, 400.0), 1300.0, "lane 1")
    assert out == tmp_path / "figs" / "ts.png"
    assert_png(out, 10)


def test_time_space_figure_empty_lane(tmp_path: Path) -> None:
    trajs = {"keep": synthetic_traj(0, lanes=(0, 1)), "empty": synthetic_traj(1, lanes=(0,))}
    out = time_space_figure(trajs, 2, tmp_path / "ts_empty.png", None, None, "lane 3")
    assert_png(out, 5)


def test_subsample_times_bounds_points() -> None:
    traj = synthetic_traj(0)
    kept = subsample_times(traj, 1000)
    assert 0 < len(kept) <= 1000
    # whole time steps are kept or dropped together
    per_time = traj.groupby("time_s").size()
    assert (kept.groupby("time_s").size() == per_time.loc[kept["time_s"].unique()]).all()
    assert subsample_times(traj, len(traj)) is traj


def test_flow_density_figure_written(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    fd = {}
    for label in ("alpha=0", "alpha=8", "keep", "mobil"):  # 4 panels on a 3-column grid: one hidden
        density = rng.uniform(0, 120, 200)
        flow = np.minimum(80 * density, 2000 - 10 * (density - 25)).clip(0)
        fd[label] = pd.DataFrame({"density_veh_km": density, "flow_veh_h": flow})
    fd["alpha=8"].loc[3, "flow_veh_h"] = np.nan
    out = flow_density_figure(fd, tmp_path / "fd.png")
    assert_png(out, 10)


def test_trajectory_windows_draw_one_line_per_vehicle_stint_on_the_lane(tmp_path: Path) -> None:
    from coopsumo.report.plots import trajectory_windows_figure

    trajs = {"a": synthetic_traj(1), "b": synthetic_traj(2)}
    out = trajectory_windows_figure(trajs, 0, {"onset": (150.0, 350.0), "dissolution": (300.0, 500.0)},
                                    tmp_path / "fig4.png", 1300.0, "lane 0")  # fmt: skip
    assert_png(out, 20)


def test_lane_segments_join_each_vehicles_samples_on_the_lane_and_break_where_it_leaves() -> None:
    """Regression: sorted by vehicle, time steps back at every new vehicle; the sampling interval was then taken
    as negative and no piece was drawn (the committed Fig. 4 was empty)."""
    from coopsumo.report.plots import lane_segments

    rows = [(t, 1, 0, 10.0 * t, 10.0) for t in (0.0, 0.5, 1.0, 1.5)]  # vehicle 1: 3 pieces on lane 0
    rows += [(t, 2, 0 if t < 1.0 else 1, 5.0 * t, 5.0) for t in (0.0, 0.5, 1.0, 1.5)]  # 1 piece, then lane 1
    rows += [(t, 3, 0, 8.0 * t, 8.0) for t in (0.0, 0.5, 2.0, 2.5)]  # a missing sample breaks the line: 2 pieces
    traj = pd.DataFrame(rows, columns=["time_s", "vid", "lane", "pos_m", "speed_mps"]).sample(frac=1.0, random_state=1)
    segments, speed = lane_segments(traj, 0)
    assert segments.shape == (6, 2, 2) and len(speed) == 6
    starts = sorted(map(tuple, segments[:, 0].tolist()))
    assert starts == [(0.0, 0.0), (0.0, 0.0), (0.0, 0.0), (0.5, 5.0), (1.0, 10.0), (2.0, 16.0)]
    assert sorted(speed.tolist()) == [5.0, 8.0, 8.0, 10.0, 10.0, 10.0]
    assert lane_segments(traj, 1)[0].shape == (1, 2, 2)  # vehicle 2 from 1.0 s to 1.5 s
    assert lane_segments(traj, 2)[0].shape == (0, 2, 2)
    # the synthetic study: every vehicle on lane 0 inside the window is drawn
    many = synthetic_traj(1)
    window = many[(many["time_s"] >= 150.0) & (many["time_s"] <= 350.0)]
    on_lane = window[window["lane"] == 0]
    assert len(lane_segments(window, 0)[0]) == len(on_lane) - on_lane["vid"].nunique()


def test_demand_figure_with_intervals(tmp_path: Path) -> None:
    from coopsumo.report.plots import demand_figure

    table = pd.DataFrame({"policy": ["keep", "keep", "greedy", "greedy"], "t_up_s": [2.0, 1.0, 2.0, 1.0],
                          "tts": [40.0, 160.0, 42.0, 150.0], "tts_lo": [38.0, 150.0, 40.0, 140.0],
                          "tts_hi": [43.0, 170.0, 44.0, 155.0]})  # fmt: skip
    assert_png(demand_figure(table, "tts", "veh-h", tmp_path / "d.png"), 15)


def _differences(pairs: list[tuple[str, str]], t_ups: tuple[float, ...]) -> pd.DataFrame:
    rows = [(a, b, t, -1.0 + j, -2.0 + j, 0.5 + j) for j, (a, b) in enumerate(pairs) for t in t_ups]
    return pd.DataFrame(rows, columns=["a", "b", "t_up_s", "diff", "lo", "hi"])


def test_difference_figure_written_with_a_panel_per_kind_of_pair(tmp_path: Path) -> None:
    from coopsumo.report.plots import difference_figure

    coop = _differences([("dqn_alpha8", "dqn_alpha0"), ("mobil_p0.5", "mobil_p0")], (2.0, 1.5, 1.0))
    classical = _differences([("dqn_alpha8", "keep"), ("dqn_alpha0", "keep")], (2.0, 1.0))
    out = difference_figure({"cooperative": coop, "learned against classical": classical}, "veh-h",
                            tmp_path / "figs" / "diff.png")  # fmt: skip
    assert out == tmp_path / "figs" / "diff.png"
    assert_png(out, 20)
    two = np.asarray(Image.open(out)).shape[1]
    empty = pd.DataFrame(columns=coop.columns)
    one = difference_figure({"cooperative": coop, "learned against classical": empty}, "veh-h", tmp_path / "one.png")
    assert np.asarray(Image.open(one)).shape[1] < two  # an empty table gets no panel
    assert_png(difference_figure({"cooperative": empty}, "veh-h", tmp_path / "none.png"), 5)


def test_bin_means_average_a_flickering_count_over_the_speed_bins() -> None:
    from coopsumo.report.plots import bin_means

    flicker = pd.Series([0.0, 1.0] * 30 + [4.0] * 10, index=np.arange(70.0))  # 0/1 for 60 s, then 4 for 10 s
    means = bin_means(flicker, 0.0, 30.0)
    assert means.index.tolist() == [0.0, 30.0, 60.0] and means.tolist() == [0.5, 0.5, 4.0]
    assert bin_means(flicker.iloc[35:], 0.0, 30.0).index.tolist() == [30.0, 60.0]  # bins from the same origin


def test_recovery_figure_written(tmp_path: Path) -> None:
    from coopsumo.report.plots import recovery_figure

    bins = np.arange(0.0, 600.0, 30.0)
    t = np.arange(0.0, 600.0, 1.0)
    speeds = {lab: pd.Series(np.where((bins > 100) & (bins < 300), 2.0, 20.0 + i), index=bins)
              for i, lab in enumerate(("dqn_alpha8", "keep", "sumo"))}  # fmt: skip
    backlogs = {"dqn_alpha8": pd.Series(np.clip(50 - np.abs(t - 250) / 3, 0, None), index=t),
                "keep": pd.Series(np.clip(60 - np.abs(t - 260) / 3, 0, None), index=t),
                "sumo": pd.Series(np.arange(len(t)) % 2, index=t)}  # fmt: skip
    out = recovery_figure(speeds, backlogs, tmp_path / "rec.png", (100.0, 300.0), 15.0, front=["dqn_alpha8"])
    assert_png(out, 20)


def test_recovery_figure_legend_names_the_threshold_and_hides_no_line(tmp_path: Path, monkeypatch: Any) -> None:
    """The legend covered the accident window in the lower left and left the 15 m/s line unexplained: it names the
    line and the window and stands outside both panels."""
    from coopsumo.report import plots

    drawn = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: drawn.append(fig) or Path(path))
    bins = np.arange(0.0, 600.0, 30.0)
    labels = ("dqn_alpha0", "dqn_alpha8", "keep", "greedy", "mobil_p0", "mobil_p0.5", "sumo")
    speeds = {lab: pd.Series(np.where((bins > 100) & (bins < 300), 2.0, 20.0 + i), index=bins)
              for i, lab in enumerate(labels)}  # fmt: skip
    plots.recovery_figure(speeds, {}, tmp_path / "rec.png", (100.0, 300.0), 15.0, front=["dqn_alpha8"])
    (fig,) = drawn
    renderer = fig.canvas.get_renderer()
    top, bottom = fig.axes
    legend = top.get_legend()
    assert [t.get_text() for t in legend.get_texts()] == [*labels, "accident window", "15 m/s: recovered above"]
    box = legend.get_window_extent(renderer)
    for ax in (top, bottom):
        assert not box.overlaps(ax.get_window_extent(renderer))
    assert box.x1 <= fig.bbox.x1  # inside the picture
