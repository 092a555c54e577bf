"""The vehicle table advanced between full reads (coopsumo.sim.vehicle_table) equals SUMO's, exactly.

Pure tests of the table functions; then real SUMO: the advanced table compared with SUMO every step in a jam
and in lane-change-heavy traffic; vehicles that depart, change lane and arrive, and teleports, with no full
read in between; identical outputs with and without --read-every-step (keep, random, MOBIL, a DQN).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from conftest import TIMING_KEYS

from coopsumo.agents.policies import make_policy, policy_for_run
from coopsumo.agents.rollout import run
from coopsumo.config import AccidentConfig, OutputConfig, RoadConfig, SimConfig, TrainConfig, to_dict
from coopsumo.sim import network
from coopsumo.sim import vehicle_table as vt
from coopsumo.sim.vehicle_table import VehicleTable
from coopsumo.sim.world import World

SimConfigOf = Callable[..., SimConfig]
NEVER = 10**6  # full_read_every_steps of a run that reads SUMO whole only on teleports


def table(nums: list[int], lane: list[int], pos: list[float], speed: list[float]) -> VehicleTable:
    return VehicleTable(np.array(nums, np.int64), np.array(lane, np.int64), np.array(pos), np.array(speed))


# -- pure --------------------------------------------------------------------------------------


def test_advance_moves_each_vehicle_by_its_commanded_speed_and_switches_lanes() -> None:
    t = table([2, 5, 9], [0, 1, 2], [10.0, 50.0, 80.0], [3.0, 0.0, 20.0])
    out = vt.advance(t, np.array([4.0, 0.5, 19.5]), np.array([-1, 2, -1]), 0.1)
    np.testing.assert_array_equal(out.nums, [2, 5, 9])
    np.testing.assert_array_equal(out.lane, [0, 2, 2])
    np.testing.assert_array_equal(out.pos, [10.0 + 4.0 * 0.1, 50.0 + 0.5 * 0.1, 80.0 + 19.5 * 0.1])  # as SUMO: x + v dt
    np.testing.assert_array_equal(out.speed, [4.0, 0.5, 19.5])
    np.testing.assert_array_equal(t.pos, [10.0, 50.0, 80.0])  # the input is left alone


def test_lane_switches_land_on_the_rows_of_vehicles_still_on_the_road() -> None:
    np.testing.assert_array_equal(vt.switch_rows(np.array([3, 5, 8]), [8, 4, 3], [1, 2, 0]), [0, -1, 1])
    assert len(vt.switch_rows(np.zeros(0, np.int64), [1], [2])) == 0


def test_drop_and_add_keep_the_table_sorted_by_number() -> None:
    t = table([1, 4, 7], [0, 1, 2], [1.0, 4.0, 7.0], [1.0, 4.0, 7.0])
    t = vt.add(vt.drop(t, np.array([4, 99])), table([5, 0], [2, 0], [0.5, 0.0], [10.0, 11.0]))
    np.testing.assert_array_equal(t.nums, [0, 1, 5, 7])
    np.testing.assert_array_equal(t.lane, [0, 0, 2, 2])
    np.testing.assert_array_equal(t.speed, [11.0, 1.0, 10.0, 7.0])


def test_deviation_sees_positions_speeds_lanes_and_missing_vehicles() -> None:
    a = table([1, 2, 3], [0, 1, 2], [5.0, 6.0, 7.0], [1.0, 2.0, 3.0])
    assert vt.deviation(a, a).exact()
    b = table([1, 2, 4], [0, 0, 2], [5.0, 6.25, 7.0], [1.0, 2.0, 3.5])
    dev = vt.deviation(a, b)
    assert (dev.pos_m, dev.speed_mps, dev.lanes, dev.membership) == (0.25, 0.0, 1, 2)
    assert not dev.exact()
    assert not vt.deviation(a, table([1, 2, 3], [0, 1, 2], [5.0, 6.0, 7.0], [1.0, 2.0, 3.0 + 1e-7])).exact()


def test_lane_switch_comes_half_way_through_the_manoeuvre() -> None:
    assert vt.lane_switch_steps(4.0, 0.1) == 20  # measured in SUMO (tests below)
    assert vt.lane_switch_steps(3.0, 0.1) == 15 and vt.lane_switch_steps(0.1, 0.1) == 1


def test_controlled_vehicles_have_sumos_lane_change_motivations_off_and_sumos_own_models_keep_them() -> None:
    controlled = network.routes_xml(30.0, 4.0, lc_motivations=False)
    own = network.routes_xml(30.0, 4.0)
    for key in ('lcStrategic="-1"', 'lcCooperative="0"', 'lcSpeedGain="0"', 'lcKeepRight="0"'):
        assert key in controlled and key not in own


# -- real SUMO: the advanced table against SUMO ----------------------------------------------------


def sumo_table(world: World) -> VehicleTable:
    """SUMO's own state of every vehicle, read here (not through the world)."""
    veh = world.session.ls.vehicle
    ids = veh.getIDList()
    return vt.sorted_table(np.array([int(v) for v in ids], np.int64), np.array([veh.getLaneIndex(v) for v in ids]),
                           np.array([veh.getLanePosition(v) for v in ids]),
                           np.array([veh.getSpeed(v) for v in ids]))  # fmt: skip


