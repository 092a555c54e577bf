"""The marker a coopsumo command writes into every folder it owns, read back: which command or study claims a folder.
Apart from run_dirs (which writes markers and judges folders by them) so that owners, which run_dirs asks whether a
study's root lies in a folder another command owns, reads markers without importing run_dirs."""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from coopsumo.errors import NotRegularFileError
from coopsumo.files import file_sha256, read_json_object, read_text

RUN_MARKER = ".coopsumo-run.json"

"""Written by a command into every folder it owns: {"kind": command, "version": coopsumo's, "finished": whether the
command has ended, "files": the names of the folder's entries when it ended (no "files" while a training or a study
runs), for a run also SUMS: their sha256}. A dot-file, so listings stay as they were; named after the package, so no
user's file is taken for it; a separate file, because config.json is a common name that proves nothing about who wrote
a folder. A marker written before "finished" was (files null while its command ran) reads as it did
(run_dirs.listed_files)."""

PARTIAL_MARKER = ".coopsumo-partial"
"""the file a partial folder is made with (removed before the folder becomes a run): clear_partials removes a
folder named like a partial one only when it holds this file, so a user's folder of such a name is left alone"""

PLANLESS_TITLES = {"regime_map": "# Scenario I: where the accident's queue goes, against demand",
                   "accident_seeds": "# Every training seed's model through scenario I's accident"}
"""the reports' first lines of the studies committed without a plan file (results/regime_map/,
archive/learning_conditioned_nr10/accident/): an unmarked root without it whose report.md begins so is that study's
own (run_dirs.check_study_root, owners.unmarked_study_problem)"""

SB3_KIND = "sb3_dqn"
"""the marker kind of experiments/sb3_dqn.py's folder (its model.zip): a simulate run's kind before, it was replaced by
a simulate run and replaced one (issue 82, probe 18, DL1)"""
RUN_KINDS = ("simulate", "train", SB3_KIND)
"""the kinds of marker a single command writes (run_dirs' users); every other kind marks a study's root"""
SUMS = "files_sha256"
"""the key of a finished run's marker (a kind of SUMMED_KINDS) that records the sha256 of each regular file its folder
held when the run finished: {name: digest}. A study reuses a run folder only while its files are the ones its run
wrote (changed_file; issue 82, probe 16, TR1: another run's trajectories.parquet or detectors.xml copied in passed
every check of the file on its own, and its measures went into runs.csv). A marker written before has none: its
folder is judged as before."""
SUMMED_KINDS = ("simulate",)
"""the commands whose finished marker records SUMS: a single run's, whose folders studies reuse (a training's files
are judged by its model's own digest, and a group's training adds its cost file after its marker)"""
LEARNING_KIND = "ablation"
"""the kind of marker `coopsumo learning` wrote on its study's root (the command retired by issue 80: its ablation is
the protocol's learning profile): such a folder is still named, as a learning study, and refused as another's"""


def kind_name(kind: str) -> str:
    """How a line names the command or study of a marker's kind: `learning` for LEARNING_KIND, kept as the marker
    writes it (issue 82, probe 13, F20: "holds a coopsumo protocol run, not a ablation study")."""
    return "learning" if kind == LEARNING_KIND else kind


def a_kind(kind: str, what: str) -> str:
    """`a NAME WHAT` (kind_name), its article fitting NAME ("an accident_seeds study")."""
    name = kind_name(kind)
    return f"{'an' if name[:1] in 'aeiou' else 'a'} {name} {what}"


def read_marker(folder: Path) -> dict[str, Any] | None:
    """The marker of `folder` when it is a JSON object naming its command ("kind", a text), else None."""
    data = read_json_object(folder / RUN_MARKER)
    return data if data is not None and isinstance(data.get("kind"), str) else None


def marker_kind(folder: Path) -> str | None:
    """The command or study whose marker claims `folder`, or None (no marker, or one that names none)."""
    marker = read_marker(folder)
    return marker["kind"] if marker is not None else None


