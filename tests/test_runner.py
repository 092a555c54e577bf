"""The shared study runner (coopsumo.studies.engine.runner) with cells that need no SUMO: records written per cell,
failures recorded while the rest finish, dependencies between cells, local against Ray; and scenario I on Ray."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
from conftest import env_with_display

from coopsumo.studies.engine import records as cell_records
from coopsumo.studies.engine import runner

ROOT = Path(__file__).resolve().parent.parent


def cell_record(spec: dict[str, Any], status: str, **extra: Any) -> dict[str, Any]:
    return {"key": spec["key"], "config": spec["config"], "status": status, **extra}


def failed(spec: dict[str, Any], error: str) -> dict[str, Any]:
    return cell_record(spec, "failed", error=error)


def square_cell(spec: dict[str, Any], root: str) -> dict[str, Any]:
    """A cell without SUMO (run in a worker process): squares its number, fails on x = 3, writes a marker file."""
    (Path(root) / f"ran_{spec['key']}").write_text(str(os.getpid()))
    x = spec["config"]["x"]
    if x == 3:
        return cell_records.run_recorded(cell_record(spec, "?"), lambda: (_ for _ in ()).throw(ValueError("three")))
    return cell_records.run_recorded(cell_record(spec, "?", value=x * x), lambda: None)


def specs_of(xs: list[int], after: dict[int, int] | None = None) -> list[dict[str, Any]]:
    after = after or {}
    return [{"key": f"c{x}", "config": {"x": x}, **({"after": f"c{after[x]}"} if x in after else {})} for x in xs]


def run_local(specs: list[dict[str, Any]], root: Path, done_keys: tuple[str, ...] = ()) -> dict[str, int]:
    backend = runner.make_backend("local", 2, None, square_cell)
    try:
        return runner.execute(specs, root, backend, len(specs), 0, progress=False, failed_record=failed,
                              done_keys=done_keys)  # fmt: skip
    finally:
        backend.close()


def records(root: Path) -> dict[str, dict[str, Any]]:
    return {p.stem: json.loads(p.read_text()) for p in sorted((root / "cells").glob("*.json"))}


def test_a_failing_cell_is_recorded_and_the_rest_finish(tmp_path: Path) -> None:
    counts = run_local(specs_of([1, 2, 3, 4]), tmp_path)
    assert counts == {"ok": 3, "failed": 1}
    got = records(tmp_path)
    assert [got[f"c{x}"]["value"] for x in (1, 2, 4)] == [1, 4, 16]
    assert got["c3"]["status"] == "failed" and got["c3"]["error"] == "ValueError: three"
    assert all(r["cell_wall_s"] is not None and r["versions"] for r in got.values())
    assert cell_records.read_record(tmp_path, specs_of([2])[0])["value"] == 4  # type: ignore[index]
    assert cell_records.read_record(tmp_path, {"key": "c2", "config": {"x": 5}}) is None  # another configuration


def test_a_record_is_reused_whatever_its_table_read_interval(tmp_path: Path) -> None:
    """full_read_every_steps changes speed, not results: a cell stored before the field existed (or with another
    interval) is still this cell; any other difference is not."""
    sim = {"seed": 1, "road": {"lanes": 3}}
    (tmp_path / "cells").mkdir()
    cell_records.cell_path(tmp_path, "s").write_text(json.dumps({"key": "s", "config": {"sim": sim}, "value": 7}))
    spec = {"key": "s", "config": {"sim": {**sim, "full_read_every_steps": 10}}}
    assert cell_records.read_record(tmp_path, spec)["value"] == 7  # type: ignore[index]
    assert cell_records.read_record(tmp_path, {"key": "s", "config": {"sim": {**sim, "seed": 2}}}) is None


def test_a_cell_waits_for_its_dependency_and_fails_with_it(tmp_path: Path) -> None:
    counts = run_local(specs_of([1, 2, 3, 4], after={2: 1, 4: 3}), tmp_path)
    assert counts == {"ok": 2, "failed": 2}
    got = records(tmp_path)
    assert got["c2"]["status"] == "ok" and got["c2"]["value"] == 4
    assert got["c4"]["status"] == "failed" and got["c4"]["error"] == "needs cell c3, which failed"
    assert not (tmp_path / "ran_c4").exists()  # never started
    # a dependency finished before (done_keys) or not part of this call does not hold a cell back
    counts = run_local(specs_of([5], after={5: 1}), tmp_path / "again", done_keys=("c1",))
    assert counts == {"ok": 1, "failed": 0}


def test_a_rerun_skips_finished_cells(tmp_path: Path) -> None:
    """As the studies do: cells whose record is ok are not given to execute again."""
    specs = specs_of([1, 2, 3])
    run_local(specs, tmp_path)
    for marker in tmp_path.glob("ran_*"):
        marker.unlink()
    todo = [s for s in specs if (cell_records.read_record(tmp_path, s) or {}).get("status") != "ok"]
    assert [s["key"] for s in todo] == ["c3"]
    run_local(todo, tmp_path)
    assert sorted(p.name for p in tmp_path.glob("ran_*")) == ["ran_c3"]


def test_local_and_ray_give_the_same_records(tmp_path: Path, ray_alone: None) -> None:
    cloudpickle = pytest.importorskip("ray.cloudpickle")
    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # Ray's workers cannot import this test module
    specs = specs_of([1, 2, 3, 4], after={4: 2})
    run_local(specs, tmp_path / "local")
    backend = runner.make_backend("ray", 2, None, square_cell)
    try:
        counts = runner.execute(specs, tmp_path / "ray", backend, len(specs), 0, progress=False, failed_record=failed)
    finally:
        backend.close()
    assert counts == {"ok": 3, "failed": 1}

    def comparable(r: dict[str, Any]) -> dict[str, Any]:
        return {k: v for k, v in r.items() if k not in ("cell_wall_s", "cell_cpu_s", "traceback")}

    local, ray = records(tmp_path / "local"), records(tmp_path / "ray")
    assert {k: comparable(r) for k, r in local.items()} == {k: comparable(r) for k, r in ray.items()}


@pytest.mark.sumo
def test_scenario1_on_ray_gives_the_same_summary_as_local(tmp_path: Path, ray_alone: None) -> None:
    pytest.importorskip("ray")
    tables = {}
    for backend in ("local", "ray"):
        out = tmp_path / backend
        cmd = [sys.executable, "-m", "coopsumo", "scenario1", "--quick", "--train-steps", "300", "--steps", "450",
               "--seeds", "1", "--train-seeds", "1", "--alphas", "0", "--t-up", "1", "--mobil-p", "0",
               "--backend", backend, "--out", str(out)]  # fmt: skip
        res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False, env=env_with_display(None))
        assert res.returncode == 0, res.stderr[-2000:]
        # the model's training and 5 policies (alpha 0, keep, greedy, MOBIL p = 0, sumo) x 1 demand x 1 seed; the
        # second study takes the first one's model from the model store beside them (the same training) and trains
        # nothing: its training's cell only links the stored model
        trained = 1 if backend == "local" else 0
        assert len(list((out / "cells").glob("*.json"))) == 1 + 5
        assert f"{1 - trained} of 1 models from the model store" in res.stderr
        assert f"; {trained} trainings to run" in res.stderr
        tables[backend] = pd.read_csv(out / "summary.csv")
    pd.testing.assert_frame_equal(tables["local"], tables["ray"])


# -- stored records: trusted only when sound ----------------------------------------------------------------
GOOD = {"key": "c1", "config": {"x": 1}, "status": "ok", "summary": {"v": 2.5, "n": 3, "note": "text"}}


@pytest.mark.parametrize(
    ("text", "why"),
    [
        (json.dumps({**GOOD, "summary": {}}), "summary is {}"),
        (json.dumps({**GOOD, "summary": None}), "summary is null"),
        (json.dumps({**GOOD, "summary": [2.5]}), "summary is [2.5]"),
        (json.dumps({**GOOD, "summary": {"v": "fast", "n": 3}}), 'v = "fast", not a number'),
        (json.dumps({**GOOD, "summary": {"v": None, "n": 3}}), "v = null, not a number"),
        (json.dumps({**GOOD, "summary": {"v": True, "n": 3}}), "v = true, not a number"),
        (json.dumps({**GOOD, "summary": {"v": float("nan"), "n": 3}}), "v = nan, not a finite number"),
        (json.dumps({**GOOD, "summary": {"v": float("inf"), "n": 3}}), "v = inf, not a finite number"),
        (json.dumps({**GOOD, "summary": {"n": 3}}), "v = null, not a number"),  # a required key missing
        (json.dumps([GOOD]), "is a JSON list, not an object"),
        (json.dumps("ok"), "is a JSON str, not an object"),
        (json.dumps({k: v for k, v in GOOD.items() if k != "status"}), "has no status"),
        (json.dumps({**GOOD, "status": None}), 'has status null, not "ok"'),
        (json.dumps(GOOD)[:30], "is unreadable (JSONDecodeError)"),
        (b"\xff\xfe".decode("latin-1"), "is unreadable"),
    ],
)  # fmt: skip
def test_a_corrupt_record_is_rerun_with_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str,
                                                  why: str) -> None:  # fmt: skip
    (tmp_path / "cells").mkdir()
    cell_records.cell_path(tmp_path, "c1").write_text(text, encoding="latin-1")
    done = cell_records.reusable_keys(tmp_path, specs_of([1]), "study", ("v", "n"))
    assert done == set()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("study: cell c1: record ") and why in err[0], err
    assert err[0].endswith("; rerunning it") and "Traceback" not in err[0]


FULL = {**GOOD, "kind": "run", "error": None, "traceback": None, "cell_wall_s": 2.5, "cell_cpu_s": 2.4,
        "versions": {"python": "3"}, "train_summary": None, "seed": 100, "eval_seed": 5001,
        "alpha": 8.0, "t_up_s": 2.0, "t_up": 2.0, "lanes": 3, "p": None, "model_sha256": "ab12", "load": 0.5,
        "resumed_from_step": None, "train_group_cpu_s": 12.5}  # fmt: skip
"""a cell record with every field of record_schemas.CELL_RECORD, each inside its limits"""
OUTSIDE = {"key": "", "kind": 3, "status": "done", "config": "x", "error": 5, "traceback": ["t"], "cell_wall_s": -1.0,
           "cell_cpu_s": "12 s", "versions": [], "train_summary": 3, "seed": -1,
           "eval_seed": 1.5, "alpha": -0.5, "t_up_s": 0.0, "t_up": 4000.0, "lanes": 7, "p": 11.0,
           "model_sha256": None, "load": "x", "resumed_from_step": -7, "train_group_cpu_s": 1e300}  # fmt: skip
"""a value outside each field's type or limits"""


