"""The closing lines commands print: `train`'s model line rounds its floats as `simulate`'s does (issue 68: it
printed mean_speed_mps=16.219737159743943)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from coopsumo.agents import train as train_module
from coopsumo.agents import train_cli


def test_train_prints_its_summary_to_four_significant_digits(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    def fake_train(cfg: Any, out: Path, **_: Any) -> dict[str, Any]:
        return {"mean_speed_mps": 16.219737159743943, "lane_changes_per_vehicle": 0.012345678, "collisions": 0,
                "teleports": 0}  # fmt: skip

    monkeypatch.setattr(train_module, "train", fake_train)
    out = tmp_path / "run"
    assert train_cli.main(["--steps", "20", "--eval-steps", "0", "--quiet", "--out", str(out)]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert line == (f"model: {out / 'model.pt'}  mean_speed_mps=16.22 lane_changes_per_vehicle=0.01235 collisions=0 "
                    "teleports=0")
