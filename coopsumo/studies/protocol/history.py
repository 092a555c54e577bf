"""`coopsumo history`: the learner search as rows of one generated table, results/history/README.md.

Every learner protocol study (a folder holding study.json and stats.csv: the current ones under results/, the frozen
ones under results/history/) gives one row per learner it judged, read from the study's own records only: how the
learner differs from today's default, how many models and evaluation sets judged it, its free-flow IQM against
`keep`, its probabilities of improvement over `greedy` and MOBIL p = 0, its total time spent through the accident
against `keep`, its lane changes per vehicle, the verdict those numbers give, and the commit and date that added the
report. Nothing here runs a simulation; the table is rewritten whole from the folders each time.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

import pandas as pd

from coopsumo.config import SPEED_ONLY_FIELDS, to_dict
from coopsumo.dqn_config import ADDED_FIELDS, DQN_PRESETS
from coopsumo.errors import UsageError
from coopsumo.files import write_atomic
from coopsumo.runio import Parser, run_cli

TABLE = "README.md"
STATS = ("study.json", "stats.csv")
"""what makes a folder a learner protocol study"""
BETTER = 0.5
"""a probability of improvement whose whole 95% interval lies above this: the learner is ahead"""


def study_folders(results: Path) -> list[Path]:
    """Every learner protocol study under results/ and results/history/, oldest commit first where git knows."""
    found = [p for base in (results, results / "history") if base.is_dir() for p in sorted(base.iterdir())
             if p.is_dir() and all((p / name).is_file() for name in STATS)]  # fmt: skip
    return sorted(found, key=lambda p: (added(p)[1] or "9999", p.name))


def added(folder: Path) -> tuple[str, str]:
    """(short commit, date) of the commit that first added folder/report.md, following moves; ('', '') outside git."""
    try:
        out = subprocess.run(["git", "log", "--follow", "--diff-filter=A", "--format=%h %as", "--", "report.md"],
                             cwd=folder, capture_output=True, text=True, check=True).stdout.split()  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        return "", ""
    return (out[-2], out[-1]) if len(out) >= 2 else ("", "")


def differences(learner: dict[str, Any], drive: dict[str, Any], weights: str) -> str:
    """How a learner (its settings, how it drives, which weights) differs from today's default, field by field."""
    default = json.loads(json.dumps(to_dict(DQN_PRESETS["default"])))  # tuples as the records hold them: lists
    learner = {**ADDED_FIELDS, **learner}  # a record made before a field existed means its implied value
    fields = [f"{k} {_short(v)}" for k, v in sorted(learner.items())
              if k not in ("preset", *SPEED_ONLY_FIELDS) and default.get(k) != v]  # fmt: skip
    fields += [f"drives with {k} {_short(v)}" for k, v in sorted(drive.items())]
    if weights != "model.pt":
        fields.append(f"weights {weights}")
    return "; ".join(fields) if fields else "today's default"


def _short(value: Any) -> str:
    if isinstance(value, list):
        return "(" + ", ".join(_short(v) for v in value) + ")"
    return f"{value:g}" if isinstance(value, float) else str(value)


def _per_demand(rows: pd.DataFrame, column: str, fmt: str) -> str:
    return " / ".join(fmt.format(v) for v in rows[column])


def _poi_range(rows: pd.DataFrame, base: str) -> str:
    low, high = rows[f"{base}_poi"].min(), rows[f"{base}_poi"].max()
    return f"{low:.2f}" if low == high else f"{low:.2f}-{high:.2f}"


def verdict(free: pd.DataFrame, accident: pd.DataFrame) -> str:
    """Where the learner is ahead of `keep` (the probability of improvement's interval above one half)."""
    parts = []
    for words, rows in (("free flow", free), ("accident", accident)):
        if len(rows):
            ahead = int((rows["keep_poi_low"] > BETTER).sum())
            parts.append(f"{words}: ahead of keep at {ahead} of {len(rows)}")
    return "; ".join(parts)


