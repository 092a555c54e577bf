"""The controller of every vehicle but SUMO's own models, as pure array functions: which lane changes start,
and the Newell speed with the collision check over every lane a vehicle occupies. No SUMO.

A vehicle in a lane change occupies its origin and target lane until the change completes (4 s).
"""

from __future__ import annotations

import numpy as np

from coopsumo.config import ControlConfig
from coopsumo.sim import fast, physics


def other_lane(lane: np.ndarray, lc_from: np.ndarray, lc_to: np.ndarray, lc_left_s: np.ndarray) -> np.ndarray:
    """The second lane a vehicle touches during a lane change (-1 when not changing)."""
    return np.where(lc_left_s > 0, lc_from + lc_to - lane, -1)


def nearest_leader(lead_gap: np.ndarray, lead_speed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gap (m) and speed (m/s) of the nearest of the leaders in the (n, k) columns."""
    pick = np.argmin(lead_gap, axis=1)
    rows = np.arange(len(lead_gap))
    return lead_gap[rows, pick], lead_speed[rows, pick]


def leaders_in_occupied_lanes(
    lane: np.ndarray, other: np.ndarray, pos_m: np.ndarray, speed_mps: np.ndarray, n_lanes: int, car_length_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Gap (m) and speed (m/s) of each vehicle's nearest leader in its lane and the second lane it occupies."""
    query = np.stack([lane, np.where(other >= 0, other, lane)], axis=1)
    _, nb = fast.occupancy_and_neighbours(lane, pos_m, other, speed_mps, query, n_lanes, car_length_m)
    return nearest_leader(nb.lead_gap, nb.lead_speed)


def lane_changes(
    actions: np.ndarray, lane: np.ndarray, pos_m: np.ndarray, speed_mps: np.ndarray, feasible: np.ndarray,
    cfg: ControlConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """(accepted, rejected, target lane) of each vehicle's action: a change is accepted when it is feasible now
    (physics.feasible_actions) and does not cut into another change into the same lane (resolve_conflicts)."""
    wants = (actions == physics.LEFT) | (actions == physics.RIGHT)
    target = lane + np.where(actions == physics.LEFT, 1, -1)
    rows = np.arange(len(actions))
    ok = wants & feasible[rows, np.where(wants, actions, physics.SPEEDUP)]
    ok = physics.resolve_conflicts(target, pos_m, speed_mps, ok, cfg)
    return ok, wants & ~ok, target
