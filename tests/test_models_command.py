"""`coopsumo models` on a store that is not there yet (a fresh clone): "no models yet" and where they would go,
exit code 0; a --store named by hand that does not exist, or a file, is still one line and exit code 2; a stored
model's config.json outside its schema is a row naming the field, not a traceback."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from coopsumo.config import SimConfig, TrainConfig, to_dict
from coopsumo.dqn_config import DQNConfig
from coopsumo.studies.engine import model_store, store_listing


def test_a_missing_default_store_has_no_models_yet(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv(model_store.STORE_ENV, raising=False)
    assert store_listing.main([]) == 0
    out = capsys.readouterr().out
    assert out.startswith("no models yet") and "results/models" in out
    assert not (tmp_path / "results").exists()  # listing makes nothing


def test_a_missing_store_from_the_environment_or_an_empty_one_has_no_models_yet(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    monkeypatch.setenv(model_store.STORE_ENV, str(tmp_path / "store"))
    assert store_listing.main([]) == 0
    assert capsys.readouterr().out.startswith(f"no models yet in {tmp_path / 'store'}")
    (tmp_path / "store").mkdir()
    assert store_listing.main(["--store", str(tmp_path / "store")]) == 0
    assert capsys.readouterr().out.startswith("no models yet")


@pytest.mark.parametrize("text", ["", " "])
def test_an_empty_store_is_one_line_and_exit_2(text: str, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 82 (ms07): `models --store ""` listed the working folder as a store."""
    with pytest.raises(SystemExit) as stop:
        store_listing.main(["--store", text])
    err = capsys.readouterr().err.strip().splitlines()
    assert stop.value.code == 2 and len(err) == 1 and "--store: is empty" in err[0], err


