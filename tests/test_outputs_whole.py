"""Probe 6, H3: a study's tables, reports and figures are written whole (files.write_atomic), so whatever entry holds
the name, a named pipe say, is replaced, never written into (which hung the study after its cells)."""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator
from pathlib import Path

import pandas as pd
import pytest

from coopsumo.files import write_atomic, write_text_atomic


@pytest.fixture(autouse=True)
def no_hang() -> Iterator[None]:
    """A write into a pipe would wait forever: fail in 30 s instead."""
    def fail(*_: object) -> None:
        raise TimeoutError("a write waited on a named pipe")

    old = signal.signal(signal.SIGALRM, fail)
    signal.alarm(30)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, old)


def test_a_report_table_and_figure_replace_a_pipe_at_their_names(tmp_path: Path) -> None:
    from coopsumo.report.plots import new_figure, save_figure

    for name in ("report.md", "runs.csv", "fig.png"):
        os.mkfifo(tmp_path / name)
    write_text_atomic(tmp_path / "report.md", "# a report\n")
    frame = pd.DataFrame({"a": [1, 2]})
    write_atomic(tmp_path / "runs.csv", lambda tmp: frame.to_csv(tmp, index=False))
    save_figure(new_figure(2, 2), tmp_path / "fig.png")
    assert (tmp_path / "report.md").read_text() == "# a report\n"
    assert (tmp_path / "runs.csv").read_text() == "a\n1\n2\n"
    assert (tmp_path / "fig.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fig.png", "report.md", "runs.csv"]  # no temporary left


def test_a_file_named_like_a_temporary_is_left_alone_but_a_studys_own_goes(tmp_path: Path) -> None:
    """A SIGKILL during write_atomic leaves .NAME.XXXXXXXX.tmp beside the file (no handler runs). write_atomic leaves
    such a name alone (issue 82, probe 8, J23: `history --out t.md` deleted a user's .t.md.20261203.tmp); a study
    claiming its root removes those of its own files (a study killed while writing evals.csv left it after its
    rerun), not those of others."""
    from coopsumo.run_dirs import study_root

    left, mine = tmp_path / ".evals.csv.abcdefgh.tmp", tmp_path / ".notes.txt.abcdefgh.tmp"
    left.write_text("half")
    mine.write_text("mine")
    write_atomic(tmp_path / "evals.csv", lambda tmp: tmp.write_text("whole"))
    assert left.exists() and (tmp_path / "evals.csv").read_text() == "whole"
    with study_root(tmp_path / "s2", "scenario2", ("sweep.json", "evals.csv", "*.tmp")) as root:
        pass
    (root / ".evals.csv.abcdefgh.tmp").write_text("half")
    (root / ".notes.txt.abcdefgh.tmp").write_text("mine")
    with study_root(root, "scenario2", ("sweep.json", "evals.csv", "*.tmp")):
        assert sorted(p.name for p in root.iterdir() if p.name.endswith(".tmp")) == [".notes.txt.abcdefgh.tmp"]


def test_a_workers_exit_waits_for_a_write_and_leaves_no_temporary(tmp_path: Path) -> None:
    """A study's worker whose main process is gone ends with os._exit from its watching thread (runio): it ended while
    the worker wrote a stored model's model.pt, which left '.model.pt.XXXXXXXX.tmp' in the store (test_scenario2's
    interrupted sweep, once on a clean clone). files.exit_between_writes waits for the write: the file is whole and
    no temporary is left; a write that would start after it is never begun."""
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent(f"""
        import threading, time
        from pathlib import Path
        from coopsumo.files import exit_between_writes, write_atomic
        out = Path({str(tmp_path)!r})
        def slow(tmp):
            tmp.write_text("half")
            time.sleep(1.0)  # the exit is asked for meanwhile
            tmp.write_text("whole")
        threading.Timer(0.3, exit_between_writes, args=(3,)).start()
        write_atomic(out / "model.pt", slow)
        time.sleep(0.2)  # the exit lands here, before the next write
        write_atomic(out / "next.txt", lambda tmp: tmp.write_text("never"))
        time.sleep(5)
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, check=False)
    assert (done.returncode, done.stderr) == (3, "")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.pt"]
    assert (tmp_path / "model.pt").read_text() == "whole"


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_stop_while_a_file_is_written_ends_the_process_after_it_and_leaves_no_temporary(tmp_path: Path,
                                                                                      signum: int) -> None:
    """A study's training process (a group's member, a worker) has SIGTERM at its default action once its training
    loop is done; a stop of the study's process group that came while it wrote model.pt killed it there and left
    '.model.pt.XXXXXXXX.tmp' in the model store (test_scenario2's interrupted sweep, once on CI, 2026-12-05). The
    signal now waits for the write: the process ends by it right after, the file whole, no temporary left, the next
    write never begun. SIGINT, default-handled too, as a process started without a shell's Ctrl-C handler has it."""
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent(f"""
        import os, signal, time
        from pathlib import Path
        from coopsumo.files import write_atomic
        signal.signal({int(signum)}, signal.SIG_DFL)
        out = Path({str(tmp_path)!r})
        def stopped(tmp):
            tmp.write_text("half")
            os.kill(os.getpid(), {int(signum)})  # the stop lands while the temporary file is on disk
            time.sleep(0.2)
            tmp.write_text("whole")
        write_atomic(out / "model.pt", stopped)
        write_atomic(out / "next.txt", lambda tmp: tmp.write_text("never"))
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == -signum
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.pt"]
    assert (tmp_path / "model.pt").read_text() == "whole"
