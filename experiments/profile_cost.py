"""A scenario II profile's cost on 2 cores, estimated from finished studies' records, without a run.

Every cell of the profile (scenario2.plan.cell_specs) is given the mean CPU time that cells of the same lane count,
T_up, policy and MOBIL p took in the studies read (runs.csv's cell_cpu_s; a DQN cell's alpha is not matched, an
alpha the studies lack takes their other DQN cells' time), and every training the mean CPU share that trainings of its
lane count took in their groups (train_group_cpu_s, once per training folder). The wall time is the CPU time over
the cores, as a study that keeps both busy. Used for issue 77's last target (docs/performance.md):

    .venv/bin/python experiments/profile_cost.py full results/scenario2_confirm_parts/L2a ...
"""

from __future__ import annotations

import argparse
import statistics
import sys
from collections import defaultdict
from pathlib import Path

from coopsumo.errors import UsageError
from coopsumo.runio import run_cli
from coopsumo.studies.scenario2.plan import PROFILES, cell_specs


def read_rows(studies: list[Path]) -> list[dict[str, str]]:
    """Every ok row of the studies' runs.csv that measured its cell's CPU time, each table read through its schema
    (study_tables.SCENARIO2_RUNS: RecordError naming the file, the row and the column; issue 82, probe 19, TB2: a
    table without cell_cpu_s, or with blanks, was a traceback)."""
    from coopsumo.study_tables import SCENARIO2_RUNS

    rows = []
    for study in studies:
        frame = SCENARIO2_RUNS.read(study / "runs.csv").astype(object)
        frame = frame.where(frame.notna(), "")
        rows += [{k: str(v) for k, v in r.items()} for r in frame.to_dict("records")
                 if r["status"] == "ok" and r.get("cell_cpu_s", "") != ""]  # fmt: skip
    return rows


def _cell_class(lanes: object, t_up: object, policy: object, p: object) -> tuple[int, float, str, str]:
    return int(str(lanes)), round(float(str(t_up)), 2), str(policy), "" if p in (None, "") else f"{float(str(p)):g}"


def estimate(profile_name: str, studies: list[Path], cores: int) -> dict[str, float]:
    """Core-seconds of the profile's evaluation cells and trainings, and its wall hours on `cores`."""
    rows = read_rows(studies)
    cell_cpu: dict[tuple[int, float, str, str], list[float]] = defaultdict(list)
    train_cpu: dict[int, dict[str, float]] = defaultdict(dict)
    for r in rows:
        cell_cpu[_cell_class(r["lanes"], r["t_up_s"], r["policy"], r["p"])].append(float(r["cell_cpu_s"]))
        if r.get("train_dir") and r.get("train_group_cpu_s"):  # a study before groups: in its first cells' time
            train_cpu[int(r["lanes"])][r["train_dir"]] = float(r["train_group_cpu_s"])
    evals = trainings = 0.0
    seen: set[str] = set()
    for spec in cell_specs(PROFILES[profile_name]):
        times = cell_cpu.get(_cell_class(spec["lanes"], spec["t_up_s"], spec["policy"], spec["p"]))
        if not times:
            raise UsageError(f"no cell of {spec['lanes']} lanes at T_up {spec['t_up_s']} s, "
                             f"policy {spec['policy']} in the studies read")  # fmt: skip
        evals += statistics.fmean(times)
        if spec.get("train_key") and spec["train_key"] not in seen:
            seen.add(spec["train_key"])
            trainings += statistics.fmean(train_cpu[int(spec["lanes"])].values() or [0.0])
    return {"trainings": len(seen), "train_core_h": trainings / 3600, "eval_core_h": evals / 3600,
            "wall_h": (trainings + evals) / 3600 / cores}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("profile", choices=sorted(PROFILES))
    p.add_argument("studies", nargs="+", type=Path, help="finished scenario II studies (folders with runs.csv)")
    p.add_argument("--cores", type=int, default=2)
    args = p.parse_args(argv)
    missing = [s for s in args.studies if not (s / "runs.csv").is_file()]
    if missing:
        p.error(f"no runs.csv in {missing[0]}")
    if args.cores < 1:
        p.error(f"--cores must be at least 1, got {args.cores}")

    def body() -> int:
        e = estimate(args.profile, args.studies, args.cores)
        print(f"{args.profile}: {e['trainings']:.0f} trainings {e['train_core_h']:.2f} core-h, evaluation cells "
              f"{e['eval_core_h']:.2f} core-h; {e['wall_h']:.2f} h on {args.cores} cores")  # fmt: skip
        return 0

    return run_cli("profile_cost", body)  # a table outside its schema: one line, exit 2


if __name__ == "__main__":
    sys.exit(main())
