"""Every committed report is the current code's answer: the learner recorded beside it is the learner its command
trains today, or, for a report made by an earlier default learner that no study on today's default has replaced
yet, the learner results/README.md's table "Reports made by an earlier default learner" names for it (a variant of
learners.toml, reproducible at the commit the row names). Reports of learners no longer made live in
results/archive/ and say so at their top."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path
from typing import Any
from unittest import mock

import pytest
from conftest import MADE_BY, REL_TOLERANCE, committed_report_pages, made_by, text_difference

from coopsumo.config import first_difference, results_view, to_dict
from coopsumo.dqn_config import DQN_PRESETS, DQNConfig
from coopsumo.studies.protocol.plan import variants
from coopsumo.studies.scenario2.plan import PROFILES as SCENARIO2_PROFILES
from coopsumo.studies.scenario2.redraw import rewrite_outputs
from coopsumo.studies.scenario2.study import learner_of

ROOT = Path(__file__).resolve().parent.parent
LEARNER_FREE = {"regime_map"}
"""reports without a learned policy (keep through the accident)"""


def committed_reports() -> list[Path]:
    """The report folders under results/ that git tracks (not the archive)."""
    return [page.parent for page in committed_report_pages()]


def _same(recorded: Any, current: Any, what: str) -> None:
    where = first_difference(recorded, current)
    assert where is None, f"{what}: the committed report's learner differs from today's ({where}); remake it"


def _learner_check(folder: Path, marks: dict[str, tuple[str, str]] | None = None) -> None:
    """The learner recorded beside the report in `folder` is today's, or the one its row of made_by names."""
    marks = made_by() if marks is None else marks
    base = variants()[marks[folder.name][0]].learner if folder.name in marks else DQNConfig()
    with mock.patch.dict(DQN_PRESETS, {"default": base}):  # the default its commands trained with
        _recorded_learner_check(folder)


def _recorded_learner_check(folder: Path) -> None:
    name = folder.name
    # the default profile, K models per alpha, of the default learner or other presets (scenario1_alpha_only_10models)
    if re.fullmatch(r"scenario1(_[a-z_]+?)?(_\d+models)?", name) and name not in ("scenario1_quick", "scenario1_full"):
        plan = json.loads((folder / "plan.json").read_text())
        assert set(plan["learners"]) == set(plan["plan"]["presets"])
        for preset, learner in plan["learners"].items():
            _same(learner, to_dict(DQN_PRESETS[preset]), f"{name} ({preset})")
        default = to_dict(DQN_PRESETS["default"])
        _same(plan["learners"].get("default", default), default, name)
    elif name.startswith("learner_protocol"):
        study = json.loads((folder / "study.json").read_text())
        known = variants()
        for variant, entry in study["learners"].items():
            _same(entry["learner"], to_dict(known[variant].learner), f"{name} ({variant})")
            assert entry["weights"] == known[variant].weights
            assert entry.get("drive", {}) == known[variant].drive(), f"{name} ({variant}): driven otherwise"
    elif name in ("scenario2", "scenario2_conditioned", "scenario2_check", "scenario2_confirm") or \
            folder.parent.name == "scenario2_confirm_parts":  # fmt: skip
        sweep = json.loads((folder / "sweep.json").read_text())
        profile = SCENARIO2_PROFILES[sweep["profile"]["name"]]
        _same(sweep["learner"], learner_of(replace(profile, conditioned=sweep["profile"]["conditioned"])), name)
    elif name == "learning" or name.startswith("learning_"):  # the retired learning study's (issue 80)
        study = json.loads((folder / "study.json").read_text())
        _same(study["default_learner"], to_dict(DQN_PRESETS["default"]), f"{name} (the default)")
        assert set(study["learners"]) >= set(study["profile"]["variants"]), f"{name}: a variant without its learner"
        for variant, learner in study["learners"].items():
            _same(learner, to_dict(variants()[variant].learner), f"{name} ({variant})")
    else:
        assert name in LEARNER_FREE, f"results/{name}: a committed report whose learner no test checks"


def test_every_committed_report_was_made_by_todays_learner() -> None:
    folders = committed_reports()
    assert any(f.name == "scenario1" for f in folders)
    for folder in folders:
        _learner_check(folder)


def test_a_report_made_by_an_earlier_default_is_marked_reproducibly() -> None:
    """Each row of the table names a committed report, a variant that is not today's default, and a commit of this
    repository (where its command trains that learner)."""
    names = {f.name for f in committed_reports()}
    for folder, (variant, commit) in made_by().items():
        assert folder in names, f"results/README.md marks {folder}, which is not a committed report"
        assert variants()[variant].learner != DQNConfig(), f"{folder}: {variant} is today's default"
        if (ROOT / ".git").exists():
            found = subprocess.run(["git", "cat-file", "-e", f"{commit}^{{commit}}"], cwd=ROOT, check=False)
            assert found.returncode == 0, f"{folder}: commit {commit} is not in this repository"


PARTS = sorted(f"{p.parent.parent.name}/{p.parent.name}" for folder in ("scenario2_parts", "scenario2_confirm_parts")
               for p in (ROOT / "results" / folder).glob("*/report.md"))  # fmt: skip
"""the committed parts of scenario II's full profile (results/scenario2_parts/README.md) and of its confirmation"""
SWEEPS = [name for name in ("scenario2", "scenario2_check", "scenario2_confirm")
          if (ROOT / "results" / name / "sweep.json").exists()]  # fmt: skip


