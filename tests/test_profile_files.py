"""Issue 82, item 5: the studies' profiles in their TOML data are checked by the very rules of the flags (one rule per
field, validation's IntRule, NumberRule and ListRule, read by the flag and by the loader), when the file is read,
before anything is written; and a profile of one's own in a file (`--profile PATH.toml[:NAME]`) is read by the same
loader, so that no one edits the installed package's data. Regression cases of the 2026-12-01 probe (t03, t04, t05,
t22, t23, t24): `seeds = []` ended in a traceback, `alphas = [0, 0.0]` was merged silently, `mobil_ps = [-1, 1]`
and `eval_seeds = 0` were found after the study ran, `loads = [nan]` wrote `--out` before it was refused."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
from test_scenario2 import faked_train  # noqa: F401  (the fixture: scenario II's cells without SUMO)

from coopsumo.errors import ConfigError
from coopsumo.studies.protocol import plan as protocol_plan
from coopsumo.studies.protocol import study as protocol
from coopsumo.studies.scenario2 import plan as s2_plan
from coopsumo.studies.scenario2 import study as s2


def run_main(main: Any, argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str]]:
    try:
        code = main(argv)
    except SystemExit as stop:
        code = int(stop.code or 0)
    return code, capsys.readouterr().err.strip().splitlines()


def packaged_table(path: Path, header: str) -> str:
    """The lines of one table of a packaged TOML file (up to the next table or the end), its header first."""
    match = re.search(rf"^{re.escape(header)}\n(.*?)(?=^\[|\Z)", path.read_text(), flags=re.S | re.M)
    assert match, header
    return header + "\n" + match.group(1).strip() + "\n"


def with_field(table: str, line: str) -> str:
    """The table with `key = value` set (the line of its key replaced, or added)."""
    key = line.split("=")[0].strip()
    kept = [x for x in table.splitlines() if x.split("=")[0].strip() != key]
    return "\n".join([*kept, line]) + "\n"


def tiny_scenario2(name: str = "mine") -> str:
    """The packaged tiny profile's settings under another name."""
    return packaged_table(s2_plan.PROFILES_FILE, "[profiles.tiny]").replace("[profiles.tiny]", f"[profiles.{name}]")


# -- the issue's cases ---------------------------------------------------------------------------------------------
ISSUE_CASES = [
    ("seeds = []", "seeds must be a list of integers from 0 to 2147483647"),  # t05: a traceback after the study ran
    ("alphas = [0, 0.0]", "alphas gives the same value twice in [0, 0.0]: 0 and 0.0"),  # t22: merged silently
    ("mobil_ps = [-1, 1]", "mobil_ps must be a list of finite numbers >= 0 and <= 10, got [-1, 1]"),  # t23
    ("eval_seeds = 0", "eval_seeds must be an integer from 1 to 1000, got 0"),  # t24: models trained, cells failed
    ("loads = [nan]", "loads must be a list of finite numbers > 0, got [nan]"),  # t03: --out written first
    ("lanes = [7]", "lanes must be a list of integers from 2 to 6, got [7]"),  # t04: an empty --out made first
]


@pytest.mark.parametrize(("line", "words"), ISSUE_CASES, ids=[c[0] for c in ISSUE_CASES])
def test_the_packaged_loader_refuses_the_issues_cases_in_one_line(tmp_path: Path, line: str, words: str) -> None:
    """The packaged scenario2.toml with its tiny profile edited: one ConfigError line naming the file, the profile and
    the field (read when scenario2.plan is imported, so `coopsumo scenario2` stops before anything is written)."""
    text = s2_plan.PROFILES_FILE.read_text()
    tiny = packaged_table(s2_plan.PROFILES_FILE, "[profiles.tiny]")
    path = tmp_path / "scenario2.toml"
    path.write_text(text.replace(tiny, with_field(tiny, line)))
    with pytest.raises(ConfigError) as bad:
        s2_plan.load_profiles(path)
    assert str(bad.value).startswith(f"{path}: [profiles.tiny] {words}") and "\n" not in str(bad.value), bad.value


@pytest.mark.parametrize(("line", "words"), ISSUE_CASES, ids=[c[0] for c in ISSUE_CASES])
def test_a_profile_file_of_ones_own_is_refused_the_same_before_anything_is_written(
        tmp_path: Path, line: str, words: str, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    path = tmp_path / "mine.toml"
    path.write_text(with_field(tiny_scenario2(), line))
    out = tmp_path / "out"
    code, err = run_main(s2.main, ["--profile", str(path), "--out", str(out), "--quiet"], capsys)
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f"scenario2: error: {path}: [profiles.mine] {words}"), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.toml"]  # no --out, no model store


