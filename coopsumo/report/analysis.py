"""Post-run analysis: loop-detector flow and density, bottleneck recovery, stop-and-go.

Inputs are the run's `detectors.xml` (SUMO E1 output) and its trajectory table
(columns time_s, vid, lane, pos_m, speed_mps). No SUMO process is needed.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd
import sumolib

DETECTOR_COLUMNS = [
    "id",
    "pos_m",
    "lane",
    "begin_s",
    "end_s",
    "n_veh",
    "flow_veh_h",
    "occupancy_pct",
    "speed_mps",
    "harmonic_speed_mps",
]
"""Columns of read_detectors' table, in order."""

_LOOP_ID = re.compile(r"^e1_x(\d+)_l(\d+)$")


def _parse_loop_id(loop_id: str) -> tuple[float, int]:
    """(position m, SUMO lane index) from an id such as e1_x01200_l2."""
    match = _LOOP_ID.match(loop_id)
    if match is None:
        raise ValueError(f"detector id {loop_id!r} is not of the form e1_x<pos>_l<lane>")
    return float(match.group(1)), int(match.group(2))


def _speed_or_nan(value: str | None) -> float:
    """A SUMO speed attribute (m/s) as float; SUMO's -1 (no vehicle) and a missing value become NaN."""
    if value is None:
        return float("nan")
    speed = float(value)
    return float("nan") if speed < 0 else speed


