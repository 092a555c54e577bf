"""Issue 82: a run's physical settings that have no flag of their own (config.SIM_LIMITS) are checked by
SimConfig.validate, so that a configuration read back (a checkpoint, a config.json, a model file) with a step of 0 s,
a negative spread or a road SUMO refuses is one line naming the setting, never a division by zero or a traceback."""

from __future__ import annotations

import dataclasses

import pytest

from coopsumo.config import SIM_LIMITS, SimConfig
from coopsumo.errors import ConfigError


def with_value(name: str, value: float) -> SimConfig:
    part, field = name.split(".")
    base = SimConfig()
    return dataclasses.replace(base, **{part: dataclasses.replace(getattr(base, part), **{field: value})})


@pytest.mark.parametrize("name", sorted(SIM_LIMITS))
def test_each_setting_outside_its_limits_is_named(name: str) -> None:
    low, high, low_open, high_open = SIM_LIMITS[name]
    SimConfig().validate()  # the defaults lie inside every limit
    for bad in (low - 1.0 if not low_open else low, high + 1.0 if not high_open else high, float("nan")):
        with pytest.raises(ConfigError, match=rf"^{name} must be .*, got "):
            with_value(name, bad).validate()


@pytest.mark.parametrize(("below", "above"), [("demand.v_exp_min_kmh", "demand.v_exp_max_kmh"),
                                              ("reward.v_min_mps", "reward.v_max_mps")])  # fmt: skip
def test_a_lower_bound_above_its_upper_is_refused(below: str, above: str) -> None:
    cfg = with_value(below, 60.0)
    cfg = dataclasses.replace(cfg, **{above.split(".")[0]: dataclasses.replace(
        getattr(cfg, above.split(".")[0]), **{above.split(".")[1]: 50.0})})
    with pytest.raises(ConfigError, match=rf"^{below} must be below {above}, got 60 and 50"):
        cfg.validate()
