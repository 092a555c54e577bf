"""Who drives a run's vehicles: the Newell controller (every policy but one) or SUMO's own models.

The policy spec `sumo[:lcCooperative=X,...]` puts SUMO's Krauss car-following and LC2013 lane changing
in charge; the World reads that driver mode from the spec here, so the simulation needs no policy object.
"""

from __future__ import annotations

from coopsumo.runio import UsageError
from coopsumo.validation import SUMO_LC_LIMITS, spec_number

LC_KEYS = ("lcCooperative", "lcSpeedGain", "lcStrategic", "lcKeepRight", "lcAssertive")
"""LC2013 parameters a `sumo:` spec may set on every vehicle"""


class PolicySpecError(UsageError):
    """A policy spec that cannot be parsed (a usage error)."""


def sumo_models(spec: str) -> bool:
    """True when the policy spec puts SUMO's own models in charge (`sumo` or `sumo:...`)."""
    return spec == "sumo" or spec.startswith("sumo:")


def sumo_lc_params(spec: str) -> dict[str, float]:
    """The LC2013 parameters of `sumo` or `sumo:lcCooperative=0.5,lcSpeedGain=1` (empty for plain `sumo`)."""
    params: dict[str, float] = {}
    body = spec[len("sumo:") :] if spec.startswith("sumo:") else ""
    for item in filter(None, body.split(",")):
        key, sep, value = item.partition("=")
        if not sep or key not in LC_KEYS:
            raise PolicySpecError(f"bad sumo policy parameter {item!r}; expected KEY=VALUE, KEY in {LC_KEYS}")
        try:
            params[key] = spec_number("sumo", key, value, SUMO_LC_LIMITS)  # finite and in range (nan refused)
        except ValueError as err:
            raise PolicySpecError(str(err)) from None
    return params
