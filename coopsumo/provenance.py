"""What made a result: the versions of coopsumo, SUMO, torch, numpy and Python, and the source's git commit."""

from __future__ import annotations

import os
import platform
import subprocess
from functools import cache
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path


def package_version(name: str) -> str:
    try:
        return version(name)
    except PackageNotFoundError:
        return "not installed"


@cache
def source_revision() -> str:
    """The git commit of the coopsumo source this process runs, with '-dirty' when tracked files differ from it;
    'unknown' outside a git checkout (an installed wheel). Read-only: git takes no lock and writes no index."""
    root = str(Path(__file__).resolve().parent.parent)
    env = {**os.environ, "GIT_OPTIONAL_LOCKS": "0"}
    try:
        head = subprocess.run(["git", "-C", root, "rev-parse", "--short=12", "HEAD"], capture_output=True, text=True,
                              timeout=20, env=env)  # fmt: skip
        if head.returncode != 0 or not head.stdout.strip():
            return "unknown"
        status = subprocess.run(["git", "-C", root, "status", "--porcelain", "--untracked-files=no"],
                                capture_output=True, text=True, timeout=20, env=env)  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return head.stdout.strip() + ("-dirty" if status.returncode != 0 or status.stdout.strip() else "")


def versions() -> dict[str, str]:
    """Versions of everything that shapes a result, with the source's git commit (source_revision)."""
    return {"coopsumo": package_version("coopsumo"), "coopsumo_source": source_revision(),
            "sumo": package_version("eclipse-sumo"), "libsumo": package_version("libsumo"),
            "torch": package_version("torch"), "numpy": package_version("numpy"),
            "python": platform.python_version()}  # fmt: skip

