"""engine/catalogue's plan flags (issue 80): a study's options come from a table of its plan's fields; the tables
of scenario I and scenario II each name a field of their plan, and apply in order."""

from __future__ import annotations

import argparse
from dataclasses import dataclass, fields

import pytest

from coopsumo.errors import UsageError
from coopsumo.studies.engine.catalogue import PlanFlag, add_plan_flags, at_least, plan_from_flags
from coopsumo.studies.scenario1 import study as scenario1
from coopsumo.studies.scenario2 import study as scenario2


@dataclass(frozen=True)
class Plan:
    steps: int = 5
    doubled: int = 10


FLAGS = (
    PlanFlag(("--steps",), at_least("steps", "steps", 2), "steps", lambda p: p.steps, int),
    PlanFlag(("--double",), lambda on, plan: {"doubled": 2 * plan.steps}, "twice the steps so far", kind=int),
)


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_plan_flags(parser, FLAGS, {"a": Plan(), "b": Plan(steps=7)})
    return parser.parse_args(argv)


def test_given_flags_set_their_fields_in_the_tables_order_and_unset_ones_leave_the_plan() -> None:
    assert plan_from_flags(Plan(), _parse([]), FLAGS) == Plan()
    assert plan_from_flags(Plan(), _parse(["--double", "1", "--steps", "4"]), FLAGS) == Plan(steps=4, doubled=8)
    with pytest.raises(UsageError, match=r"^steps must be >= 2, got 1$"):
        plan_from_flags(Plan(), _parse(["--steps", "1"]), FLAGS)


def test_help_states_each_profiles_default_or_the_one_they_share() -> None:
    parser = argparse.ArgumentParser()
    add_plan_flags(parser, FLAGS, {"a": Plan(), "b": Plan(steps=7)})
    text = " ".join(parser.format_help().split())
    assert "steps (default: the profile's: a 5; b 7)" in text and "twice the steps so far" in text


@pytest.mark.parametrize("study,plan", [(scenario1, scenario1.PROFILES["default"]),
                                        (scenario2, scenario2.PROFILES["full"])])  # fmt: skip
def test_every_studys_flag_sets_fields_of_its_plan(study: object, plan: object) -> None:
    names = {f.name for f in fields(plan)}  # type: ignore[arg-type]
    parser = study.build_parser()  # type: ignore[attr-defined]
    for flag in study.PLAN_FLAGS:  # type: ignore[attr-defined]
        assert any(flag.names[0] in a.option_strings for a in parser._actions), flag.names
        dest = flag.dest or flag.names[0].removeprefix("--").replace("-", "_")
        assert dest in {a.dest for a in parser._actions}, flag.names
    sample = {"--steps": "1000", "--eval-steps": "500", "--train-steps": "800", "--seeds": "2", "--alphas": "0,1"}
    for flag in study.PLAN_FLAGS:  # type: ignore[attr-defined]
        if flag.names[0] in sample:
            changed = flag.apply(flag.kind(sample[flag.names[0]]) if flag.kind else sample[flag.names[0]], plan)
            assert changed and set(changed) <= names, (flag.names, changed)
