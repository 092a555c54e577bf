"""The scenario I measures (report.bottleneck) on hand-made series and fields with known answers; no SUMO."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from coopsumo.report import bottleneck as bn


def _traj(rows: list[tuple[float, int, float, float]]) -> pd.DataFrame:
    return pd.DataFrame(rows, columns=["time_s", "vid", "pos_m", "speed_mps"])


def test_counts_on_the_road_and_waiting_to_enter() -> None:
    # t_up 1 s: vehicles 0, 1, 2 due at 0, 1, 2 s; vehicle 1 enters only at 3 s, vehicle 2 never
    traj = _traj([(0.0, 0, 0.0, 10.0), (1.0, 0, 10.0, 10.0), (2.0, 0, 20.0, 10.0), (3.0, 0, 30.0, 10.0),
                  (3.0, 1, 0.0, 5.0)])  # fmt: skip
    counts = bn.occupancy_counts(traj, 1.0)
    assert counts["on_road"].tolist() == [1, 1, 1, 2]
    assert counts["waiting"].tolist() == [0, 1, 2, 2]  # due 1, 2, 3, 4; entered 1, 1, 1, 2


def test_total_time_spent_counts_waiting_and_delay_against_the_reference_speed() -> None:
    # 10 samples of 2 s: 3 vehicles on the road at 10 m/s each, 2 waiting
    on, wait, speed = np.full(10, 3), np.full(10, 2), np.full(10, 30.0)
    tts = bn.total_time_spent(on, wait, speed, 2.0, 20.0)
    assert tts["on_road_veh_h"] == pytest.approx(60 / 3600)
    assert tts["waiting_veh_h"] == pytest.approx(40 / 3600)
    assert tts["tts_veh_h"] == pytest.approx(100 / 3600)
    assert tts["distance_veh_km"] == pytest.approx(0.6)  # 3 vehicles x 10 m/s x 20 s
    assert tts["delay_veh_h"] == pytest.approx((100 - 600 / 20) / 3600)  # 30 s of driving at 20 m/s needed
    # a policy that keeps vehicles off the road does not look better: the same vehicles waiting cost the same
    kept_out = bn.total_time_spent(np.full(10, 1), np.full(10, 4), np.full(10, 10.0), 2.0, 20.0)
    assert kept_out["tts_veh_h"] == pytest.approx(tts["tts_veh_h"])
    assert kept_out["delay_veh_h"] > tts["delay_veh_h"]


def test_run_time_spent_from_a_trajectory_table() -> None:
    traj = _traj([(0.0, 0, 0.0, 20.0), (1.0, 0, 20.0, 20.0), (1.0, 1, 0.0, 10.0)])
    out = bn.run_time_spent(traj, 1.0, 1.0, 20.0)
    assert out["tts_veh_h"] == pytest.approx(3 / 3600)  # 1 + 2 vehicles on the road, nobody waiting
    assert out["distance_veh_km"] == pytest.approx(0.05)


def _loops(pos: float, flows: list[int], period: float = 60.0) -> pd.DataFrame:
    rows = []
    for lane in (0, 1):
        for k, n in enumerate(flows):
            rows.append({"id": f"e1_x{int(pos):05d}_l{lane}", "pos_m": pos, "lane": lane, "begin_s": k * period,
                         "end_s": (k + 1) * period, "n_veh": n, "flow_veh_h": n * 3600 / period,
                         "occupancy_pct": 0.0, "speed_mps": 10.0, "harmonic_speed_mps": 10.0})  # fmt: skip
    return pd.DataFrame(rows)


def test_discharge_is_the_flow_at_the_first_loop_downstream_while_the_accident_holds() -> None:
    det = pd.concat([_loops(1200.0, [30, 30, 30, 30]), _loops(1400.0, [10, 5, 7, 20]), _loops(1600.0, [0] * 4)])
    # intervals 1 and 2 (60-180 s) lie inside [60, 180]: (5 + 7) x 2 lanes in 120 s
    assert bn.discharge_veh_h(det, 1300.0, 60.0, 180.0) == pytest.approx(24 * 30)
    assert math.isnan(bn.discharge_veh_h(det, 1300.0, 70.0, 100.0))
    with pytest.raises(ValueError, match="no loop downstream"):
        bn.discharge_veh_h(det, 1700.0, 0.0, 240.0)


def test_system_recovery_waits_for_both_the_speed_and_the_entrance_queue() -> None:
    speed = pd.Series([20.0, 4.0, 10.0, 16.0, 18.0, np.nan, 17.0], index=np.arange(7) * 30.0)
    nobody = pd.Series(0.0, index=np.arange(0, 210, 5.0))
    assert bn.system_recovery_s(speed, nobody, 0.0, 15.0, 3) == 90.0  # the on-road recovery alone
    queue = nobody.copy()
    queue[queue.index <= 120] = 10.0  # vehicles wait up to 120 s
    assert bn.system_recovery_s(speed, queue, 0.0, 15.0, 3) == 180.0  # the first bin starting after 120 s
    always = nobody + 5.0
    assert math.isnan(bn.system_recovery_s(speed, always, 0.0, 15.0, 3))
    slow_end = pd.Series([20.0, 20.0, 4.0], index=[0.0, 30.0, 60.0])
    assert math.isnan(bn.system_recovery_s(slow_end, nobody, 0.0, 15.0, 3))
    assert bn.system_recovery_s(speed, nobody, 60.0, 15.0, 3) == 30.0  # counted from from_s


def test_the_queue_is_the_chain_of_slow_vehicles_from_the_bottleneck() -> None:
    times = np.array([1.0, 1.0, 1.0, 1.0, 2.0, 2.0, 3.0])
    pos = np.array([1290.0, 1220.0, 1150.0, 20.0, 1100.0, 1290.0, 900.0])
    tails = bn.queue_tail_m(times, pos, 1300.0, 100.0)
    # t = 1: 1290 -> 1220 -> 1150, then a 1130 m gap to a vehicle just inserted at the entrance
    # t = 2: 1290 -> 1100 is a 190 m gap; t = 3: nothing within 100 m of the bottleneck
    assert tails.to_dict() == {1.0: 1150.0, 2.0: 1290.0, 3.0: 1300.0}


def test_queue_reach_and_the_regime() -> None:
    traj = _traj([(10.0, 0, 1250.0, 0.0), (20.0, 1, 1220.0, 2.0), (20.0, 4, 1150.0, 1.0), (20.0, 2, 1100.0, 20.0),
                  (20.0, 5, 30.0, 1.0), (5.0, 3, 1260.0, 0.0)])  # fmt: skip
    idx = np.arange(0, 40, 10.0)
    on_road = bn.queue_reach(traj, pd.Series(0.0, index=idx), 1300.0, 10.0, 5.0, 3)
    # at 20 s: 1220 -> 1150 (1100 is not slow; 30 m is an inserted vehicle, not the queue); 5 s is before the start
    assert on_road == {"queue_m": 150.0, "spilled_s": pytest.approx(float("nan"), nan_ok=True),
                       "regime": bn.REGIMES[0]}  # fmt: skip
    clears = bn.queue_reach(traj, pd.Series([0.0, 0.0, 8.0, 0.0], index=idx), 1300.0, 10.0, 5.0, 3)
    assert clears["regime"] == bn.REGIMES[1] and clears["spilled_s"] == 10.0
    stays = bn.queue_reach(traj, pd.Series([0.0, 0.0, 8.0, 9.0], index=idx), 1300.0, 10.0, 5.0, 3)
    assert stays["regime"] == bn.REGIMES[2]


def test_speed_field_is_the_mean_of_the_samples_in_each_cell() -> None:
    traj = _traj([(0.0, 0, 5.0, 10.0), (1.0, 1, 6.0, 20.0), (2.0, 0, 15.0, 4.0), (9.9, 0, 19.9, 1.0)])
    field = bn.speed_field(traj, 0.0, 20.0, 0.0, 10.0, 5.0, 10.0)
    assert field.shape == (2, 2)
    assert field[0, 0] == 15.0 and field[0, 1] == 4.0 and field[1, 1] == 1.0 and math.isnan(field[1, 0])


def test_connected_regions_are_eight_connected() -> None:
    mask = np.array([[1, 0, 0, 1], [0, 1, 0, 1], [0, 0, 0, 0], [1, 1, 0, 0]], dtype=bool)
    labels = bn.connected_regions(mask)
    assert labels.max() == 3
    assert labels[0, 0] == labels[1, 1] and labels[0, 3] == labels[1, 3] and labels[3, 0] == labels[3, 1]


DT, DX = 5.0, 25.0


def _free(n_t: int = 200, n_x: int = 52) -> np.ndarray:
    return np.full((n_t, n_x), 22.0)


def _add_wave(field: np.ndarray, t0: int, x0: int, speed_kmh: float, width: int = 3) -> None:
    """A stripe of standing traffic whose front starts at cell x0 at time t0 and moves at speed_kmh."""
    for i in range(t0, field.shape[0]):
        front = x0 + speed_kmh / 3.6 * (i - t0) * DT / DX
        j = int(round(front))
        if j - width < 0:
            break
        field[i, max(j - width, 0) : j + 1] = 1.0


def test_waves_moving_upstream_are_counted_with_their_speed() -> None:
    field = _free()
    _add_wave(field, 10, 50, -15.0)
    _add_wave(field, 80, 50, -15.0)
    jams = bn.moving_jams(field, DT, DX)
    summary = bn.wave_summary(jams)
    assert summary["waves"] == 2 and summary["slow_regions"] == 2
    assert summary["wave_speed_kmh"] == pytest.approx(-15.0, abs=1.0)


def test_steady_congestion_and_free_flow_are_quiet() -> None:
    assert bn.wave_summary(bn.moving_jams(_free(), DT, DX)) == {"waves": 0.0, "wave_speed_kmh": pytest.approx(
        float("nan"), nan_ok=True), "slow_regions": 0.0}  # fmt: skip
    queue = _free()
    # a bottleneck queue at x = 1,300 m: grows upstream for 100 cells, then shrinks from its tail
    for i in range(20, 180):
        length = min(i - 20, 180 - i) // 3 + 1
        queue[i, 52 - length :] = 2.0
    jams = bn.moving_jams(queue, DT, DX)
    assert len(jams) == 1 and not jams[0].moving and jams[0].front_travel_m == 0.0
    assert bn.wave_summary(jams)["waves"] == 0
    # a wave upstream of the queue, apart from it, is still found (one touching the queue would merge with it)
    _add_wave(queue, 150, 25, -18.0)
    assert bn.wave_summary(bn.moving_jams(queue, DT, DX))["waves"] == 1


def test_short_or_barely_moving_slow_regions_are_not_waves() -> None:
    field = _free()
    field[50:52, 10:13] = 0.0  # 10 s
    field[60:100, 20] = 1.0  # 200 s standing still
    jams = bn.moving_jams(field, DT, DX)
    assert [j.moving for j in jams] == [False]
    assert jams[0].duration_s == 200.0


def test_lane_changes_in_a_queue_are_those_made_below_the_slow_speed() -> None:
    # vehicle 1 changes lane at speed 2 m/s (in a queue) then again at 20 m/s; vehicle 2 changes at 4.9 m/s;
    # vehicle 3 never changes; a new vehicle starting in another lane is not a change of the one before it
    traj = pd.DataFrame({
        "vid": [1, 1, 1, 1, 2, 2, 3, 3, 4],
        "time_s": [0.0, 0.5, 1.0, 1.5, 0.0, 0.5, 0.0, 0.5, 0.5],
        "lane": [0, 1, 1, 2, 2, 1, 0, 0, 2],
        "speed_mps": [3.0, 2.0, 10.0, 20.0, 6.0, 4.9, 1.0, 1.0, 1.0],
    })
    assert bn.queue_lane_changes(traj.sample(frac=1.0, random_state=0), slow_mps=5.0) == 2
    assert bn.queue_lane_changes(traj, slow_mps=30.0) == 3  # every change, when every speed counts as slow
    assert bn.queue_lane_changes(traj, slow_mps=1.0) == 0
