"""Issue 82, probe 8: places a single run's output (simulate --out, train --out, --gui-screenshot, history --out) may
not go: deeper in a model store than its first level (J1: `simulate --out models/sub/run` beside a study was
written, and the study then refused its store), and inside a study's folder written before markers, as every
committed study is on a fresh clone (J2: only `history --out` refused it). Every refusal: one line, exit code 2,
nothing written."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_study_places import listing, one_line, run

from coopsumo.owners import owned_problem

MODEL = "default_a0_seed1_0123456789ab"


def store_beside(tmp_path: Path) -> Path:
    """The model store `models` beside a study's root, holding one model's folder."""
    (tmp_path / "models" / MODEL).mkdir(parents=True)
    return tmp_path / "models"


def unmarked_protocol(folder: Path) -> Path:
    """A protocol study's folder as a fresh clone holds it: study.json, runs.csv and report.md, no marker."""
    folder.mkdir(parents=True)
    for name, text in (("study.json", '{"profile": {"name": "x", "t_ups": [1.5]}}'), ("runs.csv", "a\n1\n"),
                       ("report.md", "# x\n")):  # fmt: skip
        (folder / name).write_text(text)
    return folder


@pytest.mark.parametrize("below", ["sub/run", ".x/run", "sub/deeper/run"])
def test_a_path_at_any_depth_in_a_model_store_is_refused(below: str, tmp_path: Path) -> None:
    store = store_beside(tmp_path)
    problem = owned_problem(store / below, "--out X")
    assert problem is not None and f"is in {store}, a model store" in problem
    assert owned_problem(tmp_path / "elsewhere" / "run", "--out X") is None


def test_a_path_inside_an_unmarked_study_is_refused_and_beside_it_is_not(tmp_path: Path) -> None:
    study = unmarked_protocol(tmp_path / "P")
    problem = owned_problem(study / "sim", "--out P/sim")
    assert problem is not None and f"lies inside {study}, a coopsumo study's folder (its study.json" in problem
    assert owned_problem(tmp_path / "sim", "--out sim") is None


