"""The controller and the accident as pure array functions (coopsumo.sim.controller, coopsumo.sim.accident). No SUMO."""

from __future__ import annotations

import numpy as np

from coopsumo.config import AccidentConfig, ControlConfig
from coopsumo.sim import accident, controller
from coopsumo.sim.accident import HELD, RELEASED, UNDECIDED
from coopsumo.sim.physics import LEFT, NONE, RIGHT, SPEEDUP

CFG = ControlConfig()
ACC = AccidentConfig(enabled=True, start_step=100, duration_steps=1000)  # bottleneck at x_m


def test_other_lane_is_the_second_lane_of_a_change_only_while_it_lasts() -> None:
    lane = np.array([1, 1, 0])
    other = controller.other_lane(lane, np.array([0, 0, -1]), np.array([1, 1, -1]), np.array([2.0, 0.0, 0.0]))
    assert other.tolist() == [0, -1, -1]


def test_nearest_leader_picks_the_closest_column() -> None:
    gap, speed = controller.nearest_leader(np.array([[5.0, 3.0], [np.inf, 7.0]]), np.array([[1.0, 2.0], [0.0, 4.0]]))
    assert gap.tolist() == [3.0, 7.0] and speed.tolist() == [2.0, 4.0]


def test_a_changer_sees_the_leader_in_the_lane_it_moves_into() -> None:
    # vehicle 0 changes from lane 0 to 1; vehicle 1 drives 20 m ahead of it in lane 1, vehicle 2 60 m ahead in lane 0
    lane, pos, speed = np.array([0, 1, 0]), np.array([100.0, 120.0, 160.0]), np.array([20.0, 10.0, 25.0])
    gap, v_lead = controller.leaders_in_occupied_lanes(lane, np.array([1, -1, -1]), pos, speed, 3, CFG.car_length_m)
    assert gap[0] == 120.0 - CFG.car_length_m - 100.0 and v_lead[0] == 10.0
    assert gap[1] == np.inf  # nobody ahead in lane 1
    gap_alone, _ = controller.leaders_in_occupied_lanes(lane, np.full(3, -1), pos, speed, 3, CFG.car_length_m)
    assert gap_alone[0] == 160.0 - CFG.car_length_m - 100.0


def test_lane_changes_accept_only_feasible_requests_and_the_front_one_of_a_cut_in() -> None:
    actions = np.array([LEFT, LEFT, RIGHT, SPEEDUP, NONE])
    lane = np.array([0, 0, 1, 0, 0])
    pos = np.array([200.0, 195.0, 400.0, 50.0, 10.0])  # 0 and 1 both enter lane 1, 5 m apart
    speed = np.full(5, 10.0)
    feasible = np.ones((5, 4), bool)
    feasible[2, RIGHT] = False  # the controller would refuse this one now
    ok, rejected, target = controller.lane_changes(actions, lane, pos, speed, feasible, CFG)
    assert ok.tolist() == [True, False, False, False, False]
    assert rejected.tolist() == [False, True, True, False, False]
    assert target[:3].tolist() == [1, 1, 0]


def test_the_accident_holds_with_probability_p_and_only_in_its_zone() -> None:
    x = ACC.x_m
    state = np.full(4, UNDECIDED, np.int8)
    pos = np.array([x - 50.0, x - 20.0, x - accident.ZONE_M - 1.0, x + 10.0])
    speed, gap, v_lead = np.full(4, 10.0), np.full(4, np.inf), np.zeros(4)
    rng = np.random.default_rng(0)
    new, gap_new, v_new = accident.hold_and_obstacle(state, pos, speed, gap, v_lead, ACC.start_step, ACC, 0.1, rng)
    assert new.tolist() == [HELD, HELD, UNDECIDED, UNDECIDED]  # p = 1 at the start; outside the zone: not drawn
    assert gap_new.tolist() == [50.0, 20.0, np.inf, np.inf] and v_new.tolist() == [0.0, 0.0, 0.0, 0.0]
    assert state.tolist() == [UNDECIDED] * 4  # the input is not changed
    # past the window every held vehicle is released and sees its own leader again, with no draw
    before = rng.bit_generator.state
    new, gap_new, _ = accident.hold_and_obstacle(new, pos, speed, gap, v_lead, ACC.start_step + ACC.duration_steps,
                                                 ACC, 0.1, rng)  # fmt: skip
    assert new.tolist() == [RELEASED, RELEASED, UNDECIDED, UNDECIDED] and np.isinf(gap_new).all()
    assert rng.bit_generator.state == before


def test_a_drawn_vehicle_keeps_its_draw_until_it_stands_at_the_head_of_its_queue() -> None:
    x = ACC.x_m
    step = ACC.start_step + ACC.duration_steps // 2  # p = 0.5
    rng = np.random.default_rng(1)
    state = np.array([RELEASED, HELD, HELD], np.int8)
    pos = np.array([x - 30.0, x - 30.0, x - 2.0])
    speed = np.array([10.0, 10.0, 0.0])  # the third stands at the head of its queue: it is drawn again
    gap = np.array([np.inf, np.inf, np.inf])
    draws = [accident.hold_and_obstacle(state, pos, speed, gap, np.zeros(3), step, ACC, 0.1, rng)[0] for _ in range(40)]
    assert all(d[0] == RELEASED and d[1] == HELD for d in draws)  # moving: never redrawn
    assert {int(d[2]) for d in draws} == {HELD, RELEASED}  # standing at the head: redrawn every second
