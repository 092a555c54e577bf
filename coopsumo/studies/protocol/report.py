"""The learner protocol's tables, figure and report (studies/protocol/study.py runs the cells).

Per condition (free flow or accident at one demand) and variant: the interquartile mean over models with its
stratified bootstrap interval, the worst model, and the probability of improvement against each baseline on the
same evaluation seed; then the issue's targets, the alpha response, and the training diagnosis read from each
training's validation.csv (agents/selection.py).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from coopsumo.agents.training_logs import validation_table
from coopsumo.config import as_data
from coopsumo.files import read_csv, read_json, write_atomic, write_text_atomic
from coopsumo.policy_spec import DRIVES
from coopsumo.record_schemas import PROTOCOL_STATS
from coopsumo.report.markdown import interval, md_table
from coopsumo.sim import passing
from coopsumo.studies.engine import stats
from coopsumo.studies.protocol.alpha_response import FIGURE, alpha_lines, pairs_lines, response_figure
from coopsumo.studies.protocol.figures import TWO_STAGE_NOTE, VALIDATION_CAPTION, validation_curves_figure
from coopsumo.studies.protocol.plan import BASELINES, EVAL_SEED
from coopsumo.studies.protocol.thrashing import thrashing_lines

MEASURES = {"free": ("mean_speed_mps", "mean speed (m/s)", 1.0),
            "accident": ("tts_veh_h", "total time spent (veh-h)", -1.0)}
"""scenario -> (headline measure, its words, +1 when higher is better / -1 when lower is)"""
COLUMNS = ("key", "kind", "variant", "alpha", "seed", "scenario", "t_up", "eval_seed", "weights", "train_key",
           "status", "mean_speed_mps", "tts_veh_h", "lane_changes_per_vehicle", "queue_lane_changes_per_vehicle",
           "collisions", "teleports", "selected_step", "held_share", "passing_open_share",
           "passing_taken_share")  # fmt: skip
PASSING = COLUMNS[18:]
"""the passing chances of a run (coopsumo/sim/passing.py); absent from runs made before 2026-11-27"""


COMMITTED = Path(__file__).resolve().parents[3] / "results"
"""the repository's committed reports, which Profile.paired_with names (absent beside an installed wheel)"""
SAME_DIGITS = 1e-5
"""relative difference (of the reference's value) up to which two runs' measures count as the same: runs.csv keeps 6
digits"""
SAME_PROFILE = ("lanes", "train_steps", "t_ups", "free_steps", "accident_steps", "accident_start", "accident_duration")
"""what a committed study must share with this one for its trainings to pair with this one's"""


def runs_table(records: list[dict[str, Any]]) -> pd.DataFrame:
    rows = []
    for r in records:
        s = r.get("summary") or {}
        t = r.get("train_summary") or {}
        row = {k: r.get(k) for k in COLUMNS[:11]}
        row.update({k: s.get(k) for k in COLUMNS[11:17]})
        row["selected_step"] = t.get("selected_step") if r.get("weights") == "model.pt" else None
        row.update({k: s.get(k) for k in PASSING})
        rows.append(row)
    table = pd.DataFrame(rows, columns=list(COLUMNS))
    for c in ("alpha", "t_up", *COLUMNS[11:]):
        table[c] = pd.to_numeric(table[c], errors="coerce").astype(float)
    return table


def per_model(runs: pd.DataFrame) -> pd.DataFrame:
    """One row per model (or baseline) and condition from its ok runs: the mean of each measure over its evaluation
    seeds (Profile.eval_offsets), collisions and teleports summed, eval_seed the first seed and eval_runs their
    count. With one seed per condition the rows are the runs'. Columns a table lacks (a committed runs.csv of
    before a measure) are NaN."""
    runs = runs.reindex(columns=list(COLUMNS))
    ok = runs[runs["status"] == "ok"]
    groups = ok.groupby(["kind", "variant", "alpha", "seed", "scenario", "t_up", "weights"], dropna=False, sort=False)
    summed = ["collisions", "teleports"]
    flat = groups[[c for c in COLUMNS[11:] if c not in summed]].mean()
    flat[summed] = groups[summed].sum()
    flat[["key", "train_key", "status"]] = groups[["key", "train_key", "status"]].first()
    flat["eval_seed"], flat["eval_runs"] = groups["eval_seed"].min(), groups.size()
    return flat.reset_index()[[*COLUMNS, "eval_runs"]]


