"""The package off the checkout: the wheel holds every module, installs (its dependencies already present) into a
fresh folder, and `coopsumo simulate` runs from it in a folder outside the repository, building its network into
the per-user cache, --nets-dir or COOPSUMO_NETS_DIR, never inside the package. The cluster install of docs/cluster.md
is run the same way."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SIMULATE = ["simulate", "--steps", "30", "--quiet", "--seed", "2"]
pytestmark = pytest.mark.sumo


def source_copy(dest: Path) -> Path:
    """pyproject.toml and the package, copied: a build in the checkout itself would leave build/ there, and
    setuptools puts a stale build/lib file into the next wheel."""
    dest.mkdir(parents=True)
    shutil.copy2(ROOT / "pyproject.toml", dest / "pyproject.toml")
    shutil.copytree(ROOT / "coopsumo", dest / "coopsumo", ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    return dest


def pip(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "pip", "--disable-pip-version-check", "--no-input", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=600, check=False)  # fmt: skip


def installed_env(target: Path, **extra: str) -> dict[str, str]:
    """The environment of a user of the installed package: it is first on the path; the checkout is not."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "COOPSUMO_NETS_DIR", "XDG_CACHE_HOME")}
    return {**env, "PYTHONPATH": str(target), **extra}


def run_installed(target: Path, args: list[str], cwd: Path, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    """The console script pip wrote for the package, run from cwd."""
    return subprocess.run([str(target / "bin" / "coopsumo"), *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=300, check=False)  # fmt: skip


def package_files(target: Path) -> set[str]:
    return {p.relative_to(target).as_posix() for p in (target / "coopsumo").rglob("*") if "__pycache__" not in p.parts}


def check_installed(target: Path, work: Path) -> str:
    """Run the installed coopsumo outside the repository three ways; returns what the user saw."""
    outside = work / "elsewhere"
    outside.mkdir()
    before = package_files(target)
    cache = work / "cache"
    res = run_installed(target, [*SIMULATE, "--out", "run"], outside, installed_env(target, XDG_CACHE_HOME=str(cache)))
    assert res.returncode == 0, res.stderr[-2000:]
    assert json.loads((outside / "run" / "summary.json").read_text())["steps"] == 30
    assert len(list((cache / "coopsumo" / "sumo_nets").glob("*.net.xml"))) == 1  # the per-user cache
    res_flag = run_installed(target, ["--nets-dir", "nets", *SIMULATE, "--out", "run2"], outside,
                             installed_env(target, XDG_CACHE_HOME=str(work / "unused")))  # fmt: skip
    assert res_flag.returncode == 0, res_flag.stderr[-2000:]
    assert len(list((outside / "nets").glob("*.net.xml"))) == 1 and not (work / "unused").exists()
    res_env = run_installed(target, [*SIMULATE, "--out", "run3"], outside,
                            installed_env(target, COOPSUMO_NETS_DIR=str(work / "env_nets")))  # fmt: skip
    assert res_env.returncode == 0, res_env.stderr[-2000:]
    assert len(list((work / "env_nets").glob("*.net.xml"))) == 1
    assert package_files(target) == before  # nothing generated inside the installed package
    where = subprocess.run([sys.executable, "-c", "import coopsumo; print(coopsumo.__file__)"], cwd=outside,
                           env=installed_env(target), capture_output=True, text=True, check=True)  # fmt: skip
    assert Path(where.stdout.strip()).is_relative_to(target), where.stdout  # the installed copy ran, not the checkout
    return res.stdout


def test_the_wheel_installs_and_runs_outside_the_repository(tmp_path: Path) -> None:
    src = source_copy(tmp_path / "src")
    res = pip("wheel", "--no-deps", "--no-build-isolation", "-w", str(tmp_path / "dist"), str(src), cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]
    (wheel,) = (tmp_path / "dist").glob("coopsumo-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    modules = {p.relative_to(ROOT).as_posix() for p in (ROOT / "coopsumo").rglob("*.py")}
    assert modules <= names, sorted(modules - names)  # every subpackage: sim, agents, studies, report, envs
    data = {p.relative_to(ROOT).as_posix() for p in (ROOT / "coopsumo" / "experiments_data").glob("*.toml")}
    assert len(data) == 4 and data <= names, sorted(data - names)  # learners, protocol, scenario1, scenario2
    assert not [n for n in names if n.endswith(".xml") or "sumo_nets" in n]  # no network inside the package
    entry = next(n for n in names if n.endswith("entry_points.txt"))
    assert "coopsumo = coopsumo.cli:main" in zipfile.ZipFile(wheel).read(entry).decode()
    target = tmp_path / "target"
    res = pip("install", "--no-deps", "--target", str(target), str(wheel), cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]
    out = check_installed(target, tmp_path)
    res = run_installed(target, ["protocol", "--help"], tmp_path / "elsewhere", installed_env(target))
    assert res.returncode == 0 and "stks (the default)" in " ".join(res.stdout.split()), res.stderr[-2000:]
    print(f"wheel {wheel.name} ({wheel.stat().st_size / 1024:.0f} KiB, {len(names)} files) installed into a fresh "
          f"target; coopsumo simulate from outside the repository: {out.strip()}")  # fmt: skip


def test_the_documented_cluster_install_works_outside_the_repository(tmp_path: Path) -> None:
    """docs/cluster.md's `pip install ".[ray]"` from a copy of the repository, with its dependencies already present
    (the test cannot fetch them: --no-deps), into a fresh target; Ray and the study runner import from it."""
    section = (ROOT / "docs" / "cluster.md").read_text()
    (block,) = re.findall(r"```bash\n(.*?)```", section, flags=re.S)
    lines = [line.strip() for line in block.splitlines() if line.strip()]
    assert lines == ["pip install torch==2.13.0", 'pip install ".[ray]"']
    src = source_copy(tmp_path / "src")
    target = tmp_path / "target"
    res = pip("install", "--no-deps", "--no-build-isolation", "--target", str(target), ".[ray]", cwd=src)
    assert res.returncode == 0, res.stderr[-2000:]
    check_installed(target, tmp_path)
    probe = "import ray, torch, coopsumo.studies.engine.runner as r; print(torch.__version__, r.__file__)"
    res = subprocess.run([sys.executable, "-c", probe], cwd=tmp_path / "elsewhere", env=installed_env(target),
                         capture_output=True, text=True, timeout=120, check=False)  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.startswith("2.13.0") and str(target) in res.stdout
