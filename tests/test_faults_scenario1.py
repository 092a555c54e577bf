"""Issue 25, parts 4 and 7: a tiny scenario I study stopped by Ctrl-C while it trains, killed while it runs the
accident (SIGKILL of the whole process group: partial run folders left behind) and while it writes its report;
rerun, it equals the uninterrupted study. Then its stored run folders and model are spoiled in the ways a rerun
must not trust (a summary value gone, detectors.xml and trajectories.parquet cut short, an empty model file): each
is redone, with one line saying why, and the study equals the uninterrupted one again. The study's folder is
marked as its own."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from coopsumo import simulate
from coopsumo.run_dirs import RUN_MARKER

pytestmark = pytest.mark.sumo
REPO = Path(__file__).resolve().parent.parent
STUDY = ["-m", "coopsumo", "scenario1", "--quick", "--t-up", "2", "--mobil-p", "0", "--alphas", "0", "--train-steps",
         "1500", "--steps", "600", "--seeds", "1", "--train-seeds", "1", "--workers", "2"]  # fmt: skip
"""1,500 training steps: seconds on a quiet machine, so that a Ctrl-C sent while the model trains lands in it"""
"""one model (alpha 0), one demand, one seed: a training and five accident runs (dqn_alpha0, keep, greedy, MOBIL
p = 0, sumo)"""
MODEL = "alpha0_m100"
"""the study's model folder under models/: a link into its model store"""


def env(out: Path) -> dict[str, str]:
    """No display (the report says why there is no screenshot); each study its own model store, so that the second
    study trains its model instead of taking the first one's."""
    return {**{k: v for k, v in os.environ.items() if k != "DISPLAY"}, "COOPSUMO_MODELS": f"{out}_models"}


def start(out: Path) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, *STUDY, "--out", str(out)], cwd=REPO, env=env(out), text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)  # fmt: skip


def run(out: Path) -> subprocess.CompletedProcess[str]:
    res = subprocess.run([sys.executable, *STUDY, "--out", str(out)], cwd=REPO, env=env(out), capture_output=True,
                         text=True, timeout=600, check=False)  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    return res


def run_here(out: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str],
             code: int = 0) -> str:  # fmt: skip
    """run's study by scenario I's main in this process, with run's environment (a rerun of a study whose earlier runs
    were processes): its stderr, its workers' too; its exit code must be `code`."""
    from coopsumo.studies.scenario1 import study as scenario1

    with monkeypatch.context() as patch:
        patch.delenv("DISPLAY", raising=False)
        patch.setenv("COOPSUMO_MODELS", env(out)["COOPSUMO_MODELS"])
        capfd.readouterr()
        got = scenario1.main([*STUDY[3:], "--out", str(out)])
        err = capfd.readouterr().err
    assert got == code, err[-2000:]
    return err


def kill_group_when(ready: Callable[[], bool], proc: subprocess.Popen[str], sig: int) -> tuple[int, str]:
    """Send sig to the study's process group as soon as ready(); wait until every process of it is gone. Returns
    the study's exit code and the end of its stderr."""
    end = time.monotonic() + 300
    while not ready():
        assert proc.poll() is None, f"the study ended too soon: {proc.communicate()[1][-1500:]}"
        assert time.monotonic() < end
        time.sleep(0.01)
    os.killpg(proc.pid, sig)
    _, err = proc.communicate(timeout=120)
    while True:
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            return proc.returncode, err[-1500:]
        assert time.monotonic() < end + 60, "the study's workers outlived it"
        time.sleep(0.1)


def leftovers(root: Path) -> list[str]:
    return sorted(str(p) for p in root.rglob("*") if ".partial-" in p.name or p.name.endswith((".tmp", ".lock"))
                  or p.name == "checkpoint.pt")  # fmt: skip


