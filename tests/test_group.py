"""A group of trainings whose gradient updates run together in one update process (agents/group.py, the stacked
learner of issue 77): a member's model is the same bit for bit as when it trains alone, whatever the others' seeds,
alphas and lane counts; a member that fails fails alone; only one learner's trainings make a group; a study's
trainings of the stacked learner go into the model store as groups."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
import torch

from coopsumo.agents.group import group_problem, train_group
from coopsumo.agents.model_file import load_model
from coopsumo.agents.train import train
from coopsumo.config import SimConfig, TrainConfig
from coopsumo.errors import ConfigError


def stacked(seed: int, alpha: float = 0.0, lanes: int = 3, steps: int = 400) -> TrainConfig:
    """A short training that learns from step 100 with the stacked learner (no model selection)."""
    cfg = TrainConfig(sim=SimConfig(steps=steps, seed=seed, policy="dqn"), eval_steps=0, log_every_steps=300)
    sim = dataclasses.replace(cfg.sim, reward=dataclasses.replace(cfg.sim.reward, alpha=alpha),
                              road=dataclasses.replace(cfg.sim.road, lanes=lanes))  # fmt: skip
    return dataclasses.replace(cfg, sim=sim, dqn=dataclasses.replace(cfg.dqn, stacked_updates=True,
                                                                     select_every_steps=0, learn_start_steps=100))


def weights(folder: Path) -> dict[str, torch.Tensor]:
    return load_model(folder / "model.pt")[0].state_dict()


def test_a_member_of_a_group_learns_what_it_learns_alone_and_fails_alone(tmp_path: Path) -> None:
    """Member 1 (another member with another seed, alpha and lane count beside it) is bit-identical to its lone
    training; member 2, whose folder is a user's file, fails alone."""
    alone = train(stacked(7), tmp_path / "alone", progress=False)
    assert alone["updates"] > 0 and alone["learner_process"] is True
    (tmp_path / "taken").write_text("a user's file\n")
    results = train_group([stacked(5, alpha=8.0, lanes=2), stacked(7), stacked(4)],
                          [tmp_path / "g0", tmp_path / "g1", tmp_path / "taken"])  # fmt: skip
    assert [r.error is None for r in results] == [True, True, False] and results[2].summary is None
    assert (tmp_path / "taken").read_text() == "a user's file\n"
    assert results[1].summary is not None and results[1].summary["updates"] == alone["updates"]
    mine, other, lone = weights(tmp_path / "g1"), weights(tmp_path / "g0"), weights(tmp_path / "alone")
    assert all(torch.equal(mine[k], lone[k]) for k in lone)
    assert not all(torch.equal(other[k], lone[k]) for k in lone)  # the other member learned its own model
    log = [(tmp_path / f / "train_log.csv").read_text().splitlines() for f in ("g1", "alone")]
    assert [r.split(",")[:4] for r in log[0]] == [r.split(",")[:4] for r in log[1]]


def test_only_one_learners_stacked_trainings_make_a_group() -> None:
    assert group_problem([stacked(1), stacked(2, alpha=8.0, lanes=5)]) is None
    other = stacked(2)
    other = dataclasses.replace(other, dqn=dataclasses.replace(other.dqn, lr=1e-4))
    assert "another learner" in (group_problem([stacked(1), other]) or "")
    plain = dataclasses.replace(other, dqn=dataclasses.replace(other.dqn, stacked_updates=False))
    assert "stacked_updates" in (group_problem([plain]) or "")
    with pytest.raises(ConfigError, match="another learner"):
        train_group([stacked(1), other], [Path("unused0"), Path("unused1")])


