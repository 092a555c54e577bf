"""Issue 82, probe 14, F4: `train --resume` took a checkpoint whose values were each inside their wide limits but
impossible for its own road and reward (a log speed of 65 m/s on a 33.34 m/s road, a lane change every vehicle step,
reward terms of the wrong sign, replay rewards and speed errors of 9e5, Adam's step 1 after hundreds of updates).
agents/checkpoint_bounds.py bounds each by what the checkpoint's configuration lets a training make; a real
checkpoint of the default learner passes, each spoiled one is one line and left as it was."""

from __future__ import annotations

import copy
import shutil
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
import torch
from conftest import interrupted_at_step_20
from test_corrupt_files import one_line, snapshot

from coopsumo.agents import train_cli as train
from coopsumo.agents.file_checks import checkpoint_problem
from coopsumo.config import SimConfig, TrainConfig
from coopsumo.dqn_config import DQN_PRESETS


@pytest.fixture(scope="module")
def checkpoint_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The default learner interrupted at step 20, its log window 5 steps long, 5 gradient updates made."""
    out = tmp_path_factory.mktemp("bounds") / "run"
    dqn = replace(DQN_PRESETS["default"], learn_start_steps=5, batch_size=8, decision_interval_steps=1,
                  select_every_steps=0, stacked_updates=False)  # fmt: skip
    sim = SimConfig(steps=40, seed=3, policy="dqn")
    sim = replace(sim, reward=replace(sim.reward, alpha=1.0))
    cfg = TrainConfig(sim=sim, dqn=dqn, eval_steps=0, log_every_steps=15,
                      checkpoint_every_steps=20)  # fmt: skip
    interrupted_at_step_20(cfg, out).replace(out / "checkpoint.pt")
    return out


def _state(folder: Path) -> dict[str, Any]:
    return copy.deepcopy(torch.load(folder / "checkpoint.pt", weights_only=True))


def _window(name: str, value: Callable[[dict[str, Any]], float]) -> Callable[[dict[str, Any]], None]:
    return lambda s: s["window"].update({name: value(s["window"])})


def _replay(name: str, value: float) -> Callable[[dict[str, Any]], None]:
    def change(s: dict[str, Any]) -> None:
        s["learner"]["buffer"]["data"][name][: s["learner"]["buffer"]["size"]] = value

    return change


def _every_step(s: dict[str, Any]) -> None:
    """10,000 vehicle steps in the 5-step window (at most a jam's 3,000 vehicles on 3 lanes a step), each starting a
    lane change: at most 250 changes of 4 s fit in their time, one more for each vehicle the window can have seen."""
    s["window"].update(vehicle_steps=10_000, samples=10_000, lane_changes=10_000)


def _adam_step(s: dict[str, Any]) -> None:
    for moments in s["learner"]["optimizer"]["state"].values():
        moments["step"] = torch.tensor(1.0)


CASES: dict[str, tuple[Callable[[dict[str, Any]], None], str]] = {
    "speeds above the road's": (_window("speed_sum", lambda w: 60.0 * w["vehicle_steps"]), "above its road's fastest"),
    "a lane change every vehicle step": (_every_step, "could start"),
    "a positive lane-change term": (_window("r_lane_change", lambda w: 5.0), "lane-change term is positive"),
    "a negative flow term": (_window("r_flow", lambda w: -5.0), "flow term negative"),
    "replay rewards of 9e5": (_replay("rewards", 9e5), "replay reward of 900000"),
    "replay speed errors of 9e5": (_replay("features", 9e5), "replay speed error of 900000"),
    "Adam's step 1": (_adam_step, "Adam's step 1"),
}


def test_the_real_checkpoint_holds_what_the_cases_spoil(checkpoint_folder: Path) -> None:
    state = _state(checkpoint_folder)
    assert checkpoint_problem(state) is None
    window, learner = state["window"], state["learner"]
    assert window["vehicle_steps"] > 0 and window["speed_sum"] > 0 and learner["updates"] >= 5
    assert learner["buffer"]["size"] > 0 and learner["optimizer"]["state"]


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_checkpoint_beyond_its_configuration_is_one_line_and_kept(
    case: str, checkpoint_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    change, fragment = CASES[case]
    out = tmp_path / "run"
    shutil.copytree(checkpoint_folder, out)
    state = _state(out)
    change(state)
    torch.save(state, out / "checkpoint.pt")
    before = snapshot(tmp_path)
    code = train.main(["--resume", "--quiet", "--out", str(out)])
    one_line(code, capsys.readouterr().err, "checkpoint", fragment)
    assert snapshot(tmp_path) == before
