"""The stacked network of agents/stacked.py (issue 77): K QNetworks of one architecture as one set of batched
matrix products, their weights one (K, width) buffer; and the conversions between a member's row and QNetwork's
state_dict, exact both ways.

The layout. A member's weights are one flat float32 row (Layout): every matrix is (in, out), applied to its rows of
the input with torch.baddbmm, so that nothing mixes members. The two convolutions are products over their patches:
both have width 2 and stride 2 along the cells. The first convolution's two output columns of a pair of columns
are one product of the pair's 2 lanes x 4 cells x 3 frames (conv_patches: a copy of the grids with runs of 12
floats) with the (24, 32) weights of both (_pair_weights: the 12 x 16 weights twice, zeros where a column does not
see a cell), so that its output, rows (vehicle, column pair, row) x columns (parity, filter), is already the second
convolution's patches: a view, no copy. The dueling head's advantages and value are one (100, 5) product. A row is
a whole number of 64 floats, so that an element-wise operation over the (K, width) buffer treats every row alike
whatever K.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import torch

from coopsumo.agents.dqn import QNetwork, alpha_input
from coopsumo.agents.replay import GRID_SHAPE, N_ACTIONS

_FILTERS = (16, 32)
"""filters of the two convolutions (Table II)"""
_COLUMNS = (GRID_SHAPE[2] // 2, GRID_SHAPE[2] // 4)
"""output columns of the two convolutions (10, 5); the first has 2 rows, the second 1"""
_CONV_OUT = _FILTERS[1] * _COLUMNS[1]
"""features after the two convolutions (160), as dqn's"""
_PATCH1 = 2 * 2 * GRID_SHAPE[0]
"""a first-layer patch: 2 lanes x 2 cells x 3 frames"""
_PATCH2 = 2 * 2 * _FILTERS[0]
"""a second-layer patch: 2 rows x 2 columns x 16 channels"""
_ALIGN = 16
"""floats: every parameter starts on a 64-byte boundary of its row"""
_ROW_ALIGN = 64
"""floats: a row is a whole number of the widest vector loop's steps (2 x 16 floats with AVX-512)"""
_PARITY = torch.eye(2).reshape(1, 1, 2, 1, 2, 1)
"""(half of a cell pair, output column's parity): 1 where the half is the column's own patch (_pair_weights)"""


def stacked_shapes(net: QNetwork) -> dict[str, tuple[int, int]]:
    """A member's stacked parameters, name -> (rows, columns) of its matrix, in product order."""
    n_out = N_ACTIONS + int(net.dueling)
    return {"conv1.weight": (_PATCH1, _FILTERS[0]), "conv1.bias": (1, _FILTERS[0]),
            "conv2.weight": (_PATCH2, _FILTERS[1]), "conv2.bias": (1, _FILTERS[1]),
            "fc1.weight": (net.fc1.in_features, net.fc1.out_features), "fc1.bias": (1, net.fc1.out_features),
            "fc2.weight": (net.fc2.in_features, net.fc2.out_features), "fc2.bias": (1, net.fc2.out_features),
            "head.weight": (net.out.in_features, n_out), "head.bias": (1, n_out)}  # fmt: skip


