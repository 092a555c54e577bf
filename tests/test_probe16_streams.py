"""Issue 82, probe 16: `history --out` over a file made or changed while the table was built (D1), a name too long
for its temporary file (O1), a stdout that cannot encode a path (T2) and a stderr closed or a pipe closed early
(T3)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from test_history import _one_study

from coopsumo.studies.protocol import history

ROOT = Path(__file__).resolve().parent.parent


def _history_racing(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], results: Path, out: Path,
                    meanwhile: str) -> tuple[int, list[str]]:  # fmt: skip
    """`history --out out`, the user writing `meanwhile` at out while the table is built."""
    build = history.table

    def slow_table(folder: Path) -> str:
        text = build(folder)
        out.write_text(meanwhile)
        return text

    monkeypatch.setattr(history, "table", slow_table)
    code = history.main(["--results", str(results), "--out", str(out)])
    return code, capsys.readouterr().err.strip().splitlines()


def test_a_file_made_at_out_while_the_table_is_built_is_kept(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                             capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """D1: a new --out checked free at the start, then a user's file made there: it was replaced, exit 0."""
    results, out = tmp_path / "results", tmp_path / "new.md"
    _one_study(results)
    code, err = _history_racing(monkeypatch, capsys, results, out, "MY OWN FILE\n")
    assert code == 2 and len(err) == 1 and f"--out {out} was made while the table was built" in err[0], err
    assert out.read_text() == "MY OWN FILE\n" and sorted(p.name for p in tmp_path.iterdir()) == ["new.md", "results"]


def test_a_note_added_to_the_table_while_it_is_built_is_kept(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                             capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """D1: a sealed table (history's to replace at the start), a note added to it meanwhile: the note was lost."""
    results, out = tmp_path / "results", tmp_path / "table.md"
    _one_study(results)
    assert history.main(["--results", str(results), "--out", str(out)]) == 0
    noted = out.read_text() + "MY NOTE: do not lose this\n"
    code, err = _history_racing(monkeypatch, capsys, results, out, noted)
    assert code == 2 and len(err) == 1 and f"--out {out} was changed while the table was built" in err[0], err
    assert out.read_text() == noted
    monkeypatch.undo()  # unchanged meanwhile: replaced, as before
    out.write_text(history.table(results).replace("|", "|", 1))
    assert history.main(["--results", str(results), "--out", str(out)]) == 0


def test_a_name_too_long_for_its_temporary_file_is_refused_first(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """O1: a 243-byte name (the file system takes 255) was refused after the table was built, naming the temporary
    file; now before, naming --out and the limit."""
    (tmp_path / "results").mkdir()
    monkeypatch.setattr(history, "table", lambda folder: pytest.fail("the table was built"))
    out = tmp_path / ("a" * 240 + ".md")
    assert history.main(["--results", str(tmp_path / "results"), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "has a name of 243 bytes" in err[0] and "less room for its temporary file" in err[0], err
    assert err[0].startswith(f"history: error: --out {out} ") and not out.exists()


def _run(command: str, cwd: Path, **env: str) -> subprocess.CompletedProcess[str]:
    """`command` (bash, coopsumo as $C) with env added; its output as text, undecodable bytes escaped."""
    full = {**os.environ, "C": f"{sys.executable} -m coopsumo", "PYTHONPATH": str(ROOT), **env}
    return subprocess.run(["bash", "-c", command], cwd=cwd, env=full, capture_output=True, text=True,
                          errors="backslashreplace", check=False)  # fmt: skip


def test_a_path_stdout_cannot_encode_is_escaped(tmp_path: Path) -> None:
    """T2: under PYTHONIOENCODING=ascii, `models` of a store at a path with 'é' ended in a UnicodeEncodeError
    traceback, exit 1; the path is printed with a backslash escape, exit 0."""
    store = tmp_path / "é_dir" / "store"
    (store / "default_a0_seed1_0123456789ab").mkdir(parents=True)
    res = _run(f'$C models --store "{store}"', tmp_path, PYTHONIOENCODING="ascii")
    assert (res.returncode, res.stderr) == (0, ""), res.stderr
    assert f"1 models in {tmp_path}/\\xe9_dir/store, 0 usable" in res.stdout, res.stdout


@pytest.mark.sumo
@pytest.mark.parametrize("redirect", ["2>&-", "2>&1 | head -c 1 >/dev/null"])
def test_a_run_with_its_stderr_closed_or_broken_finishes(tmp_path: Path, redirect: str) -> None:
    """T3: with stderr closed (`2>&-`) or a pipe its reader closed (`| head -c 1`), the first progress bar ended the
    run, exit 1, its folder thrown away; the run finishes, exit 0, its folder whole."""
    res = _run(f"$C simulate --steps 300 --out run {redirect}; echo rc=${{PIPESTATUS[0]}} >&2", tmp_path)
    assert res.stderr.strip().splitlines()[-1] == "rc=0", res.stderr
    assert (tmp_path / "run" / "summary.json").is_file() and (tmp_path / "run" / "detectors.xml").is_file()


def test_a_stop_between_a_prints_text_and_its_newline_leaves_the_one_line_on_its_own(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A Ctrl-C at 0.5 s into scenario II landed between the text of its header line and the newline (print writes
    them apart, through _Steady's write, where the signal's handler runs): `...on the local backendscenario2:
    interrupted` (CI, 2026-12-05). The one line now starts a line of its own; after a whole line or a bar's '\\r' it
    adds no blank line."""
    import io
    import signal

    from coopsumo import runio

    buf = io.StringIO()
    steady = runio._Steady(buf, 2)
    monkeypatch.setattr(sys, "stderr", steady)
    steady.write("scenario2: 8 to run on the local backend")  # the print's text; its newline never came
    assert runio.interrupted("scenario2", runio.Stop(signal.SIGINT)) == 130
    steady.write("cells: 1/8\r")
    runio.interrupted("scenario1", runio.Stop(signal.SIGTERM))
    assert buf.getvalue().splitlines() == ["scenario2: 8 to run on the local backend", "scenario2: interrupted",
                                           "cells: 1/8", "scenario1: interrupted"]  # fmt: skip