def assert_same(a: VehicleTable, b: VehicleTable, step: int) -> None:
    for name in ("nums", "lane", "pos", "speed"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=f"{name} at step {step}")


JAM = AccidentConfig(enabled=True, start_step=100, duration_steps=50_000)


@pytest.mark.sumo
@pytest.mark.parametrize(
    ("policy", "t_up_s", "accident", "min_lane_changes"),
    [("keep", 1.0, JAM, 0), ("random", 0.7, AccidentConfig(), 1000), ("mobil", 1.0, JAM, 50)],
    ids=["jammed-keep", "random-near-capacity", "jammed-mobil"],
)
def test_the_advanced_table_equals_sumos_on_every_step(
    tmp_path: Path, make_sim_config: SimConfigOf, policy: str, t_up_s: float, accident: AccidentConfig,
    min_lane_changes: int,
) -> None:  # fmt: skip
    """full_read_every_steps = 1 (--read-every-step): every step the table advanced from the previous one is
    compared with SUMO's full read; not one vehicle may be off by any amount, in any lane, or missing."""
    cfg = dataclasses.replace(make_sim_config(lanes=3, t_up_s=t_up_s, steps=1500, seed=5, policy=policy,
                                              accident=accident), full_read_every_steps=1)  # fmt: skip
    summary = run(cfg, make_policy(policy, np.random.default_rng(5)), tmp_path, progress=False)
    assert summary["table_max_dev_pos_m"] == 0.0 and summary["table_max_dev_speed_mps"] == 0.0
    assert summary["table_mismatch_step"] == -1
    assert summary["lane_changes"] >= min_lane_changes
    assert summary["mean_vehicles_on_road"] > 60


