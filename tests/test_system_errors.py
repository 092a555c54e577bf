"""System errors by class: a name too long, a loop of symbolic links, a file or nothing where the networks folder
belongs, a full disk. Each ends in one line naming the path and the problem, never a traceback; a failed write
leaves no temporary file."""

from __future__ import annotations

import errno
import subprocess
import sys
from pathlib import Path

import pytest

from coopsumo.errors import USAGE_EXIT
from coopsumo.files import write_atomic, write_json
from coopsumo.runio import run_cli

REPO = Path(__file__).resolve().parent.parent
LONG = "x" * 300


def _coopsumo(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "coopsumo", *args], cwd=REPO, capture_output=True, text=True,
                          env=env, timeout=120)  # fmt: skip


def _loop(tmp_path: Path) -> Path:
    (tmp_path / "loop_a").symlink_to(tmp_path / "loop_b")
    (tmp_path / "loop_b").symlink_to(tmp_path / "loop_a")
    return tmp_path / "loop_a"


@pytest.mark.parametrize("case", ["long model", "loop model", "loop model folder", "long out", "long train out",
                                  "long scenario1 out", "long nets", "loop nets"])  # fmt: skip
def test_bad_paths_are_one_line_exit_2_nothing_written(case: str, tmp_path: Path) -> None:
    loop, out = _loop(tmp_path), tmp_path / "run"
    args = {
        "long model": ["simulate", "--policy", f"dqn:{tmp_path / LONG / 'model.pt'}", "--out", str(out)],
        "loop model": ["simulate", "--policy", f"dqn:{loop / 'model.pt'}", "--out", str(out)],
        "loop model folder": ["simulate", "--policy", f"dqn:{loop}", "--out", str(out)],
        "long out": ["simulate", "--out", str(tmp_path / LONG)],
        "long train out": ["train", "--steps", "20", "--out", str(tmp_path / LONG / "x")],
        "long scenario1 out": ["scenario1", "--quick", "--out", str(tmp_path / LONG)],
        "long nets": ["--nets-dir", str(tmp_path / LONG), "simulate", "--out", str(out)],
        "loop nets": ["--nets-dir", str(loop), "simulate", "--out", str(out)],
    }[case]
    res = _coopsumo(*args, "--steps", "10", "--quiet") if "scenario1" not in case else _coopsumo(*args)
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert res.returncode == USAGE_EXIT, res.stderr
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert "too long" in lines[0] or "bytes" in lines[0] or "loop of symbolic links" in lines[0], lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["loop_a", "loop_b"]


def test_a_full_disk_is_one_line_and_exit_1(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    def body() -> int:
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "summary.json"))

    assert run_cli("simulate", body) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"simulate: error: No space left on device: {tmp_path / 'summary.json'}"]


def test_a_failed_atomic_write_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    path = tmp_path / "summary.json"
    write_json(path, {"a": 1})
    before = path.read_bytes()

    def full_disk(tmp: Path) -> None:
        tmp.write_text("half")
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp))

    with pytest.raises(OSError):
        write_atomic(path, full_disk)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]


def test_the_networks_folder_from_the_environment_is_checked_like_the_flag(tmp_path: Path) -> None:
    import os

    (tmp_path / "afile").write_text("x")
    env = dict(os.environ, COOPSUMO_NETS_DIR=str(tmp_path / "afile"))
    res = _coopsumo("simulate", "--steps", "10", "--quiet", "--out", str(tmp_path / "run"), env=env)
    assert res.returncode == USAGE_EXIT
    assert res.stderr.strip().splitlines() == [f"simulate: error: $COOPSUMO_NETS_DIR '{tmp_path / 'afile'}' is a "
                                               "file, not a folder"]  # fmt: skip
    assert not (tmp_path / "run").exists()
