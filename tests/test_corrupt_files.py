"""Issue 25, parts 4, 5 and 7: every kind of file the project reads back, spoiled in every way listed, gives one
line and the right outcome (a model file or checkpoint: exit 2 and every byte kept; a run folder's marker: the
folder left alone; a cut-short training log: cut back on resume). Also the locks and partial-folder cleanup of
runio on their own, and the environments' refusal of actions that are not integers.

Cell records of the studies are spoiled in test_runner.py, test_scenario2.py and test_ablation.py; run folders
and models of scenario I in test_faults_scenario1.py."""

from __future__ import annotations

import copy
import hashlib
import json
import math
import pickle
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from conftest import interrupted_at_step_20

from coopsumo import simulate
from coopsumo.agents import train_cli as train
from coopsumo.agents.dqn import QNetwork
from coopsumo.agents.file_checks import prepare_resume, truncate_log
from coopsumo.agents.model_file import save_model
from coopsumo.config import SimConfig, TrainConfig, to_dict
from coopsumo.dqn_config import DQN_PRESETS
from coopsumo.errors import UsageError
from coopsumo.run_dirs import (
    PARTIAL_MARKER,
    RUN_MARKER,
    check_run_dir,
    check_study_root,
    clear_partials,
    finished_run,
    lock_path,
    mark_run_dir,
    out_lock,
    release_lock,
    try_lock,
)

SIM = ["--steps", "20", "--quiet"]


