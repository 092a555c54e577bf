"""Identity that is checked, not assumed, and plausibility on everything read back: swapped or edited model
weights, a model.pt from another training than its config.json, a checkpoint copied in from another training,
records and outputs with values no run can produce."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from coopsumo.agents.dqn import QNetwork
from coopsumo.agents.model_file import MAX_MODEL_BYTES, ModelFileError, load_model, save_model
from coopsumo.config import SimConfig, TrainConfig, to_dict
from coopsumo.dqn_config import DQN_PRESETS
from coopsumo.errors import USAGE_EXIT
from coopsumo.files import write_json
from coopsumo.run_dirs import mark_run_dir
from coopsumo.studies.engine.records import implausible, record_problem
from coopsumo.studies.engine.run_checks import detectors_problem
from coopsumo.studies.engine.trainings import model_folder_problem

REPO = Path(__file__).resolve().parent.parent


def _meta(seed: int) -> dict:
    return {"config": to_dict(TrainConfig(sim=SimConfig(seed=seed, policy="dqn"), dqn=DQN_PRESETS["paper"]))}


def test_weights_changed_after_saving_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "model.pt"
    save_model(path, QNetwork(30.0), _meta(0))
    load_model(path)  # as written: loads
    payload = torch.load(path, weights_only=True)
    name = next(iter(payload["state_dict"]))
    payload["state_dict"][name] = payload["state_dict"][name] + 0.01  # finite, same shape: only the digest tells
    torch.save(payload, path)
    with pytest.raises(ModelFileError, match="do not match the digest"):
        load_model(path)


def test_a_model_from_another_training_than_its_config_is_not_reused(tmp_path: Path) -> None:
    folder = tmp_path / "alpha0"
    folder.mkdir()
    write_json(folder / "config.json", _meta(0))
    write_json(folder / "train_summary.json", {"steps": 1})
    save_model(folder / "model.pt", QNetwork(30.0), _meta(0))
    mark_run_dir(folder, "train")
    assert model_folder_problem(folder) is None
    save_model(folder / "model.pt", QNetwork(30.0), _meta(7))  # another seed's model swapped in
    problem = model_folder_problem(folder)
    assert problem is not None and "config.sim.seed: 7 != 0" in problem and "swapped" in problem


def test_a_huge_file_is_refused_before_it_is_read(tmp_path: Path) -> None:
    path = tmp_path / "model.pt"
    with open(path, "wb") as f:
        f.truncate(MAX_MODEL_BYTES + 1)  # sparse: costs no disk
    with pytest.raises(ModelFileError, match="a coopsumo model is a few MB"):
        load_model(path)
    os.truncate(path, 4096)  # zeros torch cannot read: no advice to load unsafely
    with pytest.raises(ModelFileError) as err:
        load_model(path)
    assert "weights_only=False" not in str(err.value)


OK = {"departed": 600, "arrived": 474, "collisions": 0, "teleports": 0, "lane_changes": 513,
      "lane_changes_per_vehicle": 0.855, "mean_speed_mps": 16.7, "throughput_veh_per_h": 2844.0,
      "sumo_collisions": -1, "table_max_dev_speed_mps": -1.0}  # fmt: skip


@pytest.mark.parametrize(("edit", "fragment"), [
    ({"mean_speed_mps": 500.0}, "mean_speed_mps must be a finite number >= 0 and <= 70 (m/s), got 500.0"),
    ({"mean_speed_mps": 99.0}, "mean_speed_mps must be a finite number >= 0 and <= 70 (m/s), got 99.0"),
    ({"mean_speed_mps": -1.0}, "mean_speed_mps must be a finite number >= 0"),
    ({"collisions": -3}, "collisions must be an integer >= 0, got -3"),
    ({"teleports": 1.5}, "teleports must be an integer, got 1.5"),
    ({"arrived": 700}, "above departed"),
    ({"lane_changes": 12345}, "edited?"),
    # issue 82: record_schemas.RUN_SUMMARY, its other limits
    ({"held_share": 1.5}, "held_share must be a finite number >= 0 and <= 1, got 1.5"),
    ({"mean_travel_time_s": -2.0}, "mean_travel_time_s must be"),
    ({"full_road_speed_mps": 80.0}, "full_road_speed_mps must be"),
    ({"departed": 2.5}, "departed must be an integer, got 2.5"),
    ({"lost_veh_h": -1.0}, "lost_veh_h must be"),
    ({"throughput_veh_per_h": 1e7}, "throughput_veh_per_h must be a finite number >= 0 and <= 21600 (veh/h)"),
    ({"lane_changes_per_vehicle": -0.1, "lane_changes": -60}, "lane_changes must be an integer >= 0"),
])  # fmt: skip
def test_impossible_summaries_are_not_trusted(edit: dict, fragment: str) -> None:
    assert implausible(OK) is None
    problem = record_problem({"status": "ok", "summary": {**OK, **edit}}, ("mean_speed_mps",))
    assert problem is not None and fragment in problem, problem


def test_loop_flows_above_what_a_lane_carries_are_not_trusted(tmp_path: Path) -> None:
    path = tmp_path / "detectors.xml"
    cfg = to_dict(SimConfig(steps=600))
    row = ('<interval begin="0.00" end="60.00" id="e1_x00200_l0" nVehContrib="{}" flow="{}" occupancy="5.00" '
           'speed="20.00"/>\n')
    path.write_text("<detector>\n" + row.format(30, "1800.00") + "</detector>\n")
    assert detectors_problem(path, cfg, 60.0) is None
    path.write_text("<detector>\n" + row.format(30, "1800.00") + row.format(1666, "99960.00") + "</detector>\n")
    problem = detectors_problem(path, cfg, 60.0)
    assert problem is not None and "1666 vehicles in 60 s on one lane, above a lane's capacity" in problem, problem


def _train(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "coopsumo.train", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=300)  # fmt: skip


@pytest.mark.sumo
def test_resume_refuses_a_foreign_checkpoint_and_rewrites_a_lost_config(tmp_path: Path) -> None:
    """A checkpoint copied in from another training is refused in one line; a deleted config.json comes back. Each
    training is stopped at its first checkpoint (step 0, written atomically before the first step), which holds the
    training's identity as any later one does; the resume then runs the 600 steps."""
    common = ["--eval-steps", "0", "--quiet", "--select-every", "0"]
    a, b = tmp_path / "a", tmp_path / "b"
    for out, steps, lanes in ((a, "600", "3"), (b, "600", "2")):
        proc = subprocess.Popen([sys.executable, "-m", "coopsumo.train", "--steps", steps, "--lanes", lanes, *common,
                                 "--out", str(out)], cwd=REPO, stderr=subprocess.PIPE, text=True)  # fmt: skip
        while proc.poll() is None and not (out / "checkpoint.pt").exists():
            time.sleep(0.02)
        proc.terminate()
        proc.communicate(timeout=120)
        assert (out / "checkpoint.pt").exists()
    (b / "checkpoint.pt").write_bytes((a / "checkpoint.pt").read_bytes())  # a's run copied into b
    res = _train("--resume", "--out", str(b))
    assert res.returncode == USAGE_EXIT and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert "another training's" in res.stderr and "config.json" in res.stderr
    (a / "config.json").unlink()
    res = _train("--resume", "--out", str(a), "--quiet")
    assert res.returncode == 0, res.stderr
    assert json.loads((a / "config.json").read_text())["config"]["sim"]["road"]["lanes"] == 3
