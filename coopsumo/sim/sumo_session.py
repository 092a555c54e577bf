"""The one module that talks to SUMO: start, step, read the vehicle table, set speeds, change lanes.

It chooses the binding: libsumo (SUMO inside this process) for ordinary runs, TraCI to a
`sumo-gui` process for a live view; both have the same API, so the calls below serve both.
Only one session can be open per process (libsumo allows one).
"""

from __future__ import annotations

import operator
import subprocess
import tempfile
import time
from collections import deque
from dataclasses import dataclass
from itertools import chain
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from coopsumo.config import GuiConfig, OutputConfig, SimConfig
from coopsumo.errors import UsageError
from coopsumo.sim import fast, network
from coopsumo.sim import vehicle_table as vt
from coopsumo.sim.output_headers import OUTPUT_FILES, name_run_files_by_name
from coopsumo.sim.vehicle_table import TableCheck, VehicleTable

_open_sessions = 0
GUI_VIEW = "View #0"  # sumo-gui's first (and only) view
GUI_START_TIMEOUT_S = 60.0  # how long sumo-gui may take to open its TraCI port (s)
FCD_ATTRIBUTES = "id,x,y,angle,speed,lane"  # what plot_trajectories.py reads; x is the position on the road


def _libsumo():  # type: ignore[no-untyped-def]
    import libsumo  # imported lazily: importing coopsumo never starts or loads SUMO

    return libsumo


def sumo_binary(name: str) -> str:
    """Path of a SUMO binary (sumo, sumo-gui) shipped by the eclipse-sumo wheel."""
    import sumo  # the eclipse-sumo wheel; only its path is used

    path = Path(sumo.SUMO_HOME) / "bin" / name
    if not path.exists():
        raise FileNotFoundError(f"{name} not found at {path}; install eclipse-sumo")
    return str(path)


def gui_closed_errors() -> tuple[type[BaseException], ...]:
    """The errors TraCI raises when sumo-gui went away during a run (its window was closed)."""
    import traci

    return (traci.exceptions.FatalTraCIError, ConnectionError)


_NONE = np.zeros(0, np.int64)
_NONE.flags.writeable = False  # shared by every step without departures or arrivals


@dataclass(frozen=True)
class StepEvents:
    """What SUMO reports for one step."""

    departed: np.ndarray  # vehicle numbers inserted this step
    arrived: np.ndarray  # vehicle numbers that left the road this step
    collisions: int  # new collisions SUMO detected this step (0 unless cfg.sumo_collision_check)
    teleports: int  # vehicles SUMO started teleporting this step


