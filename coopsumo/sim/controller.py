"""The controller of every vehicle but SUMO's own models, as pure array functions: which lane changes start,
and the Newell speed with the collision check over every lane a vehicle occupies. No SUMO.

These are the definitions; the world runs the controller's step (sight, decide, after_step) as coopsumo.sim.fast's
C functions of the same names, equal to them bit for bit (tests/test_fast_step.py).

A vehicle in a lane change occupies its origin and target lane until the change completes (4 s).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple, Protocol

import numpy as np

from coopsumo.config import AccidentConfig, ControlConfig
from coopsumo.sim import accident, physics
from coopsumo.sim.physics import Neighbours, Occupancy


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
    nb = physics.neighbours(physics.occupancy(lane, pos_m, other), pos_m, speed_mps, query, n_lanes, car_length_m)
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


# -- the controller's step, as the world calls it (the same in C: coopsumo.sim.fast) -------------------------


class LaneState(Protocol):
    """The per-vehicle state the controller reads and writes, arrays indexed by vehicle number."""

    v_exp: np.ndarray  # expected speed (m/s)
    lc_left_s: np.ndarray  # time left of the lane change under way (s; 0: none)
    lc_from: np.ndarray  # its origin lane
    lc_to: np.ndarray  # its target lane
    hold: np.ndarray  # int8: the accident's state (accident.UNDECIDED, HELD, RELEASED)


@dataclass(frozen=True)
class Controls:
    """What the controller's step needs of a run's configuration."""

    control: ControlConfig
    accident: AccidentConfig
    n_lanes: int
    lane_width_m: float
    params: np.ndarray = field(init=False, repr=False, compare=False)
    """the same as one float64 array, in the order kernels.c reads it"""

    def __post_init__(self) -> None:
        c, a = self.control, self.accident
        values = (self.n_lanes, c.car_length_m, c.lc_min_gap_m, c.lc_headway_s, c.t_change_s, c.v_acc_mps,
                  c.newell_c_per_s, c.newell_d, c.a1, c.a2_s, c.v_cc_mps, a.x_m, accident.ZONE_M,
                  accident.STANDING_MPS, c.dt_s, self.lane_width_m, c.vehicle_width_m)  # fmt: skip
        object.__setattr__(self, "params", np.array(values, np.float64))


@dataclass(frozen=True)
class Sight:
    """What the controller sees of every vehicle on the road before the decisions (rows of the table)."""

    v_exp: np.ndarray  # (n,) expected speed (m/s)
    other: np.ndarray  # (n,) the second lane a lane changer touches, -1 for none
    busy: np.ndarray  # (n,) bool: a lane change is under way
    occ: Occupancy
    nb: Neighbours  # (n, 4): in the left, own, right lane and the second lane (own lane when none)
    leader_gap: np.ndarray  # (n,) the nearest leader over the lanes a vehicle occupies (m)
    leader_speed: np.ndarray  # (n,) its speed (m/s)
    feasible: np.ndarray  # (n, 4) bool: physics.feasible_actions

    @property
    def around(self) -> Neighbours:
        """The neighbours in the left, own and right lane, (n, 3)."""
        return sides(self.nb)


def sides(nb: Neighbours) -> Neighbours:
    """The first three query columns of nb (left, own and right lane) as views."""
    return Neighbours(nb.lead_gap[:, :3], nb.lead_speed[:, :3], nb.lead_idx[:, :3], nb.follow_gap[:, :3],
                      nb.follow_speed[:, :3], nb.follow_idx[:, :3], nb.exists[:, :3])  # fmt: skip


class Decision(NamedTuple):
    """The controller's answer to the actions of one step (rows of the sight)."""

    ok: np.ndarray  # (n,) bool: a lane change starts
    rejected: np.ndarray  # (n,) bool: a change was asked for and refused
    target: np.ndarray  # (n,) target lane of an asked change
    speeds: np.ndarray  # (n,) speed for the next step (m/s)
    changed: np.ndarray  # (n,) bool: the speed differs from the one last sent


def sight(nums: np.ndarray, lane: np.ndarray, pos: np.ndarray, speed: np.ndarray, state: LaneState,
          controls: Controls) -> Sight:  # fmt: skip
    """The neighbours, nearest leaders and feasible actions of the vehicles nums (lane, pos m, speed m/s)."""
    c = controls.control
    v_exp = state.v_exp[nums]
    other = other_lane(lane, state.lc_from[nums], state.lc_to[nums], state.lc_left_s[nums])
    busy = other >= 0
    # one search for the three side lanes and the second lane a changer touches (its own when none)
    query = np.concatenate([physics.side_lanes(lane), np.where(busy, other, lane)[:, None]], axis=1)
    occ = physics.occupancy(lane, pos, other)
    nb = physics.neighbours(occ, pos, speed, query, controls.n_lanes, c.car_length_m)
    gap, v_lead = nearest_leader(nb.lead_gap[:, 1::2], nb.lead_speed[:, 1::2])
    feasible = physics.feasible_actions(sides(nb), busy, speed, c)
    return Sight(v_exp, other, busy, occ, nb, gap, v_lead, feasible)


def decide(
    nums: np.ndarray, lane: np.ndarray, pos: np.ndarray, speed: np.ndarray, seen: Sight, actions: np.ndarray,
    state: LaneState, sent: np.ndarray, draw: accident.HoldDraw, controls: Controls,
) -> Decision:  # fmt: skip
    """The lane changes started and refused (written into state's lane-change arrays), the accident's hold state
    (state.hold), and the Newell speeds with the collision check; sent: the speed last sent to each vehicle number
    (NaN: none)."""
    c = controls.control
    ok, rejected, target = lane_changes(actions, lane, pos, speed, seen.feasible, c)
    movers = nums[ok]
    state.lc_left_s[movers] = c.t_change_s
    state.lc_from[movers] = lane[ok]
    state.lc_to[movers] = target[ok]
    # the nearest leader over every lane a vehicle occupies (movers: both lanes from now on); the sight's holds
    # unless a change started (then every vehicle's leader may change)
    if len(movers):
        other = other_lane(lane, state.lc_from[nums], state.lc_to[nums], state.lc_left_s[nums])
        gap, v_lead = leaders_in_occupied_lanes(lane, other, pos, speed, controls.n_lanes, c.car_length_m)
    else:
        gap, v_lead = seen.leader_gap, seen.leader_speed
    state.hold[nums], gap, v_lead = accident.held(state.hold[nums], pos, speed, gap, v_lead, draw, controls.accident)
    speeds = physics.next_speed(speed, seen.v_exp, actions == physics.SPEEDUP, gap, v_lead, c)
    return Decision(ok, rejected, target, speeds, speeds != sent[nums])


def after_step(nums: np.ndarray, lane: np.ndarray, pos: np.ndarray, state: LaneState, controls: Controls) -> np.ndarray:
    """After SUMO's step: every lane change's clock runs down by one step (state.lc_left_s), then the (k, 2) rows
    (follower, leader) of vehicles whose bodies overlap (physics.body_lanes, physics.overlaps)."""
    c = controls.control
    busy = nums[state.lc_left_s[nums] > 0]
    state.lc_left_s[busy] = np.maximum(state.lc_left_s[busy] - c.dt_s, 0.0)
    first, second = physics.body_lanes(lane, state.lc_from[nums], state.lc_to[nums], state.lc_left_s[nums],
                                       c.t_change_s, controls.lane_width_m, c.vehicle_width_m)  # fmt: skip
    return physics.overlaps(physics.occupancy(first, pos, second), c.car_length_m)