def condition_stats(runs: pd.DataFrame, variants: list[str], baselines: list[str]) -> pd.DataFrame:
    """One row per (scenario, demand, variant): IQM and interval over models, worst model, mean, and against each
    baseline the probability of improvement (with interval) and how many models lost to it."""
    ok = runs[(runs["status"] == "ok") & (runs["alpha"] == 0)]
    rows = []
    for (scenario, t_up), cond in ok.groupby(["scenario", "t_up"], sort=False):
        measure, _, sign = MEASURES[str(scenario)]
        for variant in variants:
            vals = cond[(cond["variant"] == variant)][measure].dropna().to_numpy(float)
            if not len(vals):
                continue
            point, low, high = stats.iqm_interval(vals[:, None])
            worst = float(vals.min() if sign > 0 else vals.max())
            lcs = cond[cond["variant"] == variant]["lane_changes_per_vehicle"]
            row = {"scenario": scenario, "t_up": t_up, "variant": variant, "models": len(vals), "iqm": point,
                   "low": low, "high": high, "worst": worst, "mean": float(vals.mean()),
                   "lane_changes_per_vehicle": float(lcs.mean())}
            for b in baselines:
                base = cond[cond["variant"] == b][measure].dropna().to_numpy(float)
                if not len(base):
                    continue
                p, p_low, p_high = stats.improvement(sign * vals[:, None], sign * base[:1, None])
                row[f"{b}_value"] = float(base[0])
                row[f"{b}_poi"], row[f"{b}_poi_low"], row[f"{b}_poi_high"] = p, p_low, p_high
                row[f"{b}_losses"] = int((sign * vals < sign * base[0]).sum())
            rows.append(row)
    return pd.DataFrame(rows)


def pooled_stats(runs: pd.DataFrame, variant: str, baseline: str, scenario: str) -> tuple[float, float, float]:
    """The probability of improvement of variant over baseline across the scenario's demands (rliable: averaged
    over tasks), with its stratified bootstrap interval."""
    ok = runs[(runs["status"] == "ok") & (runs["alpha"] == 0) & (runs["scenario"] == scenario)]
    measure, _, sign = MEASURES[scenario]
    mine = ok[ok["variant"] == variant].pivot_table(index="seed", columns="t_up", values=measure).dropna()
    base = ok[ok["variant"] == baseline].pivot_table(index="eval_seed", columns="t_up", values=measure)
    if mine.empty or base.empty or not set(mine.columns) <= set(base.columns):  # a baseline's cell failed: none
        return math.nan, math.nan, math.nan
    base = base.max().to_frame().T[mine.columns]  # one evaluation seed per demand: one row
    return stats.improvement(sign * mine.to_numpy(float), sign * base.to_numpy(float))


def paired_rows(runs: pd.DataFrame, variant: str, reference: str) -> list[dict[str, Any]]:
    """Per condition, `variant` minus `reference` paired by training seed (the same training driven or chosen
    otherwise, or another learner's training on the same seed, evaluated on the same seeds): the mean over models
    of the paired difference in the headline measure and in lane changes per vehicle, a 95% bootstrap interval
    over models (stats.hierarchical_bootstrap, one evaluation per model), and how many models did better: by more
    than the 6 significant digits of a runs.csv (SAME_DIGITS), so that a committed study's rounded copy of the same
    run is not counted as better or worse."""
    ok = runs[(runs["status"] == "ok") & (runs["alpha"] == 0)]
    rows = []
    for (scenario, t_up), cond in ok.groupby(["scenario", "t_up"], sort=False):
        measure, _, sign = MEASURES[str(scenario)]
        mine = cond[cond["variant"] == variant].set_index("seed")
        ref = cond[cond["variant"] == reference].set_index("seed")
        both = mine.index.intersection(ref.index)
        if not len(both):
            continue
        a, b = mine.loc[both, measure].to_numpy(float), ref.loc[both, measure].to_numpy(float)
        diff = a - b
        same = np.isclose(a, b, rtol=SAME_DIGITS, atol=0.0)
        lcs = (mine.loc[both, "lane_changes_per_vehicle"] - ref.loc[both, "lane_changes_per_vehicle"]).mean()
        point, low, high = stats.hierarchical_bootstrap(diff[:, None])
        rows.append({"scenario": scenario, "t_up": t_up, "models": len(both), "diff": point, "low": low,
                     "high": high, "better": int(((sign * diff > 0) & ~same).sum()), "lane_changes": float(lcs)})
    return rows


