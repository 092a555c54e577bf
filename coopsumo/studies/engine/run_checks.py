"""What a finished run folder's files must agree with before a study reuses it: its summary with itself and with the
run's configuration, and SUMO's loop, trip and FCD files with the summary (complete, consistent, within what the
road can carry). Each check returns why the folder cannot be trusted, or None.

Cheap enough for hundreds of folders: detectors.xml and tripinfo.xml (hundreds of kB) are read whole, fcd.xml
(megabytes) only from its end.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import Any

from coopsumo.config import SUMO_ROOTS, fastest_mps
from coopsumo.errors import why_unreadable
from coopsumo.files import open_regular, read_bytes
from coopsumo.record_schemas import DETECTOR_INTERVAL, LANE_CAPACITY_VEH_H

TAIL_BYTES = 1 << 16
"""the first read from a file's end (fcd.xml's last timestep can be longer: the read doubles until it is found)"""


def _number(value: Any) -> float | None:
    """value as a float when it is a JSON number (not a bool), else None."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value)


def run_summary_problem(summary: dict[str, Any], cfg: dict[str, Any]) -> str | None:
    """Why a run's summary.json disagrees with itself or with the configuration it ran (a SimConfig dict), or None:
    its steps the configuration's and its simulated seconds theirs; wall time finite and >= 0 and its steps per
    second steps / wall time; shares from 0 to 1; a mean travel time from 0 to the run's length (NaN only without
    arrivals); throughput the arrivals per hour; the mean vehicle count from 0 to the departures; a mean loop flow
    those departures can give (together_problem); no more departures than one per lane and step; vehicles still
    waiting at the end among the blocked ones."""
    steps, dt = cfg["steps"], float(cfg["control"]["dt_s"])
    if summary.get("steps") != steps or isinstance(summary.get("steps"), bool):
        return f"has summary.json steps = {str(summary.get('steps'))[:20]}, but its configuration runs {steps} steps"
    num = {k: n for k, v in summary.items() if (n := _number(v)) is not None}
    sim_s = num.get("sim_seconds", math.nan)
    if not math.isclose(sim_s, steps * dt, abs_tol=dt / 2):
        return f"has summary.json sim_seconds = {sim_s:g}, but {steps} steps of {dt:g} s are {steps * dt:g} s"
    wall = num.get("wall_seconds", 0.0)
    if not (math.isfinite(wall) and wall >= 0):
        return f"has summary.json wall_seconds = {wall:g}, not a time"
    rate = num.get("steps_per_second")
    if rate is not None and wall > 0.001:  # both rounded: wall to 0.001 s, the rate to 0.1 step/s
        if not steps / (wall + 0.0005) - 0.05 <= rate <= steps / (wall - 0.0005) + 0.05:
            return f"has summary.json steps_per_second = {rate:g}, but {steps} steps took {wall:g} s"
    for key, value in num.items():
        if key.endswith("_share") and not (math.isnan(value) or 0 <= value <= 1):
            return f"has summary.json {key} = {value:g}, not a share from 0 to 1"
    departed = num.get("departed", 0.0)
    if problem := together_problem(num, _number(summary.get("mean_travel_time_s")), cfg):
        return problem
    lanes = int(cfg["road"]["lanes"])
    if departed > steps * lanes:
        return f"has summary.json departed = {departed:g}, more than one vehicle per lane and step ({steps * lanes})"
    if num.get("insertion_pending_at_end", 0.0) > num.get("insertion_blocked", math.inf):
        return "has summary.json insertion_pending_at_end above insertion_blocked"
    if isinstance(summary.get("policy"), str) and summary["policy"] != cfg["policy"]:
        return f"has summary.json policy {summary['policy'][:60]}, but its configuration drives {cfg['policy'][:60]}"
    return _motion_problem(num, cfg, departed, sim_s)


