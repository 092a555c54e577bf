"""Issue 82, probe 13, F18: `coopsumo models` listed as usable a store every study refuses (a user's file in it, a
link named like a model), and gave no reason for a model it called not usable."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from test_models_command import TRAINED, _stored_then_spoiled

from coopsumo.config import SimConfig, TrainConfig, to_dict
from coopsumo.run_markers import RUN_MARKER
from coopsumo.studies.engine import store_listing

CONFIG = to_dict(TrainConfig(sim=SimConfig(steps=300, seed=100, policy="dqn"), eval_steps=0))


def _listed(store: Path, capsys: pytest.CaptureFixture[str]) -> list[str]:
    assert store_listing.main(["--store", str(store)]) == 0
    return capsys.readouterr().out.strip().splitlines()


def _usable_model(store: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    from coopsumo.studies.engine import trainings

    monkeypatch.setattr(trainings, "model_folder_problem", lambda folder: None)  # model.pt's loading not judged here
    folder, _ = _stored_then_spoiled(CONFIG, store, "train_summary.json", json.dumps(TRAINED))
    return folder


def test_a_store_every_study_refuses_is_listed_with_none_usable(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    store = tmp_path / "models"
    _usable_model(store, monkeypatch)
    assert _listed(store, capsys)[-1] == f"1 models in {store}, 1 usable"
    (store / "notes.txt").write_text("hi")
    assert _listed(store, capsys)[-1] == (f"1 models in {store}, none usable: the store holds notes.txt, which is not "
                                          "a stored model, and every study refuses it; move that away")
    (store / "notes.txt").unlink()
    (tmp_path / "mine").mkdir()
    (store / "default_a9_seed9_0123456789ab").symlink_to(tmp_path / "mine")
    lines = _listed(store, capsys)
    row = next(line for line in lines if line.startswith("default_a9_seed9_0123456789ab"))
    assert f"not usable: a link to {tmp_path / 'mine'}, where the store keeps only its own folders" in row, row
    assert "none usable: the store holds default_a9_seed9_0123456789ab, a link" in lines[-1], lines[-1]


@pytest.mark.parametrize(("name", "text", "fragment"), [
    ("train_summary.json", "[1, 2]", "its train_summary.json is [1, 2], not a JSON object"),
    ("train_summary.json", "5", "its train_summary.json is 5, not a JSON object"),
    ("train_summary.json", "9" * 5000, "its train_summary.json cannot be read (ValueError)"),  # digits: no int
    (RUN_MARKER, "[]", f"its {RUN_MARKER} is [], not a training's marker"),
    (RUN_MARKER, '{"kind": "train", "finished": true, "files": "model.pt"}',
     f"its {RUN_MARKER} does not list model.pt as a finished training's file (files: \"model.pt\")"),
])  # fmt: skip
def test_an_unusable_model_is_listed_with_the_file_and_the_reason(name: str, text: str, fragment: str,
                                                                  tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """The probe's mo2_ts_list, mo2_ts_num, mo2_ts_bigint, mo2_marker_list, mo2_marker_files_str: each was "not
    usable: trained again when a study asks for it", the damaged file and the reason unnamed."""
    store = tmp_path / "models"
    folder = _usable_model(store, monkeypatch)
    (folder / name).write_text(text)
    row = next(line for line in _listed(store, capsys) if line.startswith(folder.name))
    assert f"not usable: {fragment}; trained again when a study asks for it" in row, row
