"""Measures of a bottleneck that may spill back to the entrance: pure functions on arrays and tables.

Inputs are a run's trajectory table (columns time_s, vid, lane, pos_m, speed_mps; samples every
`sample_s` seconds) and its loop table (report.analysis.read_detectors). No SUMO process is needed.

- total_time_spent: vehicle-hours on the road AND waiting to enter (the headline: a policy cannot
  look good by keeping vehicles off the road), with the delay against driving at a reference speed;
- discharge_veh_h: the flow leaving the bottleneck while the accident holds (loops just downstream);
- system_recovery_s: the time from which the road is fast AND nobody waits to enter;
- queue_reach: how far upstream the queue reaches, and the run's demand regime;
- queue_lane_changes: lane changes made where the traffic stands;
- speed_field and moving_jams: stop-and-go waves as connected slow regions of the space-time speed
  field (after Ji et al. 2024, arXiv 2409.00326) whose downstream front travels upstream (a moving
  jam; a bottleneck queue's front stays at the bottleneck: Kerner and Rehborn 1996).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
import pandas as pd

REGIMES = ("on the road", "reaches the entrance, clears", "still waiting at the end")
"""demand regimes of an accident run, from the entrance queue (queue_reach)"""


def occupancy_counts(traj: pd.DataFrame, t_up_s: float) -> pd.DataFrame:
    """Per trajectory sample time (index time_s): vehicles on the road and vehicles waiting to enter.

    Vehicle k is due at k * t_up_s (k = 0, 1, ...) and has entered once it appears in the trajectories,
    so waiting = due by t - entered by t (as report.analysis.insertion_backlog).
    """
    if t_up_s <= 0:
        raise ValueError(f"t_up_s must be positive, got {t_up_s}")
    time_s = traj["time_s"].to_numpy(dtype=float)
    times, on_road = np.unique(time_s, return_counts=True)
    first_seen = np.sort(traj.groupby("vid")["time_s"].min().to_numpy(dtype=float))
    entered = np.searchsorted(first_seen, times + 1e-9, side="right")
    due = np.floor(times / t_up_s + 1e-9).astype(np.int64) + 1
    return pd.DataFrame({"on_road": on_road, "waiting": due - entered}, index=pd.Index(times, name="time_s"))


def total_time_spent(
    on_road: np.ndarray, waiting: np.ndarray, speed_sum_mps: np.ndarray, sample_s: float, v_ref_mps: float
) -> dict[str, float]:
    """Total time spent (vehicle-hours) from per-sample counts, each sample standing for sample_s seconds.

    on_road, waiting: vehicles on the road and waiting to enter at each sample; speed_sum_mps: the sum of
    the speeds of the vehicles on the road at each sample (so the distance driven is its sum times sample_s).
    Returns tts_veh_h (on road + waiting), on_road_veh_h, waiting_veh_h, distance_veh_km and delay_veh_h:
    the time spent beyond driving that distance at v_ref_mps (waiting counts whole).
    """
    if sample_s <= 0 or v_ref_mps <= 0:
        raise ValueError(f"sample_s and v_ref_mps must be positive, got {sample_s}, {v_ref_mps}")
    on_h = float(np.sum(on_road)) * sample_s / 3600.0
    wait_h = float(np.sum(waiting)) * sample_s / 3600.0
    dist_m = float(np.sum(speed_sum_mps)) * sample_s
    tts = on_h + wait_h
    return {
        "tts_veh_h": tts,
        "on_road_veh_h": on_h,
        "waiting_veh_h": wait_h,
        "distance_veh_km": dist_m / 1000.0,
        "delay_veh_h": tts - dist_m / v_ref_mps / 3600.0,
    }


def run_time_spent(traj: pd.DataFrame, t_up_s: float, sample_s: float, v_ref_mps: float) -> dict[str, float]:
    """total_time_spent of one run's trajectory table (samples every sample_s seconds)."""
    counts = occupancy_counts(traj, t_up_s)
    speed_sum = traj.groupby("time_s")["speed_mps"].sum().reindex(counts.index).to_numpy(dtype=float)
    return total_time_spent(counts["on_road"].to_numpy(), counts["waiting"].to_numpy(), speed_sum, sample_s, v_ref_mps)


