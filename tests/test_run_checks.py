"""Issue 67, read-back checks that look inside: a study reuses a finished run folder (scenario I, adaptive-alpha) only
when its summary agrees with itself and its configuration and SUMO's loop, FCD and trip files are complete and agree
with it. One real short run (400 steps on a 400 m road, with fcd.xml, tripinfo.xml and trajectories) is made once;
each case spoils a copy and the folder is redone with one line naming it and why, the intact copy is reused and
left as it was."""

from __future__ import annotations

import json
import os
import re
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from coopsumo.config import DemandConfig, OutputConfig, RoadConfig, SimConfig, to_dict
from coopsumo.run_dirs import mark_run_dir
from coopsumo.studies.engine.run_folders import reusable_run, simulate_into

pytestmark = pytest.mark.sumo
CFG = SimConfig(road=RoadConfig(length_m=400.0, loop_spacing_m=100.0, loop_period_s=10.0),
                demand=DemandConfig(t_up_s=1.0), steps=400, seed=3, policy="keep")  # fmt: skip
"""vehicles cross the road in about 15 s: arrivals, several loop intervals and FCD timesteps in 40 s"""
OUTPUTS = OutputConfig(fcd_period_s=5.0, tripinfo=True)


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("made") / "run"
    simulate_into(to_dict(CFG), out, "run", trajectory_every=5, outputs=OUTPUTS, atomic=True)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["arrived"] > 5 and summary["steps"] == CFG.steps  # a run the cases can spoil
    return out


def snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def summary(**changes: Any) -> Callable[[Path], None]:
    def spoil(out: Path) -> None:
        values = json.loads((out / "summary.json").read_text())
        values.update({k: v(values) if callable(v) else v for k, v in changes.items()})
        (out / "summary.json").write_text(json.dumps(values))

    return spoil


def text(name: str, change: Callable[[str], str]) -> Callable[[Path], None]:
    def spoil(out: Path) -> None:
        before = (out / name).read_text()
        after = change(before)
        assert after != before, name
        (out / name).write_text(after)

    return spoil


