"""Who drives a run's vehicles: the Newell controller (every policy but one) or SUMO's own models.

The policy spec `sumo[:lcCooperative=X,...]` puts SUMO's Krauss car-following and LC2013 lane changing
in charge; the World reads that driver mode from the spec here, so the simulation needs no policy object.
"""

from __future__ import annotations

from coopsumo.policy_spec import PolicySpecError, parse_policy

LC_KEYS = ("lcCooperative", "lcSpeedGain", "lcStrategic", "lcKeepRight", "lcAssertive")
"""LC2013 parameters a `sumo:` spec may set on every vehicle"""


def sumo_models(spec: str) -> bool:
    """True when the policy spec puts SUMO's own models in charge (`sumo` or `sumo:...`)."""
    return spec == "sumo" or spec.startswith("sumo:")


def sumo_lc_params(spec: str) -> dict[str, float]:
    """The LC2013 parameters of `sumo` or `sumo:lcCooperative=0.5,lcSpeedGain=1` (empty for plain `sumo`)."""
    parsed = parse_policy(spec)  # policy_spec: the one grammar
    if parsed.name != "sumo":
        raise PolicySpecError(f"policy {spec!r} is not a sumo policy")
    return parsed.values()