@pytest.mark.parametrize("kind", ["missing", "file"])
def test_a_named_store_that_is_no_folder_is_one_line_and_exit_2(
        kind: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    store = tmp_path / "store"
    if kind == "file":
        store.write_text("x")
    assert store_listing.main(["--store", str(store)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--store" in err[0] and str(store) in err[0]


@pytest.mark.parametrize("kind", ["/proc", "a study's folder"])
def test_a_named_folder_that_is_no_model_store_is_one_line_and_exit_2(
        kind: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Issue 82, probe 7, I17b: `models --store /proc` listed "124 models in /proc", and a scenario II study's folder
    had cells/, evals/ listed as models. An empty folder is a store without models yet (above)."""
    store = Path("/proc") if kind == "/proc" else tmp_path / "s2"
    for name in ("cells", "evals", "train"):
        if kind != "/proc":
            (store / name).mkdir(parents=True)
    assert store_listing.main(["--store", str(store)]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and f"--store {store}: not a model store" in err[0] and captured.out == "", err


def _spoil(*keys: str, value: object = None, drop: bool = False) -> Callable[[dict], None]:
    def change(record: dict) -> None:
        d = record
        for k in keys[:-1]:
            d = d[k]
        if drop:
            del d[keys[-1]]
        else:
            d[keys[-1]] = value

    return change


CONFIGS = {
    # the probe's (2026-12-01): `coopsumo models` ended in a traceback
    "alpha 'x'": (_spoil("config", "sim", "reward", "alpha", value="x"),
                  "field config.sim.reward.alpha must be a number, got 'x'"),
    "alpha null": (_spoil("config", "sim", "reward", "alpha", value=None),
                   "field config.sim.reward.alpha must be a number, got None"),
    # the other fields of record_schemas.STORE_CONFIG
    "alpha -1": (_spoil("config", "sim", "reward", "alpha", value=-1.0), "field config.sim.reward.alpha must be a "
                 "finite number >= 0 and <= 1000, got -1.0"),
    "alpha 1e9": (_spoil("config", "sim", "reward", "alpha", value=1e9), "field config.sim.reward.alpha"),
    "seed -4": (_spoil("config", "sim", "seed", value=-4), "field config.sim.seed must be an integer from 0"),
    "seed 2.5": (_spoil("config", "sim", "seed", value=2.5), "field config.sim.seed must be an integer, got 2.5"),
    "steps 0": (_spoil("config", "sim", "steps", value=0), "field config.sim.steps must be an integer >= 1"),
    "preset 3": (_spoil("config", "dqn", "preset", value=3), "field config.dqn.preset must be a text, got 3"),
    "conditioned 'yes'": (_spoil("config", "dqn", "alpha_conditioned", value="yes"),
                          "field config.dqn.alpha_conditioned must be true or false"),
    "sim a list": (_spoil("config", "sim", value=[1]), "field config.sim must be a mapping"),
    "no reward": (_spoil("config", "sim", "reward", drop=True), "has no field config.sim.reward"),
    "not an object": (lambda record: record.clear(), "has no field config"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(CONFIGS))
def test_a_stored_config_outside_its_schema_is_listed_not_usable(
        case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Issue 82: one folder's config.json outside record_schemas.STORE_CONFIG is a row saying why it is not usable
    (no traceback, exit 0); the store's other models are listed as before."""
    spoil, fragment = CONFIGS[case]
    store = tmp_path / "models"
    for seed in (100, 101):
        config = to_dict(TrainConfig(sim=SimConfig(steps=300, seed=seed, policy="dqn"), eval_steps=0))
        folder = store / model_store.model_id(config)
        folder.mkdir(parents=True)
        (folder / "config.json").write_text(json.dumps({"config": config}))
    assert store_listing.main(["--store", str(store)]) == 0
    assert "not usable" not in capsys.readouterr().out  # both unfinished (no model), neither refused
    first = sorted(store.iterdir())[0]
    record = json.loads((first / "config.json").read_text())
    spoil(record)
    (first / "config.json").write_text(json.dumps(record))
    assert store_listing.main(["--store", str(store)]) == 0
    out, err = capsys.readouterr()
    assert err == "" and "2 models in" in out
    row = next(line for line in out.splitlines() if line.startswith(first.name))
    assert f"not usable: config.json {fragment}" in row, (fragment, row)
    assert "unfinished" in next(line for line in out.splitlines() if line.startswith(sorted(store.iterdir())[1].name))


LOST_RECORDS = [(".coopsumo-run.json", None), ("config.json", None), ("config.json", "garbage"),
                ("train_summary.json", None)]  # fmt: skip
"""(a stored model's record, None: deleted, else its new text): the probe's md05m_a-c and train_summary.json"""


def _stored_then_spoiled(config: dict, store: Path, lost: str, spoil: str | None) -> tuple[Path, str]:
    """A finished training's folder of `config` in the store (a model.pt of bytes) whose record `lost` is deleted or
    holds `spoil`; returns the folder and the line it should be trained again with."""
    from coopsumo.run_dirs import mark_run_dir

    folder = store / model_store.model_id(config)
    folder.mkdir(parents=True)
    (folder / "config.json").write_text(json.dumps({"config": config}))
    (folder / "train_summary.json").write_text(json.dumps({"steps": 300}))
    (folder / "model.pt").write_bytes(b"weights")
    mark_run_dir(folder, "train")
    if spoil is None:
        (folder / lost).unlink()
    else:
        (folder / lost).write_text(spoil)
    return folder, (f"coopsumo: {folder} holds a model.pt but its {lost} is missing or unreadable "
                    f"({'FileNotFoundError' if spoil is None else 'JSONDecodeError'}); training it again")


@pytest.mark.parametrize("lost, spoil", LOST_RECORDS)
def test_a_stored_model_that_lost_a_record_is_trained_again_with_a_line_naming_it(
        lost: str, spoil: str | None, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Issue 82 (md05x): a store folder holding a model.pt whose marker, config.json or train_summary.json is gone or
    garbage was trained again without a word; now one line names the folder and the file (quiet: none, as the
    listing and the study's first look use it)."""
    from coopsumo.studies.engine.trainings import finished_training

    config = to_dict(TrainConfig(sim=SimConfig(steps=300, seed=100, policy="dqn"), eval_steps=0))
    folder, line = _stored_then_spoiled(config, tmp_path, lost, spoil)
    assert finished_training(folder, config, quiet=True) is None and capsys.readouterr().err == ""
    assert finished_training(folder, config) is None
    assert capsys.readouterr().err.strip().splitlines() == [line]


@pytest.mark.parametrize("lost, spoil", LOST_RECORDS)
def test_a_stored_model_that_lost_a_record_is_trained_again_in_a_group_with_a_line_naming_it(
        lost: str, spoil: str | None, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Issue 82 (md05m): the stacked learner's trainings, trained as groups before a study's cells, trained such a
    folder again with no line naming it (the line came only from a training cell's own look); the fresh member of
    the group has none. The group's training is faked: only what is said before it counts here."""
    from coopsumo.agents import group
    from coopsumo.studies.engine.groups import train_groups

    trainings = [TrainConfig(sim=SimConfig(steps=300, seed=seed, policy="dqn"), eval_steps=0,
                             dqn=DQNConfig(stacked_updates=True)) for seed in (100, 101)]  # fmt: skip
    configs = [to_dict(t) for t in trainings]
    folder, line = _stored_then_spoiled(configs[0], tmp_path / "models", lost, spoil)
    monkeypatch.setattr(group, "train_group", lambda cfgs, outs, resumes: [group.MemberResult(out, {}) for out in outs])
    specs = [{"key": f"train_{i}", "kind": "train", "config": c, "training": t}
             for i, (c, t) in enumerate(zip(configs, trainings, strict=True))]
    assert train_groups(specs, tmp_path / "models", quiet=True) == 2
    assert capsys.readouterr().err.strip().splitlines() == [line]


DROP = object()
"""an edit's value that deletes the key"""
SUMMARIES = {
    "a speed of 999 m/s": ({"mean_speed_mps": 999.0}, "has train_summary.json mean_speed_mps must be a finite number "
                           ">= 0 and <= 70 (m/s), got 999.0"),
    "-5 updates": ({"updates": -5}, "has train_summary.json updates must be an integer >= 0, got -5"),
    "selected step -5": ({"selected_step": -5}, "has train_summary.json selected_step must be an integer >= 0, got -5"),
    "selected step above its steps": ({"selected_step": 10**6},
                                      "has train_summary.json selected_step = 1000000, not a step from 0 to its 300"),
    "selected step 'x'": ({"selected_step": "x"}, 'has train_summary.json selected_step = "x", not a step from 0'),
    # the probe's F6 (st_ts_*, s2t_ts_*): a value the studies copy that is no number, or none, was reused into a blank
    "speed 'fast'": ({"mean_speed_mps": "fast"}, 'has train_summary.json mean_speed_mps = "fast", not a number'),
    "speed null": ({"mean_speed_mps": None}, "has train_summary.json mean_speed_mps = null, not a number"),
    "departed '59'": ({"departed": "59"}, 'has train_summary.json departed = "59", not a number'),
    "updates 'many'": ({"updates": "many"}, 'has train_summary.json updates = "many", not a number'),
    "no mean_speed_mps": ({"mean_speed_mps": DROP}, "has train_summary.json without mean_speed_mps"),
    "no updates": ({"updates": DROP}, "has train_summary.json without updates"),
    "steps 123 of 300": ({"steps": 123}, "has train_summary.json steps = 123, not its last world's 300"),
    # issue 82, probe 8, J9: counts and a wall time its own training cannot give were reused into runs.csv
    "departed 99999": ({"departed": 99999}, "has train_summary.json departed = 99999, more than one vehicle per lane "
                       "and step of its last world (300 steps on 3 lanes)"),
    "lane_changes 99999": ({"lane_changes": 99999}, "has train_summary.json lane_changes = 99999, more than its 40 "
                           "vehicles could make in its last world's 300 steps (a change takes 4 s: at most 340)"),
    # issue 82, probe 14, F9: one lane change per vehicle and step (12,000 here) let 5,000 for 24 vehicles in 30 s
    # through; a vehicle starts one at most every 4 s, and one as it enters: 40 x (30 s / 4 s + 1) = 340
    "lane_changes 341 of 40 vehicles in 30 s": ({"lane_changes": 341}, "has train_summary.json lane_changes = 341, "
                                                "more than its 40 vehicles could make"),
    "updates 1e9": ({"updates": 10**9}, "has train_summary.json updates = 1e+09, more than 2 per step of its 300"),
    "wall 500000 s": ({"wall_seconds": 500000}, "has train_summary.json wall_seconds = 500000, but steps_per_second "
                      "= 100 makes its 300 steps 3 s"),
}  # fmt: skip
TRAINED = {"steps": 300, "departed": 40, "mean_speed_mps": 20.0, "lane_changes": 12, "collisions": 0, "updates": 20,
           "wall_seconds": 3.0, "steps_per_second": 100.0, "selected_step": 300}  # fmt: skip
"""a finished training's train_summary.json (the values the studies read)"""


@pytest.mark.parametrize("case", sorted(SUMMARIES))
def test_a_stored_model_whose_summary_no_run_gives_is_trained_again_and_listed_not_usable(
        case: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Issue 82 (s2_store_ts, mo_ts_*): a stored model whose train_summary.json holds a value no run gives was reused
    (scenario II then stopped at runs.csv on every rerun) and listed "ok"; now it is trained again with one line
    naming the folder and the field, and listed not usable saying why. model.pt's loading is not judged here."""
    from coopsumo.studies.engine import trainings

    monkeypatch.setattr(trainings, "model_folder_problem", lambda folder: None)
    config = to_dict(TrainConfig(sim=SimConfig(steps=300, seed=100, policy="dqn"), eval_steps=0))
    store = tmp_path / "models"
    folder, _ = _stored_then_spoiled(config, store, "train_summary.json", json.dumps(TRAINED))
    assert trainings.finished_training(folder, config) == TRAINED and capsys.readouterr().err == ""
    assert store_listing.main(["--store", str(store)]) == 0 and "not usable" not in capsys.readouterr().out
    edit, fragment = SUMMARIES[case]
    edited = {k: v for k, v in {**TRAINED, **edit}.items() if v is not DROP}
    (folder / "train_summary.json").write_text(json.dumps(edited))
    assert trainings.finished_training(folder, config, quiet=True) is None and capsys.readouterr().err == ""
    assert trainings.finished_training(folder, config) is None
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"coopsumo: {folder} {fragment}"), lines
    assert lines[0].endswith("; training it again"), lines
    assert store_listing.main(["--store", str(store)]) == 0
    row = next(line for line in capsys.readouterr().out.splitlines() if line.startswith(folder.name))
    assert f"not usable: {fragment}" in row, row
