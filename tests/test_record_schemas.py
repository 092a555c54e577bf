"""Issue 82 items 1 and 6: record_schemas' limits, each field of each record kind outside them refused in one line
naming the file and the field. Here the schemas themselves and a training checkpoint (resumed by `train --resume`);
a run's detectors.xml in test_run_checks.py, `coopsumo history`'s study.json and stats.csv in test_history.py, a
stored model's config.json in test_models_command.py, a study's cell record in test_runner.py (accident-seeds'
reading of a learning study's in test_record_checks.py), scenario I's and the learning study's tables in
test_study_tables.py."""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import math
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import torch
from conftest import interrupted_at_step_20

from coopsumo import record_schemas as rs
from coopsumo import study_tables as st
from coopsumo.agents import train_cli as train
from coopsumo.agents.file_checks import WINDOW_KEYS, checkpoint_problem
from coopsumo.agents.tb_log import Window
from coopsumo.config import SimConfig, TrainConfig
from coopsumo.dqn_config import DQN_PRESETS
from coopsumo.errors import UsageError
from coopsumo.run_dirs import finished_run


# -- the schemas on their own ---------------------------------------------------------------------------------
def test_a_json_record_names_its_first_field_outside_the_schema() -> None:
    schema = rs.Schema((rs.Field("a.b", rs.Number(0.0, 70.0, unit="m/s")), rs.Field("n", rs.Integer(1)),
                        rs.Field("c.*.d", rs.Text(("x", "y"))), rs.Field("e", rs.FLAG, optional=True)))  # fmt: skip
    good = {"a": {"b": 20.0}, "n": 3, "c": [{"d": "x"}, {"d": "y"}]}
    assert schema.problem(good) is None
    cases = {
        "field a.b must be a finite number >= 0 and <= 70 (m/s), got 999": {"a": {"b": 999}},
        "field a.b must be a number (m/s), got 'x'": {"a": {"b": "x"}},
        "field a.b must be a number (m/s), got None": {"a": {"b": None}},
        "field a.b must be a number (m/s), got True": {"a": {"b": True}},
        "field a.b must be a finite number": {"a": {"b": math.nan}},
        "has no field a.b": {"a": {}},
        "field n must be an integer, got 2.5": {"n": 2.5},
        "field n must be an integer >= 1, got 0": {"n": 0},
        "field c.1.d must be one of x, y, got 'z'": {"c": [{"d": "x"}, {"d": "z"}]},
        "field e must be true or false, got 'yes'": {"e": "yes"},
    }
    for words, change in cases.items():
        problem = schema.problem({**good, **change})
        assert problem is not None and problem.startswith(words), (words, problem)
    assert schema.problem({"n": 3}) == "has no field a"
    assert schema.problem([1]) == "is not a JSON object (got list)"
    with pytest.raises(rs.RecordError, match=r"^/x/f.json field n must be an integer >= 1, got 0$"):
        schema.check({**good, "n": 0}, "/x/f.json")


def test_a_table_names_its_row_and_column() -> None:
    table = rs.Table((rs.Field("kind", rs.Text(("free", "jam"))), rs.Field("v", rs.Number(0.0, 1e6)),
                      rs.Field("_p", rs.Number(0.0, 1.0))),
                     case="kind", cases={"free": (rs.Field("v", rs.Number(0.0, 70.0)),)})  # fmt: skip
    names = ["kind", "v", "a_p", "b_p"]
    rows = [{"kind": "free", "v": 20.0, "a_p": 0.5, "b_p": 1.0}, {"kind": "jam", "v": 500.0, "a_p": 0.0, "b_p": 0.0}]
    assert table.problem(names, rows) is None
    assert table.problem(["v"], rows) == "has no column kind"
    assert table.problem(names, []) == "has no row"
    spoiled = {"v": 80.0}, {"b_p": 1.5}, {"a_p": math.nan}, {"kind": "x"}
    words = "row 1 column v must be", "row 1 column b_p must be", "row 1 column a_p must be", "row 1 column kind"
    for change, start in zip(spoiled, words, strict=True):
        problem = table.problem(names, [{**rows[0], **change}, rows[1]])
        assert problem is not None and problem.startswith(start), (change, problem)
    assert table.problem(names, [rows[0], {**rows[1], "v": 2e6}]) is not None  # the other case's wider limit


