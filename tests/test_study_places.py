"""Issue 82, fifth probe (G1, G2, G3, G5): where a study may write. Its root never lies in the model store, in a
single run's folder (a training's, a simulate run's) or in another study's folder (run_dirs.check_study_place, the
same check as a single run's --out: owners.owned_problem); the model store never lies in a folder a marker claims
(owners.claimed_problem: $COOPSUMO_MODELS before any command starts, the store beside a study's root before the study
does); a study root whose study cannot be told is taken for no study (run_dirs.check_study_root). Every refusal: one
line, exit code 2, nothing written."""

from __future__ import annotations

import importlib
import json
from pathlib import Path

import pytest

from coopsumo.errors import UsageError
from coopsumo.run_dirs import RUN_MARKER, check_study_place, check_study_root, mark_run_dir, study_root
from coopsumo.studies.engine.run_folders import STUDY_OUTPUTS
from coopsumo.studies.scenario2.redraw import recorded_sweep

MODEL = "default_a0_seed100_0123456789ab"
"""a folder name of a model in the store (owners.STORE_NAME)"""
OWN = (*STUDY_OUTPUTS["scenario2"], "*.tmp")
"""the names a scenario II sweep writes at the top of its root (run_folders.study_root's)"""
TINY_SWEEP = "the tiny profile's sweep"
"""the study `scenario2 --profile tiny` writes (redraw.sweep_study)"""


def run(command: str, argv: list[str]) -> int:
    """`coopsumo COMMAND ARGV` in this process: its exit code (argparse's too)."""
    from coopsumo.cli import COMMANDS

    try:
        return int(importlib.import_module(COMMANDS[command][0]).main(argv))
    except SystemExit as stop:
        return int(stop.code or 0)


def listing(folder: Path) -> dict[str, tuple[int, int]]:
    """Every entry under folder with its size and modification time: equal before and after, nothing was written."""
    return {p.relative_to(folder).as_posix(): (p.lstat().st_size, p.lstat().st_mtime_ns) for p in folder.rglob("*")}


def one_line(capsys: pytest.CaptureFixture[str], code: int, *fragments: str) -> str:
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert "Traceback" not in err and ": error: " in lines[0] and all(f in lines[0] for f in fragments), err
    return lines[0]


def owned_folders(tmp_path: Path) -> dict[str, Path]:
    """The folders a study's root may not go into: the model store ($COOPSUMO_MODELS, holding a model), an
    interrupted training's folder, a finished simulate run's folder, another study's root."""
    store = tmp_path / "store"
    (store / MODEL).mkdir(parents=True)
    mark_run_dir(store / MODEL, "train")
    training, sim, other = tmp_path / "ck", tmp_path / "sim", tmp_path / "s2"
    for folder in (training, sim, other):
        folder.mkdir()
    (training / "checkpoint.pt").write_bytes(b"weights")
    mark_run_dir(training, "train", finished=False)  # as train leaves it when interrupted
    (sim / "summary.json").write_text("{}\n")
    mark_run_dir(sim, "simulate")
    (other / "cells").mkdir()
    mark_run_dir(other, "scenario2", finished=False, study=TINY_SWEEP)
    return {"store": store, "training": training, "simulate": sim, "study": other}


PLACES = {"store": "is in the model store", "training": "the folder of a coopsumo train run",
          "simulate": "the folder of a coopsumo simulate run",
          "study": "a coopsumo scenario2 study's folder"}  # fmt: skip
"""where the study's --out goes (inside owned_folders' folder), and what its refusal says"""
STUDY_COMMANDS: dict[str, tuple[str, list[str]]] = {
    "scenario1": ("scenario1", ["--quick"]),
    "scenario1 --regime-map": ("scenario1", ["--regime-map", "--seeds", "1"]),
    "scenario1 --merge": ("scenario1", ["--merge", "parts/a,parts/b"]),
    "scenario2": ("scenario2", ["--profile", "tiny"]),
    "scenario2 --merge": ("scenario2", ["--merge", "parts/L4a,parts/L4b"]),
    "protocol": ("protocol", ["--profile", "tiny"]),
}  # fmt: skip
"""every study command with arguments that would run it from the test's folder (the merges: of parts in parts/)"""
CASES = [(command, place) for command in STUDY_COMMANDS for place in PLACES]


