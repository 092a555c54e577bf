"""Probe 6, H1: a model file or checkpoint holding a sparse or a meta tensor (torch's safe loader takes both) is
refused in one line naming where, not a traceback from the first check that reads its values."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
import torch

from coopsumo.agents.dqn import QNetwork
from coopsumo.agents.file_checks import checkpoint_problem, odd_tensor
from coopsumo.agents.model_file import ModelFileError, load_model, save_model

ODD: dict[str, Callable[[torch.Tensor], torch.Tensor]] = {
    "sparse": lambda t: t.to_sparse(),
    "meta": lambda t: torch.empty(t.shape, device="meta"),
}


@pytest.mark.parametrize("kind", sorted(ODD))
def test_a_model_file_with_an_odd_tensor_is_refused_naming_it(kind: str, tmp_path: Path) -> None:
    path = tmp_path / "model.pt"
    save_model(path, QNetwork(25.0), {})
    load_model(path)
    payload = torch.load(path, weights_only=True)
    payload["state_dict"] = {**payload["state_dict"], "conv1.bias": ODD[kind](payload["state_dict"]["conv1.bias"])}
    torch.save(payload, path)
    with pytest.raises(ModelFileError, match="holds a tensor that is not a dense one in memory: "
                                             "state_dict.conv1.bias"):  # fmt: skip
        load_model(path)


@pytest.mark.parametrize("kind", sorted(ODD))
def test_a_checkpoint_with_an_odd_tensor_is_refused_before_its_values_are_read(kind: str) -> None:
    weights = {"w": ODD[kind](torch.ones(3))}
    state = {"config": {"sim": {}, "dqn": {}}, "step": 0, "learner": {"online": weights, "optimizer": {"state": {}}}}
    assert checkpoint_problem(state) == ("holds a tensor that is not a dense one in memory: learner.online.w "
                                         f"({'torch.sparse_coo' if kind == 'sparse' else 'torch.strided'}, "
                                         f"{'cpu' if kind == 'sparse' else 'meta'})")  # fmt: skip


def test_plain_tensors_in_any_nesting_pass() -> None:
    assert odd_tensor({"a": [torch.ones(2), (torch.zeros(1), {"b": torch.tensor(3)})], "c": 1}) is None
    assert odd_tensor([1, [torch.ones(1).to_sparse()]]) == "1.0 (torch.sparse_coo, cpu)"