BEYOND = {"a wall time of 1e300 s": ({"cell_wall_s": 1e300}, "field cell_wall_s must be"),
          "a CPU time of 1e300 s": ({"cell_cpu_s": 1e300}, "field cell_cpu_s must be"),
          "an error beside ok": ({"error": "boom"}, 'has status ok beside error "boom"'),
          "a traceback beside ok": ({"traceback": "Traceback ..."}, 'has status ok beside traceback "Traceback')}
"""issue 82, probe 13, F10: each was reused; sweep.json summed the wall time into 1e300 s and runs.csv copied the
error into an ok row"""


@pytest.mark.parametrize("case", sorted(BEYOND))
def test_a_record_no_run_writes_is_rerun_with_one_line(case: str, tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    (tmp_path / "cells").mkdir()
    path = cell_records.cell_path(tmp_path, "c1")
    edit, words = BEYOND[case]
    path.write_text(json.dumps({**FULL, **edit}))
    assert cell_records.reusable_keys(tmp_path, specs_of([1]), "study", ("v", "n")) == set()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"study: cell c1: record {path} {words}"), err
    assert cell_records.checked_record({**FULL, **edit}, ("v", "n"))["status"] == "failed"


def test_the_cases_cover_every_field_of_a_cell_record() -> None:
    from coopsumo.record_schemas import CELL_RECORD

    assert set(FULL) == set(OUTSIDE) | {"summary"} == {f.name for f in CELL_RECORD.fields} | {"summary"}
    assert CELL_RECORD.problem(FULL) is None and cell_records.cell_problem(FULL, ("v", "n")) is None


