"""The Gymnasium and PettingZoo environments treat bad input alike: every constructor parameter is checked as
passed (a ValueError naming it and the value), and step() after the end of an episode, before reset(), after
close() or after a failed reset() raises the same RuntimeError in both."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from coopsumo.config import DemandConfig, RoadConfig, SimConfig
from coopsumo.envs import HighwayEnv, HighwayParallelEnv
from coopsumo.envs.common import int_param
from coopsumo.sim.world import World

LIGHT = SimConfig(road=RoadConfig(lanes=2), demand=DemandConfig(t_up_s=4.0))
"""light traffic: few vehicles, fast steps (as in test_envs.py)"""
NOT_INTEGERS: list[Any] = [True, False, np.bool_(True), 2.0, 4.5, np.float64(3.0), "3", None]
INT_PARAMS = [(HighwayEnv, "warmup_steps"), (HighwayEnv, "max_steps"), (HighwayEnv, "decision_interval"),
              (HighwayParallelEnv, "max_steps"), (HighwayParallelEnv, "decision_interval")]  # fmt: skip
ENDED = r"^the episode has ended: call reset\(\) to start a new one$"
NO_EPISODE = r"^no episode is running: call reset\(\) before step\(\)"


def refusal(cls: type, **kwargs: Any) -> str:
    """The one-line ValueError message of cls(**kwargs) (SUMO never starts: constructors do not run it)."""
    with pytest.raises(ValueError) as raised:
        cls(**kwargs)
    message = str(raised.value)
    assert "\n" not in message
    return message


@pytest.mark.parametrize(("cls", "name"), INT_PARAMS)
@pytest.mark.parametrize("value", NOT_INTEGERS, ids=repr)
def test_integer_parameters_refuse_bools_floats_strings_and_none(cls: type, name: str, value: Any) -> None:
    """Before: decision_interval=True was accepted by both envs, None and '3' gave a bare TypeError from a
    comparison, a float max_steps or warmup_steps was reported as the derived step count."""
    message = refusal(cls, **{name: value})
    assert message.startswith(f"{name} must be an integer")
    assert message.endswith(f"got {value!r}")


def test_range_errors_name_the_parameter_and_the_value_passed() -> None:
    """Before: warmup_steps=0.5 with max_steps=4 said 'steps must be an integer, got 4.5' (their sum)."""
    assert refusal(HighwayEnv, warmup_steps=0.5, max_steps=4).endswith("warmup_steps must be an integer from 0 to "
                                                                       "10000000, got 0.5")  # fmt: skip
    assert refusal(HighwayEnv, warmup_steps=-1).startswith("warmup_steps must be")
    assert refusal(HighwayEnv, warmup_steps=-1).endswith("got -1")
    for cls in (HighwayEnv, HighwayParallelEnv):
        for name, value in (("max_steps", 0), ("max_steps", 10**12), ("decision_interval", 0)):
            message = refusal(cls, **{name: value})
            assert message.startswith(f"{name} must be an integer from ") and message.endswith(f"got {value}")
    # each in range, too many simulation steps together: named as passed, not as their sum alone
    message = refusal(HighwayEnv, warmup_steps=300, max_steps=2_000_000, decision_interval=5)
    assert message == ("warmup_steps + max_steps * decision_interval must be at most 10000000 simulation steps, "
                       "got 300 + 2000000 * 5 = 10000300")  # fmt: skip


def test_numpy_integers_are_integers() -> None:
    env = HighwayEnv(warmup_steps=np.int64(3), max_steps=np.int32(4), decision_interval=np.int64(2))
    assert (env.warmup_steps, env.max_steps, env.decision_interval, env.cfg.steps) == (3, 4, 2, 11)
    assert all(type(x) is int for x in (env.warmup_steps, env.max_steps, env.decision_interval))
    env.close()
    par = HighwayParallelEnv(max_steps=np.int64(30), decision_interval=np.int16(2))
    assert (par.max_steps, par.decision_interval) == (30, 2) and type(par.max_steps) is int
    par.close()
    assert int_param("n", np.uint8(7), 1) == 7


@pytest.mark.parametrize(
    ("cls", "kwargs", "start"),
    [
        (HighwayEnv, {"cfg": "light"}, "cfg must be a coopsumo.config.SimConfig or None, got str 'light'"),
        (HighwayEnv, {"cfg": {"steps": 5}}, "cfg must be"),
        (HighwayParallelEnv, {"cfg": "light"}, "cfg must be a coopsumo.config.SimConfig or None, got str 'light'"),
        (HighwayEnv, {"background": 3}, "background must be a policy spec"),  # was 'policy must be a string'
        (HighwayEnv, {"background": ""}, "background must be a policy spec"),  # was silently 'keep'
        (HighwayEnv, {"background": "sumo"}, "background must be a coopsumo policy, got 'sumo'"),  # ignored the agent
        (HighwayEnv, {"background": "sumo:lcCooperative=0.5"}, "background must be a coopsumo policy"),
        (HighwayEnv, {"model_path": 3}, "model_path must be a file path"),  # was 'model file not found: 3'
        (HighwayEnv, {"model_path": ""}, "model_path must be a file path"),  # was 'model file not found: .'
        (HighwayEnv, {"model_path": "m.pt", "background": "keep"}, "give either background or model_path"),
        (HighwayEnv, {"render_mode": "human"}, "render_mode must be None"),
    ],
)  # fmt: skip
def test_other_parameters_are_checked_as_passed(cls: type, kwargs: dict[str, Any], start: str) -> None:
    message = refusal(cls, **kwargs)
    assert message.startswith(start)
    value = next(iter(kwargs.values()))
    assert repr(value) in message or "give either" in message


def test_a_path_object_is_a_model_path(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="model file not found"):  # checked as a path: the file is looked for
        HighwayEnv(model_path=tmp_path / "missing.pt")


@pytest.mark.sumo
def test_gymnasium_env_refuses_step_after_the_end_before_reset_and_after_close() -> None:
    env = HighwayEnv(LIGHT, warmup_steps=0, max_steps=3)
    try:
        with pytest.raises(RuntimeError, match=NO_EPISODE):
            env.step(2)
        env.reset(seed=1)
        assert [env.step(2)[3] for _ in range(3)] == [False, False, True]
        for _ in range(2):  # every further step, not only the first
            with pytest.raises(RuntimeError, match=ENDED):
                env.step(2)
        env.reset(seed=1)  # a reset starts a new episode
        env.step(2)
        env.close()
        with pytest.raises(RuntimeError, match=NO_EPISODE):
            env.step(2)
    finally:
        env.close()


@pytest.mark.sumo
def test_parallel_env_refuses_step_after_truncation() -> None:
    """Before: a user stepped 35 steps of a 30-step episode; the steps after the end ran on."""
    env = HighwayParallelEnv(LIGHT, max_steps=30)
    try:
        with pytest.raises(RuntimeError, match=NO_EPISODE):
            env.step({})
        env.reset(seed=1)
        last: list[str] = []
        while env.agents:
            last = list(env.agents)
            _, _, terms, truncs, _ = env.step(dict.fromkeys(env.agents, 2))
        assert env.world is not None and env.world.step_count == 30
        assert all(truncs.values()) and not any(terms.values())
        for actions in ({}, dict.fromkeys(last, 2)):  # nothing to act for, or the agents that were truncated
            with pytest.raises(RuntimeError, match=ENDED):
                env.step(actions)
        assert env.world.step_count == 30  # nothing was simulated
        env.reset(seed=1)
        env.step(dict.fromkeys(env.agents, 2))
        env.close()
        with pytest.raises(RuntimeError, match=NO_EPISODE):
            env.step({})
    finally:
        env.close()


@pytest.mark.sumo
def test_parallel_env_ends_when_every_agent_terminated() -> None:
    """One vehicle an hour: the first leaves the road long before the next departs; its termination ends the
    episode (agents empty), and step() then raises as after truncation."""
    sparse = SimConfig(road=RoadConfig(lanes=2), demand=DemandConfig(t_up_s=3600.0))
    env = HighwayParallelEnv(sparse, max_steps=3000)
    try:
        env.reset(seed=2)
        assert env.agents == ["veh_0"]
        while env.agents:
            _, _, terms, truncs, _ = env.step({"veh_0": 2})
        assert terms == {"veh_0": True} and truncs == {"veh_0": False}
        assert env.world is not None and env.world.step_count < 3000
        with pytest.raises(RuntimeError, match=ENDED):
            env.step({})
    finally:
        env.close()


@pytest.mark.sumo
def test_a_failed_reset_leaves_no_episode_to_step(monkeypatch: pytest.MonkeyPatch) -> None:
    """Before: a reset that failed after the new World started left the old episode's state in place, and step()
    ran it on the new World."""

    def broken(self: World, grids: bool = True) -> Any:
        raise RuntimeError("SUMO failed")

    env = HighwayEnv(LIGHT, warmup_steps=5, max_steps=20)
    par = HighwayParallelEnv(LIGHT, max_steps=30)
    steps = {env: lambda: env.step(2), par: lambda: par.step(dict.fromkeys(par.agents, 2))}
    try:
        for which, step in steps.items():
            which.reset(seed=1)
            step()
            with monkeypatch.context() as patch:
                patch.setattr(World, "observe", broken)
                with pytest.raises(RuntimeError, match="SUMO failed"):
                    which.reset(seed=2)
            with pytest.raises(RuntimeError, match=NO_EPISODE):
                step()
            which.reset(seed=2)
            step()
            which.close()
    finally:
        env.close()
        par.close()


@pytest.mark.sumo
def test_reset_checks_the_seed_before_anything_changes() -> None:
    """Before: seed=True ran seed 1 in both envs; the Gymnasium env refused a numpy integer with gymnasium's own
    error and seed=-1 with gymnasium.error.Error (not a ValueError)."""
    env = HighwayEnv(LIGHT, warmup_steps=0, max_steps=20)
    par = HighwayParallelEnv(LIGHT, max_steps=30)
    try:
        for reset in (env.reset, par.reset):
            for seed in (True, -1, 2**31, 1.0, "1"):
                with pytest.raises(ValueError, match=f"seed must be an integer .*got {seed!r}"):
                    reset(seed=seed)
        _, info = env.reset(seed=np.int64(3))
        assert info["seed"] == 3 and type(info["seed"]) is int
        with pytest.raises(ValueError, match="seed"):
            env.reset(seed=True)
        env.step(2)  # a refused seed changed nothing: the episode runs on
    finally:
        env.close()
        par.close()
