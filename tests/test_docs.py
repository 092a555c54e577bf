"""Every command the README documents runs (step counts shortened, output paths moved to a temp folder)."""

from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.sumo
ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()


def blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", README, flags=re.S)


def python_commands() -> list[str]:
    """The README's `python -m coopsumo...` commands, continuation lines joined."""
    cmds = []
    for block in blocks("bash"):
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split("#")[0].strip()
            # the studies run in tests/test_scenario1.py, test_scenario2.py and test_ablation.py with tiny profiles;
            # the --gui command needs a display: tests/test_sumo_tools.py runs it under Xvfb
            study = "coopsumo.scenario" in line or "coopsumo.ablation" in line
            gui = re.search(r"--gui\b", line) is not None
            if line.startswith(".venv/bin/python -m coopsumo") and not study and not gui:
                cmds.append(line)
    return cmds


def shortened(cmd: str, tmp: Path) -> list[str]:
    """The command with --steps cut to 1,500 and results/ moved under tmp; an accident left at its default
    window (steps 20,000-70,000) gets one inside the shortened run, at the same 2/9 and 5/9 of it."""
    cmd = re.sub(r"--steps \d+", "--steps 1500", cmd).replace("results/", f"{tmp}/")
    if "--scenario accident" in cmd and "--accident-start" not in cmd:
        cmd += " --accident-start 333 --accident-steps 833"
    cmd = re.sub(r"--eval-steps \d+", "--eval-steps 300", cmd)
    args = shlex.split(cmd)
    args[0] = sys.executable
    return args


def test_readme_python_commands_run(tmp_path: Path) -> None:
    cmds = python_commands()
    assert len(cmds) >= 4 and any("--resume" in c for c in cmds)
    for i, cmd in enumerate(cmds):
        args = shortened(cmd, tmp_path)
        resumed_next = i + 1 < len(cmds) and "--resume" in cmds[i + 1]
        if not resumed_next:
            res = subprocess.run(args, cwd=ROOT, capture_output=True, text=True, check=False)
            assert res.returncode == 0, f"{cmd}\n{res.stderr[-1500:]}"
            continue
        # the documented Ctrl-C: interrupt once the first log row is written
        out = Path(args[args.index("--out") + 1])
        proc = subprocess.Popen(args, cwd=ROOT, stderr=subprocess.PIPE, text=True)
        log = out / "train_log.csv"
        deadline = time.time() + 180
        while time.time() < deadline and (not log.exists() or len(log.read_text().splitlines()) < 2):
            time.sleep(0.05)
        os.kill(proc.pid, signal.SIGINT)
        proc.communicate(timeout=120)
        assert proc.returncode == 130 and (out / "checkpoint.pt").exists()
    model = next(tmp_path.rglob("model.pt"))
    assert model.exists()


def test_make_demo_and_the_sumolib_snippet() -> None:
    res = subprocess.run(["make", "demo"], cwd=ROOT, capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr[-1500:]
    snippet = next(b for b in blocks("python") if "sumolib.xml.parse" in b)
    res = subprocess.run([sys.executable, "-c", snippet], cwd=ROOT, capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr
    rows = [line.split() for line in res.stdout.splitlines()]
    assert len(rows) >= 4  # 300 s of 60 s intervals
    assert all(float(r[1]) - float(r[0]) == pytest.approx(60.0) for r in rows)


def test_make_nets_builds_every_lane_count() -> None:
    res = subprocess.run(["make", "nets"], cwd=ROOT, capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr[-1500:]
    paths = [Path(line) for line in res.stdout.splitlines() if line.endswith(".net.xml")]
    assert [p.name.split("_")[1] for p in paths] == [f"{n}lanes" for n in range(2, 7)]
    assert all(p.exists() and "<net " in p.read_text() for p in paths)


def test_make_bench_quick() -> None:
    res = subprocess.run(["make", "bench", "BENCH_ARGS=--quick"], cwd=ROOT, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-1500:]
    assert "steps/s" in res.stdout and "us/veh/step" in res.stdout
    assert re.search(r"--fcd every 5 s \(scenario I\).*: [+-]\d+\.\d% wall time", res.stdout), res.stdout