def test_the_limits_are_ones_a_real_run_never_reaches() -> None:
    assert rs.SPEED_MAX_MPS >= 70 and rs.LANE_CAPACITY_VEH_H > 2160  # the committed loops' highest flow
    assert rs.STORE_CONFIG.problem({"config": {"sim": {"seed": 100, "steps": 90000, "reward": {"alpha": 48.0}},
                                               "dqn": {"preset": "default"}}}) is None  # fmt: skip
    interval = {"begin": 0.0, "end": 60.0, "nVehContrib": 0, "flow": 0.0, "occupancy": 0.0, "speed": -1.0,
                "harmonicMeanSpeed": -1.0}  # an interval without a vehicle, as SUMO writes it
    assert rs.DETECTOR_INTERVAL.problem(interval) is None


def test_a_writer_leaves_blanks_a_reader_refuses_them(tmp_path: Path) -> None:
    """A writer's table may leave a value it did not measure blank (a failed baseline, a MOBIL cell's alpha); the
    numbers it holds are checked before it is written. A reader that copies every value (history) refuses a blank."""
    import pandas as pd

    row = {"key": "L2_T4_a0_s1", "lanes": 2, "t_up_s": 4.0, "load": 0.25, "policy": "dqn", "alpha": 0.0,
           "p": math.nan, "eval_seed": 2001, "mean_speed_mps": 22.1, "lane_changes_per_vehicle": 1.6,
           "throughput_veh_per_h": 808.0, "mean_travel_time_s": 90.2, "collisions": 0, "teleports": 0,
           "loop_flow_veh_h_per_lane": 427.8, "loop_occupancy_pct": 2.2, "wall_seconds": 2.8}  # fmt: skip
    frame = pd.DataFrame([row, {**row, "eval_seed": 2002, "lane_changes_per_vehicle": None}])
    st.SCENARIO2_EVALS.check_frame(frame, tmp_path / "evals.csv")  # the blank is not a number outside its limits
    assert st.SCENARIO2_EVALS.frame_problem(frame.iloc[:1]) is None
    problem = st.SCENARIO2_EVALS.frame_problem(frame)
    assert problem is not None and problem.startswith("row 2 column lane_changes_per_vehicle must be a finite"), problem
    for column, value in (("mean_speed_mps", 71.0), ("loop_flow_veh_h_per_lane", 3601.0), ("lanes", 7),
                          ("loop_occupancy_pct", 101.0), ("teleports", -1), ("alpha", 1001.0), ("p", 11.0),
                          ("throughput_veh_per_h", 6 * 3600.0 + 1), ("t_up_s", 0.0), ("eval_seed", 1.5)):
        with pytest.raises(rs.RecordError, match=rf"^{tmp_path}/evals.csv row 1 column {column} must be"):
            st.SCENARIO2_EVALS.check_frame(pd.DataFrame([{**row, column: value}]), tmp_path / "evals.csv")
    assert not (tmp_path / "evals.csv").exists()
    failed = {k: row[k] for k in ("key", "lanes", "t_up_s", "load", "policy", "alpha", "p")} | {"status": "failed"}
    assert st.SCENARIO2_RUNS.frame_problem(pd.DataFrame([failed])) is None  # a failed cell's numbers: none
    assert st.SCENARIO2_RUNS.frame_problem(pd.DataFrame([failed, {**failed, "status": "ok"}])) == \
        "row 2 (status ok) has no column mean_speed_mps"  # an ok row needs its numbers (the columns of its case)
    assert st.SCENARIO2_EVALS.frame_problem(pd.DataFrame()) is None  # a study whose cells all failed
    assert st.SCENARIO2_EVALS.frame_problem(pd.DataFrame([row, row])) == \
        "rows 1 and 2 are both the row of key 'L2_T4_a0_s1', eval_seed 2001"  # one row per cell and evaluation seed