def together_problem(num: dict[str, float], travel: float | None, cfg: dict[str, Any], runs: int = 1) -> str | None:
    """Why a summary's counts and rates cannot go together in `runs` runs of the SimConfig dict cfg (num: its numbers;
    a pooled summary sums its runs' counts and seconds and averages the rest, records.pool_summaries), or None: a mean
    travel time blank exactly without arrivals (a pooled one may be blank beside some) and at most a run's length;
    throughput the arrivals per hour; at most the vehicles that departed on the road at once; a loop's mean flow per
    lane at most what those departures, each counted once at a loop and once more for each lane change, give over the
    road's lanes and the loop's intervals (of loop_period_s, the last cut at the run's end). The one home of these
    rules: a run folder's summary.json (run_summary_problem), a scenario II cell record's evaluations
    (records.runs_problem) and a merged part's runs.csv rows (issue 82, probe 14, F1, F2)."""
    arrived, departed, sim_s = num.get("arrived", 0.0), num.get("departed", 0.0), num.get("sim_seconds", math.nan)
    run_s = sim_s / runs
    if arrived > 0 and not (travel is not None and 0 <= travel <= run_s) and not (travel is None and runs > 1):
        return f"has summary.json mean_travel_time_s = {travel}, not a time from 0 to the run's {run_s:g} s"
    if arrived == 0 and travel is not None and not math.isnan(travel):
        return f"has summary.json mean_travel_time_s = {travel:g} without a vehicle that arrived"
    throughput = num.get("throughput_veh_per_h")
    if throughput is not None and sim_s > 0 and not math.isclose(throughput, arrived * 3600 / sim_s,
                                                                 rel_tol=1e-6, abs_tol=1e-6):  # fmt: skip
        return (f"has summary.json throughput_veh_per_h = {throughput:g}, but {arrived:g} vehicles arrived in "
                f"{sim_s:g} s ({arrived * 3600 / sim_s:g} veh/h)")  # fmt: skip
    on_road = num.get("mean_vehicles_on_road")
    if on_road is not None and not 0 <= on_road <= departed / runs * (1 + 1e-9):  # its vehicle time summed in steps
        return f"has summary.json mean_vehicles_on_road = {on_road:g}, outside 0 to the {departed / runs:g} departed"
    flow = num.get("loop_flow_veh_h_per_lane")
    if flow is not None and run_s > 0 and flow > (most := _most_loop_flow(num, cfg, run_s, runs)) + 0.01:
        return (f"has summary.json loop_flow_veh_h_per_lane = {flow:g}, but {departed / runs:g} vehicles departed "
                f"in {run_s:g} s on {cfg['road']['lanes']} lanes (at most {most:.2f} veh/h per lane)")  # fmt: skip
    return None


def _most_loop_flow(num: dict[str, float], cfg: dict[str, Any], run_s: float, runs: int) -> float:
    """The highest mean loop flow (veh/h per lane, over every loop, lane and interval) a run of run_s seconds can
    measure: its departures and lane changes counted in its shortest interval at every loop."""
    period = float(cfg["road"]["loop_period_s"])
    intervals = max(1, math.ceil(run_s / period - 1e-9))
    shortest = min(period, run_s - (intervals - 1) * period)
    counted = (num.get("departed", 0.0) + num.get("lane_changes", 0.0)) / runs
    return counted * 3600 / (int(cfg["road"]["lanes"]) * intervals * shortest)


def _motion_problem(num: dict[str, float], cfg: dict[str, Any], departed: float, sim_s: float) -> str | None:
    """Why a summary's speeds or lane changes are more than the run's vehicles could do, or None: a mean speed above
    the road's speed limit and the fastest desired speed (no vehicle drives faster), more lane changes than each
    vehicle that departed could make one after another (a change takes control.t_change_s) (issue 82, probe 8, J15:
    `keep` at 60 m/s on a 33.34 m/s road, 250 lane changes a vehicle in 20 s, were reused)."""
    fastest = fastest_mps(cfg)
    for key in ("mean_speed_mps", "full_road_speed_mps"):
        if num.get(key, 0.0) > fastest + 0.01:
            return f"has summary.json {key} = {num[key]:g}, above any vehicle's speed on its road ({fastest:g} m/s)"
    if num.get("lane_changes", 0.0) > most_lane_changes(departed, sim_s, cfg):
        return (f"has summary.json lane_changes = {num['lane_changes']:g}, more than its {departed:g} vehicles could "
                f"make in {sim_s:g} s")  # fmt: skip
    return None


def most_lane_changes(departed: float, sim_s: float, cfg: dict[str, Any]) -> float:
    """The most lane changes `departed` vehicles can start in sim_s seconds of a run of the SimConfig dict cfg: a
    vehicle starts one at most every control.t_change_s (a change under way blocks the next), one more as it enters.
    A run's summary (_motion_problem) and a training's last world (trainings.counts_problem) are bound by it."""
    return departed * (sim_s / float(cfg["control"]["t_change_s"]) + 1.0)


_INTERVAL = re.compile(rb"<interval(?=[\s/>])([^>]*)>")
_ATTRIBUTE = re.compile(rb'([\w:]+)="([^"]*)"')


