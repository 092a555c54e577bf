"""Issue 82, probe 16, T1: `train --resume` over a checkpoint tensor of an odd shape or dtype ended in a traceback
(Adam's step of two entries, empty or 2x1: a ValueError in checkpoint_bounds; complex replay rewards, features, Adam
step or first moment: a NotImplementedError in file_checks.deciding_entries; bool replay rewards: one in
checkpoint_bounds), and float16, float64 or integer features, rewards, weights and moments, bool or uint8 actions were
resumed after a cast without a word. Every tensor of a checkpoint is now judged for the dtype and shape a training
saves (agents/checkpoint_kinds.py) before any of its values is: one line naming the field, exit 2, nothing changed."""

from __future__ import annotations

import copy
import shutil
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
import torch
from conftest import interrupted_at_step_20
from test_corrupt_files import one_line, snapshot

from coopsumo.agents import train_cli as train
from coopsumo.agents.checkpoint_kinds import KINDS, kind_problem
from coopsumo.agents.file_checks import checkpoint_problem
from coopsumo.config import SimConfig, TrainConfig
from coopsumo.dqn_config import DQN_PRESETS
from coopsumo.record_schemas import CHECKPOINT_TENSORS


def _folder(out: Path, **dqn: Any) -> Path:
    """A learner interrupted at step 20 after real gradient updates (Adam's moments and step as torch saves them)."""
    settings = replace(DQN_PRESETS["default"], learn_start_steps=5, batch_size=8, decision_interval_steps=1,
                       replay_size=2000, select_every_steps=0, **dqn)  # fmt: skip
    cfg = TrainConfig(sim=SimConfig(steps=40, seed=3, policy="dqn"), dqn=settings, eval_steps=0, log_every_steps=15,
                      checkpoint_every_steps=20)  # fmt: skip
    interrupted_at_step_20(cfg, out).replace(out / "checkpoint.pt")
    return out


@pytest.fixture(scope="module")
def checkpoint_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _folder(tmp_path_factory.mktemp("kinds") / "run", stacked_updates=False)


def _state(folder: Path) -> dict[str, Any]:
    return copy.deepcopy(torch.load(folder / "checkpoint.pt", weights_only=True))


def _adam(change: Callable[[torch.Tensor], Any], name: str = "step") -> Callable[[dict[str, Any]], None]:
    def spoil(state: dict[str, Any]) -> None:
        for moments in state["learner"]["optimizer"]["state"].values():
            moments[name] = change(moments[name])

    return spoil


def _replay(name: str, change: Callable[[torch.Tensor], torch.Tensor]) -> Callable[[dict[str, Any]], None]:
    def spoil(state: dict[str, Any]) -> None:
        data = state["learner"]["buffer"]["data"]
        data[name] = change(data[name])

    return spoil


def _online(change: Callable[[torch.Tensor], torch.Tensor]) -> Callable[[dict[str, Any]], None]:
    def spoil(state: dict[str, Any]) -> None:
        online = state["learner"]["online"]
        online["out.bias"] = change(online["out.bias"])

    return spoil


def _lr_tensor(state: dict[str, Any]) -> None:
    state["learner"]["optimizer"]["param_groups"][0]["lr"] = torch.tensor(1e-3 + 0j)