@pytest.mark.parametrize("case", ["store", "study"])
@pytest.mark.parametrize("command", ["simulate", "train"])
def test_a_single_run_is_not_written_there(command: str, case: str, tmp_path: Path,
                                           monkeypatch: pytest.MonkeyPatch,
                                           capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("COOPSUMO_MODELS", raising=False)
    place = store_beside(tmp_path) / "sub" / "run" if case == "store" else unmarked_protocol(tmp_path / "P") / "run"
    before = listing(tmp_path)
    argv = ["--quiet", "--steps", "100", "--out", str(place)] + (["--eval-steps", "0"] if command == "train" else [])
    one_line(capsys, run(command, argv), f"--out {place}", "a model store" if case == "store" else "study's folder")
    assert listing(tmp_path) == before


def test_a_gui_screenshot_is_not_written_in_an_unmarked_study(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                              capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    monkeypatch.chdir(tmp_path)
    study = unmarked_protocol(tmp_path / "P")
    before = listing(tmp_path)
    code = run("simulate", ["--quiet", "--steps", "30", "--out", "g", "--gui", "--gui-screenshot",
                            str(study / "fig_new.png")])  # fmt: skip
    one_line(capsys, code, "--gui-screenshot", "study's folder")
    assert listing(tmp_path) == before


def test_an_unmarked_study_folder_holding_a_users_file_beside_its_plan_is_refused(tmp_path: Path) -> None:
    """J3: a copied sweep.json beside a user's notes.txt and report.md was taken as a study written before markers,
    and its report.md replaced. Such a folder is taken only when it holds nothing but the study's names (those of
    every committed study, response.csv and claim_a.md too)."""
    from coopsumo.errors import UsageError
    from coopsumo.run_dirs import check_study_root
    from coopsumo.studies.engine.run_folders import STUDY_OUTPUTS

    root = tmp_path / "X"
    root.mkdir()
    for name in ("sweep.json", "runs.csv", "response.csv", "report.md"):
        (root / name).write_text("x\n")
    check_study_root(root, "scenario2", STUDY_OUTPUTS["scenario2"])  # the names a sweep writes: an earlier one's
    (root / "notes.txt").write_text("mine\n")
    before = listing(tmp_path)
    with pytest.raises(UsageError, match="holds notes.txt, which coopsumo scenario2 does not write"):
        check_study_root(root, "scenario2", STUDY_OUTPUTS["scenario2"])
    assert listing(tmp_path) == before


def test_a_run_inside_a_folder_with_a_damaged_marker_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    """J2 (x18): `simulate --out s2/sim` inside a study whose .coopsumo-run.json was damaged was written."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "s2").mkdir()
    (tmp_path / "s2" / ".coopsumo-run.json").write_text("{broken")
    before = listing(tmp_path)
    one_line(capsys, run("simulate", ["--quiet", "--steps", "30", "--out", "s2/sim"]), "cannot be read")
    assert listing(tmp_path) == before


def test_a_model_store_inside_an_unmarked_study_is_refused(tmp_path: Path) -> None:
    """J2 (x09): COOPSUMO_MODELS=U/store inside a committed study's folder (no marker) was filled with models."""
    from coopsumo.owners import claimed_problem

    study = unmarked_protocol(tmp_path / "U")
    problem = claimed_problem(study / "store", "'U/store'", "pick a model store elsewhere")
    assert problem is not None and f"lies inside {study}, a coopsumo study's folder" in problem
    assert claimed_problem(tmp_path / "store", "'store'", "pick a model store elsewhere") is None


def test_scenario1_refuses_a_spoiled_store_model_before_writing_anything(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch,
                                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """J21: a store model whose sumo/ is a link to a user's folder was refused only after the study had written its
    marker and plan.json into --out (and, before the training-folder rule, its cells failed on every rerun)."""
    from coopsumo.config import to_dict
    from coopsumo.studies.engine.model_store import model_id
    from coopsumo.studies.scenario1.plan import train_config
    from coopsumo.studies.scenario1.study import build_parser, plan_from_args

    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("COOPSUMO_MODELS", raising=False)
    argv = ["--quick", "--alphas", "0", "--t-up", "2", "--mobil-p", "0", "--seeds", "1", "--train-seeds", "1",
            "--workers", "1", "--steps", "200", "--train-steps", "200", "--quiet", "--out", "s1b"]  # fmt: skip
    plan = plan_from_args(build_parser().parse_args(argv))
    folder = tmp_path / "models" / model_id(to_dict(train_config(plan, 0.0, plan.presets[0], plan.train_seeds[0])))
    folder.mkdir(parents=True)
    (tmp_path / "user").mkdir()
    (tmp_path / "user" / "detectors.xml").write_text("mine")
    (folder / "sumo").symlink_to(tmp_path / "user")
    before = listing(tmp_path)
    one_line(capsys, run("scenario1", argv), f"{folder}, a model's folder in the model store", "a link to")
    assert listing(tmp_path) == before and not (tmp_path / "s1b").exists()


@pytest.mark.parametrize("entry", ["file", "folder"])
def test_a_users_file_named_like_a_temporary_in_an_unmarked_folder_is_kept(entry: str, tmp_path: Path) -> None:
    """Probe 9: a folder holding only a user's .report.md.abcdefgh.tmp was taken as a study's fresh root (temporary
    files were passed over) and the claim deleted it; a folder of that name was taken as an empty root. Only the
    temporary of the marker's own write (a first run killed while marking) is passed over, and a claim removes
    temporaries only in a root the study had marked before."""
    from coopsumo.errors import UsageError
    from coopsumo.run_dirs import study_root

    root = tmp_path / "X"
    root.mkdir()
    user = root / ".report.md.abcdefgh.tmp"
    if entry == "file":
        user.write_text("my thesis")
    else:
        (user / "ch1.txt").parent.mkdir()
        (user / "ch1.txt").write_text("chapter 1")
    before = listing(tmp_path)
    with pytest.raises(UsageError, match=r"holds \.report\.md\.abcdefgh\.tmp, named like"):
        with study_root(root, "scenario2", ("sweep.json", "report.md", "*.tmp")):
            pass
    assert listing(tmp_path) == before
    user.unlink() if entry == "file" else ((user / "ch1.txt").unlink(), user.rmdir())
    notes = root / "..coopsumo-run.json.thesis01.tmp"  # probe 10, L7: a user's file named as the marker's temporary
    notes.write_text("MY NOTES\n")
    with pytest.raises(UsageError, match=r"holds \.\.coopsumo-run\.json\.thesis01\.tmp"):
        with study_root(root, "scenario2", ("sweep.json", "report.md", "*.tmp")):
            pass
    assert notes.read_text() == "MY NOTES\n"
    notes.write_text('{"my": "data"}\n')  # probe 11, M2: a user's JSON file of that name
    with pytest.raises(UsageError, match=r"holds \.\.coopsumo-run\.json\.thesis01\.tmp"):
        with study_root(root, "scenario2", ("sweep.json", "report.md", "*.tmp")):
            pass
    notes.unlink()
    (root / "..coopsumo-run.json.abcdefgh.tmp").write_text("{")  # a first run killed while it marked its root
    with study_root(root, "scenario2", ("sweep.json", "report.md", "*.tmp")):
        assert (root / ".coopsumo-run.json").is_file()


def test_an_empty_model_store_beside_a_study_is_still_its_store(tmp_path: Path) -> None:
    """Probe 9: the store `models` beside a marked study, emptied (a model folder removed), took a simulate run and
    a history table; the study then refused its store."""
    from coopsumo.run_dirs import mark_run_dir

    (tmp_path / "s1").mkdir()
    mark_run_dir(tmp_path / "s1", "scenario1", finished=False, study="the quick profile's study")
    (tmp_path / "models").mkdir()
    problem = owned_problem(tmp_path / "models" / "run", "--out models/run")
    assert problem is not None and f"is in {tmp_path / 'models'}, a model store" in problem
    assert owned_problem(tmp_path / "elsewhere" / "models" / "run", "--out elsewhere/models/run") is None
    problem = owned_problem(tmp_path / "models", "--out models")  # probe 10, L3: the store itself as an --out
    assert problem is not None and f"is in {tmp_path / 'models'}, a model store" in problem
    assert owned_problem(tmp_path / "elsewhere" / "models", "--out elsewhere/models") is None


@pytest.mark.parametrize("command", [["simulate", "--quiet", "--steps", "20"],
                                     ["train", "--quiet", "--steps", "100", "--eval-steps", "0"],
                                     ["scenario1", "--regime-map", "--seeds", "1", "--steps", "200"]])
def test_an_emptied_model_store_beside_a_study_is_no_commands_out(
        command: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Probe 10 (L3, L6): `simulate --out models`, `train --out models`, the merges and the regime map wrote their
    marker into the emptied store beside a study, which every study then refused; nothing is written now (a study's
    root is checked by the same owners.owned_problem, through run_dirs.check_study_place)."""
    from coopsumo.run_dirs import mark_run_dir

    monkeypatch.chdir(tmp_path)
    (tmp_path / "s1").mkdir()
    mark_run_dir(tmp_path / "s1", "scenario1", finished=False, study="the quick profile's study")
    (tmp_path / "models").mkdir()
    before = listing(tmp_path)
    one_line(capsys, run(command[0], [*command[1:], "--out", "models"]), "a model store")
    assert listing(tmp_path) == before


def test_nothing_is_written_inside_a_runs_partial_folder(tmp_path: Path) -> None:
    """Probe 9 (K11): a killed simulate's .o.partial-XXXXXXXX took a model store, a training and a table, and the
    next simulate into its parent folder deleted them with it."""
    from coopsumo.owners import claimed_problem
    from coopsumo.run_markers import PARTIAL_MARKER

    partial = tmp_path / ".o.partial-abcdefgh"
    partial.mkdir()
    (partial / PARTIAL_MARKER).write_text("the partial folder of a coopsumo run\n")
    for problem in (owned_problem(partial / "t", "--out t"), claimed_problem(partial / "store", "'store'", "x")):
        assert problem is not None and f"lies inside {partial}, the folder a coopsumo run is built in" in problem
    assert owned_problem(tmp_path / ".o.partial-mine" / "t", "--out t") is None  # a user's folder of such a name


@pytest.mark.parametrize("committed", ["regime_map", "archive/learning_conditioned_nr10/accident"])
def test_a_study_committed_without_its_plan_file_is_its_own_and_nothing_elses(committed: str, tmp_path: Path) -> None:
    """I5 refused the committed regime map's folder (runs.csv and report.md only: `make regime-map` on a fresh
    clone); it is known by its report's first line, and a run inside a copy of it is refused (probe 9, K8), as
    inside the accident runs of the retired accident-seeds (issue 80). A user's report.md beside a runs.csv is still
    refused."""
    import shutil

    from coopsumo.errors import UsageError
    from coopsumo.run_dirs import check_study_root
    from coopsumo.studies.engine.run_folders import STUDY_OUTPUTS

    own = (*STUDY_OUTPUTS["regime_map"], "*.tmp")
    copy = tmp_path / "copy"
    shutil.copytree(Path(__file__).resolve().parents[1] / "results" / committed, copy)
    if committed == "regime_map":
        check_study_root(copy, "regime_map", own)
    problem = owned_problem(copy / "sim", "--out copy/sim")
    assert problem is not None and "a coopsumo study's folder (its report.md" in problem
    (copy / "report.md").write_text("# my own notes\n")
    with pytest.raises(UsageError, match="named like a coopsumo"):
        check_study_root(copy, "regime_map", own)


@pytest.mark.parametrize("command", [["bench", "--quick"], ["simulate", "--quiet", "--steps", "30", "--out", "o"]])
def test_a_temporary_folder_in_a_model_store_is_refused_before_the_command_starts(
        command: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Probe 9 (K9): with $TMPDIR in a model store, a killed `bench` left its training's folder there, and every
    study then refused the store ("holds tmp4f7c0069, which is not a stored model")."""
    store = store_beside(tmp_path)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("TMPDIR", str(store))
    before = listing(tmp_path)
    one_line(capsys, run(command[0], command[1:]), f"$TMPDIR '{store}'", "pick a temporary folder elsewhere")
    assert listing(tmp_path) == before


def test_an_emptied_model_store_linked_beside_a_study_is_still_its_store(tmp_path: Path) -> None:
    """Probe 11 (M1): a study's `models` a link to a store kept elsewhere, emptied: a run, a training, a table or
    the networks were written into it (the check of probe 10, L3, read the resolved folder's name)."""
    from coopsumo.run_dirs import mark_run_dir

    (tmp_path / "w" / "s1").mkdir(parents=True)
    mark_run_dir(tmp_path / "w" / "s1", "scenario1", finished=False, study="the quick profile's study")
    (tmp_path / "kept" / "store").mkdir(parents=True)
    (tmp_path / "w" / "models").symlink_to(tmp_path / "kept" / "store")
    for where, itself in (("models", False), ("models/run", False), ("models/t.md", False), ("models/nets", True)):
        problem = owned_problem(tmp_path / "w" / where, f"--out {where}", itself=itself)
        assert problem is not None and "a model store" in problem, (where, problem)
    assert owned_problem(tmp_path / "kept" / "other", "--out kept/other") is None

