"""Probe 6, H5: a record far larger than any coopsumo writes (a sparse file of 2 GiB here) is refused as unreadable,
never read into memory: as a profile file in one line, as an ancestor's marker it claims nothing."""

from __future__ import annotations

import errno
from pathlib import Path

import pytest

from coopsumo.files import MAX_RECORD_BYTES, file_sha256, read_json
from coopsumo.run_markers import RUN_MARKER


def _huge(path: Path) -> Path:
    with path.open("wb") as f:
        f.truncate(MAX_RECORD_BYTES + 1)  # sparse: no disk is used
    return path


def test_a_record_larger_than_any_is_refused_unread(tmp_path: Path) -> None:
    with pytest.raises(OSError) as err:
        read_json(_huge(tmp_path / "sweep.json"))
    assert err.value.errno == errno.EFBIG and "larger than any record" in str(err.value.strerror)
    assert len(file_sha256(tmp_path / "sweep.json")) == 64  # a digest reads in chunks: no limit


def test_a_huge_profile_file_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from coopsumo.studies.scenario2 import study as scenario2

    profile = _huge(tmp_path / "mine.toml")
    code = scenario2.main(["--profile", str(profile), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "larger than any record" in err[0], err
    assert not (tmp_path / "out").exists()


def test_a_huge_marker_above_out_is_not_read_and_claims_its_folder(tmp_path: Path) -> None:
    """Not read whole (larger than any record), it is a marker that cannot be read: its folder is claimed as a
    damaged marker's, so nothing is written below it (issue 82, probe 8, J2)."""
    from coopsumo.owners import owned_problem

    (tmp_path / "a").mkdir()
    _huge(tmp_path / "a" / RUN_MARKER)
    problem = owned_problem(tmp_path / "a" / "b" / "sim", "--out a/b/sim")
    assert problem is not None and "whose .coopsumo-run.json cannot be read" in problem
