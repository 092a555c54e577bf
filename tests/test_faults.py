"""Issue 25, parts 4 and 7: fault injection into `simulate` and `train` (scenario II and scenario I: in
test_scenario2.py and test_faults_scenario1.py).

Each command is killed with SIGKILL, SIGTERM and SIGINT at several points (early, mid-run, after a periodic
checkpoint, during the final evaluation), rerun or resumed, and its results compared with an uninterrupted run's:
equal, nothing partial left beside or inside the run folder, no log row twice. A second command writing to the
same --out at once is refused in one line and leaves nothing behind.
"""

from __future__ import annotations

import csv
import json
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pandas as pd
import pytest
import torch
from conftest import TIMING_KEYS

from coopsumo.agents.model_file import load_model
from coopsumo.report.analysis import read_detectors
from coopsumo.run_dirs import RUN_MARKER, finished_run

pytestmark = pytest.mark.sumo
REPO = Path(__file__).resolve().parent.parent
TIMING = TIMING_KEYS | {"wall_s"}  # and train_summary.json's wall time
"""summary fields and log columns that measure the machine, not the run"""
SIM = ["coopsumo.simulate", "--steps", "8000", "--t-up", "1.2", "--seed", "4", "--policy", "greedy", "--quiet"]
TRAIN_DRIVER = """
import dataclasses, sys
import coopsumo.agents.train_cli as t
base = t.config_from_args
t.config_from_args = lambda args: dataclasses.replace(base(args), log_every_steps=250, checkpoint_every_steps=500)
sys.exit(t.main(sys.argv[1:]))
"""
"""`python -m coopsumo.train` with a log row every 250 steps and a periodic checkpoint every 500 (the command's
own are 1,000 and 10,000 steps); --resume reads them back from the checkpoint"""
TRAIN = ["--steps", "3000", "--eval-steps", "6000", "--seed", "2", "--quiet", "--tensorboard"]
"""an evaluation long enough (several seconds on a quiet machine) that a signal 0.3 s into it lands in it"""


def start(args: list[str]) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, *args], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)  # fmt: skip


def wait_until(what: str, ready: Callable[[], bool], proc: subprocess.Popen[str], timeout: float = 180.0) -> None:
    """Poll ready() every 20 ms; the process must still be running when it turns true."""
    end = time.monotonic() + timeout
    while not ready():
        assert proc.poll() is None, f"the run ended before {what}: {proc.communicate()[1][-1500:]}"
        assert time.monotonic() < end, f"no {what} within {timeout:g} s"
        time.sleep(0.02)
    assert proc.poll() is None, f"the run ended at {what}"


def stop(proc: subprocess.Popen[str], sig: int) -> tuple[int, str]:
    """Send sig to the process; its exit code and stderr."""
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    return proc.returncode, err


def partials(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if ".partial-" in p.name)


def leftovers(parent: Path) -> list[str]:
    """Partial folders, lock files and temporary files anywhere under parent."""
    return sorted(str(p.relative_to(parent)) for p in parent.rglob("*")
                  if ".partial-" in p.name or p.name.endswith((".lock", ".tmp")))  # fmt: skip


def summary_of(run: Path) -> dict[str, object]:
    return {k: v for k, v in json.loads((run / "summary.json").read_text()).items() if k not in TIMING}


def detectors_of(run: Path) -> pd.DataFrame:
    return read_detectors(run / "detectors.xml")


