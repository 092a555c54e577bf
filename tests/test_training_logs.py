"""Issue 82, fifth probe, G6 and G8: the learning study (retired since) drew each training's train_log.csv and the
protocol study read each training's validation.csv unchecked (a byte that is not UTF-8, a renamed column or no best
snapshot: a traceback; a speed of 999 m/s drawn, a score of 1e9 copied into diagnosis.csv). Both logs are now checked
by their columns' rules (agents/training_logs.py): a stored model whose log breaks them is not a finished training
(trainings.finished_training: trained again with one line naming the file and the field; `coopsumo models` lists it
not usable), a study's reused cell of such a training is run again (trainings.spoiled_logs), and the figures read
them through the same check (a RecordError naming the file and the field, never a traceback)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pandas as pd
import pytest
from test_models_command import TRAINED, _stored_then_spoiled

from coopsumo.agents.tb_log import LOG_FIELDS
from coopsumo.agents.training_logs import log_problem, validation_problem
from coopsumo.config import SimConfig, TrainConfig, to_dict
from coopsumo.record_schemas import RecordError

ROW = {"sim_time_s": 10.0, "td_loss": 0.5, "r_speed": -0.16, "r_lane_change": 0, "r_flow": 0.035, "reward": -0.13,
       "epsilon": 0.1, "mean_speed_mps": 20.0, "vehicles": 26, "lane_changes": 4, "lane_changes_rejected": 15,
       "collisions": 0, "teleports": 0, "wall_s": 0.75, "alpha": 0}  # fmt: skip


def train_log(steps: tuple[int, ...] = (100, 200, 300)) -> list[str]:
    """A finished training's train_log.csv as train writes it (csv's \\r\\n line ends), a row per logging window;
    three rows are the training of test_models_command.TRAINED (its lane changes, speed and collisions)."""
    rows = [",".join(LOG_FIELDS)] + [",".join(str({**ROW, "step": s}[f]) for f in LOG_FIELDS) for s in steps]
    return [row + "\r\n" for row in rows]


VALIDATION = ["step,score,best,stage,screen_score,screen_mean_speed_mps,screen_lane_changes_per_vehicle,"
              "screen_share_none,mean_speed_mps,lane_changes_per_vehicle,share_left,share_right,share_speedup,"
              "share_none,change_offered_share,q_gap_median,near_tie_share,change_chosen_share,mean_speed_mps_t1,"
              "lane_changes_per_vehicle_t1,mean_reward_t1,mean_speed_mps_t4,lane_changes_per_vehicle_t4,"
              "mean_reward_t4\n",
              "100,0.316337,False,screen,0.316337,12.9972,0.292857,0.734398,12.9972,0.292857,0.00138117,0.00125269,"
              "0.262969,0.734398,0.187711,-2.78667,0.0691307,0.0140315,12.9972,0.292857,0.316337,,,\n",
              "200,0.302062,False,all,0.444124,14.2626,0.0738255,0.0946649,18.1813,1.22191,0.00047019,0.000219422,"
              "0.904645,0.0946649,0.137578,-1.69688,0.110959,0.00501253,14.2626,0.0738255,0.444124,22.1,2.37,0.16\n",
              "300,0.305742,True,all,0.449483,14.3683,0.148649,0.0495412,18.2492,1.25932,0.00454396,0.00529673,"
              "0.940395,0.0497646,0.249192,-3.61553,0.233866,0.0394903,14.3683,0.148649,0.449483,22.13,2.37,0.162\n"]
"""a two-stage selection's validation.csv (as a committed store holds them): the snapshot of step 300 chosen; each
row's score, speed and lane changes the mean of its runs' (issue 82, probe 14, F10)"""


def _cell(row: int, name: str, value: str) -> Callable[[list[str]], list[str]]:
    """An edit of a CSV's lines: row `row`'s (1: the first after the header) cell of column `name` set to value."""

    def change(lines: list[str]) -> list[str]:
        header, cells = lines[0].rstrip("\r\n").split(","), lines[row].rstrip("\r\n").split(",")
        cells[header.index(name)] = value
        return [*lines[:row], ",".join(cells) + "\n", *lines[row + 1:]]

    return change


LOG_CASES: dict[str, tuple[Callable[[list[str]], list[str]], str]] = {
    # the probe's r_learn_trainlog_xff, _nostep, _999, _empty
    "a byte not UTF-8": (lambda lines: [*lines, "\xff\xfe,1\n"], "is not a text file (not UTF-8: byte 0xff at "),
    "step renamed": (lambda lines: [lines[0].replace("step,", "stp,", 1), *lines[1:]], "has the header 'stp,sim_"),
    "a speed of 999 m/s": (_cell(1, "mean_speed_mps", "999"), "has mean_speed_mps = '999' in its row of step 100: it "
                           "must be a finite number >= 0 and <= 70 (m/s)"),
    "emptied": (lambda lines: [], "has the header 'none (an empty file)'"),
    # what only a finished training's whole log may not hold (a resume drops them)
    "a row past its steps": (lambda lines: [*lines, lines[-1].replace("300,", "400,", 1)],
                             "has a row of step 400, past its training's 300 steps"),
    "a last row cut short": (lambda lines: [*lines, "400,3"], "has a row that is not one of its rows after that of "
                             "step 300: '400,3'"),
}  # fmt: skip


def _write(path: Path, lines: list[str]) -> Path:
    path.write_bytes("".join(lines).encode("latin-1"))  # "\xff": the byte 0xff
    return path


@pytest.mark.parametrize("case", sorted(LOG_CASES))
def test_a_finished_trainings_log_is_checked_whole(case: str, tmp_path: Path) -> None:
    change, fragment = LOG_CASES[case]
    log = _write(tmp_path / "train_log.csv", train_log())
    assert log_problem(log, 300, whole=True) is None
    _write(log, change(train_log()))
    problem = log_problem(log, 300, whole=True)
    assert problem is not None and problem.startswith(fragment), problem
    if case in ("a row past its steps", "a last row cut short"):  # a resume from step 300 drops them: no problem
        assert log_problem(log, 300) is None


VALIDATION_CASES: dict[str, tuple[Callable[[list[str]], list[str]], str]] = {
    # the probe's r_proto_val_nobest, _xff, _nobesttrue, _score999
    "best renamed": (lambda lines: [lines[0].replace(",best,", ",bst,"), *lines[1:]], "has no column best (its "
                     "columns: step,score,bst,"),
    "a byte not UTF-8": (lambda lines: [*lines[:2], "\xff" + lines[2], *lines[3:]], "is not a text file (not UTF-8"),
    "no best": (lambda lines: [line.replace(",True,", ",False,") for line in lines], "has 0 rows marked best"),
    "a score of 1e9": (_cell(2, "score", "1e9"), "has score = '1e9' in its row of step 200: it must be a finite number "
                       ">= -1e+06 and <= 1e+06 (a mean reward)"),
    # the other rules
    "two best": (_cell(1, "best", "True"), "has 2 rows marked best (steps [100, 300]), not one"),
    "best 'yes'": (_cell(1, "best", "yes"), "has best = 'yes' in its row of step 100, not True or False"),
    "a validation run's speed of 999": (_cell(2, "mean_speed_mps_t4", "999"), "has mean_speed_mps_t4 = '999' in its "
                                        "row of step 200: it must be a finite number >= 0 and <= 70 (m/s)"),
    "a share of 2": (_cell(1, "share_none", "2"), "has share_none = '2' in its row of step 100: it must be"),
    "a blank score": (_cell(1, "score", ""), "has score = '' in its row of step 100, not a finite number"),
    "stage 'final'": (_cell(1, "stage", "final"), "has stage = 'final' in its row of step 100: it must be one of all"),
    "a row past its steps": (_cell(3, "step", "400"), "has a row of step 400, past its training's 300 steps"),
    "a row twice": (lambda lines: [*lines[:3], lines[2], lines[3]], "has the row of step 200 after that of step 200"),
    "a screening column gone": (lambda lines: [lines[0].replace("screen_share_none", "x"), *lines[1:]],
                                "has no column screen_share_none"),
    "a row cut short": (lambda lines: [*lines, "400,0.3\n"], "has a row that is not one of its rows after that of "
                        "step 300: '400,0.3'"),
    "emptied": (lambda lines: [], "has no column step (its columns: none, an empty file)"),
    "no row": (lambda lines: lines[:1], "has no row"),
    # a row that contradicts itself, each value inside its limits (issue 82, probe 14, F10)
    "a speed not its runs' mean": (_cell(3, "mean_speed_mps", "30.0"), "has mean_speed_mps = 30.0 in its row of step "
                                   "300, not the mean of its runs' mean_speed_mps_* (18.2492): edited?"),
    "a score not its runs' mean": (_cell(3, "score", "0.9"), "has score = 0.9 in its row of step 300, not the mean of "
                                   "its runs' mean_reward_* (0.305741)"),
    "lane changes not its runs' mean": (_cell(1, "lane_changes_per_vehicle", "5.0"), "has lane_changes_per_vehicle = "
                                        "5.0 in its row of step 100, not the mean of its runs'"),
    "shares summing to 1.5": (_cell(3, "share_none", "0.5497646"), "has action shares (share_left, share_right, "
                              "share_speedup, share_none) summing to 1.5 in its row of step 300, not 1"),
    "lane changes, none chosen": (lambda lines: _cell(1, "share_left", "0")(_cell(1, "share_right", "0")(
        _cell(1, "share_speedup", "0.265602")(lines))), "has lane_changes_per_vehicle = 0.292857 in its row of step "
        "100 beside share_left and share_right 0: no lane change was ever chosen"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(VALIDATION_CASES))
def test_a_validation_table_is_checked(case: str, tmp_path: Path) -> None:
    change, fragment = VALIDATION_CASES[case]
    path = _write(tmp_path / "validation.csv", VALIDATION)
    assert validation_problem(path, 300, 300) is None and validation_problem(tmp_path / "none.csv") is None
    _write(path, change(VALIDATION))
    problem = validation_problem(path, 300, 300)
    assert problem is not None and problem.startswith(fragment), problem


def test_the_best_snapshot_is_the_one_model_pt_holds(tmp_path: Path) -> None:
    path = _write(tmp_path / "validation.csv", VALIDATION)
    assert validation_problem(path, 300, 200) == ("marks the snapshot of step 300 best, but model.pt holds step 200 "
                                                  "(train_summary.json)")  # fmt: skip


CONFIG = to_dict(TrainConfig(sim=SimConfig(steps=300, seed=100, policy="dqn"), eval_steps=0))


def _speeds(value: str) -> Callable[[list[str]], list[str]]:
    """An edit of train_log()'s lines: every row's mean speed set to value."""
    return lambda lines: _cell(1, "mean_speed_mps", value)(_cell(2, "mean_speed_mps", value)(
        _cell(3, "mean_speed_mps", value)(lines)))  # fmt: skip


@pytest.mark.parametrize(("name", "lines", "change", "fragment"), [
    ("train_log.csv", train_log(), _cell(1, "mean_speed_mps", "999"), "has mean_speed_mps = '999' in its row of "
     "step 100: it must be a finite number >= 0 and <= 70 (m/s), got 999.0"),
    # issue 82, probe 8, J20: rows inside their columns' rules that disagree with the training's own summary
    ("train_log.csv", train_log(), _cell(3, "lane_changes", "5000"), "has lane_changes summing to 5008 over its rows "
     "of steps 1-300 (its training's last world), but train_summary.json says 12"),
    ("train_log.csv", train_log(), _speeds("69.9"), "has mean_speed_mps from 69.9 to 69.9 m/s in its rows, but "
     "train_summary.json says 20 m/s for the same steps"),
    ("train_log.csv", train_log(), _cell(3, "collisions", "3"), "has collisions = 3 in its row of step 300, but "
     "train_summary.json says collisions = 0"),
    ("train_log.csv", train_log(), _cell(3, "vehicles", "99"), "has vehicles = 99 in its row of step 300, but "
     "train_summary.json says departed = 40"),
    ("train_log.csv", train_log((100, 200)), lambda lines: lines, "ends with the row of step 200, not its "
     "training's last step 300"),
    ("validation.csv", VALIDATION, _cell(2, "score", "1e9"), "has score = '1e9' in its row of step 200: it must be"),
    ("validation.csv", VALIDATION, lambda lines: [line.replace(",True,", ",False,") for line in lines],
     "has 0 rows marked best"),
])  # fmt: skip
def test_a_stored_model_whose_log_breaks_its_rules_is_trained_again_and_listed_not_usable(
        name: str, lines: list[str], change: Callable[[list[str]], list[str]], fragment: str, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """finished_training asks what the studies read of a log: one line naming the file and the field; quiet (the
    listing, the study's first look): none. model.pt's loading is not judged here."""
    from coopsumo.studies.engine import store_listing, trainings

    monkeypatch.setattr(trainings, "model_folder_problem", lambda folder: None)
    store = tmp_path / "models"
    folder, _ = _stored_then_spoiled(CONFIG, store, "train_summary.json", json.dumps(TRAINED))  # selected step 300
    _write(folder / "train_log.csv", train_log())
    _write(folder / "validation.csv", VALIDATION)
    assert trainings.finished_training(folder, CONFIG) == TRAINED and capsys.readouterr().err == ""
    _write(folder / name, change(lines))
    assert trainings.finished_training(folder, CONFIG, quiet=True) is None and capsys.readouterr().err == ""
    assert trainings.finished_training(folder, CONFIG) is None
    assert capsys.readouterr().err.startswith(f"coopsumo: {folder / name} {fragment}")
    assert store_listing.main(["--store", str(store)]) == 0
    row = next(line for line in capsys.readouterr().out.splitlines() if line.startswith(folder.name))
    assert f"not usable: {name} {fragment}"[:100] in row, row


def test_a_reused_cells_training_whose_log_breaks_its_rules_is_run_again(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """trainings.spoiled_logs, asked by the protocol study of its reusable cells: every cell of the
    training (they share it) with one line naming the log, the field and the cells; a baseline cell is not looked at,
    a training without a folder yet neither."""
    from coopsumo.studies.engine.trainings import spoiled_logs

    folder = tmp_path / "train" / "t0"
    folder.mkdir(parents=True)
    _write(folder / "train_log.csv", train_log())
    specs = [{"key": "c1", "train_key": "t0", "config": {"train": CONFIG}},
             {"key": "c2", "train_key": "t0", "config": {"train": CONFIG}},
             {"key": "c3", "train_key": "t1", "config": {"train": CONFIG}},
             {"key": "b1", "train_key": None, "config": {"eval": {}}}]  # fmt: skip
    assert spoiled_logs(tmp_path, specs, "protocol") == set() and capsys.readouterr().err == ""
    _write(folder / "train_log.csv", _cell(2, "mean_speed_mps", "999")(train_log()))
    assert spoiled_logs(tmp_path, specs, "protocol") == {"c1", "c2"}
    assert capsys.readouterr().err == (f"protocol: {folder / 'train_log.csv'} has mean_speed_mps = '999' in its row of "
                                       "step 200: it must be a finite number >= 0 and <= 70 (m/s), got 999.0; "
                                       "rerunning the 2 cells of its training (c1, c2), which train it again\n")


def test_a_reused_cells_training_link_repointed_at_another_model_is_run_again(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """Probe 6, H4: a study's train/<training> link pointed at another training's store folder (or at a file) was
    followed, every cell reused, and the (since retired) learning study's figures and the protocol study's diagnosis
    drew the other training's logs. As scenario II does (model_store.link_problem), model_store.repointed_trainings,
    asked before trainings.spoiled_logs: the training's cells are run again, which links its model back, with one
    line naming the link; a link to its own model, a baseline cell and a training without a link yet are left alone.
    The store is the study's own, beside it (model_store.store_for: a link into another store is a copied study's,
    probe 13)."""
    from coopsumo.paths import STORE_ENV
    from coopsumo.studies.engine.model_store import model_id, repointed_trainings

    monkeypatch.delenv(STORE_ENV, raising=False)
    other = to_dict(TrainConfig(sim=SimConfig(steps=300, seed=101, policy="dqn"), eval_steps=0))
    root = tmp_path / "study"
    store, link = tmp_path / "models", root / "train" / "t0"
    for config in (CONFIG, other):
        (store / model_id(config)).mkdir(parents=True)
        (store / model_id(config) / "config.json").write_text(json.dumps({"config": config}))
        _write(store / model_id(config) / "train_log.csv", train_log())
    (tmp_path / "zero").write_bytes(b"")
    link.parent.mkdir(parents=True)
    specs = [{"key": "c1", "train_key": "t0", "config": {"train": CONFIG}},
             {"key": "c2", "train_key": "t0", "config": {"train": CONFIG}},
             {"key": "c3", "train_key": "t1", "config": {"train": CONFIG}},
             {"key": "b1", "train_key": None, "config": {"eval": {}}}]  # fmt: skip
    link.symlink_to(store / model_id(CONFIG), target_is_directory=True)
    assert repointed_trainings(root, specs, "protocol") == set() and capsys.readouterr().err == ""
    for target, why in ((store / model_id(other), f"not to {model_id(CONFIG)}, the model of its training (pointed "
                                                   "at another model?)"),
                        (tmp_path / "zero", "which is not a folder (the stored model moved or removed?)")):  # fmt: skip
        link.unlink()
        link.symlink_to(target)
        assert repointed_trainings(root, specs, "protocol") == {"c1", "c2"}
        assert capsys.readouterr().err == (f"protocol: {link} leads to {target}, {why}; rerunning the 2 cells of its "
                                           "training (c1, c2), which link its model back\n")  # fmt: skip


def test_the_protocol_studys_diagnosis_and_figure_read_validation_checked(tmp_path: Path) -> None:
    """The probe's G8 where no training is redone: a RecordError naming the file and the field, never a KeyError or
    IndexError traceback, nor a score of 1e9 copied into diagnosis.csv."""
    from coopsumo.studies.protocol.figures import validation_curves_figure
    from coopsumo.studies.protocol.report import diagnosis_table

    key = "a0_seed100_default_0123abcd"
    path = tmp_path / "train" / key / "validation.csv"
    path.parent.mkdir(parents=True)
    _write(path, VALIDATION)
    runs = pd.DataFrame([{"kind": "model", "alpha": 0.0, "seed": 100, "train_key": key}])
    table = diagnosis_table(tmp_path, runs)
    assert table[["selected_step", "best_score", "last_score"]].to_dict("records") == [
        {"selected_step": 300, "best_score": 0.305742, "last_score": 0.305742}]
    assert validation_curves_figure(tmp_path, [key], tmp_path / "fig.png") is not None
    for change, fragment in ((_cell(2, "score", "1e9"), "has score = '1e9'"), (VALIDATION_CASES["no best"][0],
                             "has 0 rows marked best"), (VALIDATION_CASES["best renamed"][0], "has no column best")):
        _write(path, change(VALIDATION))
        for read in (lambda: diagnosis_table(tmp_path, runs),
                     lambda: validation_curves_figure(tmp_path, [key], tmp_path / "fig.png")):
            with pytest.raises(RecordError, match=f"^{path} {fragment}"):
                read()


@pytest.mark.parametrize("digit", ["²", "٣", "①"])
def test_a_step_in_digits_other_than_ascii_is_a_row_that_is_not_one(digit: str, tmp_path: Path) -> None:
    """The probe's H6: str.isdigit() takes '²', which int() refuses (a traceback), and '٣', which int() reads as 3:
    a step in any digit but 0-9 is not one of the log's rows."""
    log, val = tmp_path / "train_log.csv", tmp_path / "validation.csv"
    log.write_text("".join(train_log()[:2] + [train_log()[2].replace("200,", f"{digit}00,", 1)] + train_log()[3:]),
                   encoding="utf-8")  # fmt: skip
    assert (log_problem(log, 300) or "").startswith(f"has a row that is not one of its rows after that of step 100: "
                                                     f"'{digit}00,")  # fmt: skip
    val.write_text("".join(VALIDATION[:2] + [f"{digit}" + VALIDATION[2][1:]] + VALIDATION[3:]), encoding="utf-8")
    assert (validation_problem(val, 300, 300) or "").startswith("has a row that is not one of its rows after that of "
                                                                "step 100")  # fmt: skip

