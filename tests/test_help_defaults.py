"""What a study's --help states as a default is what the code does: each stated default is read back from the help
text and compared with the plan the command builds without that option (issue 68: `scenario1 --help` said
`--seeds (default 3)` while the code used 5)."""

from __future__ import annotations

import argparse
import re

from coopsumo.config import results_view, to_dict
from coopsumo.dqn_config import DQNConfig
from coopsumo.studies.engine.run_folders import default_out
from coopsumo.studies.protocol import plan as protocol_plan
from coopsumo.studies.protocol import study as protocol
from coopsumo.studies.scenario1 import study as scenario1
from coopsumo.studies.scenario2 import study as scenario2


def option_help(parser: argparse.ArgumentParser, flag: str) -> str:
    (action,) = [a for a in parser._actions if flag in a.option_strings]
    return " ".join((action.help or "").split())


def stated(text: str, profiles: tuple[str, ...]) -> dict[str, str]:
    """The default a help text states for each profile: "(default: the profile's: tiny A; quick B; paper C)", the
    profile's name before its value; one value without a profile is every profile's. Parts that name no profile after
    the first (e.g. "with --preset: ...") are left out."""
    match = re.search(r"\(default: (.*)\)", text)
    assert match, text
    body = match.group(1).removeprefix("the profile's: ")
    out: dict[str, str] = {}
    for i, part in enumerate(body.split("; ")):
        for name in profiles:
            if part.startswith(f"{name} "):
                out[name] = part.removeprefix(f"{name} ")
                break
        else:
            if i == 0:
                out[""] = part
    if set(out) == {""}:
        return {name: out[""] for name in profiles}
    return {name: out.get(name, out.get("", "")) for name in profiles}


def numbers(values: tuple[float, ...]) -> str:
    return ",".join(f"{x:g}" for x in values)


def test_scenario1_help_states_each_profiles_defaults() -> None:
    parser = scenario1.build_parser()
    names = tuple(scenario1.PROFILES)
    plans = {name: scenario1.plan_from_args(parser.parse_args(["--profile", name])) for name in names}
    expected = {
        "--seeds": lambda plan: str(len(plan.seeds)),
        "--train-seeds": lambda plan: str(len(plan.train_seeds)),
        "--t-up": lambda plan: numbers(plan.t_ups),
        "--mobil-p": lambda plan: numbers(plan.mobil_ps),
        "--train-steps": lambda plan: f"{plan.train_steps:,}",
        "--steps": lambda plan: f"{plan.steps:,}",
        "--alphas": lambda plan: numbers(plan.alphas),
        "--preset": lambda plan: ",".join(plan.presets),
        "--out": lambda plan: str(scenario1.study_out(plan)),
    }
    wrong = []
    for option, show in expected.items():
        text = option_help(parser, option)
        says = stated(text, names)
        for name, plan in plans.items():
            if says[name] != show(plan):
                wrong.append(f"{option} ({name}): help says {says[name]!r}, code {show(plan)!r}")
    assert not wrong, "; ".join(wrong)
    assert plans["default"].seeds == (1, 2, 3, 4, 5)  # the case, read from the code's plan
    assert "(default: the profile's: default 5;" in option_help(parser, "--seeds")
    assert scenario1.plan_from_args(parser.parse_args([])) == plans[scenario1.DEFAULT_PROFILE] == plans["default"]


def test_scenario2_help_states_each_profiles_defaults() -> None:
    parser = scenario2.build_parser()
    names = tuple(scenario2.PROFILES)
    profiles = {name: scenario2.profile_from_args(parser.parse_args(["--profile", name])) for name in names}
    expected = {
        "--steps": lambda f: f"{f.train_steps:,}",
        "--eval-steps": lambda f: f"{f.eval_steps:,}",
        "--seeds": lambda f: str(len(f.seeds)),
        "--eval-seeds": lambda f: str(len(f.eval_seeds)),
        "--lanes": lambda f: numbers(f.lanes),
        "--alphas": lambda f: numbers(f.alphas),
        "--mobil-p": lambda f: numbers(f.mobil_ps),
        "--preset": lambda f: f.preset,
    }
    wrong = []
    for option, show in expected.items():
        says = stated(option_help(parser, option), names)
        for name, profile in profiles.items():
            if says[name] != show(profile):
                wrong.append(f"{option} ({name}): help says {says[name]!r}, code {show(profile)!r}")
    assert not wrong, "; ".join(wrong)
    assert parser.get_default("profile") == scenario2.DEFAULT_PROFILE
    assert scenario2.DEFAULT_PROFILE == "full"  # issue 65: the lane networks, baselines and the gate
    default = default_out("scenario2", scenario2.DEFAULT_PROFILE, scenario2.DEFAULT_PROFILE)
    assert f"(default {default}, another profile results/scenario2_<profile>)" in option_help(parser, "--out")
    assert str(default) == "results/scenario2"
    policies = stated(option_help(parser, "--policies"), names)
    assert policies == {name: ",".join(profile.policies) for name, profile in profiles.items()}


