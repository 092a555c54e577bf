"""Every relative link in README.md, results/README.md and docs/*.md points at something a fresh clone has: a file
git tracks, or a folder holding one (tests/test_docs.py checks the links against this machine's files, where
generated and untracked outputs also exist). And no page names a results folder by the path it had before it was
archived (issue 68: docs/model.md and docs/studies.md read `results/learning_restart/`, now under results/archive/),
unless a study writes there by default."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

from coopsumo.studies.engine.run_folders import default_out
from coopsumo.studies.scenario2 import study as scenario2

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", ROOT / "results" / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def tracked() -> tuple[set[str], set[str]]:
    """(the files git tracks, every folder holding one), as paths relative to the checkout."""
    res = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=False)
    if res.returncode != 0 or not res.stdout:
        pytest.skip("not a git checkout")
    files = set(res.stdout.splitlines())
    folders = {parent.as_posix() for f in files for parent in Path(f).parents if parent != Path(".")}
    return files, folders


def links(page: Path) -> list[str]:
    """The page's relative link targets outside code blocks, without their #anchor; not http(s) or mailto, not
    anchors alone."""
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    targets = [link.partition("#")[0] for link in re.findall(r"\]\(([^)\s]+)\)", text)]
    return [t for t in targets if t and not re.match(r"[a-z]+:", t)]


def test_every_relative_link_points_at_a_tracked_file_or_folder() -> None:
    files, folders = tracked()
    broken, checked = [], 0
    for page in PAGES:
        for link in links(page):
            target = (page.parent / link).resolve()
            checked += 1
            rel = target.relative_to(ROOT).as_posix() if target.is_relative_to(ROOT) else None
            if rel is None or (rel not in files and rel not in folders):
                broken.append(f"{page.relative_to(ROOT)}: {link}")
    assert checked > 40
    assert not broken, "links to what a fresh clone does not have: " + "; ".join(broken)


def study_outputs() -> set[str]:
    """The folders under results/ scenario II writes without --out (a page may name them as such even when a report
    once made there is archived): results/scenario2[_<profile>]."""
    return {default_out("scenario2", name, scenario2.DEFAULT_PROFILE).name for name in scenario2.PROFILES}


def test_no_page_names_an_archived_results_folder_by_its_old_path() -> None:
    _, folders = tracked()
    archived = {Path(f).name for f in folders if re.fullmatch(r"results/archive/[^/]+", f)}
    assert {"learning_restart", "learning_robust", "scenario2_conditioned"} <= archived
    outputs = study_outputs()
    assert "scenario2" in outputs
    stale = []
    for page in PAGES:
        text = page.read_text()
        for name in re.findall(r"(?<![\w/])results/([A-Za-z0-9_]+)/", text):
            if name in archived and f"results/{name}" not in folders and name not in outputs:
                stale.append(f"{page.relative_to(ROOT)}: results/{name}/")
    assert not stale, "archived folders named by their old path: " + "; ".join(sorted(set(stale)))
