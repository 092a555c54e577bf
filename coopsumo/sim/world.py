"""The highway world: demand, the controller loop around SUMO, the accident, and run statistics.

One step: observe every vehicle (grids, neighbours) -> a policy's actions -> lane-change safety
-> Newell speed + collision check -> SUMO moves everyone -> rewards for the observed vehicles.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

import numpy as np

from coopsumo.config import (
    ACCIDENT_STREAM,
    DEMAND_STREAM,
    DemandConfig,
    GuiConfig,
    OutputConfig,
    RoadConfig,
    SimConfig,
    rng_stream,
)
from coopsumo.sim import accident, controller, fast, physics, view
from coopsumo.sim.accident import HELD
from coopsumo.sim.observation import N_CELLS, N_FRAMES, N_SIDES, FrameHistory, Observation
from coopsumo.sim.passing import PASSING_EVERY_S, PassingCount
from coopsumo.sim.reward import RewardParts, flow_term, reward_parts, speed_term
from coopsumo.sim.sumo_session import StepEvents, SumoSession
from coopsumo.sim.vehicle_table import VehicleTable

GUI_SHOT = ".gui-screenshot.png"
"""where sumo-gui saves its screenshot, in the run's own folder; the run then places it at the path asked for, as a
new file only (agents/rollout.run; issue 82, probe 15, D1: written there directly, it replaced a file made there
while the run went)"""


@dataclass(frozen=True)
class StepOutcome:
    """What happened to the vehicles of the last observation."""

    nums: np.ndarray
    actions: np.ndarray
    lane_change_started: np.ndarray  # bool
    rejected: np.ndarray  # bool: a change was asked for and refused
    arrived: np.ndarray  # bool: left the road during the step
    reward: RewardParts
    q_t: float


_Step = tuple[Observation, np.ndarray, StepEvents, np.ndarray, np.ndarray, np.ndarray]
"""what a step did: the observation, the actions, SUMO's events, the speeds sent (m/s), changes started, refused"""


@dataclass
class Totals:
    """Running counts for the summary."""

    departed: int = 0
    arrived: int = 0
    insertion_blocked: int = 0
    collisions: int = 0
    sumo_collisions: int = 0
    teleports: int = 0
    lane_changes: int = 0
    lane_changes_rejected: int = 0
    distance_m: float = 0.0
    vehicle_time_s: float = 0.0
    travel_time_sum_s: float = 0.0


class _Growable:
    """Per-vehicle arrays indexed by vehicle number."""

    def __init__(self, capacity: int = 1024):
        self.v_exp = np.zeros(capacity)
        self.depart_s = np.full(capacity, np.nan)
        self.scheduled_s = np.full(capacity, np.nan)
        self.lc_left_s = np.zeros(capacity)
        self.lc_from = np.full(capacity, -1, np.int64)
        self.lc_to = np.full(capacity, -1, np.int64)
        self.hold = np.zeros(capacity, np.int8)
        self.commanded = np.zeros(capacity, bool)  # sumo mode: speed commanded by the accident
        self.shown = np.full(capacity, -1, np.int8)  # sumo-gui: the view state (view.vehicle_states) it is coloured by

    def ensure(self, n: int) -> None:
        cap = len(self.v_exp)
        if n <= cap:
            return
        new = max(n, 2 * cap)
        fills = (("v_exp", 0.0), ("depart_s", np.nan), ("scheduled_s", np.nan), ("lc_left_s", 0.0), ("lc_from", -1),
                 ("lc_to", -1), ("hold", 0), ("commanded", False), ("shown", -1))  # fmt: skip
        for name, fill in fills:
            old = getattr(self, name)
            setattr(self, name, np.concatenate([old, np.full(new - cap, fill, old.dtype)]))