def test_a_studys_stacked_trainings_are_grouped_by_learner(tmp_path: Path) -> None:
    from coopsumo.config import to_dict
    from coopsumo.studies.engine.groups import groups_to_train

    def spec(cfg: TrainConfig, nested: bool) -> dict[str, object]:
        return {"key": f"k{cfg.sim.seed}", "config": {"train": to_dict(cfg)} if nested else to_dict(cfg),
                "kind": "eval" if nested else "train", "training": cfg}  # fmt: skip

    slow = stacked(20)
    slow = dataclasses.replace(slow, dqn=dataclasses.replace(slow.dqn, lr=1e-4))
    plain = dataclasses.replace(stacked(30), dqn=dataclasses.replace(stacked(30).dqn, stacked_updates=False))
    specs = [spec(stacked(s), s % 2 == 0) for s in range(1, 7)] + [spec(stacked(3), True), spec(slow, False),
                                                                   spec(plain, False)]  # fmt: skip
    groups = groups_to_train(specs, tmp_path / "store", size=4)
    assert [[g.sim.seed for g in group] for group in groups] == [[1, 2, 3, 4], [5, 6]]  # seed 3 once; the
    # lone learner (lr 1e-4) and the plain one are no group: their cells train them as ever


def test_a_studys_groups_land_in_the_model_store(tmp_path: Path) -> None:
    from coopsumo.config import to_dict
    from coopsumo.studies.engine.groups import train_groups
    from coopsumo.studies.engine.model_store import model_id, stored_model

    trainings = [stacked(s, steps=300) for s in (1, 2)]
    configs = [to_dict(t) for t in trainings]
    specs = [{"key": f"train_{i}", "kind": "train", "config": c, "training": t}
             for i, (c, t) in enumerate(zip(configs, trainings, strict=True))]
    store = tmp_path / "models"
    assert train_groups(specs, store, quiet=True) == 2
    assert all(stored_model(c, store) == store / model_id(c) for c in configs)
    shares = [json.loads((store / model_id(c) / "group_cost.json").read_text()) for c in configs]
    assert all(s["group_size"] == 2 and s["cpu_s"] > 0 for s in shares) and shares[0] == shares[1]
    assert train_groups(specs, store, quiet=True) == 0  # stored: nothing to train


@pytest.mark.parametrize("text, share", [
    ('{"group_size": 4, "cpu_s": 12.5}', 12.5), ('{"group_size": 4, "cpu_s": 1e300}', None),
    ('{"group_size": 4, "cpu_s": NaN}', None), ('{"group_size": 4, "cpu_s": -50}', None),
    ('{"group_size": 4, "cpu_s": true}', None), ("[1]", None), ("{", None),
    ('{"group_size": 4, "cpu_s": 600000}', None), ('{"group_size": "x", "cpu_s": 12.5}', None),
    ('{"group_size": 0, "cpu_s": 12.5}', None), ('{"cpu_s": 12.5}', None),
])  # fmt: skip
def test_a_groups_cost_record_outside_its_limits_is_left_out_in_one_line(
        text: str, share: float | None, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Also a share its group could not spend in its training's wall time (issue 82, probe 8, J11: 600,000 s of a
    2 s training made a report's 166.67 core-hours) and a group size that is no count of models."""
    from coopsumo.studies.engine.groups import group_cpu_s, groups_cpu_s

    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "train_summary.json").write_text('{"wall_seconds": 2.2}')
    (tmp_path / "m" / "group_cost.json").write_text(text)
    assert group_cpu_s(tmp_path / "m") == share and groups_cpu_s([tmp_path / "m", tmp_path / "m"]) == (share or 0.0)
    err = capsys.readouterr().err.splitlines()
    assert (not err) if share is not None else (len(err) == 2 and "group_cost.json is damaged" in err[0])
    assert group_cpu_s(tmp_path) is None  # trained alone: no record, no line
    assert not capsys.readouterr().err


def test_a_member_whose_group_has_gone_ends_without_a_word(tmp_path: Path) -> None:
    """A Ctrl-C stops the group's process: a member that then tells its outcome finds the pipe broken and ends quietly
    (it printed a BrokenPipeError traceback, 2026-12-03); with the group's end open the outcome arrives."""
    import multiprocessing

    from coopsumo.agents.group import MemberResult, tell

    mine, theirs = multiprocessing.Pipe(duplex=False)
    tell(theirs, MemberResult(tmp_path, {"steps": 1}))
    assert mine.recv() == MemberResult(tmp_path, {"steps": 1}) and theirs.closed
    mine, theirs = multiprocessing.Pipe(duplex=False)
    mine.close()  # the group's process has gone
    tell(theirs, MemberResult(tmp_path, None, "Stop: SIGINT"))
    assert theirs.closed