def marker_text(path: Path) -> bool:
    """True when the file `path`, named like a marker's temporary, may be what a marker's write left: empty, or a
    start of the very text write_json writes for a marker (indented, keys sorted, a marker's keys and values only),
    not a user's file of that name (issue 82, probe 10, L7: a user's notes there were taken, then deleted; probe 11,
    M2: a user's JSON file; probe 12, N2: a user's indented JSON file whose first key is a marker's)."""
    try:
        text = (path.read_bytes() if path.stat().st_size < 65_536 else b"\xff").decode("ascii")  # json.dumps: ASCII
    except (OSError, UnicodeDecodeError):
        return False
    *lines, last = text.split("\n")
    states = {0}
    for line in lines:
        states = {after for state in states for rule, after in _MARKER_LINES.get(state, ()) if _whole(rule, line)}
    return (last == "" and _END in states) or any(
        _start(rule, last) for state in states for rule, _ in _MARKER_LINES.get(state, ()))


_JSON_TEXT = re.compile(r'"(?:[^"\\\x00-\x1f]|\\.)*"')
_OPEN_TEXT = re.compile(r'"(?:[^"\\\x00-\x1f]|\\.)*\\?')
_END = 9  # the closing brace written: only its newline may follow
_T = None  # a JSON text, in a rule
_NAMED = ("    ", _T, ": ", _T)  # a line of SUMS: a file's name and its digest
_MARKER_LINES: dict[int, tuple[tuple[tuple[str | None, ...], int], ...]] = {
    0: ((("{",), 1),),
    1: ((('  "files": [],',), 4), (('  "files": [',), 2), (('  "finished": false,',), 5)),
    2: ((("    ", _T, ","), 2), (("    ", _T), 3)),
    3: ((("  ],",), 4),),
    4: ((('  "finished": true,',), 5), ((f'  "{SUMS}": {{}},',), 13), ((f'  "{SUMS}": {{',), 11)),
    11: (((*_NAMED, ","), 11), (_NAMED, 12)),
    12: ((("  },",), 13),),
    13: ((('  "finished": true,',), 5),),
    5: ((('  "kind": ', _T, ","), 6),),
    6: ((('  "profile_digest": ', _T, ","), 10), (('  "study": ', _T, ","), 7), (('  "version": ', _T), 8)),
    10: ((('  "study": ', _T, ","), 7), (('  "version": ', _T), 8)),
    7: ((('  "version": ', _T), 8),),
    8: ((("}",), _END),)}
"""the lines of a marker as write_json writes it (mark_run_dir), state by state: each line's pieces (a text as it
stands, _T for a JSON text), then the next state"""


def _whole(rule: tuple[str | None, ...], line: str) -> bool:
    """True when `line` is a line `rule` stands for."""
    return re.fullmatch("".join(_JSON_TEXT.pattern if p is None else re.escape(p) for p in rule), line) is not None


def _start(rule: tuple[str | None, ...], text: str) -> bool:
    """True when `text` is the start of a line `rule` stands for (a write killed within it)."""
    for piece in rule:
        if piece is None:
            if (closed := _JSON_TEXT.match(text)) is None:
                return _OPEN_TEXT.fullmatch(text) is not None
            text = text[closed.end():]
        elif len(text) <= len(piece) or not text.startswith(piece):
            return piece.startswith(text)
        else:
            text = text[len(piece):]
    return text == ""


DIGEST = "profile_digest"
"""the key of a study root's marker that records what defines its study: a digest of its profile's settings
(studies/engine/run_folders.profile_digest); a profile of the same name with other settings is another study"""


