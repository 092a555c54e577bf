"""The learning study's learners and profiles as data (coopsumo/experiments_data/learning.toml naming learners.toml's
learners, read by learning.plan.load_catalogue): the packaged file, a chain built link by link, and one ConfigError
line naming the file and the entry for each kind of bad entry."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from coopsumo.dqn_config import DQN_PRESETS, PAPER_DQN, DQNConfig
from coopsumo.errors import ConfigError
from coopsumo.studies.engine.catalogue import Learner, load_learners
from coopsumo.studies.learning import plan

LEARNERS = """
[d]
preset = "default"
status = "default"
why = "today's default"
[p]
preset = "paper"
status = "current"
why = "the paper's"
[q]
parent = "p"
status = "current"
why = "+ a decision every second"
learner = { preset = "default", decision_interval_steps = 10 }
[r]
parent = "q"
status = "tried"
why = "q trained twice as long, with Adam"
learner = { optimizer = "adam", lr = 1 }
steps_factor = 2
[last]
parent = "q"
status = "tried"
why = "q's last weights"
weights = "model_last.pt"
"""

GOOD = """
chain = ["p", "q"]
variants = ["r"]
[profiles.small]
train_steps = 300
eval_steps = 200
seeds = [0, 1]
variants = ["p", "r"]
alphas = [0, 1]
"""


def _write(tmp_path: Path, text: str, learners: str = LEARNERS) -> tuple[Path, dict[str, Learner]]:
    path = tmp_path / "learning.toml"
    path.write_text(text)
    (tmp_path / "learners.toml").write_text(learners)
    return path, load_learners(tmp_path / "learners.toml")


def test_the_packaged_chain_runs_from_the_paper_to_the_chain_end() -> None:
    names = plan.VARIANT_NAMES
    assert names[0] == "paper" and names[plan.CHAIN_LENGTH - 1] == "stacked" and plan.CHAIN_LENGTH == 18
    assert plan.learner_of("paper") == PAPER_DQN
    assert plan.STEPS_FACTOR == {"conditioned8v_2x": 2}
    assert set(plan.PROFILES) == {"full", "quick", "conditioned", "tiny"}
    assert plan.PROFILES["full"].variants[: plan.CHAIN_LENGTH] == names[: plan.CHAIN_LENGTH]


def test_each_variant_is_its_parent_plus_its_changes(tmp_path: Path) -> None:
    variants, chain, factors, profiles = plan.load_catalogue(*_write(tmp_path, GOOD))
    (_, _, p), (_, _, q), (_, why, r) = variants
    assert chain == 2 and factors == {"r": 2} and why == "q trained twice as long, with Adam"
    assert p == DQN_PRESETS["paper"]
    assert q == replace(p, decision_interval_steps=10, preset="default")
    assert r == replace(q, optimizer="adam", lr=1.0) and isinstance(r.lr, float)
    assert profiles["small"].alphas == (0.0, 1.0) and profiles["small"].lanes == 3


@pytest.mark.parametrize(("change", "words"), [
    (('chain = ["p", "q"]', 'chain = ["p", "zz"]'), "[file] chain names unknown 'zz'"),
    (('variants = ["r"]', 'variants = ["q"]'), "[file] learner 'q' is named twice"),
    (('variants = ["r"]', 'variants = ["r", "last"]'), "[file] learner 'last' drives otherwise than with model.pt"),
    (('variants = ["r"]', 'variants = "r"'), "[file] variants must be a list"),
    (('chain = ["p", "q"]', 'chain = ["p", "q"]\ncolour = "red"'), "[file] unknown field 'colour'"),
    (('variants = ["p", "r"]', 'variants = ["p", "s"]'), "[profiles.small] unknown variant 's'"),
    (("seeds = [0, 1]\n", ""), "[profiles.small] is not a whole profile"),
])  # fmt: skip
def test_a_bad_entry_is_one_line_naming_the_file_and_the_entry(tmp_path: Path, change: tuple[str, str],
                                                               words: str) -> None:  # fmt: skip
    assert change[0] in GOOD
    path, learners = _write(tmp_path, GOOD.replace(change[0], change[1], 1))
    with pytest.raises(ConfigError) as err:
        plan.load_catalogue(path, learners)
    assert str(err.value).startswith(f"{path}: ") and words in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize(("change", "words"), [
    (("steps_factor = 2", "steps_factor = 0"), "[r] steps_factor must be at least 1"),
    (("steps_factor = 2", 'steps_factor = "2"'), "[r] steps_factor must be int"),
    (("learner = { optimizer", "learner = { optimiser"), "[r] unknown field 'optimiser' in learner"),
])  # fmt: skip
def test_a_bad_learner_is_one_line_naming_the_catalogue_and_the_learner(tmp_path: Path, change: tuple[str, str],
                                                                        words: str) -> None:  # fmt: skip
    with pytest.raises(ConfigError) as err:
        _write(tmp_path, GOOD, LEARNERS.replace(change[0], change[1], 1))
    assert str(err.value).startswith(f"{tmp_path / 'learners.toml'}: ") and words in str(err.value), str(err.value)


def test_the_catalogue_gives_the_protocol_and_the_learning_study_the_same_learners() -> None:
    """One file: a name means one learner in every study (issue 80: learners.toml's `select` and `margin` and
    learning.toml's were different learners); the protocol's names of the chain's learners are those learners."""
    from coopsumo.studies.protocol.plan import variants

    known = variants()
    for name, _, learner in plan.VARIANTS:
        assert known[name].learner == learner, name
    for protocol, chain in (("nr10", "noreturn"), ("f05q_ts2k", "target"), ("stks", "stacked"),
                            ("c2x", "conditioned8v")):  # fmt: skip
        assert known[protocol].learner == known[chain].learner
    assert known["stacked"].learner == DQNConfig() and known["select_last"].weights == "model_last.pt"
