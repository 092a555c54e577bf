"""`coopsumo train --tensorboard`: the event files hold every scalar of train_log.csv at its step (read back with
TensorBoard's own event reader); without the package the flag is a one-line usage error."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from coopsumo.agents import tb_log
from coopsumo.agents.train import LOG_FIELDS
from coopsumo.agents.train_cli import build_parser

ROOT = Path(__file__).resolve().parent.parent


def test_every_scalar_is_a_column_of_the_csv_log() -> None:
    assert set(tb_log.SCALARS) <= set(LOG_FIELDS)
    assert {"td_loss", "r_speed", "r_lane_change", "r_flow", "epsilon", "mean_speed_mps", "lane_changes"} <= set(
        tb_log.SCALARS
    )


def test_without_tensorboard_the_flag_is_a_usage_error(monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    monkeypatch.setattr(tb_log, "available", lambda: False)
    with pytest.raises(SystemExit) as stop:
        build_parser().parse_args(["--tensorboard"])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install 'coopsumo[tensorboard]'" in err[0]


def test_flag_off_by_default() -> None:
    assert build_parser().parse_args([]).tensorboard is False


@pytest.mark.sumo
def test_train_writes_the_csv_scalars_to_tensorboard(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "coopsumo", "train", "--steps", "1500", "--eval-steps", "0", "--seed", "3",
           "--tensorboard", "--quiet", "--out", str(out)]  # fmt: skip
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600, check=False)
    assert res.returncode == 0, res.stderr[-2000:]
    rows = list(csv.DictReader((out / "train_log.csv").open()))
    assert [int(r["step"]) for r in rows] == [1000, 1500]  # a row every 1,000 steps and at the end
    events = list((out / tb_log.TB_DIR).glob("events.out.tfevents.*"))
    assert len(events) == 1
    acc = EventAccumulator(str(out / tb_log.TB_DIR))
    acc.Reload()
    assert set(acc.Tags()["scalars"]) == set(tb_log.SCALARS.values())
    for column, tag in tb_log.SCALARS.items():
        points = acc.Scalars(tag)
        expected = [(int(r["step"]), float(r[column])) for r in rows if r[column] != ""]
        assert [p.step for p in points] == [s for s, _ in expected], tag
        assert [p.value for p in points] == pytest.approx([v for _, v in expected], rel=1e-5, abs=1e-7), tag
    # the command (its main, in this process) refuses to train afresh over a finished training, its event file
    # untouched
    from coopsumo.agents.train_cli import main

    before = events[0].read_bytes()
    capsys.readouterr()
    argv = cmd[cmd.index("train") + 1:]
    code = main([*argv[: argv.index("1500")], "1000", *argv[argv.index("1500") + 1:]])
    err = capsys.readouterr().err
    assert code == 2 and "finished training" in err and len(err.strip().splitlines()) == 1, err
    assert list((out / tb_log.TB_DIR).glob("events.out.tfevents.*")) == events and events[0].read_bytes() == before
    # a study's fresh (shorter) training into the same folder (train() itself, as the model store retrains a damaged
    # model) replaces the event files instead of mixing two runs
    from coopsumo.agents.train import train
    from coopsumo.config import SimConfig, TrainConfig

    train(TrainConfig(sim=SimConfig(steps=500, seed=3, policy="dqn"), eval_steps=0), out, progress=False,
          tensorboard=True)  # fmt: skip
    assert len(list((out / tb_log.TB_DIR).glob("events.out.tfevents.*"))) == 1
    acc = EventAccumulator(str(out / tb_log.TB_DIR))
    acc.Reload()
    assert [p.step for p in acc.Scalars(tb_log.SCALARS["td_loss"])] == [500]  # the new run's points alone