def read_detectors(path: str | Path) -> pd.DataFrame:
    """Read a SUMO E1 induction-loop XML file into one row per (detector, interval).

    Columns: id, pos_m (m), lane (SUMO index), begin_s, end_s (s), n_veh (nVehContrib),
    flow_veh_h (veh/h, this lane), occupancy_pct (%), speed_mps (arithmetic mean, m/s) and
    harmonic_speed_mps (harmonic mean, m/s); both speeds are NaN where SUMO wrote -1.
    Rows are sorted by pos_m, lane, begin_s. Raises ValueError if the file is missing,
    is not well-formed XML, or holds no interval.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"detector output {path} does not exist")
    rows = []
    try:
        for iv in sumolib.xml.parse(str(path), "interval"):
            pos_m, lane = _parse_loop_id(iv.id)
            rows.append(
                (
                    iv.id,
                    pos_m,
                    lane,
                    float(iv.begin),
                    float(iv.end),
                    int(iv.nVehContrib),
                    float(iv.flow),
                    float(iv.occupancy),
                    _speed_or_nan(iv.speed),
                    _speed_or_nan(iv.getAttributeSecure("harmonicMeanSpeed")),
                )
            )
    except ET.ParseError as err:
        raise ValueError(f"detector output {path} is not well-formed XML: {err}") from err
    if not rows:
        raise ValueError(f"detector output {path} holds no <interval> element")
    det = pd.DataFrame(rows, columns=DETECTOR_COLUMNS)
    return det.sort_values(["pos_m", "lane", "begin_s"], ignore_index=True)


def flow_density(
    det: pd.DataFrame,
    effective_length_m: float = 4.0,
    speed_col: Literal["speed_mps", "harmonic_speed_mps"] = "speed_mps",
) -> pd.DataFrame:
    """Flow (veh/h/lane) and density (veh/km/lane) per (detector, interval).

    density_veh_km is
      - flow_veh_h / (3.6 * v) where the interval's mean speed v (m/s, column speed_col) is
        known, i.e. at least one vehicle passed (the fundamental relation q = k v);
      - otherwise occupancy_pct / 100 * 1000 / effective_length_m, the time share the loop was
        covered divided by the covered length per vehicle (vehicle length plus loop length,
        m; SUMO's E1 loops have length 0, so the default is the 4 m car).
    Both are capped at the jam density 1000 / effective_length_m, which a near-zero mean speed
    could otherwise exceed. density_source says which formula was used ("speed"/"occupancy").
    speed_col="harmonic_speed_mps" uses the space-mean speed, the exact estimator for q = k v.
    Returns id, pos_m, lane, begin_s, end_s, flow_veh_h, density_veh_km, speed_mps, density_source.
    """
    if effective_length_m <= 0:
        raise ValueError(f"effective_length_m must be positive, got {effective_length_m}")
    flow = det["flow_veh_h"].to_numpy(dtype=float)
    speed = det[speed_col].to_numpy(dtype=float)
    occupancy = det["occupancy_pct"].to_numpy(dtype=float)
    jam_veh_km = 1000.0 / effective_length_m
    known = np.isfinite(speed) & (speed > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        from_speed = flow / (3.6 * speed)
    from_occupancy = occupancy / 100.0 * jam_veh_km
    density = np.minimum(np.where(known, from_speed, from_occupancy), jam_veh_km)
    out = det[["id", "pos_m", "lane", "begin_s", "end_s"]].copy()
    out["flow_veh_h"] = flow
    out["density_veh_km"] = density
    out["speed_mps"] = speed
    out["density_source"] = np.where(known, "speed", "occupancy")
    return out


def cross_section_flow(det: pd.DataFrame, pos_m: float) -> pd.Series:
    """Total flow (veh/h, summed over lanes) per interval at the loops at pos_m (m).

    Indexed by begin_s (s). Raises ValueError if no loop sits at pos_m (within 0.5 m).
    """
    at = det[np.abs(det["pos_m"].to_numpy(dtype=float) - pos_m) < 0.5]
    if at.empty:
        known = sorted(det["pos_m"].unique().tolist())
        raise ValueError(f"no detector at {pos_m} m; detector positions are {known}")
    total = at.groupby("begin_s")["flow_veh_h"].sum()
    total.name = "flow_veh_h"
    return total


def section_speed_bins(traj: pd.DataFrame, x_from_m: float, x_to_m: float, t_start_s: float, bin_s: float) -> pd.Series:
    """Space-mean speed (m/s) in x_from_m <= pos_m <= x_to_m per time bin from t_start_s.

    Bin k covers [t_start_s + k bin_s, t_start_s + (k+1) bin_s) and is indexed by its start (s).
    The space-mean speed is Edie's total distance / total vehicle-time in the space-time box;
    with samples equally spaced in time it is the mean of the samples' speeds. Bins run up
    to the last sample time of traj; a bin with no sample in the section is NaN.
    """
    if bin_s <= 0:
        raise ValueError(f"bin_s must be positive, got {bin_s}")
    t_end_s = float(traj["time_s"].max()) if len(traj) else t_start_s
    n_bins = max(int(np.floor((t_end_s - t_start_s) / bin_s)) + 1, 0)
    time_s = traj["time_s"].to_numpy(dtype=float)
    pos_m = traj["pos_m"].to_numpy(dtype=float)
    inside = (time_s >= t_start_s) & (pos_m >= x_from_m) & (pos_m <= x_to_m)
    k = np.floor((time_s[inside] - t_start_s) / bin_s).astype(np.int64)
    speed = traj["speed_mps"].to_numpy(dtype=float)[inside]
    total = np.bincount(k, weights=speed, minlength=n_bins)[:n_bins]
    count = np.bincount(k, minlength=n_bins)[:n_bins]
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / count, np.nan)
    index = pd.Index(t_start_s + bin_s * np.arange(n_bins), name="bin_start_s")
    return pd.Series(mean, index=index, name="speed_mps")


def recovery_time_s(
    traj: pd.DataFrame,
    x_bottleneck_m: float,
    release_start_s: float,
    threshold_mps: float = 15.0,
    upstream_m: float = 200.0,
    bin_s: float = 30.0,
    hold_bins: int = 2,
) -> float:
    """Time (s) from release_start_s until the bottleneck's upstream speed has recovered.

    The speed is section_speed_bins over x_bottleneck_m - upstream_m <= pos_m <= x_bottleneck_m
    (all lanes), in bins of bin_s seconds starting at release_start_s (the first moment the
    accident releases vehicles). Bins with no vehicle in the section are ignored. The
    recovery bin is the first bin k whose speed is strictly above threshold_mps and such that
    every later non-empty bin is also strictly above it, with at least hold_bins non-empty
    bins from k to the end of the data (so one last lucky bin is not a recovery).
    Returns k * bin_s (0 if already recovered in the first bin), NaN if there is no such bin.
    """
    if hold_bins < 1:
        raise ValueError(f"hold_bins must be at least 1, got {hold_bins}")
    speed = section_speed_bins(traj, x_bottleneck_m - upstream_m, x_bottleneck_m, release_start_s, bin_s).to_numpy()
    filled = np.isfinite(speed)
    above = speed > threshold_mps
    # bad[k]: some non-empty bin at or after k is at or below the threshold
    bad = np.flip(np.logical_or.accumulate(np.flip(filled & ~above)))
    # remaining[k]: non-empty bins at or after k
    remaining = np.flip(np.cumsum(np.flip(filled)))
    ok = filled & above & ~bad & (remaining >= hold_bins)
    if not ok.any():
        return float("nan")
    return float(np.argmax(ok)) * bin_s


def stop_and_go(traj: pd.DataFrame, x_from_m: float, x_to_m: float, slow_mps: float = 5.0) -> dict[str, float]:
    """Stop-and-go statistics in the section x_from_m <= pos_m < x_to_m (all lanes).

    Only samples inside the section count; samples are assumed equally spaced in time.
    - slow_share: samples with speed_mps < slow_mps over all samples in the section
      (the share of vehicle-time spent slow);
    - stops_per_vehicle: stops over distinct vehicles seen in the section, where a stop is
      a sample below slow_mps whose previous in-section sample of the same vehicle was
      >= slow_mps (a vehicle entering the section already slow has not stopped there);
    - n_vehicles and n_stops, the two counts behind it.
    Ratios are NaN when no sample lies in the section.
    """
    pos_m = traj["pos_m"].to_numpy(dtype=float)
    inside = traj[(pos_m >= x_from_m) & (pos_m < x_to_m)]
    if inside.empty:
        return {"slow_share": float("nan"), "stops_per_vehicle": float("nan"), "n_vehicles": 0.0, "n_stops": 0.0}
    inside = inside.sort_values(["vid", "time_s"], kind="stable")
    vid = inside["vid"].astype(str).to_numpy()
    slow = inside["speed_mps"].to_numpy(dtype=float) < slow_mps
    same_vehicle = np.zeros(len(vid), dtype=bool)
    same_vehicle[1:] = vid[1:] == vid[:-1]
    was_fast = np.zeros(len(vid), dtype=bool)
    was_fast[1:] = ~slow[:-1]
    n_stops = int(np.count_nonzero(slow & was_fast & same_vehicle))
    n_vehicles = int(len(vid) - np.count_nonzero(same_vehicle))
    return {
        "slow_share": float(np.count_nonzero(slow)) / len(slow),
        "stops_per_vehicle": n_stops / n_vehicles,
        "n_vehicles": float(n_vehicles),
        "n_stops": float(n_stops),
    }


def loop_interval_speeds(det: pd.DataFrame) -> pd.Series:
    """Each loop interval's speed (m/s): SUMO's mean speed; 0 where no vehicle passed but the loop was
    occupied (a vehicle standing on it); NaN where the loop saw nothing (an empty road)."""
    speed = det["speed_mps"].to_numpy(dtype=float)
    standing = ~np.isfinite(speed) & (det["occupancy_pct"].to_numpy(dtype=float) > 0)
    return pd.Series(np.where(standing, 0.0, speed), index=det.index, name="speed_mps")


def stop_and_go_waves(
    det: pd.DataFrame, x_to_m: float, slow_mps: float = 5.0, fast_mps: float = 15.0, lookback_s: float = 120.0
) -> dict[str, float]:
    """Stop-and-go waves at the loops upstream of x_to_m (pos_m < x_to_m), from SUMO's E1 output.

    A wave onset is a loop interval whose speed (loop_interval_speeds) is below slow_mps while the same
    loop measured more than fast_mps in an interval that began within the previous lookback_s seconds:
    traffic went from flowing to standing within two minutes. Returns
    - wave_share: onsets over all loop intervals with a speed (empty intervals do not count);
    - n_onsets, n_intervals: the counts behind it;
    - onsets_per_loop_hour: onsets per loop and hour of data. NaN ratios when no interval has a speed.
    """
    up = det[det["pos_m"].to_numpy(dtype=float) < x_to_m].sort_values(["id", "begin_s"], kind="stable")
    speed = loop_interval_speeds(up).to_numpy()
    begin = up["begin_s"].to_numpy(dtype=float)
    loop = up["id"].to_numpy()
    valid = np.isfinite(speed)
    onsets = 0
    for start, stop in _runs(loop):
        v, b = speed[start:stop], begin[start:stop]
        fast_begins = b[v > fast_mps]
        for k in np.flatnonzero(v < slow_mps):
            recent = fast_begins[(fast_begins < b[k]) & (fast_begins >= b[k] - lookback_s)]
            onsets += int(len(recent) > 0)
    n = int(valid.sum())
    hours = float((up["end_s"] - up["begin_s"]).sum()) / 3600.0
    return {
        "wave_share": onsets / n if n else float("nan"),
        "n_onsets": float(onsets),
        "n_intervals": float(n),
        "onsets_per_loop_hour": onsets / hours if hours > 0 else float("nan"),
    }


def _runs(labels: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of each run of equal consecutive labels."""
    if len(labels) == 0:
        return []
    cuts = np.flatnonzero(labels[1:] != labels[:-1]) + 1
    bounds = np.concatenate([[0], cuts, [len(labels)]])
    return list(zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True))


