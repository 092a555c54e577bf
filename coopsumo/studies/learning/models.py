"""The finished trainings of a learning study's folder (`coopsumo learning --out ROOT`), for the commands that read
its models: accident_seeds and diagnosis."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from coopsumo.errors import UsageError
from coopsumo.studies.learning.plan import learner_of, training_key


def finished_trainings(root: Path, prog: str, variants: tuple[str, ...] | None = None,
                       alphas: tuple[float, ...] | None = None,
                       seeds: int | None = None) -> list[dict[str, Any]]:  # fmt: skip
    """Every training of root whose record says it finished, of `variants`, at an alpha of `alphas`, on a training
    seed below `seeds` (None: any): its record's key, variant, alpha, seed and config, its learner (DQNConfig) and its
    model (ROOT/train/<training_key>/model.pt, where the study trained it: a variant that differs only in its change
    margin drives its twin's training).

    A record that cannot be read, or names a variant this version does not know, is skipped with one line on stderr;
    UsageError when root has no cells/ or the model of a finished training asked for is missing."""
    if not (root / "cells").is_dir():
        raise UsageError(f"{root} is not a learning-study folder (it has no cells/): give the --out of `coopsumo "
                         "learning`")  # fmt: skip
    found = []
    for cell in sorted((root / "cells").glob("*.json")):
        try:
            rec = json.loads(cell.read_text())
            if not (isinstance(rec, dict) and rec.get("kind") == "train" and rec.get("status") == "ok"):
                continue
            variant, alpha, seed = str(rec["variant"]), float(rec["alpha"]), int(rec["seed"])
            learner, config = learner_of(variant), dict(rec["config"])
            steps = int(config["train"]["sim"]["steps"])
        except (OSError, ValueError, KeyError, TypeError) as err:  # UsageError (an unknown variant) among them
            print(f"{prog}: record {cell} cannot be used ({err if isinstance(err, UsageError) else type(err).__name__})"
                  "; skipped", file=sys.stderr)  # fmt: skip
            continue
        if (variants is not None and variant not in variants) or (alphas is not None and alpha not in alphas) \
                or (seeds is not None and seed >= seeds):  # fmt: skip
            continue
        # the study's own training folder (a link into the model store), not the store folder it points to
        key = training_key(learner, variant, alpha, seed, steps)
        model = root.resolve() / "train" / key / "model.pt"
        if not model.is_file():
            raise UsageError(f"{model} is missing, though record {cell} says its training finished: run `coopsumo "
                             f"learning` on {root} again")  # fmt: skip
        found.append({"key": str(rec.get("key", cell.stem)), "variant": variant, "alpha": alpha, "seed": seed,
                      "config": config, "learner": learner, "model": model})  # fmt: skip
    return found