def test_simulate_killed_at_every_point_leaves_nothing_and_reruns_equal(tmp_path: Path) -> None:
    ref, cut = tmp_path / "ref", tmp_path / "cut"
    # the uninterrupted run; a second simulate into the same --out meanwhile is refused and leaves nothing
    first = start(["-m", *SIM, "--out", str(ref)])
    wait_until("the partial folder", lambda: bool(partials(tmp_path)), first)
    second = subprocess.run([sys.executable, "-m", *SIM, "--out", str(ref)], cwd=REPO, capture_output=True,
                            text=True, timeout=120, check=False)  # fmt: skip
    lines = second.stderr.strip().splitlines()
    assert second.returncode == 2 and len(lines) == 1 and "another coopsumo command is writing" in lines[0], lines
    assert first.wait(timeout=180) == 0, first.communicate()[1][-1500:]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ref"] and finished_run(ref, "simulate")

    left: list[str] = []  # the partial folder the last kill left, which the next run must remove and report
    # mid-run: 0.3 s after the partial folder appeared (a quiet machine runs all 8,000 steps in about 2 s)
    for sig, when_s in ((signal.SIGKILL, 0.0), (signal.SIGINT, 0.3), (signal.SIGTERM, 0.3), (signal.SIGKILL, 0.3)):
        proc = start(["-m", *SIM, "--out", str(cut)])
        wait_until("a new partial folder", lambda old=left: bool(set(partials(tmp_path)) - set(old)), proc)
        time.sleep(when_s)
        code, err = stop(proc, sig)
        assert code == (130 if sig == signal.SIGINT else -sig), err[-1500:]
        assert "Traceback" not in err and not cut.exists()
        removed = [line for line in err.splitlines() if "the partial folder of an interrupted run" in line]
        assert len(removed) == len(left) and all(name in removed[0] for name in left), (left, err[-1500:])
        left = partials(tmp_path)
        if sig == signal.SIGINT:  # Ctrl-C: the run removes its own partial folder and lock
            assert err.strip().splitlines()[-1] == "simulate: interrupted" and left == []
        else:  # SIGKILL and SIGTERM leave theirs
            assert len(left) == 1
    res = subprocess.run([sys.executable, "-m", *SIM, "--out", str(cut)], cwd=REPO, capture_output=True, text=True,
                         timeout=180, check=False)  # fmt: skip
    assert res.returncode == 0, res.stderr[-1500:]
    removed = [line for line in res.stderr.splitlines() if "the partial folder of an interrupted run" in line]
    assert len(removed) == 1 and left[0] in removed[0] and leftovers(tmp_path) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut", "ref"]
    assert summary_of(cut) == summary_of(ref)
    pd.testing.assert_frame_equal(detectors_of(cut), detectors_of(ref))


# -- train ----------------------------------------------------------------------------------------------------
def train_run(out: Path, *extra: str) -> subprocess.Popen[str]:
    return start(["-c", TRAIN_DRIVER, *TRAIN, "--out", str(out), *extra])


def resume(out: Path) -> subprocess.Popen[str]:
    return start(["-m", "coopsumo.train", "--resume", "--quiet", "--tensorboard", "--out", str(out)])


def logged_steps(out: Path) -> list[int]:
    try:
        rows = list(csv.DictReader((out / "train_log.csv").read_text().splitlines()))
    except FileNotFoundError:
        return []
    return [int(r["step"]) for r in rows if r.get("step", "").isdigit()]


def log_rows(out: Path) -> list[dict[str, str]]:
    return [{k: v for k, v in r.items() if k not in TIMING}
            for r in csv.DictReader((out / "train_log.csv").read_text().splitlines())]  # fmt: skip


