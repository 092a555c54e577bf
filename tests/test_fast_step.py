"""The controller's step in C (fast.sight, decide, after_step, advanced_table) equals its numpy definition
(controller, vehicle_table) bit for bit: on random roads, on hand-made cases, and over whole SUMO runs."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pandas as pd
import pytest
from conftest import TIMING_KEYS, sim_config

from coopsumo.agents.policies import make_policy
from coopsumo.agents.rollout import run
from coopsumo.config import AccidentConfig, ControlConfig
from coopsumo.sim import accident, controller, fast, physics
from coopsumo.sim import vehicle_table as vt

LANES = 3
SIZE = 400  # vehicle numbers in the state arrays
CONTROLS = controller.Controls(ControlConfig(), AccidentConfig(enabled=True, x_m=200.0), LANES, 3.2)


def state(rng: np.random.Generator, nums: np.ndarray, lane: np.ndarray) -> SimpleNamespace:
    """Per-number state: expected speeds, about one vehicle in four changing lanes (into a lane on the road or from
    one), the accident's hold state at random."""
    lc_left = np.zeros(SIZE)
    lc_from, lc_to = np.full(SIZE, -1, np.int64), np.full(SIZE, -1, np.int64)
    changing = nums[rng.random(len(nums)) < 0.25]
    own = lane[np.searchsorted(nums, changing)]
    side = np.clip(own + rng.choice([-1, 1], len(changing)), 0, LANES - 1)
    leaving = rng.random(len(changing)) < 0.5
    lc_from[changing] = np.where(leaving, own, side)
    lc_to[changing] = np.where(leaving, side, own)
    lc_left[changing] = rng.choice([0.05, 0.1, 1.0, 2.0, 3.9, 4.0], len(changing))
    return SimpleNamespace(v_exp=rng.uniform(20.0, 33.0, SIZE), lc_left_s=lc_left, lc_from=lc_from, lc_to=lc_to,
                           hold=rng.integers(0, 3, SIZE).astype(np.int8))  # fmt: skip


def road(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    """Sorted vehicle numbers, lanes, positions (m; some on a 2 m grid so that vehicles meet and changes conflict,
    some past the accident at 200 m), speeds (m/s; some standing)."""
    nums = np.sort(rng.choice(SIZE, n, replace=False)).astype(np.int64)
    lane = rng.integers(0, LANES, n).astype(np.int64)
    pos = np.where(rng.random(n) < 0.4, 2.0 * np.round(rng.uniform(0, 150, n)), rng.uniform(0, 300, n))
    speed = np.where(rng.random(n) < 0.2, rng.choice([0.0, 0.05], n), rng.uniform(0, 30, n))
    return nums, lane, pos, speed


def copy(s: SimpleNamespace) -> SimpleNamespace:
    return SimpleNamespace(**{k: v.copy() for k, v in vars(s).items()})


def same(a: Any, b: Any, what: str) -> None:
    a, b = np.asarray(a), np.asarray(b)
    assert a.dtype == b.dtype and a.shape == b.shape, (what, a.dtype, b.dtype, a.shape, b.shape)
    assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), what
    if a.dtype.kind == "f":  # the sign of a zero too
        assert np.array_equal(np.signbit(a), np.signbit(b)), what


def same_sight(got: controller.Sight, ref: controller.Sight) -> None:
    for f in ("v_exp", "other", "busy", "leader_gap", "leader_speed", "feasible"):
        same(getattr(got, f), getattr(ref, f), f)
    for f in dataclasses.fields(ref.occ):
        same(getattr(got.occ, f.name), getattr(ref.occ, f.name), f"occ.{f.name}")
    for f in dataclasses.fields(ref.nb):
        same(getattr(got.nb, f.name), getattr(ref.nb, f.name), f"nb.{f.name}")
        same(getattr(got.around, f.name), getattr(ref.around, f.name), f"around.{f.name}")