def insertion_backlog(traj: pd.DataFrame, t_up_s: float) -> pd.Series:
    """Vehicles waiting to enter the road at each trajectory sample time (veh), indexed by time_s.

    Vehicle k is scheduled at k * t_up_s (k = 0, 1, ...); it has entered once it appears in the
    trajectories. backlog(t) = scheduled by t - entered by t. With samples every s seconds an
    entering vehicle is seen up to s late, so the backlog of a free road is about s / t_up_s.
    """
    if t_up_s <= 0:
        raise ValueError(f"t_up_s must be positive, got {t_up_s}")
    times = np.unique(traj["time_s"].to_numpy(dtype=float))
    first_seen = np.sort(traj.groupby("vid")["time_s"].min().to_numpy(dtype=float))
    entered = np.searchsorted(first_seen, times + 1e-9, side="right")
    scheduled = np.floor(times / t_up_s + 1e-9).astype(np.int64) + 1
    return pd.Series(scheduled - entered, index=pd.Index(times, name="time_s"), name="backlog_veh")


def backlog_cleared_s(backlog: pd.Series, from_s: float, limit_veh: float) -> float:
    """Time (s) after from_s at which the backlog is at or below limit_veh for good: the sample after the
    last one above it (0 if none after from_s is above it); NaN if it is still above at the end."""
    after = backlog[backlog.index >= from_s]
    above = np.flatnonzero(after.to_numpy() > limit_veh)
    if len(above) == 0:
        return 0.0
    if above[-1] == len(after) - 1:
        return float("nan")
    return float(after.index[above[-1] + 1] - from_s)
