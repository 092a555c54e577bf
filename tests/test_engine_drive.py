"""studies/engine/cells.py: a model's dqn policy string with its drive settings, and the protocol driving its runs
through it (the drive settings reach the loaded policy). No SUMO run: the training and the run are
faked, the model file and its policy are real."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from coopsumo.config import SimConfig, TrainConfig, as_data
from coopsumo.policy_spec import DRIVES, parse_policy
from coopsumo.studies.engine.cells import cell_policy, dqn_policy, drive_pooled


def test_the_policy_string_carries_every_drive_setting_and_alpha_exactly() -> None:
    model = Path("/m/model.pt")
    assert dqn_policy(model) == dqn_policy(model, {}) == "dqn:/m/model.pt"  # driven as saved
    every = {"change_margin": 2.0, "no_return_s": 10.0, "restart_below_mps": 50.0, "queue_below_mps": 5.0}
    assert dqn_policy(model, every, alpha=8.0) == "dqn:/m/model.pt,margin=2,noreturn=10,restart=50,queue=5,alpha=8"
    for field, key, _ in DRIVES:  # each setting on its own reaches the parsed policy, none other does
        parsed = parse_policy(dqn_policy(model, {key: 1 / 3}))
        assert getattr(parsed, field) == 1 / 3 and parsed.alpha is None, key  # exactly, not :g's 0.333333
        assert [f for f, _, _ in DRIVES if getattr(parsed, f) is not None] == [field]
    assert parse_policy(dqn_policy(model, alpha=0.125)).alpha == 0.125


def test_a_cell_drives_at_its_alpha_only_when_its_training_is_conditioned() -> None:
    spec: dict[str, Any] = {"alpha": 8.0, "training": TrainConfig(), "config": {"drive": {"change_margin": 2.0}}}
    assert cell_policy(spec, Path("/m/model.pt")) == "dqn:/m/model.pt,margin=2"
    spec["training"] = replace(spec["training"], dqn=replace(spec["training"].dqn, alpha_conditioned=True))
    assert cell_policy(spec, Path("/m/model.pt")) == "dqn:/m/model.pt,margin=2,alpha=8"


def test_drive_pooled_keeps_each_evaluation_and_pools_them(tmp_path: Path) -> None:
    def measure(config: dict[str, Any], out: Path, label: str) -> dict[str, Any]:
        assert label == "cell" and out.parent == tmp_path
        return {"departed": 10, "lane_changes": config["seed"] - 1, "mean_speed_mps": float(config["seed"]),
                "collisions": 0}  # fmt: skip

    record: dict[str, Any] = {}
    drive_pooled(record, [(SimConfig(seed=2), tmp_path / "a"), (SimConfig(seed=4), tmp_path / "b")], "cell", measure)
    assert [s["eval_seed"] for s in record["eval_summaries"]] == [2, 4]
    assert record["summary"] == {"departed": 20, "lane_changes": 4, "mean_speed_mps": 3.0, "collisions": 0}


def protocol_specs() -> dict[str, dict[str, Any]]:
    """The free-flow cells of the tiny protocol profile with three variants: paper (as saved), m2 (target's training
    driven with a margin of 2, a queue rule below 5 m/s and no change back within 10 s) and conditioned8 (driven at
    its cell's alpha), its alpha response at 8 on one seed."""
    from coopsumo.studies.engine.catalogue import Learner
    from coopsumo.studies.protocol.plan import PROFILES, cell_specs, variants

    known = variants()
    known["m2"] = Learner("m2", "target driven otherwise", known["target"].learner, margin=2.0, queue=5.0,
                          noreturn=10.0)
    profile = replace(PROFILES["tiny"], variants=("paper", "m2", "conditioned8"), judged="conditioned8",
                      seeds=(100,), alpha_seeds=1, t_ups=(1.0,))  # fmt: skip
    return {s["key"]: s for s in cell_specs(profile, known) if s["kind"] == "model" and s["scenario"] == "free"}


@pytest.fixture
def faked_runs(monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, Any, Path]]:
    """The protocol's trainings faked (a real model file with the training's configuration, untrained) and
    its runs (rollout.run): each run's (policy string, the policy built from it, run folder) is listed."""
    import coopsumo.agents.rollout as rollout
    from coopsumo.agents.dqn import QNetwork
    from coopsumo.agents.model_file import save_model
    from coopsumo.studies.engine import model_store

    def fake_train(cfg: TrainConfig, out: Path, store: Path) -> tuple[dict[str, Any], None]:
        dqn = cfg.dqn
        net = QNetwork(30.0, dueling=dqn.dueling, observation=dqn.observation, conditioned=dqn.alpha_conditioned)
        out.mkdir(parents=True, exist_ok=True)
        save_model(out / "model.pt", net, {"config": as_data(cfg)})
        return {"steps": cfg.sim.steps}, None

    runs: list[tuple[str, Any, Path]] = []

    def fake_run(cfg: SimConfig, policy: Any, run_dir: Path, **kwargs: Any) -> dict[str, Any]:
        runs.append((cfg.policy, policy, run_dir))
        return {"steps": cfg.steps, "departed": 40, "arrived": 30, "mean_speed_mps": 20.0, "lane_changes": 4,
                "lane_changes_per_vehicle": 0.1, "collisions": 0, "teleports": 0, "policy": cfg.policy}  # fmt: skip

    monkeypatch.setattr(model_store, "train_shared", fake_train)
    monkeypatch.setattr(rollout, "run", fake_run)
    return runs


def test_the_protocol_drives_each_run_with_its_variants_drive_settings(
    tmp_path: Path, faked_runs: list[tuple[str, Any, Path]]
) -> None:
    """m2 drives target's training with its margin, queue rule and no-return time, each reaching the loaded policy;
    paper drives its model as saved (its own settings); the conditioned model at its cell's alpha."""
    from coopsumo.dqn_config import dqn_config_from_dict
    from coopsumo.studies.protocol.study import run_cell

    specs = protocol_specs()
    expected = {"paper_a0_seed100_free_t1": (None, None), "m2_a0_seed100_free_t1": ((2.0, 5.0, 10.0), None),
                "conditioned8_a0_seed100_free_t1": (None, 0.0), "conditioned8_a8_seed100_free_t1": (None, 8.0)}
    assert set(expected) == set(specs)
    for key, (drive, alpha) in expected.items():
        faked_runs.clear()
        record = run_cell(specs[key], str(tmp_path))
        assert record["status"] == "ok", record.get("error")
        trained = dqn_config_from_dict(specs[key]["config"]["train"]["dqn"])
        own = (trained.change_margin, trained.queue_below_mps, trained.no_return_s)
        ((text, policy, folder),) = faked_runs
        assert folder.parent == tmp_path / "runs" and folder.name.startswith(f".{key}.partial-")  # written atomically
        assert (policy.change_margin, policy.queue_below_mps, policy.no_return_s) == (drive or own), key
        assert policy.alpha == alpha and text.startswith(f"dqn:{tmp_path / 'train' / specs[key]['train_key']}")
        assert record["summary"]["mean_speed_mps"] == 20.0