@pytest.mark.parametrize("field", sorted(OUTSIDE))
def test_a_record_outside_its_schema_is_rerun_with_one_line_naming_the_field(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], field: str) -> None:  # fmt: skip
    """Issue 82: a record whose envelope (key, status, times, configuration, the studies' shared coordinates) lies
    outside record_schemas.CELL_RECORD is not trusted: the cell is rerun, with one line naming the file and the
    field."""
    (tmp_path / "cells").mkdir()
    path = cell_records.cell_path(tmp_path, "c1")
    path.write_text(json.dumps({**FULL, field: OUTSIDE[field]}))
    assert cell_records.reusable_keys(tmp_path, specs_of([1]), "study", ("v", "n")) == set()
    err = capsys.readouterr().err.strip().splitlines()
    words = 'has status "done", not "ok"' if field == "status" else f"field {field} must be"
    assert len(err) == 1 and err[0].startswith(f"study: cell c1: record {path} {words}"), err
    assert err[0].endswith("; rerunning it")
    # a cell that ran and broke the schema is counted as failed, not ok
    counted = cell_records.checked_record({**FULL, field: OUTSIDE[field]}, ("v", "n"))
    assert counted["status"] == "failed" or field == "status", counted
    assert field == "status" or counted["error"].startswith(f"record field {field} must be")


