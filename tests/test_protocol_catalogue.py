"""The learner protocol's catalogue as data (coopsumo/experiments_data/learners.toml and protocol.toml): each bad
entry is one ConfigError naming the file and the entry; the packaged files hold what the current reports need."""

from __future__ import annotations

from pathlib import Path

import pytest

from coopsumo.dqn_config import DQN_PRESETS
from coopsumo.errors import ConfigError
from coopsumo.studies.protocol import plan as protocol_plan
from coopsumo.studies.protocol.plan import load_profiles, load_variants

BASE = '''
[nr10]
preset = "default"
status = "default"
why = "the default"

[f05q_ts2k]
parent = "nr10"
status = "retired"
why = "the default before"
learner = { no_return_s = 0.0 }
'''

X = '[x]\nparent = "nr10"\nstatus = "tried"\nwhy = "w"\n'
VARIANT_ERRORS = [
    (X + 'colour = "red"', "x", "unknown field 'colour' in a learner"),
    (X + 'learner = { lrate = 0.1 }', "x", "unknown field 'lrate' in learner"),
    (X + 'learner = { preset = "fancy" }', "x", "learner: preset must be one of"),
    (X + 'drive = { margin = 2 }', "x", "unknown field 'margin' in drive"),
    ('[x]\nparent = "nr9"\nstatus = "tried"\nwhy = "w"', "x", "unknown parent 'nr9'"),
    ('[x]\npreset = "fancy"\nstatus = "tried"\nwhy = "w"', "x", "unknown preset 'fancy' (one of default, paper"),
    ('[x]\nparent = "nr10"\npreset = "paper"\nstatus = "tried"\nwhy = "w"', "x", "not both"),
    ('[x]\nstatus = "tried"\nwhy = "w"', "x", "needs a parent"),
    ('[a]\nparent = "b"\nstatus = "tried"\nwhy = "w"\n[b]\nparent = "a"\nstatus = "tried"\nwhy = "w"', "a",
     "is its own ancestor: a -> b -> a"),
    ('[x]\nparent = "x"\nstatus = "tried"\nwhy = "w"', "x", "is its own ancestor: x -> x"),
    ('[x]\nparent = "nr10"\nstatus = "maybe"\nwhy = "w"', "x", "unknown status 'maybe' (one of default, current"),
    ('[x]\nparent = "nr10"\nstatus = "tried"', "x", "needs why"),
    (X + 'learner = { gamma = "high" }', "x", "learner.gamma must be float, got 'high'"),
    (X + 'learner = { batch_size = true }', "x", "learner.batch_size must be int"),
    (X + 'learner = { train_t_ups = 2.0 }', "x", "learner.train_t_ups must be a list"),
    (X + 'learner = { gamma = 1.5 }', "x", "learner: gamma must be a finite number >= 0 and < 1, got 1.5"),
    (X + 'drive = { queue_below_mps = "slow" }', "x", "drive.queue_below_mps must be float"),
    (X + 'drive = { ensemble_snapshots = 2 }', "x", "unknown field 'ensemble_snapshots' in drive"),
    (X + 'weights = "best.pt"', "x", "weights must be one of"),
    ("x = 3", "x", "a learner must be a table, got 3"),
    ('[x]\npreset = "default"\nstatus = "default"\nwhy = "w"', None, "exactly one learner has status 'default'"),
]


@pytest.mark.parametrize("extra, entry, fragment", VARIANT_ERRORS, ids=[e[2][:40] for e in VARIANT_ERRORS])
def test_a_bad_variant_is_one_error_naming_the_file_and_the_entry(tmp_path: Path, extra: str, entry: str | None,
                                                                   fragment: str) -> None:  # fmt: skip
    path = tmp_path / "learners.toml"
    path.write_text(extra + "\n" + BASE)
    with pytest.raises(ConfigError) as err:
        load_variants(path)
    text = str(err.value)
    assert text.startswith(f"{path}: " + (f"[{entry}] " if entry else "")) and fragment in text, text
    assert "\n" not in text


@pytest.mark.parametrize("text, fragment", [
    ('[nr10]\npreset = "default"\nstatus = "default"\nwhy = "w"\nlearner = { gamma = 0.5 }',
     "[nr10] has status 'default' but is not the default preset"),
    ('[nr10]\npreset = "default"\nstatus = "current"\nwhy = "w"', "exactly one learner has status 'default'"),
    ("[nr10\n", "not TOML"),
])  # fmt: skip
def test_the_catalogue_names_exactly_one_default_the_default_preset(tmp_path: Path, text: str, fragment: str) -> None:
    path = tmp_path / "learners.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"^" + str(path).replace("\\", "\\\\")) as err:
        load_variants(path)
    assert fragment in str(err.value)
    with pytest.raises(ConfigError, match="cannot read it"):
        load_variants(tmp_path / "missing.toml")


