"""Issue 82, probe 7: folders a study writes into that it did not make. A run folder of a study (scenario II's evals/
and mobil/; the learning study's baselines/ and evals/ until issue 80 retired it) holding a user's files is refused
before any run as scenario I refuses one (I1). Every refusal: one line, exit code 2, the user's files as they were."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from coopsumo.errors import UsageError
from coopsumo.studies.engine.run_folders import check_run_places, run_places

S2 = """[profiles.mini]
help = "probe"
lanes = [2]
loads = [0.5]
alphas = [0]
seeds = [1]
train_steps = 200
eval_steps = 300
mobil_ps = [0]
policies = ["dqn", "mobil"]
"""


def run(command: str, argv: list[str]) -> int:
    from test_study_places import run as run_command

    return run_command(command, argv)


def one_line(capsys: pytest.CaptureFixture[str], code: int, *fragments: str) -> str:
    from test_study_places import one_line as check

    return check(capsys, code, *fragments)


def user_folder(folder: Path) -> None:
    """A user's folder where a study's run belongs: a config.json of its own and notes."""
    folder.mkdir(parents=True)
    (folder / "config.json").write_text('{"mine": 1}\n')
    (folder / "notes.txt").write_text("x\n")


def test_a_run_folder_is_the_studys_only_when_it_holds_only_a_runs_names(tmp_path: Path) -> None:
    """I1: the rule, one home (run_folders.check_run_places, scenario I's check_run_dir beneath): missing, empty or
    holding only what a run writes in place is taken; a user's file beside them, a file in its place, refused."""
    check_run_places([tmp_path / "none"], in_place=True)
    (tmp_path / "empty").mkdir()
    check_run_places([tmp_path / "empty"], in_place=True)
    own = tmp_path / "own"
    own.mkdir()
    for name in ("config.json", "summary.json", "detectors.xml", ".summary.json.abcd1234.tmp"):
        (own / name).write_text("{}")
    check_run_places([own], in_place=True)
    with pytest.raises(UsageError, match="own has no .coopsumo-run.json"):  # scenario I's and the protocol's runs
        check_run_places([own])  # are built aside and marked: an unmarked one is never theirs
    user_folder(tmp_path / "user")
    with pytest.raises(UsageError, match="user has no .coopsumo-run.json"):
        check_run_places([tmp_path / "user"], in_place=True)
    (tmp_path / "evals" / "k").mkdir(parents=True)
    (tmp_path / "evals" / "k" / "eval_s1").write_text("mine")
    with pytest.raises(UsageError, match="eval_s1 exists and is not a folder"):
        check_run_places(run_places(tmp_path / "evals" / "k", nested=True), in_place=True)


def mark_study(root: Path, command: str, profile: str) -> None:
    """Mark `root` as the study `command --profile profile` (scenario II) marks its root when it starts."""
    from coopsumo.run_dirs import mark_run_dir
    from coopsumo.studies.scenario2.redraw import sweep_study
    from coopsumo.studies.scenario2.study import chosen_profile

    assert command == "scenario2"
    mark_run_dir(root, "scenario2", finished=False, study=sweep_study(chosen_profile(profile)))


CASES = {
    "scenario2 evals": ("scenario2", S2, "evals/L2_T2_a0_s1/eval_s2001", ["--bootstrap", "10"]),
    "scenario2 mobil": ("scenario2", S2, "mobil/L2_T2_mobil_p0_s2001", ["--bootstrap", "10"]),
}


@pytest.mark.parametrize("case", CASES)
def test_a_studys_run_folder_holding_a_users_files_is_refused_before_any_run(case: str, tmp_path: Path,
                                                                           monkeypatch: pytest.MonkeyPatch,
                                                                           capsys: pytest.CaptureFixture[str]) -> None:
    """I1: `scenario2 --out s` with s/evals/<key>/eval_s2001 (or s/mobil/<key>) holding a user's config.json and
    notes.txt (and the since retired `learning --out L` with L/baselines/keep_seed0 so): the run was written in, the
    user's config.json replaced, exit 0. Refused now before any cell runs, naming the folder; the user's files
    kept."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("COOPSUMO_MODELS", raising=False)
    command, profile, place, extra = CASES[case]
    (tmp_path / "p.toml").write_text(profile)
    folder = tmp_path / "s" / place
    user_folder(folder)
    mark_study(tmp_path / "s", command, f"{tmp_path / 'p.toml'}:mini")  # the study's own root, interrupted (I5)
    argv = ["--profile", f"{tmp_path / 'p.toml'}:mini", "--workers", "1", "--quiet", "--out", "s", *extra]
    one_line(capsys, run(command, argv), f"output folder {folder.resolve()}", "left alone")
    assert json.loads((folder / "config.json").read_text()) == {"mine": 1}
    assert sorted(p.name for p in folder.iterdir()) == ["config.json", "notes.txt"]
    assert not (tmp_path / "models").exists() or not any((tmp_path / "models").iterdir())  # no model trained


# -- I4: learning and protocol both write study.json ---------------------------------------------------------------
COMMITTED = {"protocol": "learner_protocol_u1", "ablation": "archive/learning_conditioned_nr10"}
"""a committed study of each command that writes study.json, without a marker (written before markers)"""


def committed_root(root: Path, kind: str, name: str | None = None) -> str:
    """root holding the committed study.json of the study `kind` (its profile renamed `name`): its profile's name."""
    data = json.loads((Path(__file__).parents[1] / "results" / COMMITTED[kind] / "study.json").read_text())
    if name is not None:
        data["profile"]["name"] = name
    root.mkdir(parents=True)
    (root / "study.json").write_text(json.dumps(data))
    return str(data["profile"]["name"])


@pytest.mark.parametrize("kind", COMMITTED)
def test_an_unmarked_study_json_names_its_command_too(kind: str, tmp_path: Path) -> None:
    """I4: a root without a marker was told by its study.json's profile name alone, so a protocol study was taken
    for a learning study of the same name and the other way round. The committed studies are still their own."""
    from coopsumo.run_dirs import check_study_root
    from coopsumo.run_markers import kind_name
    from coopsumo.studies.engine.run_folders import STUDY_OUTPUTS, profile_study, recorded_profile

    for root_kind in COMMITTED:
        name = committed_root(tmp_path / root_kind, root_kind)
        recorded = recorded_profile("study.json", "profile", "name", kind=kind)
        own = (*STUDY_OUTPUTS[kind], "*.tmp")
        if root_kind == kind:
            check_study_root(tmp_path / root_kind, kind, own, profile_study(name), recorded)
            continue
        with pytest.raises(UsageError, match=f"holds a coopsumo {kind_name(root_kind)} study \\(study.json says so\\), "
                           "not the"):  # fmt: skip
            check_study_root(tmp_path / root_kind, kind, own, profile_study(name), recorded)


@pytest.mark.parametrize(("command", "other"), [("protocol", "ablation")])
def test_another_commands_unmarked_study_of_the_same_profile_is_refused(command: str, other: str, tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    """I4: `learning --profile tiny --out P` over an unmarked protocol study P of profile tiny (the reverse too) took
    it: study.json, runs.csv and report.md replaced. Refused in one line before anything is written."""
    from test_study_places import listing

    from coopsumo.run_markers import kind_name

    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("COOPSUMO_MODELS", raising=False)
    committed_root(tmp_path / "P", other, "tiny")
    before = listing(tmp_path)
    one_line(capsys, run(command, ["--profile", "tiny", "--quiet", "--workers", "1", "--out", "P"]),
             f"holds a coopsumo {kind_name(other)} study")  # fmt: skip
    assert listing(tmp_path) == before


# -- I5: an unmarked folder of the study's own names but no plan file --------------------------------------------
I5_COMMANDS = {"scenario2": ["--profile", "tiny"], "scenario1": ["--quick"], "protocol": ["--profile", "tiny"]}


@pytest.mark.parametrize("command", I5_COMMANDS)
def test_an_unmarked_folder_of_output_names_without_a_plan_file_is_refused(command: str, tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch,
                                                                          capsys: pytest.CaptureFixture[str]) -> None:
    """I5 (decided): `scenario2 --out an` over a user's report.md and runs.csv (no marker, no plan file) replaced
    them, exit 0. A first run marks its root before writing anything, so such a folder is never the study's: refused
    in one line naming it, nothing written. Empty, or only a temporary file: taken (test_study_places)."""
    from test_study_places import listing

    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("COOPSUMO_MODELS", raising=False)
    (tmp_path / "an").mkdir()
    (tmp_path / "an" / "report.md").write_text("notes\n")
    (tmp_path / "an" / "runs.csv").write_text("a,b\n1,2\n")
    before = listing(tmp_path)
    one_line(capsys, run(command, [*I5_COMMANDS[command], "--quiet", "--workers", "1", "--out", "an"]),
             f"output folder {tmp_path.resolve() / 'an'} holds report.md and 1 more", "named like a coopsumo",
             "but neither a .coopsumo-run.json nor its")  # fmt: skip
    assert listing(tmp_path) == before


# -- I6: a folder in the model store holding a user's files -----------------------------------------------------------
def test_a_store_folder_holding_a_users_files_is_never_trained_into(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """I6: a folder in the store named like a model, without a marker, holding a user's config.json and notes.txt,
    was trained into (config.json replaced); a stored model with a user's notes.txt (or sumo/mine.txt) added, its
    marker deleted, was trained again and its new marker listed the user's files as the training's. Refused in one
    line naming the folder and the file (model_store.check_entry); a store model with only a training's files (and
    its group's group_cost.json) is taken as before."""
    from test_data_loss import TINY, as_json, snapshot

    from coopsumo.run_dirs import RUN_MARKER
    from coopsumo.studies.engine.model_store import model_id, stored_model, train_shared

    monkeypatch.delenv("COOPSUMO_MODELS", raising=False)
    store = tmp_path / "models"
    entry = store / model_id(as_json(TINY))
    user_folder(entry)
    before = snapshot(tmp_path)
    link = tmp_path / "s" / "t"
    steps = (lambda: stored_model(as_json(TINY), store), lambda: train_shared(TINY, link, store))
    for step in steps:
        with pytest.raises(UsageError) as err:
            step()
        assert f"{entry}, a model's folder in the model store, holds notes.txt" in str(err.value)
        assert len(str(err.value).splitlines()) == 1 and snapshot(tmp_path) == before
    (entry / "notes.txt").unlink()
    (entry / "config.json").unlink()
    train_shared(TINY, link, store)  # an empty folder of that name: the training's
    (entry / "group_cost.json").write_text('{"group_size": 2, "cpu_s": 1.0}')
    assert stored_model(as_json(TINY), store) == entry
    for added in ("notes.txt", "sumo/mine.txt"):
        (entry / added).write_text("mine\n")
        (entry / RUN_MARKER).unlink(missing_ok=True)
        before = snapshot(tmp_path)
        for step in steps:
            with pytest.raises(UsageError, match=f"holds {added}, which no training writes"):
                step()
            assert snapshot(tmp_path) == before
        (entry / added).unlink()


# -- I12: the study's own --out as its model store ------------------------------------------------------------------
I12_COMMANDS = {"scenario1": ["--quick"], "scenario2": ["--profile", "tiny"], "protocol": ["--profile", "tiny"]}


@pytest.mark.parametrize("command", I12_COMMANDS)
def test_a_store_that_is_or_lies_in_the_studys_own_out_is_refused_before_anything_is_written(
        command: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """I12: `--out models` (the store beside it is itself) and `COOPSUMO_MODELS=Y/st ... --out Y` were refused only
    after the study's marker, plan file, cells/ and train/ were written, and the folder then claimed. Now before."""
    from test_study_places import listing

    monkeypatch.chdir(tmp_path)
    (tmp_path / "Y").mkdir()
    for env, out, says in ((None, "models", "is"), (str(tmp_path / "Y" / "st"), "Y", "lies inside")):
        if env is None:
            monkeypatch.delenv("COOPSUMO_MODELS", raising=False)
        else:
            monkeypatch.setenv("COOPSUMO_MODELS", env)
        before = listing(tmp_path)
        one_line(capsys, run(command, [*I12_COMMANDS[command], "--quiet", "--workers", "1", "--out", out]),
                 f"the model store {env or tmp_path / 'models'}", f"{says} {out}, the study's own --out")  # fmt: skip
        assert listing(tmp_path) == before


# -- I14: history --out into a study's folder written before markers -------------------------------------------------
def test_history_out_refuses_an_unmarked_protocol_study_folder(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """I14: `history --out P/table.md` with P a copy of a committed protocol study (no marker) wrote the table into
    it, exit 0; a marked one was refused. Refused alike: one line naming the folder, nothing written."""
    import shutil

    from test_study_places import listing

    from coopsumo.studies.protocol import history

    checkout = Path(__file__).parents[1] / "results"
    shutil.copytree(checkout / "learner_protocol_u1", tmp_path / "P")
    out = tmp_path / "P" / "table.md"
    before = listing(tmp_path)
    one_line(capsys, history.main(["--results", str(checkout), "--out", str(out)]),
             f"--out {out} lies inside {tmp_path / 'P'}, a coopsumo study's folder (its study.json")  # fmt: skip
    assert listing(tmp_path) == before
    history.check_writable(tmp_path / "elsewhere" / "table.md")  # a file beside it is fine
