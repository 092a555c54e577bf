"""Issue 82, probe 4 (F8-F12, F20-F22): records read back edited in ways that were a traceback or trusted (JSON
nested deeply, a profile not UTF-8, numbers too large for a float, a detectors.xml count `6.0`, a checkpoint's log
window, a store model's `sim.seed: true`), and arguments refused only after the runs (`accident-seeds ROOT ROOT`,
`bench --model` of random bytes)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from coopsumo.agents import train_cli as train
from coopsumo.files import loads_json, read_json_object
from coopsumo.run_dirs import RUN_MARKER
from coopsumo.studies.engine.records import cell_path, reusable_keys

DEEP = "[" * 200_000  # json's decoder raises RecursionError for it
NESTED = "[" * 100 + "]" * 100  # decoded, yet deeper than any record: later code walking it would recurse


def snapshot(folder: Path) -> dict[str, str]:
    """Every file under folder with its sha256."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}  # fmt: skip


def one_line(capsys: pytest.CaptureFixture[str], *fragments: str) -> str:
    """The one line on stderr, which names every fragment; no traceback."""
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err and all(f in lines[0] for f in fragments), err
    return lines[0]


@pytest.mark.parametrize("text", [DEEP, NESTED])
def test_json_nested_deeply_is_not_json(text: str, tmp_path: Path) -> None:
    """F8: the shared reader takes deep nesting for text that is not JSON (a ValueError), not a RecursionError."""
    with pytest.raises(ValueError, match="nested deeper"):
        loads_json(text)
    path = tmp_path / "record.json"
    path.write_text(text)
    assert read_json_object(path) is None
    assert loads_json('{"a": [[{"b": 1}]]}') == {"a": [[{"b": 1}]]}


def test_a_deeply_nested_marker_is_damaged(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """F8: a training folder's marker nested 200,000 deep was a RecursionError traceback on `train --resume`."""
    out = tmp_path / "train"
    out.mkdir()
    (out / "config.json").write_text("{}\n")
    (out / "checkpoint.pt").write_bytes(b"weights")
    (out / RUN_MARKER).write_text(DEEP)
    before = snapshot(tmp_path)
    assert train.main(["--resume", "--quiet", "--out", str(out)]) == 2
    one_line(capsys, str(out), RUN_MARKER, "is not readable JSON (damaged)", "left alone")
    assert snapshot(tmp_path) == before


def test_a_deeply_nested_cell_record_is_rerun(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """F8: a study's cell record nested deeply is unreadable: rerun with one line, like any record not JSON."""
    spec = {"key": "c1", "config": {"steps": 10}}
    path = cell_path(tmp_path, "c1")
    path.parent.mkdir(parents=True)
    path.write_text(DEEP)
    assert reusable_keys(tmp_path, [spec], "scenario2", ["mean_speed_mps"]) == set()
    one_line(capsys, "cell c1", str(path), "unreadable (ValueError); rerunning it")


def test_a_deeply_nested_study_record_is_named(tmp_path: Path) -> None:
    """F8: `history` reading a protocol study's study.json nested deeply: RecordError naming the file."""
    from coopsumo.record_schemas import RecordError
    from coopsumo.studies.protocol.history import records

    (tmp_path / "study.json").write_text(json.dumps({"a": 1})[:-1] + ', "b": ' + DEEP)
    with pytest.raises(RecordError, match="study.json cannot be read as JSON"):
        records(tmp_path)


@pytest.mark.parametrize(("text", "words"), [
    (b'[profiles.mine]\nhelp = "x\xff"\nlanes = [2]\n', "not TOML (not UTF-8: byte 0xff"),
    (b"[profiles.mine]\nlanes = " + b"[" * 50_000 + b"]" * 50_000 + b"\n", "not TOML (nested deeper"),
    (b"[profiles.mine]\nlanes = " + b"[" * 100 + b"]" * 100 + b"\n", "not TOML (nested deeper"),
], ids=["not_utf8", "recursion", "nested"])  # fmt: skip
@pytest.mark.parametrize("study", ["scenario2", "protocol", "learning"])
def test_a_profile_file_not_utf8_or_nested_deeply_is_not_toml(
        study: str, text: bytes, words: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """F9: `--profile a.toml` holding a byte that is not UTF-8, or arrays nested 50,000 deep, was a
    UnicodeDecodeError or RecursionError traceback: one line naming the file, exit 2, nothing written."""
    import importlib

    main = importlib.import_module(f"coopsumo.studies.{study}.study").main
    path = tmp_path / "a.toml"
    path.write_bytes(text)
    assert main(["--profile", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    assert one_line(capsys, f"{study}: error: {path}: {words}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.toml"]
