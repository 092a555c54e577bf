"""Claim (a)'s report under its analysis plan (claim_a.py): claim_a.md and fig_thrashing.png beside a scenario I
study's report.md, for a study with alpha 0 and alpha 8 of one learner. The header quotes the plan's commit."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pandas as pd

from coopsumo.files import write_text_atomic
from coopsumo.report.markdown import md_table
from coopsumo.studies.scenario1 import claim_a

PLAN_COMMIT = "40d5c82"
"""the commit that fixed the plan (docs/studies.md, "Claim (a): the analysis plan"), quoted by every report"""
UNITS = {"tts_veh_h": ("total time spent", "veh-h", 1), "system_recovery_s": ("system recovery", "s", 0),
         "waves": ("stop-and-go waves", "per run", 2)}  # fmt: skip


def _num(value: float, digits: int) -> str:
    return "-" if not math.isfinite(value) else f"{value:+.{digits}f}"


def comparison_table(table: pd.DataFrame) -> str:
    """The family's rows: demand, measure, alpha 8 minus alpha 0 [95%], models lower, p, Holm's p, verdict, and the
    smallest effect its models detect with the plan's power."""
    rows = []
    for r in table.itertuples():
        name, unit, dg = UNITS[str(r.measure)]
        rows.append([f"{r.t_up_s:g}", f"{name} ({unit})", f"{_num(r.diff, dg)} [{_num(r.lo, dg)}, {_num(r.hi, dg)}]",
                     f"{r.lower} of {r.models}", f"{r.p:.3f}", f"{r.p_holm:.3f}", f"**{r.verdict}**",
                     _num(getattr(r, "detectable", math.nan), dg).lstrip("+")])  # fmt: skip
    return md_table(["T_up (s)", "measure", "alpha 8 - alpha 0 [95%]", "models lower", "p", "Holm p", "verdict",
                     "detectable"], rows)  # fmt: skip


def thrashing_table(table: pd.DataFrame) -> str:
    rows = [[f"{r.t_up_s:g}", f"{r.thrash_a} of {r.models_a}", f"{r.thrash_b} of {r.models_b}", f"{r.p:.3f}",
             f"{r.p_holm:.3f}"] for r in table.itertuples()]  # fmt: skip
    return md_table(["T_up (s)", "thrashing, alpha 8", "thrashing, alpha 0", "Fisher p", "Holm p"], rows)


def pilot_table(table: pd.DataFrame) -> str:
    rows = []
    for r in table.itertuples():
        name, unit, dg = UNITS[str(r.measure)]
        needed = "more than 40" if r.needed is None or pd.isna(r.needed) else f"{int(r.needed)}"
        rows.append([f"{r.t_up_s:g}", f"{name} ({unit})", _num(r.diff, dg), _num(r.model_sd, dg).lstrip("+"), needed])
    return md_table(["T_up (s)", "measure", "alpha 8 - alpha 0", "sd between models", "models for 90% power"], rows)


def write_claim_a(root: Path, rows: pd.DataFrame, a: str, b: str, exploratory: str | None = None) -> dict[str, Any]:
    """claim_a.md and fig_thrashing.png in root for policy a (alpha 8) against b (alpha 0) of one learner; returns
    claim_a.summary. exploratory: why the reading is exploratory (its models suggested the plan), or None."""
    from coopsumo.report.plots import thrashing_figure

    s = claim_a.summary(rows, a, b)
    keep = rows[rows["policy"] == "keep"].groupby("t_up_s")["tts_veh_h"].mean().to_dict()
    panels = {float(t): {lab: claim_a.thrashing(rows[rows["t_up_s"] == t], lab) for lab in (b, a)}
              for t in sorted(rows["t_up_s"].unique(), reverse=True)}  # fmt: skip
    thrashing_figure(panels, {float(k): float(v) for k, v in keep.items()}, claim_a.THRASHING_QLC,
                     root / "fig_thrashing.png")  # fmt: skip
    models = int(s["comparisons"]["models"].max()) if len(s["comparisons"]) else 0
    decided = s["comparisons"][s["comparisons"]["verdict"] != "cannot decide"]
    found = "; ".join(f"{UNITS[str(r.measure)][0]} at T_up {r.t_up_s:g} s ({r.verdict})" for r in decided.itertuples())
    planned = int(s["planned_models"]) if models >= claim_a.PILOT_MODELS else 0
    early = 0 < models < planned and not exploratory  # an exploratory reading is never the plan's study in parts
    interim = (f"**Interim: {models} of the plan's {planned} models per alpha.** The plan reads its verdict at "
               f"{planned} models; what is decided below is where the study stands, not its answer (part 1's decided "
               "comparisons did not survive 5 more models).\n\n") if early else ""  # fmt: skip
    head = (f"# Claim (a): alpha 8 against alpha 0 ({a} against {b}), under the analysis plan of {PLAN_COMMIT}\n\n"
            + (f"**Exploratory**: {exploratory}\n\n" if exploratory else "") + interim
            + f"{models} models per alpha. Decided under the plan (Holm over {len(s['comparisons'])} comparisons at a "
            f"family-wise {claim_a.FAMILY_ALPHA:g}, at least 3 models): "
            + (found or "nothing") + ".\n")  # fmt: skip
    text = "\n\n".join([
        head,
        "## The co-primary measures\n\nPaired by training seed and evaluation seed; the 95% interval and p from the "
        "two-level bootstrap (models, then seeds); a run that never recovers counts as its horizon; `detectable`: the "
        f"smallest difference these models detect with {claim_a.POWER:.0%} power at the corrected level.\n\n"
        + comparison_table(s["comparisons"]),
        f"## The mechanism: thrashing models\n\nA model thrashes at a demand when its lane changes below 5 m/s exceed "
        f"{claim_a.THRASHING_QLC:g} per vehicle (mean over its seeds). Fisher's exact test per demand, Holm over "
        "the demands. `fig_thrashing.png`: every model, its queue lane changes against its total time spent, "
        "`keep` as the dashed line.\n\n" + thrashing_table(s["thrashing"]),
        f"## The number of models\n\nFrom the first {claim_a.PILOT_MODELS} models per alpha: each comparison's models "
        f"for {claim_a.POWER:.0%} power (t-test of the model means at {claim_a.FAMILY_ALPHA:g} / "
        f"{len(s['comparisons'])}). The plan's number: **{s['planned_models']} models per alpha**.\n\n"
        + pilot_table(s["pilot"]),
    ])
    write_text_atomic(root / "claim_a.md", text + "\n")
    return s
