"""`coopsumo models` (the command; the store itself is model_store's): what a model store holds, one row per stored
model, whether a study would use it and, when it
would not, why: the file and the field (issue 82, probe 13, F18: "not usable: trained again when a study asks for
it" named neither), and the store's own problem, which every study refuses it for (model_store.store_problem: a
user's file in it was listed "4 usable")."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from coopsumo.errors import why_unreadable
from coopsumo.files import read_json
from coopsumo.paths import STORE_ENV
from coopsumo.record_schemas import STORE_CONFIG
from coopsumo.studies.engine.model_store import foreign_entry, model_id, store_problem


def listing(store: Path) -> list[dict[str, Any]]:
    """One row per stored model folder: its name, preset, alpha, training seed, steps, whether it is whole and
    its own (trainings.finished_training against its recorded configuration and name), and the step model.pt
    was chosen at."""
    from coopsumo.studies.engine.trainings import finished_training

    rows = []
    for folder in sorted(p for p in store.iterdir() if p.is_dir() and not p.name.startswith(".")):
        row: dict[str, Any] = {"model": folder.name, "preset": "-", "alpha": "-", "seed": "-", "steps": "-",
                               "state": "unfinished", "selected_step": "-"}  # fmt: skip
        if folder.is_symlink():  # every study refuses the store for it (model_store.store_problem)
            row["state"] = f"not usable: a link to {folder.resolve()}, where the store keeps only its own folders"
            rows.append(row)
            continue
        try:
            recorded = read_json(folder / "config.json")
        except FileNotFoundError:  # probe 15: a training's first moments were listed as an unreadable file
            row["state"] = "unfinished: no config.json yet (being trained, or stopped before it was written)"
            rows.append(row)
            continue
        except (OSError, ValueError) as err:
            row["state"] = f"no readable config.json ({why_unreadable(err)})"
            rows.append(row)
            continue
        if (problem := STORE_CONFIG.problem(recorded)) is not None:  # what names the folder, inside its limits
            row["state"] = f"not usable: config.json {problem}"
            rows.append(row)
            continue
        config = recorded["config"]
        sim, dqn = config["sim"], config["dqn"]
        row.update(preset=dqn["preset"], seed=sim["seed"], steps=sim["steps"],
                   alpha="conditioned" if dqn.get("alpha_conditioned") else sim["reward"]["alpha"])  # fmt: skip
        if model_id(config) != folder.name:
            row["state"] = "config.json is not this folder's identity (edited?)"
        elif (problem := foreign_entry(folder)) is not None:  # every study refuses it (check_entry)
            row["state"] = f"not usable: {problem} (move it away)"
        elif (summary := finished_training(folder, config, quiet=True)) is not None:
            row["state"] = "ok"
            row["selected_step"] = summary.get("selected_step", "-")
        elif (folder / "model.pt").exists():
            row["state"] = f"not usable: {unusable_reason(folder, config)}; trained again when a study asks for it"
        rows.append(row)
    return rows


def unusable_reason(folder: Path, config: dict[str, Any]) -> str:
    """Why a stored model folder holding a model.pt is not a finished training a study uses, naming the file and what
    is wrong with it, as trainings.finished_training judges it: its marker, config.json or train_summary.json that
    cannot be read or is not a finished training's, its model.pt (trainings.model_folder_problem), its summary or
    logs (_summary_problem)."""
    from coopsumo.run_dirs import RUN_MARKER, listed_files
    from coopsumo.studies.engine.trainings import model_folder_problem

    read: dict[str, Any] = {}
    for name in (RUN_MARKER, "config.json", "train_summary.json"):
        try:
            read[name] = read_json(folder / name)
        except (OSError, ValueError) as err:
            return f"its {name} cannot be read ({why_unreadable(err)})"
    marker, summary = read[RUN_MARKER], read["train_summary.json"]
    if not isinstance(marker, dict) or marker.get("kind") != "train":
        return f"its {RUN_MARKER} is {_shown(marker)}, not a training's marker"
    if (listed := listed_files(marker)) is None or "model.pt" not in listed:
        files = _shown(marker.get("files"))
        return f"its {RUN_MARKER} does not list model.pt as a finished training's file (files: {files})"
    if not isinstance(summary, dict):
        return f"its train_summary.json is {_shown(summary)}, not a JSON object"
    if (problem := model_folder_problem(folder)) is not None:
        return f"its model.pt {problem}"
    return _summary_problem(folder, config) or "it is not the training its name says (config.json, model.pt)"


def _shown(value: Any) -> str:
    """A JSON value in a few characters (a 5,000-digit integer: its first digits)."""
    import json

    text = json.dumps(value) if not isinstance(value, int) or abs(value) < 10**40 else f"{str(value)[:20]}..."
    return text if len(text) <= 40 else text[:37] + "..."


def _summary_problem(folder: Path, config: dict[str, Any]) -> str | None:
    """Why a stored model's train_summary.json or one of its logs keeps it from use (trainings.train_summary_problem:
    a value no run gives, a selected step outside its training; trainings.logs_problem: a train_log.csv or
    validation.csv that cannot be read back), or None (another reason, or none readable)."""
    from coopsumo.studies.engine.trainings import logs_problem, train_summary_problem

    try:
        summary = read_json(folder / "train_summary.json")
    except (OSError, ValueError):
        return None
    if not isinstance(summary, dict):
        return None
    if (problem := train_summary_problem(summary, config)) is not None:
        return problem
    found = logs_problem(folder, config, summary)
    return f"{found[0]} {found[1]}" if found is not None else None


def print_store(store: Path, rows: list[dict[str, Any]]) -> None:
    """The store's table and its last line: how many models it holds and how many a study uses: none when the store
    itself is one every study refuses (model_store.store_problem: a user's file, a link named like a model)."""
    keys = ("model", "preset", "alpha", "seed", "steps", "selected_step", "state")
    widths = {k: max([len(k)] + [len(str(r[k])) for r in rows]) for k in keys}
    print("  ".join(k.ljust(widths[k]) for k in keys))
    for r in rows:
        print("  ".join(str(r[k]).ljust(widths[k]) for k in keys))
    if (problem := store_problem(store)) is not None:
        print(f"{len(rows)} models in {store}, none usable: the store {problem}, and every study refuses it; move "
              "that away")  # fmt: skip
        return
    usable = sum(r["state"] == "ok" for r in rows)
    print(f"{len(rows)} models in {store}, {usable} usable")


# -- the command ------------------------------------------------------------------------------------------
STORE_FOLDER = "models"
"""the name of a model store's folder (store_for: beside a study's results folder)"""
SEARCH_DEPTH = 3
"""`coopsumo models` without --store looks for stores this many folders down from the current one"""


def is_store(folder: Path) -> bool:
    """True when `folder` holds a stored model (a folder named as model_id names one, owners.STORE_NAME)."""
    from coopsumo.owners import STORE_NAME

    try:
        return any(STORE_NAME.fullmatch(p.name) and p.is_dir() for p in folder.iterdir())
    except OSError:
        return False


def found_stores(base: Path, depth: int = SEARCH_DEPTH) -> list[Path]:
    """Every model store under `base`, relative to it: the folders named `models` at most `depth` folders down that
    hold a stored model (hidden folders, the virtualenv's and stores' insides not searched), in name order."""
    found, level = [], [base]
    for _ in range(depth):
        below = []
        for folder in level:
            try:
                entries = sorted(p for p in folder.iterdir() if p.is_dir() and not p.is_symlink()
                                 and not p.name.startswith(".") and p.name not in ("venv", "node_modules"))  # fmt: skip
            except OSError:
                continue
            for entry in entries:
                if entry.name == STORE_FOLDER and is_store(entry):
                    found.append(entry.relative_to(base))
                else:
                    below.append(entry)
        level = below
    return sorted(found)


def _store_path(text: str) -> Path:
    """--store's value: a folder's path, not empty (Path("") is the working folder, which was listed as a store)."""
    import argparse

    if not text.strip():
        raise argparse.ArgumentTypeError("is empty: name the store's folder")
    return Path(text)


def build_parser() -> Any:
    from coopsumo.runio import Parser

    p = Parser(prog="coopsumo models", description="List the model stores: every trained model, by the training "
               "that made it, and whether a study would use it.")  # fmt: skip
    p.add_argument("--store", type=_store_path, default=None,
                   help=f"one store (default: ${STORE_ENV} if set, else results/models and every other store found "
                        f"up to {SEARCH_DEPTH} folders below the current one: a study's is `models` beside its --out, "
                        "which it names)")  # fmt: skip
    return p


def _first_folder(folder: Path) -> Path | None:
    """The first folder in `folder` that `listing` would list as a model (not hidden), or None."""
    return next(iter(sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))), None)