def passing_lines(runs: pd.DataFrame, profile: Any) -> list[str]:
    """Free flow, alpha 0: each learner's and baseline's passing chances (coopsumo/sim/passing.py), means over its
    models; nothing when no run recorded them."""
    ok = runs[(runs["status"] == "ok") & (runs["alpha"] == 0) & (runs["scenario"] == "free")]
    if ok.empty or ok["held_share"].isna().all():
        return []
    lines = ["", "## Passing in free flow: held back, a faster lane open, and taken", "",
             f"Sampled every {passing.PASSING_EVERY_S:g} s over every vehicle on the road: the share held back "
             f"(more than {passing.HELD_BELOW_MPS:g} m/s below its expected speed behind a leader within "
             f"{passing.HELD_GAP_M:g} m), the share held back with a side lane open to pass (one the controller would "
             f"let it enter now, whose leader is at least {passing.FASTER_MPS:g} m/s faster or absent), and the share "
             "of those open chances after which the vehicle started a lane change before the next sample. Means over "
             "models (alpha 0); a policy that passes well is seldom held back and takes its chances.", "",
             ]  # fmt: skip
    rows = []
    for t_up, cond in ok.groupby("t_up", sort=False):
        for name in [*profile.variants, *BASELINES]:
            taken = cond[cond["variant"] == name].dropna(subset=["held_share"])
            if taken.empty:
                continue
            rows.append([f"{t_up:g}", f"`{name}`", str(len(taken)), f"{taken['held_share'].mean():.3f}",
                         f"{taken['passing_open_share'].mean():.3f}", f"{taken['passing_taken_share'].mean():.2f}"])
    return lines + md_table(["T_up (s)", "policy", "runs", "held back", "lane open", "taken"], rows).split("\n")


def committed_folder(results: Path, name: str) -> Path:
    """A committed protocol study's folder: results/<name>, or results/history/<name> once it is frozen there."""
    frozen = results / "history" / name
    return frozen if not (results / name).is_dir() and frozen.is_dir() else results / name


def committed_runs(folder: Path, variant: str, runs: pd.DataFrame, profile: Any) -> tuple[pd.DataFrame, str]:
    """`variant`'s alpha-0 model rows of the committed protocol study in `folder`, or an empty table and why they
    cannot be paired with this study's: missing, another profile, another learner than today's, other seeds."""
    from coopsumo.config import first_difference, to_dict
    from coopsumo.studies.protocol.plan import variants

    empty = runs.iloc[0:0]
    if not (folder / "runs.csv").is_file() or not (folder / "study.json").is_file():
        return empty, f"no runs.csv and study.json in {folder.name}"
    study = read_json(folder / "study.json")
    theirs, ours = study.get("profile", {}), as_data(profile)
    differ = [f for f in SAME_PROFILE if json.dumps(theirs.get(f)) != json.dumps(ours.get(f))]
    if differ:
        return empty, f"its profile differs in {', '.join(differ)}"
    known, entry = variants().get(variant), study.get("learners", {}).get(variant)
    if known is None or entry is None:
        return empty, f"no variant {variant} there or here"
    if first_difference(entry.get("learner"), to_dict(known.learner)) is not None or \
            entry.get("drive", {}) != known.drive() or entry.get("weights") != known.weights:
        return empty, f"its {variant} is not today's"
    ref = read_csv(folder / "runs.csv")
    ref = ref[(ref["kind"] == "model") & (ref["variant"] == variant) & (ref["alpha"] == 0) & (ref["status"] == "ok")]
    for (scenario, t_up), cond in runs[runs["kind"] == "model"].groupby(["scenario", "t_up"]):
        there = ref[(ref["scenario"] == scenario) & (ref["t_up"] == t_up)]["eval_seed"]
        if set(there) != set(cond["eval_seed"]):
            return empty, f"other evaluation seeds ({scenario}, T_up {t_up:g} s)"
    return ref, ""


