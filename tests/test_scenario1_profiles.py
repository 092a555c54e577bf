"""Issue 80, item 2: scenario I's profiles are data (coopsumo/experiments_data/scenario1.toml) read by the one profile
loader (studies/engine/catalogue.py), as scenario II's are; a profile of one's own (`--profile PATH.toml[:NAME]`) is
read and checked the same way, by the flags' rules, before anything is written."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import pytest

from coopsumo.config import to_dict
from coopsumo.errors import ConfigError
from coopsumo.studies.scenario1 import plan as s1_plan
from coopsumo.studies.scenario1 import regime_map
from coopsumo.studies.scenario1 import study as s1

COMMON = {"lanes": 3, "train_t_up_s": 1.0, "trajectory_every": 5, "baselines": ("keep", "greedy", "sumo"),
          "mobil_ps": (0.0, 0.5), "alphas": (0.0, 8.0), "presets": ("default",), "fcd_period_s": 5.0,
          "tripinfo": True}  # fmt: skip
TODAY = {  # the profiles' values as Plan(), Plan.quick() and Plan.full() gave them in code (commit 8272c65)
    "default": {**COMMON, "t_ups": (2.0, 1.5, 1.0), "train_steps": 90000, "steps": 20000, "accident_start": 2000,
                "accident_steps": 10000, "seeds": (1, 2, 3, 4, 5), "train_seeds": (100, 101, 102, 103, 104),
                "loop_period_s": 60.0, "profile": "default"},
    "quick": {**COMMON, "t_ups": (3.0, 1.0), "train_steps": 3000, "steps": 6000, "accident_start": 1000,
              "accident_steps": 3000, "seeds": (1,), "train_seeds": (100, 101), "loop_period_s": 30.0,
              "profile": "quick"},
    "full": {**COMMON, "t_ups": (3.0, 2.0, 1.5, 1.0), "train_steps": 90000, "steps": 90000, "accident_start": 20000,
             "accident_steps": 50000, "seeds": (1, 2, 3, 4, 5), "train_seeds": (100, 101, 102, 103, 104),
             "loop_period_s": 60.0, "profile": "full"},
}  # fmt: skip
FIELD_ORDER = ["lanes", "t_ups", "train_t_up_s", "train_steps", "steps", "accident_start", "accident_steps", "seeds",
               "train_seeds", "trajectory_every", "loop_period_s", "baselines", "mobil_ps", "alphas", "presets",
               "fcd_period_s", "tripinfo", "profile"]  # fmt: skip
"""plan.json's keys in order (to_dict(plan)): a record written before the move reads the same"""
DIGESTS = {"default": "4b079aadf65b5e29", "quick": "a497f4ba28bbc2f9", "full": "fcb17900912d8cc3"}
"""each profile's trainings, baseline runs, outputs and results folder, as the code of commit 8272c65 made them"""


def cells_digest(plan: s1_plan.Plan) -> str:
    cells: list[Any] = [to_dict(s1_plan.train_config(plan, a, p, s)) for p in plan.presets for a in plan.alphas
                        for s in plan.train_seeds]  # fmt: skip
    cells += [to_dict(s1_plan.accident_config(plan, b, k, t)) for b in plan.baseline_policies() for t in plan.t_ups
              for k in plan.seeds]  # fmt: skip
    cells += [to_dict(plan.outputs()), str(s1_plan.study_out(plan))]
    return hashlib.sha256(json.dumps(cells, sort_keys=True).encode()).hexdigest()[:16]


@pytest.mark.parametrize("name", sorted(TODAY))
def test_each_profile_read_from_the_file_is_todays_plan(name: str) -> None:
    plan = s1_plan.PROFILES[name]
    assert asdict(plan) == TODAY[name] and list(asdict(plan)) == FIELD_ORDER
    assert cells_digest(plan) == DIGESTS[name]  # no cell identity, model identity or run folder changes