def snapshot(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*"))}  # fmt: skip


def one_line(code: int, err: str, *fragments: str) -> str:
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert all(f in lines[0] for f in fragments), (fragments, lines[0])
    assert "weights_only" not in lines[0], lines[0]  # never torch's advice to load a file unsafely
    return lines[0]


# -- model files ----------------------------------------------------------------------------------------------
def _payload() -> dict[str, Any]:
    """What save_model writes for a default-learner model (dueling head)."""
    cfg = TrainConfig(sim=SimConfig(policy="dqn"))
    net = QNetwork(cfg.dqn.speed_scale_mps, dueling=True)
    meta = {"config": to_dict(cfg)}
    return {"state_dict": {k: v.clone() for k, v in net.state_dict().items()}, "grid_shape": [3, 3, 20],
            "n_actions": 4, "speed_scale_mps": net.speed_scale_mps, "dueling": True, "observation": "paper",
            "meta": meta}  # fmt: skip


def _learner(**fields: Any) -> Callable[[dict[str, Any]], None]:
    return lambda p: p["meta"]["config"]["dqn"].update(fields)


def _set(key: str, value: Any) -> Callable[[dict[str, Any]], None]:
    return lambda p: p.update({key: value})


def _nan_weight(p: dict[str, Any]) -> None:
    p["state_dict"]["fc1.weight"][0, 0] = math.nan


MODEL_CASES: dict[str, tuple[Callable[[dict[str, Any]], None] | bytes, str]] = {
    "empty file": (b"", "cannot read model file"),
    "garbage": (b"not a model at all", "cannot read model file"),
    "json": (b'{"state_dict": {}}', "cannot read model file"),
    "a list": (lambda p: p.clear(), "not a coopsumo model file"),
    "no weights": (lambda p: p.pop("state_dict"), "not a coopsumo model file"),
    "grid shape a string": (_set("grid_shape", "3x3x20"), "grid shape"),
    "grid shape with a float": (_set("grid_shape", [3, 3.5, 20]), "grid shape"),
    "action count a string": (_set("n_actions", "4"), "action count"),
    "action count a bool": (_set("n_actions", True), "action count"),
    "speed scale a string": (_set("speed_scale_mps", "30"), "speed scale"),
    "speed scale nan": (_set("speed_scale_mps", math.nan), "speed scale"),
    "speed scale 0": (_set("speed_scale_mps", 0.0), "speed scale"),
    "dueling a string": (_set("dueling", "yes"), "dueling"),
    "meta a list": (_set("meta", [1, 2]), "meta of type list"),
    "weights a list": (_set("state_dict", [1, 2]), "weights of type list"),
    "a weight not a tensor": (lambda p: p["state_dict"].update({"fc1.bias": "x"}), "not a tensor"),
    "a nan weight": (_nan_weight, "non-finite"),
    # issue 82: record_schemas.MODEL_TENSORS, |w| < 1e6
    "a weight 1e30": (lambda p: p["state_dict"]["fc1.weight"].view(-1).__setitem__(0, 1e30),
                      "field state_dict.fc1.weight must be a finite number > -1e+06 and < 1e+06 (a network weight)"),
    "a bias -2e6": (lambda p: p["state_dict"]["out.bias"].view(-1).__setitem__(0, -2e6), "field state_dict.out.bias"),
    "decision interval 0": (_learner(decision_interval_steps=0), "decision_interval_steps"),
    "decision interval a string": (_learner(decision_interval_steps="10"), "decision_interval_steps must be an"),
    "decision interval 2.5": (_learner(decision_interval_steps=2.5), "decision_interval_steps must be an integer"),
    "decision interval 10000": (_learner(decision_interval_steps=10_000), "decision_interval_steps"),
    "action mask a string": (_learner(action_mask="yes"), "action_mask must be true or false"),
    "restart speed nan": (_learner(restart_below_mps=math.nan), "restart_below_mps"),
    "restart speed 1e308": (_learner(restart_below_mps=1e308), "restart_below_mps"),
    "lr a string": (_learner(lr="fast"), "lr must be a finite number"),
    "gamma 1.5": (_learner(gamma=1.5), "gamma"),
    "learner settings a list": (lambda p: p["meta"]["config"].update(dqn=[1]), "no learner settings"),
    "configuration a string": (lambda p: p["meta"].update(config="trained"), "no learner settings"),
    # the probe's (2026-12-02): each was copied into a run's config.json as what the model was trained on
    "trained on 7 lanes": (lambda p: p["meta"]["config"]["sim"]["road"].update(lanes=7), "sim.road.lanes = 7, outside"),
    "trained at alpha -3": (lambda p: p["meta"]["config"]["sim"]["reward"].update(alpha=-3.0), "sim.reward.alpha"),
    "trained with steps of 0 s": (lambda p: p["meta"]["config"]["sim"]["control"].update(dt_s=0.0), "sim.control.dt_s"),
    # the probe's (2026-12-02, third): the network's own speed scale drove (lane changes 6 -> 0) unchecked
    "speed scale 1e9": (_set("speed_scale_mps", 1e9), "speed scale 1000000000.0, not a finite number > 0 and <= 1000"),
    "a plain pickle": (pickle.dumps({"a": 1}, protocol=4), "not a file of tensors torch can read safely"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(MODEL_CASES))
def test_a_spoiled_model_file_is_one_line_and_nothing_is_written(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    change, fragment = MODEL_CASES[case]
    model = tmp_path / "models" / "model.pt"
    model.parent.mkdir()
    if isinstance(change, bytes):
        model.write_bytes(change)
    else:
        payload = _payload()
        change(payload)
        torch.save(payload if payload else [], model)
    out = tmp_path / "runs" / "out"
    before = snapshot(tmp_path)
    code = simulate.main([*SIM, "--policy", f"dqn:{model}", "--out", str(out)])
    one_line(code, capsys.readouterr().err, "--policy", fragment)
    assert snapshot(tmp_path) == before


def test_a_model_file_cut_short_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    model = tmp_path / "model.pt"
    save_model(model, QNetwork(30.0, dueling=True), _payload()["meta"])
    model.write_bytes(model.read_bytes()[: model.stat().st_size // 2])
    code = simulate.main([*SIM, "--policy", f"dqn:{model}", "--out", str(tmp_path / "out")])
    one_line(code, capsys.readouterr().err, "--policy", "cannot read model file")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.pt"]


# -- checkpoints ----------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def checkpoint_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A training folder as train leaves it when interrupted: its marker, config.json, a checkpoint at step 20."""
    out = tmp_path_factory.mktemp("ckpt") / "run"
    cfg = TrainConfig(sim=SimConfig(steps=40, seed=3, policy="dqn"), dqn=DQN_PRESETS["paper"], eval_steps=0,
                      log_every_steps=10, checkpoint_every_steps=20)  # fmt: skip
    interrupted_at_step_20(cfg, out).replace(out / "checkpoint.pt")  # the log goes on to step 40
    return out


def _at(*keys: str, value: Any) -> Callable[[dict[str, Any]], None]:
    def change(state: dict[str, Any]) -> None:
        d = state
        for k in keys[:-1]:
            d = d[k]
        d[keys[-1]] = value

    return change


def _drop(*keys: str) -> Callable[[dict[str, Any]], None]:
    def change(state: dict[str, Any]) -> None:
        d = state
        for k in keys[:-1]:
            d = d[k]
        del d[keys[-1]]

    return change


def _tensor(key: str, fn: Callable[[torch.Tensor], torch.Tensor]) -> Callable[[dict[str, Any]], None]:
    return lambda s: s.update({key: fn(s[key])})


def _nan_online(state: dict[str, Any]) -> None:
    name = next(iter(state["learner"]["online"]))
    state["learner"]["online"][name] = torch.full_like(state["learner"]["online"][name], math.nan)


def _set_in(*keys: Any, value: Any) -> Callable[[dict[str, Any]], None]:
    """Set state[k1][k2]...[kn] = value (keys may be list indices)."""

    def change(state: dict[str, Any]) -> None:
        d: Any = state
        for k in keys[:-1]:
            d = d[k]
        d[keys[-1]] = value

    return change


def _replay(field: str, row: int, value: float) -> Callable[[dict[str, Any]], None]:
    """Write `value` into row `row` (one the memory holds) of the replay memory's field `field`."""

    def change(state: dict[str, Any]) -> None:
        data = state["learner"]["buffer"]["data"]
        data[field] = data[field].clone()
        data[field][row] = value
        assert row < state["learner"]["buffer"]["size"]

    return change


def _inf_target(state: dict[str, Any]) -> None:
    name = next(iter(state["learner"]["target"]))
    state["learner"]["target"][name] = torch.full_like(state["learner"]["target"][name], math.inf)


def _action_seven(state: dict[str, Any]) -> None:
    state["actions"] = state["actions"].clone()
    state["actions"][0] = 7


CHECKPOINT_CASES: dict[str, tuple[Callable[[dict[str, Any]], None] | bytes, str]] = {
    "empty file": (b"", "cannot read checkpoint"),
    "garbage": (b"\x00\x01 not a checkpoint", "cannot read checkpoint"),
    # the probe's (2026-12-02, third): torch's advice to load these with weights_only=False, and its warning
    "a plain pickle": (pickle.dumps({"a": 1}, protocol=4), "cannot read checkpoint"),
    "JSON": (b'{"step": 20}', "cannot read checkpoint"),
    "a list": (lambda s: s.clear(), "not a coopsumo training checkpoint"),
    "no log window": (_drop("window"), "not a coopsumo training checkpoint"),
    "step a string": (_at("step", value="20"), "step '20'"),
    "step negative": (_at("step", value=-1), "step -1"),
    "step a bool": (_at("step", value=True), "step True"),
    "counts of floats": (_tensor("action_counts", lambda t: t.float()),
                         "recorded action counts a torch.float32 tensor, not a tensor of integers"),  # probe 16, T1
    "counts cut short": (_tensor("action_counts", lambda t: t[:5]), "records actions for 5 steps, not its 20"),
    "an action 7": (_action_seven, "outside 0-3"),
    "actions cut short": (_tensor("actions", lambda t: t[:3]), "do not match their counts"),
    "window a list": (_at("window", value=[1]), "log window"),
    "window loss a string": (_at("window", "loss", value="x"), "log window"),
    # issue 82, probe 4, F12: a text among the losses was a traceback after the resume began; a true was a number
    "window loss a text entry": (_at("window", "loss", value=[0.5, "x"]), "window.loss.1 is 'x', not a number"),
    "window r_speed true": (_at("window", "r_speed", value=True), "window.r_speed is True, not a number"),
    "window r_flow of 400 digits": (_at("window", "r_flow", value=int("9" * 400)), "larger than a float holds"),
    "no online weights": (_drop("learner", "online"), "learner state without online"),
    "env steps negative": (_at("learner", "env_steps", value=-1), "env_steps"),
    "updates a string": (_at("learner", "updates", value="3"), "updates"),
    "nan online weights": (_nan_online, "non-finite"),
    "online weights a list": (_at("learner", "online", value=[1]), "online weights of type list"),
    "replay memory a list": (_at("learner", "buffer", value=[1]), "replay memory"),
    "rng state a list": (_at("learner", "torch_rng", value=[1]), "random-generator"),
    "configuration a list": (_at("config", value=[1]), "no training configuration"),
    "learner settings a list": (_at("config", "dqn", value=[1]), "no training configuration"),
    "a configuration field of another version": (lambda s: s["config"].update(zzz=1), "unknown field 'zzz'"),
    "a run setting of another version": (lambda s: s["config"]["sim"].update(zzz=1), "unknown field 'zzz'"),
    "decision interval 0": (_at("config", "dqn", "decision_interval_steps", value=0), "decision_interval_steps"),
    "lr a string": (_at("config", "dqn", "lr", value="x"), "lr must be a finite number"),
    "lr 1e308": (_at("config", "dqn", "lr", value=1e308), "lr must be"),
    "lanes a string": (_at("config", "sim", "road", "lanes", value="3"), "road.lanes must be an integer"),
    "steps 2.5": (_at("config", "sim", "steps", value=2.5), "steps must be an integer"),
    "alpha nan": (_at("config", "sim", "reward", "alpha", value=math.nan), "alpha must be a finite number"),
    "step beyond the run": (_at("config", "sim", "steps", value=10), "step 20 lies beyond the run's 10 steps"),
    "eval steps negative": (_at("config", "eval_steps", value=-1), "eval steps"),
    # issue 67: what a checkpoint holds must agree with itself before it is trusted
    "nan in the optimizer state": (_at("learner", "optimizer", "state", value={0: {"momentum_buffer": torch.full(
        (3,), math.nan)}}), "non-finite values (nan or inf) in its optimizer state (state.0.momentum_buffer)"),
    "optimizer lr inf": (_set_in("learner", "optimizer", "param_groups", 0, "lr", value=math.inf),
                         "optimizer state (param_groups.0.lr)"),
    "nan reward in the replay memory": (_replay("rewards", 0, math.nan), "replay memory (rewards)"),
    "inf reward in the replay memory": (_replay("rewards", 1, math.inf), "replay memory (rewards)"),
    "-inf feature in the replay memory": (_replay("next_features", 2, -math.inf), "replay memory (next_features)"),
    "an action 9 in the replay memory": (_replay("actions", 0, 9), "actions outside 0-3 in its replay memory"),
    "replay position beyond its capacity": (_at("learner", "buffer", "pos", value=5000), "position 5000"),
    "replay position out of order": (_at("learner", "buffer", "pos", value=3), "position 3"),
    "replay size beyond its capacity": (_at("learner", "buffer", "size", value=2001), "size 2001"),
    "replay position a string": (_at("learner", "buffer", "pos", value="3"), "without a capacity, size, position"),
    "replay capacity not the configuration's": (_at("learner", "buffer", "capacity", value=1000), "capacity 1000"),
    "a replay field cut short": (_set_in("learner", "buffer", "data", "rewards", value=torch.zeros(100)),
                                 "'rewards' that is not a tensor of 2000 rows"),
    "env steps not the step": (_at("learner", "env_steps", value=25), "env_steps = 25, not its step 20"),
    "more decisions than steps": (_at("learner", "decisions", value=21), "21 decision rounds in 20 steps"),
    "updates no decisions can make": (_at("learner", "updates", value=6), "6 gradient updates"),
    "inf in the log window": (_at("window", "r_speed", value=math.inf), "log window (r_speed)"),
    "nan in the log window's losses": (_at("window", "loss", value=[0.5, math.nan]), "log window (loss.1)"),
    "inf target weights": (_inf_target, "non-finite values (nan or inf) in target weights"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(CHECKPOINT_CASES))
def test_a_spoiled_checkpoint_is_one_line_and_every_byte_is_kept(
    case: str, checkpoint_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    change, fragment = CHECKPOINT_CASES[case]
    out = tmp_path / "run"
    shutil.copytree(checkpoint_folder, out)
    path = out / "checkpoint.pt"
    if isinstance(change, bytes):
        path.write_bytes(change)
    else:
        state = copy.deepcopy(torch.load(path, weights_only=True))
        change(state)
        torch.save(state if state else [], path)
    before = snapshot(tmp_path)
    code = train.main(["--resume", "--quiet", "--out", str(out)])
    one_line(code, capsys.readouterr().err, "checkpoint", fragment)
    assert snapshot(tmp_path) == before


def test_the_unspoiled_checkpoint_resumes(checkpoint_folder: Path, tmp_path: Path) -> None:
    """The cases above fail for what was spoiled, not for the checkpoint they start from."""
    out = tmp_path / "run"
    shutil.copytree(checkpoint_folder, out)
    assert [line.split(",")[0] for line in (out / "train_log.csv").read_text().splitlines()] == ["step", "10", "20",
                                                                                                "30", "40"]  # fmt: skip
    assert train.main(["--resume", "--quiet", "--out", str(out)]) == 0
    assert finished_run(out, "train") and not (out / "checkpoint.pt").exists()
    steps = [line.split(",")[0] for line in (out / "train_log.csv").read_text().splitlines()]
    assert steps == ["step", "10", "20", "30", "40"]  # rows 30 and 40 once, written again by the resume


SIM_CASES = {  # the probe's (2026-12-02): tracebacks, a changed reward, or a replay that "diverged" unexplained
    "dt_s": ("control", 0.0), "v_exp_std_kmh": ("demand", -15.0), "capacity_veh_h_per_lane": ("reward", 0.0),
    "car_length_m": ("control", 0.0), "loop_period_s": ("road", 0.0), "flow_window_s": ("reward", 0.0),
    "v_min_mps": ("reward", 40.0), "newell_c_per_s": ("control", -5.0), "lane_width_m": ("road", 1000.0),
    "a2_s": ("control", -0.5), "v_exp_min_kmh": ("demand", 500.0),
}  # fmt: skip


@pytest.mark.parametrize("name", sorted(SIM_CASES))
def test_a_checkpoint_whose_run_is_out_of_range_names_the_setting(
    name: str, checkpoint_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A checkpoint's (and config.json's) physical settings have limits too (config.SIM_LIMITS): one line naming the
    setting, exit 2, nothing written."""
    part, value = SIM_CASES[name]
    out = tmp_path / "run"
    shutil.copytree(checkpoint_folder, out)
    state = copy.deepcopy(torch.load(out / "checkpoint.pt", weights_only=True))
    state["config"]["sim"][part][name] = value
    torch.save(state, out / "checkpoint.pt")
    (out / "config.json").write_text(json.dumps({"config": state["config"]}))
    before = snapshot(tmp_path)
    code = train.main(["--resume", "--quiet", "--out", str(out)])
    one_line(code, capsys.readouterr().err, f"{part}.{name} must be")
    assert snapshot(tmp_path) == before


# -- the training log and temporary files on resume -------------------------------------------------------------
@pytest.mark.parametrize(("value", "shown"), [(math.nan, "NaN"), ("x", '"x"'), (0.5, "0.5")])
def test_a_config_json_that_is_not_the_checkpoints_names_the_field(
    value: Any, shown: str, checkpoint_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The probe's (2026-12-02): config.json's learning rate edited to NaN was refused as another training's without
    saying which field differs; now the line names it and its two values."""
    out = tmp_path / "run"
    shutil.copytree(checkpoint_folder, out)
    meta = {"config": copy.deepcopy(torch.load(out / "checkpoint.pt", weights_only=True)["config"])}
    lr = meta["config"]["dqn"]["lr"]
    meta["config"]["dqn"]["lr"] = value
    (out / "config.json").write_text(json.dumps(meta))
    before = snapshot(tmp_path)
    code = train.main(["--resume", "--quiet", "--out", str(out)])
    one_line(code, capsys.readouterr().err, f"(first at config.dqn.lr: {json.dumps(lr)} != {shown})", "copied in?")
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("cell", ["nan", "inf", "x"])
def test_a_log_row_the_resume_would_keep_must_be_numbers(
    cell: str, checkpoint_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The probe's (2026-12-02): a row of train_log.csv before the checkpoint's step with a loss of nan was kept and
    resumed; now it is one line naming the log, the column and the row, and nothing is written."""
    out = tmp_path / "run"
    shutil.copytree(checkpoint_folder, out)
    log = out / "train_log.csv"
    lines = log.read_text().splitlines(keepends=True)
    header, row = lines[0].strip().split(","), lines[1].split(",")
    row[header.index("mean_speed_mps")] = cell
    log.write_text(lines[0] + ",".join(row) + "".join(lines[2:]))
    before = snapshot(tmp_path)
    code = train.main(["--resume", "--quiet", "--out", str(out)])
    one_line(code, capsys.readouterr().err, f"training log {log} has mean_speed_mps = '{cell}' in its row of step 10",
             "train again without --resume")  # fmt: skip
    assert snapshot(tmp_path) == before


def _log_cell(name: str, value: str) -> Callable[[list[str]], list[str]]:
    """An edit of train_log.csv's lines: its first row's cell of column `name` set to value."""

    def change(lines: list[str]) -> list[str]:
        header, row = lines[0].strip().split(","), lines[1].rstrip("\n").split(",")
        row[header.index(name)] = value
        return [lines[0], ",".join(row) + "\n", *lines[2:]]

    return change


LOG_CASES: dict[str, tuple[Callable[[list[str]], list[str]], str]] = {
    # the probe's (2026-12-02, third): each was kept by the resume, rc 0
    "a row twice": (lambda lines: [*lines[:3], lines[1], *lines[3:]], "has the row of step 10 after that of step 20 ("),
    "a speed of 999 m/s": (_log_cell("mean_speed_mps", "999"), "has mean_speed_mps = '999' in its row of step 10: it"),
    "-100 vehicles": (_log_cell("vehicles", "-100"), "has vehicles = '-100' in its row of step 10: it must be"),
    "2.5 lane changes": (_log_cell("lane_changes", "2.5"), "has lane_changes = '2.5' in its row of step 10"),
    "two columns swapped": (lambda lines: [lines[0].replace("vehicles,lane_changes,", "lane_changes,vehicles,"),
                                           *lines[1:]], "has the header 'step,"),
    "a column missing": (lambda lines: [lines[0].replace(",alpha", ""), *lines[1:]], "not train's step,"),
    "emptied": (lambda lines: [], "has the header 'none (an empty file)'"),
    "a row that is not one between two": (lambda lines: [lines[0], "garbage,row\n", *lines[1:]],
                                          "has a row that is not one of its rows after that of step 0: 'garbage,row'"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(LOG_CASES))
def test_a_damaged_log_the_resume_would_keep_is_one_line_and_every_byte_is_kept(
    case: str, checkpoint_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    change, fragment = LOG_CASES[case]
    out = tmp_path / "run"
    shutil.copytree(checkpoint_folder, out)
    log = out / "train_log.csv"
    log.write_text("".join(change(log.read_text().splitlines(keepends=True))))
    before = snapshot(tmp_path)
    code = train.main(["--resume", "--quiet", "--out", str(out)])
    one_line(code, capsys.readouterr().err, f"training log {log} ", fragment, "train again without --resume")
    assert snapshot(tmp_path) == before


def test_a_users_file_in_an_interrupted_training_is_not_taken_for_the_trainings(
    checkpoint_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The probe's (2026-12-02, third): notes.txt put into an interrupted training's folder was listed in its finished
    marker as one of train's own files; now the resume refuses in one line naming it, and every byte is kept."""
    out = tmp_path / "run"
    shutil.copytree(checkpoint_folder, out)
    (out / "notes.txt").write_text("my own notes\n")
    before = snapshot(tmp_path)
    code = train.main(["--resume", "--quiet", "--out", str(out)])
    one_line(code, capsys.readouterr().err, f"--out {out} holds notes.txt, which no training writes")
    assert snapshot(tmp_path) == before


def test_the_log_rules_are_the_logs_columns() -> None:
    from coopsumo.agents.file_checks import LOG_RULES
    from coopsumo.agents.tb_log import LOG_FIELDS

    assert set(LOG_RULES) == set(LOG_FIELDS)


def test_resume_cuts_the_log_back_to_the_checkpoint(tmp_path: Path) -> None:
    log = tmp_path / "train_log.csv"
    rows = ["step,td_loss,wall_s"] + [f"{s},0.5,{s / 100}" for s in (250, 500, 750, 1000)]
    log.write_text("\n".join(rows) + "\n1250,0.")  # killed in the middle of writing a row
    (tmp_path / ".checkpoint.pt.x1y2z3w4.tmp").write_bytes(b"half")
    (tmp_path / ".model.pt.x1y2z3w4.tmp").write_bytes(b"half")
    (tmp_path / "keep.txt").write_text("kept\n")
    prepare_resume(tmp_path, 500)
    assert log.read_text().splitlines() == rows[:3]
    assert sorted(p.name for p in tmp_path.iterdir()) == [".checkpoint.pt.x1y2z3w4.tmp", ".model.pt.x1y2z3w4.tmp",
                                                          "keep.txt", "train_log.csv"]  # probe 12, N3: kept
    assert truncate_log(log, 500) == 0 and truncate_log(tmp_path / "missing.csv", 10) == 0
    log.write_text("step,td_loss\n250,1\nnot a row\n500,2\n")
    assert truncate_log(log, 1000) == 2 and log.read_text() == "step,td_loss\n250,1\n"


# -- run folders: a spoiled marker keeps the folder from being replaced ----------------------------------------
MARKERS: dict[str, str | None] = {
    "not JSON": "{kind: simulate",
    "a list": '["simulate"]',
    "kind a number": '{"kind": 7, "files": []}',
    "files a string": '{"kind": "simulate", "files": "config.json"}',
    "files null": '{"kind": "simulate", "files": null}',
    "not finished": '{"kind": "simulate", "finished": false}',
    "files not names": '{"kind": "simulate", "files": [null, "config.json", "summary.json"]}',
    "another command's": '{"kind": "train", "files": ["config.json", "summary.json"]}',
    "a folder": None,
}


@pytest.mark.parametrize("case", sorted(MARKERS))
def test_a_spoiled_marker_keeps_the_folder(case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "config.json").write_text("{}\n")
    (out / "summary.json").write_text("{}\n")
    marker = MARKERS[case]
    if marker is None:
        (out / RUN_MARKER).mkdir()
    else:
        (out / RUN_MARKER).write_text(marker)
    before = snapshot(tmp_path)
    code = simulate.main([*SIM, "--out", str(out)])
    one_line(code, capsys.readouterr().err, str(out), "left alone")
    assert snapshot(tmp_path) == before


def test_finished_run_needs_the_marker_of_its_kind_and_every_listed_entry(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "summary.json").write_text("{}")
    assert not finished_run(out, "simulate")
    mark_run_dir(out, "simulate")
    assert finished_run(out, "simulate") and not finished_run(out, "train")
    (out / "summary.json").unlink()
    assert not finished_run(out, "simulate")
    mark_run_dir(out, "train", finished=False)
    assert not finished_run(out, "train")


def test_a_running_commands_marker_says_so_and_lists_names_only(tmp_path: Path) -> None:
    """A training's marker while it runs (and a study's) was {"files": null}: now "finished" false and no list until
    it ends, then the names of what it holds; a marker of either form, or an older one, reads the same."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "train_log.csv").write_text("step\n")
    mark_run_dir(out, "train", finished=False)
    running = json.loads((out / RUN_MARKER).read_text())
    assert running["finished"] is False and "files" not in running and None not in running.values()
    check_run_dir(out, "train")  # its training may go on (resume) or start again (simulate's: MARKERS above)
    (out / "model.pt").write_text("weights")
    mark_run_dir(out, "train")
    ended = json.loads((out / RUN_MARKER).read_text())
    assert ended["finished"] is True and ended["files"] == ["model.pt", "train_log.csv"] and finished_run(out, "train")
    (out / RUN_MARKER).write_text('{"kind": "train", "version": "0.1.0", "files": null}')  # written before
    assert not finished_run(out, "train")
    check_run_dir(out, "train")
    (out / RUN_MARKER).write_text('{"kind": "train", "files": ["model.pt", 7]}')  # a list spoiled: left alone
    with pytest.raises(UsageError, match="lists no files"):
        check_run_dir(out, "train")


# -- study roots ------------------------------------------------------------------------------------------------
OWN = ("plan.json", "cells", "runs", "report.md", "fig*.png")


def test_a_study_root_is_claimed_only_when_it_is_the_studys(tmp_path: Path) -> None:
    legacy = tmp_path / "legacy"  # only the study's own names, but no marker and no plan file: a user's (probe 7, I5)
    (legacy / "cells").mkdir(parents=True)
    (legacy / "report.md").write_text("# report\n")
    (legacy / "fig4.png").write_bytes(b"png")
    with pytest.raises(UsageError, match="holds cells and 2 more, named like a coopsumo scenario1 study's"):
        check_study_root(legacy, "scenario1", OWN)
    (legacy / "notes.txt").write_text("mine\n")
    with pytest.raises(UsageError, match="holds notes.txt, which coopsumo scenario1 does not write"):
        check_study_root(legacy, "scenario1", OWN)
    (legacy / "plan.json").write_text("{}\n")  # its own plan file: a study root of an earlier version, but for
    with pytest.raises(UsageError, match="holds notes.txt"):  # a file no study writes (issue 82, probe 8, J3)
        check_study_root(legacy, "scenario1", OWN)
    (legacy / "notes.txt").unlink()
    check_study_root(legacy, "scenario1", OWN)
    other = tmp_path / "other"
    other.mkdir()
    mark_run_dir(other, "scenario2", finished=False)
    with pytest.raises(UsageError, match="scenario2 run, not a scenario1 study"):
        check_study_root(other, "scenario1", OWN)
    check_study_root(tmp_path / "missing", "scenario1", OWN)


def test_scenario2_refuses_a_training_folder_as_its_root(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from coopsumo.studies.scenario2 import study as scenario2

    out = tmp_path / "trained"
    out.mkdir()
    (out / "model.pt").write_bytes(b"weights")
    mark_run_dir(out, "train")
    before = snapshot(tmp_path)
    code = scenario2.main(["--profile", "tiny", "--quiet", "--out", str(out)])
    one_line(code, capsys.readouterr().err, "train run, not a scenario2 study")
    assert snapshot(tmp_path) == before


# -- locks and partial folders -------------------------------------------------------------------------------------
def test_a_second_lock_on_the_same_folder_is_refused_and_the_lock_file_goes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import coopsumo.run_dirs as run_dirs

    monkeypatch.setattr(run_dirs, "LOCK_WAIT_S", 0.1)
    out = tmp_path / "run"
    with out_lock(out, "simulate"):
        assert "simulate, pid" in lock_path(out.resolve()).read_text()
        with pytest.raises(UsageError, match="another coopsumo command is writing") as refused:
            with out_lock(out, "train"):
                pass
        assert len(str(refused.value).splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no lock file left (the parent was made for it)
    with out_lock(out, "simulate"):  # free again
        pass


def test_clear_partials_removes_only_what_no_running_command_holds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    stale = tmp_path / ".a.partial-abc12345"
    running = tmp_path / ".b.partial-xyz98765"
    mine = tmp_path / ".c.partial-mmm00000"
    for folder in (stale, running, mine):
        folder.mkdir()
        (folder / "summary.json").write_text("{}")
        (folder / PARTIAL_MARKER).write_text("the partial folder of a coopsumo run\n")
    (tmp_path / ".d.lock").write_text("simulate, pid 1\n")  # left by a killed run
    (tmp_path / ".e.partial-notours").mkdir()  # not a name a run makes: left alone
    (tmp_path / "a").mkdir()
    held = try_lock(lock_path(tmp_path / "b"))
    assert held is not None
    try:
        removed = clear_partials(tmp_path, "simulate", mine="c")
    finally:
        release_lock(held, lock_path(tmp_path / "b"))
    assert sorted(p.name for p in removed) == [".a.partial-abc12345", ".c.partial-mmm00000"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [".b.partial-xyz98765", ".e.partial-notours", "a"]
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 2 and all("the partial folder of an interrupted run" in line for line in lines)


# -- the environments refuse actions that are not integers ---------------------------------------------------------
BAD_ACTIONS: list[tuple[Any, type[Exception]]] = [
    (True, TypeError), (np.bool_(False), TypeError), (1.0, TypeError), (None, TypeError), ("1", TypeError),
    (np.array([1, 2]), TypeError), (np.array([1]), TypeError), ([1], TypeError), (4, ValueError), (-1, ValueError),
]  # fmt: skip


def test_check_action_takes_integers_and_names_everything_else() -> None:
    from coopsumo.envs.common import check_action

    assert [check_action(a) for a in (0, 3, np.int64(2), np.array(1))] == [0, 3, 2, 1]
    for action, error in BAD_ACTIONS:
        with pytest.raises(error, match="action") as raised:
            check_action(action, "action")
        assert repr(action)[:6] in str(raised.value) or type(action).__name__ in str(raised.value)


@pytest.mark.sumo
def test_the_environments_refuse_non_integer_actions() -> None:
    """Before: the Gymnasium env took step(True) as 'right'; the PettingZoo env's step(None) gave a bare TypeError."""
    from coopsumo.envs.highway_env import HighwayEnv
    from coopsumo.envs.parallel_env import HighwayParallelEnv

    env = HighwayEnv(max_steps=5)
    try:
        env.reset(seed=1)
        for action, error in BAD_ACTIONS:
            with pytest.raises(error, match=r"action must be") as raised:
                env.step(action)
            assert "0-3" in str(raised.value) or "speedup" in str(raised.value)
        env.step(np.int64(2))  # still usable: nothing was applied
    finally:
        env.close()
    penv = HighwayParallelEnv(max_steps=5)
    try:
        penv.reset(seed=1)
        with pytest.raises(TypeError, match="actions must be a dict of live agent name -> action"):
            penv.step(None)  # type: ignore[arg-type]
        agent = penv.agents[0]
        for action, error in BAD_ACTIONS:
            with pytest.raises(error, match=f"action of {agent} must"):
                penv.step({a: (action if a == agent else 2) for a in penv.agents})
        penv.step({a: 2 for a in penv.agents})
    finally:
        penv.close()
