"""The stop-and-go wave measure (report.bottleneck.lane_jams) on a real SUMO disturbance: vehicles in dense
traffic forced to stop for 90 s make a jam whose front travels upstream, and it is counted; the same
traffic without the disturbance has none."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from coopsumo.agents.policies import make_policy
from coopsumo.agents.rollout import run
from coopsumo.config import AccidentConfig, SimConfig
from coopsumo.report import bottleneck as bn

pytestmark = pytest.mark.sumo


def _waves(tmp_path: Path, make_sim_config: Callable[..., SimConfig], accident: AccidentConfig,
           steps: int = 3600) -> list[bn.Jam]:  # fmt: skip
    cfg = make_sim_config(lanes=3, t_up_s=0.7, steps=steps, seed=3, policy="keep", accident=accident)
    summary = run(cfg, make_policy("keep", np.random.default_rng(0)), tmp_path, trajectories=True, progress=False,
                  trajectory_every=5)  # fmt: skip
    assert summary["collisions"] == 0 and summary["teleports"] == 0
    traj = pd.read_parquet(tmp_path / "trajectories.parquet")
    return bn.lane_jams(traj, accident.x_m, cfg.steps * cfg.control.dt_s, 5.0, 25.0)


def test_a_forced_stop_in_dense_traffic_makes_waves_that_travel_upstream(
    tmp_path: Path, make_sim_config: Callable[..., SimConfig]
) -> None:
    # dense traffic (5,140 veh/h on 3 lanes, near the Newell capacity); the first vehicle reaching x = 1,300 m
    # in each lane after t = 60 s brakes to a stop there and stands until t = 150 s (no redraw before the window
    # ends), the vehicles behind it too; then the jam dissolves from its front while the inflow feeds its tail.
    # (A 30 s stop is not enough: the Newell controller restarts a short queue almost at once, its vehicles
    # standing 8 m apart may go at 8.8 m/s in the first step, so no slow region outlives the stop.)
    stop = AccidentConfig(enabled=True, start_step=600, duration_steps=900, redraw_s=120.0)
    (tmp_path / "stop").mkdir()
    jams = _waves(tmp_path / "stop", make_sim_config, stop)
    waves = [j for j in jams if j.moving]
    assert len(waves) >= 1, jams
    for w in waves:
        assert -30.0 <= w.front_speed_kmh <= -5.0 and w.front_travel_m >= 100.0
        assert w.start_s >= 60.0  # not before the disturbance
    (tmp_path / "none").mkdir()
    quiet = _waves(tmp_path / "none", make_sim_config, AccidentConfig(enabled=False), steps=1800)
    assert [j for j in quiet if j.moving] == []
