"""Issue 77, item 4: what a model selection in two stages would pick, read offline on stored trainings.

A stored training that validated every snapshot on every run holds, inside each snapshot's validation.json, the
very runs a screening stage would make (the same configurations and seeds: agents/selection.validation_configs), so
the two-stage pick (DQNConfig.validation_screen, validation_finalists; read here for any set of screening demands)
follows from those files without a run: each snapshot's screening score is the mean reward over its runs at the
screening demands, the finalists the best screened (ties to the earlier step), the pick the finalist of the best
full score. For each scheme, the table
gives how many trainings it picks today's snapshot for, what the pick's full validation score loses against
today's best (mean and largest), and its share of today's greedy validation steps.

    .venv/bin/python experiments/screening_reading.py [STORE] [--preset NAME]

STORE defaults to results/models; --preset keeps the trainings of one learner preset (as config.json names it).
"""

from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path
from typing import Any

import numpy as np

from coopsumo.agents.snapshots import SNAPSHOTS, by_score, result
from coopsumo.errors import UsageError
from coopsumo.files import read_json_object
from coopsumo.runio import run_cli


def full_trainings(store: Path, preset: str | None) -> list[tuple[str, dict[str, Any], list[dict[str, Any]]]]:
    """(name, learner settings, every snapshot's full validation) of each stored training validated whole."""
    found = []
    if not store.is_dir():
        raise UsageError(f"{store} is not a folder (a model store: results/models, or $COOPSUMO_MODELS)")
    for folder in sorted(p for p in store.iterdir() if (p / "config.json").is_file()):
        config = read_json_object(folder / "config.json") or {}  # a folder no training wrote: passed over (probe 19)
        dqn = config.get("config", {}).get("dqn") if isinstance(config.get("config"), dict) else None
        if not isinstance(dqn, dict) or not isinstance(dqn.get("validation_t_ups"), list):
            print(f"screening_reading: {folder} holds no training's config.json; passed over", file=sys.stderr)
            continue
        if preset is not None and dqn.get("preset") != preset:
            continue
        snaps = sorted((folder / SNAPSHOTS).glob("step*"), key=lambda d: int(d.name[4:]))
        results = [result(d) for d in snaps]
        if len(results) >= 2 and all(r is not None for r in results):
            found.append((folder.name, dqn, results))
    return found


def run_steps(run: dict[str, Any], dqn: dict[str, Any]) -> int:
    return int(dqn["validation_accident_steps"] if run["accident"] else dqn["validation_steps"])


def pick(results: list[dict[str, Any]], screen: tuple[float, ...], finalists: int) -> dict[str, Any]:
    """The two-stage pick among a training's full validations."""
    screened = [dict(r, score=float(np.mean([x["mean_reward"] for x in r["runs"] if x["t_up_s"] in screen])))
                for r in results]  # fmt: skip
    chosen = {r["step"] for r in by_score(screened)[:finalists]}
    return by_score([r for r in results if r["step"] in chosen])[0]


def cost_share(results: list[dict[str, Any]], dqn: dict[str, Any], screen: tuple[float, ...], finalists: int) -> float:
    """Greedy validation steps of the two-stage scheme over today's (a finalist's screening runs are not run again)."""
    runs = results[0]["runs"]
    whole = sum(run_steps(x, dqn) for x in runs)
    screened = sum(run_steps(x, dqn) for x in runs if x["t_up_s"] in screen)
    n = len(results)
    return (n * screened + min(finalists, n) * (whole - screened)) / (n * whole)


def scheme_row(group: list[tuple[str, dict[str, Any], list[dict[str, Any]]]], screen: tuple[float, ...],
               finalists: int) -> str:
    """One scheme's table row over a group of trainings of one validation design."""
    same, lost, share = 0, [], []
    for _, dqn, results in group:
        today = by_score(results)[0]
        mine = pick(results, screen, finalists)
        same += mine["step"] == today["step"]
        lost.append(today["score"] - mine["score"])
        share.append(cost_share(results, dqn, screen, finalists))
    return (f"| {', '.join(f'{t:g}' for t in screen)} | {finalists} | {same} of {len(group)} | "
            f"{np.mean(lost):.4f} | {max(lost):.4f} | {np.mean(share):.0%} |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("store", nargs="?", default="results/models", type=Path)
    parser.add_argument("--preset", default=None)
    args = parser.parse_args(argv)
    return run_cli("screening_reading", lambda: _read(args))  # bad input: one line (issue 82, probe 19, TB2)


def _read(args: argparse.Namespace) -> int:
    trainings = full_trainings(args.store, args.preset)
    if not trainings:
        print(f"screening_reading: no training of {args.store} validated every snapshot on every run",
              file=sys.stderr)  # fmt: skip
        return 1
    designs: dict[tuple[Any, ...], list[tuple[str, dict[str, Any], list[dict[str, Any]]]]] = {}
    for training in trainings:  # the schemes are read per validation design
        dqn = training[1]
        designs.setdefault((tuple(dqn["validation_t_ups"]), dqn["validation_accident_steps"]), []).append(training)
    for (t_ups, accident_steps), group in designs.items():
        print(f"\n{len(group)} trainings of {args.store}: validation demands {', '.join(f'{t:g}' for t in t_ups)} s"
              f"{f', with accident runs of {accident_steps:,} steps' if accident_steps else ', free flow'}")
        print("| screen (T_up s) | finalists | today's pick | score lost: mean | largest | greedy steps |")
        print("|---|---|---|---|---|---|")
        for size in range(1, len(t_ups)):
            for screen in itertools.combinations(t_ups, size):
                for finalists in (1, 2, 3):
                    print(scheme_row(group, screen, finalists))
    return 0


if __name__ == "__main__":
    sys.exit(main())