def committed_pair_lines(runs: pd.DataFrame, profile: Any, results: Path = COMMITTED) -> list[str]:
    """Profile.paired_with: each named variant here minus a committed study's variant, paired by training seed."""
    if not profile.paired_with:
        return []
    lines = ["", "## Paired with the trainings of committed studies on the same training seeds", "",
             "Each variant here minus a variant of another committed protocol study that ran the same training "
             "seeds, demands, evaluation seeds and step counts with today's settings of that variant (checked from "
             "its study.json and runs.csv); mean over training seeds of the paired difference, 95% bootstrap "
             "interval over them, and how many did better (free flow: mean speed, m/s; accident: total time spent, "
             "veh-h).", "",
             ]  # fmt: skip
    notes, rows = [], []
    for mine, folder, theirs in profile.paired_with:
        where = committed_folder(results, folder)
        ref, problem = committed_runs(where, theirs, runs, profile)
        if problem:
            notes.append(f"- `{mine}` minus `{theirs}` of {folder}: not paired, {problem}.")
            continue
        label = f"{theirs} ({folder})"
        both = per_model(pd.concat([runs[runs["variant"] == mine], ref.assign(variant=label)], ignore_index=True))
        link = f"../{where.relative_to(results).as_posix()}/report.md"
        for r in paired_rows(both, mine, label):
            rows.append([f"`{mine}`", f"`{theirs}` ([{folder}]({link}))", r["scenario"], f"{r['t_up']:g}",
                         interval(r["diff"], r["low"], r["high"], "{:+.2f}"), f"{r['better']} of {r['models']}",
                         f"{r['lane_changes']:+.2f}"])  # fmt: skip
    head = ["learner", "minus", "scenario", "T_up (s)", "difference [95% CI]", "better", "lane changes / veh, diff."]
    return lines + md_table(head, rows).split("\n") + ([""] + notes if notes else [])


def diagnosis_table(root: Path, runs: pd.DataFrame) -> pd.DataFrame:
    """Per alpha-0 training: its validation course (agents/selection.py) and its models' free-flow results."""
    rows = []
    trainings = runs[(runs["kind"] == "model") & (runs["alpha"] == 0)].drop_duplicates("seed")
    for _, r in trainings.iterrows():
        val = validation_table(root / "train" / str(r["train_key"]) / "validation.csv")  # RecordError naming it
        if val is None:
            continue
        best = val[val["best"]].iloc[0]  # validation_table: exactly one
        last = val.iloc[-1]
        row = {"seed": int(r["seed"]), "selected_step": int(best["step"]), "best_score": best["score"],
               "last_score": last["score"]}
        if "stage" in val:  # a selection in two stages (a column only then: the other studies' tables stay as made)
            row["screened"] = True
        for tag, src in (("best", best), ("last", last)):
            for col in ("mean_speed_mps", "lane_changes_per_vehicle", "share_speedup", "share_none", "share_left",
                        "share_right", "q_gap_median", "near_tie_share"):
                row[f"{tag}_{col}"] = src.get(col, math.nan)
        rows.append(row)
    return pd.DataFrame(rows)


def write_outputs(root: Path, profile: Any, records: list[dict[str, Any]], meta: dict[str, Any]) -> None:
    runs = runs_table(records)
    write_atomic(root / "runs.csv", lambda tmp: runs.to_csv(tmp, index=False, float_format="%.6g"))
    models = per_model(runs)  # every statistic below is over models, each its mean over its evaluation seeds
    table = condition_stats(models, list(profile.variants), list(BASELINES))
    PROTOCOL_STATS.check_frame(table, root / "stats.csv")  # inside record_schemas' limits (a failed baseline: blank)
    write_atomic(root / "stats.csv", lambda tmp: table.to_csv(tmp, index=False, float_format="%.6g"))
    diag = diagnosis_table(root, models[models["variant"] == profile.judged_variant()])  # the judged trainings
    if len(diag):
        write_atomic(root / "diagnosis.csv", lambda tmp: diag.to_csv(tmp, index=False, float_format="%.6g"))
    trained = runs[(runs["kind"] == "model") & (runs["alpha"] == 0)].dropna(subset=["train_key"])
    names = dict(zip(trained["train_key"][::-1], trained["variant"][::-1], strict=True))  # the first variant driving it
    folders: dict[Path, str] = {}  # one curve per training: cells copied from other studies name it by their keys
    for key in sorted(names):
        folders.setdefault((root / "train" / key).resolve(), key)
    validation_curves_figure(root, sorted(folders.values()), root / "fig_validation.png", names)
    response_figure(profile, models, root / FIGURE)
    write_text_atomic(root / "report.md", report_text(profile, runs, models, table, diag, meta))