def rows_of(folder: Path, results: Path) -> list[dict[str, str]]:
    """One table row per learner the study judged, from its study.json and stats.csv."""
    study = json.loads((folder / "study.json").read_text())
    stats = pd.read_csv(folder / "stats.csv")
    profile = study.get("profile", {})
    commit, date = added(folder)
    out = []
    for variant, entry in study.get("learners", {}).items():
        mine = stats[stats["variant"] == variant].sort_values("t_up", ascending=False)
        if mine.empty:
            continue
        free, accident = mine[mine["scenario"] == "free"], mine[mine["scenario"] == "accident"]
        gap = free.assign(gap=free["iqm"] - free["keep_value"])
        tts = accident.assign(gap=accident["iqm"] - accident["keep_value"])
        sets = len(profile.get("eval_offsets", [0]))
        out.append({
            "learner": f"`{variant}`",
            "differs from today's default": differences(entry.get("learner", {}), entry.get("drive", {}),
                                                        entry.get("weights", "model.pt")),
            "models x evaluation sets": f"{int(mine['models'].max())} x {sets}",
            "T_up (s)": " / ".join(f"{t:g}" for t in free["t_up"]),
            "free flow: IQM - keep (m/s)": _per_demand(gap, "gap", "{:+.2f}"),
            "P(> greedy)": _poi_range(free, "greedy"),
            "P(> MOBIL p 0)": _poi_range(free, "mobil:p=0"),
            "accident: IQM - keep (veh-h)": _per_demand(tts, "gap", "{:+.1f}") if len(tts) else "not run",
            "lane changes / veh": f"{mine['lane_changes_per_vehicle'].min():.2f}-"
                                  f"{mine['lane_changes_per_vehicle'].max():.2f}",
            "verdict": verdict(free, accident),
            "date": date or "-",
            "commit": commit or "-",
            "report": f"[{folder.name}]({_link(folder, results)})",
        })  # fmt: skip
    return out


def _link(folder: Path, results: Path) -> str:
    """folder/report.md relative to results/history/, where the table lives."""
    rel = folder.resolve().relative_to(results.resolve())
    return f"{rel.name}/report.md" if rel.parts[0] == "history" else f"../{rel.as_posix()}/report.md"


def table(results: Path) -> str:
    """The history page: a header, then one row per learner judged, oldest first."""
    rows = [row for folder in study_folders(results) for row in rows_of(folder, results)]
    if not rows:
        raise UsageError(f"{results}: no learner protocol study (a folder with study.json and stats.csv) here")
    head = list(rows[0])
    lines = [
        "# The learner search, one row per learner judged",
        "",
        "Generated by `coopsumo history` from each learner protocol study's own `study.json` and `stats.csv`; do "
        "not edit by hand. The studies whose learner is no longer today's are frozen in this folder, each with its "
        "resolved configuration (`study.json`) and the commit that made it; the current ones stay in `results/`. "
        "Every learner is alpha 0; its models x evaluation sets are training seeds x evaluation seed sets. "
        "Columns with ' / ' hold one value per demand, in the order of T_up. IQM: interquartile mean over models "
        "and evaluation seeds; P(> X): probability of improvement over X (min-max over demands, rliable); the "
        f"verdict counts the demands where the learner's P(> keep) has its whole 95% interval above {BETTER:g}.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    lines += ["| " + " | ".join(row[k] for k in head) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def build_parser() -> Parser:
    p = Parser(prog="coopsumo history", description="Write the learner search's table (results/history/README.md) "
                                                     "from the learner protocol studies' own records.")  # fmt: skip
    p.add_argument("--results", type=Path, default=Path("results"),
                   help="the results folder whose learner_protocol* studies and history/ are read")  # fmt: skip
    p.add_argument("--out", type=Path, default=None, help="the table's file (default: RESULTS/history/README.md)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def body() -> int:
        if not args.results.is_dir():
            raise UsageError(f"--results {args.results}: no such folder")
        text = table(args.results)
        out = args.out or args.results / "history" / TABLE
        out.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(out, lambda tmp: tmp.write_text(text))
        learners = sum(line.startswith("| `") for line in text.splitlines())
        print(f"history: {learners} learners judged, written to {out}")
        return 0

    return run_cli("coopsumo history", body)