@dataclass(frozen=True)
class Layout:
    """Where each stacked parameter lives in a member's row: name -> (offset, (rows, columns)); width: floats a row."""

    slots: dict[str, tuple[int, tuple[int, int]]]
    width: int

    @classmethod
    def of(cls, net: QNetwork) -> Layout:
        slots, offset = {}, 0
        for name, (rows, cols) in stacked_shapes(net).items():
            slots[name] = (offset, (rows, cols))
            offset += -(-rows * cols // _ALIGN) * _ALIGN
        return cls(slots, -(-offset // _ROW_ALIGN) * _ROW_ALIGN)

    def views(self, buffer: torch.Tensor) -> dict[str, torch.Tensor]:
        """name -> (rows of buffer, rows, columns) view of buffer (n, width)."""
        n = buffer.shape[0]
        return {name: buffer[:, offset : offset + r * c].view(n, r, c) for name, (offset, (r, c)) in self.slots.items()}


def _conv_order() -> torch.Tensor:
    """stacked index (column, filter) of the flattened convolution output -> QNetwork's index (filter, column)."""
    return torch.arange(_CONV_OUT).reshape(_FILTERS[1], _COLUMNS[1]).t().reshape(-1)


def stacked_weights(state: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """A QNetwork's state_dict (or its parameters' Adam moments, shaped alike) as one member's stacked matrices."""
    fc1 = state["fc1.weight"].t()
    heads = ["out", "value"] if "value.weight" in state else ["out"]
    return {"conv1.weight": state["conv1.weight"].permute(2, 3, 1, 0).reshape(_PATCH1, _FILTERS[0]),
            "conv1.bias": state["conv1.bias"].reshape(1, -1),
            "conv2.weight": state["conv2.weight"].permute(2, 3, 1, 0).reshape(_PATCH2, _FILTERS[1]),
            "conv2.bias": state["conv2.bias"].reshape(1, -1),
            "fc1.weight": torch.cat([fc1[:_CONV_OUT][_conv_order()], fc1[_CONV_OUT:]]),
            "fc1.bias": state["fc1.bias"].reshape(1, -1),
            "fc2.weight": state["fc2.weight"].t(), "fc2.bias": state["fc2.bias"].reshape(1, -1),
            "head.weight": torch.cat([state[f"{h}.weight"] for h in heads]).t(),
            "head.bias": torch.cat([state[f"{h}.bias"] for h in heads]).reshape(1, -1)}  # fmt: skip


def network_weights(stacked: Mapping[str, torch.Tensor], dueling: bool) -> dict[str, torch.Tensor]:
    """Inverse of stacked_weights: QNetwork's state_dict (its keys in its order, contiguous copies)."""
    fc1 = stacked["fc1.weight"]
    conv_rows = torch.empty_like(fc1[:_CONV_OUT])
    conv_rows[_conv_order()] = fc1[:_CONV_OUT]
    head_w, head_b = stacked["head.weight"].t(), stacked["head.bias"].reshape(-1)
    state = {"conv1.weight": stacked["conv1.weight"].reshape(2, 2, GRID_SHAPE[0], _FILTERS[0]).permute(3, 2, 0, 1),
             "conv1.bias": stacked["conv1.bias"].reshape(-1),
             "conv2.weight": stacked["conv2.weight"].reshape(2, 2, _FILTERS[0], _FILTERS[1]).permute(3, 2, 0, 1),
             "conv2.bias": stacked["conv2.bias"].reshape(-1),
             "fc1.weight": torch.cat([conv_rows, fc1[_CONV_OUT:]]).t(), "fc1.bias": stacked["fc1.bias"].reshape(-1),
             "fc2.weight": stacked["fc2.weight"].t(), "fc2.bias": stacked["fc2.bias"].reshape(-1),
             "out.weight": head_w[:N_ACTIONS], "out.bias": head_b[:N_ACTIONS]}  # fmt: skip
    if dueling:
        state.update({"value.weight": head_w[N_ACTIONS:], "value.bias": head_b[N_ACTIONS:]})
    return {name: t.detach().clone().contiguous() for name, t in state.items()}


def conv_patches(grids: torch.Tensor) -> torch.Tensor:
    """The first convolution's input as products' rows (K, B x 5 x 2, 24) from grids (K, B, 3, 3, 20): a row is
    (vehicle, column pair, row), i.e. both output columns 2c and 2c + 1 of a column pair c, whose patches together
    are 2 lanes x 4 cells x 3 frames (lane, cell, frame)."""
    k, b = grids.shape[:2]
    frames, lanes, cells = GRID_SHAPE
    x = grids.permute(0, 1, 3, 4, 2).reshape(k, b, lanes, _COLUMNS[1], 4 * frames)  # (lane, pair, cells x frames)
    return x.unfold(2, 2, 1).permute(0, 1, 3, 2, 5, 4).reshape(k, b * _COLUMNS[1] * 2, 2 * 4 * frames)


def _pair_weights(w: torch.Tensor, bias: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The first convolution's weights (K, 12, 16) and bias (K, 1, 16) for conv_patches' rows: (K, 24, 32) and
    (K, 1, 32), output columns (2c + parity, filter), a patch cell 2 parity + j meeting the weights' column j only."""
    k = w.shape[0]
    pair = w.reshape(k, 2, 1, 2 * GRID_SHAPE[0], 1, _FILTERS[0]) * _PARITY  # (lane, half, (cell, frame), parity, f)
    return pair.reshape(k, 2 * _PATCH1, 2 * _FILTERS[0]), bias.repeat(1, 1, 2)


def q_from_patches(w: Mapping[str, torch.Tensor], patches: torch.Tensor, features: torch.Tensor,
                   alphas: torch.Tensor | None, speed_scale_mps: float, dueling: bool) -> torch.Tensor:  # fmt: skip
    """stacked_q_values with the grids given as conv_patches(grids)."""
    k, b = features.shape[:2]
    frames = GRID_SHAPE[0]
    pair_w, pair_b = _pair_weights(w["conv1.weight"], w["conv1.bias"])
    x = torch.relu_(torch.baddbmm(pair_b, patches, pair_w))  # (vehicle, column pair, row) x (parity, filter)
    x = x.reshape(k, b * _COLUMNS[1], _PATCH2)  # the second convolution's patches, (row, column, filter): a view
    x = torch.relu_(torch.baddbmm(w["conv2.bias"], x, w["conv2.weight"]))  # (vehicle, column) x filter
    parts = [x.reshape(k, b, _CONV_OUT), features[:, :, :frames] / speed_scale_mps, features[:, :, frames:]]
    if alphas is not None:
        parts.append(alpha_input(alphas.unsqueeze(2).to(features.dtype)))
    x = torch.relu_(torch.baddbmm(w["fc1.bias"], torch.cat(parts, dim=2), w["fc1.weight"]))
    x = torch.relu_(torch.baddbmm(w["fc2.bias"], x, w["fc2.weight"]))
    out = torch.baddbmm(w["head.bias"], x, w["head.weight"])
    if not dueling:
        return out
    adv = out[:, :, :N_ACTIONS]
    return out[:, :, N_ACTIONS:] + adv - adv.mean(dim=2, keepdim=True)


def stacked_q_values(w: Mapping[str, torch.Tensor], grids: torch.Tensor, features: torch.Tensor,
                     alphas: torch.Tensor | None, speed_scale_mps: float, dueling: bool) -> torch.Tensor:  # fmt: skip
    """Q-values (K, B, 4) of K stacked networks w (Layout.views), member k on its own rows: grids (K, B, 3, 3, 20),
    features (K, B, F), alphas (K, B) for conditioned networks (else None); QNetwork.forward, member by member."""
    return q_from_patches(w, conv_patches(grids), features, alphas, speed_scale_mps, dueling)
