"""The headers of SUMO's output files of a run (sim/sumo_session.py writes them; this module only rewrites a
closed file's header comment, never touching SUMO)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

OUTPUT_FILES = ("detectors.xml", "fcd.xml", "tripinfo.xml")
"""SUMO's output files of a run (the loops' always, FCD and tripinfo when asked for), in its run folder"""
HEADER_BYTES = 1 << 16
"""SUMO's header comment (its command line) lies within this many bytes of an output file's start"""


def name_run_files_by_name(path: Path, run_dir: Path) -> None:
    """Make the header of SUMO's output file `path` name the run's own files by file name alone.

    SUMO heads every output file with its command line, which names the route, detector and output files by their
    path in run_dir: when a run is written into a temporary folder and then moved (run_dirs.atomic_run_dir), a
    folder that no longer exists. The files lie beside `path` wherever the folder ends up, so their names say where
    they are. Only the header comment is changed; the rest of the file is copied as it is."""
    folder = str(run_dir)
    if folder in ("", ".") or not path.is_file():
        return
    from xml.sax.saxutils import escape

    prefixes = {os.fsencode(p + os.sep) for p in (folder, escape(folder, {'"': "&quot;", "'": "&apos;"}))}
    with path.open("rb") as src:
        head = src.read(HEADER_BYTES)
        end = head.find(b"-->")
        if end < 0:
            return
        named = head[:end]
        for prefix in prefixes:
            named = named.replace(prefix, b"")
        if named == head[:end]:
            return
        tmp = path.with_name(f".{path.name}.header")
        with tmp.open("wb") as dst:
            dst.write(named + head[end:])
            shutil.copyfileobj(src, dst)
    os.replace(tmp, path)
