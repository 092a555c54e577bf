"""What a training writes into its folder, at every depth: the one rule by which a training folder (train's --out, a
model's folder in the model store) is judged its training's own before a training writes into it, resumes in it or
starts it over. Anything else there is a user's, and so is every link (a training makes none: through one it would
write into, or delete, the folder it leads to). Issue 82, probe 8, J4-J6: a user's snapshots/step100/notes.txt was
deleted by a retrain and listed by a resume as the training's own, and a link sumo -> . had SUMO write into the root.
Torch-free: train's checks run before torch loads.
"""

from __future__ import annotations

import fnmatch
import os
import re
from collections.abc import Sequence
from pathlib import Path

from coopsumo.files import TEMPORARY
from coopsumo.run_dirs import RUN_OUTPUTS

Tree = dict[str, "Tree | None"]
"""a folder's rule: a regular expression an entry's name must match in full -> the rule of that entry's contents
when it is a folder, None when it is a file"""

RUN_FOLDER: Tree = {fnmatch.translate(pattern): None for pattern in RUN_OUTPUTS}
"""a run's folder (sumo/, eval/, a validation run's): the files a run writes (run_dirs.RUN_OUTPUTS)"""
TRAIN_FILES = (".coopsumo-run.json", "config.json", "checkpoint.pt", "train_log.csv", "model.pt", "model_last.pt",
               "train_summary.json", "summary.json", "validation.csv")
"""the files a training writes at the top of its folder"""


def files_rule(names: Sequence[str]) -> str:
    """The rule (a regular expression) of the files `names` and of the temporary files a write of one of them leaves
    when a kill cuts it short ('.NAME.XXXXXXXX.tmp', files.write_atomic; files.left_temporaries finds them): a
    user's 'notes.tmp' is neither (issue 82, probe 8, J22: a resume deleted every '*.tmp' in the folder)."""
    names_rule = "|".join(re.escape(name) for name in names)
    return rf"(?:{names_rule})|\.(?:{names_rule})\.[A-Za-z0-9_]{{8}}{re.escape(TEMPORARY)}"


SNAPSHOT: Tree = {files_rule(("model.pt", "request.json", "validation.json", "screen.json")): None,
                  r"\.run\d+\..+": RUN_FOLDER}  # fmt: skip
"""a snapshot's folder (agents/snapshots.py): its weights, validation request and results, the temporary files of
a write and the runs of a validation a kill cut short (selection.validate)"""
TRAIN_TREE: Tree = {
    files_rule(TRAIN_FILES): None,
    r"sumo|eval": RUN_FOLDER,
    r"tensorboard": {r"events\.out\.tfevents\..+": None},
    r"snapshots": {r"step[0-9]+": SNAPSHOT},
}
"""what a training writes into its folder (the temporary file of a write a kill cut short included)"""


def foreign_entry(folder: Path, also: Sequence[str] = ()) -> str | None:
    """Why the training folder `folder` holds what no training writes (a phrase naming the entry by its path in the
    folder), or None: an entry at any depth that TRAIN_TREE does not name (a file where a training makes a folder,
    or the reverse, too), or a link anywhere, and where it leads, or a file with a second name (a hard link: issue 82,
    probe 9, a resume appended to a user's file hard-linked as train_log.csv). also: more file names a training of
    the caller writes at the top (the model store's group_cost.json). A training started over or resumed there would
    delete it, write through it, or list it in its finished marker as its own."""
    return _foreign(folder, {**TRAIN_TREE, **({files_rule(also): None} if also else {})}, "")


def _foreign(folder: Path, tree: Tree, prefix: str) -> str | None:
    """foreign_entry below `folder`, whose entries are named `prefix` + name."""
    try:
        entries = sorted(folder.iterdir())
    except OSError as err:
        return f"holds {prefix.rstrip('/') or folder}, which cannot be read ({err.strerror})"
    for entry in entries:
        name = prefix + entry.name
        if entry.is_symlink():
            return f"holds {name}, a link to {os.path.realpath(entry)}, which no training makes"
        rules = [inner for pattern, inner in tree.items() if re.fullmatch(pattern, entry.name)]
        if not rules or (rules[0] is None) == entry.is_dir():
            return f"holds {name}, which no training writes"
        if rules[0] is None and entry.lstat().st_nlink > 1:  # a hard link: written in place, the other name changes
            return f"holds {name}, a file with another name too (a hard link), which no training makes"
        if rules[0] is not None and (found := _foreign(entry, rules[0], f"{name}/")) is not None:
            return found
    return None
