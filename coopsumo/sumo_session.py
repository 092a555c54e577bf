"""The one module that talks to libsumo: start, step, read the vehicle table, set speeds, change lanes.

libsumo runs SUMO inside this process, so only one session can be open per process.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

import numpy as np

from coopsumo import network
from coopsumo.config import SimConfig

_open_sessions = 0


def _libsumo():  # type: ignore[no-untyped-def]
    import libsumo  # imported lazily: importing coopsumo never starts or loads SUMO

    return libsumo


@dataclass(frozen=True)
class VehicleTable:
    """All vehicles on the road after a step; arrays share one order."""

    nums: np.ndarray  # (n,) int64 vehicle numbers (SUMO id is str(num))
    lane: np.ndarray  # (n,) int64 SUMO lane index, 0 = rightmost
    pos: np.ndarray  # (n,) float64 front-bumper position along the road (m)
    speed: np.ndarray  # (n,) float64 (m/s)


@dataclass(frozen=True)
class StepEvents:
    """What SUMO reports for one step."""

    departed: np.ndarray  # vehicle numbers inserted this step
    arrived: np.ndarray  # vehicle numbers that left the road this step
    collisions: int  # new collisions SUMO detected this step (0 unless cfg.sumo_collision_check)
    teleports: int  # vehicles SUMO started teleporting this step


class SumoSession:
    """Owns the SUMO process for one run; use as a context manager (closed on every exit path).

    `sumo_models=True` leaves SUMO's own car-following and lane-changing in charge.
    """

    def __init__(
        self, cfg: SimConfig, run_dir: Path, sumo_models: bool = False, lc_params: dict[str, float] | None = None
    ):
        self.cfg = cfg
        self.run_dir = run_dir
        self.sumo_models = sumo_models
        self.lc_params = lc_params or {}
        self._ls = None

    def args(self) -> list[str]:
        """SUMO's command line for this run; writes the route and detector files into run_dir."""
        cfg = self.cfg
        net = network.build_net(cfg.road)
        routes = self.run_dir / "routes.rou.xml"
        detectors = self.run_dir / "detectors.add.xml"
        max_speed = cfg.demand.v_exp_max_kmh / 3.6
        routes.write_text(network.routes_xml(max_speed, cfg.control.car_length_m))
        detectors.write_text(network.detectors_xml(cfg.road, "detectors.xml"))
        return [
            "sumo",
            "--net-file", str(net),
            "--route-files", str(routes),
            "--additional-files", str(detectors),
            "--step-length", f"{cfg.control.dt_s:g}",
            "--lanechange.duration", f"{cfg.control.t_change_s:g}",
            "--collision.action", "warn" if cfg.sumo_collision_check else "none",
            "--collision.mingap-factor", "0",
            "--time-to-teleport", f"{cfg.time_to_teleport_s:g}",
            "--seed", str(cfg.seed),
            "--no-step-log", "true",
            "--no-warnings", "true",
            "--duration-log.disable", "true",
        ]  # fmt: skip

    def __enter__(self) -> SumoSession:
        global _open_sessions
        if _open_sessions:
            raise RuntimeError("a SUMO session is already open in this process (libsumo allows one)")
        ls = _libsumo()
        ls.start(self.args())
        _open_sessions += 1
        self._ls = ls
        self._collision_pairs: set[tuple[str, str]] = set()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def close(self) -> None:
        global _open_sessions
        if self._ls is not None:
            self._ls.close()
            self._ls = None
            _open_sessions -= 1

    @property
    def ls(self):  # type: ignore[no-untyped-def]
        if self._ls is None:
            raise RuntimeError("SUMO session is not open")
        return self._ls

    def add_vehicle(self, num: int, lane: int, v_exp_mps: float) -> None:
        """Ask SUMO to insert a vehicle now at the road's start, at its expected speed if safe."""
        ls = self.ls
        vid = str(num)
        ls.vehicle.add(vid, network.ROUTE_ID, typeID=network.VTYPE_ID, depart="now", departLane=str(lane),
                       departPos="base", departSpeed="max")  # fmt: skip
        ls.vehicle.setMaxSpeed(vid, float(v_exp_mps))

    def _take_control(self, vid: str) -> None:
        ls = self.ls
        if self.sumo_models:
            for key, value in self.lc_params.items():
                ls.vehicle.setParameter(vid, f"laneChangeModel.{key}", f"{value:g}")
        else:
            ls.vehicle.setSpeedMode(vid, 0)  # no SUMO safety checks: the Newell controller rules
            ls.vehicle.setLaneChangeMode(vid, 0)  # no SUMO lane changes: only the controller's requests
        tc = ls.constants
        ls.vehicle.subscribe(vid, [tc.VAR_LANE_INDEX, tc.VAR_LANEPOSITION, tc.VAR_SPEED])

    def step(self) -> StepEvents:
        """Advance SUMO by one step."""
        ls = self.ls
        ls.simulationStep()
        departed = ls.simulation.getDepartedIDList()
        for vid in departed:
            self._take_control(vid)
        arrived = ls.simulation.getArrivedIDList()
        new_collisions = 0
        if self.cfg.sumo_collision_check:  # with --collision.action none SUMO reports none
            pairs = {(c.collider, c.victim) for c in ls.simulation.getCollisions()}
            new_collisions = len(pairs - self._collision_pairs)
            self._collision_pairs |= pairs
        return StepEvents(
            departed=np.array([int(v) for v in departed], dtype=np.int64),
            arrived=np.array([int(v) for v in arrived], dtype=np.int64),
            collisions=new_collisions,
            teleports=ls.simulation.getStartingTeleportNumber(),
        )

    def table(self) -> VehicleTable:
        """The vehicle table from the subscriptions (one read for all vehicles)."""
        tc = self.ls.constants
        results = self.ls.vehicle.getAllSubscriptionResults()
        n = len(results)
        nums = np.empty(n, np.int64)
        lane = np.empty(n, np.int64)
        pos = np.empty(n)
        speed = np.empty(n)
        for i, (vid, values) in enumerate(results.items()):
            nums[i] = int(vid)
            lane[i] = values[tc.VAR_LANE_INDEX]
            pos[i] = values[tc.VAR_LANEPOSITION]
            speed[i] = values[tc.VAR_SPEED]
        order = np.argsort(nums)
        return VehicleTable(nums[order], lane[order], pos[order], speed[order])

    def set_speeds(self, nums: np.ndarray, speeds: np.ndarray) -> None:
        """Speeds (m/s) for the next step."""
        set_speed = self.ls.vehicle.setSpeed
        for num, v in zip(nums.tolist(), speeds.tolist(), strict=True):
            set_speed(str(num), v)

    def release_speeds(self, nums: np.ndarray) -> None:
        """Hand speed control back to SUMO's car-following model."""
        set_speed = self.ls.vehicle.setSpeed
        for num in nums.tolist():
            set_speed(str(num), -1.0)

    def change_lanes(self, nums: np.ndarray, target_lanes: np.ndarray) -> None:
        """Start lane changes; SUMO moves each vehicle sideways over --lanechange.duration."""
        change = self.ls.vehicle.changeLane
        for num, lane in zip(nums.tolist(), target_lanes.tolist(), strict=True):
            change(str(num), lane, self.cfg.control.dt_s)