def scalars(out: Path) -> dict[str, list[tuple[int, float]]]:
    """Every TensorBoard scalar of the training, by tag: (step, value), read as TensorBoard reads them."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(out / "tensorboard"))
    acc.Reload()
    return {tag: [(p.step, p.value) for p in acc.Scalars(tag)] for tag in sorted(acc.Tags()["scalars"])}


def checkpoint_step(out: Path) -> int:
    return int(torch.load(out / "checkpoint.pt", weights_only=True)["step"])


def weights(out: Path) -> dict[str, torch.Tensor]:
    net, _ = load_model(out / "model.pt")
    return net.state_dict()


def test_train_interrupted_anywhere_resumes_to_the_uninterrupted_result(tmp_path: Path) -> None:
    ref, cut = tmp_path / "ref", tmp_path / "cut"
    # the uninterrupted training; a second train into the same --out meanwhile is refused and changes nothing
    first = train_run(ref)
    wait_until("the first log row", lambda: bool(logged_steps(ref)), first)
    second = subprocess.run([sys.executable, "-m", "coopsumo.train", *TRAIN, "--out", str(ref)], cwd=REPO,
                            capture_output=True, text=True, timeout=120, check=False)  # fmt: skip
    lines = second.stderr.strip().splitlines()
    assert second.returncode == 2 and len(lines) == 1 and "another coopsumo command is writing" in lines[0], lines
    assert first.wait(timeout=300) == 0, first.communicate()[1][-1500:]
    assert finished_run(ref, "train") and not (ref / "checkpoint.pt").exists()

    # 1. Ctrl-C early, as soon as the step-0 checkpoint exists (before the first log row)
    proc = train_run(cut)
    wait_until("the first checkpoint", lambda: (cut / "checkpoint.pt").exists(), proc)
    code, err = stop(proc, signal.SIGINT)
    assert code == 130 and "--resume" in err and "Traceback" not in err, err[-1500:]
    # 2. SIGKILL after the periodic checkpoint of step 500, once a row past it is logged: those rows come again
    proc = resume(cut)
    wait_until("a row logged past the checkpoint", lambda: 750 in logged_steps(cut), proc)
    code, err = stop(proc, signal.SIGKILL)
    assert code == -signal.SIGKILL
    assert max(logged_steps(cut)) > checkpoint_step(cut) == 500  # without truncation the resume would log twice
    # 3. Ctrl-C mid-run
    proc = resume(cut)
    wait_until("step 1,750 logged", lambda: 1750 in logged_steps(cut), proc)
    code, err = stop(proc, signal.SIGINT)
    assert code == 130 and "--resume" in err and "Traceback" not in err, err[-1500:]
    assert checkpoint_step(cut) >= 1750 and not (cut / "model.pt").exists()
    # 4. Ctrl-C during the final evaluation (before: --resume then said there was nothing to resume)
    proc = resume(cut)
    wait_until("the evaluation", lambda: (cut / "eval").is_dir(), proc)
    time.sleep(0.3)
    code, err = stop(proc, signal.SIGINT)
    assert code == 130 and "--resume" in err and "Traceback" not in err, err[-1500:]
    assert checkpoint_step(cut) == 3000 and (cut / "model.pt").exists() and not (cut / "summary.json").exists()
    # 5. SIGKILL during the evaluation resumed from the end of the training
    proc = resume(cut)
    wait_until("the evaluation", lambda: (cut / "eval").is_dir(), proc)
    time.sleep(0.3)
    code, _ = stop(proc, signal.SIGKILL)
    assert code == -signal.SIGKILL and (cut / "checkpoint.pt").exists()
    # 6. the last resume completes it
    res = subprocess.run([sys.executable, "-m", "coopsumo.train", "--resume", "--quiet", "--tensorboard", "--out",
                          str(cut)], cwd=REPO, capture_output=True, text=True, timeout=300, check=False)  # fmt: skip
    assert res.returncode == 0, res.stderr[-1500:]
    assert finished_run(cut, "train") and not (cut / "checkpoint.pt").exists() and leftovers(tmp_path) == []
    steps = logged_steps(cut)
    assert steps == sorted(set(steps)) == list(range(250, 3001, 250))  # every row once
    assert log_rows(cut) == log_rows(ref)
    assert scalars(cut) == scalars(ref)  # TensorBoard's points too: each step once (purge_step on resume)
    ref_w, cut_w = weights(ref), weights(cut)
    assert ref_w.keys() == cut_w.keys() and all(torch.equal(ref_w[k], cut_w[k]) for k in ref_w)
    assert summary_of(cut) == {**summary_of(ref), "policy": f"dqn:{cut / 'model.pt'}"}
    pd.testing.assert_frame_equal(read_detectors(cut / "eval" / "detectors.xml"),
                                  read_detectors(ref / "eval" / "detectors.xml"))  # fmt: skip
    train_summary = {k: v for k, v in json.loads((cut / "train_summary.json").read_text()).items() if k not in TIMING}
    assert train_summary == {k: v for k, v in json.loads((ref / "train_summary.json").read_text()).items()
                             if k not in TIMING}  # fmt: skip
    listed = [[f for f in json.loads((run / RUN_MARKER).read_text())["files"] if not f.startswith("tensorboard/")]
              for run in (cut, ref)]  # fmt: skip
    assert listed[0] == listed[1]  # the same files (one event file per resume besides)


def test_resume_without_a_checkpoint_says_why_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from coopsumo.agents import train_cli as train

    out = tmp_path / "done"
    assert train.main(["--steps", "30", "--eval-steps", "0", "--quiet", "--out", str(out)]) == 0
    capsys.readouterr()
    assert train.main(["--resume", "--quiet", "--out", str(out)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "nothing to resume" in lines[0] and "has finished" in lines[0], lines


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (writes fail as on a full disk)")
def test_a_model_write_on_a_full_disk_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    """torch reports a failed write (here to /dev/full, which answers every write as a full disk does) as a
    RuntimeError of its own; the command boundary makes it one line with exit code 1, not a traceback."""
    from coopsumo.runio import run_cli

    def body() -> int:
        torch.save({"weights": torch.zeros(10_000)}, "/dev/full")
        return 0

    assert run_cli("train", body) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("train: error: writing a model or checkpoint failed (is the disk full?)")


def test_resume_from_a_checkpoint_that_is_a_pipe_says_why_without_waiting(tmp_path: Path) -> None:
    """A fresh probe (issue 82): `train --resume` on a checkpoint.pt made a FIFO waited for a writer forever."""
    import os

    from coopsumo.agents.train import Trainer
    from coopsumo.errors import UsageError

    os.mkfifo(tmp_path / "checkpoint.pt")
    with pytest.raises(UsageError, match="it is not a regular file"):
        Trainer.load_checkpoint(tmp_path)
