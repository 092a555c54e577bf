"""Every command the README and the docs/ pages document runs (step counts shortened, output paths moved to a temp
folder), every relative link in them resolves, and the README stays short."""

from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import committed_report_pages

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
TEXT = {page: page.read_text() for page in PAGES}
RUN_HERE = [page for page in PAGES if page.name != "extending.md"]
"""the pages whose commands and snippets run here (docs/extending.md's run in tests/test_extending.py, in a working
folder holding its module)"""
STUDIES = ("scenario1", "scenario2", "protocol", "history")
"""run in tests/test_scenario1.py, test_scenario2.py and test_protocol.py with tiny profiles;
history (which prints the whole committed table) in tests/test_history.py"""


def blocks(lang: str, pages: list[Path] = RUN_HERE) -> list[str]:
    return [b for page in pages for b in re.findall(rf"```{lang}\n(.*?)```", TEXT[page], flags=re.S)]


def coopsumo_commands(pages: list[Path] = RUN_HERE) -> list[str]:
    """The `coopsumo ...` commands of the pages' bash blocks, continuation lines joined, comments dropped; not the
    studies, and not --gui (it needs a display: tests/test_sumo_tools.py runs it under Xvfb)."""
    cmds = []
    for block in blocks("bash", pages):
        for line in block.replace("\\\n", " ").splitlines():
            line = re.sub(r"\s+", " ", line.split("#")[0]).strip()
            words = line.split()
            if words[:1] == ["coopsumo"] and words[1] not in STUDIES and "--gui" not in words:
                cmds.append(line)
    return cmds


def shortened(cmd: str, tmp: Path, steps: int = 1500) -> list[str]:
    """The command with --steps cut to `steps` and results/ moved under tmp; an accident follows the run (left at its
    default window, 2/9 and 5/9 of it; a window given, --accident-start and --accident-steps cut by the same factor)."""
    if found := re.search(r"--steps (\d+)", cmd):
        factor = min(1.0, steps / int(found.group(1)))
        cmd = re.sub(r"(--accident-(?:start|steps)) (\d+)", lambda m: f"{m.group(1)} {int(int(m.group(2)) * factor)}",
                     cmd)  # fmt: skip
    cmd = re.sub(r"--steps \d+", f"--steps {steps}", cmd).replace("results/", f"{tmp}/")
    cmd = re.sub(r"--eval-steps \d+", "--eval-steps 300", cmd)
    return [sys.executable, "-m", "coopsumo", *shlex.split(cmd)[1:]]


@pytest.mark.sumo
def test_documented_commands_run(tmp_path: Path) -> None:
    cmds = coopsumo_commands()
    assert len(cmds) >= 6 and any("--resume" in c for c in cmds) and any("--tensorboard" in c for c in cmds)
    for i, cmd in enumerate(cmds):
        args = shortened(cmd, tmp_path, 600)
        resumed_next = i + 1 < len(cmds) and "--resume" in cmds[i + 1]
        if not resumed_next:
            res = subprocess.run(args, cwd=ROOT, capture_output=True, text=True, check=False)
            assert res.returncode == 0, f"{cmd}\n{res.stderr[-1500:]}"
            continue
        # the documented Ctrl-C: interrupt once the training has its first checkpoint (that a resume mid-run ends as
        # the uninterrupted training: tests/test_train.py and tests/test_faults.py)
        out = Path(args[args.index("--out") + 1])
        proc = subprocess.Popen(args, cwd=ROOT, stderr=subprocess.PIPE, text=True)
        deadline = time.time() + 180
        while time.time() < deadline and not (out / "checkpoint.pt").exists():
            time.sleep(0.02)
        os.kill(proc.pid, signal.SIGINT)
        proc.communicate(timeout=120)
        assert proc.returncode == 130 and (out / "checkpoint.pt").exists()
    model = next(tmp_path.rglob("model.pt"))
    assert model.exists()
    assert any(tmp_path.rglob("events.out.tfevents.*"))  # the README's --tensorboard


