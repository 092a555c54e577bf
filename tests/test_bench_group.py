"""bench's group line (coopsumo/bench/group.py, issue 77) on a short training: `make bench`'s full run prints it,
`--quick` does not (tests/test_docs.py runs that), so it is run here at a size that takes seconds: a group of 2
against a lone training's figures given as bench gives them (its selection share trains the same lone training)."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import pytest

from coopsumo.bench.figures import scaled_selection
from coopsumo.bench.group import before_and_after, group_lines

pytestmark = pytest.mark.sumo
LINE = (r"  train \(default, 300 steps, selection scaled to it\): lone, as before issue 77, 20\.0 CPU s "
        r"\(9\.0 s wall\); a group of 2 with stacked updates and the two-stage selection (\d+\.\d) CPU s per model "
        r"\(\d+\.\d s wall for all 2\)")


def test_before_and_after_differ_in_issue_77s_settings_alone() -> None:
    before, after = before_and_after(scaled_selection(300))
    assert not before.dqn.stacked_updates and before.dqn.validation_screen == 0
    assert after.dqn.stacked_updates and after.dqn.validation_screen == 1 and after.dqn.validation_finalists == 2
    assert replace(after, dqn=replace(after.dqn, stacked_updates=False, validation_screen=0)) == before


def test_the_group_line_measures_a_group_against_the_lone_training_given() -> None:
    cfg = scaled_selection(300)
    cfg = replace(cfg, dqn=replace(cfg.dqn, select_every_steps=0))  # the line's arithmetic, not a selection's cost
    cfg = before_and_after(cfg)[0]  # the lone figures given are this learner's
    first, second = group_lines(cfg, 2, lone=(20.0, 9.0))
    per_model = re.fullmatch(LINE, first)
    assert per_model, first
    assert 1.0 < float(per_model.group(1)) < 200.0  # two real trainings' processes were measured
    cost = re.match(r"group cost (\d+\.\d\d) ", second)
    assert cost and abs(float(cost.group(1)) - float(per_model.group(1)) / 20.0) <= 0.01, second
    after = before_and_after(cfg)[1]  # figures measured on another learner than the one before: trained again
    assert "lone, as before issue 77, 20.0 CPU s" not in group_lines(after, 1, lone=(20.0, 9.0))[0]


def test_experiments_group_processes_reads_every_process_of_a_group(tmp_path: Path) -> None:
    """docs/performance.md's table of where a model's CPU goes (2026-12-03) is made by experiments/group_processes.py:
    a group of 2 short trainings, each process's CPU from /proc, its members, update process and validations found;
    a bad K is a usage line, exit 2."""
    import json
    import subprocess
    import sys

    script = Path(__file__).resolve().parents[1] / "experiments" / "group_processes.py"
    done = subprocess.run([sys.executable, str(script), "2", "300"], capture_output=True, text=True, timeout=300,
                          cwd=str(tmp_path))  # fmt: skip
    assert done.returncode == 0, done.stderr
    found = json.loads(done.stdout.strip().splitlines()[-1])
    busy = [cpu for cpu in found["roles"]["member or update process"] if cpu > 0.2]
    assert found["k"] == 2 and len(busy) == 3 and len(found["roles"]["validation"]) == 2, found
    assert found["cpu_s_per_model"] * 2 >= sum(busy) + sum(found["roles"]["validation"]) > 0
    bad = subprocess.run([sys.executable, str(script), "two"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and bad.stderr.startswith("usage: ") and not bad.stdout
