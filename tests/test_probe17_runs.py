"""Issue 82, probe 17: SUMO's outputs cut short by a file-size limit were kept as a finished run (DL1); a stderr that
fails other than as a closed pipe ended every command (T1); a usage error before the streams were made steady was a
traceback (T4); a run marker whose digests were emptied or taken out let a file copied in be reused (TR1)."""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from coopsumo.agents.rollout import check_sumo_outputs
from coopsumo.config import OutputConfig
from coopsumo.run_dirs import RUN_MARKER
from coopsumo.run_markers import SUMS, changed_file

ROOT = Path(__file__).resolve().parent.parent


def _bash(command: str, cwd: Path, **env: str) -> subprocess.CompletedProcess[str]:
    full = {**os.environ, "C": f"{sys.executable} -m coopsumo", "PYTHONPATH": str(ROOT), **env}
    return subprocess.run(["bash", "-c", command], cwd=cwd, env=full, capture_output=True, text=True,
                          errors="backslashreplace", check=False)  # fmt: skip


def test_a_sumo_output_cut_short_is_an_error_naming_it(tmp_path: Path) -> None:
    (tmp_path / "detectors.xml").write_text('<?xml version="1.0"?>\n<detector>\n  <interval begin="0"/>\n</detector>\n')
    (tmp_path / "fcd.xml").write_text('<fcd-export>\n  <timestep time="0.00">\n    <vehicle id="53" x="351.60" a')
    with pytest.raises(OSError, match=r"SUMO's fcd.xml ends cut short at 71 bytes, before </fcd-export>") as err:
        check_sumo_outputs(tmp_path, OutputConfig(fcd_period_s=1.0))
    assert err.value.errno == errno.EFBIG and err.value.filename == str(tmp_path / "fcd.xml")
    check_sumo_outputs(tmp_path, OutputConfig())  # a fcd.xml the run did not ask for: not its own, not judged
    (tmp_path / "fcd.xml").write_text("<fcd-export>\n</fcd-export>\n\n")
    check_sumo_outputs(tmp_path, OutputConfig(fcd_period_s=1.0))  # whole: nothing said


@pytest.mark.sumo
def test_a_run_under_a_file_size_limit_is_one_line_and_no_folder(tmp_path: Path) -> None:
    """DL1: `ulimit -f 12` cut SUMO's detectors.xml at 12 KB, exit 0, the run marked finished."""
    res = _bash("ulimit -f 12; $C simulate --steps 3000 --quiet --out run", tmp_path)
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 1 and len(lines) == 1 and "detectors.xml ends cut short" in lines[0], res.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.sumo
def test_a_stderr_on_a_full_disk_lets_the_run_finish(tmp_path: Path) -> None:
    """T1: `2>/dev/full` (ENOSPC on every write) ended the run at its first progress bar, exit 1."""
    res = _bash("$C simulate --steps 200 --out run 2>/dev/full", tmp_path)
    assert res.returncode == 0 and (tmp_path / "run" / "summary.json").is_file(), res.stderr


@pytest.mark.parametrize("redirect", ["2>&-", "2>/dev/full", "2</dev/null"])
def test_a_usage_error_with_a_failing_stderr_is_exit_2(tmp_path: Path, redirect: str) -> None:
    """T4: with stderr closed and a path stdout's encoding cannot take, the usage error was a traceback, exit 1."""
    res = _bash(f"$C simulate --lanes 9 --out é {redirect}", tmp_path, PYTHONIOENCODING="ascii")
    assert res.returncode == 2 and "Traceback" not in res.stdout + res.stderr, res.stdout + res.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("sums", [{}, None, "x", {"detectors.xml": "0" * 64}])
def test_a_marker_without_a_files_digest_is_a_changed_run(tmp_path: Path, sums: object) -> None:
    """TR1: files_sha256 of {} or null, or without the entry of a file it lists, let a file copied in be reused."""
    (tmp_path / "summary.json").write_text("{}")
    (tmp_path / "detectors.xml").write_text("<detector/>")
    marker = {"kind": "simulate", "finished": True, "files": ["detectors.xml", "summary.json"], SUMS: sums}
    (tmp_path / RUN_MARKER).write_text(json.dumps(marker))
    problem = changed_file(tmp_path)
    assert problem is not None and ("not a table of digests" in problem or "records no digest" in problem
                                    or "not the file its run wrote" in problem), problem  # fmt: skip
    del marker[SUMS]  # a marker written before digests: not judged
    (tmp_path / RUN_MARKER).write_text(json.dumps(marker))
    assert changed_file(tmp_path) is None


def test_a_stdout_that_cannot_be_written_is_named(tmp_path: Path) -> None:
    """O1: `>/dev/full` ended a finished command with "error: No space left on device", naming nothing; its output
    lost is one line naming stdout, exit 1; a pipe its reader closed early (`| head -1`) is no loss, exit 0."""
    full = _bash(f"$C history --results {ROOT / 'results'} >/dev/full", tmp_path)
    lines = full.stderr.strip().splitlines()
    assert full.returncode == 1 and len(lines) == 1, full.stderr
    assert lines[0] == ("history: error: its output could not be written to stdout (No space left on device): what "
                        "it printed is incomplete"), lines  # fmt: skip
    head = _bash(f"$C history --results {ROOT / 'results'} | head -1; exit ${{PIPESTATUS[0]}}", tmp_path)
    assert (head.returncode, head.stderr) == (0, "") and head.stdout.startswith("# "), head.stderr