@pytest.mark.sumo
def test_a_wrong_lane_switch_step_is_caught_and_then_every_step_is_read(
    tmp_path: Path, make_sim_config: SimConfigOf, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The check has teeth: with the lane switch expected one step early, the first full read after a lane
    change finds the vehicle in its old lane, and from then on the world reads SUMO every step."""
    monkeypatch.setattr(vt, "lane_switch_steps", lambda t_change_s, dt_s: 19)
    cfg = make_sim_config(lanes=3, t_up_s=0.7, steps=600, seed=5, policy="random")
    with World(cfg, tmp_path) as world:
        policy = make_policy("random", np.random.default_rng(5))
        for _ in range(cfg.steps):
            world.apply(policy.act(world.observe()))
        check = world.session.check
        summary = world.summary()
    assert check.lanes_off > 0 and summary["table_mismatch_step"] > 0
    assert check.full_reads > cfg.steps - summary["table_mismatch_step"]  # every step since


@pytest.mark.sumo
def test_vehicles_that_depart_change_lane_and_arrive_between_two_full_reads_are_tracked(
    tmp_path: Path, make_sim_config: SimConfigOf
) -> None:
    """No full read at all on a 400 m road: every vehicle's whole trip, lane changes included, is advanced
    from the commands and the departures and arrivals SUMO reports; it equals SUMO's state on every step."""
    base = make_sim_config(lanes=3, t_up_s=1.5, steps=700, seed=2, policy="random")
    cfg = dataclasses.replace(base, road=RoadConfig(lanes=3, length_m=400.0), full_read_every_steps=NEVER)
    policy = make_policy("random", np.random.default_rng(2))
    life: dict[int, list[int]] = {}  # vehicle -> lanes it was seen in, in order
    arrived: set[int] = set()
    with World(cfg, tmp_path) as world:
        for step in range(1, cfg.steps + 1):
            out = world.apply(policy.act(world.observe()))
            assert_same(world.table, sumo_table(world), step)
            arrived |= set(out.nums[out.arrived].tolist())
            for num, lane in zip(world.table.nums.tolist(), world.table.lane.tolist(), strict=True):
                life.setdefault(num, []).append(lane)
        assert world.session.check.full_reads == 0  # nothing but departures and arrivals was read
        summary = world.summary()
    whole_trips = [lanes for num, lanes in life.items() if num in arrived]
    changed = [lanes for lanes in whole_trips if len(set(lanes)) > 1]
    assert len(whole_trips) > 20 and len(changed) > 15  # 29 and 28
    assert summary["lane_changes"] > 100


@pytest.mark.sumo
def test_teleports_between_full_reads_are_tracked(tmp_path: Path, make_sim_config: SimConfigOf) -> None:
    """Held vehicles stand at the bottleneck until SUMO teleports them (after 10 s); on this one-edge road a
    teleport ends the trip in the same step. Teleport steps are read whole, nothing else is."""
    acc = AccidentConfig(enabled=True, x_m=200.0, start_step=50, duration_steps=50_000)
    base = make_sim_config(lanes=2, t_up_s=2.0, steps=700, seed=1, policy="keep", accident=acc)
    cfg = dataclasses.replace(base, road=RoadConfig(lanes=2, length_m=400.0), time_to_teleport_s=10.0,
                              full_read_every_steps=NEVER)  # fmt: skip
    policy = make_policy("keep", np.random.default_rng(1))
    teleport_steps = 0
    with World(cfg, tmp_path) as world:
        ls = world.session.ls
        for step in range(1, cfg.steps + 1):
            world.apply(policy.act(world.observe()))
            gone = ls.simulation.getStartingTeleportIDList()
            teleport_steps += bool(gone)
            assert not set(map(int, gone)) & set(world.table.nums.tolist())
            assert_same(world.table, sumo_table(world), step)
        check = world.session.check
        summary = world.summary()
    assert summary["teleports"] >= 3 and teleport_steps >= 3
    assert check.full_reads == teleport_steps and check.mismatch_step == -1


# -- identical outputs with and without --read-every-step ------------------------------------------


def run_folder(cfg: SimConfig, out: Path) -> dict[str, Any]:
    out.mkdir()
    summary = run(cfg, policy_for_run(cfg), out, trajectories=True, progress=False,
                  outputs=OutputConfig(fcd_period_s=0.5, tripinfo=True))  # fmt: skip
    return {k: v for k, v in summary.items() if k not in TIMING_KEYS}


def sumo_file(path: Path) -> bytes:
    """A SUMO output file without its header comment (the time it was written and the paths of the run)."""
    return path.read_bytes().split(b"-->", 1)[1]


@pytest.fixture(scope="module")
def dqn_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    import torch

    from coopsumo.agents.dqn import QNetwork
    from coopsumo.agents.model_file import save_model

    torch.manual_seed(4)
    path = tmp_path_factory.mktemp("model") / "model.pt"
    # the paper's state, no margin: untrained, it changes lanes often
    cfg = TrainConfig(dqn=dataclasses.replace(TrainConfig().dqn, change_margin=0.0, observation="paper"))
    save_model(path, QNetwork(30.0, dueling=True, observation=cfg.dqn.observation), {"config": to_dict(cfg)})
    return path


@pytest.mark.sumo
@pytest.mark.parametrize("policy", ["keep", "random", "mobil", "dqn"])
def test_outputs_are_identical_with_and_without_read_every_step(
    tmp_path: Path, make_sim_config: SimConfigOf, dqn_model: Path, policy: str
) -> None:
    spec = f"dqn:{dqn_model}" if policy == "dqn" else policy
    cfg = make_sim_config(lanes=3, t_up_s=1.0, steps=1200, seed=3, policy=spec, accident=JAM)
    every = run_folder(dataclasses.replace(cfg, full_read_every_steps=1), tmp_path / "every")
    sparse = run_folder(cfg, tmp_path / "sparse")
    assert cfg.full_read_every_steps == 10
    assert json.dumps(every) == json.dumps(sparse)  # as written to summary.json (NaN equals NaN)
    assert sparse["table_max_dev_pos_m"] == 0.0 and sparse["table_mismatch_step"] == -1
    assert sparse["lane_changes"] >= (0 if policy == "keep" else 20)
    for name in ("detectors.xml", "fcd.xml", "tripinfo.xml"):
        assert sumo_file(tmp_path / "every" / name) == sumo_file(tmp_path / "sparse" / name), name
    traj = [pd.read_parquet(tmp_path / d / "trajectories.parquet") for d in ("every", "sparse")]
    pd.testing.assert_frame_equal(traj[0], traj[1])
    assert len(traj[0]) > 30_000
    configs = [json.loads((tmp_path / d / "config.json").read_text())["config"] for d in ("every", "sparse")]
    assert [c["full_read_every_steps"] for c in configs] == [1, 10]