def test_scenario1_interrupted_and_spoiled_ends_as_the_uninterrupted_study(
    tmp_path: Path, capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The uninterrupted study and the interrupted ones run as processes; the reruns that judge what they left run
    scenario I's main in this process."""
    ref, cut = tmp_path / "ref", tmp_path / "cut"
    run(ref)
    runs_t2 = cut / "runs" / "t2"
    # 1. Ctrl-C while the model trains (its step-0 checkpoint exists)
    code, err = kill_group_when(lambda: (cut / "models" / MODEL / "checkpoint.pt").exists(), start(cut),
                                signal.SIGINT)  # fmt: skip
    assert code == 130 and "scenario1: interrupted" in err.splitlines() and "Traceback" not in err, err
    # 2. SIGKILL of everything once an accident run is finished: the runs still going leave partial folders
    done = lambda: runs_t2.is_dir() and any(".partial-" not in p.name for p in runs_t2.iterdir())  # noqa: E731
    assert kill_group_when(done, start(cut), signal.SIGKILL)[0] == -signal.SIGKILL
    # 3. SIGKILL while the report is written (runs.csv comes first, then the figures and report.md). Not Ctrl-C:
    # CPython ignores a KeyboardInterrupt that lands in a garbage collector's callback, which the report's many
    # objects make likely enough to lose the interrupt now and then
    assert kill_group_when(lambda: (cut / "runs.csv").exists(), start(cut), signal.SIGKILL)[0] == -signal.SIGKILL
    assert not (cut / "report.md").exists()
    # 4. the rerun finishes it: the same tables as the uninterrupted study, nothing partial left
    run_here(cut, monkeypatch, capfd)
    for name in ("runs.csv", "summary.csv"):
        assert (cut / name).read_text() == (ref / name).read_text(), name
    assert leftovers(tmp_path) == [] and (cut / "report.md").is_file()

    # 5. spoiled run folders and model: each redone with one line, the tables equal again
    (runs_t2 / "keep_seed1" / "summary.json").write_text('{"mean_speed_mps": null}\n')
    detectors = runs_t2 / "greedy_seed1" / "detectors.xml"
    detectors.write_bytes(detectors.read_bytes()[: detectors.stat().st_size // 2])
    traj = runs_t2 / "mobil_p0_seed1" / "trajectories.parquet"
    traj.write_bytes(traj.read_bytes()[: traj.stat().st_size // 2])
    (cut / "models" / MODEL / "model.pt").write_bytes(b"")
    marker = runs_t2 / "sumo_seed1" / RUN_MARKER  # its own run marked unfinished: redone (issue 82, F9: rc 1, looped)
    marker.write_text(marker.read_text().replace('"finished": true', '"finished": false'))
    err = run_here(cut, monkeypatch, capfd)
    for fragment in ("keep_seed1 has summary.json", "greedy_seed1 has a missing or cut-short detectors.xml",
                     "mobil_p0_seed1 has an unreadable trajectories.parquet", "model.pt cannot be used",
                     f"sumo_seed1 has a {RUN_MARKER} that does not mark a finished simulate run"):  # fmt: skip
        assert sum(fragment in line for line in err.splitlines()) == 1, (fragment, err[-3000:])
    for name in ("runs.csv", "summary.csv"):
        assert (cut / name).read_text() == (ref / name).read_text(), name
    assert leftovers(tmp_path) == []
    # a marker with no list of the run's files: the folder is not the study's to replace; one line, rc 2, kept
    marker.write_text('{"kind": "simulate", "finished": false}')
    before = sorted((p.relative_to(cut).as_posix(), p.stat().st_mtime_ns) for p in (cut / "runs").rglob("*"))
    err = run_here(cut, monkeypatch, capfd, code=2)  # a refusal as a process: tests/test_bad_inputs.py
    lines = [line for line in err.splitlines() if "error" in line or "Traceback" in line]
    assert len(lines) == 1, err[-2000:]
    assert "sumo_seed1 has a .coopsumo-run.json that says its run did not finish and lists no files" in lines[0]
    assert sorted((p.relative_to(cut).as_posix(), p.stat().st_mtime_ns) for p in (cut / "runs").rglob("*")) == before

    # the study's folder is its own: simulate refuses it, every byte kept
    assert '"scenario1"' in (cut / RUN_MARKER).read_text()
    assert simulate.main(["--steps", "20", "--quiet", "--out", str(cut)]) == 2
    line = capfd.readouterr().err.strip().splitlines()
    assert len(line) == 1 and "scenario1 run, not a simulate run" in line[0]