@pytest.mark.parametrize("study", [*SWEEPS, *PARTS])
def test_scenario2_is_todays_rendering_of_its_runs(study: str, tmp_path: Path) -> None:
    """A committed scenario II keeps no cells/ (rerunning its command would train every cell again): its tables,
    report.md and figures are redrawn from runs.csv, evals.csv and sweep.json by rewrite_outputs, and are what
    today's code draws from them."""
    committed = ROOT / "results" / study
    for name in ("runs.csv", "evals.csv", "sweep.json"):
        if (committed / name).exists():
            shutil.copy(committed / name, tmp_path / name)
    rewrite_outputs(tmp_path)
    tables = [p.name for p in committed.glob("*.csv") if p.name not in ("runs.csv", "evals.csv")]
    for name in ("report.md", "sweep.json", *tables):
        # numbers to a relative 1e-9, not byte for byte: the fits and bootstraps go through BLAS
        where = text_difference((committed / name).read_text(), (tmp_path / name).read_text())
        assert where is None, (
            f"results/{study}/{name} is not what today's code draws from its records ({where}); redraw it with "
            f"coopsumo.studies.scenario2.redraw.rewrite_outputs(Path('results/{study}'))")  # fmt: skip
    assert sorted(p.name for p in committed.glob("*.png")) == sorted(p.name for p in tmp_path.glob("*.png"))


def test_a_redrawn_record_may_differ_only_in_its_numbers_last_bits() -> None:
    """The comparison above could fail: it passes another processor's last bits and nothing more."""
    committed = '{"slope": -0.21047964504306, "n": 12, "name": "L2"}\n| 2 | 0.21 |'
    assert text_difference(committed, committed.replace("04306", "0431")) is None
    moved = text_difference(committed, committed.replace("-0.2104", "-0.2105"))
    assert moved == "line 1: -0.21047964504306 != -0.21057964504306"
    assert text_difference(committed, committed.replace("12", "13")) is not None  # integers exactly
    assert text_difference(committed, committed.replace("0.21 |", "0.22 |")) is not None
    assert text_difference(committed, committed.replace("L2", "L3")) is not None
    assert text_difference(committed, committed.replace("slope", "slop")) is not None
    assert text_difference(committed, committed + " 1") == "the texts hold different numbers of numbers"
    assert text_difference("1.0", f"{1 + REL_TOLERANCE / 2}") is None


def test_the_default_learner_is_the_protocols_stks_and_scenario_ones() -> None:
    """The learner report that adopted today's default judges it."""
    assert (ROOT / "results" / "learner_protocol_stks" / "report.md").is_file()
    assert results_view(to_dict(variants()["stks"].learner)) == results_view(to_dict(DQNConfig()))
    assert results_view(to_dict(DQN_PRESETS["default"])) == results_view(to_dict(DQNConfig()))


def test_the_check_fires_on_a_changed_learner(tmp_path: Path) -> None:
    """The test above could fail: a scenario I plan.json with another learning rate is caught."""
    plan = {"plan": {"presets": ["default"]}, "learners": {"default": to_dict(DQNConfig(lr=0.5))}}
    folder = tmp_path / "scenario1"
    folder.mkdir()
    (folder / "plan.json").write_text(json.dumps(plan))
    with pytest.raises(AssertionError, match=r"config\.lr"):
        _learner_check(folder)
    with pytest.raises(AssertionError, match="no test checks"):
        _learner_check(tmp_path / "learned_old")
    # a report made by an earlier default (here u1's learner, as if it had been the default): caught unless marked
    plan["learners"]["default"] = to_dict(variants()["u1"].learner)
    (folder / "plan.json").write_text(json.dumps(plan))
    with pytest.raises(AssertionError, match=r"differs from today's"):
        _learner_check(folder)
    readme = tmp_path / "README.md"
    readme.write_text(f"# results\n\n{MADE_BY}\n\n| report | learner | commit |\n|---|---|---|\n"
                      "| `scenario1/` | `u1` | `abc1234` |\n\n## Next\n| `scenario2/` | `u1` | `abc1234` |\n")
    assert made_by(readme) == {"scenario1": ("u1", "abc1234")}
    _learner_check(folder, made_by(readme))
    with pytest.raises(AssertionError, match=r"updates_per_learn"):
        _learner_check(folder, {"scenario1": ("nr10", "abc1234")})
    # a learning study whose `mix` variant was trained with another replay size
    folder = tmp_path / "learning"
    folder.mkdir()
    learners = {"paper": to_dict(variants()["paper"].learner),
                "mix": to_dict(replace(variants()["mix"].learner, replay_size=7))}
    study = {"default_learner": to_dict(DQNConfig()), "profile": {"variants": ["paper", "mix"]}, "learners": learners}
    (folder / "study.json").write_text(json.dumps(study))
    with pytest.raises(AssertionError, match=r"learning \(mix\).*replay_size"):
        _learner_check(folder)
    study["learners"]["mix"] = to_dict(variants()["mix"].learner)
    (folder / "study.json").write_text(json.dumps(study))
    _learner_check(folder)
    # the same study under another profile's folder (results/learning_conditioned) is checked alike
    other = tmp_path / "learning_conditioned"
    other.mkdir()
    study["default_learner"] = to_dict(DQNConfig(gamma=0.5))
    (other / "study.json").write_text(json.dumps(study))
    with pytest.raises(AssertionError, match=r"learning_conditioned \(the default\).*gamma"):
        _learner_check(other)


def test_archived_reports_say_so_at_their_top() -> None:
    for page in sorted((ROOT / "results" / "archive").rglob("report.md")):
        head = "\n".join(page.read_text().splitlines()[:4])
        assert "**Archived on " in head and ("earlier default learner" in head or "earlier variant" in head), page
