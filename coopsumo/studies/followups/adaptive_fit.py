"""`coopsumo adaptive-fit`: the adaptive rule's points from a finished `scenario2 --conditioned` folder.

Per condition, the mean loop occupancy its evaluations measured (runs.csv, all alphas and seeds) and its alpha*
(alpha_star.csv): written to ROOT/adaptive_rule.json, and the AdaptiveRule printed to paste into
coopsumo/agents/adaptive.py (DEFAULT_RULE, the rule `alpha=adaptive` drives by). `coopsumo adaptive` then drives
every model of the folder by it (adaptive_alpha).
"""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

from coopsumo.errors import UsageError, first_line
from coopsumo.files import read_json_object, write_json
from coopsumo.runio import Parser, run_cli
from coopsumo.studies.engine.run_folders import study_root

COLUMNS = {"runs.csv": ("key", "status", "lanes", "t_up_s", "seed", "alpha", "mean_speed_mps",
                        "lane_changes_per_vehicle", "loop_occupancy_pct"),
           "alpha_star.csv": ("lanes", "t_up_s", "alpha_star")}  # fmt: skip
"""the sweep's tables read here and by `coopsumo adaptive`, with the columns they need (loop_occupancy_pct: only a
conditioned sweep measures it)"""


def read_sweep(root: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(runs.csv's ok cells, alpha_star.csv) of the finished conditioned sweep in root; UsageError naming what is
    missing or unreadable, and for a sweep whose sweep.json says it is not conditioned (its rule was written into a
    plain or merged sweep)."""
    if not root.is_dir():
        raise UsageError(f"{root} is not a folder: give a finished `coopsumo scenario2 --conditioned` folder")
    profile = (read_json_object(root / "sweep.json") or {}).get("profile")
    if isinstance(profile, dict) and profile.get("conditioned") is False:  # a sweep of one model per alpha
        raise UsageError(f"{root} holds a scenario2 sweep that is not conditioned (its sweep.json: profile "
                         f"{str(profile.get('name'))[:40]}, conditioned false); give a finished `coopsumo scenario2 "
                         "--conditioned` folder")  # fmt: skip
    tables = {}
    for name, columns in COLUMNS.items():
        path = root / name
        if not path.is_file():
            raise UsageError(f"{root} holds no {name}: run `coopsumo scenario2 --profile quick --conditioned --out "
                             f"{root}` first")
        try:
            tables[name] = pd.read_csv(path)
        except ValueError as err:  # pandas' parser and empty-file errors
            raise UsageError(f"{path} cannot be read: {first_line(err)}") from None
        if missing := [c for c in columns if c not in tables[name].columns]:
            raise UsageError(f"{path} has no column {missing[0]}: not a finished `scenario2 --conditioned` sweep")
    runs = tables["runs.csv"]
    return runs[runs["status"] == "ok"], tables["alpha_star.csv"]


def fit(runs: pd.DataFrame, star: pd.DataFrame) -> list[tuple[int, float, float]]:
    """(lanes, mean loop occupancy %, alpha*) of every condition with an alpha*."""
    occ = runs.groupby(["lanes", "t_up_s"])["loop_occupancy_pct"].mean()
    rows = []
    for r in star.itertuples():
        if pd.notna(r.alpha_star) and (r.lanes, r.t_up_s) in occ.index:
            rows.append((int(r.lanes), round(float(occ[(r.lanes, r.t_up_s)]), 3), float(r.alpha_star)))
    return rows


def build_parser() -> Parser:
    p = Parser(prog="coopsumo adaptive-fit",
               description="Fit the adaptive rule (lanes, mean loop occupancy, alpha*) on a `scenario2 --conditioned` "
                           "sweep: ROOT/adaptive_rule.json, printed as DEFAULT_RULE.")  # fmt: skip
    p.add_argument("root", type=Path, metavar="ROOT", help="a finished `coopsumo scenario2 --conditioned` folder")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def body() -> int:
        from coopsumo.agents.adaptive import fit_rule

        runs, star = read_sweep(args.root)
        try:
            rule = fit_rule(fit(runs, star), str(args.root))
        except ValueError as err:  # no condition with an alpha* and a finite occupancy
            raise UsageError(f"{args.root}: {err}") from None
        with study_root(args.root, "scenario2"):  # a scenario2 sweep's folder: its lock held, its ownership checked
            write_json(args.root / "adaptive_rule.json", {"points": rule.points, "source": rule.source})
        print(f"DEFAULT_RULE = AdaptiveRule(points={rule.points!r}, source={rule.source!r})")
        return 0

    return run_cli("adaptive-fit", body)


if __name__ == "__main__":
    sys.exit(main())