class SumoSession:
    """Owns the SUMO process for one run; use as a context manager (closed on every exit path).

    `sumo_models=True` leaves SUMO's own car-following and lane-changing in charge. `outputs` adds
    SUMO's FCD and tripinfo files to run_dir; `gui` runs the same simulation in sumo-gui via TraCI.

    The vehicle table (table()): with SUMO's models, and in sumo-gui, every vehicle is read every step.
    Controlled vehicles move exactly as sent (coopsumo.sim.vehicle_table), so the table is read whole only
    every cfg.full_read_every_steps steps and on steps with a teleport; in between it is advanced from the
    speeds and lane changes sent, and only departures (their lane, position, speed) and arrivals are read.
    Every full read is compared with the advanced table (self.check); after one that is not exact, every
    step is read.
    """

    def __init__(
        self,
        cfg: SimConfig,
        run_dir: Path,
        sumo_models: bool = False,
        lc_params: dict[str, float] | None = None,
        outputs: OutputConfig | None = None,
        gui: GuiConfig | None = None,
    ):
        self.cfg = cfg
        self.run_dir = run_dir
        self.sumo_models = sumo_models
        self.lc_params = lc_params or {}
        self.outputs = outputs or OutputConfig()
        self.gui = gui
        self._ls: Any = None
        self._tc: Any = None  # the binding's constants module
        self._gui_proc: subprocess.Popen[bytes] | None = None
        self._ids = np.zeros(1024, dtype=object)  # SUMO id (str) by vehicle number, made once per vehicle
        self._speed_sent = np.full(1024, np.nan)  # by vehicle number: the speed last sent (m/s), which SUMO keeps
        self._switches: dict[int, tuple[list[int], list[int]]] = {}  # step -> (vehicles, lanes) of its lane switches
        self._switch_steps = vt.lane_switch_steps(cfg.control.t_change_s, cfg.control.dt_s)
        self._table = VehicleTable.empty()
        self.steps = 0
        """simulation steps done"""
        self.check = TableCheck()
        """what the full reads found against the advanced table (controlled runs)"""
        self.step_seconds = 0.0
        """wall time spent inside SUMO's simulationStep so far (s): SUMO's own share of a run"""
        road = cfg.road
        self._loop_ids = [network.loop_id(pos, lane) for pos in road.loop_positions_m() for lane in range(road.lanes)]

    def args(self) -> list[str]:
        """SUMO's command line for this run; writes the route and detector files into run_dir."""
        cfg = self.cfg
        net = network.build_net(cfg.road)
        routes = self.run_dir / "routes.rou.xml"
        detectors = self.run_dir / "detectors.add.xml"
        max_speed = cfg.demand.v_exp_max_kmh / 3.6
        routes.write_text(network.routes_xml(max_speed, cfg.control.car_length_m, lc_motivations=self.sumo_models))
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
            # SUMO keeps each vehicle's waiting intervals of the last N s for junction impatience (this road has no
            # junction; teleports and tripinfo use their own counts): 1 s instead of 100 s saves a standing queue's work
            "--waiting-time-memory", "1",
            # the controller brakes harder than the vehicle type's emergency deceleration whenever it must (tens of
            # times a step in a jam); SUMO would format a warning for each, then drop it (--no-warnings)
            "--emergencydecel.warning-threshold", "1e9",
            "--seed", str(cfg.seed),
            "--no-step-log", "true",
            "--no-warnings", "true",
            "--duration-log.disable", "true",
            *self._output_args(),
        ]  # fmt: skip

    def _output_args(self) -> list[str]:
        """SUMO's options for the FCD and tripinfo files (written into run_dir)."""
        out = self.outputs
        args = []
        if out.fcd_period_s > 0:
            args += ["--fcd-output", str(self.run_dir / "fcd.xml"), "--device.fcd.period", f"{out.fcd_period_s:g}",
                     "--fcd-output.attributes", FCD_ATTRIBUTES]  # fmt: skip
        if out.tripinfo:
            args += ["--tripinfo-output", str(self.run_dir / "tripinfo.xml")]
        return args

    def __enter__(self) -> SumoSession:
        global _open_sessions
        if _open_sessions:
            raise RuntimeError("a SUMO session is already open in this process (libsumo allows one)")
        if self.gui is None:
            ls = _libsumo()
            ls.start(self.args())
            self._ls, self._tc = ls, ls.constants
        else:
            self._ls, self._tc = self._start_gui(self.gui)
        _open_sessions += 1
        # setSpeed: with libsumo its compiled function itself, without the Python wrapper around it (TraCI: the wrapper)
        native = getattr(self._ls, "_libsumo", None)
        self._set_speed = getattr(native, "vehicle_setSpeed", None) or self._ls.vehicle.setSpeed
        self._collision_pairs: set[tuple[str, str]] = set()
        tc = self._tc
        self._row = operator.itemgetter(tc.VAR_LANE_INDEX, tc.VAR_LANEPOSITION, tc.VAR_SPEED)
        return self

    def _start_gui(self, gui: GuiConfig) -> tuple[Any, Any]:
        """Start sumo-gui with this run's command line and connect to it through TraCI.

        Raises UsageError with sumo-gui's first line of complaint when it cannot start (no display).
        """
        import traci
        from sumolib.miscutils import getFreeSocketPort

        port = getFreeSocketPort()
        width, height = gui.window_px
        cmd = [sumo_binary("sumo-gui"), *self.args()[1:], "--start", "true", "--quit-on-end", "true",
               "--window-size", f"{width},{height}", "--delay", f"{gui.delay_ms:g}",
               "--remote-port", str(port)]  # fmt: skip
        with tempfile.TemporaryFile() as log:
            proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=log)
            deadline = time.monotonic() + GUI_START_TIMEOUT_S
            while True:
                try:  # one try per call: traci's own retry loop prints to stdout
                    conn = traci.connect(port, numRetries=0, proc=proc)
                    break
                except (traci.exceptions.TraCIException, traci.exceptions.FatalTraCIError):
                    if proc.poll() is None and time.monotonic() < deadline:
                        time.sleep(0.1)
                        continue
                    proc.kill()
                    proc.wait()
                    log.seek(0)
                    lines = [ln.strip() for ln in log.read().decode(errors="replace").splitlines() if ln.strip()]
                    reason = lines[0] if lines else f"no TraCI connection within {GUI_START_TIMEOUT_S:g} s"
                    raise UsageError(f"sumo-gui could not start: {reason}") from None
        self._gui_proc = proc
        return conn, traci.constants

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def close(self) -> None:
        global _open_sessions
        if self._ls is None:
            return
        ls, self._ls = self._ls, None
        _open_sessions -= 1
        if self._gui_proc is None:
            ls.close()
            self._name_files()
            return
        proc, self._gui_proc = self._gui_proc, None
        try:
            ls.close()  # sumo-gui ends the simulation, writes its files and quits (--quit-on-end)
        except gui_closed_errors():
            pass  # the window was closed already: nothing left to tell it
        finally:
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        self._name_files()

    def _name_files(self) -> None:
        """SUMO has closed its output files: their headers name the run's files by name (name_run_files_by_name)."""
        for name in OUTPUT_FILES:
            name_run_files_by_name(self.run_dir / name, self.run_dir)

    @property
    def ls(self):  # type: ignore[no-untyped-def]
        if self._ls is None:
            raise RuntimeError("SUMO session is not open")
        return self._ls

    def loop_last_interval(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every E1 loop's last completed period (road.loop_period_s): vehicles counted, occupancy (%) and mean
        speed (m/s; -1 where none was counted), as SUMO reports them (inductionloop.getLastInterval*)."""
        il = self.ls.inductionloop
        ids = self._loop_ids
        counts = np.array([il.getLastIntervalVehicleNumber(i) for i in ids], np.float64)
        occupancy = np.array([il.getLastIntervalOccupancy(i) for i in ids], np.float64)
        speed = np.array([il.getLastIntervalMeanSpeed(i) for i in ids], np.float64)
        return counts, occupancy, speed

    def add_vehicle(self, num: int, lane: int, v_exp_mps: float) -> None:
        """Ask SUMO to insert a vehicle now at the road's start, at its expected speed if safe."""
        ls = self.ls
        vid = self._id(num)
        ls.vehicle.add(vid, network.ROUTE_ID, typeID=network.VTYPE_ID, depart="now", departLane=str(lane),
                       departPos="base", departSpeed="max")  # fmt: skip
        ls.vehicle.setMaxSpeed(vid, float(v_exp_mps))

    def _id(self, num: int) -> str:
        """SUMO's id of vehicle `num` (its number as text), remembered for the per-step calls."""
        if num >= len(self._ids):
            more = max(num + 1, 2 * len(self._ids)) - len(self._ids)
            self._ids = np.concatenate([self._ids, np.zeros(more, object)])
            self._speed_sent = np.concatenate([self._speed_sent, np.full(more, np.nan)])
        vid = str(num)
        self._ids[num] = vid
        return vid

    def _take_control(self, vid: str) -> None:
        ls = self.ls
        if self.sumo_models:
            for key, value in self.lc_params.items():
                ls.vehicle.setParameter(vid, f"laneChangeModel.{key}", f"{value:g}")
        else:
            ls.vehicle.setSpeedMode(vid, 0)  # no SUMO safety checks: the Newell controller rules
            ls.vehicle.setLaneChangeMode(vid, 0)  # no SUMO lane changes: only the controller's requests
        if self.gui is not None:  # over TraCI one subscription read beats three calls per vehicle
            tc = self._tc
            ls.vehicle.subscribe(vid, [tc.VAR_LANE_INDEX, tc.VAR_LANEPOSITION, tc.VAR_SPEED])

    def step(self) -> StepEvents:
        """Advance SUMO by one step, then the vehicle table."""
        ls = self.ls
        start = time.perf_counter()
        ls.simulationStep()
        self.step_seconds += time.perf_counter() - start
        self.steps += 1
        departed = ls.simulation.getDepartedIDList()
        for vid in departed:
            self._take_control(vid)
        arrived = ls.simulation.getArrivedIDList()
        new_collisions = 0
        if self.cfg.sumo_collision_check:  # with --collision.action none SUMO reports none
            pairs = {(c.collider, c.victim) for c in ls.simulation.getCollisions()}
            new_collisions = len(pairs - self._collision_pairs)
            self._collision_pairs |= pairs
        teleports = ls.simulation.getStartingTeleportNumber()
        arrived_nums = np.array(list(map(int, arrived)), dtype=np.int64) if arrived else _NONE
        self._update_table(departed, arrived_nums, teleports > 0 or ls.simulation.getEndingTeleportNumber() > 0)
        return StepEvents(
            departed=np.array(list(map(int, departed)), dtype=np.int64) if departed else _NONE,
            arrived=arrived_nums,
            collisions=new_collisions,
            teleports=teleports,
        )

    def _update_table(self, departed: tuple[str, ...], arrived: np.ndarray, teleported: bool) -> None:
        """The table after this step: read whole, or advanced from what was sent (see the class)."""
        switch = self._switches.pop(self.steps, None)
        if self.sumo_models:  # SUMO decides the speeds and lane changes: nothing to advance
            self._table = self._read_all()
            return
        advanced = self._advanced(departed, arrived, switch)
        every = 1 if self.gui is not None or self.check.mismatch_step >= 0 else self.cfg.full_read_every_steps
        if advanced is not None and not teleported and self.steps % every:
            self._table = advanced
            return
        self._table = self._read_all()
        if advanced is not None:
            self.check.record(vt.deviation(advanced, self._table), self.steps)

    def _advanced(
        self, departed: tuple[str, ...], arrived: np.ndarray, switch: tuple[list[int], list[int]] | None
    ) -> VehicleTable | None:
        """The last table advanced by one step from the speeds and lane changes sent, without the arrived
        vehicles, with the departed ones as read; None when a vehicle on the road was never sent a speed."""
        prev = self._table
        switch_to = vt.switch_rows(prev.nums, *switch) if switch is not None else np.full(len(prev.nums), -1)
        # World.apply sends every vehicle a speed; a caller that did not gets a full read (None)
        table = fast.advanced_table(prev, self._speed_sent, switch_to, arrived, self.cfg.control.dt_s)
        if table is None:
            return None
        return vt.add(table, self._read(departed)) if departed else table

    def _read(self, ids: tuple[str, ...]) -> VehicleTable:
        return read_vehicles(self.ls.vehicle, ids)

    def _read_all(self) -> VehicleTable:
        """Every vehicle's lane, position and speed from SUMO (sumo-gui: from the subscriptions)."""
        if self.gui is None:
            return self._read(self.ls.vehicle.getIDList())
        results = self.ls.vehicle.getAllSubscriptionResults()
        if not results:
            return VehicleTable.empty()
        n = len(results)
        nums = np.fromiter(map(int, results), np.int64, count=n)
        values = np.fromiter(chain.from_iterable(map(self._row, results.values())), np.float64, count=3 * n)
        values = values.reshape(n, 3)
        return vt.sorted_table(nums, values[:, 0].astype(np.int64), values[:, 1], values[:, 2])

    def table(self) -> VehicleTable:
        """The vehicle table after the last step, sorted by number."""
        return self._table

    def set_speeds(self, nums: np.ndarray, speeds: np.ndarray) -> None:
        """Speeds (m/s) for the next step (one libsumo call per vehicle, without a Python loop); SUMO keeps them."""
        deque(map(self._set_speed, self._ids[nums], speeds.tolist()), maxlen=0)
        self._speed_sent[nums] = speeds

    def speeds_sent(self, nums: np.ndarray) -> np.ndarray:
        """The speed (m/s) last sent to each of `nums`, which SUMO keeps; NaN where none is in force."""
        return self._speed_sent[nums]

    def speeds_sent_all(self) -> np.ndarray:
        """speeds_sent of every vehicle number, indexed by it (the session's own array: read it, do not write)."""
        return self._speed_sent

    def release_speeds(self, nums: np.ndarray) -> None:
        """Hand speed control back to SUMO's car-following model."""
        deque(map(self.ls.vehicle.setSpeed, self._ids[nums], [-1.0] * len(nums)), maxlen=0)
        self._speed_sent[nums] = np.nan

    def change_lanes(self, nums: np.ndarray, target_lanes: np.ndarray) -> None:
        """Start lane changes; SUMO moves each vehicle sideways over --lanechange.duration (its lane index
        switches half-way, vehicle_table.lane_switch_steps after the request)."""
        change = self.ls.vehicle.changeLane
        lanes = target_lanes.tolist()
        for vid, lane in zip(self._ids[nums], lanes, strict=True):
            change(vid, lane, self.cfg.control.dt_s)
        if lanes:
            switch = self._switches.setdefault(self.steps + self._switch_steps, ([], []))
            switch[0].extend(nums.tolist())
            switch[1].extend(lanes)

    # -- sumo-gui only: what the view shows; none of it changes the simulation --------------------
    def show_region(self, x_min_m: float, x_max_m: float) -> None:
        """Zoom sumo-gui's view on the road between x_min_m and x_max_m (m), the whole road width,
        drawn with sumo-gui's "real world" scheme (car shapes, lane markings; vehicles keep set colours)."""
        half = self.cfg.road.lanes * self.cfg.road.lane_width_m / 2 + 2.0
        self.ls.gui.setSchema(GUI_VIEW, "real world")
        self.ls.gui.setBoundary(GUI_VIEW, x_min_m, -half, x_max_m, half)

    def mark_line(self, poly_id: str, x_m: float, rgba: tuple[int, int, int, int]) -> None:
        """Draw (or recolour) a bar across every lane at x_m (m) in sumo-gui."""
        ls = self.ls
        if poly_id in ls.polygon.getIDList():
            ls.polygon.setColor(poly_id, rgba)
            return
        half = self.cfg.road.lanes * self.cfg.road.lane_width_m / 2 + 1.0
        shape = [(x_m, -half), (x_m + 1.5, -half), (x_m + 1.5, half), (x_m, half)]
        ls.polygon.add(poly_id, shape, rgba, fill=True, polygonType="accident", layer=10)

    def set_colors(self, nums: np.ndarray, rgba: np.ndarray) -> None:
        """Vehicle colours in sumo-gui; rgba is (n, 4) of 0-255."""
        set_color = self.ls.vehicle.setColor
        for vid, color in zip(self._ids[nums], rgba.tolist(), strict=True):
            set_color(vid, tuple(color))

    def screenshot(self, path: Path, size_px: tuple[int, int]) -> None:
        """sumo-gui saves its view, size_px (width, height) pixels, to path (PNG) when the next step is drawn."""
        self.ls.gui.screenshot(GUI_VIEW, str(path), *size_px)


def read_vehicles(vehicle: Any, ids: tuple[str, ...]) -> VehicleTable:
    """Lane, position and speed of the vehicles `ids` (three libsumo calls each; cheaper than subscriptions,
    which SUMO fills every step), sorted by number. vehicle: the binding's vehicle module."""
    n = len(ids)
    return vt.sorted_table(np.fromiter(map(int, ids), np.int64, count=n),
                           np.fromiter(map(vehicle.getLaneIndex, ids), np.int64, count=n),
                           np.fromiter(map(vehicle.getLanePosition, ids), np.float64, count=n),
                           np.fromiter(map(vehicle.getSpeed, ids), np.float64, count=n))  # fmt: skip


def plain_run(
    cfg: SimConfig,
    run_dir: Path,
    departures: list[tuple[float, int, float]],
    block_from_s: float | None,
    read_table: bool = False,
) -> tuple[float, float]:
    """SUMO alone, for `make bench`: SUMO's own models, nothing called per vehicle.

    departures: (time s, lane, expected speed m/s) of every vehicle, sorted by time, as a route file (the
    expected speed as the vehicle's speedFactor). block_from_s: from then on every lane is blocked at the
    accident's position by a standing vehicle, numbered after the departures (None: free flow). read_table:
    also read every vehicle's lane, position and speed every step, as a full read of SumoSession does.
    Runs cfg.steps steps; returns (wall seconds of the stepping loop, mean vehicles on the road).
    """
    if _open_sessions:
        raise RuntimeError("a SUMO session is already open in this process (libsumo allows one)")
    session = SumoSession(cfg, run_dir, sumo_models=True)
    args = session.args()
    limit = cfg.road.speed_limit_mps
    x = cfg.accident.x_m
    rows = [(t, f'    <vehicle id="{k}" type="{network.VTYPE_ID}" route="{network.ROUTE_ID}" depart="{t:.2f}" '
                f'departLane="{lane}" departPos="base" departSpeed="max" speedFactor="{v / limit:.6f}"/>')
            for k, (t, lane, v) in enumerate(departures)]  # fmt: skip
    if block_from_s is not None:
        rows += [(block_from_s, f'    <vehicle id="{len(departures) + lane}" type="{network.VTYPE_ID}" '
                  f'route="{network.ROUTE_ID}" '
                  f'depart="{block_from_s:.2f}" departLane="{lane}" departPos="{x:.2f}" departSpeed="0">'
                  f'<stop lane="{network.EDGE_ID}_{lane}" startPos="{x:.2f}" endPos="{x + 5:.2f}" duration="1e7"/>'
                  "</vehicle>") for lane in range(cfg.road.lanes)]  # fmt: skip
    extra = run_dir / "plain.rou.xml"
    extra.write_text("<routes>\n" + "\n".join(row for _, row in sorted(rows, key=lambda r: r[0])) + "\n</routes>\n")
    args[args.index("--route-files") + 1] += f",{extra}"
    ls = _libsumo()
    ls.start(args)
    try:
        on_road = 0
        block_step = round(block_from_s / cfg.control.dt_s) if block_from_s is not None else cfg.steps + 1
        start = time.perf_counter()
        for step in range(cfg.steps):
            ls.simulationStep()
            if read_table:
                read_vehicles(ls.vehicle, ls.vehicle.getIDList())
            on_road += ls.vehicle.getIDCount() - (cfg.road.lanes if step >= block_step else 0)  # not the blockers
        wall = time.perf_counter() - start
    finally:
        ls.close()
    session._name_files()
    return wall, on_road / max(cfg.steps, 1)
