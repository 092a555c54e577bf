"""The learning study's variants and profiles as data (coopsumo/experiments_data/learning.toml, read by
learning.plan.load_catalogue): the packaged file, a chain built link by link, and one ConfigError line naming the file
and the entry for each kind of bad entry."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from coopsumo.dqn_config import DQN_PRESETS, PAPER_DQN
from coopsumo.errors import ConfigError
from coopsumo.studies.learning import plan

GOOD = """
[variants.p]
preset = "paper"
chain = true
why = "the paper's"
[variants.q]
parent = "p"
chain = true
why = "+ a decision every second"
learner = { decision_interval_steps = 10 }
[variants.r]
parent = "q"
why = "q trained twice as long, with Adam"
learner = { optimizer = "adam", lr = 1 }
steps_factor = 2
[profiles.small]
train_steps = 300
eval_steps = 200
seeds = [0, 1]
variants = ["p", "r"]
alphas = [0, 1]
"""


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "learning.toml"
    path.write_text(text)
    return path


def test_the_packaged_chain_runs_from_the_paper_to_the_chain_end() -> None:
    names = plan.VARIANT_NAMES
    assert names[0] == "paper" and names[plan.CHAIN_LENGTH - 1] == "stacked" and plan.CHAIN_LENGTH == 18
    assert plan.learner_of("paper") == PAPER_DQN
    assert plan.STEPS_FACTOR == {"conditioned8v_2x": 2}
    assert set(plan.PROFILES) == {"full", "quick", "conditioned", "tiny"}
    assert plan.PROFILES["full"].variants[: plan.CHAIN_LENGTH] == names[: plan.CHAIN_LENGTH]


def test_each_variant_is_its_parent_plus_its_changes(tmp_path: Path) -> None:
    variants, chain, factors, profiles = plan.load_catalogue(_write(tmp_path, GOOD))
    (_, _, p), (_, _, q), (_, why, r) = variants
    assert chain == 2 and factors == {"r": 2} and why == "q trained twice as long, with Adam"
    assert p == DQN_PRESETS["paper"]
    assert q == replace(p, decision_interval_steps=10, preset="default")
    assert r == replace(q, optimizer="adam", lr=1.0) and isinstance(r.lr, float)
    assert profiles["small"].alphas == (0.0, 1.0) and profiles["small"].lanes == 3


@pytest.mark.parametrize(("change", "words"), [
    (('[variants.q]\nparent = "p"', '[variants.q]\nparent = "zz"'), "[variants.q] unknown parent 'zz'"),
    (('[variants.q]\nparent = "p"', '[variants.q]\nparent = "p"\npreset = "paper"'), "not both"),
    (("learner = { decision_interval_steps = 10 }", "learner = { decision_interval_step = 10 }"),
     "[variants.q] unknown field 'decision_interval_step' in learner"),
    (("learner = { decision_interval_steps = 10 }", 'learner = { decision_interval_steps = "10" }'),
     "[variants.q] learner.decision_interval_steps must be int"),
    (("learner = { decision_interval_steps = 10 }", "learner = { decision_interval_steps = 0 }"),
     "[variants.q] learner: decision_interval_steps must be"),
    (("steps_factor = 2", "steps_factor = 0"), "[variants.r] steps_factor must be at least 1"),
    (('why = "the paper\'s"', 'why = "the paper\'s"\ncolour = "red"'), "[variants.p] unknown field 'colour'"),
    (("steps_factor = 2\n", 'steps_factor = 2\n[variants.s]\nparent = "r"\nchain = true\nwhy = "s"\n'),
     "[variants.s] is in the chain after"),
    (('variants = ["p", "r"]', 'variants = ["p", "s"]'), "[profiles.small] unknown variant 's'"),
    (("seeds = [0, 1]\n", ""), "[profiles.small] is not a whole profile"),
])  # fmt: skip
def test_a_bad_entry_is_one_line_naming_the_file_and_the_entry(tmp_path: Path, change: tuple[str, str],
                                                               words: str) -> None:  # fmt: skip
    assert change[0] in GOOD
    path = _write(tmp_path, GOOD.replace(change[0], change[1], 1))
    with pytest.raises(ConfigError) as err:
        plan.load_catalogue(path)
    assert str(err.value).startswith(f"{path}: ") and words in str(err.value) and "\n" not in str(err.value)
