"""The accident bottleneck of scenario I as pure array functions: who is held, and the obstacle they see.

A vehicle entering the ZONE_M before the bottleneck is drawn once: held with the stuck ratio p (which decays
from 1 to 0 over the accident window, config.AccidentConfig.hold_probability), else released for good. A held
vehicle sees a standing obstacle at the bottleneck, so the Newell model and eq. (11) stop it there; once it
stands at the head of its queue it is drawn again every redraw_s. No SUMO.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from coopsumo.config import AccidentConfig

UNDECIDED, HELD, RELEASED = 0, 1, 2
ZONE_M = 100.0  # vehicles within this distance upstream of the bottleneck are drawn (m)
STANDING_MPS = 0.1  # a held vehicle slower than this (m/s) is standing at the bottleneck


class HoldDraw(NamedTuple):
    """A step's draw for the accident: the stuck ratio p, one uniform number per vehicle (empty when p <= 0), and
    whether held vehicles at the head of their queue are drawn again on this step."""

    p: float
    u: np.ndarray
    redraw: bool


def hold_draw(step_count: int, acc: AccidentConfig, dt_s: float, rng: np.random.Generator, n: int) -> HoldDraw:
    """The draw of step step_count for n vehicles: one uniform number each from rng when p > 0 (none otherwise)."""
    p = acc.hold_probability(step_count)
    u = rng.random(n) if p > 0.0 else np.zeros(0)
    return HoldDraw(p, u, step_count % max(1, round(acc.redraw_s / dt_s)) == 0)


def hold_and_obstacle(
    state: np.ndarray,
    pos_m: np.ndarray,
    speed_mps: np.ndarray,
    gap_m: np.ndarray,
    v_lead_mps: np.ndarray,
    step_count: int,
    acc: AccidentConfig,
    dt_s: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """held(...) with the draw of step step_count (hold_draw)."""
    return held(state, pos_m, speed_mps, gap_m, v_lead_mps, hold_draw(step_count, acc, dt_s, rng, len(state)), acc)


def held(
    state: np.ndarray,
    pos_m: np.ndarray,
    speed_mps: np.ndarray,
    gap_m: np.ndarray,
    v_lead_mps: np.ndarray,
    draw: HoldDraw,
    acc: AccidentConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(new hold state, gap m, leader speed m/s) of vehicles whose state, position, speed and nearest leader are given.

    Held vehicles get the obstacle at acc.x_m as their leader when it is nearer than their leader. A vehicle is
    drawn on entering the zone, and a held one again every redraw_s only once it stands at the head of its queue,
    so a vehicle reaching the bottleneck is held with probability p, not p to the power of its redraws.
    """
    p = draw.p
    if p <= 0.0:
        return np.where(state == HELD, RELEASED, state).astype(state.dtype), gap_m, v_lead_mps
    in_zone = (pos_m >= acc.x_m - ZONE_M) & (pos_m < acc.x_m)
    obstacle_gap = acc.x_m - pos_m
    at_head = (obstacle_gap < gap_m) & (speed_mps < STANDING_MPS)
    redraw = (state == HELD) & at_head & draw.redraw
    draw_now = in_zone & ((state == UNDECIDED) | redraw)
    u = draw.u
    new = state.copy()
    new[draw_now] = np.where(u[draw_now] < p, HELD, RELEASED)
    closer = (new == HELD) & (obstacle_gap < gap_m)
    return new, np.where(closer, obstacle_gap, gap_m), np.where(closer, 0.0, v_lead_mps)