def discharge_veh_h(det: pd.DataFrame, x_m: float, t_from_s: float, t_to_s: float) -> float:
    """Flow (veh/h, all lanes) past the first loops downstream of x_m, over the loop intervals that lie
    inside [t_from_s, t_to_s]: the bottleneck's discharge while it is active. NaN if no interval fits."""
    down = det[det["pos_m"].to_numpy(dtype=float) > x_m]
    if down.empty:
        raise ValueError(f"no loop downstream of {x_m} m")
    at = down[np.isclose(down["pos_m"].to_numpy(dtype=float), float(down["pos_m"].min()))]
    inside = at[(at["begin_s"] >= t_from_s - 1e-9) & (at["end_s"] <= t_to_s + 1e-9)]
    if inside.empty:
        return float("nan")
    span_s = float(inside["end_s"].max() - inside["begin_s"].min())
    return float(inside["n_veh"].sum()) * 3600.0 / span_s


def system_recovery_s(
    speed_bins: pd.Series, waiting: pd.Series, from_s: float, threshold_mps: float, waiting_limit: float
) -> float:
    """Time (s) after from_s from which the road is back: every later speed bin (speed_bins, indexed by
    bin start, NaN = empty) is above threshold_mps AND every later waiting count (indexed by time) is at
    most waiting_limit. Measured in the bins' steps: the start of the first bin from which both hold to
    the end, counting waiting samples from that bin's start. NaN if that never happens (or no bin is filled).
    """
    bins = speed_bins[speed_bins.index >= from_s - 1e-9]
    starts = bins.index.to_numpy(dtype=float)
    speed = bins.to_numpy(dtype=float)
    if not np.isfinite(speed).any():
        return float("nan")
    slow = np.isfinite(speed) & ~(speed > threshold_mps)
    w_times = waiting.index.to_numpy(dtype=float)
    crowded = w_times[waiting.to_numpy(dtype=float) > waiting_limit]
    last_slow = starts[np.flatnonzero(slow)[-1]] if slow.any() else -np.inf
    last_crowded = crowded.max() if len(crowded) else -np.inf
    ok = (starts > last_slow) & (starts > last_crowded) & np.isfinite(speed)
    if not ok.any():
        return float("nan")
    return float(starts[np.argmax(ok)] - from_s)


def queue_tail_m(times_s: np.ndarray, pos_m: np.ndarray, x_m: float, max_gap_m: float) -> pd.Series:
    """Per sample time: the position (m) of the upstream end of the queue standing at x_m, from the positions
    of the slow vehicles (all lanes) at that time. The queue is the chain of slow vehicles that starts within
    max_gap_m of x_m and continues upstream while consecutive ones are at most max_gap_m apart (so vehicles
    slow elsewhere, e.g. just inserted at the entrance, are not part of it); x_m where there is none."""
    out = {}
    order = np.lexsort((-pos_m, times_s))
    t_sorted, p_sorted = times_s[order], pos_m[order]
    cuts = np.flatnonzero(np.diff(t_sorted)) + 1
    for t_group, p_group in zip(np.split(t_sorted, cuts), np.split(p_sorted, cuts), strict=True):
        if not len(t_group):
            continue
        chain = np.concatenate([[x_m], p_group])
        broken = np.flatnonzero(-np.diff(chain) > max_gap_m)
        last = broken[0] if len(broken) else len(p_group)
        out[float(t_group[0])] = float(chain[last])
    return pd.Series(out, name="tail_m", dtype=float)


