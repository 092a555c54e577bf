"""Issue 82, probe 14, F7 and F8: a number is judged by the text it is written as, wherever it is read. F7: a number
that is not 0 but too small for a float (1e-400) was taken as 0 in the list flags, the policy parameters and the
profile files; F8: a profile file's value over a limit by less than a float's precision was taken, though the flag
refuses it (TOML gives the float already rounded; the loader now keeps the file's text: field_rules.Written)."""

from __future__ import annotations

from pathlib import Path

import pytest

from coopsumo.cli import main as cli_main
from coopsumo.errors import ConfigError
from coopsumo.policy_spec import PolicySpecError, parse_policy
from coopsumo.studies.scenario1 import plan as s1_plan
from coopsumo.studies.scenario2 import plan as s2_plan
from coopsumo.validation import ALPHA_LIST, MOBIL_P_LIST

SMALL = "too small for a float"


def main(argv: list[str]) -> int:
    try:
        return cli_main(argv)
    except SystemExit as stop:  # argparse's error, in this process
        return int(stop.code or 0)


@pytest.mark.parametrize(("command", "flags"), [
    ("scenario2", ["--profile", "tiny", "--alphas", "1e-400,1"]),
    ("scenario2", ["--profile", "tiny", "--policies", "dqn,mobil", "--mobil-p", "1e-400"]),
    ("scenario1", ["--quick", "--alphas", "0,1e-400"]),
    ("simulate", ["--policy", "mobil:p=1e-400"]),
    ("simulate", ["--policy", "sumo:lcCooperative=1e-400"]),
])  # fmt: skip
def test_a_flags_number_too_small_for_a_float_is_refused(command: str, flags: list[str], tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    code = main([command, *flags, "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and SMALL in err[0] and "1e-400" in err[0], err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("policy", ["mobil:p=1e-400", "mobil:threshold=1e-400", "mobil:bias=1e-400",
                                    "sumo:lcCooperative=1e-400", "dqn:m.pt,margin=1e-400", "mobil:p=1e-999"])
def test_a_policy_parameter_too_small_for_a_float_is_refused(policy: str) -> None:
    with pytest.raises(PolicySpecError, match=SMALL):
        parse_policy(policy)


def test_zero_written_any_way_and_small_numbers_are_taken() -> None:
    assert parse_policy("mobil:p=0e5").values() == {"p": 0.0}
    assert parse_policy("mobil:p=1e-300").values() == {"p": 1e-300}
    assert ALPHA_LIST.parse("--alphas", "0,1/8,1e-300") == (0.0, 0.125, 1e-300)
    assert MOBIL_P_LIST.parse("--mobil-p", "-0.0,1") == (0.0, 1.0)
    for text in ("1e-400/1", "1e-200/1e200"):
        with pytest.raises(Exception, match=SMALL):
            ALPHA_LIST.parse("--alphas", f"0,{text}")


S2_BASE = ('[profiles.mine]\nalpha_models = true\npolicies = ["dqn"]\ntrain_steps = 200\neval_steps = 300\n'
           'eval_seeds = 1\nlanes = [2]\nseeds = [1]\n')  # fmt: skip


@pytest.mark.parametrize(("lines", "words"), [
    ("alphas = [1e-400, 1]\nloads = [0.25]", f"alphas must be a list of finite numbers >= 0 and <= 1000, got "
                                              f"[1e-400, 1]: 1e-400 is {SMALL}"),
    ("alphas = [0, 1000.00000000000000001]\nloads = [0.25]",
     "alphas must be a list of finite numbers >= 0 and <= 1000, got [0, 1000.00000000000000001]"),
    ("alphas = [0]\nloads = []\nt_up_s = [3600.00000000000001]",
     "t_up_s must be a list of finite numbers >= 0.1 and <= 3600 s"),
    ("alphas = [0]\nloads = [0.25]\nalpha_draw_max = 1000.00000000000000001", "alpha_draw_max must be a finite"),
])  # fmt: skip
def test_a_scenario2_profile_files_number_is_judged_as_written(tmp_path: Path, lines: str, words: str) -> None:
    path = tmp_path / "mine.toml"
    path.write_text(S2_BASE + lines + "\n")
    with pytest.raises(ConfigError) as bad:
        s2_plan.own_profiles(path)
    assert str(bad.value).startswith(f"{path}: [profiles.mine] {words}"), str(bad.value)


def test_a_profile_files_values_at_their_limits_are_taken(tmp_path: Path) -> None:
    path = tmp_path / "mine.toml"
    path.write_text(S2_BASE + "alphas = [0, 1000.000, 1e-300]\nloads = [0.25]\n")
    profile = s2_plan.own_profiles(path)[0]["mine"]
    assert profile.alphas == (0.0, 1000.0, 1e-300) and all(type(a) is float for a in profile.alphas)


S1_BASE = """[profiles.mine]
lanes = 2
train_t_up_s = 1
train_steps = 200
train_seeds = [100]
seeds = [1]
alphas = [0]
presets = ["default"]
baselines = ["keep"]
trajectory_every = 5
loop_period_s = 30
fcd_period_s = 5
tripinfo = true
steps = 300
accident_start = 50
accident_steps = 100
"""


@pytest.mark.parametrize(("lines", "words"), [
    ("mobil_ps = [0, 10.0000000000000000001]\nt_ups = [2]",
     "mobil_ps must be a list of finite numbers >= 0 and <= 10, got [0, 10.0000000000000000001]"),
    ("mobil_ps = [0]\nt_ups = [3600.00000000000001]", "t_ups must be a list of finite numbers >= 0.1 and <= 3600 s"),
    ("mobil_ps = [1e-400]\nt_ups = [2]", f"mobil_ps must be a list of finite numbers >= 0 and <= 10, got [1e-400]: "
                                         f"1e-400 is {SMALL}"),
    ("mobil_ps = [0]\nt_ups = [2]\ntrain_t_up_s = 1e-400", "train_t_up_s must be a finite number >= 0.1"),
])  # fmt: skip
def test_a_scenario1_profile_files_number_is_judged_as_written(tmp_path: Path, lines: str, words: str) -> None:
    path = tmp_path / "mine.toml"
    path.write_text(S1_BASE.replace("train_t_up_s = 1\n", "") if "train_t_up_s" in lines else S1_BASE)
    path.write_text(path.read_text() + lines + "\n")
    with pytest.raises(ConfigError) as bad:
        s1_plan.own_profiles(path)
    message = str(bad.value)
    assert message.startswith(f"{path}: [profiles.mine] {words}") and "\n" not in message, message
    assert "got 0.0" not in message and "[0.0" not in message  # as written, never as the float it rounds to


def test_a_float_field_without_a_rule_refuses_a_number_too_small(tmp_path: Path) -> None:
    from coopsumo.studies.engine.catalogue import Entry, read_toml

    path = tmp_path / "x.toml"
    path.write_text("x = 1e-400\ny = 0.0e7\n")
    data = read_toml(path)
    at = Entry(path, "t")
    with pytest.raises(ConfigError, match=SMALL):
        at.value("x", data["x"], float)
    assert at.value("y", data["y"], float) == 0.0
