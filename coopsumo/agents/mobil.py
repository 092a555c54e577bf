"""MOBIL lane changing (Kesting, Treiber, Helbing 2007) on top of the Newell controller.

MOBIL ("minimizing overall braking induced by lane changes") asks, for a change of vehicle c
from its lane to the adjacent lane on side s, with o the follower it leaves behind and n the
follower it will have in the target lane:

    incentive:  (a~_c - a_c) + p * ((a~_n - a_n) + (a~_o - a_o))  >  threshold +/- bias
    safety:     a~_n >= -b_safe

where a is an acceleration before and a~ after the change. A positive bias favours the right:
a change to the right needs `threshold - bias`, one to the left `threshold + bias`. When both
sides qualify, the larger margin over its threshold wins (a tie goes right). Without a change
the action is speedup (the controller caps the speed at v_exp and at the Newell bound).

Accelerations come from the project's own controller, not from a second car-following model:

    a(v, v_exp, gap, v_lead) = (physics.next_speed(v, v_exp, speedup=True, gap, v_lead) - v) / dt

i.e. the speed change over one 0.1 s step the controller would impose (Newell eq. 9 then the
collision check eq. 11) if the vehicle asked to speed up, per second. It lies between
-v / dt (a stop in one step) and +v_acc / dt = +4 m/s^2. Because Newell adapts the speed in a
single step, the braking a cut-in imposes shows up as a large negative a~_n, so b_safe is a
strict criterion: with the default 4 m/s^2 the new follower may lose at most 0.4 m/s in the
next step. "Before" and "after" use the current gaps and speeds of `obs.around`:

- c before: own lane's leader; c after: target lane's leader.
- o before: c is its leader, gap = follow_gap[own]; after: c's leader, gap = follow_gap[own] + L_car + lead_gap[own].
- n before: the target lane's leader, gap = follow_gap[s] + L_car + lead_gap[s]; after: c, gap = follow_gap[s].
- followers use their own v_exp (obs.v_exp[follow_idx]); a missing follower contributes 0
  and is always safe; a missing leader is an infinite gap.

On top of MOBIL, a change is only asked for when the controller would accept it: the target
lane exists, the vehicle is not already changing lane (obs.busy), and physics.lane_change_safe
holds. (An asked-for change that the controller rejects would cost the vehicle its speedup.)

One at a time: MOBIL judges a change with every other vehicle in place, and the model's authors'
simulator executes changes one after another. Here all vehicles decide on the same snapshot, so
the decisions are taken front to back, and a change that depends on a vehicle given a change in
the same step (one that leaves or enters the changer's own or target lane between its follower
and leader there) is deferred to the next step, when it is judged again on the new layout.
Without this, a vehicle leaving to free its follower and the follower leaving to escape it both
changed to the same lane in the same step, and repeated this every 4 s (with p = 1 on 3 lanes,
about 3 in 4 changes were reversed within 10 s).

Defaults (spec `mobil` = `mobil:p=0.5`):

| parameter | default | meaning |
|---|---|---|
| p | 0.5 | politeness: 0 selfish, 1 weighs the others' changes like its own (Kesting et al.: 0-0.5) |
| threshold | 0.1 m/s^2 | change threshold Delta a_th (Kesting et al.'s value) |
| b_safe | 4.0 m/s^2 | largest deceleration imposed on the new follower (Kesting et al.'s value) |
| bias | 0.0 m/s^2 | keep-right bias; 0 = symmetric, as the paper's simulator has no keep-right rule |

Spec grammar: `mobil` or `mobil:KEY=VALUE[,KEY=VALUE...]` with keys p, threshold, b_safe, bias
(each at most once); p from 0 to 10, threshold from 0 to 100, b_safe above 0 up to 1e6, bias from -100 to 100
(validation.MOBIL_LIMITS).
"""

from __future__ import annotations

import math

import numpy as np

from coopsumo.config import ControlConfig
from coopsumo.policy_spec import PolicySpecError, parse_policy
from coopsumo.sim import physics
from coopsumo.sim.observation import Observation
from coopsumo.sim.physics import LEFT, RIGHT, SPEEDUP
from coopsumo.validation import MOBIL_LIMITS, number_problem