# -- a training checkpoint ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def checkpoint_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A training folder of the default learner (Adam) interrupted at step 20, its optimizer holding Adam's moments
    for every parameter (as after its first updates)."""
    out = tmp_path_factory.mktemp("ckpt") / "run"
    dqn = dataclasses.replace(DQN_PRESETS["default"], replay_size=500, batch_size=8, select_every_steps=0)
    cfg = TrainConfig(sim=SimConfig(steps=40, seed=3, policy="dqn"), dqn=dqn, eval_steps=0, log_every_steps=10,
                      checkpoint_every_steps=20)  # fmt: skip
    state = torch.load(interrupted_at_step_20(cfg, out), weights_only=True)
    step = torch.tensor(float(state["learner"]["updates"]))  # Adam counts the updates made (checkpoint_bounds)
    state["learner"]["optimizer"]["state"] = {
        i: {"step": step.clone(), "exp_avg": torch.full_like(w, 0.01), "exp_avg_sq": torch.full_like(w, 1e-4)}
        for i, w in enumerate(state["learner"]["online"].values())}  # fmt: skip
    torch.save(state, out / "checkpoint.pt")
    (out / "step20.pt").unlink()
    return out


def _set(*keys: Any, value: Any) -> Callable[[dict[str, Any]], None]:
    """Set state[k1]...[kn] = value; a tensor value is written into the tensor there (its first entries)."""

    def change(state: dict[str, Any]) -> None:
        d: Any = state
        for k in keys[:-1]:
            d = d[k]
        if isinstance(d[keys[-1]], torch.Tensor) and not isinstance(value, torch.Tensor):
            d[keys[-1]] = d[keys[-1]].clone()
            d[keys[-1]].view(-1)[0] = value
        else:
            d[keys[-1]] = value

    return change


def _done_half_beside_a_one(state: dict[str, Any]) -> None:
    dones = state["learner"]["buffer"]["data"]["dones"] = state["learner"]["buffer"]["data"]["dones"].clone()
    dones[:2] = torch.tensor([0.5, 1.0])


def _adam_emptied(state: dict[str, Any]) -> None:
    state["learner"]["optimizer"]["state"] = {}
    state["learner"]["updates"] = 2  # two updates made, within the decision rounds of 20 steps


def _adam_one_gone(state: dict[str, Any]) -> None:
    del state["learner"]["optimizer"]["state"][4]
    state["learner"]["updates"] = 2


def _speeds_without_steps(state: dict[str, Any]) -> None:
    state["window"].update(vehicle_steps=0, speed_sum=max(float(state["window"]["speed_sum"]), 100.0))


def _int_bias(state: dict[str, Any]) -> None:
    online = state["learner"]["online"]
    online["out.bias"] = online["out.bias"].to(torch.int64)


def _no_next_action(state: dict[str, Any]) -> None:
    mask = state["learner"]["buffer"]["data"]["next_mask"] = state["learner"]["buffer"]["data"]["next_mask"].clone()
    mask[0] = False
    state["learner"]["buffer"].update(size=1, pos=1)  # the fixture's memory is still empty: its first row is stored


def _as_floats(name: str, value: float) -> Callable[[dict[str, Any]], None]:
    """The replay field `name` stored as float64, its first entries `value` (the memory stores whole numbers)."""

    def change(state: dict[str, Any]) -> None:
        data = state["learner"]["buffer"]["data"]
        data[name] = data[name].double()
        data[name].view(-1)[:5] = value

    return change


GROUP = ("learner", "optimizer", "param_groups", 0)
ADAM = ("learner", "optimizer", "state", 0)
REPLAY = ("learner", "buffer", "data")
CASES: dict[str, tuple[Callable[[dict[str, Any]], None], str]] = {
    # the probe's (2026-12-01): each resumed with rc 0, the first two writing a model of NaN weights
    "learning rate 1e30": (_set(*GROUP, "lr", value=1e30), "field learner.optimizer.param_groups.0.lr must be a "
                           "finite number > 0 and <= 1 (a learning rate), got 1e+30"),
    "learning rate -1": (_set(*GROUP, "lr", value=-1.0), "field learner.optimizer.param_groups.0.lr must be"),
    "learning rate 0": (_set(*GROUP, "lr", value=0.0), "field learner.optimizer.param_groups.0.lr must be"),
    "Adam's second moment -1": (_set(*ADAM, "exp_avg_sq", value=-1.0),
                                "field learner.optimizer.state.0.exp_avg_sq must be a finite number >= 0"),
    "online weights 1e30": (_set("learner", "online", "conv1.weight", value=1e30),
                            "field learner.online.conv1.weight must be a finite number > -1e+06 and < 1e+06"),
    "stored rewards 3e38": (_set(*REPLAY, "rewards", value=3e38),
                            "field learner.buffer.data.rewards must be a finite number > -1e+06 and < 1e+06 (a "
                            "reward), got 3.0"),
    "Adam's betas (5, 0.999)": (_set(*GROUP, "betas", value=(5.0, 0.999)),
                                "field learner.optimizer.param_groups.0.betas.0 must be"),
    "a moment of another shape": (_set(*ADAM, "exp_avg", value=torch.zeros(3)), "field 0.exp_avg of another shape"),
    "Adam's step -5": (_set(*ADAM, "step", value=torch.tensor(-5.0)), "field learner.optimizer.state.0.step must be"),
    "a replay done of 7": (_set(*REPLAY, "dones", value=7.0), "field learner.buffer.data.dones must be an integer"),
    "optimizer parameters [999]": (_set(*GROUP, "params", value=[999]), "optimizer parameters [999]"),
    # the other limits of record_schemas.CHECKPOINT_TENSORS
    "Adam's first moment 1e9": (_set(*ADAM, "exp_avg", value=1e9), "field learner.optimizer.state.0.exp_avg must"),
    "Adam's second moment 1e13": (_set(*ADAM, "exp_avg_sq", value=1e13), "state.0.exp_avg_sq must"),
    "Adam's step 2.5": (_set(*ADAM, "step", value=torch.tensor(2.5)), "state.0.step must be an integer"),
    "Adam's eps -1": (_set(*GROUP, "eps", value=-1.0), "param_groups.0.eps must"),
    "Adam's second beta 1": (_set(*GROUP, "betas", value=(0.9, 1.0)), "param_groups.0.betas.1 must"),
    "weight decay 2": (_set(*GROUP, "weight_decay", value=2.0), "param_groups.0.weight_decay must"),
    "target weights -1e7": (_set("learner", "target", "fc1.bias", value=-1e7), "field learner.target.fc1.bias"),
    "a stored feature 1e7": (_set(*REPLAY, "features", value=1e7), "field learner.buffer.data.features must"),
    "a next feature -1e7": (_set(*REPLAY, "next_features", value=-1e7), "field learner.buffer.data.next_features"),
    "a replay done of -1": (_set(*REPLAY, "dones", value=-1.0), "field learner.buffer.data.dones must"),
    "a replay done of 0.5 beside a 1": (_done_half_beside_a_one, "field learner.buffer.data.dones must be an integer, "
                                        "got 0.5"),  # the smallest and largest dones were checked, not those between
    "two parameter groups": (lambda s: s["learner"]["optimizer"]["param_groups"].append({}), "one parameter group"),
    # the probe's (2026-12-02): the first resumed with an infinite loss, the others with a log of negative counts
    "a replay row whose next state allows no action": (_no_next_action, "next_mask all false"),
    "a log window of -3 samples": (_set("window", "samples", value=-3), "field window.samples must be"),
    "a log window loss of -1": (_set("window", "loss", value=[0.5, -1.0]), "field window.loss.1 must be"),
    "a log window of another version": (lambda s: s["window"].update(episodes=2), "has a log window with"),
    # the probe's (2026-12-02, second): each resumed with rc 0 (a traceback for the increment)
    "numpy's increment -5": (lambda s: s["learner"]["numpy_rng"]["state"].update(inc=-5), "128-bit whole number"),
    "numpy's has_uint32 7": (lambda s: s["learner"]["numpy_rng"].update(has_uint32=7), "buffered value"),
    "Adam's state emptied after 2 updates": (_adam_emptied, "has no Adam state for parameter 0 after 2 gradient"),
    "Adam's state of one parameter gone": (_adam_one_gone, "has no Adam state for parameter 4 after 2 gradient"),
    "a log window's speeds summing to 1e300": (_set("window", "speed_sum", value=1e300), "whose speeds sum to 1e+300"),
    "a log window's flow reward 1e300": (_set("window", "r_flow", value=1e300), "whose r_flow sums to 1e+300"),
    "a log window of speeds over no vehicle step": (_speeds_without_steps, "m/s over 0 vehicle steps"),
    # issue 82, probe 8, J13: resumed into a log row of 50,187 lane changes for 118 vehicles in 1,000 steps
    "a log window of more lane changes than vehicle steps": (_set("window", "lane_changes", value=50000),
                                                             "has a log window of 50000 lane changes over 0 vehicle"),
    "a log window of more refusals than vehicle steps": (_set("window", "rejected", value=40000),
                                                         "has a log window of 40000 rejected over 0 vehicle steps"),
    "replay grids of 255": (_set(*REPLAY, "grids", value=255), "occupancy grids outside 0-1 in its replay memory"),
    "replay next grids of 200": (_set(*REPLAY, "next_grids", value=200), "outside 0-1 in its replay memory (next_"),
    "integer online weights": (_int_bias, "has online weights 'out.bias' a torch.int64 tensor, not a tensor of floats"),
    "a negative action count": (_set("action_counts", value=-5), "records a negative number of actions at step 0"),
    # the probe's (2026-12-02, third): a learning rate of another type ended the learner process (rc 1, a --resume
    # that failed again); the other settings of the group were taken as they were
    "a learning rate '0.001'": (_set(*GROUP, "lr", value="0.001"), "optimizer setting lr = '0.001', not 0.001"),
    "a learning rate True": (_set(*GROUP, "lr", value=True), "optimizer setting lr = True"),
    "a learning rate None": (_set(*GROUP, "lr", value=None), "optimizer setting lr = None"),
    "a learning rate not the configuration's": (_set(*GROUP, "lr", value=0.5), "lr = 0.5, not 0.001"),
    "Adam's eps '1e-8'": (_set(*GROUP, "eps", value="1e-8"), "optimizer setting eps = '1e-8'"),
    "Adam's betas as text": (_set(*GROUP, "betas", value=("0.9", "0.999")), "optimizer setting betas"),
    "amsgrad 'no'": (_set(*GROUP, "amsgrad", value="no"), "optimizer setting amsgrad = 'no', not False"),
    "maximize True": (_set(*GROUP, "maximize", value=True), "optimizer setting maximize = True, not False"),
    "foreach 'x'": (_set(*GROUP, "foreach", value="x"), "optimizer setting foreach = 'x', not None"),
    "an optimizer setting torch does not have": (lambda s: s["learner"]["optimizer"]["param_groups"][0].update(
        momentum2=0.5), "optimizer setting momentum2 = 0.5, not none"),
    # issue 82, probe 13: each inside its field's limits but impossible, resumed with rc 0 (F3: into a model of
    # weights 8e11 every reader refuses; F4: into a train_log.csv row of loss 6e299; F5: the action 1.5 taken as 1)
    "Adam's first moment 9e5 beside a second of 1e-4": (_set(*ADAM, "exp_avg", value=9e5),
                                                         "field learner.optimizer.state.0.exp_avg is 900000 beside an "
                                                         "exp_avg_sq of 0.0001: Adam's first moment is at most 7.28"),
    "a log window loss of 1e300": (_set("window", "loss", value=[1e300]),
                                   "field window.loss.0 must be a finite number >= 0 and <= 1e+12"),
    "a log window of 1e14 vehicle steps": (lambda s: s["window"].update(vehicle_steps=10**14, samples=10**14),
                                           "has a log window of 100000000000000 vehicle steps in 0 steps"),
    # (issue 82, probe 16, T1: a replay field is refused for its dtype first, before its values are read)
    "replay actions of 1.5 stored as floats": (_as_floats("actions", 1.5),
                                               "has replay actions a torch.float64 tensor, not a tensor of integers"),
    "replay grids of 0.5 stored as floats": (_as_floats("grids", 0.5),
                                             "has replay grids a torch.float64 tensor, not a tensor of integers"),
}  # fmt: skip


def snapshot(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*"))}  # fmt: skip


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_checkpoint_outside_its_limits_is_one_line_and_every_byte_is_kept(
    case: str, checkpoint_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    change, fragment = CASES[case]
    out = tmp_path / "run"
    shutil.copytree(checkpoint_folder, out)
    state = copy.deepcopy(torch.load(out / "checkpoint.pt", weights_only=True))
    change(state)
    torch.save(state, out / "checkpoint.pt")
    before = snapshot(tmp_path)
    code = train.main(["--resume", "--quiet", "--out", str(out)])
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith(f"train: error: checkpoint {out / 'checkpoint.pt'} "), lines[0]
    assert fragment in lines[0] and lines[0].endswith("; train again without --resume"), (fragment, lines[0])
    assert snapshot(tmp_path) == before


def test_the_window_keys_a_checkpoint_must_hold_are_the_logs() -> None:
    assert WINDOW_KEYS == tuple(f.name for f in dataclasses.fields(Window))


def test_the_checkpoint_inside_its_limits_resumes(checkpoint_folder: Path, tmp_path: Path) -> None:
    """The cases above fail for what was spoiled: the checkpoint they start from (Adam's moments included) resumes."""
    out = tmp_path / "run"
    shutil.copytree(checkpoint_folder, out)
    assert checkpoint_problem(torch.load(out / "checkpoint.pt", weights_only=True)) is None
    assert train.main(["--resume", "--quiet", "--out", str(out)]) == 0
    assert finished_run(out, "train") and (out / "model.pt").is_file()


def test_a_model_outside_its_limits_is_never_written(tmp_path: Path) -> None:
    """Issue 82, probe 13, F3: train wrote a model.pt of weights 8e11, marked its folder finished and exited 0; every
    reader then refused it. save_model checks what load_model checks, and writes nothing outside it."""
    from coopsumo.agents.dqn import QNetwork
    from coopsumo.agents.model_file import load_model, save_model

    net = QNetwork(30.0)
    save_model(tmp_path / "model.pt", net, {"config": {}})
    assert load_model(tmp_path / "model.pt")[0] is not None
    with torch.no_grad():
        next(iter(net.parameters())).fill_(-8.1e11)
    with pytest.raises(UsageError, match=r"model2.pt is not written: its weights are no model's \(field state_dict\."):
        save_model(tmp_path / "model2.pt", net, {"config": {}})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.pt"]