def detectors_problem(path: Path, cfg: dict[str, Any], sim_seconds: float) -> str | None:
    """Why SUMO's E1 loop file of a run of cfg (sim_seconds long) cannot be trusted, or None: complete (it ends
    with </detector>), at least one interval, each inside the run and at most a loop period long, its numbers inside
    record_schemas.DETECTOR_INTERVAL (speeds 0-70 m/s, occupancy 0-100 %), its count at most a lane's capacity over
    the interval (a loop lies on one lane; one vehicle more for the interval's edges) and its flow the vehicles it
    counted per hour of the interval (nVehContrib * 3600 / (end - begin), as SUMO rounds it), each loop's interval
    once and on a lane of the road, the last interval ending with the run."""
    try:
        text = read_bytes(path)
    except OSError as err:
        return f"has an unreadable detectors.xml ({why_unreadable(err)})"
    if not text.rstrip().endswith(SUMO_ROOTS["detectors.xml"]):
        return "has a missing or cut-short detectors.xml"
    dt, period = float(cfg["control"]["dt_s"]), float(cfg["road"]["loop_period_s"])
    last_end, seen, lanes, fastest = -math.inf, set(), int(cfg["road"]["lanes"]), fastest_mps(cfg)
    for match in _INTERVAL.finditer(text):
        if (problem := _interval_problem(match, sim_seconds, dt, period, fastest)) is not None:
            return f"has detectors.xml with {problem}"
        attrs = dict(_ATTRIBUTE.findall(match.group(1)))
        loop, begin = attrs[b"id"].decode(), float(attrs[b"begin"])
        if int(loop.rsplit("_l", 1)[1]) >= lanes:  # (issue 82, probe 8, J16: both were reused and drawn)
            return f"has detectors.xml with loop {loop} on a lane the road's {lanes} lanes do not have"
        if (loop, begin) in seen:
            return f"has detectors.xml with loop {loop}'s interval from {begin:g} s twice"
        seen.add((loop, begin))
        last_end = max(last_end, float(attrs[b"end"]))
    if last_end == -math.inf:
        return "has a detectors.xml without an interval"
    if abs(last_end - sim_seconds) > dt / 2:
        return f"has detectors.xml ending at {last_end:g} s, but the run lasted {sim_seconds:g} s"
    return _unreadable_detectors(path)


def _unreadable_detectors(path: Path) -> str | None:
    """Why the measures' own reader (report.analysis.read_detectors, SUMO's parser) cannot read a detectors.xml the
    checks above passed (not well-formed XML, e.g. an attribute twice), or None (probe 6, H7)."""
    from coopsumo.report.analysis import read_detectors

    try:
        read_detectors(path)
    except (ValueError, TypeError, KeyError) as err:
        return f"has a detectors.xml the measures cannot read ({str(err).splitlines()[0][:160]})"
    return None


def _interval_problem(match: re.Match[bytes], sim_seconds: float, dt: float, period: float,
                      fastest: float) -> str | None:  # fmt: skip
    """Why one <interval> of detectors.xml cannot be trusted (words after "has detectors.xml with"), or None; its
    fields against each other and the road: _contradiction."""
    pairs = _ATTRIBUTE.findall(match.group(1))
    attrs = {k.decode(errors="replace"): v.decode(errors="replace") for k, v in pairs}
    shown = match.group(0).decode(errors="replace")[:120]
    if len(attrs) != len(pairs):
        return f"an interval giving an attribute twice: {shown}"
    if not re.fullmatch(r"e1_x[0-9]+_l[0-9]+", attrs.get("id", "")):
        return f"an interval of a loop whose id is not e1_x<pos>_l<lane>: {shown}"
    try:
        begin, end, count, flow = (float(attrs[k]) for k in ("begin", "end", "nVehContrib", "flow"))
        numbers = {k: float(v) for k, v in attrs.items() if k != "id"}
    except (KeyError, ValueError):
        return f"an interval lacking a number: {shown}"
    if problem := DETECTOR_INTERVAL.problem(numbers):
        return f"an interval {attrs['begin']}-{attrs['end']} s of {attrs.get('id', '?')[:40]}: {problem}"
    if not re.fullmatch(r"[0-9]+", attrs["nVehContrib"]):  # SUMO writes a count in digits; the reader takes no other
        return (f"an interval {attrs['begin']}-{attrs['end']} s of {attrs.get('id', '?')[:40]}: field nVehContrib "
                f"must be written as a whole number, got {attrs['nVehContrib'][:40]!r}")  # fmt: skip
    if not (begin < end <= sim_seconds + dt / 2 and end - begin <= period + 1e-6):
        return (f"an interval {begin:g}-{end:g} s, not within the run's {sim_seconds:g} s and its {period:g} s loop "
                "period")  # fmt: skip
    if count > LANE_CAPACITY_VEH_H * (end - begin) / 3600 + 1:
        return (f"{count:g} vehicles in {end - begin:g} s on one lane, above a lane's capacity of "
                f"{LANE_CAPACITY_VEH_H:,.0f} veh/h")  # fmt: skip
    expected = count * 3600 / (end - begin)
    if abs(flow - expected) > 0.011:
        return f"flow {flow:g} veh/h from {count:g} vehicles in {end - begin:g} s (that is {expected:.2f} veh/h)"
    if problem := _contradiction(numbers, fastest):
        return f"an interval {attrs['begin']}-{attrs['end']} s of {attrs['id'][:40]}: {problem}"
    return None


