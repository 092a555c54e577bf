"""The marker a coopsumo command writes into every folder it owns, read back: which command or study claims a folder.
Apart from run_dirs (which writes markers and judges folders by them) so that owners, which run_dirs asks whether a
study's root lies in a folder another command owns, reads markers without importing run_dirs."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from coopsumo.files import read_json_object

RUN_MARKER = ".coopsumo-run.json"

"""Written by a command into every folder it owns: {"kind": command, "version": coopsumo's, "finished": whether the
command has ended, "files": the names of the folder's entries when it ended (no "files" while a training or a study
runs)}. A dot-file, so listings stay as they were; named after the package, so no user's file is taken for it; a
separate file, because config.json is a common name that proves nothing about who wrote a folder. A marker written
before "finished" was (files null while its command ran) reads as it did (run_dirs.listed_files)."""

PARTIAL_MARKER = ".coopsumo-partial"
"""the file a partial folder is made with (removed before the folder becomes a run): clear_partials removes a
folder named like a partial one only when it holds this file, so a user's folder of such a name is left alone"""

PLANLESS_TITLES = {"regime_map": "# Scenario I: where the accident's queue goes, against demand",
                   "accident_seeds": "# Every training seed's model through scenario I's accident"}
"""the reports' first lines of the studies committed without a plan file (results/regime_map/, learning_conditioned/
accident/): an unmarked root without it whose report.md begins so is that study's own (run_dirs.check_study_root,
owners.unmarked_study_problem)"""

RUN_KINDS = ("simulate", "train")
"""the kinds of marker a single command writes (run_dirs' users); every other kind marks a study's root"""
LEARNING_KIND = "ablation"
"""the kind of marker `coopsumo learning` writes on its study's root: the only study accident-seeds reads (its ROOTs),
and the only one it may write directly into (run_dirs.check_study_place's hosts)"""


def read_marker(folder: Path) -> dict[str, Any] | None:
    """The marker of `folder` when it is a JSON object naming its command ("kind", a text), else None."""
    data = read_json_object(folder / RUN_MARKER)
    return data if data is not None and isinstance(data.get("kind"), str) else None


def marker_kind(folder: Path) -> str | None:
    """The command or study whose marker claims `folder`, or None (no marker, or one that names none)."""
    marker = read_marker(folder)
    return marker["kind"] if marker is not None else None


def marker_text(path: Path) -> bool:
    """True when the file `path`, named like a marker's temporary, may be what a marker's write left (nothing yet, or
    the start of its JSON object as write_json writes it), not a user's file of that name (issue 82, probe 10, L7: a
    user's notes there were taken, then deleted; probe 11, M2: a user's JSON file)."""
    try:
        text = path.read_bytes() if path.stat().st_size < 65_536 else b"x"
    except OSError:
        return False
    starts = [b'{\n  "' + key + b'"' for key in MARKER_KEYS]  # files.write_json: indented, keys sorted
    return any(start.startswith(text) or text.startswith(start) for start in starts)


MARKER_KEYS = (b"files", b"finished", b"kind", b"study", b"version")
"""the keys a marker's JSON object may begin with (run_dirs.mark_run_dir)"""
