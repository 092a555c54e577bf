"""Issue 82, probe 7, I9: a path (or any argument) holding a byte that is not valid UTF-8 is refused in one line, exit
code 2, before anything is written: given to any flag of any command (runio.Parser), or in $COOPSUMO_NETS_DIR
(paths.out_path_problem, behind paths.env_problem). Before, simulate ended in a UnicodeEncodeError traceback and left
its partial folder, train and a $COOPSUMO_NETS_DIR in a libsumo TypeError traceback, and a scenario II study failed
every cell on every rerun."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO

BAD = "x\udcff"  # the byte 0xff, as Python holds it (os.fsencode gives it back)
CASES = {
    "simulate --out": (["simulate", "--quiet", "--steps", "100", "--out", BAD], {}),
    "train --out": (["train", "--quiet", "--steps", "300", "--eval-steps", "100", "--out", BAD], {}),
    "scenario2 --out": (["scenario2", "--quick", "--workers", "1", "--quiet", "--out", BAD], {}),
    "--policy dqn:PATH": (["simulate", "--quiet", "--steps", "100", "--policy", f"dqn:{BAD}.pt", "--out", "o"], {}),
    "--nets-dir": (["--nets-dir", BAD, "simulate", "--quiet", "--steps", "100", "--out", "o"], {}),
    "$COOPSUMO_NETS_DIR": (["simulate", "--quiet", "--steps", "100", "--out", "o"], {"COOPSUMO_NETS_DIR": BAD}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_byte_that_is_not_utf8_is_one_line_and_nothing_written(tmp_path: Path, case: str) -> None:
    args, extra = CASES[case]
    env = {**os.environ, "LC_ALL": "C.UTF-8", "PYTHONPATH": str(REPO)}
    env.update({k: str(tmp_path / v) for k, v in extra.items()})
    proc = subprocess.run([sys.executable, "-m", "coopsumo", *args], cwd=tmp_path, env=env, capture_output=True,
                          text=True, errors="replace", timeout=120, check=False)  # fmt: skip
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr[-2000:]
    assert "not valid UTF-8" in lines[0] and "Traceback" not in proc.stderr
    assert list(tmp_path.iterdir()) == []
