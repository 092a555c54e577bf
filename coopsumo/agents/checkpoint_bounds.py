"""A training checkpoint's values against what its own configuration lets a training make (issue 82, probe 14, F4).

file_checks.checkpoint_problem first checks each value inside its record's wide limits (record_schemas); these are
the bounds its road, its vehicles and its reward give, each derived from the checkpoint's configuration:

- the log window's speeds at most the fastest any vehicle drives (config.fastest_mps) per vehicle step;
- its lane changes at most what its vehicles could start one after another (a change takes control.t_change_s):
  the vehicle steps' time over a change's, plus one for every vehicle the window can have seen (a jam's on the road,
  and one a lane for each of its steps entering);
- its reward terms of their signs (sim/reward.reward_parts: -alpha on a change, w_flow q >= 0) and their sizes;
- a replay transition's reward at most its decision interval's steps of the largest speed and flow terms plus the
  largest alpha times the changes one vehicle can start in the interval; its speed errors at most the fastest speed;
  an alpha-conditioned memory's alphas inside 0 and the largest alpha drawn;
- Adam's step count the updates the learner made (torch counts one a parameter at each step of the optimizer).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import torch

from coopsumo.config import fastest_mps

ROUNDING = 1e-5
"""relative slack for float32 sums and the log's rounding"""


def bounds_problem(state: Mapping[str, Any]) -> str | None:
    """Why the checkpoint `state` (its structure and wide limits already checked) holds a value its configuration
    cannot give, or None; a configuration missing a value these read is the configuration check's to name."""
    config, window, learner = state["config"], state["window"], state["learner"]
    try:
        sim, dqn = config["sim"], config["dqn"]
        limits = _limits(sim, dqn)
        every, lanes = int(config["log_every_steps"]), int(sim["road"]["lanes"])
    except (KeyError, TypeError, ValueError, ZeroDivisionError, OverflowError):
        return None
    if limits is None:
        return None
    window_steps = int(state["step"]) % every if every > 0 else 0
    return (_window_problem(window, limits, window_steps, lanes)
            or _replay_problem(learner["buffer"], limits, sim)
            or _adam_problem(learner["optimizer"], int(learner["updates"]), dqn))


def _limits(sim: Mapping[str, Any], dqn: Mapping[str, Any]) -> dict[str, float] | None:
    """The bounds the configuration gives: fastest speed (m/s), a step's speed and flow terms, the largest alpha, the
    changes a vehicle can start in a decision interval and in a step's time, a jam's vehicles; None for settings
    outside their own ranges (the configuration's check names them, checkpoint_problem's caller)."""
    reward, control, road = sim["reward"], sim["control"], sim["road"]
    dt, change = float(control["dt_s"]), float(control["t_change_s"])
    settings = (dt, change, float(reward["v_max_mps"]) - float(reward["v_min_mps"]),
                float(reward["capacity_veh_h_per_lane"]), float(control["car_length_m"]),
                float(dqn.get("decision_interval_steps", 1)))  # fmt: skip
    if not all(math.isfinite(x) and x > 0 for x in settings):
        return None
    fastest = fastest_mps(sim)
    speed_term = float(reward["w_speed"]) * fastest / (float(reward["v_max_mps"]) - float(reward["v_min_mps"]))
    flow_term = float(reward["w_flow"]) * (3600.0 / dt) / float(reward["capacity_veh_h_per_lane"])  # a car a step
    alpha = float(dqn["alpha_draw_max"]) if dqn.get("alpha_conditioned") else float(reward["alpha"])
    interval = int(dqn.get("decision_interval_steps", 1))
    limits = {"fastest": fastest, "speed_term": speed_term, "flow_term": flow_term, "alpha": alpha,
            "interval": interval, "changes": 1.0 + interval * dt / change, "step_share": dt / change,
            "jam": 2 * int(road["lanes"]) * float(road["length_m"]) / float(control["car_length_m"])}  # fmt: skip
    return limits if all(math.isfinite(x) and x >= 0 for x in limits.values()) else None


def _window_problem(window: Mapping[str, Any], b: Mapping[str, float], steps: int, lanes: int) -> str | None:
    vehicle_steps, samples = float(window["vehicle_steps"]), float(window["samples"])
    if float(window["speed_sum"]) > b["fastest"] * vehicle_steps * (1 + ROUNDING):
        return (f"has a log window whose speeds sum to {window['speed_sum']:g} m/s over {window['vehicle_steps']} "
                f"vehicle steps, above its road's fastest {b['fastest']:g} m/s each")  # fmt: skip
    most = vehicle_steps * b["step_share"] + b["jam"] + steps * lanes
    if float(window["lane_changes"]) > most:
        return (f"has a log window of {window['lane_changes']} lane changes over {window['vehicle_steps']} vehicle "
                f"steps, more than its vehicles could start ({most:.0f}: a change takes its time)")  # fmt: skip
    slack = ROUNDING * max(samples, 1.0)
    sizes = {"r_speed": b["speed_term"], "r_flow": b["flow_term"], "r_lane_change": b["alpha"]}
    for name, size in sizes.items():
        value = float(window[name])
        if abs(value) > size * max(samples, 1.0) * (1 + ROUNDING) + slack:
            return f"has a log window whose {name} sums to {value:g} over {window['samples']} samples, above its size"
    if float(window["r_lane_change"]) > slack or float(window["r_flow"]) < -slack:
        return ("has a log window whose lane-change term is positive or flow term negative (the reward's terms are "
                f"-alpha and w_flow q: r_lane_change {window['r_lane_change']:g}, r_flow {window['r_flow']:g})")
    return None


def _replay_problem(buffer: Mapping[str, Any], b: Mapping[str, float], sim: Mapping[str, Any]) -> str | None:
    data, size = buffer["data"], int(buffer["size"])
    most = b["interval"] * (b["speed_term"] + b["flow_term"]) + b["alpha"] * b["changes"]
    rewards = data.get("rewards")
    if isinstance(rewards, torch.Tensor) and size and float(rewards[:size].abs().max()) > most * (1 + ROUNDING):
        return (f"has a replay reward of {float(rewards[:size].abs().max()):g} in magnitude, above the {most:g} one "
                "decision interval of its reward can give")  # fmt: skip
    frames = 3  # the speed errors of the observation's frames come first (agents/replay.GRID_SHAPE)
    for name in ("features", "next_features"):
        x = data.get(name)
        if isinstance(x, torch.Tensor) and x.dim() == 2 and size:
            err = float(x[:size, :frames].abs().max())
            if err > b["fastest"] * (1 + ROUNDING):
                return f"has a replay speed error of {err:g} m/s ({name}), above its road's fastest {b['fastest']:g}"
    alphas = data.get("alphas")
    if isinstance(alphas, torch.Tensor) and size and not 0 <= float(alphas[:size].min()) <= float(
            alphas[:size].max()) <= b["alpha"] * (1 + ROUNDING):  # fmt: skip
        return f"has replay alphas outside 0 and the largest alpha drawn, {b['alpha']:g}"
    return None


def _adam_problem(optimizer: Mapping[str, Any], updates: int, dqn: Mapping[str, Any]) -> str | None:
    if dqn.get("optimizer") != "adam":
        return None
    for index, moments in optimizer.get("state", {}).items():
        step = moments.get("step") if isinstance(moments, Mapping) else None
        count = float(step) if isinstance(step, torch.Tensor | int | float) and not isinstance(step, bool) else None
        if count is not None and math.isfinite(count) and count != updates:
            return (f"has Adam's step {count:g} for parameter {index} beside its {updates} gradient updates (one "
                    "step each)")  # fmt: skip
    return None