def test_a_cell_that_breaks_the_schema_is_written_as_failed() -> None:
    """The writer's side: run_recorded records a cell whose body leaves a field outside CELL_RECORD as failed."""
    record = cell_records.run_recorded({**FULL, "alpha": -1.0}, lambda: None)
    assert record["status"] == "failed" and record["error"].startswith("record field alpha must be a finite number")
    assert cell_records.run_recorded(dict(FULL), lambda: None)["status"] == "ok"


def test_a_record_cut_by_a_kill_of_the_writer_is_removed_and_the_cell_rerun(tmp_path: Path) -> None:
    """SIGKILL of a study's main process while it writes a record leaves that record's temporary file (no process
    can catch SIGKILL); the next run removes it and reruns the cell. Other files are left alone."""
    (tmp_path / "cells").mkdir()
    cut = tmp_path / "cells" / ".c2.json.k3x9q2ab.tmp"  # as files.write_atomic names it (mkstemp)
    cut.write_text(json.dumps(GOOD)[:20])
    cell_records.cell_path(tmp_path, "c1").write_text(json.dumps(GOOD))
    other = tmp_path / "cells" / "notes.tmp"
    other.write_text("a user's file")
    assert cell_records.reusable_keys(tmp_path, specs_of([1, 2]), "study", ("v", "n")) == {"c1"}
    assert not cut.exists() and other.read_text() == "a user's file"


