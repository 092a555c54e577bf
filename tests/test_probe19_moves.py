"""Issue 82, probe 19, O3: `--out`'s parent moved or deleted while a command ran: simulate and train said only "No
such file or directory" naming a temporary file, exit 2; scenario II once wrote its whole study again at the old path
(workers made its cells/ there again), unmarked, exit 0, leaving the moved copy half made."""

from __future__ import annotations

import errno
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from coopsumo.errors import gone_folder


def test_gone_folder_names_the_folder_that_went() -> None:
    gone = Path("/nonexistent-coopsumo-test/sub/.run.partial-abc/.summary.json.x.tmp")
    assert gone_folder(FileNotFoundError(errno.ENOENT, "No such file or directory", str(gone))) == \
        "/nonexistent-coopsumo-test"  # fmt: skip
    here = Path(__file__)
    assert gone_folder(FileNotFoundError(errno.ENOENT, "No such file", str(here.parent / "no_such_file"))) is None
    assert gone_folder(PermissionError(errno.EACCES, "Permission denied", str(gone))) is None
    assert gone_folder(FileNotFoundError(errno.ENOENT, "No such file or directory")) is None


@pytest.mark.sumo
def test_simulate_whose_out_parent_is_moved_names_it_in_one_line(tmp_path: Path) -> None:
    parent = tmp_path / "parent"
    parent.mkdir()
    proc = subprocess.Popen([sys.executable, "-m", "coopsumo", "simulate", "--steps", "60000", "--lanes", "2",
                             "--quiet", "--out", str(parent / "run")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)  # fmt: skip
    end = time.monotonic() + 120
    while not list(parent.glob(".run.partial-*")):
        assert proc.poll() is None and time.monotonic() < end, proc.communicate()
        time.sleep(0.05)
    parent.rename(tmp_path / "moved")
    _, err = proc.communicate(timeout=600)
    lines = err.strip().splitlines()
    assert proc.returncode == 1 and len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith(f"simulate: error: the folder {parent} is gone, moved or deleted while the command ran ")


def test_a_study_whose_folder_is_moved_while_its_cells_run_writes_no_tables(tmp_path: Path,
                                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """The engine's check, with the cells' run replaced by the move (and a worker's record made again at the old
    path): OSError ESTALE naming the folder, and the study's outputs never written."""
    from coopsumo.studies.engine import cells
    from coopsumo.studies.scenario1.accident_runs import CELLS, REQUIRED

    root = tmp_path / "study"

    def moved_meanwhile(*_: Any, **__: Any) -> list[dict[str, Any]]:
        root.rename(tmp_path / "moved")
        (root / "cells").mkdir(parents=True)  # a worker writes its record at the old path
        return []

    monkeypatch.setattr(cells, "run_todo", moved_meanwhile)
    finished: list[int] = []
    study = cells.Study("test", CELLS, REQUIRED, lambda root, s: (), lambda todo: None, checks=())
    with pytest.raises(OSError) as err:
        study.run([], root, {}, "p", lambda records, meta: finished.append(1))
    assert err.value.errno == errno.ESTALE and err.value.filename == str(root) and finished == []
    assert "moved or deleted while its cells ran" in str(err.value)
