"""A road of one's own (its length, speed limit, loop spacing and the accident's position as simulate's flags) and the
reward's weights as train's flags: the limits, each refusal one line with exit code 2 and nothing written, a real run
on such a road (its network, loops and speeds), and the weights reaching the training's configuration."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from coopsumo import simulate
from coopsumo.agents import train_cli
from coopsumo.config import AccidentConfig, DemandConfig, RewardConfig, RoadConfig, SimConfig, TrainConfig, road_problem
from coopsumo.errors import ConfigError, UsageError
from coopsumo.sim.world import draw_vehicle

ROOT = Path(__file__).resolve().parent.parent


def test_the_roads_limits() -> None:
    fine, accident = RoadConfig(), AccidentConfig(enabled=True)
    assert road_problem(fine, accident) is None
    for road, acc, fragment in (
        (replace(fine, length_m=99.0), accident, "road length (m) must be a finite number >= 100"),
        (replace(fine, speed_limit_mps=float("nan")), accident, "speed limit (m/s) must be"),
        (replace(fine, loop_spacing_m=5.0), accident, "loop spacing (m) must be"),
        (replace(fine, length_m=150.0, loop_spacing_m=200.0), AccidentConfig(), "leaves no loop on the 150 m road"),
        (replace(fine, length_m=1300.0), accident, "the accident at 1300 m is not on the 1300 m road"),
    ):
        assert fragment in (road_problem(road, acc) or ""), fragment
        with pytest.raises(ConfigError):
            SimConfig(road=road, accident=acc).validate()
    assert road_problem(replace(fine, length_m=1300.0), AccidentConfig()) is None  # no accident: none to place
    for weights in ({"w_speed": -1.0}, {"w_flow": 1001.0}, {"w_flow": float("inf")}):
        with pytest.raises(ConfigError, match="w_(speed|flow) must be"):
            SimConfig(reward=RewardConfig(**weights)).validate()


def test_a_speed_limit_caps_the_expected_speeds_and_the_default_changes_none() -> None:
    demand = DemandConfig()
    default = [draw_vehicle(np.random.default_rng(3), demand, RoadConfig(lanes=3)) for _ in range(1)]
    capped, plain = np.random.default_rng(7), np.random.default_rng(7)
    draws = [(draw_vehicle(capped, demand, RoadConfig(speed_limit_mps=20.0)),
              draw_vehicle(plain, demand, RoadConfig())) for _ in range(200)]  # fmt: skip
    assert all(c[0] == min(p[0], 20.0) and c[1] == p[1] for c, p in draws)
    assert any(p[0] > 20.0 for _, p in draws) and max(p[0] for _, p in draws) <= 110 / 3.6  # below 33.34: untouched
    assert default[0][0] == draw_vehicle(np.random.default_rng(3), demand, RoadConfig(speed_limit_mps=70.0))[0]


@pytest.mark.parametrize(("args", "fragment"), [
    (["--scenario", "accident", "--road-length", "1000"],
     "--road-length 1000 is too short for its accident: the default --accident-x 1300 m must lie below the road's end"),
    (["--scenario", "accident", "--road-length", "800", "--accident-x", "900"], "--accident-x 900 m must lie below"),
    (["--road-length", "500", "--loop-spacing", "600"], "--loop-spacing 600 leaves no loop on the 500 m road"),
    (["--accident-x", "500"], "--accident-x needs --scenario accident"),
    (["--net-file", "nothing.net.xml"], "--net-file: no such file: nothing.net.xml"),  # probe 20, O2
    (["--net-file", __file__], f"--net-file: {__file__} is not a SUMO network sumolib can read"),
])  # fmt: skip
def test_a_road_the_world_cannot_drive_is_refused_in_one_line(args: list[str], fragment: str, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    out = tmp_path / "run"
    assert simulate.main([*args, "--steps", "100", "--quiet", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and fragment in err[0], err
    assert list(tmp_path.iterdir()) == []  # nothing written


@pytest.mark.parametrize("flag", ["--road-length", "--speed-limit", "--loop-spacing", "--accident-x"])
def test_a_road_setting_out_of_range_is_refused_by_its_flag(flag: str, tmp_path: Path) -> None:
    res = subprocess.run([sys.executable, "-m", "coopsumo", "simulate", "--scenario", "accident", flag, "0",
                          "--out", str(tmp_path / "run")], capture_output=True, text=True, check=False)  # fmt: skip
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and f"argument {flag}: must be" in res.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.sumo
def test_a_run_on_a_road_of_ones_own(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                     capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """600 m, loops every 100 m, 15 m/s, the accident at 400 m: SUMO gets that network, every vehicle stays at the
    limit, the loops report where they stand; --net-file on that network names the flags that build it."""
    monkeypatch.setenv("COOPSUMO_NETS_DIR", str(tmp_path / "nets"))
    out = tmp_path / "run"
    assert simulate.main(["--scenario", "accident", "--road-length", "600", "--loop-spacing", "100", "--speed-limit",
                          "15", "--accident-x", "400", "--t-up", "2", "--steps", "900", "--trajectories", "--quiet",
                          "--out", str(out)]) == 0  # fmt: skip
    cfg = json.loads((out / "config.json").read_text())["config"]
    assert (cfg["road"]["length_m"], cfg["road"]["speed_limit_mps"], cfg["accident"]["x_m"]) == (600, 15, 400)
    traj = pd.read_parquet(out / "trajectories.parquet")
    assert traj["speed_mps"].max() <= 15.0 + 1e-9 and traj["pos_m"].max() <= 600.0
    loops = {float(x) for x in pd.Series(
        [line.split('pos="')[1].split('"')[0] for line in (out / "detectors.add.xml").read_text().splitlines()
         if "inductionLoop" in line])}  # fmt: skip
    assert loops == {100.0, 200.0, 300.0, 400.0, 500.0}
    summary = json.loads((out / "summary.json").read_text())
    assert summary["table_mismatch_step"] == -1 and summary["collisions"] == 0 and summary["arrived"] > 0
    net = tmp_path / "nets" / "highway_3lanes_600m_w3.2_v15.net.xml"
    capsys.readouterr()
    assert simulate.main(["--net-file", str(net), "--out", str(tmp_path / "mine")]) == 2
    err = capsys.readouterr().err
    assert "is such a road: give it as --lanes 3 --road-length 600 --speed-limit 15" in err
    assert not (tmp_path / "mine").exists()


def test_the_reward_weights_are_trains_flags() -> None:
    args = train_cli.build_parser().parse_args(["--w-speed", "2", "--w-flow", "0", "--steps", "100"])
    cfg = train_cli.config_from_args(args)
    assert (cfg.sim.reward.w_speed, cfg.sim.reward.w_flow, cfg.sim.reward.alpha) == (2.0, 0.0, 0.0)
    plain = train_cli.config_from_args(train_cli.build_parser().parse_args([]))
    assert plain.sim.reward == RewardConfig() and (RewardConfig.w_speed, RewardConfig.w_flow) == (1.0, 1.0)
    with pytest.raises(UsageError, match="--w-flow 1.0 differs from the checkpoint's 0.0"):
        train_cli.check_resume_flags(["--resume", "--out", "x", "--w-flow", "1"], cfg)
    train_cli.check_resume_flags(["--resume", "--out", "x", "--w-flow", "0"], cfg)  # the same value: fine
    assert isinstance(cfg, TrainConfig)


@pytest.mark.parametrize("value", ["-1", "1001", "nan", "x"])
def test_a_reward_weight_out_of_range_is_refused(value: str, tmp_path: Path) -> None:
    res = subprocess.run([sys.executable, "-m", "coopsumo", "train", "--w-flow", value, "--out", str(tmp_path / "t")],
                         capture_output=True, text=True, check=False)  # fmt: skip
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "argument --w-flow: must be" in res.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_net_file_that_is_a_named_pipe_is_refused_not_waited_on(tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 82, probe 18, O1: sumolib waited for ever on `--net-file FIFO`; now one line, as every file flag."""
    fifo = tmp_path / "net.xml"
    os.mkfifo(fifo)
    assert simulate.main(["--net-file", str(fifo), "--steps", "100", "--quiet", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"simulate: error: --net-file: {fifo} is not a regular file but a named pipe"], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["net.xml"]
