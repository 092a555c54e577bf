"""The vehicle table and how it moves between two reads from SUMO, as pure array functions. No SUMO.

In speed mode 0 SUMO moves a controlled vehicle at exactly the speed it was last sent (Euler: the lane
position grows by speed x step), and a lane change of `--lanechange.duration` switches the lane index
when the manoeuvre is half done. So between two full reads the table can be advanced from what the
controller sent; only departures, arrivals and teleports (SUMO's decisions) must be read.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class VehicleTable:
    """All vehicles on the road after a step, sorted by number; arrays share one order."""

    nums: np.ndarray  # (n,) int64 vehicle numbers (SUMO id is str(num))
    lane: np.ndarray  # (n,) int64 SUMO lane index, 0 = rightmost
    pos: np.ndarray  # (n,) float64 front-bumper position along the road (m)
    speed: np.ndarray  # (n,) float64 (m/s)

    @staticmethod
    def empty() -> VehicleTable:
        return VehicleTable(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0))


@dataclass(frozen=True)
class Deviation:
    """How far an advanced table is from SUMO's (one full read)."""

    pos_m: float  # largest |position difference| (m) of the vehicles in both
    speed_mps: float  # largest |speed difference| (m/s)
    lanes: int  # vehicles whose lane index differs
    membership: int  # vehicles in one table and not the other

    def exact(self, tol: float = 1e-9) -> bool:
        """Both tables hold the same vehicles in the same lanes, positions and speeds within tol (m, m/s)."""
        return self.membership == 0 and self.lanes == 0 and self.pos_m <= tol and self.speed_mps <= tol


@dataclass
class TableCheck:
    """What the full reads of a run found against the advanced table."""

    max_dev_pos_m: float = 0.0  # largest position deviation seen (m)
    max_dev_speed_mps: float = 0.0  # largest speed deviation seen (m/s)
    lanes_off: int = 0  # vehicles found in another lane, summed over the full reads
    membership_off: int = 0  # vehicles found in one table and not the other, summed over the full reads
    full_reads: int = 0  # full reads compared
    mismatch_step: int = -1  # first step whose full read was not exact (-1: none); every step is read from then on

    def record(self, dev: Deviation, step: int) -> None:
        self.max_dev_pos_m = max(self.max_dev_pos_m, dev.pos_m)
        self.max_dev_speed_mps = max(self.max_dev_speed_mps, dev.speed_mps)
        self.lanes_off += dev.lanes
        self.membership_off += dev.membership
        self.full_reads += 1
        if self.mismatch_step < 0 and not dev.exact():
            self.mismatch_step = step


def lane_switch_steps(t_change_s: float, dt_s: float) -> int:
    """Steps from a lane-change request to the step whose table shows the target lane (SUMO switches the
    index when the manoeuvre passes its midpoint; measured: 20 steps for 4 s at 0.1 s)."""
    return max(1, math.ceil(t_change_s / dt_s / 2 - 1e-9))


def advance(table: VehicleTable, speed_mps: np.ndarray, switch_to: np.ndarray, dt_s: float) -> VehicleTable:
    """The table one step later: every vehicle drove at its commanded speed_mps (m/s, per row) for dt_s (s);
    rows with switch_to >= 0 are now in that lane."""
    lane = np.where(switch_to >= 0, switch_to, table.lane)
    return VehicleTable(table.nums, lane, table.pos + speed_mps * dt_s, speed_mps.astype(np.float64, copy=True))


def switch_rows(on_road: np.ndarray, nums: list[int], lanes: list[int]) -> np.ndarray:
    """Per row of a table of the vehicles `on_road` (sorted numbers): the lane it switches to, -1 for none;
    switches of vehicles no longer on the road are ignored."""
    switch_to = np.full(len(on_road), -1, np.int64)
    if len(on_road) == 0:
        return switch_to
    nums_a, lanes_a = np.array(nums, np.int64), np.array(lanes, np.int64)
    rows = np.minimum(np.searchsorted(on_road, nums_a), len(on_road) - 1)
    there = on_road[rows] == nums_a
    switch_to[rows[there]] = lanes_a[there]
    return switch_to


def drop(table: VehicleTable, nums: np.ndarray) -> VehicleTable:
    """The table without the vehicles `nums` (those not in it are ignored)."""
    if len(nums) == 0 or len(table.nums) == 0:
        return table
    keep = ~np.isin(table.nums, nums)
    return VehicleTable(table.nums[keep], table.lane[keep], table.pos[keep], table.speed[keep])


def add(table: VehicleTable, rows: VehicleTable) -> VehicleTable:
    """The table with `rows` (vehicles not yet in it) added, sorted by number."""
    if len(rows.nums) == 0:
        return table
    nums = np.concatenate([table.nums, rows.nums])
    order = np.argsort(nums, kind="stable")
    return VehicleTable(nums[order], np.concatenate([table.lane, rows.lane])[order],
                        np.concatenate([table.pos, rows.pos])[order],
                        np.concatenate([table.speed, rows.speed])[order])  # fmt: skip


def sorted_table(nums: np.ndarray, lane: np.ndarray, pos: np.ndarray, speed: np.ndarray) -> VehicleTable:
    """A table of rows in any order, sorted by vehicle number."""
    order = np.argsort(nums)
    return VehicleTable(nums[order], lane[order].astype(np.int64), pos[order], speed[order])


def deviation(advanced: VehicleTable, read: VehicleTable) -> Deviation:
    """Compare a table advanced by `advance` with SUMO's own (both sorted by number)."""
    both, i, j = np.intersect1d(advanced.nums, read.nums, assume_unique=True, return_indices=True)
    membership = len(advanced.nums) + len(read.nums) - 2 * len(both)
    if len(both) == 0:
        return Deviation(0.0, 0.0, 0, membership)
    return Deviation(
        pos_m=float(np.max(np.abs(advanced.pos[i] - read.pos[j]))),
        speed_mps=float(np.max(np.abs(advanced.speed[i] - read.speed[j]))),
        lanes=int(np.count_nonzero(advanced.lane[i] != read.lane[j])),
        membership=membership,
    )


def advanced_table(
    table: VehicleTable, sent_mps: np.ndarray, switch_to: np.ndarray, arrived: np.ndarray, dt_s: float
) -> VehicleTable | None:
    """The table one step later (advance) without the arrived vehicles (drop); sent_mps: the speed last sent to
    each vehicle number (m/s). None when a vehicle of the table was never sent one (NaN)."""
    speed = sent_mps[table.nums]
    if np.isnan(speed).any():
        return None
    return drop(advance(table, speed, switch_to, dt_s), arrived)
