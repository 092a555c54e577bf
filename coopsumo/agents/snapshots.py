"""Where a training that selects its model keeps its snapshots and their validations (agents/selection.py makes
them; model selection reads them back).

OUT/snapshots/step<N>/model.pt is the weights that drive at training step N (the online network),
OUT/snapshots/step<N>/validation.json the
result of validating it (its "score" the mean reward per vehicle and step over the validation runs); with a
selection in two stages, OUT/snapshots/step<N>/screen.json that of its screening runs, and validation.json only for
the finalists.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from coopsumo.files import read_json_object

SNAPSHOTS = "snapshots"
"""folder of a training's snapshots (one subfolder step<N> each)"""
RESULT = "validation.json"
SCREEN = "screen.json"
"""a snapshot's validation on the screening runs alone (DQNConfig.validation_screen)"""
SCREEN_STAGE = "screen"
"""a request's stage when it asks for the screening runs alone"""


def snapshot_dir(out: Path, step: int) -> Path:
    return out / SNAPSHOTS / f"step{step}"


def result(folder: Path, name: str = RESULT) -> dict[str, Any] | None:
    """The finished validation of a snapshot folder (on every run; name SCREEN: on the screening runs), or None."""
    data = read_json_object(folder / name)
    return data if data is not None and isinstance(data.get("score"), float) else None


def by_score(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Validation results best score first, ties to the earlier step (model selection's order)."""
    return sorted(results, key=lambda r: (-r["score"], r["step"]))


def best(results: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The result with the highest score; the earliest step among equal scores; None for none."""
    return next(iter(by_score(results)), None)


def results(out: Path) -> list[dict[str, Any]]:
    """Every finished validation of the training in out, by step."""
    found = [r for d in sorted((out / SNAPSHOTS).glob("step*")) if (r := result(d)) is not None]
    return sorted(found, key=lambda r: r["step"])
