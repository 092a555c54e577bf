"""Issue 82, probe 13: messages that were not one line or that said the wrong thing (F17, F19, F20)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from test_profile_files import run_main, tiny_scenario2
from test_scenario2 import faked_train  # noqa: F401  (the fixture: scenario II's cells without SUMO)

from coopsumo.errors import UsageError
from coopsumo.runio import run_cli
from coopsumo.studies.scenario2 import redraw
from coopsumo.studies.scenario2 import study as s2


def test_a_merge_parts_unparsable_table_is_one_line_naming_it(tmp_path: Path) -> None:
    """F17: pandas' ParserError text ends in a newline, which the refusal passed on ("...saw 4\\n)"); the file that
    could not be read was not named."""
    part = tmp_path / "L2b"
    part.mkdir()
    (part / "sweep.json").write_text("{}")
    (part / "runs.csv").write_text("a,b\n1,2\n")
    (part / "evals.csv").write_text("root\nx:1:2:3\nx,1,2,3\n")
    with pytest.raises(UsageError) as refused:
        redraw._read_part(part)
    text = str(refused.value)
    assert "\n" not in text and f"{part} is not a finished scenario2 sweep (evals.csv: ParserError: " in text, text


def test_a_usage_error_of_several_lines_is_printed_on_one(capsys: pytest.CaptureFixture[str]) -> None:
    """F17's class: whatever a library's text a UsageError passes on, the command's error is one line."""

    def body() -> int:
        raise UsageError("a table cannot be read (Error tokenizing data. C error: Expected 1 fields\n)\nand more\n")

    assert run_cli("scenario2", body) == 2
    err = capsys.readouterr().err
    assert err == "scenario2: error: a table cannot be read (Error tokenizing data. C error: Expected 1 fields ) and " \
                  "more\n", err


def test_a_learning_study_is_called_learning_with_its_article(tmp_path: Path) -> None:
    """F20: the learning study's marker kind is "ablation", and lines called it so: "holds a coopsumo protocol run,
    not a ablation study"; its own lines began "ablation:"."""
    from coopsumo.run_dirs import check_study_root, mark_run_dir
    from coopsumo.run_markers import LEARNING_KIND, a_kind, kind_name

    assert (kind_name(LEARNING_KIND), a_kind("accident_seeds", "study")) == ("learning", "an accident_seeds study")
    root = tmp_path / "p"
    root.mkdir()
    mark_run_dir(root, "protocol", finished=False, study="the tiny profile's study")
    with pytest.raises(UsageError, match=f"^output folder {root} holds a coopsumo protocol run, not a learning study"):
        check_study_root(root, LEARNING_KIND, ("study.json",))
    mark_run_dir(root, LEARNING_KIND, finished=False, study="the tiny profile's study")
    with pytest.raises(UsageError, match="holds a coopsumo learning run, not a protocol study"):
        check_study_root(root, "protocol", ("study.json",))


def test_a_merge_part_without_the_learners_cells_says_so(tmp_path: Path, faked_train: list[str],  # noqa: F811
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    """F20: a finished sweep of policies ["mobil"] was refused as "runs.csv has no loop_flow_veh_h_per_lane column
    and 1 more: not as a sweep writes it", though a sweep wrote it: a part needs the learner's cells."""
    path = tmp_path / "mine.toml"
    path.write_text(tiny_scenario2())
    part = tmp_path / "part"
    code, err = run_main(s2.main, ["--profile", str(path), "--out", str(part), "--quiet", "--bootstrap", "20"], capsys)
    assert code == 0, err
    meta = json.loads((part / "sweep.json").read_text())  # a sweep of MOBIL only (its cells need SUMO: its record;
    # the faked cells lack the loop columns too, which the check before the tables must not reach)
    meta["profile"]["policies"] = ["mobil"]
    (part / "sweep.json").write_text(json.dumps(meta))
    with pytest.raises(UsageError, match=f"^--merge: {part} is a sweep of mobil only .*: a merge joins the learner's"):
        redraw._read_part(part)


@pytest.mark.parametrize(("text", "keys"), [('current = "mine"\n[mine]\nseeds = [1]\n', "'current', 'mine'"),
                                            ("x = 1\n", "'x'")])
def test_a_profile_file_without_profiles_names_its_keys_and_the_format(text: str, keys: str, tmp_path: Path) -> None:
    """F19: a file of the format before 2026-12-04, or one holding only `x = 1`, was refused with "[profiles] must
    be a table, got None", naming nothing; the docs promise a line naming the keys it knows."""
    from coopsumo.errors import ConfigError
    from coopsumo.studies.scenario2 import plan as s2_plan

    path = tmp_path / "old.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as refused:
        s2_plan.own_profiles(path)
    line = str(refused.value)
    assert line.startswith(f"{path}: unknown top-level keys {keys} (known: default, shared, profiles); no [profiles] "
                           "table: a profile file holds each profile as a [profiles.NAME] table"), line
    assert "\n" not in line and "None" not in line


@pytest.mark.parametrize("plan", ["x; rm -rf /", "B2BB97B", "b2bb9", "b2bb97bz", "1" * 41])
def test_a_profiles_response_plan_must_be_a_commits_hash(plan: str, tmp_path: Path) -> None:
    """F21: `response_plan = "x; rm -rf /"` was taken and recorded as the analysis plan's commit, which declares the
    response reading confirmatory."""
    from coopsumo.errors import ConfigError
    from coopsumo.studies.scenario2 import plan as s2_plan

    path = tmp_path / "mine.toml"
    path.write_text(tiny_scenario2() + f"response_plan = {json.dumps(plan)}\n")
    with pytest.raises(ConfigError, match=r"\[profiles.mine\] response_plan must be a commit's hash \(7 to 40 hex"):
        s2_plan.own_profiles(path)
    path.write_text(tiny_scenario2() + 'response_plan = "b2bb97b"\n')
    assert s2_plan.own_profiles(path)[0]["mine"].response_plan == "b2bb97b"


def test_a_merge_parts_response_plan_must_be_a_commits_hash(tmp_path: Path, faked_train: list[str],  # noqa: F811
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    """F21 for a merge part: its sweep.json's profile.response_plan is checked as a profile file's is."""
    path = tmp_path / "mine.toml"
    path.write_text(tiny_scenario2())
    part = tmp_path / "part"
    code, err = run_main(s2.main, ["--profile", str(path), "--out", str(part), "--quiet", "--bootstrap", "20"], capsys)
    assert code == 0, err
    meta = json.loads((part / "sweep.json").read_text())
    meta["profile"]["response_plan"] = "x; rm -rf /"
    (part / "sweep.json").write_text(json.dumps(meta))
    with pytest.raises(UsageError, match=r"^--merge: .*sweep.json: \[profile\] response_plan must be a commit's hash"):
        redraw._read_part(part)