def queue_reach(
    traj: pd.DataFrame, waiting: pd.Series, x_m: float, t_from_s: float, slow_mps: float, waiting_limit: float,
    max_gap_m: float = 100.0,
) -> dict[str, float | str]:
    """How far upstream the accident's queue reaches, and the demand regime of the run.

    queue_m: the largest distance from x_m to the queue's upstream end (queue_tail_m of the vehicles slower
    than slow_mps on [0, x_m]) at any sample from t_from_s; spilled_s: the first time after t_from_s at which
    more than waiting_limit vehicles wait to enter (NaN if never); regime: REGIMES[0] if nobody had to wait,
    REGIMES[1] if the queue reached the entrance but nobody waits at the last sample, else REGIMES[2].
    """
    t = traj["time_s"].to_numpy(dtype=float)
    pos = traj["pos_m"].to_numpy(dtype=float)
    slow = (t >= t_from_s) & (pos <= x_m) & (traj["speed_mps"].to_numpy(dtype=float) < slow_mps)
    tails = queue_tail_m(t[slow], pos[slow], x_m, max_gap_m)
    queue_m = float(x_m - tails.min()) if len(tails) else 0.0
    after = waiting[waiting.index >= t_from_s]
    over = after.index[after.to_numpy(dtype=float) > waiting_limit]
    spilled = float(over[0] - t_from_s) if len(over) else float("nan")
    if not len(over):
        regime = REGIMES[0]
    elif len(after) and float(after.iloc[-1]) <= waiting_limit:
        regime = REGIMES[1]
    else:
        regime = REGIMES[2]
    return {"queue_m": queue_m, "spilled_s": spilled, "regime": regime}


def speed_field(
    traj: pd.DataFrame, x_from_m: float, x_to_m: float, t_from_s: float, t_to_s: float, dt_s: float, dx_m: float
) -> np.ndarray:
    """Space-mean speed (m/s) on a (time, position) grid of dt_s x dx_m cells over all lanes: the mean of the
    speeds sampled in each cell (Edie's definition when samples are equally spaced in time); NaN for a cell
    with no sample. Cell (i, j) covers [t_from_s + i dt_s, + dt_s) x [x_from_m + j dx_m, + dx_m)."""
    if dt_s <= 0 or dx_m <= 0 or t_to_s <= t_from_s or x_to_m <= x_from_m:
        raise ValueError("speed_field needs positive cell sizes and non-empty ranges")
    n_t = int(np.ceil((t_to_s - t_from_s) / dt_s - 1e-9))
    n_x = int(np.ceil((x_to_m - x_from_m) / dx_m - 1e-9))
    t = traj["time_s"].to_numpy(dtype=float)
    x = traj["pos_m"].to_numpy(dtype=float)
    inside = (t >= t_from_s) & (t < t_to_s) & (x >= x_from_m) & (x < x_to_m)
    i = np.minimum(((t[inside] - t_from_s) / dt_s).astype(np.int64), n_t - 1)
    j = np.minimum(((x[inside] - x_from_m) / dx_m).astype(np.int64), n_x - 1)
    flat = i * n_x + j
    total = np.bincount(flat, weights=traj["speed_mps"].to_numpy(dtype=float)[inside], minlength=n_t * n_x)
    count = np.bincount(flat, minlength=n_t * n_x)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / count, np.nan).reshape(n_t, n_x)


def connected_regions(mask: np.ndarray) -> np.ndarray:
    """Labels 1..k of the 8-connected regions of True cells in a 2-D mask (0 elsewhere)."""
    labels = np.zeros(mask.shape, dtype=np.int64)
    n_rows, n_cols = mask.shape
    current = 0
    for start in zip(*np.nonzero(mask), strict=True):
        if labels[start]:
            continue
        current += 1
        labels[start] = current
        todo = deque([start])
        while todo:
            r, c = todo.popleft()
            for dr in (-1, 0, 1):
                for dc in (-1, 0, 1):
                    rr, cc = r + dr, c + dc
                    if 0 <= rr < n_rows and 0 <= cc < n_cols and mask[rr, cc] and not labels[rr, cc]:
                        labels[rr, cc] = current
                        todo.append((rr, cc))
    return labels


