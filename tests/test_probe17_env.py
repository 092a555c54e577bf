"""Issue 82, probe 17: variables that a library coopsumo draws with reads when it is imported (matplotlib's
$MPLBACKEND, tqdm's $TQDM_*) ended commands in a ValueError traceback; they are judged first, one line naming them."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _coopsumo(tmp_path: Path, *args: str, **env: str) -> subprocess.CompletedProcess[str]:
    full = {name: value for name, value in os.environ.items() if name != "MPLBACKEND" and not name.startswith("TQDM_")}
    full.update(PYTHONPATH=str(ROOT), **env)
    return subprocess.run([sys.executable, "-m", "coopsumo", *args], cwd=tmp_path, env=full, capture_output=True,
                          text=True, check=False)  # fmt: skip


@pytest.mark.parametrize(("env", "words"), [
    ({"MPLBACKEND": "bogus"}, "$MPLBACKEND 'bogus' is not a backend matplotlib knows"),
    ({"TQDM_MININTERVAL": "abc"}, "$TQDM_MININTERVAL='abc': a value the progress bars' library (tqdm) cannot take"),
    ({"TQDM_NCOLS": "wide"}, "$TQDM_NCOLS='wide'"),
])  # fmt: skip
@pytest.mark.parametrize("command", [["models", "--store", "store"], ["history"], ["scenario1", "--help"]])
def test_a_library_variable_its_library_refuses_is_one_line(tmp_path: Path, env: dict[str, str], words: str,
                                                            command: list[str]) -> None:  # fmt: skip
    (tmp_path / "store").mkdir()
    res = _coopsumo(tmp_path, *command, **env)
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1 and words in lines[0], res.stderr
    assert "Traceback" not in res.stderr and res.stdout == ""


def test_library_variables_they_take_are_taken(tmp_path: Path) -> None:
    (tmp_path / "store").mkdir()
    res = _coopsumo(tmp_path, "models", "--store", "store", MPLBACKEND="agg", TQDM_MININTERVAL="2")
    assert (res.returncode, res.stderr) == (0, ""), res.stderr
    assert res.stdout.startswith("no models yet in store"), res.stdout