def _eval_seed_words(profile: Any) -> str:
    sets = profile.eval_offsets
    free = ", ".join(f"{EVAL_SEED + o}+i" for o in sets)
    accident = ", ".join(f"{EVAL_SEED + 100 + o}+i" for o in sets)
    words = f"on evaluation seeds {free} (free flow) and {accident} (accident) that no training or validation saw; "
    if len(sets) > 1:
        words += (f"each model and baseline met every condition on these {len(sets)} seeds, and each value below is "
                  "its mean over them; ")  # fmt: skip
    return words


def _longer(profile: Any) -> str:
    """The learners a profile trains longer than its train_steps (learners.toml's steps_factor), in words: ", `c2xs`
    360,000" or ""."""
    from coopsumo.studies.protocol.plan import variants

    known = variants()
    factors = [(v, known[v].steps_factor) for v in profile.variants if v in known and known[v].steps_factor != 1]
    return "".join(f", `{v}` {profile.train_steps * f:,}" for v, f in factors)


def plan_line(profile: Any) -> list[str]:
    """The header's line on the profile's analysis plan (Profile.plan), or none when the profile names no commit."""
    if not profile.plan:
        return []
    return [f"Read under the analysis plan fixed before these models were driven, in commit `{profile.plan}` "
            "(docs/studies.md, the profile's own section)."]


def _header_lines(profile: Any, meta: dict[str, Any]) -> list[str]:
    lines = [
        "# The learner protocol: every training seed against the hand-made rules",
        "",
        f"Profile `{profile.name}`: {profile.lanes} lanes; each learner trained {profile.train_steps:,} steps"
        f"{_longer(profile)} (in "
        f"free flow at T_up 1 s unless its line below says otherwise) on training seeds {list(profile.seeds)}; "
        "every model driven greedily in free flow "
        f"({profile.free_steps:,} steps) and through scenario I's accident ({profile.accident_steps:,} steps, closure "
        f"decaying over steps {profile.accident_start:,}-{profile.accident_start + profile.accident_duration:,}) at "
        f"T_up {', '.join(f'{t:g}' for t in profile.t_ups)} s, {_eval_seed_words(profile)}"
        "the baselines on the same seeds. "
        "The trained model is the unit: each interval is a 95% stratified bootstrap over models (rliable's "
        "procedure), IQM is the interquartile mean over models, P(>b) the probability that a model beats "
        "baseline b (rliable's probability of improvement), 'lost' how many models did worse than b.",
        *plan_line(profile),
        f"{meta['cells']} cells, {meta['cells_run']} run by the last command ({meta['wall_seconds']:.0f} s wall, "
        f"{meta['workers']} worker{'s' if meta['workers'] != 1 else ''}); "
        f"{meta.get('cell_cpu_seconds_sum', 0) / 3600:.1f} CPU hours in all.",
        "",
        "Learners:",
        "",
    ]
    for name in profile.variants:
        info = meta["learners"][name]
        drive = info.get("drive") or {}
        how = "".join(f", {words} {drive[key]:g}" for _, key, words in DRIVES if key in drive)
        lines.append(f"- `{name}`: {info['text']} (drives `{info['weights']}`{how})")
    return lines


