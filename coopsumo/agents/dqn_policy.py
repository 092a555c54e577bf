"""A trained DQN as a policy: one batched forward pass per step for the vehicles whose input changed."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from coopsumo.agents.adaptive import DEFAULT_RULE, AdaptiveRule, LoopInterval, choose_alpha
from coopsumo.agents.decisions import no_change_in_queue, no_return, offered, with_change_margin
from coopsumo.agents.dqn import GRID_SHAPE, N_ACTIONS, QNetwork
from coopsumo.agents.model_file import ModelFileError, load_model
from coopsumo.config import MAX_LANES, MIN_LANES, SIM_LIMITS, ControlConfig
from coopsumo.dqn_config import PAPER_DQN, dqn_config_from_dict
from coopsumo.errors import ConfigError, UsageError
from coopsumo.field_rules import number_problem
from coopsumo.files import file_sha256
from coopsumo.policy_spec import ADAPTIVE, model_file, parse_policy, split_dqn_spec
from coopsumo.sim.observation import Observation, network_features
from coopsumo.sim.physics import LEFT, RIGHT
from coopsumo.validation import ALPHA_MAX, ALPHA_MIN, MAX_T_UP_S

DT_S = ControlConfig().dt_s
"""the step (s) a decision interval counts in"""


TRAINED_ON_LIMITS = {("road", "lanes"): (MIN_LANES, MAX_LANES), ("demand", "t_up_s"): (1e-3, MAX_T_UP_S),
                     ("reward", "alpha"): (ALPHA_MIN, ALPHA_MAX), ("control", "dt_s"): SIM_LIMITS["control.dt_s"][:2]}
"""the recorded training configuration's settings a model's run copies into its config.json (model_trained_on)"""


def trained_on_problem(config: Any) -> str | None:
    """Why the training configuration a model file records holds a setting no training had, or None (an absent one
    is fine: a model saved before it was recorded)."""
    for (part, name), (low, high) in TRAINED_ON_LIMITS.items():
        value = _field(config, "sim", part, name)
        bad = value is not None and (isinstance(value, bool) or not isinstance(value, int | float)
                                     or number_problem(float(value), low, high) is not None)  # fmt: skip
        if bad:
            return f"its training configuration has sim.{part}.{name} = {value!r}, outside {low:g} to {high:g}"
    return None


def _field(d: Any, *keys: str) -> Any:
    """d[k1][k2]...; None where a level is missing or not a mapping."""
    for k in keys:
        d = d.get(k) if isinstance(d, dict) else None
    return d


class DQNPolicy:
    """Greedy actions of a Q-network (its weights must not change while the policy is in use).

    The network reads what it was trained on (net.observation: the paper's grids and speed errors, or those
    and the v2x features; observation.network_features).

    A vehicle whose grids, features and feasible actions are exactly those of its previous
    decision (typically one standing in a queue) gets its previous action again without a forward
    pass: the network is deterministic, so the action is the same, and a jam costs far less.

    decision_interval: the runner asks for actions every this many steps (coopsumo.agents.decisions);
    action_mask: choose only among the feasible actions (obs.feasible); restart_below_mps: 'none' is not
    chosen below this speed (m/s; 0: at any speed). All three as in training (decisions.offered).

    An alpha-conditioned network drives at `alpha` (the lane-change penalty it weighs, for every vehicle), or,
    with an adaptive `rule`, at the alpha the rule chooses from each loop interval (loop_interval; the
    choices are kept in alpha_log).
    """

    needs_grids = True

    def __init__(
        self,
        net: QNetwork,
        name: str = "dqn",
        decision_interval: int = 1,
        action_mask: bool = False,
        restart_below_mps: float = 0.0,
        change_margin: float = 0.0,
        alpha: float | None = None,
        rule: AdaptiveRule | None = None,
        lanes: int = 3,
        queue_below_mps: float = 0.0,
        no_return_s: float = 0.0,
    ):
        if net.conditioned == (alpha is None and rule is None):
            raise ValueError("an alpha-conditioned network drives at an alpha or by a rule, another at neither")
        # one torch thread, as in every study cell: a second thread can change the last bit of a Q-value (and so a
        # near-tie's choice), so `simulate` now repeats a study's run exactly whatever the machine's core count;
        # a decision is one small batch, and on a busy machine a second thread's spinning made it 40 times slower
        torch.set_num_threads(1)
        self.net = net.eval()
        self.name = name
        self.decision_interval = decision_interval
        self.action_mask = action_mask
        self.restart_below_mps = restart_below_mps
        self.change_margin = change_margin
        self.no_return_s = no_return_s
        """seconds after a lane change during which the change back is not chosen (0: none; the model's
        DQNConfig.no_return_s, or dqn:PATH,noreturn=S)"""
        self.queue_below_mps = queue_below_mps
        """speed below which no lane change is chosen (m/s; 0: none; the model's DQNConfig.queue_below_mps, or
        dqn:PATH,queue=V)"""
        self.rule = rule
        self.lanes = lanes
        self.alpha = choose_alpha(rule, lanes, 0.0) if rule is not None else alpha
        """the alpha the vehicles drive with now (None: the network is not conditioned)"""
        self.alpha_log: list[dict[str, float]] = []
        """adaptive: one row per loop interval: its measurements and the alpha chosen from them"""
        self.trained_on: dict[str, object] | None = None
        """what a model file says it was trained on (preset, lanes, T_up, alpha, version); None when unknown"""
        self._grids = np.zeros((0, *GRID_SHAPE), np.uint8)  # last input and action, by vehicle number
        self._features = np.zeros((0, net.n_features), np.float32)
        self._mask = np.zeros((0, N_ACTIONS), bool)
        self._action = np.full(0, -1, np.int64)  # -1: no previous decision
        self._rounds = 0  # decision rounds driven
        self._busy_round = np.zeros(0, np.int64)  # the last round each vehicle was seen changing lanes (0: never)
        self._last_change = np.full(0, -1, np.int64)  # the direction (LEFT, RIGHT) of its last lane change (-1: none)
        self.q_log: list[np.ndarray] | None = None
        """when a list: every fresh decision appends its rows [Q-values (4), offered (4), action] (diagnosis)"""

    @classmethod
    def from_spec(cls, spec: str, lanes: int = 3) -> DQNPolicy:
        """The policy of 'dqn:PATH[,alpha=A|adaptive][,margin=M][,noreturn=S][,restart=R][,queue=V]' on
        a road of `lanes` lanes (policy_spec: the one grammar).

        alpha is for an alpha-conditioned model only, and such a model needs it: otherwise a usage error. margin
        replaces the change margin the model was saved with (training ignores it, so any margin can drive it), and
        restart the speed below which 'none' is withheld (m/s; as the mask, it only narrows the greedy choice);
        queue the speed below which no lane change is chosen (m/s).
        """
        parsed = parse_policy(spec)
        path, alpha = split_dqn_spec(spec)
        policy = cls.from_file(path)
        if parsed.margin is not None:
            policy.change_margin = parsed.margin
            policy.trained_on = dict(policy.trained_on or {}, driven_change_margin=parsed.margin)
        if parsed.noreturn is not None:
            policy.no_return_s = parsed.noreturn
            policy.trained_on = dict(policy.trained_on or {}, driven_no_return_s=parsed.noreturn)
        if parsed.queue is not None:
            policy.queue_below_mps = parsed.queue
            policy.trained_on = dict(policy.trained_on or {}, driven_queue_below_mps=parsed.queue)
        if parsed.restart is not None:
            policy.restart_below_mps = parsed.restart
            policy.trained_on = dict(policy.trained_on or {}, driven_restart_below_mps=parsed.restart)
        conditioned = policy.net.conditioned
        if alpha is not None and not conditioned:
            raise UsageError(f"model {path} is not alpha-conditioned (trained at one alpha): drive it as dqn:{path}, "
                             "without alpha=")  # fmt: skip
        if alpha is None and conditioned:
            raise UsageError(f"model {path} is alpha-conditioned: say the alpha it drives with, dqn:{path},alpha=A "
                             f"or dqn:{path},alpha={ADAPTIVE}")  # fmt: skip
        if alpha is not None:
            policy.drive_at(alpha, lanes)
            policy.trained_on = dict(policy.trained_on or {}, driven_alpha=alpha)
        return policy

    def drive_at(self, alpha: float | str, lanes: int) -> None:
        """Drive a conditioned network at a fixed alpha, or at 'adaptive' by DEFAULT_RULE on a road of `lanes`."""
        self.rule = DEFAULT_RULE if alpha == ADAPTIVE else None
        self.lanes = lanes
        self.alpha = choose_alpha(self.rule, lanes, 0.0) if self.rule is not None else float(alpha)
        self._action[:] = -1  # choices remembered at another alpha

    @classmethod
    def from_file(cls, path: str) -> DQNPolicy:
        """Load model.pt (or the model.pt of the folder `path`) and drive it as it was trained; a missing, corrupt or
        mismatched file is a usage error.
        An alpha-conditioned model is driven at alpha 0 (from_spec chooses another).

        The observation is the same on every road (left, own and right lane; lanes off the road are full),
        so a model trained on another lane count or inflow is driven by the same rules; `trained_on` says
        what it was trained on (simulate records it in config.json).
        """
        path = model_file(path)  # a training's folder stands for its model.pt
        try:
            net, meta = load_model(path)
        except ModelFileError as err:
            raise UsageError(str(err)) from None
        config = meta.get("config")
        try:
            if config is None:  # saved without its training configuration: driven as before presets
                dqn = PAPER_DQN
            elif isinstance(_field(config, "dqn"), dict):
                dqn = dqn_config_from_dict(config["dqn"])
            else:
                raise ConfigError("its training configuration has no learner settings")
            dqn.validate()  # the learner settings' types and ranges (a decision interval of 0, a string)
            if problem := trained_on_problem(config):  # what simulate records as trained on
                raise ConfigError(problem)
            if dqn.dueling != net.dueling:
                raise ConfigError(f"its learner settings say dueling={dqn.dueling}, its weights have "
                                  f"{'a dueling' if net.dueling else 'a plain'} head")  # fmt: skip
            if dqn.observation != net.observation:
                raise ConfigError(f"its learner settings say observation {dqn.observation!r}, its weights read "
                                  f"{net.observation!r}")  # fmt: skip
            if dqn.alpha_conditioned != net.conditioned:
                raise ConfigError(f"its learner settings say alpha_conditioned={dqn.alpha_conditioned}, its weights "
                                  f"are {'' if net.conditioned else 'not '}conditioned")  # fmt: skip
        except ConfigError as err:
            raise UsageError(f"model {path}: {err}") from None
        policy = cls(net, name=f"dqn:{Path(path).parent.name or path}",
                     decision_interval=dqn.decision_interval_steps, action_mask=dqn.action_mask,
                     restart_below_mps=dqn.restart_below_mps, change_margin=dqn.change_margin,
                     alpha=0.0 if net.conditioned else None, queue_below_mps=dqn.queue_below_mps,
                     no_return_s=dqn.no_return_s)  # fmt: skip
        policy.trained_on = {"preset": dqn.preset, "observation": dqn.observation,
                             "decision_interval_steps": dqn.decision_interval_steps,
                             "action_mask": dqn.action_mask, "restart_below_mps": dqn.restart_below_mps,
                             "change_margin": dqn.change_margin, "queue_below_mps": dqn.queue_below_mps,
                             "no_return_s": dqn.no_return_s, "alpha_conditioned": dqn.alpha_conditioned,
                             "lanes": _field(config, "sim", "road", "lanes"),
                             "t_up_s": _field(config, "sim", "demand", "t_up_s"),
                             "alpha": _field(config, "sim", "reward", "alpha"),
                             "coopsumo": _field(meta, "versions", "coopsumo"),
                             "model_sha256": file_sha256(Path(path))}  # fmt: skip
        return policy

    def loop_interval(self, interval: LoopInterval) -> None:
        """An adaptive policy's alpha for the next interval, chosen from the one the loops just measured."""
        if self.rule is None:
            return
        alpha = choose_alpha(self.rule, self.lanes, interval.occupancy_pct)
        self.alpha_log.append({"time_s": round(interval.time_s, 3), "flow_veh_h_per_lane": interval.flow_veh_h_per_lane,
                               "occupancy_pct": interval.occupancy_pct, "speed_mps": interval.speed_mps,
                               "alpha": alpha})  # fmt: skip
        if alpha != self.alpha:
            self.alpha = alpha
            self._action[:] = -1  # choices remembered at another alpha

    def _grow(self, needed: int) -> None:
        cap = len(self._action)
        if needed <= cap:
            return
        extra = max(needed, 2 * cap, 1024) - cap
        self._grids = np.concatenate([self._grids, np.zeros((extra, *GRID_SHAPE), np.uint8)])
        self._features = np.concatenate([self._features, np.zeros((extra, self.net.n_features), np.float32)])
        self._mask = np.concatenate([self._mask, np.zeros((extra, N_ACTIONS), bool)])
        self._action = np.concatenate([self._action, np.full(extra, -1, np.int64)])
        self._busy_round = np.concatenate([self._busy_round, np.zeros(extra, np.int64)])
        self._last_change = np.concatenate([self._last_change, np.full(extra, -1, np.int64)])

    def act(self, obs: Observation) -> np.ndarray:
        n = len(obs)
        if n == 0:
            return np.zeros(0, dtype=np.int64)
        nums = obs.nums
        self._grow(int(nums.max()) + 1)
        mask = offered(obs.feasible, obs.speed, self.action_mask, self.restart_below_mps)
        feats = network_features(obs, self.net.observation, self.net.speed_scale_mps)
        if mask is None:
            mask = np.ones((n, N_ACTIONS), bool)
        self._rounds += 1
        self._busy_round[nums[obs.busy]] = self._rounds
        if self.no_return_s > 0:
            # a change under way was started by the vehicle's last choice (no change is offered while one runs)
            started = obs.busy & ((self._action[nums] == LEFT) | (self._action[nums] == RIGHT))
            self._last_change[nums[started]] = self._action[nums[started]]
        if self.no_return_s > 0:
            last = self._busy_round[nums]
            since_s = np.where(last > 0, (self._rounds - last) * self.decision_interval * DT_S, np.inf)
            mask = no_return(mask, since_s, self._last_change[nums], self.no_return_s)
        mask = no_change_in_queue(mask, obs.speed, self.queue_below_mps)
        # the features (speeds, gaps) differ for nearly every moving vehicle: the grids and masks are compared only
        # where they do not
        same = (self._action[nums] >= 0) & (self._features[nums] == feats).all(axis=1)
        if same.any():
            rows = np.flatnonzero(same)
            same[rows] = ((self._grids[nums[rows]] == obs.grids[rows]).reshape(len(rows), -1).all(axis=1)
                          & (self._mask[nums[rows]] == mask[rows]).all(axis=1))  # fmt: skip
        actions = self._action[nums]
        fresh = ~same
        if fresh.any():
            inputs = [torch.from_numpy(obs.grids[fresh]).float(), torch.from_numpy(feats[fresh])]
            if self.alpha is not None:
                inputs.append(torch.full((int(fresh.sum()),), float(self.alpha)))
            with torch.no_grad():
                q = self.net(*inputs)
            chosen = np.where(mask[fresh], with_change_margin(q.numpy(), self.change_margin), -np.inf)
            actions[fresh] = chosen.argmax(axis=1)
            if self.q_log is not None:
                self.q_log.append(np.column_stack([q.numpy(), mask[fresh], actions[fresh]]).astype(np.float32))
            changed = nums[fresh]
            self._grids[changed] = obs.grids[fresh]
            self._features[changed] = feats[fresh]
            self._mask[changed] = mask[fresh]
            self._action[changed] = actions[fresh]
        return actions
