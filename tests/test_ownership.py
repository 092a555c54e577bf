"""Issue 25: nothing a user owns is deleted by --out. An existing non-empty folder is replaced or written
into only if the same command wrote it (.coopsumo-run.json) and nothing was added; a run never writes into,
or replaces, the folder its model is read from. Every refusal: one line, exit code 2, every byte kept."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

from coopsumo import simulate
from coopsumo.agents import train_cli as train
from coopsumo.errors import UsageError
from coopsumo.run_dirs import RUN_MARKER, atomic_run_dir, mark_run_dir

SIM = ["--steps", "20", "--quiet"]


def snapshot(folder: Path) -> dict[str, str]:
    """Every entry under folder: a file's sha256, or 'dir'."""
    return {p.relative_to(folder).as_posix(): "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*"))}  # fmt: skip


def refused(capsys: pytest.CaptureFixture[str], code: int, *fragments: str) -> str:
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert "Traceback" not in err and all(f in lines[0] for f in fragments), err
    return lines[0]


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny training folder (model.pt, train_log.csv, eval/) written by the train command."""
    out = tmp_path_factory.mktemp("own") / "train"
    proc = subprocess.run([sys.executable, "-m", "coopsumo.train", "--steps", "200", "--eval-steps", "20", "--quiet",
                           "--out", str(out)], capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert {"model.pt", "train_log.csv", "eval", RUN_MARKER} <= {p.name for p in out.iterdir()}
    return out


@pytest.fixture(scope="module")
def simulated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("own") / "sim"
    assert simulate.main([*SIM, "--out", str(out)]) == 0
    return out


def test_the_training_folder_given_as_out_to_simulate_is_kept_byte_for_byte(trained: Path) -> None:
    """The user's report: simulate --policy dqn:D/model.pt --out D replaced D (model, log and eval gone)."""
    before = snapshot(trained.parent)
    proc = subprocess.run([sys.executable, "-m", "coopsumo.simulate", *SIM, "--policy", f"dqn:{trained / 'model.pt'}",
                           "--out", str(trained)], capture_output=True, text=True, timeout=300)  # fmt: skip
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "the model is read from" in lines[0] and proc.stdout == ""
    assert snapshot(trained.parent) == before


@pytest.mark.parametrize("where", ["parent", "inside"])
def test_simulate_never_writes_around_its_model(
    trained: Path, capsys: pytest.CaptureFixture[str], where: str
) -> None:
    out = trained.parent if where == "parent" else trained / "sim"
    before = snapshot(trained.parent)
    code = simulate.main([*SIM, "--policy", f"dqn:{trained / 'model.pt'}", "--out", str(out)])
    refused(capsys, code, "--out", "the model is read from")
    assert snapshot(trained.parent) == before


def test_simulate_refuses_a_training_folder(trained: Path, capsys: pytest.CaptureFixture[str]) -> None:
    before = snapshot(trained)
    refused(capsys, simulate.main([*SIM, "--out", str(trained)]), str(trained), "train run, not a simulate run")
    assert snapshot(trained) == before


def test_train_refuses_a_simulate_folder(simulated: Path, capsys: pytest.CaptureFixture[str]) -> None:
    before = snapshot(simulated)
    code = train.main(["--steps", "20", "--eval-steps", "0", "--quiet", "--out", str(simulated)])
    refused(capsys, code, str(simulated), "simulate run, not a train run")
    code = train.main(["--resume", "--quiet", "--out", str(simulated)])
    refused(capsys, code, str(simulated), "simulate run, not a train run")
    assert snapshot(simulated) == before


def test_train_refuses_a_study_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    study = tmp_path / "study"
    (study / "cells").mkdir(parents=True)
    (study / "cells" / "c1.json").write_text('{"ok": true}\n')
    (study / "summary.json").write_text("{}\n")
    before = snapshot(tmp_path)
    code = train.main(["--steps", "20", "--eval-steps", "0", "--quiet", "--out", str(study)])
    refused(capsys, code, str(study), "not a coopsumo run folder")
    assert snapshot(tmp_path) == before


