"""Issue 67: an interruption is never lost. `coopsumo train` started the way a shell script's background job is
(SIGINT ignored) gets Ctrl-C (SIGINT to its whole process group: the update worker and the validation process too)
or SIGTERM at moments from its imports to its evaluation, and ends within seconds with one line: nothing written
before its first checkpoint, else the checkpoint to resume from. Before, a SIGINT during the setup was lost and the
training ran to its end."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from coopsumo.run_dirs import finished_run

pytestmark = pytest.mark.sumo
REPO = Path(__file__).resolve().parent.parent
TRAIN = ["-m", "coopsumo.train", "--steps", "600", "--eval-steps", "3000", "--seed", "6", "--update-worker", "on",
         "--select-every", "300", "--validation-steps", "100", "--validation-t-up", "1.5",
         "--validation-accident-steps", "600", "--quiet"]  # fmt: skip
"""a short training with every part a signal may land in: the update worker (learning from step 200), model
selection (at steps 300 and 600, in free flow and through the shortest accident; the log's one row at the end), the
evaluation"""


def background_job() -> None:
    """In the child: a session of its own (a process group to signal) and SIGINT ignored, as `cmd &` in a script."""
    os.setsid()
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def rows(out: Path) -> int:
    log = out / "train_log.csv"
    return len(log.read_text().splitlines()) if log.exists() else 0


MOMENTS: dict[str, tuple[Callable[[Path], bool], int, str]] = {
    "importing": (lambda out: False, signal.SIGINT, "nothing"),
    "setting up (the first checkpoint written)": (lambda out: (out / "checkpoint.pt").exists(), signal.SIGINT,
                                                  "checkpoint"),
    "training": (lambda out: rows(out) >= 2, signal.SIGTERM, "checkpoint"),
    "model selection": (lambda out: (out / "snapshots" / "step600").exists(), signal.SIGINT, "checkpoint"),
    "evaluating": (lambda out: (out / "eval").exists(), signal.SIGINT, "checkpoint"),
}  # fmt: skip
"""moment -> (ready(out): signal now (never: after 0.4 s), signal, what the folder then holds)"""


@pytest.mark.parametrize("moment", list(MOMENTS))
def test_a_signal_at_any_moment_ends_train_within_seconds_in_one_line(moment: str, tmp_path: Path) -> None:
    ready, sig, left = MOMENTS[moment]
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, *TRAIN, "--out", str(out)], cwd=REPO, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, preexec_fn=background_job)  # fmt: skip
    start = time.monotonic()
    while not ready(out) and not (moment == "importing" and time.monotonic() - start > 0.4):
        assert proc.poll() is None, f"ended before {moment}: {proc.communicate()[1][-1500:]}"
        assert time.monotonic() - start < 120, f"no {moment} within 120 s"
        time.sleep(0.02)
    sent = time.monotonic()
    os.killpg(proc.pid, sig)
    _, err = proc.communicate(timeout=60)
    took = time.monotonic() - sent
    lines = err.strip().splitlines()
    assert proc.returncode == 128 + sig and len(lines) == 1 and "Traceback" not in err, (proc.returncode, err[-2000:])
    assert lines[0].startswith("train: interrupted") and took < 15, (lines, took)
    if left == "nothing":
        assert not out.exists() and list(tmp_path.iterdir()) == [], list(tmp_path.rglob("*"))
    else:
        assert (out / "checkpoint.pt").exists() and not finished_run(out, "train"), sorted(os.listdir(out))
        assert f"--resume --out {out}" in lines[0]
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no lock file left


def test_a_signal_handled_as_the_training_loop_ends_is_not_lost(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """The loop's signal handler only notes a signal; one whose handler ran after the loop's last look and before the
    handlers were put back (Python runs a handler when the main thread next checks, e.g. as SUMO's close returns) was
    lost: the training ran on through its evaluation and exited 0 (tests above, 1 run in 10). It now checkpoints
    and stops as one in the last step does. Here the handler runs at that very moment."""
    import dataclasses

    import torch

    from coopsumo.agents.model_file import load_model
    from coopsumo.agents.train import Interrupted, train
    from coopsumo.config import SimConfig, TrainConfig

    real, fired = signal.signal, []

    def put_back(signum: int, handler: Any) -> Any:
        noted = signal.getsignal(signum)
        if getattr(noted, "__name__", "") == "_on_signal" and noted.__self__.step == 60 and not fired:
            fired.append(signum)  # the loop's handlers are put back after its last step: the signal that came
            noted(signal.SIGTERM, None)  # meanwhile has its handler run only now
        return real(signum, handler)

    cfg = TrainConfig(sim=SimConfig(steps=60, seed=2, policy="dqn"), eval_steps=0, log_every_steps=30)
    cfg = dataclasses.replace(cfg, dqn=dataclasses.replace(cfg.dqn, select_every_steps=0, learn_start_steps=10))
    monkeypatch.setattr(signal, "signal", put_back)
    with pytest.raises(Interrupted) as stop:
        train(cfg, tmp_path / "run", progress=False, learner_process=True)
    monkeypatch.undo()
    assert (stop.value.signum, stop.value.step) == (signal.SIGTERM, 60)
    assert (tmp_path / "run" / "checkpoint.pt").exists() and not finished_run(tmp_path / "run", "train")
    train(cfg, tmp_path / "run", resume=True, progress=False, learner_process=True)  # it resumes to its end,
    train(cfg, tmp_path / "whole", progress=False, learner_process=True)  # the model of the uninterrupted training
    assert finished_run(tmp_path / "run", "train")
    resumed, whole = (load_model(tmp_path / f / "model.pt")[0].state_dict() for f in ("run", "whole"))
    assert all(torch.equal(resumed[k], whole[k]) for k in whole)


def test_a_signal_as_the_loop_puts_its_handlers_in_leaves_none_behind(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """A signal that came just before the loop starts has its handler run as soon as the loop's handler is in, before
    the first step, and stops the training at once (runio.Stop). The handlers used to go in outside the loop's
    try: one raising there left the loop's handlers installed, and a study's worker, idle again after the cell,
    ended in a traceback of its own at the abort's SIGTERM (scenario I's Ctrl-C test, 1 run in about 10). Here the
    handler runs at that very moment; afterwards both handlers are the ones from before."""
    from coopsumo.agents.train import train
    from coopsumo.config import SimConfig, TrainConfig
    from coopsumo.runio import Stop

    real = signal.signal

    def put_in(signum: int, handler: Any) -> Any:
        before = real(signum, handler)
        if getattr(handler, "__name__", "") == "_on_signal" and signum == signal.SIGINT:
            handler(signal.SIGTERM, None)  # the pending signal's handler runs at the next instruction
        return before

    cfg = TrainConfig(sim=SimConfig(steps=60, seed=2, policy="dqn"), eval_steps=0, log_every_steps=30)
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    monkeypatch.setattr(signal, "signal", put_in)
    with pytest.raises(Stop):
        train(cfg, tmp_path / "run", progress=False)
    monkeypatch.undo()
    assert {s: signal.getsignal(s) for s in handlers} == handlers


BENCH_STOPPED = """
import os, signal, sys
from coopsumo.agents.train import Trainer
advance = Trainer._advance
def _advance(self, *args, **kwargs):
    if self.step == 50:  # a signal in the middle of bench's first training, its handler the training's own
        os.kill(os.getpid(), {sig})
    return advance(self, *args, **kwargs)
Trainer._advance = _advance
from coopsumo.cli import main
sys.exit(main(["bench", "--quick", "--learner"]))
"""


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_during_a_bench_training_is_one_line(sig: int, tmp_path: Path) -> None:
    """Issue 82, probe 4, F14: a Ctrl-C or SIGTERM while bench trains ended in agents.train.Interrupted's traceback,
    exit code 1; it is `bench: interrupted` and 128 + the signal, as every other command says it."""
    res = subprocess.run([sys.executable, "-c", BENCH_STOPPED.format(sig=int(sig))], cwd=tmp_path, text=True,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, timeout=300)  # fmt: skip
    assert res.stderr.strip().splitlines() == ["bench: interrupted"], res.stderr[-1500:]
    assert res.returncode == 128 + sig


TRAIN_SIGNALLED_TWICE = """
import builtins, os, signal, sys, time
from coopsumo.agents import train_cli
from coopsumo.agents.train import Trainer
run, advance = Trainer.run, Trainer._advance
def first_stop(self, *args, **kwargs):
    if {where!r} == "setup" or self.step == 50:
        os.kill(os.getpid(), signal.SIGINT)
    return (run if {where!r} == "setup" else advance)(self, *args, **kwargs)
setattr(Trainer, "run" if {where!r} == "setup" else "_advance", first_stop)
def said(*args, **kwargs):
    builtins.print(*args, **kwargs)
    if "interrupted" in str(args[0]):  # the second SIGINT, after the command's line: timeout's to the process group
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.2)
train_cli.print = said
from coopsumo.cli import main
sys.exit(main(["train", "--steps", "600", "--eval-steps", "0", "--update-worker", "off", "--out", "run", "--quiet"]))
"""


@pytest.mark.parametrize("where", ["setup", "loop"])
def test_a_second_signal_as_train_ends_adds_no_second_line(where: str, tmp_path: Path) -> None:
    """Issue 82, probe 4, F15: `timeout -s INT` sends its signal to the command and again to its process group; the
    second one, landing after `train` had said it was interrupted (as it released its folder's lock), printed a second
    line, `train: interrupted`. A stop that comes while a stopped command ends is only counted."""
    res = subprocess.run([sys.executable, "-c", TRAIN_SIGNALLED_TWICE.format(where=where)], cwd=tmp_path, text=True,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, timeout=300)  # fmt: skip
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("train: interrupted"), res.stderr[-1500:]
    assert res.returncode == 130


FOREVER = '''
import threading, time


class Forever:
    needs_grids = False

    def __init__(self):
        threading.Thread(target=self.loop).start()  # not a daemon: Python waits for it as it exits

    def loop(self):
        while True:
            time.sleep(0.05)

    def act(self, obs):
        return [3] * len(obs)
'''


@pytest.mark.sumo
def test_a_signal_ends_a_command_that_cannot_exit_in_one_line(tmp_path: Path) -> None:
    """Issue 82, probe 12, N6: a policy of one's own that leaves a thread running kept the command from exiting once
    its work was done, and SIGINT and SIGTERM were ignored there (only SIGKILL ended it)."""
    (tmp_path / "x.py").write_text(FOREVER)
    argv = [sys.executable, "-m", "coopsumo", "simulate", "--quiet", "--steps", "30", "--policy", "py:x.py:Forever",
            "--out", "o"]  # fmt: skip
    proc = subprocess.Popen(argv, cwd=tmp_path, text=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while not finished_run(tmp_path / "o", "simulate"):  # its work done, it cannot exit
            assert proc.poll() is None and time.monotonic() < deadline, proc.poll()
            time.sleep(0.2)
        time.sleep(1.0)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("simulate: stopped by SIGTERM while it exited"), err


SIGNALLED_IN_TEARDOWN = """
import os, signal, sys, time
sys.path.insert(0, {root!r})
from coopsumo.runio import run_interruptible


class Late:
    def __del__(self):  # run as Python tears its modules down, after it gave signals their default action
        os.kill(os.getpid(), signal.{name})
        time.sleep(0.2)


late = Late()
if {worker}:  # a library's worker thread (OpenMP, BLAS) that does not block the signals: it may be the one to take it
    import threading
    threading.Thread(target=time.sleep, args=(600,), daemon=True).start()
sys.exit(run_interruptible(lambda: print("4 models, 4 usable") or {code}, lambda: "models", whole_process=True))
"""


@pytest.mark.parametrize(("name", "code", "worker"), [("SIGINT", 0, False), ("SIGTERM", 0, False),
                                                     ("SIGINT", 2, False), ("SIGINT", 0, True), ("SIGTERM", 0, True)])
def test_a_signal_as_python_tears_down_leaves_the_commands_exit_code(name: str, code: int, worker: bool,
                                                                     tmp_path: Path) -> None:  # fmt: skip
    """Issue 82, probe 13, F22: a Ctrl-C in a console command's last moments (Python tearing its modules down, after
    it gave SIGINT its default action back) ended `models` and `train`, finished and printed, with exit code 130 and
    no line; it now leaves the command's own exit code (runio._deaf_at_exit). Probe 14, F6: also when another thread
    that does not block the signal is there to take it (a library's worker thread)."""
    script = SIGNALLED_IN_TEARDOWN.format(root=str(Path(__file__).resolve().parent.parent), name=name, code=code,
                                          worker=worker)  # fmt: skip
    res = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert (res.returncode, res.stdout, res.stderr) == (code, "4 models, 4 usable\n", "")