def _contradiction(numbers: dict[str, float], fastest: float) -> str | None:
    """Why an interval's fields contradict each other or the road, or None. SUMO's E1 loop averages its speeds over
    the vehicles it counted (nVehContrib, those that left it), writing -1 exactly when it counted none; no vehicle
    drives faster than the road's speed limit and the fastest desired speed (fastest, m/s); a loop that no vehicle
    entered or left in the interval was either empty throughout or held one vehicle throughout, so its occupancy is
    0 or 100 % (issue 82, probe 13, F8: a speed beside no vehicle, -1 beside 3 vehicles, 65 m/s on a 33.34 m/s road,
    90 % occupancy with no vehicle were reused and drawn into fig5)."""
    count = numbers["nVehContrib"]
    for key in ("speed", "harmonicMeanSpeed"):
        if key not in numbers:
            continue
        if (count == 0) != (numbers[key] == -1.0):
            return f"{key} {numbers[key]:g} beside {count:g} vehicles counted (SUMO writes -1 exactly when none)"
        if numbers[key] > fastest + 0.01:
            return f"{key} {numbers[key]:g} m/s, above any vehicle's speed on its road ({fastest:g} m/s)"
    occupancy = numbers["occupancy"]
    if count == 0 and numbers.get("nVehEntered") == 0 and 0.01 < occupancy < 99.99:
        return (f"occupancy {occupancy:g} % though no vehicle entered or left the loop (0 %, or 100 % for one on it "
                "throughout)")  # fmt: skip
    return None


def tail(path: Path, size: int = TAIL_BYTES) -> bytes:
    """The last `size` bytes of the file at path (OSError when it cannot be read)."""
    with open_regular(path, limit=None) as f:  # only its tail is read
        f.seek(max(0, f.seek(0, os.SEEK_END) - size))
        return f.read()


_TIMESTEP = re.compile(rb'<timestep time="([^"]*)"')


def fcd_problem(path: Path, sim_seconds: float, period_s: float, dt: float) -> str | None:
    """Why SUMO's FCD file of a run sim_seconds long, written every period_s, cannot be trusted, or None: it ends
    with </fcd-export> and its last timestep lies within one period (and a step) of the run's end. Reads from the
    end only, until the last timestep is found."""
    try:
        size, end = TAIL_BYTES, tail(path)
        if not end.rstrip().endswith(closing := SUMO_ROOTS["fcd.xml"]):
            return f"has a cut-short fcd.xml (it does not end with {closing.decode()})"
        while not (found := _TIMESTEP.findall(end)) and size < path.stat().st_size:
            size *= 4
            end = tail(path, size)
    except OSError as err:
        return f"has an unreadable fcd.xml ({why_unreadable(err)})"
    if not found:
        return "has an fcd.xml without a timestep"
    try:
        last = float(found[-1])
    except ValueError:
        last = math.nan
    if not sim_seconds - period_s - dt - 1e-6 < last <= sim_seconds + 1e-6:
        shown = found[-1].decode(errors="replace")[:20]
        return f"has fcd.xml ending at {shown} s, but the run lasted {sim_seconds:g} s"
    return None


_DURATION = re.compile(rb'<tripinfo\s[^>]*?\sduration="([^"]*)"')


def tripinfo_problem(path: Path, summary: dict[str, Any]) -> str | None:
    """Why SUMO's tripinfo file cannot be trusted beside the run's summary, or None: it ends with </tripinfos>, holds
    one trip per vehicle that arrived, and their mean duration is the summary's mean travel time."""
    try:
        text = read_bytes(path)
    except OSError as err:
        return f"has an unreadable tripinfo.xml ({why_unreadable(err)})"
    if not text.rstrip().endswith(closing := SUMO_ROOTS["tripinfo.xml"]):
        return f"has a cut-short tripinfo.xml (it does not end with {closing.decode()})"
    trips, arrived = text.count(b"<tripinfo "), summary.get("arrived")
    if trips != arrived:
        return f"has tripinfo.xml with {trips} trips, but summary.json says {arrived} vehicles arrived"
    try:
        durations = [float(d) for d in _DURATION.findall(text)]
    except ValueError:
        return "has tripinfo.xml with a duration that is not a number"
    if len(durations) != trips:
        return "has tripinfo.xml with a trip without a duration"
    travel = _number(summary.get("mean_travel_time_s"))
    if trips and (travel is None or not math.isclose(sum(durations) / trips, travel, rel_tol=1e-6, abs_tol=1e-3)):
        return (f"has tripinfo.xml with a mean duration of {sum(durations) / len(durations):g} s, but summary.json "
                f"says a mean travel time of {travel} s")  # fmt: skip
    return None