def test_simulate_refuses_a_link_out_of_its_own_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The probe's (2026-12-02): a listed file of simulate's own folder replaced by a link to a user's file was not
    refused (train refuses it); the rerun replaced the link. Now one line, and the user's file is kept."""
    out, mine = tmp_path / "s1", tmp_path / "user" / "notes.txt"
    assert simulate.main([*SIM, "--out", str(out)]) == 0
    mine.parent.mkdir()
    mine.write_text("my notes\n")
    (out / "summary.json").unlink()
    (out / "summary.json").symlink_to(mine)
    before = snapshot(tmp_path)
    refused(capsys, simulate.main([*SIM, "--out", str(out)]), f"{out / 'summary.json'} is a link to {mine}")
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("command", ["simulate", "train"])
def test_a_study_s_run_folder_is_the_study_s(tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str) -> None:
    """The probe's (2026-12-02): simulate --out into a scenario I study's run folder replaced it (a simulate folder
    by its marker); a run folder anywhere inside a marked study root is now refused, as is a training there."""
    root = tmp_path / "study"
    run = root / "runs" / "t2" / "keep_seed1"
    assert simulate.main([*SIM, "--out", str(run)]) == 0  # as the study's cell wrote it, before the root was marked
    mark_run_dir(root, "scenario1", finished=False, study="the default profile's study")
    before = snapshot(tmp_path)
    for out in (run, root / "runs" / "t2" / "new_run"):
        if command == "simulate":
            code = simulate.main([*SIM, "--out", str(out)])
        else:
            code = train.main(["--steps", "20", "--eval-steps", "0", "--quiet", "--out", str(out)])
        refused(capsys, code, f"--out {out} lies inside {root.resolve()}, a coopsumo scenario1 study's folder")
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("command", ["simulate", "train"])
def test_a_config_json_beside_foreign_files_is_not_a_run_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str
) -> None:
    """Before: any folder holding a config.json was replaced; a run of an older coopsumo is refused too."""
    out = tmp_path / "mine"
    out.mkdir()
    (out / "config.json").write_text('{"config": {}}\n')
    (out / "notes.txt").write_text("keep me\n")
    (out / "summary.json").write_text("{}\n")
    before = snapshot(tmp_path)
    if command == "simulate":
        code = simulate.main([*SIM, "--out", str(out)])
    else:
        code = train.main(["--steps", "20", "--eval-steps", "0", "--quiet", "--out", str(out)])
    refused(capsys, code, str(out), RUN_MARKER, "remove it yourself or pick another --out")
    assert snapshot(tmp_path) == before


