"""Issue 82, probe 16, TR1: a rerun of scenario I or accident-seeds (since retired) reused a run folder whose
trajectories.parquet or detectors.xml had been copied in from another run of the same road. Each file was checked
only on its own (readable, on the road, within a lane's capacity), so the other run's measures went into runs.csv and
Fig. 5 with no line. A finished run's marker now records the sha256 of each file its run wrote (run_markers.SUMS),
and a file that is not that one makes the run be done again, with one line naming the folder and the file. A marker
written before (no digests) is judged as before: its folder is reused."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

import pytest

from coopsumo.run_dirs import RUN_MARKER, mark_run_dir
from coopsumo.run_markers import SUMS, changed_file, marker_text

CHANGED = "that is not the file its run wrote (changed or copied in since); running it again"
"""the end of the line a rerun gives a run folder holding a file its run did not write"""


def _marker(folder: Path) -> dict[str, object]:
    return dict(json.loads((folder / RUN_MARKER).read_text()))


def _lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if " run folder " in line]


def test_a_runs_marker_records_its_files_digests_and_a_file_not_its_own_is_named(tmp_path: Path) -> None:
    """run_markers.changed_file against the digests mark_run_dir records: another file's bytes, a file put back, a
    named pipe (not waited on), a marker without digests (an older one) and one whose digests are damaged."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "detectors.xml").write_text("<detector/>\n")
    (run / "trajectories.parquet").write_bytes(b"its own samples")
    (run / "sub").mkdir()
    mark_run_dir(run, "simulate")
    marker = _marker(run)
    assert marker["files"] == ["detectors.xml", "sub", "trajectories.parquet"]
    assert marker[SUMS] == {"detectors.xml": hashlib.sha256(b"<detector/>\n").hexdigest(),
                            "trajectories.parquet": hashlib.sha256(b"its own samples").hexdigest()}  # fmt: skip
    assert changed_file(run) is None
    (run / "trajectories.parquet").write_bytes(b"another run's samples")
    assert changed_file(run) == f"has a trajectories.parquet {CHANGED.split(';')[0]}"
    (run / "trajectories.parquet").write_bytes(b"its own samples")  # the same bytes again: its own
    assert changed_file(run) is None
    (run / "detectors.xml").unlink()
    os.mkfifo(run / "detectors.xml")
    assert changed_file(run) == f"has a detectors.xml {CHANGED.split(';')[0]}"
    (run / RUN_MARKER).write_text(json.dumps({k: v for k, v in marker.items() if k != SUMS}))
    assert changed_file(run) is None  # a marker from before digests: judged as before
    (run / RUN_MARKER).write_text(json.dumps({**marker, SUMS: ["not", "a", "table"]}))
    assert changed_file(run) == f"has a {RUN_MARKER} whose {SUMS} is not a table of digests (damaged?)"
    training = tmp_path / "train"
    training.mkdir()
    (training / "model.pt").write_bytes(b"weights")
    mark_run_dir(training, "train")  # a training's files are judged by its model's digest: none recorded
    assert SUMS not in _marker(training) and _marker(training)["files"] == ["model.pt"]


def test_a_killed_marking_of_a_run_with_digests_is_still_a_markers_text(tmp_path: Path) -> None:
    """run_markers.marker_text knows the new key: every start of a run's marker with its digests, and of one with
    none (an empty folder), is what a killed write of a marker leaves."""
    temporary = tmp_path / "t.tmp"
    for files in ({}, {'a "b"': "x", "c.xml": "<c/>"}):
        run = tmp_path / f"run{len(files)}"
        run.mkdir()
        for name, text in files.items():
            (run / name).write_text(text)
        mark_run_dir(run, "simulate")
        text = (run / RUN_MARKER).read_text()
        assert f'"{SUMS}"' in text
        for end in range(len(text) + 1):
            temporary.write_text(text[:end])
            assert marker_text(temporary), text[:end]
        temporary.write_text(text + "x")
        assert not marker_text(temporary)
    temporary.write_text('{\n  "files": [],\n  "files_sha256": {\n    "a": "b": "c"\n')
    assert not marker_text(temporary)