PROFILE = '[profiles.p]\nhelp = "w"\nvariants = ["nr10"]\n'
PROFILE_ERRORS = [
    (PROFILE + "steps = 5", "p", "unknown field 'steps' in the profile"),
    (PROFILE + "name = 'q'", "p", "unknown field 'name' in the profile"),
    ('[profiles.p]\nhelp = "w"\nvariants = ["nope"]', "p", "unknown variant 'nope'"),
    ('[profiles.p]\nhelp = "w"\nvariants = []', "p", "needs variants"),
    ('[profiles.p]\nhelp = 3\nvariants = ["nr10"]', "p", "help must be str"),
    (PROFILE + 'judged = "f05q_ts2k"', "p", "judges 'f05q_ts2k', which it does not run"),
    (PROFILE + 'paired_with = [["nr10", "learner_protocol_x", "gone"]]', "p", "unknown variant 'gone'"),
    (PROFILE + 'paired_with = [["f05q_ts2k", "learner_protocol_x", "nr10"]]', "p",
     "pairs 'f05q_ts2k', which it does not run"),
    (PROFILE + 'paired_with = [["nr10", "learner_protocol_x"]]', "p", "paired_with must be a list of 3"),
    (PROFILE + 'seeds = "100"', "p", "seeds must be a list, got '100'"),
    (PROFILE + "train_steps = 9e4", "p", "train_steps must be int, got 9e4"),
    (PROFILE + "t_ups = [2, true]", "p", "t_ups must be float, got True"),
    (PROFILE + "alphas = [0, 8]", "p", "alphas must be a list of finite numbers > 0"),
    (PROFILE + "alphas = [1, 1.0]", "p", "alphas gives the same value twice"),
    (PROFILE + 'alpha_variants = ["f05q_ts2k"]', "p", "alpha_variants names unknown 'f05q_ts2k'"),
    (PROFILE + 'alpha_variants = ["nr10", "nr10"]', "p", "alpha_variants names 'nr10' twice"),
]


@pytest.mark.parametrize("text, entry, fragment", PROFILE_ERRORS, ids=[e[2][:40] for e in PROFILE_ERRORS])
def test_a_bad_profile_is_one_error_naming_the_file_and_the_entry(tmp_path: Path, text: str, entry: str,
                                                                   fragment: str) -> None:  # fmt: skip
    (tmp_path / "learners.toml").write_text(BASE)
    path = tmp_path / "protocol.toml"
    path.write_text('default = "p"\n' + text + "\n")
    with pytest.raises(ConfigError) as err:
        load_profiles(load_variants(tmp_path / "learners.toml"), path)
    assert str(err.value).startswith(f"{path}: [profiles.{entry}] ") and fragment in str(err.value), str(err.value)


def test_the_default_profile_must_be_one_of_the_file(tmp_path: Path) -> None:
    known = load_variants(protocol_plan.LEARNERS_FILE)
    path = tmp_path / "protocol.toml"
    for head in ('default = "q"\n', ""):
        path.write_text(head + PROFILE)
        with pytest.raises(ConfigError, match=r"default must name one of its profiles \(p\), got "):
            load_profiles(known, path)
    path.write_text('default = "p"\n' + PROFILE + "t_ups = [2, 1]\n")
    profiles, default = load_profiles(known, path)
    assert default == "p" and profiles["p"].t_ups == (2.0, 1.0)  # integers where floats belong become floats
    path.write_text('current = "p"\n' + PROFILE)  # the format before 2026-12-04: one line naming what it knows
    with pytest.raises(ConfigError, match=r"unknown top-level keys 'current' \(known: default, shared, profiles\)"):
        load_profiles(known, path)


def test_the_packaged_catalogue_holds_the_current_profiles_and_what_they_pair_with() -> None:
    """Inside the package (an installed wheel reads it too); every profile's variants and pairs are in it, nr10 is
    the one default and the default preset, nr10 (the default before it) that learner with torch's updates and a
    one-stage selection, c2x is the learning study's conditioned8v on it."""
    from dataclasses import replace

    from coopsumo.agents.conditioning import CONDITIONED8V

    assert protocol_plan.LEARNERS_FILE.parent == Path(protocol_plan.__file__).parents[2] / "experiments_data"
    known = protocol_plan.variants()
    assert {"nr10_3sets", "alpha_only", "tiny"} <= set(protocol_plan.PROFILES) and protocol_plan.CURRENT == "stks"
    assert ("nr10", "learner_protocol_f05q_ts2k10", "f05q_ts2k") in protocol_plan.PROFILES["nr10"].paired_with
    assert known["stks"].learner == DQN_PRESETS["default"]
    assert known["nr10"].learner == replace(DQN_PRESETS["default"], stacked_updates=False, validation_screen=0)
    assert known["alpha_only"].learner == DQN_PRESETS["alpha_only"]
    dense = replace(DQN_PRESETS["alpha_only"], train_t_ups=(2.67, 2.0, 1.5, 1.33, 1.0, 0.89, 0.67),
                    validation_t_ups=(2.0, 1.0, 0.67))  # fmt: skip
    assert known["alpha_only_dense"].learner == dense and dense.accident_share == dense.validation_accident_steps == 0
    assert protocol_plan.PROFILES["alpha_only_dense"].variants == ("alpha_only", "alpha_only_dense")
    assert known["c2x"].learner == replace(known["nr10"].learner, **CONDITIONED8V)  # made on nr10
    assert known["f05q_ts2k"].learner == replace(known["nr10"].learner, no_return_s=0.0)
    assert known["select_last"].learner == known["select"].learner and known["select_last"].weights == "model_last.pt"


def test_a_refused_catalogue_ends_the_command_in_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                          capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """protocol_plan reads the catalogue when it is imported: `coopsumo protocol` then says the error in one line,
    exit 2, not a traceback."""
    from coopsumo import cli

    (tmp_path / "broken_protocol.py").write_text(
        "from coopsumo.config import ConfigError\nraise ConfigError(\"learners.toml: [x] unknown parent 'nr9'\")\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(cli.COMMANDS, "protocol", ("broken_protocol", "judge learners"))
    assert cli.main(["protocol", "--profile", "nr10"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["coopsumo protocol: error: learners.toml: [x] unknown parent 'nr9'"]