def cut(name: str) -> Callable[[Path], None]:
    def spoil(out: Path) -> None:
        data = (out / name).read_bytes()
        (out / name).write_bytes(data[: len(data) // 2])

    return spoil


def _interval_flow(xml: str, count: int, flow: str) -> str:
    """The first loop interval with nVehContrib and flow replaced."""
    return re.sub(r'nVehContrib="\d+" flow="[^"]*"', f'nVehContrib="{count}" flow="{flow}"', xml, count=1)


def _attribute(xml: str, name: str, value: str) -> str:
    """The first loop interval with its attribute `name` set to value."""
    return re.sub(rf' {name}="[^"]*"', f' {name}="{value}"', xml, count=1)


def _interval(xml: str, count: int, **values: str) -> str:
    """The first loop interval counting `count` vehicles in its 10 s (its flow so), its other attributes `values`."""
    xml = _interval_flow(xml, count, f"{count * 360:.2f}")
    for name, value in values.items():
        xml = _attribute(xml, name, value)
    return xml


def _drop_last_intervals(xml: str) -> str:
    """detectors.xml of a run 10 s shorter: its last period's intervals gone."""
    return "\n".join(line for line in xml.splitlines() if 'end="40.00"' not in line) + "\n"


def _drop_last_timesteps(xml: str) -> str:
    """fcd.xml of a run one FCD period shorter: its last timestep gone, closed again."""
    return xml[: xml.rindex("<timestep ")] + "</fcd-export>\n"


def _one_interval_twice(xml: str) -> str:
    line = next(ln for ln in xml.splitlines(keepends=True) if "<interval " in ln and 'begin="0.00"' in ln)
    return xml.replace(line, line + line, 1)


def _one_longer_trip(xml: str) -> str:
    return re.sub(r'duration="([\d.]+)"', lambda m: f'duration="{float(m.group(1)) + 30:.2f}"', xml, count=1)


def _trajectories(**first: float) -> Callable[[Path], None]:
    """trajectories.parquet with its first sample's columns set to `first`, its types kept."""

    def spoil(out: Path) -> None:
        import pandas as pd

        table = pd.read_parquet(out / "trajectories.parquet")
        for name, value in first.items():
            table.loc[0, name] = value
        table.astype(pd.read_parquet(out / "trajectories.parquet").dtypes).to_parquet(out / "trajectories.parquet")

    return spoil


def _newer_model(out: Path) -> None:
    later = (out / "summary.json").stat().st_mtime_ns + 10**9
    os.utime(out.parent / "model.pt", ns=(later, later))


CASES: dict[str, tuple[Callable[[Path], None], str]] = {
    # the probe's corruptions (issue 67)
    "travel time 1e308": (summary(mean_travel_time_s=1e308), "mean_travel_time_s = 1e+308"),
    "negative wall time": (summary(wall_seconds=-3.0), "wall_seconds must be a finite number >= 0 (s), got -3.0"),
    "150 steps": (summary(steps=150), "steps = 150, but its configuration runs 400 steps"),
    "30,000 veh/h from 3 vehicles": (text("detectors.xml", lambda x: _interval_flow(x, 3, "30000.00")),
                                     "flow 30000 veh/h from 3 vehicles in 10 s"),
    "fcd.xml cut short": (cut("fcd.xml"), "cut-short fcd.xml"),
    "fcd.xml without its closing tag": (text("fcd.xml", lambda x: x.replace("</fcd-export>", "")),
                                        "cut-short fcd.xml"),
    # more of the same classes
    "tripinfo.xml cut short": (cut("tripinfo.xml"), "cut-short tripinfo.xml"),
    "detectors.xml cut short": (cut("detectors.xml"), "cut-short detectors.xml"),
    "a lane above one vehicle a step": (text("detectors.xml", lambda x: _interval_flow(x, 101, "36360.00")),
                                        "101 vehicles in 10 s on one lane, above a lane's capacity"),
    "loops of a shorter run": (text("detectors.xml", _drop_last_intervals), "ending at 30 s, but the run lasted 40"),
    "FCD of a shorter run": (text("fcd.xml", _drop_last_timesteps),
                             "fcd.xml ending at 30.00 s, but the run lasted 40 s"),
    "one arrival more": (summary(arrived=lambda s: s["arrived"] + 1,
                                 throughput_veh_per_h=lambda s: (s["arrived"] + 1) * 90.0), "trips, but summary.json"),
    "throughput edited": (summary(throughput_veh_per_h=lambda s: s["throughput_veh_per_h"] * 2),
                          "throughput_veh_per_h"),
    "a trip longer than recorded": (text("tripinfo.xml", _one_longer_trip), "mean duration"),
    "negative travel time": (summary(mean_travel_time_s=-1.0), "mean_travel_time_s must be a finite number >= 0"),
    "sim seconds edited": (summary(sim_seconds=4000.0), "sim_seconds = 4000"),
    "steps per second edited": (summary(steps_per_second=lambda s: s["steps_per_second"] * 10),
                                "steps_per_second"),
    "a share above 1": (summary(held_share=1.5), "held_share must be a finite number >= 0 and <= 1, got 1.5"),
    "more vehicles on the road than departed": (summary(mean_vehicles_on_road=1e6), "mean_vehicles_on_road"),
    "another policy's summary": (summary(policy="greedy"), "policy greedy"),
    "infinite speed": (summary(mean_speed_mps=float("inf")), "mean_speed_mps = inf"),
    "another configuration": (text("config.json", lambda x: x.replace('"steps": 400', '"steps": 401')),
                              "another or an unreadable configuration"),
    "its model written after the run": (_newer_model, "was driven by another model"),
    # issue 82: every number of an interval inside record_schemas.DETECTOR_INTERVAL's limits
    "a loop speed of 999 m/s": (text("detectors.xml", lambda x: _attribute(x, "speed", "999.00")),
                                "field speed must be a finite number >= 0 and <= 70 (m/s, or -1 without a vehicle), "
                                "got 999.0"),
    "a loop speed of -5 m/s": (text("detectors.xml", lambda x: _attribute(x, "speed", "-5.00")), "field speed"),
    "a harmonic mean speed of 80 m/s": (text("detectors.xml", lambda x: _attribute(x, "harmonicMeanSpeed", "80")),
                                        "field harmonicMeanSpeed"),
    "an occupancy of 150 %": (text("detectors.xml", lambda x: _attribute(x, "occupancy", "150.00")),
                              "field occupancy must be a finite number >= 0 and <= 100 (%)"),
    "a negative count": (text("detectors.xml", lambda x: _interval_flow(x, -1, "-360.00")), "field nVehContrib"),
    "a count of 2.5": (text("detectors.xml", lambda x: _interval_flow(x, 2.5, "900.00")), "field nVehContrib"),
    "a speed not a number": (text("detectors.xml", lambda x: _attribute(x, "speed", "fast")), "lacking a number"),
    # probe 6, H7: passed the checks, then the measures' reader failed with a traceback
    "a bare interval": (text("detectors.xml", lambda x: x.replace("<interval ", "<interval/>\n    <interval ", 1)),
                        "an interval of a loop whose id is not e1_x<pos>_l<lane>: <interval/>"),
    "an attribute twice": (text("detectors.xml", lambda x: x.replace(' flow="', ' flow="1" flow="', 1)),
                           "an interval giving an attribute twice"),
    "a loop id of another form": (text("detectors.xml", lambda x: x.replace('id="e1_', 'id="zz', 1)),
                                  "an interval of a loop whose id is not e1_x<pos>_l<lane>"),
    "a comment that breaks the XML": (text("detectors.xml", lambda x: x.replace("</detector>",
                                                                                "<!-- -- --></detector>")),
                                      "has a detectors.xml the measures cannot read (detector output"),
    "detectors.xml deleted": (lambda out: (out / "detectors.xml").unlink(),
                              "has lost detectors.xml, which its .coopsumo-run.json lists"),  # was blamed on the marker
    "tripinfo.xml deleted": (lambda out: (out / "tripinfo.xml").unlink(), "has no tripinfo.xml"),
    "above a lane's capacity": (text("detectors.xml", lambda x: _interval_flow(x, 12, "4320.00")),
                                "12 vehicles in 10 s on one lane, above a lane's capacity of 3,600 veh/h"),
    # the probe's (2026-12-02): trajectories were read, never checked, and a scenario I rerun measured them
    "a trajectory speed of 999 m/s": (_trajectories(speed_mps=999.0), "speed_mps = 999.0 (outside 0.0 to 70.0)"),
    "a trajectory on lane 9 of 3": (_trajectories(lane=9), "lane = 9 (outside 0 to 2)"),
    "a trajectory before time 0": (_trajectories(time_s=-5.0), "time_s = -5.0"),
    # probe 8 (issue 82, J15, J16): values each inside its limits, but no run's
    "keep at 60 m/s on a 33.34 m/s road": (summary(mean_speed_mps=60.0), "mean_speed_mps = 60, above any vehicle's"),
    "250 lane changes a vehicle in 40 s": (summary(lane_changes=lambda s: s["departed"] * 250,
                                                   lane_changes_per_vehicle=250.0), "more than its"),
    "a loop's interval twice": (text("detectors.xml", _one_interval_twice), "interval from 0 s twice"),
    "a loop on lane 7 of 3": (text("detectors.xml", lambda x: re.sub(r'id="e1_x(\d+)_l\d+"', r'id="e1_x\1_l7"', x,
                                                                     count=1)), "on a lane the road's 3 lanes"),
    # probe 13 (issue 82, F8): an interval's fields against each other and the road
    "a loop speed beside no vehicle": (text("detectors.xml", lambda x: _interval(x, 0, speed="30.00")),
                                       "speed 30 beside 0 vehicles counted"),
    "no loop speed beside 3 vehicles": (text("detectors.xml", lambda x: _interval(x, 3, speed="-1.00")),
                                        "speed -1 beside 3 vehicles counted"),
    "a loop speed of 65 m/s on a 33.34 m/s road": (
        text("detectors.xml", lambda x: _interval(x, 3, speed="65.00", harmonicMeanSpeed="20.00")),
        "speed 65 m/s, above any vehicle's speed on its road (33.34 m/s)"),
    "90 % occupancy with no vehicle": (
        text("detectors.xml", lambda x: _interval(x, 0, speed="-1.00", harmonicMeanSpeed="-1.00", occupancy="90.00",
                                                  nVehEntered="0")), "occupancy 90 % though no vehicle entered"),
}  # fmt: skip


def test_a_count_at_a_lanes_capacity_is_trusted(made: Path, tmp_path: Path) -> None:
    """The capacity limit leaves a vehicle for the interval's edges: 8 vehicles in 10 s (2,880 veh/h) pass."""
    from coopsumo.studies.engine.run_checks import detectors_problem

    out = tmp_path / "run"
    shutil.copytree(made, out)
    text("detectors.xml", lambda x: _interval(x, 8, speed="20.00", harmonicMeanSpeed="20.00"))(out)
    assert detectors_problem(out / "detectors.xml", to_dict(CFG), 40.0) is None


@pytest.mark.parametrize("case", CASES)
def test_a_spoiled_run_folder_is_redone_with_one_line(
    case: str, made: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    spoil, fragment = CASES[case]
    out = tmp_path / "run"
    shutil.copytree(made, out)
    model = tmp_path / "model.pt"  # the model the run stands for (keep drives: a stand-in file, older than the run)
    model.write_bytes(b"weights")
    old = (out / "summary.json").stat().st_mtime_ns - 10**9
    os.utime(model, ns=(old, old))
    assert reusable_run(out, to_dict(CFG), OUTPUTS, model)
    assert capsys.readouterr().err == ""
    spoil(out)
    assert not reusable_run(out, to_dict(CFG), OUTPUTS, model)
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"scenario1: run folder {out} "), lines
    assert fragment in lines[0] and lines[0].endswith("; running it again"), lines


def test_an_intact_run_folder_is_reused_untouched(
    made: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    shutil.copytree(made, out)
    before = snapshot(out)
    for _ in range(2):
        assert reusable_run(out, to_dict(CFG), OUTPUTS)
        assert reusable_run(out, to_dict(CFG), OutputConfig(fcd_period_s=5.0, tripinfo=True))
    assert capsys.readouterr().err == ""
    assert snapshot(out) == before
    # a run never made (no summary.json) is run without a word; one with other outputs is redone with a line
    assert not reusable_run(tmp_path / "none", to_dict(CFG), OUTPUTS)
    assert capsys.readouterr().err == ""
    assert not reusable_run(out, to_dict(CFG), OutputConfig(fcd_period_s=1.0, tripinfo=True))
    assert "has other SUMO outputs" in capsys.readouterr().err
    assert snapshot(out) == before


def test_fcd_is_read_from_its_end(made: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A big fcd.xml is not read whole: the check reads a tail (doubling until a timestep is found)."""
    from coopsumo.studies.engine import run_checks

    out = tmp_path / "run"
    shutil.copytree(made, out)
    fcd = out / "fcd.xml"
    head, body = fcd.read_text().split("<timestep ", 1)
    fcd.write_text(head + "<!--" + "x" * 5_000_000 + "-->\n<timestep " + body)  # 5 MB before the timesteps
    mark_run_dir(out, "simulate")  # as its run would mark it: the digest of this file (probe 16, TR1)
    read: list[int] = []
    real_tail = run_checks.tail
    monkeypatch.setattr(run_checks, "tail", lambda path, size=run_checks.TAIL_BYTES: read.append(size) or
                        real_tail(path, size))  # fmt: skip
    assert reusable_run(out, to_dict(CFG), OUTPUTS)
    assert read and max(read) < 1_000_000, read


def test_a_run_written_in_place_again_leaves_a_hard_linked_copy_of_its_folder_as_it_was(tmp_path: Path) -> None:
    """Issue 82, probe 9 (K7): scenario II's and the learning study's evaluations are written in place, and SUMO
    opened an earlier run's detectors.xml and routes.rou.xml to write them again, so a hard-linked snapshot of the
    study (`cp -al`, `rsync --link-dest`) changed with a rerun of its cell."""
    from dataclasses import replace

    out = tmp_path / "study" / "evals" / "cell" / "eval_s3"
    simulate_into(to_dict(CFG), out, "run")
    copy = tmp_path / "copy"
    shutil.copytree(out, copy, copy_function=os.link)
    assert (copy / "detectors.xml").stat().st_nlink == 2
    before = snapshot(copy)
    simulate_into(to_dict(replace(CFG, seed=4)), out, "run")
    assert snapshot(copy) == before and snapshot(out)["detectors.xml"] != before["detectors.xml"]


def test_a_users_file_in_a_run_folder_written_in_place_is_refused_or_kept(tmp_path: Path) -> None:
    """Issue 82, probe 10 (L2): a user's `.notes.tmp` in a scenario II run folder was taken as a run's temporary and
    deleted by the cell's rerun, and a user's fcd.xml in a run that writes none was deleted too. A temporary of a
    run's own file ('.NAME.XXXXXXXX.tmp') is the run's, removed by the rerun (a killed write's left in a finished
    folder: test_scenario2's interrupted sweep, once); a user's dot-file is refused; an output name the run does not
    write is kept."""
    from coopsumo.errors import UsageError
    from coopsumo.studies.engine.run_folders import check_run_places

    out = tmp_path / "evals" / "cell" / "eval_s3"
    simulate_into(to_dict(CFG), out, "run")
    (out / ".detectors.xml.abcd1234.tmp").write_text("a killed write's\n")
    check_run_places([out], in_place=True)  # the run's own temporary: taken
    (out / ".notes.tmp").write_text("my notes\n")
    with pytest.raises(UsageError, match="has no .coopsumo-run.json .* is left alone"):
        check_run_places([out], in_place=True)
    (out / ".notes.tmp").unlink()
    (out / "fcd.xml").write_text("my fcd\n")
    check_run_places([out], in_place=True)
    simulate_into(to_dict(CFG), out, "run")  # writes no FCD
    assert (out / "fcd.xml").read_text() == "my fcd\n"
    assert not (out / ".detectors.xml.abcd1234.tmp").exists()  # the run's own, left by a killed write: removed