def test_protocol_without_a_profile_judges_todays_default_learner_and_says_so() -> None:
    parser = protocol.build_parser()
    current = parser.get_default("profile")
    assert current == protocol_plan.CURRENT
    judged = protocol_plan.PROFILES[current].judged_variant()
    assert results_view(to_dict(protocol_plan.variants()[judged].learner)) == results_view(to_dict(DQNConfig()))
    text = option_help(parser, "--profile")
    assert f"{current} (the default) judges today's default learner" in text
    assert all(re.search(rf"\b{name}\b", text) for name in protocol_plan.PROFILES), text  # every profile listed
    assert "results/history/README.md" in text  # where the earlier ones are
    assert f"(default results/learner_protocol_{current};" in option_help(parser, "--out")


# -- every default in the form its flag takes (issue 81: `train --help` printed `(2.0, 1.5, 1.0)` and `True`) -------
PYTHON_FORMS = re.compile(r"\((?:[-+\d.e]+, )+[-+\d.e]+,?\)|\(\)|\[[^\]]*'[^\]]*\]|\b(?:True|False|None)\b")
"""a tuple, an empty tuple, a list of strings, a bool or None as Python prints them"""


def test_no_help_prints_a_python_value() -> None:
    import importlib

    from coopsumo import cli

    found = {}
    for name, (module, _) in cli.COMMANDS.items():
        text = " ".join(importlib.import_module(module).build_parser().format_help().split())
        found.update({name: hits} if (hits := PYTHON_FORMS.findall(text)) else {})
    assert not found, found


def test_train_help_states_each_presets_learner_values_as_the_flags_take_them() -> None:
    """Each learner flag's help states the default preset's value and every other preset's that differs; each
    stated value, given to its flag (beside --preset P), makes P's setting again."""
    from coopsumo.agents import train_cli
    from coopsumo.dqn_config import DQN_PRESETS, LEARNER_FLAGS

    select = ["--select-every", "15000"]
    enable = {"--alpha-period": ["--alpha-conditioned"], "--alpha-relabel": ["--alpha-conditioned"],
              "--alpha-draw-max": ["--alpha-conditioned"], "--validation-alphas": ["--alpha-conditioned", *select],
              "--validation-seed": select, "--validation-t-up": select, "--validation-steps": select,
              "--episode-steps": ["--accident-share", "0.5"],
              "--validation-screen": select, "--validation-finalists": [*select, "--validation-screen", "1"]}
    assert set(enable) == set(train_cli.FLAG_NEEDS)  # the flags that act only beside another, given it
    parser = train_cli.build_parser()
    checked = empty = 0
    for flag, name, kind, _ in LEARNER_FLAGS:
        match = re.search(r"\((default preset: [^()]*)\)$", option_help(parser, flag))
        assert match, flag
        says = dict(part.split(": ", 1) for part in match.group(1).split("; "))
        says = {"default": says.pop("default preset"), **says}
        assert set(says) <= set(DQN_PRESETS), flag
        for preset, cfg in DQN_PRESETS.items():
            value = says.get(preset, says["default"])  # not named: the default preset's value
            want = getattr(cfg, name)
            if value == "empty":
                assert want == (), f"{flag} ({preset}): help says empty, the preset has {want!r}"
                empty += 1
                continue
            if kind is bool:
                assert value in (flag, f"--no-{flag[2:]}"), f"{flag} ({preset}): {value}"
                args = ["--preset", preset, *enable.get(flag, []), value]
            else:
                args = ["--preset", preset, *enable.get(flag, []), flag, value]
            got = getattr(train_cli.learner_from_args(parser.parse_args(args)), name)
            assert got == want, f"{flag} {value} ({preset}): makes {got!r}, the preset has {want!r}"
            checked += 1
    assert checked + empty == len(DQN_PRESETS) * len(LEARNER_FLAGS) and empty <= 12
    text = option_help(parser, "--validation-t-up")
    assert "(default preset: 2,1.5,1)" in text and "(2.0" not in text  # the case
    assert "(default preset: --action-mask; paper: --no-action-mask)" in option_help(parser, "--action-mask")
    assert "--no-action-mask" in parser.format_help()  # a flag is never broken across lines at its hyphens


def test_train_preset_lists_every_preset() -> None:
    from coopsumo.agents import train_cli
    from coopsumo.dqn_config import DQN_PRESETS

    parser = train_cli.build_parser()
    (action,) = [a for a in parser._actions if "--preset" in a.option_strings]
    assert action.choices is not None and tuple(action.choices) == tuple(DQN_PRESETS)
    assert "alpha_only" in DQN_PRESETS
    text = option_help(parser, "--preset")
    assert all(f"'{name}' (" in text for name in DQN_PRESETS), text
    assert train_cli.learner_from_args(parser.parse_args(["--preset", "alpha_only"])) == DQN_PRESETS["alpha_only"]
