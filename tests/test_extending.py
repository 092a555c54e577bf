"""docs/extending.md as written: its module written where its first line names it, then every command of its bash
blocks in a temporary working folder (step counts shortened; scenario I at one demand, one 300-step model and
300-step runs), each refusal it marks ending in one line with exit code 2 and nothing written, and its Python snippet.
What they made is then checked: the class of one's own and the SB3 model drove simulate and stand beside `keep` in
scenario I's report, the road has its settings, the training its reward weights."""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGE = (ROOT / "docs" / "extending.md").read_text()
REFUSED = "# refused: exit 2"
"""how the page marks a command that must be refused"""
SHORTER = {"--steps": "300", "--eval-steps": "150"}
"""step counts the test runs instead of the page's"""
SMALL_SCENARIO1 = ["--train-steps", "300", "--steps", "300", "--seeds", "1", "--t-up", "2", "--mobil-p", "0",
                   "--alphas", "0", "--train-seeds", "1", "--workers", "2"]  # fmt: skip
"""scenario I's --quick at a test's size: one 300-step model (alpha 0), one demand, one seed, 300-step runs"""


def blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", PAGE, flags=re.S)


def files() -> dict[str, str]:
    """The page's Python blocks whose first line names a file (`# mypolicy.py`): name -> text."""
    return {b.splitlines()[0][2:].strip(): b for b in blocks("python") if re.match(r"# \w+\.py\n", b)}


def commands() -> list[tuple[str, bool]]:
    """Every command of the page's bash blocks and whether the page marks it refused."""
    out = []
    for block in blocks("bash"):
        for line in block.replace("\\\n", " ").splitlines():
            if line.strip():
                out.append((line.split("#")[0].strip(), REFUSED in line))
    return out


def argv(cmd: str) -> list[str]:
    """The command as the test runs it: coopsumo through this interpreter, experiments/ from the checkout, step counts
    shortened, scenario I's --quick at a test's size."""
    words = shlex.split(cmd)
    for i, word in enumerate(words[:-1]):
        if word in SHORTER:
            words[i + 1] = SHORTER[word]
    if words[0] == "python":
        return [sys.executable, str(ROOT / words[1]), *words[2:], "--warmup", "50", "--max-steps", "150"]
    assert words[0] == "coopsumo", cmd
    if words[1] == "scenario1":
        words = [*words, *SMALL_SCENARIO1]
    return [sys.executable, "-m", "coopsumo", *words[1:]]


def test_the_page_holds_what_the_issue_asks() -> None:
    cmds = " ".join(c for c, _ in commands())
    for part in ("--policy py:mypolicy:KeepRight", "--baseline py:mypolicy:KeepRight", "--policy sb3:",
                 "--baseline sb3:", "--road-length", "--accident-x", "--loop-spacing", "--speed-limit", "--net-file",
                 "--w-speed", "--w-flow"):  # fmt: skip
        assert part in cmds, part
    assert list(files()) == ["mypolicy.py"]
    assert sum(refused for _, refused in commands()) == 2
    assert "| left | 0 |" in PAGE and "| right | 1 |" in PAGE and "| speed-up | 2 |" in PAGE and "| none | 3 |" in PAGE


@pytest.mark.sumo
def test_every_example_runs_as_written(tmp_path: Path) -> None:
    for name, text in files().items():
        (tmp_path / name).write_text(text)
    env = {**{k: v for k, v in os.environ.items() if k not in ("DISPLAY", "COOPSUMO_MODELS")},
           "COOPSUMO_NETS_DIR": str(tmp_path / "sumo_nets")}  # the study's model store: its own, beside its --out
    said = ""
    for cmd, refused in commands():
        res = subprocess.run(argv(cmd), cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600, check=False)
        said += res.stderr
        if refused:
            out = tmp_path / shlex.split(cmd)[shlex.split(cmd).index("--out") + 1]
            assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, f"{cmd}\n{res.stderr}"
            assert not out.exists() and not list(out.parent.glob(f".{out.name}*")), cmd
        else:
            assert res.returncode == 0, f"{cmd}\n{res.stderr[-2000:]}"
    for snippet in (b for b in blocks("python") if b not in files().values()):
        res = subprocess.run([sys.executable, "-c", snippet], cwd=tmp_path, env=env, capture_output=True, text=True,
                             timeout=300, check=False)  # fmt: skip
        assert res.returncode == 0, res.stderr[-2000:]
    _what_they_made(tmp_path / "results")
    # written nowhere but the --out folders, the networks folder and the model store, which the study named
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mypolicy.py", "results", "sumo_nets"]
    assert sorted(p.name for p in (tmp_path / "results").iterdir()) == [
        "highway_dqn", "keep_right", "models", "my_road", "sb3_drive", "scenario1_own", "train"]  # fmt: skip
    assert f"model store {tmp_path / 'results' / 'models'}" in said
    listed = subprocess.run([sys.executable, "-m", "coopsumo", "models"], cwd=tmp_path, env=env, capture_output=True,
                            text=True, check=True).stdout  # fmt: skip
    assert "default_a0_seed100_" in listed and "1 models in results/models, 1 usable" in listed


def _what_they_made(results: Path) -> None:
    own = json.loads((results / "keep_right" / "summary.json").read_text())
    assert own["policy"] == "py:mypolicy:KeepRight" and own["departed"] > 0 and own["collisions"] == 0
    sb3 = json.loads((results / "sb3_drive" / "config.json").read_text())["model_trained_on"]
    assert sb3["policy_file"] == str(results / "highway_dqn" / "model.zip") and len(sb3["model_sha256"]) == 64
    runs = pd.read_csv(results / "scenario1_own" / "runs.csv")
    assert {"keep", "py_KeepRight", "sb3_highway_dqn"} <= set(runs["policy"])
    report = (results / "scenario1_own" / "report.md").read_text()
    assert all(f"| {label} |" in report for label in ("keep", "py_KeepRight", "sb3_highway_dqn"))
    road = json.loads((results / "my_road" / "config.json").read_text())["config"]
    assert (road["road"]["length_m"], road["road"]["loop_spacing_m"], road["road"]["speed_limit_mps"],
            road["accident"]["x_m"]) == (1500, 100, 25, 900)  # fmt: skip
    trained = json.loads((results / "train" / "no_flow" / "config.json").read_text())["config"]["sim"]["reward"]
    assert (trained["w_speed"], trained["w_flow"], trained["alpha"]) == (1, 0, 8)
