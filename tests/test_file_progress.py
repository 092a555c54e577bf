"""make test's per-file progress (tests/file_progress.py): one line per test file as its last test ends, with the
share of all tests done, its outcomes and time, and no dots; under pytest-xdist as in make test, and in one process."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
FILES = {
    "test_one.py": "def test_a():\n    pass\n\ndef test_b():\n    pass\n",
    "test_two.py": ("import pytest\n\ndef test_c():\n    assert 1 == 2\n\n"
                    "@pytest.mark.skip(reason='not here')\ndef test_d():\n    pass\n\ndef test_e():\n    pass\n"),
}  # fmt: skip


@pytest.mark.parametrize("workers", [["-n", "2", "--dist", "loadfile"], ["-p", "no:xdist"]], ids=["xdist", "one"])
def test_one_line_per_file_with_the_share_done(tmp_path: Path, workers: list[str]) -> None:
    for name, text in FILES.items():
        (tmp_path / name).write_text(text)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")])}
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "file_progress", "--file-progress", *workers,
                             "-o", "console_output_style=classic", "-p", "no:cacheprovider", "test_one.py",
                             "test_two.py"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120,
                            check=False)  # fmt: skip
    out = result.stdout
    assert result.returncode == 1, out + result.stderr
    lines = [line for line in out.splitlines() if re.match(r"\[ *\d+%\] ", line)]
    assert len(lines) == 2, out
    by_file = {re.search(r"(test_\w+\.py)", line)[1]: line for line in lines}  # type: ignore[index]
    assert re.fullmatch(r"\[ *\d+%\] test_one\.py: 2 passed in \d+\.\d s", by_file["test_one.py"])
    assert re.fullmatch(r"\[ *\d+%\] test_two\.py: 1 failed, 1 passed, 1 skipped in \d+\.\d s", by_file["test_two.py"])
    assert lines[-1].startswith("[100%]")
    assert not re.search(r"^[.sF]+\s*$", out, re.MULTILINE), out  # no line of dots
    assert "def test_c" in out and "1 failed, 3 passed, 1 skipped" in out  # pytest's own traceback and summary