COMPLEX = torch.complex64
CASES: dict[str, tuple[Callable[[dict[str, Any]], None], str]] = {
    # the probe's tracebacks (2026-12-04)
    "Adam's step a 2-vector": (_adam(lambda s: torch.stack([s, s])),
                               "has Adam's step for parameter 0 of shape (2,), not one number"),
    "Adam's step empty": (_adam(lambda s: torch.zeros(0)), "has Adam's step for parameter 0 of shape (0,), not one"),
    "Adam's step 2x1": (_adam(lambda s: s.reshape(1, 1).repeat(2, 1)), "step for parameter 0 of shape (2, 1), not one"),
    "Adam's step complex": (_adam(lambda s: s.to(COMPLEX)),
                            "has Adam's step for parameter 0 a torch.complex64 tensor, not a tensor of floats"),
    "Adam's first moment complex": (_adam(lambda m: m.to(COMPLEX), "exp_avg"),
                                    "has Adam's exp_avg for parameter 0 a torch.complex64 tensor, not a tensor of "
                                    "floats"),
    "replay rewards complex": (_replay("rewards", lambda r: r.to(COMPLEX)),
                               "has replay rewards a torch.complex64 tensor, not a tensor of floats"),
    "replay features complex": (_replay("features", lambda f: f.to(COMPLEX)),
                                "has replay features a torch.complex64 tensor, not a tensor of floats"),
    "replay rewards bool": (_replay("rewards", lambda r: r > 0),
                            "has replay rewards a torch.bool tensor, not a tensor of floats"),
    # resumed after a cast, without a word
    "replay features float16": (_replay("features", lambda f: f.half()),
                                "has replay features a torch.float16 tensor, not the torch.float32 one a training"),
    "replay features float64": (_replay("next_features", lambda f: f.double()), "replay next_features a torch.float64"),
    "replay rewards integers": (_replay("rewards", lambda r: r.round().long()), "rewards a torch.int64 tensor, not a "
                                "tensor of floats"),
    "Adam's moments integers": (_adam(lambda m: m.round().long(), "exp_avg_sq"),
                                "has Adam's exp_avg_sq for parameter 0 a torch.int64 tensor, not a tensor of floats"),
    "online weights float16": (_online(lambda w: w.half()),
                               "has online weights 'out.bias' a torch.float16 tensor, not the torch.float32 one"),
    "online weights complex": (_online(lambda w: w.to(COMPLEX)),
                               "has online weights 'out.bias' a torch.complex64 tensor, not a tensor of floats"),
    "replay actions uint8": (_replay("actions", lambda a: a.to(torch.uint8)),
                             "has replay actions a torch.uint8 tensor, not the torch.int64 one a training saves"),
    "replay actions bool": (_replay("actions", lambda a: a.clamp(0, 1).bool()),
                            "has replay actions a torch.bool tensor, not a tensor of integers"),
    "replay grids bool": (_replay("grids", lambda g: g.bool()), "has replay grids a torch.bool tensor, not a tensor"),
    "replay next mask of bytes": (_replay("next_mask", lambda m: m.to(torch.uint8)),
                                  "has replay next_mask a torch.uint8 tensor, not a tensor of true/false values"),
    "replay rewards of two columns": (_replay("rewards", lambda r: torch.stack([r, r], 1)),
                                      "has replay rewards of shape (2000, 2), not of shape (rows,)"),
    "replay grids of another shape": (_replay("grids", lambda g: g.reshape(len(g), -1)),
                                      "has replay grids of shape (2000, 180), not of shape (rows, 3, 3, 20)"),
    "recorded actions int64": (lambda s: s.update(actions=s["actions"].long()),
                               "has recorded actions a torch.int64 tensor, not the torch.int8 one a training saves"),
    # a tensor where a training saves a number: a complex learning rate reached deciding_entries too
    "a learning rate as a complex tensor": (_lr_tensor, "holds a tensor at learner.optimizer.param_groups.0.lr, where "
                                            "a training saves none"),
    "the step as a tensor": (lambda s: s.update(step=torch.tensor(s["step"])), "holds a tensor at step, where"),
}  # fmt: skip


def test_a_real_checkpoint_holds_the_kinds_declared(checkpoint_folder: Path) -> None:
    state = _state(checkpoint_folder)
    assert kind_problem(state) is None and checkpoint_problem(state) is None
    assert state["learner"]["optimizer"]["state"], "the fixture made no gradient update"


def test_a_stacked_or_conditioned_learners_checkpoint_holds_them_too(tmp_path: Path) -> None:
    """The default learner's stacked updates save Adam's state through their own code (agents/stacked.py); an
    alpha-conditioned memory holds its alphas and lane changes too."""
    assert kind_problem(_state(_folder(tmp_path / "stacked"))) is None
    state = _state(_folder(tmp_path / "conditioned", alpha_conditioned=True, stacked_updates=False))
    assert {"alphas", "lane_changes"} <= set(state["learner"]["buffer"]["data"]) and kind_problem(state) is None


def test_every_tensor_field_with_limits_has_its_kind() -> None:
    """The limits of record_schemas.CHECKPOINT_TENSORS are judged only after the kind: each tensor field there is
    declared here (the log window's and the optimizer's settings are plain numbers)."""
    tensors = [f.name for f in CHECKPOINT_TENSORS if f.name.startswith(("learner.buffer", "learner.optimizer.state"))
               or f.name.startswith(tuple(f"learner.{net}." for net in ("online", "target", "average")))]  # fmt: skip
    assert tensors and all(tuple(name.split(".")) in KINDS for name in tensors), tensors


@pytest.mark.parametrize("case", sorted(CASES))
def test_an_odd_tensor_is_named_before_its_values_are_read(case: str, checkpoint_folder: Path) -> None:
    change, fragment = CASES[case]
    state = _state(checkpoint_folder)
    change(state)
    problem = checkpoint_problem(state)
    assert problem is not None and fragment in problem, (fragment, problem)


@pytest.mark.parametrize("case", ["Adam's step a 2-vector", "replay rewards complex", "replay rewards bool",
                                  "replay features float16"])  # fmt: skip
def test_train_resume_over_an_odd_tensor_is_one_line_and_every_byte_is_kept(
    case: str, checkpoint_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    change, fragment = CASES[case]
    out = tmp_path / "run"
    shutil.copytree(checkpoint_folder, out)
    state = _state(out)
    change(state)
    torch.save(state, out / "checkpoint.pt")
    before = snapshot(tmp_path)
    code = train.main(["--resume", "--quiet", "--out", str(out)])
    line = one_line(code, capsys.readouterr().err, fragment)
    assert line.startswith(f"train: error: checkpoint {out / 'checkpoint.pt'} has "), line
    assert line.endswith("; train again without --resume"), line
    assert snapshot(tmp_path) == before
