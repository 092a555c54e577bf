"""Issue 82, probe 19, TB2: the analysis scripts of experiments/ ended in tracebacks on bad input (a missing or
foreign model store, a runs.csv without its CPU times, a group of 0 steps) and stacked_bench.py failed on every run
(learn() had lost an argument); now one line each, and stacked_bench runs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]


def _run(script: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(ROOT / "experiments" / script), *args], capture_output=True, text=True,
                          timeout=300, cwd=ROOT, check=False)  # fmt: skip


def _no_traceback(done: subprocess.CompletedProcess[str]) -> list[str]:
    assert "Traceback" not in done.stderr and "Exception ignored" not in done.stderr, done.stderr[-2000:]
    return done.stderr.strip().splitlines()


def test_screening_reading_names_a_missing_store_and_passes_over_a_foreign_folder(tmp_path: Path) -> None:
    done = _run("screening_reading.py", str(tmp_path / "none"))
    assert done.returncode == 2 and _no_traceback(done) == [
        f"screening_reading: error: {tmp_path / 'none'} is not a folder (a model store: results/models, or "
        "$COOPSUMO_MODELS)"]  # fmt: skip
    (tmp_path / "store" / "foreign").mkdir(parents=True)
    (tmp_path / "store" / "foreign" / "config.json").write_text(json.dumps({"steps": 30}))
    done = _run("screening_reading.py", str(tmp_path / "store"))
    lines = _no_traceback(done)
    assert done.returncode == 1 and lines[0].endswith("foreign holds no training's config.json; passed over"), lines


def test_profile_cost_names_a_table_without_its_cpu_times(tmp_path: Path) -> None:
    runs = pd.read_csv(ROOT / "results" / "scenario2" / "runs.csv")
    for name, frame in (("nocol", runs.drop(columns=["cell_cpu_s"])), ("blank", runs.assign(cell_cpu_s=None))):
        (tmp_path / name).mkdir()
        frame.to_csv(tmp_path / name / "runs.csv", index=False)
        done = _run("profile_cost.py", "full", str(tmp_path / name))
        lines = _no_traceback(done)
        assert done.returncode == 2 and len(lines) == 1, lines
        assert lines[0].startswith("profile_cost: error: no cell of "), lines


def test_group_processes_refuses_sizes_it_cannot_run_in_one_line() -> None:
    for args in (("0", "0"), ("99999999999999999999", "1"), ("\u0663",)):  # 0 steps, 10**20 members, an Arabic 3
        done = _run("group_processes.py", *args)
        lines = _no_traceback(done)
        assert done.returncode == 2 and len(lines) == 1 and lines[0].startswith("usage: "), (args, lines)


def test_stacked_bench_runs() -> None:
    done = _run("stacked_bench.py", "--rounds", "1", "--groups", "1,2")
    assert done.returncode == 0, done.stderr[-2000:]
    assert "round 1: K=1: " in done.stdout and done.stdout.splitlines()[-1].startswith("2 ")
    done = _run("stacked_bench.py", "--groups", "0")
    lines = _no_traceback(done)  # argparse's usage, then its error
    assert done.returncode == 2, lines
    assert lines[-1] == "stacked_bench.py: error: --rounds must be at least 1 and every group size from 1 to 64"
