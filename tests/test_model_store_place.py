"""Where a study's models go, said and found (issue 81): the model store stays `models` beside the study's --out (or
$COOPSUMO_MODELS), so the committed studies keep theirs (results/models) and their models' identities; a study that
trains says the store's path on stderr, and `coopsumo models` without flags lists every store below the current
folder. Moving the store changes no cell key and no model's name. A real study's run (its store printed and listed,
nothing written elsewhere) is in tests/test_extending.py."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from coopsumo.config import TrainConfig, to_dict
from coopsumo.studies.engine import cells, model_store, store_listing
from coopsumo.studies.engine.model_store import model_id, store_for
from coopsumo.studies.engine.store_listing import found_stores

MODEL = "default_a0_seed100_0123456789ab"
"""a folder name as model_id makes one"""


def _store(folder: Path, *names: str) -> Path:
    for name in names:
        (folder / name).mkdir(parents=True)
    return folder


def test_the_store_is_beside_the_results_folder_unless_the_environment_names_one(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    monkeypatch.delenv(model_store.STORE_ENV, raising=False)
    assert store_for(tmp_path / "work" / "protocol_tiny") == tmp_path / "work" / "models"
    monkeypatch.chdir(tmp_path)
    assert store_for(Path("results/scenario1")) == tmp_path / "results" / "models"  # the committed studies' store
    monkeypatch.setenv(model_store.STORE_ENV, str(tmp_path / "shared"))
    assert store_for(tmp_path / "work" / "protocol_tiny") == tmp_path / "shared"


def test_stores_are_found_below_the_current_folder(tmp_path: Path) -> None:
    _store(tmp_path / "results" / "models", MODEL)
    _store(tmp_path / "work" / "models", MODEL, ".x.lock")
    _store(tmp_path / "a" / "b" / "models", MODEL)  # three folders down: found
    _store(tmp_path / "a" / "b" / "c" / "models", MODEL)  # four: not searched
    _store(tmp_path / "results" / "scenario1" / "models", "alpha0_m100")  # a study's links: no store
    _store(tmp_path / ".hidden" / "models", MODEL)
    _store(tmp_path / "empty" / "models")
    found = found_stores(tmp_path)
    assert found == [Path("a/b/models"), Path("results/models"), Path("work/models")]


def test_models_without_flags_lists_every_store_found(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    monkeypatch.delenv(model_store.STORE_ENV, raising=False)
    monkeypatch.chdir(tmp_path)
    _store(tmp_path / "work" / "models", MODEL, "default_a8_seed100_0123456789ab")
    _store(tmp_path / "results" / "models", "alpha_only_a0_seed101_0123456789ab")
    assert store_listing.main([]) == 0
    out = capsys.readouterr().out
    assert "1 models in results/models, 0 usable" in out and "2 models in work/models, 0 usable" in out
    assert MODEL in out and "unfinished: no config.json yet (being trained" in out  # each folder's state (probe 15)
    assert out.index("results/models") < out.index("work/models")
    monkeypatch.setenv(model_store.STORE_ENV, str(tmp_path / "work" / "models"))
    assert store_listing.main([]) == 0
    assert "results/models" not in capsys.readouterr().out  # $COOPSUMO_MODELS: the one store the studies use


def test_moving_the_store_changes_no_cell_key_and_no_model_name(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """A model's name is a digest of its training's configuration, and the studies' cells are keyed by their plans:
    a study run with another store reuses its records and finds or trains the same models."""
    from coopsumo.studies.protocol import plan as protocol_plan
    from coopsumo.studies.scenario1 import plan as scenario1_plan
    from coopsumo.studies.scenario1 import study as scenario1

    keys = []
    for store in ("a", "b"):
        monkeypatch.setenv(model_store.STORE_ENV, str(tmp_path / store))
        specs = scenario1._cells(scenario1_plan.PROFILES["quick"], tmp_path / "study")[0]
        keys.append([s["key"] for s in specs])
        assert {s["store"] for s in specs if s["kind"] == "train"} == {str(tmp_path / store)}
    assert keys[0] == keys[1] and len(keys[0]) > 4
    specs = protocol_plan.cell_specs(protocol_plan.PROFILES["tiny"])
    assert "models" not in json.dumps([{k: v for k, v in s.items() if k != "config"} for s in specs], default=to_dict)
    config = to_dict(scenario1_plan.train_config(scenario1_plan.PROFILES["default"], 8.0, "default", 100))
    assert model_id(config) == model_id(json.loads(json.dumps(config)))  # no path in it: the same name anywhere
    assert str(tmp_path) not in json.dumps(model_store.identity(config))


TRAINED = {"mean_speed_mps": 20.0, "lane_changes": 3, "collisions": 0, "updates": 10, "wall_seconds": 1.0,
           "steps_per_second": 100.0, "departed": 50, "steps": 100}
"""a training's summary as train writes it (record_schemas.TRAIN_SUMMARY_KEYS): a cell that trains keeps one"""


def test_a_study_that_trains_names_its_store(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                             capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """run_todo (the protocol's, the learning study's, scenario II's) says where the study's models are, whatever
    it has left to run; a study without trainings says nothing of a store."""
    monkeypatch.delenv(model_store.STORE_ENV, raising=False)
    root = tmp_path / "work" / "study"
    (root / "cells").mkdir(parents=True)
    (root / "cells" / "c.json").write_text(json.dumps({"key": "c", "status": "ok", "config": {"train": {}, "eval": {}},
                                                       "summary": {"x": 1.0}, "train_summary": TRAINED}))  # fmt: skip
    train = [{"key": "c", "training": TrainConfig(), "config": {"train": {}, "eval": {}}}]
    records = cells.run_todo([], train, root, lambda s, r: {}, lambda s, e: {}, required=["x"])
    assert records[0]["status"] == "ok", records[0].get("error")
    assert f"coopsumo: model store {tmp_path / 'work' / 'models'} (the study's models" in capsys.readouterr().err
    cells.run_todo([], [{"key": "c", "config": {"eval": {}}}], root, lambda s, r: {}, lambda s, e: {}, required=["x"])
    assert "model store" not in capsys.readouterr().err