@pytest.mark.parametrize(("command", "place"), CASES, ids=[f"{c}-{p}" for c, p in CASES])
def test_a_study_never_goes_inside_the_store_a_run_or_another_study(command: str, place: str, tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """G1: `scenario2 --out STORE/s2x` wrote its marker, plan and cells into the model store before the store check
    refused it, and every study then refused the store; G2: `scenario2 --out ck/s2` (an interrupted training's
    folder), `--out sim/s2`, `learning --out s2/evals/l` (a study since retired) were run, and that folder's own
    command then refused it.
    Every study command refuses such an --out as `simulate` and `train` do, in one line, before anything is
    written (no lock file, no marker, no model store)."""
    from conftest import made_by
    from test_scenario2_merge import copy_part

    from coopsumo.dqn_config import DQN_PRESETS
    from coopsumo.studies.protocol.plan import variants

    if "scenario2" in made_by():  # the committed parts' learner, as test_scenario2_merge merges them
        monkeypatch.setitem(DQN_PRESETS, "default", variants()[made_by()["scenario2"][0]].learner)
    monkeypatch.chdir(tmp_path)
    for name in ("L4a", "L4b"):
        copy_part(name, tmp_path / "parts")
    folders = owned_folders(tmp_path)
    monkeypatch.setenv("COOPSUMO_MODELS", str(folders["store"]))
    out = folders[place] / "evals" / "mine"
    prog, argv = STUDY_COMMANDS[command]
    before = listing(tmp_path)
    one_line(capsys, run(prog, [*argv, "--quiet", "--out", str(out)]), f"--out {out}", PLACES[place],
             "pick another --out")  # fmt: skip
    assert listing(tmp_path) == before


def test_a_study_may_go_beside_the_store_and_resume_its_own_root(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """What the place check leaves alone: a root beside the store and the other runs (its models stored beside it),
    the study's own root again (same study), and its own folders under it."""
    folders = owned_folders(tmp_path)
    monkeypatch.setenv("COOPSUMO_MODELS", str(folders["store"]))
    for root in (tmp_path / "mine", folders["study"], tmp_path / "new" / "deeper"):
        check_study_place(root)
    check_study_root(folders["study"], "scenario2", OWN, TINY_SWEEP, recorded_sweep)
    with study_root(folders["study"], "scenario2", OWN, TINY_SWEEP, recorded_sweep) as root:
        (root / "train").mkdir()
        (root / "train" / "L2_a0_s1").symlink_to(folders["store"] / MODEL, target_is_directory=True)
    check_study_root(folders["study"], "scenario2", OWN, TINY_SWEEP, recorded_sweep)
    with pytest.raises(UsageError, match="is in the model store"):  # through its model link, links resolved
        check_study_place(folders["study"] / "train" / "L2_a0_s1" / "mine")
    with pytest.raises(UsageError, match="a coopsumo scenario2 study's folder"):
        check_study_place(folders["study"] / "cells" / "mine")


# -- G3: the model store in a folder a marker claims ------------------------------------------------------------------
ENV_COMMANDS = {"simulate": ["--steps", "20", "--quiet"], "train": ["--steps", "20", "--eval-steps", "0", "--quiet"],
                "scenario2": ["--profile", "tiny", "--quiet"], "protocol": ["--profile", "tiny", "--quiet"],
                "models": []}  # fmt: skip
"""commands that start after the environment's folders are checked (runio.run_cli), with arguments that would run"""
STORE_CASES = [(command, place) for command in ENV_COMMANDS for place in ("training", "simulate", "study")]


@pytest.mark.parametrize(("command", "place"), STORE_CASES, ids=[f"{c}-{p}" for c, p in STORE_CASES])
def test_the_model_store_variable_never_names_a_folder_a_marker_claims(command: str, place: str, tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch,
                                                                        capsys: pytest.CaptureFixture[str]) -> None:
    """G3: `COOPSUMO_MODELS=ck/store scenario2 ...` trained into an interrupted training's folder (and into a simulate
    run's), whose command then refused it. $COOPSUMO_MODELS inside, or naming, a folder a marker claims is refused
    before any command starts, as $COOPSUMO_NETS_DIR there is: one line naming the variable and the folder."""
    monkeypatch.chdir(tmp_path)
    folders = owned_folders(tmp_path)
    before = listing(tmp_path)
    for store in (folders[place] / "store", folders[place]):
        monkeypatch.setenv("COOPSUMO_MODELS", str(store))
        out = [] if command == "models" else ["--out", str(tmp_path / "out")]
        line = one_line(capsys, run(command, [*ENV_COMMANDS[command], *out]), f"$COOPSUMO_MODELS {str(store)!r}",
                        "pick a model store elsewhere")  # fmt: skip
        assert str(folders[place].resolve()) in line and PLACES[place] in line
    assert listing(tmp_path) == before


def test_the_store_beside_a_study_never_lies_in_a_folder_a_marker_claims(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch,
                                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """The default store, `models` beside the study's root, that is a training's folder (`train --out models`
    interrupted before its first file: only its marker, which the store's own check passed as a dot-file) is
    refused before the study writes anything, naming the store and where it comes from."""
    from coopsumo.studies.engine.model_store import store_for

    monkeypatch.delenv("COOPSUMO_MODELS", raising=False)
    (tmp_path / "models").mkdir()
    mark_run_dir(tmp_path / "models", "train", finished=False)
    with pytest.raises(UsageError, match=f"model store {tmp_path / 'models'} \\(beside .*s2\\) is .*train run"):
        store_for(tmp_path / "s2")
    before = listing(tmp_path)
    one_line(capsys, run("scenario2", ["--profile", "tiny", "--quiet", "--out", str(tmp_path / "s2")]),
             f"the model store {tmp_path / 'models'}", "the folder of a coopsumo train run")  # fmt: skip
    assert listing(tmp_path) == before


# -- G5: a study root whose study cannot be told ------------------------------------------------------------------
def untold_root(root: Path, marker: str, plan: str) -> None:
    """A sweep root of the tiny profile's default learner (cells/, report.md) with its marker ("named": naming its
    study, "unnamed": naming none, as markers before issue 82, "none") and its sweep.json ("ok", "preset list": a
    preset that is not a text, "cut": cut at 30 bytes, "none")."""
    (root / "cells").mkdir(parents=True)
    (root / "cells" / "L2_T4_a0_s1.json").write_text('{"status": "ok"}\n')
    (root / "report.md").write_text("# the default learner's sweep\n")
    if marker != "none":
        mark_run_dir(root, "scenario2", finished=False, study=TINY_SWEEP if marker == "named" else None)
    sweep = json.dumps({"profile": {"name": "tiny", "preset": ["paper"] if plan == "preset list" else "default"}})
    if plan != "none":
        (root / "sweep.json").write_text(sweep[:30] if plan == "cut" else sweep)


UNTOLD = [("unnamed", "preset list"), ("unnamed", "cut"), ("none", "cut"), ("none", "preset list"),
          ("unnamed", "none")]  # fmt: skip
"""(marker, plan file) of a root whose study cannot be told"""


@pytest.mark.parametrize(("marker", "plan"), UNTOLD, ids=[f"marker {m}, plan {p}" for m, p in UNTOLD])
@pytest.mark.parametrize("preset", ["paper", "default"])
def test_a_study_root_whose_study_cannot_be_told_is_taken_for_none(marker: str, plan: str, preset: str,
                                                                   tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """G5: a sweep whose marker names no study and whose sweep.json cannot be read (cut, edited: a preset that is not
    a text) was taken for any study: `scenario2 --preset paper` replaced the default learner's cells. Such a root is
    refused to every study, its own too (which it is cannot be told), in one line, nothing changed."""
    root = tmp_path / "s2"
    untold_root(root, marker, plan)
    before = listing(tmp_path)
    line = one_line(capsys, run("scenario2", ["--profile", "tiny", "--preset", preset, "--quiet", "--out", str(root)]),
                    f"cannot tell which study output folder {root} holds", "remove it yourself or pick another --out")
    assert (f"its {RUN_MARKER} names none" if marker == "unnamed" else f"it has no {RUN_MARKER}") in line
    assert ("it has no sweep.json" if plan == "none" else "its sweep.json cannot be read as one") in line
    assert listing(tmp_path) == before


@pytest.mark.parametrize(("marker", "plan"), [("named", "none"), ("named", "cut"), ("none", "ok"), ("unnamed", "ok")])
def test_a_study_root_that_can_be_told_or_is_fresh_is_taken(marker: str, plan: str, tmp_path: Path) -> None:
    """What G5's refusal leaves alone: a root whose marker names its study (a first run interrupted before its plan
    file: study_root marks the root before anything else), one whose plan file says (written before markers named
    a study), and one that nothing claims (no marker, no plan file: an empty one, one with only the temporary file of
    the marker's write, killed; a folder of the study's own names is not one since probe 7, I5)."""
    root = tmp_path / "s2"
    untold_root(root, marker, plan)
    check_study_root(root, "scenario2", OWN, TINY_SWEEP, recorded_sweep)
    for fresh in (tmp_path / "empty", tmp_path / "tmp_only"):
        fresh.mkdir()
    (tmp_path / "tmp_only" / f".{RUN_MARKER}.a1b2c3d4.tmp").write_text('{\n  "fi')  # a killed marking
    for fresh in (tmp_path / "empty", tmp_path / "tmp_only", tmp_path / "missing"):
        check_study_root(fresh, "scenario2", OWN, TINY_SWEEP, recorded_sweep)


def test_a_root_without_a_study_name_stays_open_to_commands_that_name_none(tmp_path: Path) -> None:
    """The studies that do not name theirs (the regime map, the retired accident-seeds: their markers never hold one)
    are not refused for it."""
    root = tmp_path / "acc"
    root.mkdir()
    mark_run_dir(root, "accident_seeds", finished=False)
    check_study_root(root, "accident_seeds", ("plan.json", "cells"))
    with study_root(root, "accident_seeds", ("plan.json", "cells")):
        pass
    assert "study" not in json.loads((root / RUN_MARKER).read_text())
