"""alpha chosen online from the loops: the rule that maps one loop interval's measurements to the alpha every
vehicle of an alpha-conditioned model drives with (policy `dqn:PATH,alpha=adaptive`). Pure; no SUMO, no torch.

Every loop period (60 s) the road's E1 loops report, per detector, the vehicles counted, the occupancy (% of the
period) and the mean speed. `interval_measures` reduces them to one road-wide interval: flow per lane (veh/h),
mean occupancy (%) and count-weighted mean speed (m/s). `choose_alpha` looks the occupancy up in the rule: the
alpha* scenario II found at the condition of the same lane count whose measured occupancy is nearest
(`AdaptiveRule`). Occupancy, not flow, is the rule's variable: flow is the same at a light load and in a jam,
occupancy grows with the load in free flow and keeps growing in a queue.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LoopInterval:
    """One loop period's road-wide measurements."""

    time_s: float
    """simulation time at the end of the period (s)"""
    flow_veh_h_per_lane: float
    """vehicles counted per detector, as veh/h, averaged over the detectors (each covers one lane)"""
    occupancy_pct: float
    """mean occupancy over the detectors (% of the period a vehicle stood over the loop)"""
    speed_mps: float
    """mean speed of the vehicles counted, weighted by count (m/s; nan when none was counted)"""


def interval_measures(time_s: float, counts: np.ndarray, occupancy_pct: np.ndarray, speeds_mps: np.ndarray,
                      period_s: float) -> LoopInterval:  # fmt: skip
    """Reduce one period of every detector (SUMO's getLastInterval*: count, occupancy %, mean speed m/s with -1 for
    no vehicle) to one LoopInterval."""
    counts = np.asarray(counts, np.float64)
    occupancy_pct = np.asarray(occupancy_pct, np.float64)
    speeds_mps = np.asarray(speeds_mps, np.float64)
    if len(counts) == 0 or period_s <= 0:
        return LoopInterval(time_s, 0.0, 0.0, math.nan)
    flow = float(counts.mean() / period_s * 3600.0)
    counted = (counts > 0) & (speeds_mps >= 0)
    speed = float((speeds_mps[counted] * counts[counted]).sum() / counts[counted].sum()) if counted.any() else math.nan
    return LoopInterval(time_s, flow, float(occupancy_pct.mean()), speed)


@dataclass(frozen=True)
class AdaptiveRule:
    """Per lane count, the measured occupancies (%) of scenario II's conditions and the alpha* found at each.

    points: ((lanes, occupancy %, alpha*), ...). A road whose lane count is not in the rule uses the nearest lane
    count's points (the larger on a tie).
    """

    points: tuple[tuple[int, float, float], ...]
    source: str = ""
    """where the points were measured (a results folder)"""

    def lane_counts(self) -> list[int]:
        return sorted({p[0] for p in self.points})


def choose_alpha(rule: AdaptiveRule, lanes: int, occupancy_pct: float) -> float:
    """The alpha* of the rule's point (same or nearest lane count) whose occupancy is nearest to occupancy_pct.

    Beyond the measured range the end point's alpha holds (a jam denser than any free-flow condition gets the
    densest condition's alpha*). Ties go to the denser point.
    """
    if not rule.points:
        raise ValueError("the adaptive rule has no points")
    counts = rule.lane_counts()
    nearest = min(counts, key=lambda n: (abs(n - lanes), -n))
    pts = sorted((occ, a) for n, occ, a in rule.points if n == nearest)
    occ = 0.0 if not math.isfinite(occupancy_pct) else occupancy_pct
    best = min(range(len(pts)), key=lambda i: (abs(pts[i][0] - occ), -pts[i][0]))
    return float(pts[best][1])


DEFAULT_RULE = AdaptiveRule(
    points=((2, 1.961, 2.0), (2, 4.329, 0.25), (2, 7.09, 8.0), (2, 10.749, 8.0),
            (3, 1.987, 0.25), (3, 4.405, 0.0), (3, 7.074, 0.125), (3, 10.255, 1.0),
            (4, 2.012, 0.0), (4, 4.32, 0.0), (4, 6.963, 0.125), (4, 9.892, 48.0)),
    source="results/scenario2_conditioned",
)
"""the rule `alpha=adaptive` uses: per condition of results/archive/scenario2_conditioned, its mean loop occupancy and
alpha* (2, 3 and 4 lanes, 90,000 training steps, 3 seeds; a road of another lane count uses the nearest lane count's
points), as `coopsumo adaptive-fit` printed it (retired 2026-12-02; run it at commit dd78f46)"""