DEFAULT_P = 0.5
DEFAULT_THRESHOLD_MPS2 = 0.1
DEFAULT_B_SAFE_MPS2 = 4.0
DEFAULT_BIAS_MPS2 = 0.0

_SIDE_LEFT, _SIDE_OWN, _SIDE_RIGHT = 0, 1, 2  # columns of Neighbours arrays


def newell_accel(
    v_mps: np.ndarray, v_exp_mps: np.ndarray, gap_m: np.ndarray, v_lead_mps: np.ndarray, cfg: ControlConfig
) -> np.ndarray:
    """Acceleration (m/s^2) the controller gives a vehicle asking to speed up: one step of next_speed, over dt."""
    speedup = np.ones(np.shape(v_mps), dtype=bool)
    return (physics.next_speed(v_mps, v_exp_mps, speedup, gap_m, v_lead_mps, cfg) - v_mps) / cfg.dt_s


class MobilPolicy:
    """MOBIL on the Newell controller; see the module docstring for definitions and defaults."""

    needs_grids = False
    decision_interval = 1

    def __init__(
        self,
        p: float = DEFAULT_P,
        threshold: float = DEFAULT_THRESHOLD_MPS2,
        b_safe: float = DEFAULT_B_SAFE_MPS2,
        bias: float = DEFAULT_BIAS_MPS2,
        control: ControlConfig | None = None,
    ):
        for key, value in (("p", p), ("threshold", threshold), ("b_safe", b_safe), ("bias", bias)):
            low, high, low_open = MOBIL_LIMITS[key]
            if number_problem(float(value), low, high, low_open):
                raise PolicySpecError(f"mobil: bad value {key}={value!r}; {_RULES[key]}")
        self.p = float(p)
        self.threshold = float(threshold)
        self.b_safe = float(b_safe)
        self.bias = float(bias)
        self.control = control if control is not None else ControlConfig()
        self.name = f"mobil:p={self.p:g},threshold={self.threshold:g},b_safe={self.b_safe:g},bias={self.bias:g}"

    @classmethod
    def from_spec(cls, spec: str, control: ControlConfig | None = None) -> MobilPolicy:
        """Parse `mobil` or `mobil:p=0.5,threshold=0.1,b_safe=4,bias=0` (any subset, any order)."""
        parsed = parse_policy(spec)  # policy_spec: the one grammar, ranges included
        if parsed.name != "mobil":
            raise PolicySpecError(f"policy {spec!r} is not mobil; expected mobil or mobil:p=P[,threshold=T,...]")
        return cls(control=control, **parsed.values())

    def incentives(self, obs: Observation) -> tuple[np.ndarray, np.ndarray]:
        """(n, 2) MOBIL incentive (m/s^2) and (n, 2) bool admissibility for [left, right].

        Admissible: target lane exists, not busy, controller's gap check passes, b_safe holds.
        """
        cfg = self.control
        nb = obs.around
        v, v_exp = obs.speed, obs.v_exp
        a_own_now = newell_accel(v, v_exp, nb.lead_gap[:, _SIDE_OWN], nb.lead_speed[:, _SIDE_OWN], cfg)

        # the old follower: behind c now; behind c's leader after the change (same for both sides)
        vf_o, vexp_o, has_o = self._follower(obs, _SIDE_OWN)
        gap_o = nb.follow_gap[:, _SIDE_OWN]
        a_o_now = newell_accel(vf_o, vexp_o, gap_o, v, cfg)
        a_o_new = newell_accel(vf_o, vexp_o, gap_o + cfg.car_length_m + nb.lead_gap[:, _SIDE_OWN],
                               nb.lead_speed[:, _SIDE_OWN], cfg)  # fmt: skip
        d_old = np.where(has_o, a_o_new - a_o_now, 0.0)

        incentive = np.zeros((len(obs), 2))
        admissible = np.zeros((len(obs), 2), dtype=bool)
        for col, side in enumerate((_SIDE_LEFT, _SIDE_RIGHT)):
            a_own_new = newell_accel(v, v_exp, nb.lead_gap[:, side], nb.lead_speed[:, side], cfg)
            vf_n, vexp_n, has_n = self._follower(obs, side)
            gap_n = nb.follow_gap[:, side]
            a_n_now = newell_accel(vf_n, vexp_n, gap_n + cfg.car_length_m + nb.lead_gap[:, side],
                                   nb.lead_speed[:, side], cfg)  # fmt: skip
            a_n_new = newell_accel(vf_n, vexp_n, gap_n, v, cfg)
            d_new = np.where(has_n, a_n_new - a_n_now, 0.0)
            incentive[:, col] = a_own_new - a_own_now + self.p * (d_new + d_old)
            safe_follower = ~has_n | (a_n_new >= -self.b_safe)
            room = physics.lane_change_safe(nb.lead_gap[:, side], gap_n, v, nb.follow_speed[:, side], cfg)
            admissible[:, col] = nb.exists[:, side] & ~obs.busy & room & safe_follower
        return incentive, admissible

    def act(self, obs: Observation) -> np.ndarray:
        """MOBIL's decisions (`decide`), taken one vehicle at a time, front to back (`_one_at_a_time`)."""
        return self._one_at_a_time(obs, self.decide(obs))

    def decide(self, obs: Observation) -> np.ndarray:
        """Each vehicle's MOBIL decision on the current layout, as if it alone changed lane."""
        incentive, admissible = self.incentives(obs)
        margin = incentive - np.array([self.threshold + self.bias, self.threshold - self.bias])[None, :]
        go = admissible & (margin > 0)
        go_left = go[:, 0] & (~go[:, 1] | (margin[:, 0] > margin[:, 1]))
        go_right = go[:, 1] & ~go_left
        actions = np.full(len(obs), SPEEDUP, dtype=np.int64)
        actions[go_left] = LEFT
        actions[go_right] = RIGHT
        return actions

    def _one_at_a_time(self, obs: Observation, actions: np.ndarray) -> np.ndarray:
        """Defer a change that depends on a vehicle changing lane in the same step (front to back).

        MOBIL judges one change with every other vehicle in place. A change is deferred (speedup
        this step, judged again on the next one) when a vehicle in front, already given a change in
        this step, leaves or enters its own or target lane between its follower and leader there.
        """
        movers = np.flatnonzero(actions != SPEEDUP)
        if len(movers) < 2:
            return actions
        nb, length = obs.around, self.control.car_length_m
        done_from: list[int] = []
        done_to: list[int] = []
        done_pos: list[float] = []
        for i in movers[np.argsort(-obs.pos[movers], kind="stable")]:
            side = _SIDE_LEFT if actions[i] == LEFT else _SIDE_RIGHT
            target = obs.lane[i] + (1 if side == _SIDE_LEFT else -1)
            if done_pos:
                moved_pos = np.array(done_pos)
                lanes = np.array([done_from, done_to])
                for lane, col in ((obs.lane[i], _SIDE_OWN), (target, side)):
                    lo = obs.pos[i] - length - nb.follow_gap[i, col]  # follower's front (-inf if none)
                    hi = obs.pos[i] + length + nb.lead_gap[i, col]  # leader's front (+inf if none)
                    if np.any((lanes == lane).any(axis=0) & (moved_pos >= lo) & (moved_pos <= hi)):
                        actions[i] = SPEEDUP
                        break
            if actions[i] != SPEEDUP:
                done_from.append(int(obs.lane[i]))
                done_to.append(int(target))
                done_pos.append(float(obs.pos[i]))
        return actions

    @staticmethod
    def _follower(obs: Observation, side: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Speed, expected speed and presence of each vehicle's follower on `side` (placeholders if none)."""
        idx = obs.around.follow_idx[:, side]
        has = idx >= 0
        v_exp = np.where(has, obs.v_exp[np.where(has, idx, 0)], 1.0)
        return np.where(has, obs.around.follow_speed[:, side], 0.0), v_exp, has


_RULES = {
    key: f"{key}{' (politeness)' if key == 'p' else ' (m/s^2)'} must be {number_problem(math.nan, lo, hi, lo_open)}"
    for key, (lo, hi, lo_open) in MOBIL_LIMITS.items()
}
"""each parameter's range in words (validation.MOBIL_LIMITS)"""