@pytest.mark.sumo
def test_make_demo_and_the_sumolib_snippet(tmp_path: Path) -> None:
    """`make demo` (into a temporary folder: the suite leaves the checkout as it found it), which says where it wrote,
    and the snippet on it."""
    demo = tmp_path / "results" / "demo"
    res = subprocess.run(["make", "demo", f"DEMO_OUT={demo}"], cwd=ROOT, capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr[-1500:]
    assert f"demo: wrote the run folder {demo}/" in res.stdout  # where it wrote, as its last line
    snippet = next(b for b in blocks("python") if "sumolib.xml.parse" in b and "detectors.xml" in b)
    res = subprocess.run([sys.executable, "-c", snippet], cwd=tmp_path, capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr
    rows = [line.split() for line in res.stdout.splitlines()]
    assert len(rows) >= 4  # 300 s of 60 s intervals
    assert all(float(r[1]) - float(r[0]) == pytest.approx(60.0) for r in rows)


@pytest.mark.sumo
def test_the_gymnasium_snippet_runs() -> None:
    (snippet,) = [b for b in blocks("python") if "gym.make" in b]
    res = subprocess.run([sys.executable, "-c", snippet], cwd=ROOT, capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr[-1500:]


@pytest.mark.sumo
def test_make_nets_builds_every_lane_count() -> None:
    res = subprocess.run(["make", "nets"], cwd=ROOT, capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr[-1500:]
    paths = [Path(line) for line in res.stdout.splitlines() if line.endswith(".net.xml")]
    assert [p.name.split("_")[1] for p in paths] == [f"{n}lanes" for n in range(2, 7)]
    assert all(p.exists() and "<net " in p.read_text() for p in paths)
    assert all(p.parent == ROOT / "sumo_nets" for p in paths)  # a checkout builds into its top-level sumo_nets/


@pytest.mark.sumo
def test_make_bench_quick() -> None:
    res = subprocess.run(["make", "bench", "BENCH_ARGS=--quick"], cwd=ROOT, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-1500:]
    assert "steps/s" in res.stdout and "us/veh/step" in res.stdout
    assert re.search(r"--fcd every 5 s \(scenario I\).*: [+-]\d+\.\d% wall time", res.stdout), res.stdout
    assert re.search(r"^training ratio \d+\.\d\d .*; \d+\.\d\d serially\)$", res.stdout, re.M), res.stdout


# -- the pages themselves (no SUMO) ------------------------------------------------------------------------
def anchor(heading: str) -> str:
    """GitHub's anchor of a markdown heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    return {anchor(m) for m in re.findall(r"^#+ (.*)$", text, flags=re.M)}


def relative_links(page: Path) -> list[str]:
    text = re.sub(r"```.*?```", "", TEXT[page], flags=re.S)
    links = re.findall(r"\]\(([^)\s]+)\)", text)
    return [link for link in links if not re.match(r"[a-z]+:", link)]


def test_every_relative_link_resolves() -> None:
    readmes = [ROOT / "results" / "README.md", ROOT / "results" / "archive" / "README.md",
               ROOT / "results" / "history" / "README.md", *sorted((ROOT / "results" / "history").glob("*/report.md"))]
    pages = [*PAGES, *committed_report_pages(), *readmes]
    broken, checked = [], 0
    for page in pages:
        TEXT.setdefault(page, page.read_text())
        for link in relative_links(page):
            path, _, frag = link.partition("#")
            target = (page.parent / path).resolve() if path else page
            checked += 1
            if not target.exists():
                broken.append(f"{page.relative_to(ROOT)}: {link} (no such file)")
            elif frag and target.suffix == ".md" and frag not in anchors(target):
                broken.append(f"{page.relative_to(ROOT)}: {link} (no such heading)")
    assert checked > 40
    assert not broken, "; ".join(broken)


def test_anchor_follows_github() -> None:
    assert anchor("Scenario I: the accident (`make scenario1`)") == "scenario-i-the-accident-make-scenario1"
    assert anchor("Deviations and choices") == "deviations-and-choices"


def test_readme_is_short_and_links_each_report_instead_of_copying_it() -> None:
    readme = TEXT[ROOT / "README.md"]
    assert len(readme.splitlines()) <= 200
    reports = sorted(p.relative_to(ROOT).as_posix() for p in committed_report_pages())
    assert reports and all(f"]({r})" in readme for r in reports)
    assert not re.search(r"\d+\.\d+ ± \d", readme)  # no measured value copied from a report
    assert readme[: readme.index("## The package")].count("\n") < 40  # the package map near the top


def test_one_deviations_table() -> None:
    """The deviations and choices are one table, in docs/model.md; nothing else (no page, no code) holds a copy."""
    holders = [p for p in PAGES if re.search(r"^\| topic \| paper \| here \|$", TEXT[p], flags=re.M)]
    assert holders == [ROOT / "docs" / "model.md"]
    code = [p for p in (ROOT / "coopsumo").rglob("*.py") if "| topic | paper | here |" in p.read_text()]
    assert code == []