@pytest.mark.sumo
def test_a_regime_map_rerun_redoes_a_run_folder_holding_another_runs_file(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """The probe's as_traj_swap (found in accident-seeds, whose accident runs were scenario I's, as the regime map's
    are): the paper-length accident's trajectories.parquet copied over the default one's. The run is done again with
    one line naming its folder and the file, and runs.csv is the study's own again; a rerun after that, and one of
    folders whose markers record no digests (written before), reuse every run without a line."""
    from coopsumo.studies.scenario1 import study as scenario1

    out = tmp_path / "rm"
    args = ["--regime-map", "--t-up", "4", "--seeds", "1", "--steps", "600", "--workers", "1", "--quiet", "--out",
            str(out)]  # fmt: skip
    assert scenario1.main(args) == 0
    own = (out / "runs.csv").read_text()
    default, paper = out / "runs" / "default" / "t4" / "keep_seed1", out / "runs" / "paper" / "t4" / "keep_seed1"
    shutil.copyfile(paper / "trajectories.parquet", default / "trajectories.parquet")
    capfd.readouterr()
    assert scenario1.main(args) == 0
    err = capfd.readouterr().err
    assert _lines(err) == [f"scenario1: run folder {default} has a trajectories.parquet {CHANGED}"], err
    assert (out / "runs.csv").read_text() == own
    assert scenario1.main(args) == 0  # untouched since (the redone run's marker records its new files)
    assert _lines(capfd.readouterr().err) == []
    folders = (default, paper)
    for folder in folders:  # markers as they were written before digests: reused as before
        marker = _marker(folder)
        del marker[SUMS]
        (folder / RUN_MARKER).write_text(json.dumps(marker))
    written = [(folder / "summary.json").stat().st_mtime_ns for folder in folders]
    assert scenario1.main(args) == 0
    assert _lines(capfd.readouterr().err) == [] and (out / "runs.csv").read_text() == own
    assert [(folder / "summary.json").stat().st_mtime_ns for folder in folders] == written
    assert all(SUMS not in _marker(folder) for folder in folders)


@pytest.mark.sumo
def test_a_scenario1_rerun_redoes_a_run_folder_holding_another_runs_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    """The probe's s1_det_swap and s1_traj_swap: greedy's detectors.xml copied over keep's (Fig. 5 drew keep from
    greedy's loops), greedy's trajectories.parquet over MOBIL's. Each run is done again with one line naming its
    folder and the file; runs.csv and Fig. 5 are the study's own again."""
    from coopsumo.studies.scenario1 import study as scenario1

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.setenv("COOPSUMO_MODELS", str(tmp_path / "models"))  # a model store of its own
    out = tmp_path / "s1"
    args = ["--quick", "--t-up", "2", "--mobil-p", "0", "--alphas", "0", "--train-steps", "200", "--steps", "300",
            "--seeds", "1", "--train-seeds", "1", "--workers", "1", "--quiet", "--out", str(out)]  # fmt: skip
    assert scenario1.main(args) == 0
    own = {name: (out / name).read_bytes() for name in ("runs.csv", "fig5_flow_density_t2.png")}
    runs = out / "runs" / "t2"
    keep, greedy, mobil = runs / "keep_seed1", runs / "greedy_seed1", runs / "mobil_p0_seed1"
    shutil.copyfile(greedy / "detectors.xml", keep / "detectors.xml")
    shutil.copyfile(greedy / "trajectories.parquet", mobil / "trajectories.parquet")
    capfd.readouterr()
    assert scenario1.main(args) == 0
    err = capfd.readouterr().err
    assert sorted(_lines(err)) == [f"scenario1: run folder {keep} has a detectors.xml {CHANGED}",
                                   f"scenario1: run folder {mobil} has a trajectories.parquet {CHANGED}"], err
    assert {name: (out / name).read_bytes() for name in own} == own