@pytest.mark.parametrize("seed", range(30))
def test_sight_equals_the_definition(seed: int) -> None:
    rng = np.random.default_rng(seed)
    nums, lane, pos, speed = road(rng, int(rng.integers(0, 80)))
    s = state(rng, nums, lane)
    same_sight(fast.sight(nums, lane, pos, speed, s, CONTROLS), controller.sight(nums, lane, pos, speed, s, CONTROLS))


@pytest.mark.parametrize("seed", range(60))
def test_decide_equals_the_definition(seed: int) -> None:
    """Every path: lane changes accepted, refused and in conflict (or none at all), the accident inactive or
    drawing, held vehicles redrawn or not, speeds equal to the ones last sent or not (NaN: none sent)."""
    rng = np.random.default_rng(1000 + seed)
    n = int(rng.integers(0, 80))
    nums, lane, pos, speed = road(rng, n)
    s = state(rng, nums, lane)
    seen = controller.sight(nums, lane, pos, speed, s, CONTROLS)
    actions = rng.integers(0, 4, n) if seed % 4 else rng.choice([physics.SPEEDUP, physics.NONE], n)
    p = [0.0, 0.3, 1.0][seed % 3]
    draw = accident.HoldDraw(p, rng.random(n) if p > 0 else np.zeros(0), bool(seed % 2))
    sent = np.where(rng.random(SIZE) < 0.1, np.nan, rng.uniform(0, 30, SIZE))
    first = controller.decide(nums, lane, pos, speed, seen, actions, copy(s), sent, draw, CONTROLS)
    sent[nums[::2]] = first.speeds[::2]  # half of them sent this speed already
    s_ref, s_got = copy(s), copy(s)
    ref = controller.decide(nums, lane, pos, speed, seen, actions, s_ref, sent, draw, CONTROLS)
    got = fast.decide(nums, lane, pos, speed, seen, actions, s_got, sent, draw, CONTROLS)
    for f in ref._fields:
        same(getattr(got, f), getattr(ref, f), f)
    for k in vars(s_ref):
        same(getattr(s_got, k), getattr(s_ref, k), k)
    if n >= 20 and seed % 4:
        assert ref.ok.any() or ref.rejected.any()  # the random actions asked for changes
    assert not ref.changed[::2].any()


def test_decide_refuses_the_rear_of_two_changes_into_one_lane_and_stops_a_held_vehicle() -> None:
    """A hand-made case, so that the comparison above cannot pass on two equal mistakes."""
    nums = np.array([0, 1, 2])
    lane = np.array([0, 2, 1])
    pos = np.array([50.0, 47.0, 195.0])  # 0 and 1 both move into lane 1, 1 only 3 m behind 0; 2 at the accident
    speed = np.array([10.0, 10.0, 0.0])
    s = SimpleNamespace(v_exp=np.full(3, 30.0), lc_left_s=np.zeros(3), lc_from=np.full(3, -1),
                        lc_to=np.full(3, -1), hold=np.array([0, 0, accident.HELD], np.int8))  # fmt: skip
    seen = fast.sight(nums, lane, pos, speed, s, CONTROLS)
    actions = np.array([physics.LEFT, physics.RIGHT, physics.SPEEDUP])
    draw = accident.HoldDraw(1.0, np.zeros(3), False)
    d = fast.decide(nums, lane, pos, speed, seen, actions, s, np.full(3, np.nan), draw, CONTROLS)
    assert d.ok.tolist() == [True, False, False] and d.rejected.tolist() == [False, True, False]
    assert s.lc_left_s.tolist() == [4.0, 0.0, 0.0] and s.lc_to[0] == 1
    assert s.hold[2] == accident.HELD and d.speeds[2] == 0.0  # 5 m before the obstacle, standing: stays
    assert d.changed.all()


@pytest.mark.parametrize("seed", range(30))
def test_after_step_equals_the_definition(seed: int) -> None:
    rng = np.random.default_rng(2000 + seed)
    nums, lane, pos, _ = road(rng, int(rng.integers(0, 80)))
    s = state(rng, nums, lane)
    s_ref, s_got = copy(s), copy(s)
    same(fast.after_step(nums, lane, pos, s_got, CONTROLS), controller.after_step(nums, lane, pos, s_ref, CONTROLS),
         "rows")  # fmt: skip
    same(s_got.lc_left_s, s_ref.lc_left_s, "lc_left_s")