def test_the_packaged_profiles_and_the_default() -> None:
    assert list(s1_plan.PROFILES) == ["default", "quick", "full"] and s1_plan.DEFAULT_PROFILE == "default"
    assert set(s1_plan.PROFILE_HELP) == set(s1_plan.PROFILES)


def test_the_regime_map_starts_from_the_default_and_full_profiles() -> None:
    plans = regime_map.plans(1, regime_map.DEMANDS)
    for length, profile in (("default", "default"), ("paper", "full")):
        want = {**TODAY[profile], "seeds": (1,), "t_ups": (4.0, 3.0, 2.5, 2.0, 1.5, 1.25, 1.0)}
        assert asdict(plans[length]) == want


@pytest.mark.parametrize(("flags", "name"), [([], "default"), (["--quick"], "quick"), (["--full"], "full"),
                                             (["--profile", "quick"], "quick"), (["--profile", "full"], "full")])
def test_the_flags_choose_the_profile(flags: list[str], name: str) -> None:
    args = s1.build_parser().parse_args(flags)
    assert asdict(s1.plan_from_args(args)) == TODAY[name]


# -- a profile of one's own ----------------------------------------------------------------------------------------
MINE = {"use": '"study"', "t_ups": "[3, 1]", "steps": "6000", "accident_start": "1000", "accident_steps": "3000"}
"""a profile of one's own: the packaged shared table's settings, and its own demands and accident"""


def own_file(tmp_path: Path, line: str = "", name: str = "mine") -> Path:
    """A file of one's own: the profile `name` (MINE with `key = value` of `line` set) and the packaged file's
    [shared.study] table."""
    settings = dict(MINE)
    if line:
        key, value = (x.strip() for x in line.split("=", 1))
        settings[key] = value
    shared = s1_plan.PROFILES_FILE.read_text().split("[shared.study]", 1)[1].split("\n[", 1)[0]
    path = tmp_path / "own.toml"
    path.write_text("\n".join([f"[profiles.{name}]", *(f"{k} = {v}" for k, v in settings.items()),
                               "[shared.study]" + shared]) + "\n")  # fmt: skip
    return path


def run_main(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str]]:
    try:
        code = s1.main(argv)
    except SystemExit as stop:
        code = int(stop.code or 0)
    return code, capsys.readouterr().err.strip().splitlines()


def test_a_profile_of_ones_own_is_read_as_the_packaged_ones(tmp_path: Path) -> None:
    path = own_file(tmp_path, "seeds = [1, 2]")
    args = s1.build_parser().parse_args(["--profile", f"{path}:mine"])
    plan = s1.plan_from_args(args)
    assert plan == replace(s1_plan.PROFILES["default"], profile="mine", t_ups=(3.0, 1.0), steps=6000,
                           accident_start=1000, accident_steps=3000, seeds=(1, 2))  # fmt: skip
    assert s1_plan.study_out(plan) == Path("results/scenario1_mine")
    assert s1.plan_from_args(s1.build_parser().parse_args(["--profile", str(path)])) == plan  # its only profile


def test_a_profile_of_ones_own_runs_into_its_own_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`scenario1 --profile own.toml:mine` runs the file's profile (the flags over it) into results/scenario1_mine."""
    path = own_file(tmp_path, "seeds = [1, 2]")
    ran: list[tuple[s1_plan.Plan, Path]] = []
    monkeypatch.setattr(s1, "run_study", lambda plan, root, *_, **__: ran.append((plan, root)) or 0)
    monkeypatch.chdir(tmp_path)
    assert s1.main(["--profile", f"{path}:mine", "--alphas", "8", "--quiet"]) == 0
    ((plan, root),) = ran
    assert root == Path("results/scenario1_mine") and plan.profile == "mine" and plan.seeds == (1, 2)
    assert plan.alphas == (0.0, 8.0) and plan.t_ups == (3.0, 1.0)