def other_settings(root: Path, marker: dict[str, Any] | None, study: str, digest: str | None,
                   advice: str) -> str | None:  # fmt: skip
    """Why the study root `root`, which holds `study` by name, holds another study of that name (a line), or None: its
    marker records a digest of its profile's settings (DIGEST) that is not `digest`. A profile's name alone did not
    tell two studies apart: another file's profile of the same name replaced a finished study's tables and report
    (issue 82, probe 13, F11). A marker without one (written before markers recorded it) is taken as the study's."""
    recorded = marker.get(DIGEST) if marker is not None and digest is not None else None
    if recorded is None or recorded == digest:
        return None
    return (f"output folder {root} holds {study} run with other settings (its {RUN_MARKER} records the profile's "
            f"settings as {str(recorded)[:16]}, this profile's are {digest}: another file's profile of that name, or "
            f"the profile edited): a study writes into its own folder, and this one is left alone; {advice}")


def committed_planless(root: Path, kind: str) -> bool:
    """Whether the unmarked study root `root` without a plan file is a committed study of `kind` written so: its
    report.md begins with PLANLESS_TITLES[kind] (run_dirs.check_study_root)."""
    if not (root / "report.md").is_file():
        return False
    try:
        return read_text(root / "report.md").split("\n", 1)[0] == PLANLESS_TITLES.get(kind)
    except (OSError, UnicodeDecodeError, ValueError):
        return False


def entries(folder: Path) -> list[str]:
    """Every file and folder under `folder` (relative, '/'-separated), the marker left out."""
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p != folder / RUN_MARKER)


def finished_entries(folder: Path, kind: str) -> dict[str, Any]:
    """What the finished marker of the command `kind` records of its folder: its entries ("files") and, for a run
    (SUMMED_KINDS), the sha256 of each of its files (SUMS), of the files as they are now: a run's partial folder is
    marked just before it is renamed into place (run_dirs.finish_run_dir), so these are its final files."""
    files = entries(folder)
    return {"files": files, **({SUMS: file_sums(folder, files)} if kind in SUMMED_KINDS else {})}


def file_sums(folder: Path, names: Sequence[str]) -> dict[str, str]:
    """The sha256 of each regular file of `folder` among `names` (its entries), as a finished marker records them
    (SUMS); folders and links are left out."""
    return {name: file_sha256(folder / name) for name in names
            if (folder / name).is_file() and not (folder / name).is_symlink()}  # fmt: skip


def changed_file(folder: Path) -> str | None:
    """Why a file of the finished run folder `folder` is not the one its run wrote (a line's end), or None: its
    sha256 is not the one the marker records (SUMS), or it is no longer a regular file, or the marker records no digest
    of a regular file it lists, or SUMS is empty or not a table (probe 17, TR1). Only the entries the marker lists are
    looked at (a lost one is judged where the list is); a file that cannot be read is left to its reader's check, and
    a marker without SUMS (written before markers recorded them) is not judged."""
    marker = read_marker(folder) or {}
    if SUMS not in marker:
        return None
    sums, listed = marker.get(SUMS), marker.get("files")
    if not isinstance(sums, dict) or not sums or not all(isinstance(v, str) for v in sums.values()):
        return f"has a {RUN_MARKER} whose {SUMS} is not a table of digests (damaged?)"
    for name in sorted({f for f in listed if isinstance(f, str)} if isinstance(listed, list) else ()):
        path = folder / name
        if not os.path.lexists(path) or (name not in sums and (path.is_symlink() or not path.is_file())):
            continue  # lost: judged where the list is; a link or folder: the marker records no digest of it
        if name not in sums:  # probe 17, TR1: a digest taken out of the marker let a file copied in be reused
            return f"has a {name} its {RUN_MARKER} records no digest of (the marker edited?)"
        try:
            same = not path.is_symlink() and file_sha256(path) == sums[name]
        except NotRegularFileError:
            same = False
        except OSError:
            continue  # unreadable: its reader's check says so
        if not same:
            return f"has a {name} that is not the file its run wrote (changed or copied in since)"
    return None
