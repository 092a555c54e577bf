"""The learner ablation as data: protocol.toml's `learning` profile runs the chain of learners.toml from the paper's
learner to the default design, one change a link (the learning study's chain until issue 80 retired the study); the
catalogue builds each learner as its parent plus its changes, and a bad learner is one ConfigError line naming the
catalogue and the learner."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from coopsumo.dqn_config import DQN_PRESETS, PAPER_DQN, DQNConfig
from coopsumo.errors import ConfigError
from coopsumo.studies.engine.catalogue import load_learners
from coopsumo.studies.protocol.plan import PROFILES, cell_specs, variants

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
"""
BRANCHES = ("eps_decay", "store_all", "margin2", "conditioned", "conditioned8", "conditioned8v", "conditioned8v_2x")
"""the learning study's variants off the chain's end when they were made, `noreturn`"""


def test_the_chain_adds_one_change_at_a_time_from_the_paper_to_the_default() -> None:
    profile = PROFILES["learning"]
    known = variants()
    chain = [known[name] for name in profile.variants]
    assert chain[0].name == "paper" and chain[0].learner == PAPER_DQN and len(chain) == 18
    assert chain[-1].name == "stacked" == profile.judged_variant() and chain[-1].learner == DQNConfig()
    fields = DQNConfig.__dataclass_fields__
    base = known["noreturn"]
    for before, after in [*zip(chain, chain[1:], strict=False), *((base, known[b]) for b in BRANCHES)]:
        changed = [f for f in fields if f != "preset" and getattr(before.learner, f) != getattr(after.learner, f)]
        assert 1 <= len(changed) <= 3, (after.name, changed)  # one idea (e.g. replay size + its update rate)
    # the protocol's names of the chain's learners are those learners
    names = (("nr10", "noreturn"), ("f05q_ts2k", "target"), ("stks", "stacked"), ("c2x", "conditioned8v"))
    for protocol, link in names:
        assert known[protocol].learner == known[link].learner
    assert known["select_last"].weights == "model_last.pt" and known["conditioned8v_2x"].steps_factor == 2
    # every link trained on the same seeds and judged on the same evaluation seeds, none a training seed
    specs = cell_specs(profile)
    models = [s for s in specs if s["kind"] == "model"]
    assert {s["variant"] for s in models if s["alpha"] == 0} == set(profile.variants)
    assert {s["variant"] for s in models if s["alpha"] > 0} == {"stacked"}
    assert not {s["eval_seed"] for s in specs} & set(profile.seeds)


def test_each_learner_is_its_parent_plus_its_changes(tmp_path: Path) -> None:
    (tmp_path / "learners.toml").write_text(LEARNERS)
    known = load_learners(tmp_path / "learners.toml")
    p, q, r = known["p"].learner, known["q"].learner, known["r"].learner
    assert p == DQN_PRESETS["paper"]
    assert q == replace(p, decision_interval_steps=10, preset="default")
    assert r == replace(q, optimizer="adam", lr=1.0) and isinstance(r.lr, float)
    assert known["r"].steps_factor == 2 and known["r"].text == "q trained twice as long, with Adam"


@pytest.mark.parametrize(("change", "words"), [
    (("steps_factor = 2", "steps_factor = 0"), "[r] steps_factor must be at least 1"),
    (("steps_factor = 2", 'steps_factor = "2"'), "[r] steps_factor must be int"),
    (("learner = { optimizer", "learner = { optimiser"), "[r] unknown field 'optimiser' in learner"),
])  # fmt: skip
def test_a_bad_learner_is_one_line_naming_the_catalogue_and_the_learner(tmp_path: Path, change: tuple[str, str],
                                                                        words: str) -> None:  # fmt: skip
    (tmp_path / "learners.toml").write_text(LEARNERS.replace(change[0], change[1], 1))
    with pytest.raises(ConfigError) as err:
        load_learners(tmp_path / "learners.toml")
    assert str(err.value).startswith(f"{tmp_path / 'learners.toml'}: ") and words in str(err.value), str(err.value)