BAD = [
    ("seeds = []", "seeds must be a list of integers from 0 to 2147483647"),
    ("alphas = [0, 0.0]", "alphas gives the same value twice in [0, 0.0]: 0 and 0.0"),
    ("mobil_ps = [-1, 1]", "mobil_ps must be a list of finite numbers >= 0 and <= 10, got [-1, 1]"),
    ("t_ups = [0]", "t_ups must be a list of"),
    ("steps = 5", "steps must be an integer from 10 to 10000000, got 5"),
    ("train_steps = 0", "train_steps must be an integer from 1 to 10000000, got 0"),
    ("presets = [\"fastest\"]", "presets names unknown 'fastest'"),
    ("lanes = 7", "lanes must be an integer from 2 to 6, got 7"),
    ("steps = \"many\"", "steps must be int, got 'many'"),
    ("what = 1", "unknown field 'what' in the profile"),
    ("accident_start = 7000", "accident_start must be an integer from 0 to 5999 (a step of the 6000-step run), got "
                              "7000"),
    ("train_seeds = [1, 100]", "train_seeds: training seed 1 is also an evaluation seed"),
    ("alphas = [8]", "alphas must hold 0, the study's reference, got [8]"),
    ("fcd_period_s = 0.15", "makes a run the simulation refuses: fcd period must be a multiple of the 0.1 s step"),
    ("use = \"other\"", "use must name a [shared.NAME] table (study), got 'other'"),
]  # fmt: skip


@pytest.mark.parametrize(("line", "words"), BAD, ids=[c[0] for c in BAD])
def test_a_bad_value_in_a_profile_of_ones_own_is_one_line_and_nothing_written(
        tmp_path: Path, line: str, words: str, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    path = own_file(tmp_path, line)
    out = tmp_path / "out"
    code, err = run_main(["--profile", f"{path}:mine", "--out", str(out), "--quiet"], capsys)
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f"scenario1: error: {path}: [profiles.mine] {words}"), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["own.toml"]  # no --out, no model store


def test_a_profile_of_ones_own_may_not_take_a_packaged_name(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    path = own_file(tmp_path, name="quick")
    code, err = run_main(["--profile", f"{path}:quick", "--out", str(tmp_path / "out")], capsys)
    assert code == 2 and len(err) == 1 and "takes the name of a packaged profile" in err[0], err


def test_an_unknown_profile_is_refused_naming_both_forms(capsys: pytest.CaptureFixture[str]) -> None:
    code, err = run_main(["--profile", "huge"], capsys)
    assert code == 2 and "choose from default, quick, full, or a profile file of your own" in err[-1], err


def test_the_packaged_file_is_checked_by_the_same_rules(tmp_path: Path) -> None:
    """The packaged scenario1.toml with a bad value: one ConfigError line naming the file, the profile and the field
    (read when scenario1.plan is imported, so `coopsumo scenario1` stops before anything is written)."""
    path = tmp_path / "scenario1.toml"
    path.write_text(s1_plan.PROFILES_FILE.read_text().replace("steps = 6000", "steps = 5", 1))
    with pytest.raises(ConfigError) as bad:
        s1_plan.load_profiles(path)
    assert str(bad.value) == f"{path}: [profiles.quick] steps must be an integer from 10 to 10000000, got 5"
    path.write_text(s1_plan.PROFILES_FILE.read_text().replace('default = "default"', 'default = "huge"', 1))
    with pytest.raises(ConfigError, match=r"default must name one of its profiles \(default, quick, full\)"):
        s1_plan.load_profiles(path)


def test_a_missing_field_is_named(tmp_path: Path) -> None:
    path = own_file(tmp_path)
    path.write_text(path.read_text().replace('use = "study"\n', ""))
    with pytest.raises(ConfigError, match=r"\[profiles.mine\] needs lanes, train_t_up_s, train_steps, seeds"):
        s1_plan.own_profiles(path)