def _stores(given: Path | None) -> list[Path]:
    """The stores `coopsumo models` lists: --store; else $COOPSUMO_MODELS; else results/models and every store found
    below the current folder."""
    from coopsumo.errors import UsageError

    if given is not None:
        if not given.exists():  # a folder named by hand: a typo is not an empty store
            raise UsageError(f"--store {given}: no such folder (a study makes it when it trains its first model)")
        if not given.is_dir():
            raise UsageError(f"--store {given}: not a folder")
        if not is_store(given) and (first := _first_folder(given)) is not None:  # /proc, a study's folder (probe 7)
            raise UsageError(f"--store {given}: not a model store: none of its folders ({first.name}, ...) is a "
                             "stored model's (named <preset>_a<alpha>_seed<seed>_<digest>)")  # fmt: skip
        return [given]
    if os.environ.get(STORE_ENV):
        return [Path(os.environ[STORE_ENV])]
    return list(dict.fromkeys([Path("results/models"), *found_stores(Path("."))]))


def main(argv: list[str] | None = None) -> int:
    from coopsumo.errors import UsageError
    from coopsumo.runio import run_cli

    args = build_parser().parse_args(argv)

    def body() -> int:
        stores = _stores(args.store)
        listed = 0
        for store in stores:
            if store.exists() and not store.is_dir():
                raise UsageError(f"--store {store}: not a folder")
            rows = listing(store) if store.is_dir() else []
            if rows:
                if listed:
                    print()
                print_store(store, rows)
                listed += 1
        if not listed:
            print(f"no models yet in {stores[0]}: the studies (scenario1, scenario2, protocol) train into "
                  "`models` beside their --out (or $COOPSUMO_MODELS) and say where")  # fmt: skip
        return 0

    return run_cli("models", body)
