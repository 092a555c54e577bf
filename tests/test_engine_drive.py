"""studies/engine/cells.py: a model's dqn policy string with its drive settings, and the learning study driving its
evaluations through it (the drive settings reach the loaded policy). No SUMO run: the training and the run are
faked, the model file and its policy are real."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from coopsumo.config import SimConfig, to_dict
from coopsumo.dqn_config import DQNConfig
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
    spec: dict[str, Any] = {"alpha": 8.0, "config": {"train": {"dqn": {"alpha_conditioned": False}},
                                                     "drive": {"change_margin": 2.0}}}  # fmt: skip
    assert cell_policy(spec, Path("/m/model.pt")) == "dqn:/m/model.pt,margin=2"
    spec["config"]["train"]["dqn"]["alpha_conditioned"] = True
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


def learning_specs() -> dict[str, dict[str, Any]]:
    from coopsumo.studies.learning.plan import PROFILES, cell_specs

    profile = replace(PROFILES["tiny"], variants=("paper", "margin2", "conditioned"), alpha_variants=("conditioned",),
                      alphas=(0.0, 8.0), seeds=(0,))  # fmt: skip
    return {s["key"]: s for s in cell_specs(profile, DQNConfig()) if s["kind"] == "train"}


@pytest.fixture
def faked_runs(monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, Any, Path]]:
    """The learning study's trainings faked (a real model file with the training's configuration, untrained) and
    its runs (rollout.run): each run's (policy string, the policy built from it, run folder) is listed."""
    import coopsumo.agents.rollout as rollout
    from coopsumo.agents.dqn import QNetwork
    from coopsumo.agents.model_file import save_model
    from coopsumo.dqn_config import dqn_config_from_dict
    from coopsumo.studies.engine import model_store

    def fake_train(config: dict[str, Any], out: Path, store: Path) -> tuple[dict[str, Any], None]:
        dqn = dqn_config_from_dict(config["dqn"])
        net = QNetwork(30.0, dueling=dqn.dueling, observation=dqn.observation, conditioned=dqn.alpha_conditioned)
        out.mkdir(parents=True, exist_ok=True)
        save_model(out / "model.pt", net, {"config": config})
        return {"steps": config["sim"]["steps"]}, None

    runs: list[tuple[str, Any, Path]] = []

    def fake_run(cfg: SimConfig, policy: Any, run_dir: Path, **kwargs: Any) -> dict[str, Any]:
        runs.append((cfg.policy, policy, run_dir))
        return {"steps": cfg.steps, "departed": 40, "arrived": 30, "mean_speed_mps": 20.0, "lane_changes": 4,
                "lane_changes_per_vehicle": 0.1, "collisions": 0, "teleports": 0, "policy": cfg.policy}  # fmt: skip

    monkeypatch.setattr(model_store, "train_shared", fake_train)
    monkeypatch.setattr(rollout, "run", fake_run)
    return runs


def test_the_learning_study_drives_each_evaluation_with_its_cells_drive_settings(
    tmp_path: Path, faked_runs: list[tuple[str, Any, Path]]
) -> None:
    """margin2 drives target's training with a margin of 2, a queue rule below 5 m/s and no change back within 10 s,
    each set on the loaded policy (as the study set them before it drove through the policy string); paper drives
    its model with none (0, as saved); the conditioned model at its cell's alpha with its variant's settings."""
    from coopsumo.studies.learning.study import run_cell

    specs = learning_specs()
    expected = {
        "paper_alpha0_seed0": ((0.0, 0.0, 0.0), None, "eval_seed{}"),
        "margin2_alpha0_seed0": ((2.0, 5.0, 10.0), None, "eval_seed{}_margin2_queue5_noreturn10"),
        "conditioned_alpha8_seed0": ((1.0, 5.0, 10.0), 8.0, "eval_seed{}_margin1_queue5_noreturn10_alpha8"),
    }
    for key, (drive, alpha, folder) in expected.items():
        faked_runs.clear()
        record = run_cell(specs[key], str(tmp_path))
        assert record["status"] == "ok", record.get("error")
        seeds = [ev["seed"] for ev in specs[key]["config"]["evals"]]
        assert [r[2] for r in faked_runs] == [tmp_path / "evals" / specs[key]["train_key"] / folder.format(s)
                                              for s in seeds]  # fmt: skip
        for text, policy, _ in faked_runs:
            assert (policy.change_margin, policy.queue_below_mps, policy.no_return_s) == drive, key
            assert policy.alpha == alpha and text.startswith(f"dqn:{tmp_path / 'train' / specs[key]['train_key']}")
        assert [s["eval_seed"] for s in record["eval_summaries"]] == seeds
        assert record["summary"]["mean_speed_mps"] == 20.0 and "eval_seed" not in record["summary"]


def test_a_drive_setting_a_learning_cell_does_not_give_is_none_in_its_model() -> None:
    """The learning study drives a setting its cell's config.drive does not give with the model's own value, which
    is 0 (as_trained): what the study set on the loaded policy before it drove through the policy string."""
    from coopsumo.studies.learning.plan import DRIVE_FIELDS, PROFILES, cell_specs

    for profile in PROFILES.values():
        for spec in cell_specs(profile, DQNConfig()):
            if spec["kind"] != "train":
                continue
            drive, trained = spec["config"].get("drive", {}), spec["config"]["train"]["dqn"]
            assert all(trained[f] == 0.0 for f in DRIVE_FIELDS if f not in drive), spec["key"]
            assert set(drive) <= {key for _, key, _ in DRIVES}
    assert to_dict(DQNConfig())["change_margin"] != 0.0  # the default learner's margin is not 0: the check matters
