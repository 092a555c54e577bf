"""The finished trainings of a learning study's folder (`coopsumo learning --out ROOT`), for the commands that read
its models: accident_seeds."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

from coopsumo.errors import UsageError
from coopsumo.files import read_json
from coopsumo.studies.engine.records import cell_problem
from coopsumo.studies.learning.plan import REQUIRED_SUMMARY, learner_of, training_key


def finished_trainings(root: Path, prog: str, variants: tuple[str, ...] | None = None,
                       alphas: tuple[float, ...] | None = None,
                       seeds: int | None = None) -> list[dict[str, Any]]:  # fmt: skip
    """Every training of root whose record says it finished, of `variants`, at an alpha of `alphas`, on a training
    seed below `seeds` (None: any): its record's key, variant, alpha, seed and config, its learner (DQNConfig) and its
    model (ROOT/train/<training_key>/model.pt, where the study trained it: a variant that differs only in its change
    margin drives its twin's training).

    A record that cannot be read, that the study itself would rerun (records.cell_problem: outside
    record_schemas.CELL_RECORD, a summary or train_summary no run gives, naming the field; issue 82, probe 8, J14: a
    train_summary of 999 m/s was driven) or that names a variant this version does not know, is skipped with one line
    on stderr;
    UsageError when root is not a learning study's folder (root_problem), has no cells/, or the model of a finished
    training asked for is missing or is not that training's (model_problem: a model swapped in from another learner is
    never driven as this one)."""
    if (problem := root_problem(root)) is not None:
        raise UsageError(problem)
    if not (root / "cells").is_dir():
        raise UsageError(f"{root} is not a learning-study folder (it has no cells/): give the --out of `coopsumo "
                         "learning`")  # fmt: skip
    found = []
    for cell in sorted((root / "cells").glob("*.json")):
        try:
            rec = read_json(cell)
            if not (isinstance(rec, dict) and rec.get("kind") == "train" and rec.get("status") == "ok"):
                continue
            if (problem := cell_problem(rec, REQUIRED_SUMMARY)) is not None:  # as the study judges it (probe 8, J14)
                raise UsageError(problem)
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
        if (problem := model_problem(model, config["train"])) is not None:
            raise UsageError(f"{problem}: it is not the model record {cell} trained, and is not driven as it; restore "
                             f"it, or run `coopsumo learning` on {root} again")  # fmt: skip
        found.append({"key": str(rec.get("key", cell.stem)), "variant": variant, "alpha": alpha, "seed": seed,
                      "config": config, "learner": learner, "model": model})  # fmt: skip
    return found


def model_problem(model: Path, config: dict[str, Any]) -> str | None:
    """Why `model` (ROOT/train/<key>/model.pt) is not the model of the training `config` (a TrainConfig dict, its
    record's), in words naming the file, or None: its folder is a link into the model store that leads elsewhere
    (model_store.link_problem), or the model file records another training than that (config.first_difference:
    another learner's model copied in). A model file that cannot be read is left to the command that drives it,
    which says so in its own line."""
    from coopsumo.agents.model_file import ModelFileError, load_model
    from coopsumo.config import first_difference
    from coopsumo.studies.engine.model_store import link_problem

    if (problem := link_problem(model.parent, config)) is not None:
        return f"{model.parent} {problem}"
    try:
        _, meta = load_model(model)
    except ModelFileError:
        return None
    if (where := first_difference(meta.get("config"), config)) is not None:
        return f"{model} was made by another training than its record's ({where}; swapped in?)"
    return None


def root_problem(root: Path) -> str | None:
    """Why the folder `root` is not taken for a learning study's (a line), or None: a marker that names another
    command or study than `coopsumo learning` (run_markers.LEARNING_KIND: a scenario II or scenario I study, a
    training), one that cannot be read, or, a folder written before markers, another study's plan file in it (a
    scenario II sweep's sweep.json, a plan.json). Issue 82, probe 6, H2: a scenario II study taken for one was read
    as a learning study, and the study that read it was written into its folder."""
    from coopsumo.run_markers import LEARNING_KIND, RUN_MARKER, kind_name, marker_kind
    from coopsumo.studies.engine.run_folders import STUDY_OUTPUTS

    advice = "give the --out of `coopsumo learning`"
    if (kind := marker_kind(root)) is not None:
        if kind == LEARNING_KIND:
            return None
        what = f"the folder of a coopsumo {kind} run" if kind in ("simulate", "train") else \
            f"a coopsumo {kind_name(kind)} study's folder"  # fmt: skip
        return f"{root} is {what}, not a learning study's: {advice}"
    if os.path.lexists(root / RUN_MARKER):
        return f"{root} has a {RUN_MARKER} that names no command (damaged?), so it is not told for a learning study; " \
            f"{advice}"  # fmt: skip
    own = STUDY_OUTPUTS[LEARNING_KIND][0]
    for other in sorted({outputs[0] for outputs in STUDY_OUTPUTS.values()} - {own}):
        if (root / other).exists():
            return f"{root} holds {other}, another study's plan file, not a learning study's {own}: {advice}"
    return None