def test_a_file_added_to_a_simulate_folder_keeps_it_from_being_replaced(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    assert simulate.main([*SIM, "--out", str(out)]) == 0
    (out / "notes.txt").write_text("my notes\n")
    before = snapshot(tmp_path)
    refused(capsys, simulate.main([*SIM, "--out", str(out)]), str(out), "notes.txt", "did not write")
    assert snapshot(tmp_path) == before


def test_a_run_marked_unfinished_that_lists_its_files_is_redone(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 82 (probe 3, F9): a simulate folder whose marker says "finished": false was refused as a marker that
    "lists no files", though it listed them, and scenario I failed on every rerun. Its listed files are its own: it
    is run again; with a file added, or with no list, it is left alone, saying which."""
    out = tmp_path / "run"
    assert simulate.main([*SIM, "--out", str(out)]) == 0
    marker = json.loads((out / RUN_MARKER).read_text())
    (out / RUN_MARKER).write_text(json.dumps({**marker, "finished": False}))
    assert simulate.main(["--steps", "30", "--quiet", "--out", str(out)]) == 0
    assert json.loads((out / "summary.json").read_text())["steps"] == 30
    assert json.loads((out / RUN_MARKER).read_text())["finished"] is True
    (out / RUN_MARKER).write_text(json.dumps({**marker, "finished": False}))
    (out / "notes.txt").write_text("my notes\n")
    before = snapshot(tmp_path)
    refused(capsys, simulate.main([*SIM, "--out", str(out)]), str(out), "notes.txt", "did not write")
    (out / "notes.txt").unlink()
    (out / RUN_MARKER).write_text(json.dumps({"kind": "simulate", "finished": False}))
    before = snapshot(tmp_path)
    refused(capsys, simulate.main([*SIM, "--out", str(out)]), str(out), "says its run did not finish and lists no "
            "files")  # fmt: skip
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize(("text", "fragment"), [("x", "is not readable JSON (damaged)"),
                                                ("[1]", "is not a JSON object"), ('{"kind": 7}', "names no command")])
def test_a_damaged_marker_is_named_as_damaged_not_missing(
    text: str, fragment: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 82 (probe 3, F10): a training folder whose marker was not JSON was said to have no marker at all."""
    out = tmp_path / "train"
    out.mkdir()
    (out / "config.json").write_text("{}\n")
    (out / "checkpoint.pt").write_bytes(b"weights")
    (out / RUN_MARKER).write_text(text)
    before = snapshot(tmp_path)
    line = refused(capsys, train.main(["--resume", "--quiet", "--out", str(out)]), str(out), RUN_MARKER, fragment,
                   "left alone")  # fmt: skip
    assert "written before coopsumo marked" not in line
    assert snapshot(tmp_path) == before


def test_simulate_reruns_into_its_own_folder_and_into_an_empty_one(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()  # an empty existing folder is fine
    assert simulate.main([*SIM, "--out", str(out)]) == 0
    marker = json.loads((out / RUN_MARKER).read_text())
    assert marker["kind"] == "simulate" and {"config.json", "summary.json"} <= set(marker["files"])
    assert simulate.main(["--steps", "30", "--quiet", "--out", str(out)]) == 0
    assert json.loads((out / "summary.json").read_text())["steps"] == 30
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_finish_keeps_a_folder_that_gained_a_file_during_the_run(tmp_path: Path) -> None:
    """The replacement deletes nothing it did not write, even what appeared while the run was going."""
    out = tmp_path / "run"
    with atomic_run_dir(out) as tmp:
        (tmp / "summary.json").write_text("1\n")
    (out / "late.txt").write_text("added by hand\n")
    before = snapshot(tmp_path)
    with pytest.raises(UsageError, match="late.txt"), atomic_run_dir(out) as tmp:
        (tmp / "summary.json").write_text("2\n")
    assert snapshot(tmp_path) == before  # and no partial folder left beside it


# -- issue 82: a study's folder belongs to one study ----------------------------------------------------------------
STUDIES = {
    "scenario1": (["--quick"], "quick", "plan.json", {"plan": {"profile": "default"}}, "default"),
    "scenario2": (["--profile", "tiny"], "tiny", "sweep.json", {"profile": {"name": "full"}}, "full"),
    "protocol": (["--profile", "tiny"], "tiny", "study.json", {"profile": {"name": "nr10", "t_ups": [1.5]}}, "nr10"),
}
"""each study command: how to run a profile and its name, and the plan file of another profile's study, whose
profile it names"""
KINDS = {"scenario1": "scenario1", "scenario2": "scenario2", "protocol": "protocol"}
"""the kind each study command marks its folder with"""


def study_main(name: str, argv: list[str]) -> int:
    from coopsumo.studies.protocol import study as protocol
    from coopsumo.studies.scenario1 import study as scenario1
    from coopsumo.studies.scenario2 import study as scenario2

    mains = {"scenario1": scenario1.main, "scenario2": scenario2.main, "protocol": protocol.main}
    return mains[name](argv)


@pytest.mark.parametrize("marked", [False, True], ids=["written before markers named a study", "marked"])
@pytest.mark.parametrize("name", sorted(STUDIES))
def test_a_study_refuses_the_folder_of_another_profiles_study(name: str, marked: bool, tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """The probe's mg46: `scenario2 --profile tiny` replaced a merged 576-cell sweep with a 2-cell one (scenario I
    refused another profile's folder; the others did not). A folder marked before markers named a study is known by
    its plan file; a marked one by its marker, with or without the plan file."""
    from coopsumo.run_dirs import mark_run_dir

    argv, mine, plan_file, plan, other = STUDIES[name]
    root = tmp_path / "study"
    (root / "cells").mkdir(parents=True)
    (root / "report.md").write_text("# the other profile's report\n")
    if marked:
        mark_run_dir(root, KINDS[name], finished=False, study=f"the {other} profile's study")
    else:
        (root / plan_file).write_text(json.dumps(plan))
    before = snapshot(tmp_path)
    code = study_main(name, [*argv, "--out", str(root)])
    line = refused(capsys, code, str(root), f"holds the {other} profile's", f"not the {mine} profile's")
    assert "pick another --out" in line
    assert snapshot(tmp_path) == before


PRESET_STUDIES = {
    "scenario1": (["--quick"], "the quick profile's study", "plan.json",
                  {"plan": {"profile": "quick", "presets": ["default"]}}),
    "scenario2": (["--profile", "tiny"], "the tiny profile's sweep", "sweep.json",
                  {"profile": {"name": "tiny", "preset": "default"}}),
}  # fmt: skip
"""each study with learner presets: its profile's arguments, the default learner's study name, its plan file"""


@pytest.mark.parametrize("marked", [False, True], ids=["written before markers named a study", "marked"])
@pytest.mark.parametrize("name", sorted(PRESET_STUDIES))
def test_a_study_refuses_the_folder_of_another_learner_presets_study(name: str, marked: bool, tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 82, fourth probe (F7): `scenario2 --profile tiny --preset paper` into the default learner's tiny sweep
    replaced its cells and tables (scenario I's --preset likewise): the learner presets are part of which study a
    folder holds. Refused in one line naming both studies, before anything is written."""
    from coopsumo.run_dirs import mark_run_dir

    argv, study, plan_file, plan = PRESET_STUDIES[name]
    root = tmp_path / "study"
    (root / "cells").mkdir(parents=True)
    (root / "report.md").write_text("# the default learner's report\n")
    if marked:
        mark_run_dir(root, name, finished=False, study=study)
    else:
        (root / plan_file).write_text(json.dumps(plan))
    before = snapshot(tmp_path)
    code = study_main(name, [*argv, "--preset", "paper", "--out", str(root)])
    refused(capsys, code, str(root), f"holds {study}, not {study} (learner preset paper)")
    assert snapshot(tmp_path) == before


def test_a_folder_marked_before_the_preset_named_a_study_is_its_plans_learners(tmp_path: Path) -> None:
    """A marker written before the learner presets were part of a study's name ("the tiny profile's sweep") names
    the study its plan file records with those presets: the paper learner's sweep is taken for a paper rerun (and
    its marker named again), and refused to the default learner."""
    from coopsumo.run_dirs import check_study_root, held_study, mark_run_dir
    from coopsumo.studies.engine.run_folders import STUDY_OUTPUTS, profile_study, recorded_profile
    from coopsumo.studies.scenario2.redraw import recorded_sweep

    root = tmp_path / "study"
    (root / "cells").mkdir(parents=True)
    mark_run_dir(root, "scenario2", finished=False, study="the tiny profile's sweep")
    (root / "sweep.json").write_text(json.dumps({"profile": {"name": "tiny", "preset": "paper"}}))
    paper = profile_study("tiny", "sweep", ("paper",))
    assert held_study(root, recorded_sweep) == paper == "the tiny profile's sweep (learner preset paper)"
    check_study_root(root, "scenario2", STUDY_OUTPUTS["scenario2"], paper, recorded_sweep)
    with pytest.raises(UsageError, match=r"holds the tiny profile's sweep \(learner preset paper\), not the tiny"):
        check_study_root(root, "scenario2", STUDY_OUTPUTS["scenario2"], "the tiny profile's sweep", recorded_sweep)
    (root / "plan.json").write_text(json.dumps({"plan": {"profile": "full", "presets": ["default", "alpha_only"]}}))
    recorded = recorded_profile("plan.json", "plan", "profile", presets=("plan", "presets"))
    assert recorded(root) == "the full profile's study (learner presets default, alpha_only)"


def test_a_study_root_resumes_its_own_study_and_keeps_its_name(tmp_path: Path) -> None:
    """A rerun of the same profile into its own folder is taken (its finished cells are reused), and names the study
    in the marker; a later claim of the folder that names no study keeps the name."""
    from coopsumo.run_dirs import check_study_root, held_study
    from coopsumo.studies.engine.run_folders import profile_study, recorded_profile, study_root

    root = tmp_path / "study"
    (root / "cells").mkdir(parents=True)
    (root / "study.json").write_text(json.dumps({"profile": {"name": "nr10"}}))
    recorded = recorded_profile("study.json", "profile", "name")
    with study_root(root, "protocol", profile_study("nr10"), recorded):
        pass
    assert json.loads((root / RUN_MARKER).read_text())["study"] == "the nr10 profile's study"
    (root / "study.json").unlink()  # the marker names it now
    with pytest.raises(UsageError, match="holds the nr10 profile's study, not the tiny profile's study"):
        check_study_root(root, "protocol", ("study.json", "cells"), profile_study("tiny"), recorded)
    with study_root(root, "protocol"):
        pass
    assert held_study(root) == "the nr10 profile's study"


def test_a_study_refuses_a_run_folder_that_links_outside_it(tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """The probe's rl1b: scenario I's run folder runs/t2/greedy_seed1 made a link to a user's folder outside the
    study; the rerun replaced the user's folder through it. Refused as train refuses such links: one line naming the
    link, before anything is written; the user's folder is kept byte for byte."""
    root = tmp_path / "study"
    (root / "runs" / "t2").mkdir(parents=True)
    (root / "plan.json").write_text(json.dumps({"plan": {"profile": "quick"}}))
    user = tmp_path / "mine"
    user.mkdir()
    (user / "summary.json").write_text('{"mine": true}\n')
    (root / "runs" / "t2" / "greedy_seed1").symlink_to(user, target_is_directory=True)
    before = snapshot(tmp_path)
    code = study_main("scenario1", ["--quick", "--out", str(root)])
    refused(capsys, code, str(root / "runs" / "t2" / "greedy_seed1"), f"is a link to {user}", "remove the link")
    assert snapshot(tmp_path) == before


def test_a_study_refuses_a_run_folder_that_links_to_another_of_its_runs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 82, fourth probe (F6): scenario I's runs/t1/greedy_seed1 made a link to runs/t1/keep_seed1, inside the
    study; the rerun replaced the keep run with the greedy one through it (runs.csv then gave keep greedy's measures).
    A study makes no links but its model links: refused in one line naming the link, before anything is written."""
    root = tmp_path / "study"
    keep = root / "runs" / "t1" / "keep_seed1"
    keep.mkdir(parents=True)
    (keep / "config.json").write_text('{"policy": "keep"}\n')
    (root / "plan.json").write_text(json.dumps({"plan": {"profile": "quick"}}))
    (root / "runs" / "t1" / "greedy_seed1").symlink_to(keep, target_is_directory=True)
    before = snapshot(tmp_path)
    code = study_main("scenario1", ["--quick", "--out", str(root)])
    refused(capsys, code, str(root / "runs" / "t1" / "greedy_seed1"), f"is a link to {keep}", "inside the study's")
    assert snapshot(tmp_path) == before


def test_only_the_model_links_of_a_study_may_lead_outside_it(tmp_path: Path) -> None:
    """models/<name> and train/<key> are the study's links into the model store, which may lie anywhere; any other
    link out of the study (its cells/, an evaluation's folder) is refused, and since the fourth probe of issue 82
    (F6) one inside it too (test_a_study_refuses_a_run_folder_that_links_to_another_of_its_runs)."""
    from coopsumo.run_dirs import check_study_root, study_link

    store = tmp_path / "store" / "model_a"
    store.mkdir(parents=True)
    root = tmp_path / "study"
    for folder in ("models", "train", "evals", "cells"):
        (root / folder).mkdir(parents=True)
    (root / "models" / "alpha0_m100").symlink_to(store)
    (root / "train" / "L2_a0_s1").symlink_to(store)
    mark_run_dir(root, "scenario2", finished=False)  # its own root (unmarked without sweep.json: a user's, probe 7 I5)
    assert study_link(root) is None
    check_study_root(root, "scenario2", ("sweep.json", "models", "train", "evals", "cells"))
    (root / "evals" / "L2_T2_a0_s1").symlink_to(tmp_path / "store")
    assert study_link(root) == (root.resolve() / "evals" / "L2_T2_a0_s1", (tmp_path / "store").resolve())
    with pytest.raises(UsageError, match="L2_T2_a0_s1 is a link to"):
        check_study_root(root, "scenario2", ("sweep.json", "models", "train", "evals", "cells"))


def test_scenario2_refuses_a_user_file_where_a_model_link_belongs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The probe's s2f1: train/<key> replaced by a user's file failed its cell on every rerun without naming the file;
    refused before any cell, as scenario I refuses a real folder under models/, one line naming it, the file kept."""
    root = tmp_path / "study"
    (root / "train").mkdir(parents=True)
    (root / "train" / "L2_a8_s2").write_text("my notes\n")
    mark_run_dir(root, "scenario2", finished=False, study="the tiny profile's sweep")  # its own, interrupted
    code = study_main("scenario2", ["--profile", "tiny", "--quiet", "--out", str(root)])
    refused(capsys, code, str(root / "train" / "L2_a8_s2"), "is a file the study did not make")
    assert (root / "train" / "L2_a8_s2").read_text() == "my notes\n" and not (root / "cells").exists()


def test_simulate_refuses_the_model_store(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                          monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """Issue 82, probe 4, F16: `simulate --out` inside the model store (or a store model's folder) was written, and
    every study then refused the store ("holds myrun, which is not a stored model"); train's --out was refused there.
    One check for both (owners.owned_problem): one line, nothing written."""
    store, env_store = tmp_path / "store", tmp_path / "env_store"
    model = store / "default_a0_seed100_0123456789ab"
    model.mkdir(parents=True)
    mark_run_dir(model, "train")
    env_store.mkdir()
    monkeypatch.setenv("COOPSUMO_MODELS", str(env_store))
    before = snapshot(tmp_path)
    for out, says in ((store / "myrun", "a model store (it holds the studies' models)"),
                      (model / "run", "a model of a model store"), (env_store / "myrun", "is in the model store")):
        refused(capsys, simulate.main([*SIM, "--out", str(out)]), f"--out {out}", says, "pick another --out")
    assert snapshot(tmp_path) == before


def test_a_run_never_goes_inside_another_run_s_folder(trained: Path, simulated: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Issue 82, probe 4, F19: `simulate --out` inside a finished training's folder and `train --out` inside a simulate
    run's were written, and that folder was then no longer its command's (its rerun refused: "holds t, which coopsumo
    simulate did not write"). Refused as one inside a study's folder is: one line, nothing written."""
    before = snapshot(trained), snapshot(simulated)
    out = trained / "eval2"
    refused(capsys, simulate.main([*SIM, "--out", str(out)]),
            f"--out {out} lies inside {trained.resolve()}, the folder of a coopsumo train run")  # fmt: skip
    out = simulated / "t"
    refused(capsys, train.main(["--steps", "20", "--eval-steps", "0", "--quiet", "--out", str(out)]),
            f"--out {out} lies inside {simulated.resolve()}, the folder of a coopsumo simulate run")  # fmt: skip
    assert (snapshot(trained), snapshot(simulated)) == before
