"""Issue 82, probe 13, F11: a study's folder was known only by its profile's name, so another file's profile of the
same name replaced a finished study's tables and report (exit 0). A study root's marker now records a digest of its
profile's settings (run_folders.profile_digest), and a study of the same name with other settings is refused in one
line, exit 2, everything kept."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from test_profile_files import run_main, tiny_scenario2, with_field
from test_scenario2 import faked_train  # noqa: F401  (the fixture: scenario II's cells without SUMO)

from coopsumo.errors import UsageError
from coopsumo.run_dirs import mark_run_dir, study_root
from coopsumo.run_markers import DIGEST, RUN_MARKER, marker_text
from coopsumo.studies.scenario2 import study as s2

OWN = ("sweep.json", "cells", "*.tmp")


def _files(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_another_files_profile_of_the_same_name_is_another_study(tmp_path: Path,
                                                                  faked_train: list[str],  # noqa: F811
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """The probe's pr_samename, for scenario II: mine.toml's study, then another file's `mine` with other seeds over
    it, refused before anything is written; the first file again resumes; its flags keep its study."""
    first, second = tmp_path / "a" / "mine.toml", tmp_path / "b" / "mine.toml"
    first.parent.mkdir()
    second.parent.mkdir()
    first.write_text(tiny_scenario2())
    second.write_text(with_field(tiny_scenario2(), "seeds = [7]"))
    out = tmp_path / "out"
    argv = ["--out", str(out), "--quiet", "--bootstrap", "20"]
    code, err = run_main(s2.main, ["--profile", str(first), *argv], capsys)
    assert code == 0, err
    marker = json.loads((out / RUN_MARKER).read_text())
    assert isinstance(marker[DIGEST], str) and len(marker[DIGEST]) == 16
    before = _files(out)
    code, err = run_main(s2.main, ["--profile", str(second), *argv], capsys)
    assert code == 2 and len(err) == 1, err
    assert "holds the mine profile's sweep run with other settings" in err[0] and marker[DIGEST] in err[0], err
    assert _files(out) == before
    code, err = run_main(s2.main, ["--profile", str(first), *argv], capsys)
    assert code == 0 and "already done" in "\n".join(err), err
    code, err = run_main(s2.main, ["--profile", str(first), "--eval-steps", "300", *argv], capsys)
    assert code == 0, err  # a flag keeps the profile's study, as documented


def test_a_marker_without_settings_is_the_studys_and_gets_them(tmp_path: Path) -> None:
    """A root marked before markers recorded the settings is taken as the study's, and then records them; a marker
    of other settings is refused; a command without settings (a merge) is not compared."""
    root = tmp_path / "study"
    root.mkdir()
    mark_run_dir(root, "scenario2", finished=False, study="the mine profile's sweep")
    with study_root(root, "scenario2", OWN, "the mine profile's sweep", digest="0123456789abcdef"):
        pass
    assert json.loads((root / RUN_MARKER).read_text())[DIGEST] == "0123456789abcdef"
    with pytest.raises(UsageError, match="run with other settings") as refused:
        with study_root(root, "scenario2", OWN, "the mine profile's sweep", digest="fedcba9876543210"):
            pass
    assert "\n" not in str(refused.value)
    with study_root(root, "scenario2", OWN, "the mine profile's sweep"):
        pass


def test_a_killed_marking_with_settings_is_still_a_markers_text(tmp_path: Path) -> None:
    """run_markers.marker_text knows the new key: every start of a marker that records its settings is a killed
    marking (an unmarked root holding it is taken), as for the other keys."""
    (tmp_path / "run").mkdir()
    temporary = tmp_path / "t.tmp"
    for study in (None, "the quick profile's study"):
        mark_run_dir(tmp_path / "run", "scenario2", finished=False, study=study, digest="0123456789abcdef")
        text = (tmp_path / "run" / RUN_MARKER).read_text()
        for end in range(len(text) + 1):
            temporary.write_text(text[:end])
            assert marker_text(temporary), text[:end]
        temporary.write_text(text + "x")
        assert not marker_text(temporary)