def draw_vehicle(rng: np.random.Generator, demand: DemandConfig, road: RoadConfig) -> tuple[float, int]:
    """The next upstream vehicle's expected speed (m/s, clipped normal, at most the road's speed limit) and entry
    lane (uniform)."""
    v_kmh = np.clip(rng.normal(demand.v_exp_mean_kmh, demand.v_exp_std_kmh), demand.v_exp_min_kmh,
                    demand.v_exp_max_kmh)  # fmt: skip
    return min(float(v_kmh) / 3.6, road.speed_limit_mps), int(rng.integers(0, road.lanes))


def departures(cfg: SimConfig) -> list[tuple[float, int, float]]:
    """(time s, lane, expected speed m/s) of every vehicle scheduled during cfg's run, as World draws them."""
    rng = rng_stream(cfg.seed, DEMAND_STREAM)
    n = int(cfg.steps * cfg.control.dt_s / cfg.demand.t_up_s + 1e-9) + 1
    out = []
    for num in range(n):
        v, lane = draw_vehicle(rng, cfg.demand, cfg.road)
        out.append((num * cfg.demand.t_up_s, lane, v))
    return out


class World:
    """A running simulation. Use as a context manager; call observe() then apply(actions) each step."""

    def __init__(
        self,
        cfg: SimConfig,
        run_dir: Path,
        record_trajectories_every: int = 0,
        observe_grids: bool = True,
        outputs: OutputConfig | None = None,
        gui: GuiConfig | None = None,
    ):
        """observe_grids=False skips the occupancy grids (obs.grids and obs.speed_err are then zeros),
        for policies that do not read them; it saves about a sixth of a step.
        outputs: SUMO's FCD and tripinfo files; gui: run in sumo-gui, vehicles coloured by view.vehicle_states."""
        cfg.validate()
        outputs = outputs or OutputConfig()
        outputs.validate(cfg.control.dt_s)
        if gui is not None:
            gui.validate(cfg.steps)
        self.cfg = cfg
        self.run_dir = run_dir
        self.gui = gui
        lc_params = cfg.sumo_driver
        self.sumo_models = lc_params is not None
        self.session = SumoSession(cfg, run_dir, sumo_models=self.sumo_models, lc_params=lc_params,
                                   outputs=outputs, gui=gui)  # fmt: skip
        self._accident_marked: bool | None = None  # sumo-gui: whether the marker shows an active accident
        self.demand_rng = rng_stream(cfg.seed, DEMAND_STREAM)
        self.accident_rng = rng_stream(cfg.seed, ACCIDENT_STREAM)
        self.veh = _Growable()
        self.history = FrameHistory.empty()
        self.totals = Totals()
        self.step_count = 0
        self.next_num = 0
        self._waiting: list[deque[int]] = [deque() for _ in range(cfg.road.lanes)]  # per lane, not yet in SUMO
        self._handed = np.full(cfg.road.lanes, -1, np.int64)  # per lane: the vehicle SUMO is trying to insert
        self.table = VehicleTable.empty()
        window = max(1, round(cfg.reward.flow_window_s / cfg.control.dt_s))
        self._loop_counts: deque[int] = deque(maxlen=window)
        self._sections_m = np.array(cfg.road.loop_positions_m())
        self._n_sections = len(self._sections_m)
        self._obs: Observation | None = None
        self._sight: controller.Sight | None = None  # what the controller saw at the observation
        self.controls = controller.Controls(cfg.control, cfg.accident, cfg.road.lanes, cfg.road.lane_width_m)
        self._overlapping: set[tuple[int, int]] = set()  # (follower, leader) pairs already counted
        self.passing = PassingCount(max(1, round(PASSING_EVERY_S / cfg.control.dt_s)))
        self.observe_grids = observe_grids
        self.record_every = record_trajectories_every  # 0: no trajectories
        self._traj: list[tuple[np.ndarray, ...]] = []

    # -- lifecycle -------------------------------------------------------------------------
    def __enter__(self) -> World:
        self.session.__enter__()
        try:
            if self.gui is not None:
                self._set_up_view()
            self._insert_due()
        except BaseException:
            self.session.close()  # __exit__ is not called when __enter__ raises
            raise
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.session.close()

    # -- sumo-gui ----------------------------------------------------------------------------
    def _set_up_view(self) -> None:
        """Zoom on the bottleneck and mark it (accident scenario); the whole road otherwise."""
        acc = self.cfg.accident
        if acc.enabled:
            self.session.show_region(acc.x_m - view.VIEW_UPSTREAM_M, acc.x_m + view.VIEW_DOWNSTREAM_M)
            self._show_accident()
        else:
            self.session.show_region(0.0, self.cfg.road.length_m)

    def _show_accident(self) -> None:
        """Marker at the bottleneck: red while vehicles may be held there, grey otherwise."""
        active = self.cfg.accident.hold_probability(self.step_count) > 0
        if active != self._accident_marked:
            rgba = view.ACCIDENT_ACTIVE_RGBA if active else view.ACCIDENT_IDLE_RGBA
            self.session.mark_line("accident", self.cfg.accident.x_m, rgba)
            self._accident_marked = active

    def _show_states(self) -> None:
        """Colour every vehicle by what the controller does with it; only changed colours are sent."""
        t = self.table
        v = self.veh
        states = view.vehicle_states(t.speed, v.lc_left_s[t.nums] > 0, v.hold[t.nums] == HELD)
        changed = states != v.shown[t.nums]
        self.session.set_colors(t.nums[changed], view.STATE_RGBA[states[changed]])
        v.shown[t.nums[changed]] = states[changed]
        if self.cfg.accident.enabled:
            self._show_accident()

    @property
    def time_s(self) -> float:
        return self.step_count * self.cfg.control.dt_s

    @property
    def loop_period_steps(self) -> int:
        """Steps of one loop aggregation period (road.loop_period_s)."""
        return max(1, round(self.cfg.road.loop_period_s / self.cfg.control.dt_s))

    def loop_last_interval(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every E1 loop's last completed period: vehicles counted, occupancy (%), mean speed (m/s; -1: none)."""
        return self.session.loop_last_interval()

    # -- demand ----------------------------------------------------------------------------
    def _insert_due(self) -> None:
        """Queue every vehicle whose departure time (num * T_up) has come; hand SUMO each lane's next one.

        SUMO holds at most one waiting vehicle per lane (it retries every waiting vehicle every
        step, which gets slow behind a long queue); the rest wait here, in order, per lane.
        """
        d = self.cfg.demand
        t_up = d.t_up_s
        while self.next_num * t_up <= self.time_s + 1e-9:
            num = self.next_num
            self.veh.ensure(num + 1)
            self.veh.v_exp[num], lane = draw_vehicle(self.demand_rng, d, self.cfg.road)
            self.veh.scheduled_s[num] = num * t_up
            self._waiting[lane].append(num)
            self.next_num += 1
        for lane, queue in enumerate(self._waiting):
            if self._handed[lane] < 0 and queue:
                num = queue.popleft()
                self.session.add_vehicle(num, lane, float(self.veh.v_exp[num]))
                self._handed[lane] = num

    # -- one step --------------------------------------------------------------------------
    def _other_lane(self, nums: np.ndarray, lane: np.ndarray) -> np.ndarray:
        """The second lane a vehicle touches during a lane change (-1 when not changing)."""
        v = self.veh
        return controller.other_lane(lane, v.lc_from[nums], v.lc_to[nums], v.lc_left_s[nums])

    def observe(self, grids: bool | None = None) -> Observation:
        """Observation of every vehicle on the road now (call once per step, before apply).

        grids: build the occupancy grids and push them into the frame history (default: the
        world's observe_grids). Off, obs.grids and obs.speed_err are zeros and the history is
        left alone, so the 3 frames are those of the steps on which grids were asked for.
        """
        t = self.table
        c = self.cfg
        seen = self._sight = fast.sight(t.nums, t.lane, t.pos, t.speed, self.veh, self.controls)
        around = seen.around
        if self.observe_grids if grids is None else grids:
            grid = fast.snapshot(seen.occ, t.lane, t.pos, c.road.lanes, c.control.car_length_m)
            frames, speed_err = self.history.push(t.nums, grid, (t.speed - seen.v_exp).astype(np.float32))
        else:
            frames = np.zeros((len(t.nums), N_FRAMES, N_SIDES, N_CELLS), np.uint8)
            speed_err = np.zeros((len(t.nums), N_FRAMES), np.float32)
        self.passing.look(self.step_count, t.nums, t.speed, seen.v_exp, around, seen.feasible)
        self._obs = Observation(
            nums=t.nums, grids=frames, speed_err=speed_err, lane=t.lane, pos=t.pos, speed=t.speed,
            v_exp=seen.v_exp, busy=seen.busy, around=around, n_lanes=c.road.lanes, feasible=seen.feasible,
        )  # fmt: skip
        return self._obs

    def apply(self, actions: np.ndarray) -> StepOutcome:
        """Check and execute the actions of the last observation, step SUMO, return the outcome."""
        return self._outcome(*self._step(actions))

    def drive(self, actions: np.ndarray) -> None:
        """apply() without building the outcome (rewards and the flow term), for a run that needs only the world's
        outputs (summary, loops, FCD, tripinfo, trajectories), which are the same."""
        self._step(actions)

    def _step(self, actions: np.ndarray) -> _Step:
        """Check and execute the actions of the last observation, step SUMO, count the lane changes."""
        obs, seen = self._obs, self._sight
        if obs is None or seen is None:
            raise RuntimeError("apply() and drive() need an observe() first")
        self._obs = self._sight = None
        c = self.cfg.control
        n = len(obs)
        actions = np.asarray(actions, dtype=np.int64)
        if actions.shape != (n,):
            raise ValueError(f"expected {n} actions, got shape {actions.shape}")

        if self.sumo_models:
            return self._apply_sumo(obs, actions)

        # lane changes (asked, safe, no same-step conflict), the accident's obstacle, Newell speeds and eq. (11)
        draw = accident.hold_draw(self.step_count, self.cfg.accident, c.dt_s, self.accident_rng, n)
        d = fast.decide(obs.nums, obs.lane, obs.pos, obs.speed, seen, actions, self.veh, self.session.speeds_sent_all(),
                        draw, self.controls)  # fmt: skip
        movers = obs.nums[d.ok]
        self.passing.changed(movers)
        # SUMO keeps a set speed until told otherwise, so only changed speeds are sent
        self.session.set_speeds(obs.nums[d.changed], d.speeds[d.changed])
        self.session.change_lanes(movers, d.target[d.ok])
        events = self._advance()
        return self._counted(obs, actions, events, d.speeds, d.ok, d.rejected)

    def _counted(self, obs: Observation, actions: np.ndarray, events: StepEvents, speeds: np.ndarray, ok: np.ndarray,
                 rejected: np.ndarray) -> _Step:  # fmt: skip
        """The step's lane changes, started and refused, added to the run's totals; the step passed on."""
        self.totals.lane_changes += int(np.count_nonzero(ok))
        self.totals.lane_changes_rejected += int(np.count_nonzero(rejected))
        return obs, actions, events, speeds, ok, rejected

    def _apply_sumo(self, obs: Observation, actions: np.ndarray) -> _Step:
        """SUMO's own models drive; only vehicles held by the accident get a commanded speed."""
        c = self.cfg.control
        n = len(obs)
        gap, _ = self._accident_obstacle(obs, np.full(n, np.inf), np.zeros(n))
        held = np.isfinite(gap)
        speeds = physics.next_speed(obs.speed, obs.v_exp, np.ones(n, bool), gap, np.zeros(n), c)
        released = obs.nums[~held & self.veh.commanded[obs.nums]] if len(obs) else obs.nums
        self.session.set_speeds(obs.nums[held], speeds[held])
        self.session.release_speeds(released)
        self.veh.commanded[obs.nums] = held
        events = self._advance()
        row, still = self._rows_now(obs.nums)
        changed = still & (self.table.lane[row] != obs.lane)
        self.passing.changed(obs.nums[changed])
        return self._counted(obs, actions, events, obs.speed.copy(), changed, np.zeros(n, bool))

    def _rows_now(self, nums: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rows of `nums` in the current table, and whether each is still on the road."""
        on_road = self.table.nums
        if len(on_road) == 0:
            return np.zeros(len(nums), np.int64), np.zeros(len(nums), bool)
        row = np.minimum(np.searchsorted(on_road, nums), len(on_road) - 1)
        return row, on_road[row] == nums

    def _outcome(
        self,
        obs: Observation,
        actions: np.ndarray,
        events: StepEvents,
        speeds: np.ndarray,
        ok: np.ndarray,
        rejected: np.ndarray,
    ) -> StepOutcome:
        """The rewards of the observed vehicles after the step."""
        c = self.cfg.control
        q_t = flow_term(sum(self._loop_counts), len(self._loop_counts) * c.dt_s, self._n_sections,
                        self.cfg.road.lanes, self.cfg.reward)  # fmt: skip
        arrived = np.isin(obs.nums, events.arrived) if len(events.arrived) else np.zeros(len(obs.nums), bool)
        new_speed = speeds.copy()
        row, still = self._rows_now(obs.nums)
        still &= ~arrived
        new_speed[still] = self.table.speed[row[still]]
        reward = reward_parts(new_speed, obs.v_exp, ok, q_t, self.cfg.reward)
        return StepOutcome(obs.nums, actions, ok, rejected, arrived, reward, q_t)

    def followers_speed_reward(self, nums: np.ndarray, window_m: float) -> np.ndarray:
        """Now (after a step): for each vehicle of `nums`, the mean speed reward r_v of the vehicles behind it within
        window_m (m) in the lanes it occupies (reward.followers_mean, in C: fast.followers_mean); 0 for one that has
        left or has none behind."""
        t = self.table
        other = self._other_lane(t.nums, t.lane)
        occ = fast.occupancy(t.lane, t.pos, other)
        r_v = speed_term(t.speed, self.veh.v_exp[t.nums], self.cfg.reward)
        behind = fast.followers_mean(occ.keys, r_v[occ.veh], t.lane, other, t.pos, window_m)
        row, still = self._rows_now(nums)
        out = np.zeros(len(nums))
        out[still] = behind[row[still]]
        return out

    def _accident_obstacle(
        self, obs: Observation, gap: np.ndarray, v_lead: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Held vehicles see a standing obstacle at the bottleneck (coopsumo.sim.accident); updates their state."""
        hold = self.veh.hold
        hold[obs.nums], gap, v_lead = accident.hold_and_obstacle(
            hold[obs.nums], obs.pos, obs.speed, gap, v_lead, self.step_count, self.cfg.accident,
            self.cfg.control.dt_s, self.accident_rng,
        )  # fmt: skip
        return gap, v_lead

    def _advance(self) -> StepEvents:
        """SUMO step, then bookkeeping: table, lane-change clocks, counts, new departures."""
        gui = self.gui
        if gui is not None and gui.screenshot and self.step_count + 1 == gui.screenshot_step:
            self.session.screenshot(self.run_dir / GUI_SHOT, gui.screenshot_px)  # placed by the run at its end
        events = self.session.step()
        self.step_count += 1
        dt = self.cfg.control.dt_s
        prev = self.table
        self.table = self.session.table()
        t = self.table
        tot = self.totals
        overlapping = fast.after_step(t.nums, t.lane, t.pos, self.veh, self.controls)  # lane-change clocks run down
        if len(events.departed):
            self.veh.depart_s[events.departed] = self.time_s - dt
            self._handed[np.isin(self._handed, events.departed)] = -1
            tot.departed += len(events.departed)
            late = self.time_s - dt - self.veh.scheduled_s[events.departed]
            tot.insertion_blocked += int(np.sum(late >= dt - 1e-6))
        if len(events.arrived):
            tot.arrived += len(events.arrived)
            # as SUMO's tripinfo counts it: from the start of the departure step to the start of the arrival step
            tot.travel_time_sum_s += float(np.sum(self.time_s - dt - self.veh.depart_s[events.arrived]))
        tot.collisions += self._new_overlaps(overlapping)
        tot.sumo_collisions += events.collisions
        tot.teleports += events.teleports
        tot.distance_m += float(t.speed.sum()) * dt
        tot.vehicle_time_s += len(t.nums) * dt
        self._loop_counts.append(fast.section_crossings(prev.nums, prev.pos, t.nums, t.pos, self._sections_m))
        if self.record_every and self.step_count % self.record_every == 0 and len(t.nums):
            self._traj.append((np.full(len(t.nums), self.time_s, np.float32), t.nums.astype(np.int32),
                               t.lane.astype(np.int8), t.pos.astype(np.float32),
                               t.speed.astype(np.float32)))  # fmt: skip
        if gui is not None:
            self._show_states()
        self._insert_due()
        return events

    def _new_overlaps(self, rows: np.ndarray) -> int:
        """Pairs of vehicles whose bodies overlap after the step (rows of the table: controller.after_step) that
        were not overlapping already: the step's new collisions."""
        if len(rows) == 0:
            return 0
        t = self.table
        pairs = set(zip(t.nums[rows[:, 0]].tolist(), t.nums[rows[:, 1]].tolist(), strict=True))
        new = pairs - self._overlapping
        self._overlapping |= new
        return len(new)

    # -- results ---------------------------------------------------------------------------
    def summary(self) -> dict[str, float | int]:
        """Run statistics (definitions: docs/run-folders.md)."""
        tot = self.totals
        hours = self.time_s / 3600.0
        # vehicles that had a step to be inserted in (scheduled before the last step began) and were not;
        # one scheduled at the very end of the run was handed to SUMO but never had a chance
        last_step_start = self.time_s - self.cfg.control.dt_s + 1e-9
        pending = int(np.count_nonzero(self.veh.scheduled_s[: self.next_num] <= last_step_start)) - tot.departed
        return {
            "steps": self.step_count,
            "sim_seconds": round(self.time_s, 3),
            "departed": tot.departed,
            "arrived": tot.arrived,
            "insertion_blocked": tot.insertion_blocked + pending,
            "insertion_pending_at_end": pending,
            "collisions": tot.collisions,
            "sumo_collisions": tot.sumo_collisions if self.cfg.sumo_collision_check else -1,
            "teleports": tot.teleports,
            "lane_changes": tot.lane_changes,
            "lane_changes_rejected": tot.lane_changes_rejected,
            "lane_changes_per_vehicle": tot.lane_changes / max(tot.departed, 1),
            "mean_speed_mps": tot.distance_m / tot.vehicle_time_s if tot.vehicle_time_s else 0.0,
            "mean_vehicles_on_road": tot.vehicle_time_s / self.time_s if self.time_s else 0.0,
            "mean_travel_time_s": tot.travel_time_sum_s / tot.arrived if tot.arrived else float("nan"),
            "throughput_veh_per_h": tot.arrived / hours if hours else 0.0,
            **self.passing.summary(),
            **self._table_check(),
        }

    def _table_check(self) -> dict[str, float | int]:
        """The largest deviations the full reads found between the advanced table and SUMO's (m, m/s), and the
        first step whose read was not exact; -1 each with SUMO's own models (nothing advanced)."""
        if self.sumo_models:
            return {"table_max_dev_pos_m": -1.0, "table_max_dev_speed_mps": -1.0, "table_mismatch_step": -1}
        check = self.session.check
        return {"table_max_dev_pos_m": check.max_dev_pos_m, "table_max_dev_speed_mps": check.max_dev_speed_mps,
                "table_mismatch_step": check.mismatch_step}  # fmt: skip

    def trajectories(self) -> dict[str, np.ndarray]:
        """Recorded samples as columns: time_s, vid, lane, pos_m, speed_mps."""
        names = ("time_s", "vid", "lane", "pos_m", "speed_mps")
        if not self._traj:
            return {k: np.zeros(0) for k in names}
        return {k: np.concatenate([row[i] for row in self._traj]) for i, k in enumerate(names)}
