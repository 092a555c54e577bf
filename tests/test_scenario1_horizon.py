"""Scenario I at the paper's horizon: the recovery step and the waves on one lane, on known cases (no SUMO)."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from coopsumo.studies.scenario1 import horizon as hz
from coopsumo.studies.scenario1.measures import FIELD_DT_S, FIELD_DX_M


def test_the_recovery_step_counts_from_the_accident_start() -> None:
    assert hz.recovery_step(5400.0, 20_000, 0.1) == 74_000  # the paper's alpha 8 reading
    assert math.isnan(hz.recovery_step(math.nan, 20_000, 0.1))


def _field_samples(field: np.ndarray, lane: int) -> pd.DataFrame:
    """One sample per cell centre of a (time, position) speed field, on one lane."""
    t, x = np.meshgrid(np.arange(field.shape[0]), np.arange(field.shape[1]), indexing="ij")
    return pd.DataFrame({"time_s": (t.ravel() + 0.5) * FIELD_DT_S, "pos_m": (x.ravel() + 0.5) * FIELD_DX_M,
                         "speed_mps": field.ravel(), "lane": lane, "vid": np.arange(field.size)})  # fmt: skip


def test_waves_are_counted_on_their_own_lane_only() -> None:
    n_t, n_x = 200, 52
    wave = np.full((n_t, n_x), 22.0)
    for t0 in (10, 80):  # two stripes of standing traffic whose front moves upstream at 15 km/h
        for i in range(t0, n_t):
            j = int(round(50 - 15 / 3.6 * (i - t0) * FIELD_DT_S / FIELD_DX_M))
            if j - 3 < 0:
                break
            wave[i, j - 3 : j + 1] = 1.0
    traj = pd.concat([_field_samples(wave, 0), _field_samples(np.full((n_t, n_x), 22.0), 1)])
    x_to, t_to = n_x * FIELD_DX_M, n_t * FIELD_DT_S
    assert hz.lane_waves(traj, 0, x_to, t_to) == 2.0
    assert hz.lane_waves(traj, 1, x_to, t_to) == 0.0
    assert hz.lane_waves(traj, 2, x_to, t_to) == 0.0  # no vehicle there


def _rows() -> pd.DataFrame:
    rows = [
        # a model that recovers on both seeds, one on one seed of two (never counted as later than any: its median
        # is never), one that never does; keep recovers once
        ("dqn_alpha8", 100, 1, 5000.0), ("dqn_alpha8", 100, 2, 5200.0),
        ("dqn_alpha8", 101, 1, 6000.0), ("dqn_alpha8", 101, 2, math.nan),
        ("dqn_alpha0", 100, 1, math.nan), ("dqn_alpha0", 100, 2, math.nan),
        ("keep", None, 1, 6800.0), ("keep", None, 2, math.nan),
    ]  # fmt: skip
    frame = pd.DataFrame(rows, columns=["policy", "train_seed", "seed", "recovery_time_s"]).assign(t_up_s=3.0)
    frame["train_seed"] = frame["train_seed"].astype("Int64")
    return frame


def test_the_recovery_table_gives_each_model_and_the_paper() -> None:
    text = hz.recovery_table(_rows(), 3.0, 20_000, 0.1)
    line = {row.split("|")[1].strip(): row for row in text.splitlines()[2:]}
    assert "m100: 71,000" in line["`dqn_alpha8`"] and "m101: never" in line["`dqn_alpha8`"]
    assert "1 of 2" in line["`dqn_alpha8`"] and "71,000 [71,000, 71,000]" in line["`dqn_alpha8`"]
    assert line["`dqn_alpha8`"].rstrip(" |").endswith("about 74,000")
    assert "m100: never" in line["`dqn_alpha0`"] and "0 of 1" in line["`dqn_alpha0`"]
    assert line["`dqn_alpha0`"].rstrip(" |").endswith("never")
    assert "s1: 88,000, s2: never" in line["`keep`"] and "1 of 2" in line["`keep`"]


def test_the_calm_and_the_thrashing_model_are_read_from_queue_lane_changes_at_their_demand() -> None:
    rows = pd.DataFrame({"policy": ["dqn_alpha0"] * 4 + ["dqn_alpha8"] * 2 + ["keep"] * 2,
                         "train_seed": [100, 100, 101, 101, 100, 100, None, None],
                         "t_up_s": [1.0, 1.0, 1.0, 2.0, 1.0, 1.0, 1.0, 1.0],
                         "queue_lane_changes_per_vehicle": [3.0, 5.0, 0.5, 9.0, 0.2, 0.4, 0.0, 0.0]})  # fmt: skip
    rows["train_seed"] = rows["train_seed"].astype("Int64")
    (calm, thrashing) = hz.calm_and_thrashing(rows, 1.0)  # means over each model's runs at T_up 1 s only
    assert calm[:2] == ("dqn_alpha8", 100) and calm[2] == pytest.approx(0.3) and thrashing == ("dqn_alpha0", 100, 4.0)
    assert hz.calm_and_thrashing(rows, 2.0) == [("dqn_alpha0", 101, 9.0)]  # one model: one entry
    assert hz.calm_and_thrashing(rows, 3.0) == []


def test_alpha_of_a_label() -> None:
    assert hz._alpha_of("dqn_alpha8") == 8.0 and hz._alpha_of("dqn_alpha_only_alpha0.25") == 0.25
    assert hz._alpha_of("keep") is None and hz._alpha_of("mobil_p0.5") is None


@pytest.mark.sumo
def test_the_recovery_measure_on_a_run_that_recovers_and_one_that_does_not(tmp_path: Path) -> None:
    """`keep` in SUMO: a light demand through a short accident recovers; a heavy one whose accident holds to the
    end of the run never does. The measure the horizon table reads must tell them apart."""
    from coopsumo.config import AccidentConfig
    from coopsumo.report.analysis import recovery_time_s

    found = {}
    for name, t_up, steps, length in (("recovers", 4.0, 6000, 1500), ("never", 1.0, 4000, 3000)):
        out = tmp_path / name
        cmd = [sys.executable, "-m", "coopsumo", "simulate", "--scenario", "accident", "--policy", "keep",
               "--t-up", str(t_up), "--steps", str(steps), "--accident-start", "1000", "--accident-steps",
               str(length), "--seed", "1", "--trajectories", "--out", str(out)]  # fmt: skip
        res = subprocess.run(cmd, capture_output=True, text=True, check=False)
        assert res.returncode == 0, res.stderr[-1500:]
        traj = pd.read_parquet(out / "trajectories.parquet")
        found[name] = hz.recovery_step(recovery_time_s(traj, AccidentConfig().x_m, 100.0, threshold_mps=15.0), 1000,
                                       0.1)  # fmt: skip
    assert 1000 < found["recovers"] < 6000  # after the accident started (step 1,000), before the run ended
    assert math.isnan(found["never"])