def _scenario_tables(profile: Any, ok: pd.DataFrame, table: pd.DataFrame) -> list[str]:
    """Per scenario: each learner's IQM, worst model and probability of improvement per demand, then pooled."""
    lines: list[str] = []
    for scenario in ("free", "accident"):
        measure, words, sign = MEASURES[scenario]
        sub = table[table["scenario"] == scenario] if len(table) else table
        if sub.empty:
            continue
        title = "Free flow" if scenario == "free" else "Through scenario I's accident"
        better = "higher" if sign > 0 else "lower"
        lines += ["", f"## {title}: {words}, {better} is better", ""]
        head = ["T_up (s)", "learner", "models", "IQM [95% CI]", "worst model", "lane changes / veh"]
        head += [f"`{b}`" for b in BASELINES] + [f"P(> `{b}`) [95% CI], lost" for b in BASELINES]
        rows = []
        for _, r in sub.iterrows():
            cells = [f"{r['t_up']:g}", f"`{r['variant']}`", str(int(r["models"])),
                     interval(r["iqm"], r["low"], r["high"]), f"{r['worst']:.2f}",
                     f"{r['lane_changes_per_vehicle']:.2f}"]  # fmt: skip
            values = [r.get(f"{b}_value", math.nan) for b in BASELINES]  # a failed baseline's: blank
            cells += ["-" if pd.isna(v) else f"{v:.2f}" for v in values]
            for b in BASELINES:
                poi = (r.get(f"{b}_poi", math.nan), r.get(f"{b}_poi_low", math.nan), r.get(f"{b}_poi_high", math.nan))
                losses = r.get(f"{b}_losses", 0)  # blank where the baseline's cell failed (issue 82, probe 7, I10)
                cells.append(f"{interval(*poi)}, {'-' if pd.isna(losses) else int(losses)}")
            rows.append(cells)
        lines += md_table(head, rows).split("\n")
        lines += ["", "Across the demands (probability of improvement averaged over demands, 95% CI):", ""]
        for variant in profile.variants:
            parts = [f"P(> `{b}`) = {interval(*pooled_stats(ok, variant, b, scenario))}" for b in BASELINES]
            lines.append(f"- `{variant}`: " + "; ".join(parts))
    return lines


def _diagnosis_lines(profile: Any, diag: pd.DataFrame) -> list[str]:
    lines: list[str] = []
    if len(diag):
        judged = profile.judged_variant()
        lines += [f"## Diagnosis: what each training of `{judged}` saw in its validation (alpha 0)", "",
                  "Each training was validated every few thousand steps on held-out free-flow demand "
                  "(agents/selection.py); `best` is the snapshot model.pt holds, `last` the last weights. Shares are "
                  "of the greedy decisions; q gap: median Q(best change) - Q(best stay) where a change was offered; "
                  "near ties: share of those decisions within 5% of each other.", ""]  # fmt: skip
        head = ["seed", "chosen step", "speed best / last (m/s)", "lane changes best / last", "'none' best / last",
                "speed-up best / last", "q gap best / last", "near ties best / last"]  # fmt: skip
        pairs = ["mean_speed_mps", "lane_changes_per_vehicle", "share_none", "share_speedup", "q_gap_median",
                 "near_tie_share"]  # fmt: skip
        rows = [[str(int(d["seed"])), f"{int(d['selected_step']):,}",
                 *(f"{d[f'best_{k}']:.2f} / {d[f'last_{k}']:.2f}" for k in pairs)] for _, d in diag.iterrows()]
        lines += md_table(head, rows).split("\n")
        lines += ["", "![validation over training](fig_validation.png)", "", VALIDATION_CAPTION, ""]
        if "screened" in diag and diag["screened"].eq(True).any():
            lines += [TWO_STAGE_NOTE, ""]
    return lines


def report_text(profile: Any, runs: pd.DataFrame, ok: pd.DataFrame, table: pd.DataFrame, diag: pd.DataFrame,
                meta: dict[str, Any]) -> str:  # fmt: skip
    """The report from every run (runs) and every model's and baseline's mean over its evaluation seeds (ok,
    per_model)."""
    lines = _header_lines(profile, meta) + _scenario_tables(profile, ok, table) + thrashing_lines(ok, profile)
    lines += passing_lines(ok, profile)
    lines += paired_lines(ok, profile, meta)
    lines += committed_pair_lines(runs, profile)
    lines += ["", *target_lines(table, ok, profile), ""]
    lines += alpha_lines(profile, ok) + pairs_lines(profile, ok)
    done = runs[runs["status"] == "ok"]
    safety = done[["collisions", "teleports"]].sum()
    lines += [f"Safety: {int(safety['collisions'])} collisions and {int(safety['teleports'])} teleports in all "
              f"{len(done)} runs.", ""]  # fmt: skip
    lines += _diagnosis_lines(profile, diag)
    failed = runs[runs["status"] != "ok"]
    if len(failed):
        lines += [f"Failed cells ({len(failed)}): " + ", ".join(failed["key"]), ""]
    return "\n".join(lines) + "\n"


