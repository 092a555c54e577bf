"""The report's reading of claim (b) on the response of speed to alpha (response.py): response.csv, the response
surface figure, sweep.json's "response" entry, the report's section and its first lines; and alpha*'s sensitivity
(the secondary reading: leave one condition out, log and rank readings of the plane)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from coopsumo.files import write_atomic
from coopsumo.report.markdown import md_table, num
from coopsumo.studies.scenario2.measures import PlaneFitError, fit_plane
from coopsumo.studies.scenario2.plan import Profile
from coopsumo.studies.scenario2.response import (
    FAMILY_ALPHA,
    LEVEL,
    RESPONSE_ALPHAS,
    condition_responses,
    model_scores,
    trends,
)

RESPONSE_FIGURE = "fig6_response.png"
TRENDS = {"lanes": ("per lane", "restraint costs more speed as lanes are added (c_lanes < 0: the paper's alpha* "
                                "rising as the lane count falls)"),
          "load": ("per unit of load", "restraint costs less speed as the load per lane rises (c_load > 0: the "
                                       "paper's alpha* rising with the inflow)")}  # fmt: skip


def write_response(root: Path, evals: pd.DataFrame, kept: set[tuple[int, float]], kept_table: pd.DataFrame,
                   profile: Profile, meta: dict[str, Any], n_boot: int) -> dict[str, Any]:  # fmt: skip
    """response.csv and the surface figure from the evaluations; meta["response"] (the trends over the conditions
    `kept`, those that pass the gate) and meta["alpha_star_sensitivity"] (alpha*'s plane over kept_table). Returns
    the trends ({"error": why} when the study has fewer than two of RESPONSE_ALPHAS or no evaluations)."""
    from coopsumo.report.plots_sweep import response_surface_figure

    meta["alpha_star_sensitivity"] = sensitivity(kept_table, profile.alphas) if len(kept_table) else \
        {"error": "no condition passes the gate"}  # fmt: skip

    alphas = [a for a in profile.alphas if a in RESPONSE_ALPHAS]
    if len(alphas) < 2 or evals.empty:
        meta["response"] = {"error": f"the response needs at least two of the alphas {list(RESPONSE_ALPHAS)}"}
        return meta["response"]
    responses = condition_responses(model_scores(evals, profile.criterion, alphas), n_boot)
    write_atomic(root / "response.csv", lambda tmp: responses.table.to_csv(tmp, index=False))
    found = trends(responses, kept)
    found["alphas"] = alphas
    found["plan"] = profile.response_plan or None
    found["conditions"] = responses.table.to_dict("records")
    meta["response"] = found
    if len(responses.table):
        response_surface_figure(responses.table, root / RESPONSE_FIGURE,
                                f"speed's response to alpha ({LEVEL:.0%} intervals over models)")  # fmt: skip
    return found


def reading(profile: Profile) -> str:
    """Whether the response was fixed before these models ran (the plan's commit) or read after (exploratory)."""
    if profile.response_plan:
        return (f"**Confirmatory**: the measure, its trends and the rule for \"decided\" were fixed before these "
                f"models were trained, in commit `{profile.response_plan}` (docs/studies.md, \"Claim (b): the "
                "response of speed to alpha\").")  # fmt: skip
    return ("**Exploratory**: this measure was chosen after looking at these models (issue 79), so the reading "
            "proves nothing until models that did not suggest it confirm it under the plan in docs/studies.md "
            "(\"Claim (b): the response of speed to alpha\").")  # fmt: skip


def _p(p: float) -> str:
    return "p < 0.001" if p < 0.001 else f"p = {p:.3f}"


def _trend_line(name: str, entry: dict[str, Any]) -> str:
    unit, words = TRENDS[name]
    text = (f"- **{entry['verdict']}**: {words}: c_{name} = {entry['coef']:+.3f} m/s {unit}, {LEVEL:.0%} interval "
            f"over models [{entry['low']:+.3f}, {entry['high']:+.3f}], bootstrap {_p(entry['p'])}")  # fmt: skip
    if entry["decided"]:
        return text + f", decided under Holm's correction at {FAMILY_ALPHA:g}."
    needed = entry.get("models_to_decide")
    more = f"; about {needed} models per lane count and alpha would decide it if the estimate and the spread " \
        "stayed as measured" if needed else "; its interval excludes 0 but not under Holm's correction"  # fmt: skip
    return text + more + "."


def first_lines(found: dict[str, Any], profile: Profile) -> str:
    """What holds, in one line, for the report's top."""
    if "lanes" not in found:
        what = "the slope per condition only; no trend" if found.get("conditions") else "not read"
        return f"**Claim (b) on the response of speed to alpha**: {what} ({found.get('error', 'no response')})."
    kind = "confirmatory" if profile.response_plan else "exploratory"
    said = "; ".join(f"against {'lanes' if n == 'lanes' else 'load per lane'}, **{found[n]['verdict']}**"
                     for n in ("lanes", "load"))  # fmt: skip
    return f"**Claim (b) on the response of speed to alpha ({kind})**: {said} (section \"The response\")."


def response_section(found: dict[str, Any], profile: Profile) -> str:
    """The report's section, with its heading and a blank line after it."""
    table = pd.DataFrame(found.get("conditions", []))
    head = "## The response of speed to alpha (claim (b)'s primary measure)"
    return f"{head}\n\n{response_text(found, table, profile)}\n"


def response_text(found: dict[str, Any], table: pd.DataFrame, profile: Profile) -> str:
    """The report's section on the primary measure."""
    if "error" in found and "lanes" not in found:
        return f"Not read: {found['error']}."
    alphas = ", ".join(f"{a:g}" for a in found["alphas"])
    rows = [[str(int(r.lanes)), f"{r.load:g}", f"{r.t_up_s:g}", str(int(r.models)),
             f"{num(r.slope_mps, '{:+.3f}')} [{num(r.slope_low, '{:+.3f}')}, {num(r.slope_high, '{:+.3f}')}]"]
            for r in table.itertuples()]  # fmt: skip
    head = ["lanes", "load", "T_up (s)", "models per alpha", f"slope (m/s per doubling of 1 + alpha) [{LEVEL:.0%}]"]
    lines = [reading(profile), "",
             f"Per condition, the least-squares slope of each model's {profile.criterion} (its mean over the "
             f"evaluation seeds) over log2(1 + alpha), alphas {{{alphas}}}; the interval draws the models again within "
             "each lane count and alpha (one draw shared by the lane count's loads, which the same models drive). "
             "Negative: restraint costs speed.", "", md_table(head, rows), "",
             "The paper's trends on it: the plane slope = c0 + c_lanes lanes + c_load load over the "
             f"{found.get('n', 0)} conditions that pass the gate (R² = {num(found.get('r2', math.nan))}), each "
             f"trend tested against 0 by its bootstrap p-value, Holm's correction over the two at {FAMILY_ALPHA:g}:",
             ""]  # fmt: skip
    if "lanes" not in found:
        return "\n".join(lines + [f"No plane fitted: {found['error']}."])
    lines += [_trend_line(name, found[name]) for name in ("lanes", "load")]
    lines += ["", f"![the response per lane count and load]({RESPONSE_FIGURE})"]
    return "\n".join(lines)


# -- alpha*'s sensitivity (the secondary reading) -------------------------------------------------------------------
def sensitivity(table: pd.DataFrame, alphas: tuple[float, ...]) -> dict[str, Any]:
    """The alpha* plane (alpha* = b0 + b1 T_up + b2 lanes) refitted without each condition in turn, and on two other
    readings of alpha*: log2(1 + alpha*) and its rank in the alphas tried. table: lanes, t_up_s, alpha_star of the
    conditions in the trend fit."""
    solved = table[np.isfinite(table["alpha_star"].astype(float))].reset_index(drop=True)
    t, n, a = (solved[c].to_numpy(float) for c in ("t_up_s", "lanes", "alpha_star"))
    out: dict[str, Any] = {}
    try:
        fits = [fit_plane(np.delete(t, i), np.delete(n, i), np.delete(a, i)) for i in range(len(a))]
        out["leave_one_out"] = {name: [min(getattr(f, name) for f in fits), max(getattr(f, name) for f in fits)]
                                for name in ("b1", "b2")}  # fmt: skip
        rank = np.array([sorted(alphas).index(x) for x in a], float)
        for label, values in (("log2", np.log2(1 + a)), ("rank", rank)):
            fit = fit_plane(t, n, values)
            out[label] = {"b1": fit.b1, "b2": fit.b2, "r2": fit.r2}
    except (PlaneFitError, ValueError) as err:
        out["error"] = str(err)
    return out


def sensitivity_text(found: dict[str, Any]) -> str:
    """A paragraph on how far alpha*'s plane moves under the readings of sensitivity()."""
    if "error" in found or "leave_one_out" not in found:
        return f"alpha*'s sensitivity: not read ({found.get('error', 'no plane')})."
    loo = found["leave_one_out"]
    return (f"**alpha\\*'s sensitivity** (the secondary reading): leaving out one condition at a time moves the lane "
            f"slope b2 from {loo['b2'][0]:+.3f} to {loo['b2'][1]:+.3f} per lane and the T_up slope b1 from "
            f"{loo['b1'][0]:+.3f} to {loo['b1'][1]:+.3f} per s; read as log2(1 + alpha\\*) the plane's slopes are "
            f"b2 {found['log2']['b2']:+.3f}, b1 {found['log2']['b1']:+.3f} (R² {num(found['log2']['r2'])}), read as "
            f"alpha\\*'s rank in the grid b2 {found['rank']['b2']:+.3f}, b1 {found['rank']['b1']:+.3f} (R² "
            f"{num(found['rank']['r2'])}).")  # fmt: skip
