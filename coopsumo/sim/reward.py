"""Reward of eq. (5)-(7) as named components: speed, lane-change penalty, flow."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coopsumo.config import RewardConfig
from coopsumo.sim.physics import lane_key


@dataclass(frozen=True)
class RewardParts:
    """Per-vehicle reward components for one step; total = speed + lane_change + flow."""

    speed: np.ndarray
    lane_change: np.ndarray
    flow: np.ndarray

    @property
    def total(self) -> np.ndarray:
        return self.speed + self.lane_change + self.flow


def section_crossings(
    prev_nums: np.ndarray, prev_pos: np.ndarray, nums: np.ndarray, pos: np.ndarray, sections_m: np.ndarray
) -> int:
    """Vehicles whose front passed a loop cross-section between two vehicle tables (sorted by number).

    A vehicle counts once per cross-section it passed (prev_pos < x <= pos), whatever lane it
    is in: the number SUMO's loops report as nVehContrib, without counting vehicles that merely
    change lanes onto a loop. Vehicles missing from either table are not counted.
    """
    if len(prev_nums) == 0 or len(nums) == 0 or len(sections_m) == 0:
        return 0
    idx = np.minimum(np.searchsorted(prev_nums, nums), len(prev_nums) - 1)
    both = prev_nums[idx] == nums
    before = prev_pos[idx][both][:, None]
    after = pos[both][:, None]
    x = np.asarray(sections_m, dtype=np.float64)[None, :]
    return int(np.count_nonzero((before < x) & (x <= after)))


def flow_term(vehicles_counted: int, window_s: float, n_sections: int, lanes: int, cfg: RewardConfig) -> float:
    """q_t: vehicles counted by the loops over the window, as veh/h per cross-section, over the capacity.

    1.0 means the road carries lanes * capacity_veh_h_per_lane.
    """
    if window_s <= 0 or n_sections <= 0:
        return 0.0
    flow_veh_h = vehicles_counted / n_sections / window_s * 3600.0
    return flow_veh_h / (lanes * cfg.capacity_veh_h_per_lane)


def speed_term(speed_mps: np.ndarray, v_exp_mps: np.ndarray, cfg: RewardConfig) -> np.ndarray:
    """Eq. (5): r_v = w_v * (v - v_exp) / (v_max - v_min) per vehicle."""
    return cfg.w_speed * (speed_mps - v_exp_mps) / (cfg.v_max_mps - cfg.v_min_mps)


def reward_parts(
    speed_mps: np.ndarray, v_exp_mps: np.ndarray, lane_change_started: np.ndarray, q_t: float, cfg: RewardConfig
) -> RewardParts:
    """r_v = w_v * (v - v_exp) / (v_max - v_min); r_cl = -alpha on a started change; w_q * q_t."""
    r_v = speed_term(speed_mps, v_exp_mps, cfg)
    r_cl = np.where(lane_change_started, -cfg.alpha, 0.0)
    r_q = np.full(len(speed_mps), cfg.w_flow * q_t)
    return RewardParts(r_v.astype(np.float64), r_cl.astype(np.float64), r_q)


def followers_mean(
    occ_keys: np.ndarray, occ_value: np.ndarray, lane: np.ndarray, other_lane: np.ndarray, pos: np.ndarray,
    window_m: float,
) -> np.ndarray:
    """Per vehicle, the mean value of the vehicles behind it within window_m (m) in every lane it occupies (its
    own, and the second lane while it changes; -1: none); 0 where no vehicle is there.

    occ_keys, occ_value: a sorted occupancy's keys (physics.occupancy) and each entry's value. A vehicle behind in
    both lanes of a changer counts twice; the vehicle itself and one at exactly its position do not count.
    """
    if len(pos) == 0:
        return np.zeros(0)
    csum = np.concatenate([[0.0], np.cumsum(occ_value, dtype=np.float64)])
    total, count = np.zeros(len(pos)), np.zeros(len(pos))
    second = (other_lane >= 0) & (other_lane != lane)
    for lanes, use in ((lane, np.ones(len(pos), bool)), (other_lane, second)):
        hi_key = lane_key(lanes[use], pos[use])
        lo = np.searchsorted(occ_keys, hi_key - window_m, side="left")
        hi = np.searchsorted(occ_keys, hi_key, side="left")
        total[use] += csum[hi] - csum[lo]
        count[use] += hi - lo
    return np.divide(total, count, out=np.zeros(len(pos)), where=count > 0)