@pytest.mark.parametrize("seed", range(30))
def test_advanced_table_equals_the_definition(seed: int) -> None:
    rng = np.random.default_rng(3000 + seed)
    nums, lane, pos, speed = road(rng, int(rng.integers(0, 80)))
    table = vt.VehicleTable(nums, lane, pos, speed)
    sent = rng.uniform(0, 30, SIZE)
    if seed % 5 == 0 and len(nums):
        sent[rng.choice(nums)] = np.nan  # one never sent a speed: no advanced table
    switch_to = np.where(rng.random(len(nums)) < 0.2, rng.integers(0, LANES, len(nums)), -1)
    arrived = rng.choice(np.concatenate([nums, [SIZE + 1]]), int(rng.integers(0, 4)))
    ref = vt.advanced_table(table, sent, switch_to, arrived, 0.1)
    got = fast.advanced_table(table, sent, switch_to, arrived, 0.1)
    assert (got is None) == (ref is None)
    if ref is not None and got is not None:
        for f in ("nums", "lane", "pos", "speed"):
            same(getattr(got, f), getattr(ref, f), f)


def test_the_step_kernels_refuse_numbers_outside_the_state() -> None:
    nums, lane = np.array([0, SIZE + 5]), np.zeros(2, np.int64)
    s = state(np.random.default_rng(0), np.array([0]), np.zeros(1, np.int64))
    with pytest.raises(IndexError, match="vehicle number"):
        fast.sight(nums, lane, np.zeros(2), np.zeros(2), s, CONTROLS)
    with pytest.raises(IndexError, match="vehicle number"):
        fast.after_step(nums, lane, np.zeros(2), s, CONTROLS)


def _outputs(run_dir: Path, summary: dict[str, Any]) -> dict[str, Any]:
    files = {p.name: p.read_bytes() for p in run_dir.glob("*.xml") if p.name != "detectors.add.xml"}
    return {"summary": {k: v for k, v in summary.items() if k not in TIMING_KEYS},
            "trajectories": pd.read_parquet(run_dir / "trajectories.parquet"), **files}  # fmt: skip


@pytest.mark.parametrize("policy", ["random", "mobil"])
def test_a_run_through_the_accident_is_the_same_with_the_definitions(
    policy: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The world driven by the C step and by the numpy definitions: the same summary, trajectories and SUMO
    outputs (loops, FCD, tripinfo) on an accident run with lane changes."""
    from coopsumo.config import OutputConfig

    base = sim_config(lanes=3, t_up_s=1.0, steps=2400, seed=5, policy=policy)
    cfg = dataclasses.replace(base, accident=AccidentConfig(enabled=True, x_m=900.0, start_step=200,
                                                            duration_steps=1000))  # fmt: skip
    outs = []
    for name in ("fast", "definitions"):
        if name == "definitions":
            for f in ("sight", "decide", "after_step"):
                monkeypatch.setattr(fast, f, getattr(controller, f))
            monkeypatch.setattr(fast, "advanced_table", vt.advanced_table)
        run_dir = tmp_path / name
        run_dir.mkdir()
        summary = run(cfg, make_policy(policy, np.random.default_rng(1)), run_dir, trajectories=True,
                      progress=False, outputs=OutputConfig(fcd_period_s=1.0, tripinfo=True))  # fmt: skip
        outs.append(_outputs(run_dir, summary))
    fast_out, ref_out = outs
    assert fast_out["summary"]["lane_changes"] > 50
    assert fast_out["summary"] == ref_out["summary"]
    pd.testing.assert_frame_equal(fast_out["trajectories"], ref_out["trajectories"])
    for name in ("detectors.xml", "fcd.xml", "tripinfo.xml"):  # after SUMO's header, which names the run folder
        body = fast_out[name].split(b"-->", 1)[-1]
        assert body.count(b"\n") > 10 and body == ref_out[name].split(b"-->", 1)[-1], name