@dataclass(frozen=True)
class Jam:
    """One slow region of the space-time speed field."""

    start_s: float
    """its first cell's start, from the field's start (s)"""
    duration_s: float
    front_travel_m: float
    """how far its downstream front moved upstream from its first to its last time (m; > 0 = upstream)"""
    front_speed_kmh: float
    """least-squares speed of its downstream front (km/h; < 0 = upstream)"""
    moving: bool
    """a stop-and-go wave (moving jam) by moving_jams' rule, rather than a standing queue"""


def moving_jams(
    field: np.ndarray,
    dt_s: float,
    dx_m: float,
    slow_mps: float = 5.0,
    min_duration_s: float = 20.0,
    min_travel_m: float = 100.0,
    front_kmh: tuple[float, float] = (-30.0, -5.0),
) -> list[Jam]:
    """The slow regions (cells below slow_mps, 8-connected) of a speed_field lasting at least min_duration_s.

    A region is a moving jam (a stop-and-go wave) when its downstream front travels upstream like a jam's: the
    front (its most downstream cell at each time) moves at least min_travel_m upstream from its first to its
    last time, at a least-squares speed inside front_kmh (km/h; congested waves travel at about -15 to -20
    km/h; a faster "front" is a slow region breaking up everywhere at once). A bottleneck queue's front stays
    at the bottleneck (speed near 0), so steady congestion is not a wave, whatever its size. A wave that touches the
    standing queue in the field is part of the queue's region and is not counted on its own.
    """
    labels = connected_regions(np.isfinite(field) & (field < slow_mps))
    jams = []
    for k in range(1, int(labels.max()) + 1):
        rows, cols = np.nonzero(labels == k)
        times = np.unique(rows)
        duration = float((times[-1] - times[0] + 1) * dt_s)
        if duration < min_duration_s:
            continue
        front = np.array([cols[rows == r].max() for r in times], dtype=float) * dx_m
        t = times * dt_s
        slope = float(np.polyfit(t, front, 1)[0]) if len(times) > 1 else 0.0
        travel = float(front[0] - front[-1])
        jams.append(Jam(float(times[0] * dt_s), duration, travel, slope * 3.6,
                        travel >= min_travel_m and front_kmh[0] <= slope * 3.6 <= front_kmh[1]))  # fmt: skip
    return jams


def lane_jams(traj: pd.DataFrame, x_to_m: float, t_to_s: float, dt_s: float, dx_m: float,
              slow_mps: float = 5.0) -> list[Jam]:  # fmt: skip
    """moving_jams of each lane's own speed field from the entrance to x_to_m (m), over [0, t_to_s) (s), together:
    every lane is its own queue (as in the paper's Fig. 4), so a wave across all lanes counts once per lane."""
    jams: list[Jam] = []
    for lane in np.unique(traj["lane"].to_numpy()):
        field = speed_field(traj[traj["lane"] == lane], 0.0, x_to_m, 0.0, t_to_s, dt_s, dx_m)
        jams += moving_jams(field, dt_s, dx_m, slow_mps=slow_mps)
    return jams


def wave_summary(jams: list[Jam]) -> dict[str, float]:
    """waves: moving jams counted; wave_speed_kmh: their mean front speed (NaN if none); slow_regions: all."""
    moving = [j for j in jams if j.moving]
    speed = float(np.mean([j.front_speed_kmh for j in moving])) if moving else float("nan")
    return {"waves": float(len(moving)), "wave_speed_kmh": speed, "slow_regions": float(len(jams))}


def queue_lane_changes(traj: pd.DataFrame, slow_mps: float = 5.0) -> int:
    """Lane changes made in a queue: a vehicle's sample whose lane differs from its previous sample's while it moves
    below slow_mps (m/s). A change takes seconds (4 s here) across both lanes, so one made where the traffic
    stands holds up the followers of two queues; counted once per change (samples every few tenths of a second)."""
    order = traj.sort_values(["vid", "time_s"], kind="stable")
    vid = order["vid"].to_numpy()
    lane = order["lane"].to_numpy()
    speed = order["speed_mps"].to_numpy()
    changed = (vid[1:] == vid[:-1]) & (lane[1:] != lane[:-1])
    return int(np.count_nonzero(changed & (speed[1:] < slow_mps)))