FLAG_AND_FIELD = [  # (the file's line, the flags, the words both give after the flag's or the field's name)
    ("alphas = [0, 0.0]", ["--alphas", "0,0.0"], "gives the same value twice in"),
    ("lanes = [2, 7]", ["--lanes", "2,7"], "list of integers from 2 to 6, got"),
    ("mobil_ps = [0, 11]", ["--policies", "dqn,mobil", "--mobil-p", "0,11"],
     "list of finite numbers >= 0 and <= 10, got"),
    ("alphas = [0, 1001]", ["--alphas", "0,1001"], "list of finite numbers >= 0 and <= 1000, got"),
    ("eval_seeds = 1001", ["--eval-seeds", "1001"], "must be an integer from 1 to 1000, got"),
    ("train_steps = 0", ["--steps", "0"], "must be an integer from 1 to 10000000, got"),
]  # fmt: skip


@pytest.mark.parametrize(("line", "flags", "words"), FLAG_AND_FIELD, ids=[c[0] for c in FLAG_AND_FIELD])
def test_the_file_and_the_flag_refuse_a_value_by_one_rule(tmp_path: Path, line: str, flags: list[str], words: str,
                                                          capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    out = tmp_path / "out"
    code, by_flag = run_main(s2.main, ["--profile", "tiny", *flags, "--out", str(out)], capsys)
    assert code == 2 and len(by_flag) == 1 and words in by_flag[0], by_flag
    path = tmp_path / "mine.toml"
    path.write_text(with_field(tiny_scenario2(), line))
    code, by_file = run_main(s2.main, ["--profile", str(path), "--out", str(out)], capsys)
    assert code == 2 and len(by_file) == 1 and words in by_file[0] and f"{path}: [profiles.mine]" in by_file[0]
    assert not out.exists()


@pytest.mark.parametrize(("line", "words"), [
    ("loads = [1, 1.001]", "loads 1 and 1.001 give the same T_up 1 s on 2 lanes"),
    ("loads = [50]", "loads: load 50 gives T_up 0.02 s on 2 lanes"),
    ("t_up_s = [2]", "loads must be [] beside t_up_s"),
    ("eval_loads = [0.3]", "eval_loads must be some of loads (0.25, 0.5), got 0.3"),
    ("check_alphas = [0]", "check_alphas needs alpha_models = false (per-alpha models beside a conditioned network)"),
    ("seeds = [1, 2001]", "seeds: training seed 2001 is also an evaluation seed"),
    ("policies = [\"dqn\", \"dqn\"]", "policies names 'dqn' twice"),
    ("policies = [\"ppo\"]", "policies names unknown 'ppo'"),
    ("criterion = \"fast\"", "criterion must be mean_speed_mps or full_road_speed_mps, got 'fast'"),
    ("conditioned = true", "conditioned must be false: the conditioned sweep (one network per condition and seed) was "
                           "retired"),
    ("preset = \"fastest\"", "preset must be one of default"),
    ("trajectory_every_steps = -1", "trajectory_every_steps must be an integer from 0 to 10000000, got -1"),
])  # fmt: skip
def test_the_rules_between_fields_and_of_fields_without_a_flag(tmp_path: Path, line: str, words: str) -> None:
    path = tmp_path / "mine.toml"
    table = tiny_scenario2()
    for one in line.splitlines():
        table = with_field(table, one)
    path.write_text(table)
    with pytest.raises(ConfigError) as bad:
        s2_plan.own_profiles(path)
    assert str(bad.value).startswith(f"{path}: [profiles.mine] {words}"), str(bad.value)


def test_a_missing_field_is_named_not_a_traceback(tmp_path: Path) -> None:
    path = tmp_path / "mine.toml"
    path.write_text("\n".join(x for x in tiny_scenario2().splitlines() if not x.startswith(("seeds", "loads"))))
    with pytest.raises(ConfigError, match=re.escape("[profiles.mine] needs loads, seeds (a profile's fields")):
        s2_plan.own_profiles(path)


# -- a profile of one's own ----------------------------------------------------------------------------------------
def test_a_scenario2_profile_of_ones_own_runs(tmp_path: Path, faked_train: list[str],  # noqa: F811
                                              capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """tiny's settings under another name in a file of one's own: the same 8 cells as tiny's, the study named by
    the file's profile (sweep.json, the folder's marker); training faked (no SUMO)."""
    path = tmp_path / "mine.toml"
    path.write_text(tiny_scenario2())
    out = tmp_path / "out"
    code, err = run_main(s2.main, ["--profile", str(path), "--out", str(out), "--quiet", "--bootstrap", "20"], capsys)
    assert code == 0, err
    mine = s2.chosen_profile(str(path))
    assert mine == replace(s2_plan.PROFILES["tiny"], name="mine")
    specs = s2_plan.cell_specs(mine)
    assert [s["key"] for s in specs] == [s["key"] for s in s2_plan.cell_specs(s2_plan.PROFILES["tiny"])]
    assert len(specs) == 8 and sorted(p.stem for p in (out / "cells").glob("*.json")) == sorted(s["key"] for s in specs)
    assert json.loads((out / "sweep.json").read_text())["profile"]["name"] == "mine"
    assert "profile mine: 8 cells" in "\n".join(err)
    # the same command again is the same study, resumed; the packaged tiny profile is another study
    code, err = run_main(s2.main, ["--profile", str(path), "--out", str(out), "--quiet", "--bootstrap", "20"], capsys)
    assert code == 0 and "8 already done" in "\n".join(err), err
    code, err = run_main(s2.main, ["--profile", "tiny", "--out", str(out), "--quiet"], capsys)
    assert code == 2 and len(err) == 1 and "mine" in err[0], err


def test_a_file_of_several_profiles_needs_the_name_of_one(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "mine.toml"
    two = tiny_scenario2("a") + "\n" + with_field(tiny_scenario2("b"), "lanes = [3]")
    path.write_text(two)
    out = tmp_path / "out"
    code, err = run_main(s2.main, ["--profile", str(path), "--out", str(out)], capsys)
    assert code == 2 and len(err) == 1 and "holds 2 profiles (a, b) and no default; name one: --profile" in err[0]
    assert s2.chosen_profile(f"{path}:b").lanes == (3,) and s2.chosen_profile(f"{path}:a").lanes == (2,)
    (tmp_path / "folder.toml").mkdir()
    path.write_text('default = "b"\n' + two)
    assert s2.chosen_profile(str(path)).name == "b"  # the file's default, as the packaged file's
    for text, words in [(f"{path}:c", "has no profile 'c' (it has a, b)"),
                        (str(tmp_path / "none.toml"), "no file"),
                        (str(tmp_path / "folder.toml"), "no file")]:  # fmt: skip
        code, err = run_main(s2.main, ["--profile", text, "--out", str(out)], capsys)
        assert code == 2 and len(err) == 1 and words in err[0], err
    path.write_text(tiny_scenario2("tiny"))  # a packaged profile's name: its folder and records are that profile's
    code, err = run_main(s2.main, ["--profile", str(path), "--out", str(out)], capsys)
    assert code == 2 and len(err) == 1 and "takes the name of a packaged profile" in err[0], err
    code, err = run_main(s2.main, ["--profile", "huge", "--out", str(out)], capsys)
    assert code == 2 and len(err) == 1 and "'huge'" in err[0] and "PATH.toml:NAME" in err[0], err
    assert not out.exists()


def tiny_protocol(name: str = "mine") -> str:
    table = packaged_table(protocol_plan.PROFILES_FILE, "[profiles.tiny]")
    return table.replace("[profiles.tiny]", f"[profiles.{name}]")


@pytest.mark.parametrize(("line", "words"), [
    ("seeds = []", "seeds must be a list of integers from 0 to 2147483647"),
    ("t_ups = [1.5, 1.50]", "t_ups gives the same value twice in [1.5, 1.50]: 1.5 and 1.50"),
    ("t_ups = [nan]", "t_ups must be a list of finite numbers >= 0.1 and <= 3600 s"),
    ("accident_start = 600", "accident_start must be an integer from 0 to 599 (a step of the 600-step run), got 600"),
    ("alpha_seeds = 3", "alpha_seeds must be at most the number of seeds (2)"),
    ("lanes = 7", "lanes must be an integer from 2 to 6, got 7"),
    ("variants = [\"select\", \"select\"]", "variants names 'select' twice"),
    ("seeds = [100, 5000]", "seeds: training seed 5000 is also an evaluation seed"),
    ("eval_offsets = [0, 0]", "eval_offsets gives the same value twice"),
    ("free_steps = 0", "free_steps must be an integer from 1 to 10000000, got 0"),
    ("train_steps = 1", "train_steps: learner select_last drives model_last.pt, the last weights a training writes "
                        "beside the model it selects, and a training of 1 step selects none"),  # probe 15: cells failed
])  # fmt: skip
def test_a_protocol_profile_is_checked_by_the_same_rules(tmp_path: Path, line: str, words: str,
                                                         capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    path = tmp_path / "mine.toml"
    path.write_text(with_field(tiny_protocol(), line))
    out = tmp_path / "out"
    code, err = run_main(protocol.main, ["--profile", str(path), "--out", str(out), "--quiet"], capsys)
    assert code == 2 and len(err) == 1 and err[0].startswith(f"protocol: error: {path}: [profiles.mine] {words}"), err
    assert not out.exists()
    with pytest.raises(ConfigError, match=re.escape(f"[profiles.mine] {words}")):  # the packaged loader: the same
        protocol_plan.load_profiles(protocol_plan.variants(), path.parent / "mine.toml")


def test_a_protocol_profile_of_ones_own_runs_under_its_name(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                            capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """tiny's settings under another name: the cells are tiny's, and the study (run_study faked) is the file's
    profile's, in the folder --out names."""
    path = tmp_path / "mine.toml"
    path.write_text(tiny_protocol())
    ran: list[Any] = []

    def fake_study(profile: Any, root: Path, *args: Any, **kwargs: Any) -> dict[str, Any]:
        ran.append((profile, root))
        return {"cells": len(protocol_plan.cell_specs(profile)), "wall_seconds": 0.0, "failed_cells": []}

    monkeypatch.setattr(protocol, "run_study", fake_study)
    out = tmp_path / "out"
    code, err = run_main(protocol.main, ["--profile", f"{path}:mine", "--out", str(out), "--quiet"], capsys)
    assert code == 0, err
    (profile, root), = ran
    assert profile.name == "mine" and root == out and out.is_dir()
    tiny = protocol_plan.PROFILES["tiny"]
    assert [s["key"] for s in protocol_plan.cell_specs(profile)] == [s["key"] for s in protocol_plan.cell_specs(tiny)]


def test_the_documented_profile_file_runs_as_documented(tmp_path: Path, faked_train: list[str],  # noqa: F811
                                                        monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """docs/studies.md's "A profile of one's own": its file and its commands, run in a folder of their own (training
    faked)."""
    page = (Path(__file__).resolve().parent.parent / "docs" / "studies.md").read_text()
    section = page.split("## A profile of one's own\n", 1)[1].split("\n## ", 1)[0]
    (toml,) = re.findall(r"```toml\n(.*?)```", section, flags=re.S)
    (bash,) = re.findall(r"```bash\n(.*?)```", section, flags=re.S)
    monkeypatch.chdir(tmp_path)
    Path(toml.splitlines()[0].removeprefix("# ").split(":")[0]).write_text(toml)
    for line in bash.strip().splitlines():
        words = line.split()
        assert words[:2] == ["coopsumo", "scenario2"], line
        code, err = run_main(s2.main, [*words[2:], "--quiet", "--bootstrap", "20"], capsys)
        assert code == 0, (line, err)
        out = tmp_path / words[words.index("--out") + 1]
        meta = json.loads((out / "sweep.json").read_text())
        assert meta["profile"]["name"] == "mine" and meta["profile"]["lanes"] == [3]
        assert meta["cells_ok"] == meta["cells"] == 4 * len(meta["profile"]["alphas"])


@pytest.mark.parametrize("name", ["a/../../esc", "", "..", "x y"])
def test_a_profile_name_that_is_no_folder_name_is_refused(name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                          capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """The name chooses the results folder (results/scenario2_<name>): a name with a path in it, or none, is refused
    before anything is written, wherever the command runs."""
    monkeypatch.chdir(tmp_path)  # the default --out, results/scenario2_<name>, would be here
    path = tmp_path / "mine.toml"
    path.write_text(tiny_scenario2().replace("[profiles.mine]", f"[profiles.{json.dumps(name)}]"))
    code, err = run_main(s2.main, ["--profile", f"{path}:{name}" if name else str(path), "--quiet"], capsys)
    assert code == 2 and len(err) == 1 and "must be 1-64 letters" in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.toml"]
