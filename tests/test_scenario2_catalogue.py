"""Scenario II's profiles as data (coopsumo/experiments_data/scenario2.toml, read by scenario2.plan.load_profiles):
the packaged file, and one ConfigError line naming the file and the entry for each kind of bad entry."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import pytest

from coopsumo.errors import ConfigError
from coopsumo.studies.scenario2 import plan

GOOD = """
default = "a"
[shared.base]
train_steps = 500
eval_steps = 200
[profiles.a]
help = "one"
use = "base"
lanes = [2]
loads = [0.5, 1]
alphas = [0, 8]
seeds = [1, 2]
eval_seeds = 2
[profiles.b]
lanes = [3]
loads = [1]
alphas = [1]
seeds = [1]
train_steps = 100
eval_steps = 100
"""


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "scenario2.toml"
    path.write_text(text)
    return path


def test_the_packaged_profiles() -> None:
    assert plan.DEFAULT_PROFILE == "full"
    assert set(plan.PROFILES) == {"tiny", "full", "check", "confirm", "paper"}
    assert all(plan.PROFILE_HELP[name] for name in plan.PROFILES)
    full, check = plan.PROFILES["full"], plan.PROFILES["check"]
    # per lane count and seed: a model per alpha (every profile but check), or check's conditioned network beside
    # per-alpha models at its check alphas
    assert all(p.alpha_models and not p.check_alphas for name, p in plan.PROFILES.items() if name != "check")
    assert not check.alpha_models and check.check_alphas == (0.0, 1.0, 8.0) and check.n_trainings() == 12
    assert full.eval_seeds == (2001, 2002, 2003) and plan.PROFILES["paper"].eval_seeds[-1] == 2005
    # every float of the grid is a float, so that a model's identity (its configuration's JSON) stays what it was
    assert json.dumps(asdict(full)["alphas"]) == "[0.0, 0.25, 1.0, 2.0, 8.0, 32.0]"


def test_a_profile_starts_from_the_shared_table_it_uses(tmp_path: Path) -> None:
    profiles, helps, default = plan.load_profiles(_write(tmp_path, GOOD))
    a, b = profiles["a"], profiles["b"]
    assert default == "a" and helps == {"a": "one", "b": ""}
    assert (a.train_steps, a.eval_steps, a.alphas, a.eval_seeds) == (500, 200, (0.0, 8.0), (2001, 2002))
    assert (b.train_steps, b.eval_steps, b.eval_seeds) == (100, 100, (2001,))  # the defaults but for its own


@pytest.mark.parametrize(
    ("change", "words"),
    [
        (("lanes = [2]", "lanes = [2]\nlane = 3"), "[profiles.a] unknown field 'lane'"),
        (('use = "base"', 'use = "other"'), "[profiles.a] use must name a [shared.NAME] table"),
        (("alphas = [0, 8]", 'alphas = ["0", 8]'), "[profiles.a] alphas must be float"),
        (('default = "a"', 'default = "c"'), "default must name one of its profiles"),
        (("eval_steps = 200", "eval_steps = 200\nseed = 1"), "[shared.base] unknown field 'seed'"),
        (("[profiles.b]", "colour = 1\n[profiles.b]"), None),
        (('default = "a"', 'default = "a"\nwhat = 1'), "unknown top-level keys 'what'"),
        # the per-alpha design's setting, retired on 2026-12-03 (every profile is of lane networks)
        (("lanes = [2]", "lanes = [2]\nlane_networks = true"), "[profiles.a] unknown field 'lane_networks'"),
    ],
)
def test_a_bad_entry_is_one_line_naming_it(tmp_path: Path, change: tuple[str, str], words: str | None) -> None:
    path = _write(tmp_path, GOOD.replace(*change, 1))
    with pytest.raises(ConfigError) as bad:
        plan.load_profiles(path)
    text = str(bad.value)
    assert len(text.splitlines()) == 1 and str(path) in text and (words or "unknown field 'colour'") in text, text