def test_a_sound_record_is_reused_and_expected_reruns_are_silent(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    (tmp_path / "cells").mkdir()
    cell_records.cell_path(tmp_path, "c1").write_text(json.dumps(GOOD))  # sound (a string beside the numbers is fine)
    cell_records.cell_path(tmp_path, "c2").write_text(json.dumps({**GOOD, "key": "c2", "status": "failed"}))
    cell_records.cell_path(tmp_path, "c3").write_text(json.dumps({**GOOD, "key": "c3"}))  # made with x = 1, not 3
    # c4 has no record yet
    assert cell_records.reusable_keys(tmp_path, specs_of([1, 2, 3, 4]), "study", ("v", "n")) == {"c1"}
    assert capsys.readouterr().err == ""
    # issue 82 (s2x2): a record copied in from another cell is rerun with a line naming both
    cell_records.cell_path(tmp_path, "c5").write_text(json.dumps(GOOD))
    assert cell_records.reusable_keys(tmp_path, specs_of([1, 5]), "study", ("v", "n")) == {"c1"}
    path = cell_records.cell_path(tmp_path, "c5")
    assert capsys.readouterr().err == f"study: cell c5: record {path} is cell c1's (copied?); rerunning it\n"
    # read_record never raises on a record of the wrong shape
    cell_records.cell_path(tmp_path, "c2").write_text("[1, 2]")
    assert cell_records.read_record(tmp_path, specs_of([2])[0]) is None


def test_failed_exit_names_the_failed_cells(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cell_records.failed_exit("study", [], 4, tmp_path) == 0 and capsys.readouterr().err == ""
    assert cell_records.failed_exit("study", ["c3", "c4"], 4, tmp_path) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("study: error: 2 of 4 cells failed (c3, c4)")


# -- distinct parameter values never share a key or folder --------------------------------------------------
def test_number_names_are_exact_and_keep_the_short_form() -> None:
    from coopsumo.validation import number_name

    assert [number_name(x) for x in (8.0, 0.0, 0.125, 2.5, 1e-05, 0.1)] == ["8", "0", "0.125", "2.5", "1e-05", "0.1"]
    assert number_name(8.000001) == "8.000001" and number_name(1 / 3) == repr(1 / 3)
    values = [8.0, 8.000001, 8.0000001, 8 + 2**-40, 1 / 3, 0.3333333, 123456.0, 123456.5, 1e6, 1e6 + 1]
    names = [number_name(v) for v in values]
    assert len(set(names)) == len(values) and [float(n) for n in names] == values


def test_close_alphas_give_distinct_cells_in_every_study() -> None:
    from dataclasses import replace

    from coopsumo.studies.protocol import plan as protocol
    from coopsumo.studies.scenario1 import study as scenario1
    from coopsumo.studies.scenario2 import study as scenario2

    profile = replace(scenario2.PROFILES["tiny"], alphas=(8.0, 8.000001), t_up_s=(2.0, 2.000001))
    keys = [s["key"] for s in scenario2.cell_specs(profile)]
    assert len(keys) == len(set(keys)) == profile.n_cells()
    assert "L2_T2_a8_s1" in keys and "L2_T2.000001_a8.000001_s1" in keys
    judged = replace(protocol.PROFILES["tiny"], alphas=(8.0, 8.000001))
    above = [s for s in protocol.cell_specs(judged) if s["alpha"] > 0]
    assert len(above) == 2 * judged.alpha_seeds * len(judged.t_ups) == len({s["key"] for s in above})
    assert len({s["train_key"] for s in above}) == 2 * judged.alpha_seeds
    assert scenario1.model_name("default", 8.0, 100) == "alpha8_m100" != scenario1.model_name("default", 8.000001, 100)
    assert scenario1.run_folder("keep", 1, 8.0) != scenario1.run_folder("keep", 1, 8.000001)


def test_study_lists_refuse_only_equal_values() -> None:
    from coopsumo.errors import UsageError
    from coopsumo.validation import distinct_list

    assert distinct_list("--t-up", "8,8.000001") == (8.0, 8.000001)
    with pytest.raises(UsageError, match="same value twice in '8,8.0': '8' and '8.0'"):
        distinct_list("--t-up", "8,8.0")
    with pytest.raises(UsageError, match="'0' and '-0'"):  # 0 == -0, though number_name tells them apart
        distinct_list("--alphas", "0,-0")


def test_a_fresh_record_with_a_bad_summary_counts_as_failed() -> None:
    bad = {**GOOD, "summary": {"v": None, "n": 3}}
    assert cell_records.checked_record(GOOD, ("v", "n")) == GOOD
    assert cell_records.checked_record(bad, ("v", "n"))["status"] == "failed"
    assert cell_records.checked_record(bad, ("v", "n"))["error"] == "record has summary v = null, not a number"
    assert cell_records.checked_record({**bad, "status": "failed"}, ("v",))["status"] == "failed"


def test_a_cell_counts_the_cpu_of_the_processes_it_ran() -> None:
    """A training's update worker and validations are child processes: their CPU time is the cell's too."""
    burn = "import time\nt = time.process_time()\nwhile time.process_time() - t < 0.4: pass"
    record = cell_records.run_recorded({"key": "c1", "config": {}},
                                       lambda: subprocess.run([sys.executable, "-c", burn], check=True))
    assert record["status"] == "ok" and record["cell_cpu_s"] >= 0.4


class _StepBackend:
    """A backend without processes: each wait() ends the oldest cell in flight with an ok record."""

    name = "local"
    slots = 2

    def __init__(self) -> None:
        self.running: list[dict[str, Any]] = []

    def submit(self, spec: dict[str, Any], root: Path) -> Any:
        self.running.append(spec)
        return spec["key"]

    def wait(self, handles: list[Any], timeout: float) -> list[tuple[Any, dict[str, Any]]]:
        spec = self.running.pop(0)
        return [(spec["key"], cell_record(spec, "ok"))]

    def abort(self) -> None:
        pass


class _BarSpy:
    """tqdm's place in runner.execute: what the bar showed at each refresh (its format and postfix)."""

    def __init__(self, **kwargs: Any) -> None:
        self.bar_format = kwargs.get("bar_format")
        self.postfix = ""
        self.shown: list[tuple[str | None, str]] = []

    def set_postfix_str(self, text: str, refresh: bool = True) -> None:
        self.postfix = text

    def refresh(self) -> None:
        self.shown.append((self.bar_format, self.postfix))

    def update(self, n: int) -> None:
        self.refresh()

    def close(self) -> None:
        self.refresh()  # tqdm draws the bar a last time


def test_the_bar_names_the_cells_in_flight_and_estimates_only_after_a_cell_ends(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    bars: list[_BarSpy] = []
    monkeypatch.setattr(runner, "tqdm", lambda **kw: bars.append(_BarSpy(**kw)) or bars[-1])
    specs = [{"key": "L3_T1.33_a0_s1", "config": {}}, {"key": "noreturn_alpha0_seed0", "kind": "train", "config": {}},
             {"key": "train_alpha8_m100", "kind": "train", "config": {}}]  # fmt: skip
    backend: Any = _StepBackend()
    counts = runner.execute(specs, tmp_path, backend, 3, 0, progress=True, failed_record=failed)
    assert counts == {"ok": 3, "failed": 0}
    shown = bars[0].shown
    first_end = next(i for i, (fmt, _) in enumerate(shown) if fmt is None)
    assert shown[0] == (runner.WAITING_FORMAT, "running L3_T1.33_a0_s1, training noreturn_alpha0_seed0")
    assert all("{remaining}" not in fmt for fmt, _ in shown[:first_end])  # type: ignore[operator]
    assert "{remaining}" not in runner.WAITING_FORMAT and "{elapsed}" in runner.WAITING_FORMAT
    assert all(fmt is None for fmt, _ in shown[first_end:])  # tqdm's own format, with its estimate, from then on
    assert shown[-1][1] == "" and any(text == "running train_alpha8_m100" for _, text in shown)  # none at the end


def test_a_cells_label_is_short_and_the_bar_says_how_many_more_run() -> None:
    long_key = "alpha_only_a0.25_seed100_accident_t1.5_set40_extra"
    label = runner.cell_label({"key": long_key})
    assert len(label) == runner.LABEL_CHARS and label.startswith("alpha_only") and label.endswith("_extra")
    assert runner.cell_label({"key": "a0_seed1", "kind": "train"}) == "training a0_seed1"
    specs = [{"key": f"c{i}"} for i in range(5)]
    assert runner.in_flight_text(specs, 0) == "running c0, c1, c2 and 2 more"
    assert runner.in_flight_text(specs[:1], 2) == "running c0; 2 failed"
    assert runner.in_flight_text([], 1) == "1 failed" and runner.in_flight_text([], 0) == ""


def test_a_record_that_is_a_pipe_is_rerun_without_waiting_on_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """A fresh probe (issue 82): a cell record made a FIFO hung the study on its read; the cell is rerun, one line."""
    import os

    (tmp_path / "cells").mkdir()
    os.mkfifo(cell_records.cell_path(tmp_path, "c1"))
    assert cell_records.reusable_keys(tmp_path, specs_of([1]), "study", ("v", "n")) == set()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is not a regular file; rerunning it" in err[0]


def test_sigterm_during_a_studys_cells_ends_with_its_own_exit_code(capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 82, probe 8, J17: a SIGTERM while a study's workers ran became a plain KeyboardInterrupt, reported with
    exit code 130 (SIGINT's); it keeps its signal: 143."""
    import os
    import signal
    import time

    from coopsumo.runio import interrupted
    from coopsumo.studies.engine.runner import sigterm_interrupts

    with pytest.raises(KeyboardInterrupt) as caught, sigterm_interrupts():
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler raises at once
    assert interrupted("scenario2", caught.value) == 128 + signal.SIGTERM
    assert capsys.readouterr().err == "scenario2: interrupted\n"


def test_a_temporary_folder_too_long_for_the_fork_servers_socket_falls_back_to_spawned_workers(tmp_path: Path) -> None:
    """The fork server listens on a socket file in the temporary folder; under a TMPDIR whose path leaves no room for
    it in an AF_UNIX address (108 bytes) every study ended in "AF_UNIX path too long", exit 1 (2026-12-05, found
    before it landed). Its workers are spawned then, as before the fork server, and run their cells; under a short
    TMPDIR the same process forks them."""
    script = ("import sys; from pathlib import Path; from coopsumo.studies.engine import runner\n"
              "backend = runner.LocalBackend(1, cell_fn=dict.get)\n"  # dict.get(spec, root): a cell in one call
              "handles = [backend.submit({'key': 'k'}, Path('unused'))]\n"
              "done = []\n"
              "while not done:\n"
              "    done = backend.wait(handles, timeout=1.0)\n"
              "backend.close()\n"
              "print(backend._ctx.get_start_method(), done[0][1])\n")  # fmt: skip
    (tmp_path / ("x" * 100)).mkdir()
    for tmp, method in ((tmp_path / ("x" * 100), "spawn"), (Path("/tmp"), "forkserver")):
        env = {**os.environ, "TMPDIR": str(tmp)}  # multiprocessing's own folder there is removed as the process ends
        done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120,
                              check=False)  # fmt: skip
        assert (done.returncode, done.stdout) == (0, f"{method} None\n"), done.stderr[-2000:]
