"""What `make install` installs, and that the README's Set up says the same (issue 81): by default torch from PyPI by
name (`pip install torch==2.13.0`, unchanged: CI and this machine reach only PyPI), and with the README's
`TORCH_INDEX=...` the CPU build from PyTorch's own index, as PyTorch's instructions for CPU-only machines give it
(pip's --index-url). The recipes are printed by `make -n` (nothing runs, nothing is installed)."""

from __future__ import annotations

import re
import shlex
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CPU_INDEX = "https://download.pytorch.org/whl/cpu"


def install_recipe(*variables: str) -> list[str]:
    """The lines `make install` would run in a new checkout (-B: as if .venv were not installed yet; -n: printed)."""
    stamp = ROOT / ".venv" / ".installed"
    before = stamp.stat().st_mtime_ns if stamp.exists() else None
    res = subprocess.run(["make", "-n", "-B", "install", *variables], cwd=ROOT, capture_output=True, text=True,
                         check=False)  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert (stamp.stat().st_mtime_ns if stamp.exists() else None) == before  # printed, not run
    return res.stdout.splitlines()


def pip_lines(lines: list[str]) -> list[str]:
    return [line.split("#")[0].strip() for line in lines if line.startswith(".venv/bin/pip install")]


def setup_block() -> str:
    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("## Set up") : readme.index("## Commands")]
    (block,) = re.findall(r"```bash\n(.*?)```", section, flags=re.S)
    return block


def pinned_torch() -> str:
    (version,) = re.findall(r'"torch==([0-9.]+)"', (ROOT / "pyproject.toml").read_text())
    return version


def test_the_default_install_takes_torch_from_pypi_by_name() -> None:
    lines = pip_lines(install_recipe())
    assert lines[1] == f".venv/bin/pip install --quiet torch=={pinned_torch()}"
    assert not any("--index-url" in line or "--extra-index-url" in line for line in lines)


def test_the_readmes_cpu_command_takes_the_cpu_build_from_pytorchs_index() -> None:
    commands = [shlex.split(line.split("#")[0]) for line in setup_block().splitlines() if line.startswith("make ")]
    assert commands[0] == ["make", "install"]
    (cpu,) = [words for words in commands if any(w.startswith("TORCH_INDEX=") for w in words)]
    assert cpu == ["make", "install", f"TORCH_INDEX={CPU_INDEX}"]
    lines = pip_lines(install_recipe(*cpu[2:]))
    assert lines[1] == f".venv/bin/pip install --quiet torch=={pinned_torch()} --index-url {CPU_INDEX}"
    assert lines[2].startswith(".venv/bin/pip install --quiet -e ") and "index-url" not in lines[2]  # the rest: PyPI


def test_the_readme_says_what_the_default_installs() -> None:
    comment = next(line for line in setup_block().splitlines() if line.startswith("make install  #"))
    assert f"PyPI's torch {pinned_torch()} (CUDA build on Linux x86-64)" in comment
    assert "(CPU)" not in setup_block()  # what it said before: the default is no CPU build
    extras = re.search(r'-e "\.\[([a-z0-9,]+)\]"', (ROOT / "Makefile").read_text())
    assert extras is not None and comment.endswith("extras " + ", ".join(extras.group(1).split(",")))