def paired_lines(runs: pd.DataFrame, profile: Any, meta: dict[str, Any]) -> list[str]:
    """A section per variant that drives the first variant's trainings another way (another margin or weights) or
    chooses among their snapshots otherwise (the learner differs only in selection.SELECTION_FIELDS): the
    differences paired by model, which the intervals against the baselines above cannot show."""
    from coopsumo.agents.selection import trained_part

    def trained(variant: str) -> dict[str, Any]:
        return trained_part(meta["learners"][variant]["learner"])

    first = profile.variants[0]
    same = [v for v in profile.variants[1:] if trained(v) == trained(first)]
    other = [v for v in profile.variants[1:] if v not in same]
    lines: list[str] = []
    for group, title, unit in (
        (same, "The same trainings driven or chosen otherwise", "model"),
        (other, "Other trainings on the same training seeds (the same evaluation seeds too)", "training seed"),
    ):
        if not group:
            continue
        lines += ["", f"## {title}: each variant minus `{first}`, paired by {unit}", "",
                  f"Mean over {unit}s of the paired difference, 95% bootstrap interval over them, and how many did "
                  f"better than `{first}` (free flow: mean speed, m/s; accident: total time spent, veh-h).", ""]
        rows = [[f"`{variant}`", r["scenario"], f"{r['t_up']:g}", interval(r["diff"], r["low"], r["high"], "{:+.2f}"),
                 f"{r['better']} of {r['models']}", f"{r['lane_changes']:+.2f}"]
                for variant in group for r in paired_rows(runs, variant, first)]  # fmt: skip
        lines += md_table(["learner", "scenario", "T_up (s)", "difference [95% CI]", "better",
                           "lane changes / veh, difference"], rows).split("\n")  # fmt: skip
    return lines


def target_lines(table: pd.DataFrame, ok: pd.DataFrame, profile: Any) -> list[str]:
    """The learner issue's targets for the judged learner, as measured."""
    if table.empty:
        return []
    v = profile.judged_variant()
    mine = table[table["variant"] == v]
    free = mine[mine["scenario"] == "free"]
    acc = mine[mine["scenario"] == "accident"]
    out = [f"## Targets for `{v}`", ""]
    if len(free) and "keep_losses" in free:
        out.append(f"- free flow, no model below `keep` at any demand: {int(free['keep_losses'].sum())} model-demand "
                   f"pairs below ({'met' if free['keep_losses'].sum() == 0 else 'not met'})")  # fmt: skip
        gaps = free["iqm"] - free["greedy_value"]
        out.append("- free flow, IQM at least `greedy`'s: " + ", ".join(
            f"T_up {t:g}: {g:+.2f} m/s" for t, g in zip(free["t_up"], gaps, strict=True))
            + f" ({'met' if (gaps >= 0).all() else 'not met'})")  # fmt: skip
    if len(acc) and "keep_losses" in acc:
        out.append(f"- accident, no model above `keep`'s total time spent: {int(acc['keep_losses'].sum())} "
                   f"model-demand pairs above ({'met' if acc['keep_losses'].sum() == 0 else 'not met'})")  # fmt: skip
        gaps = acc["iqm"] - acc["mobil:p=0_value"]
        out.append("- accident, IQM at most MOBIL p=0's: " + ", ".join(
            f"T_up {t:g}: {g:+.2f} veh-h" for t, g in zip(acc["t_up"], gaps, strict=True))
            + f" ({'met' if (gaps <= 0).all() else 'not met'})")  # fmt: skip
    a0 = ok[(ok["variant"] == v) & (ok["alpha"] == 0) & (ok["scenario"] == "free")]["lane_changes_per_vehicle"]
    if len(a0):
        out.append(f"- no model above 3 lane changes per vehicle at alpha 0: highest {a0.max():.2f} "
                   f"({'met' if a0.max() <= 3 else 'not met'})")  # fmt: skip
    return out
