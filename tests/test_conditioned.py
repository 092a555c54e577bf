"""One network for every alpha: the conditioned forward pass, replay with alpha and relabelling, the alpha schedule of
training, driving at an alpha, the adaptive rule and bad input (the protocol's conditioned variant: test_protocol)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import torch

from coopsumo.agents.adaptive import AdaptiveRule, choose_alpha, interval_measures
from coopsumo.agents.conditioning import conditioned_alphas, training_alpha
from coopsumo.agents.dqn import ALPHA_INPUT_SCALE, GRID_SHAPE, N_ACTIONS, QNetwork, ReplayBuffer, alpha_input
from coopsumo.agents.model_file import ModelFileError, load_model, save_model
from coopsumo.agents.replay import relabelled
from coopsumo.config import PAPER_ALPHAS, RewardConfig, SimConfig, TrainConfig, to_dict
from coopsumo.dqn_config import DQNConfig
from coopsumo.errors import ConfigError, UsageError
from coopsumo.policy_spec import ADAPTIVE, split_dqn_spec
from coopsumo.sim.observation import Observation
from coopsumo.sim.physics import LEFT, SPEEDUP

ROOT = Path(__file__).resolve().parent.parent


# -- network and replay (no SUMO) ------------------------------------------------------------------
def test_the_conditioned_network_reads_alpha_beside_the_speed_errors() -> None:
    torch.manual_seed(0)
    net = QNetwork(30.0, dueling=True, conditioned=True)
    plain = QNetwork(30.0, dueling=True)
    assert net.fc1.in_features == plain.fc1.in_features + 1
    grids = (torch.rand(5, *GRID_SHAPE) < 0.3).float()
    feats = torch.randn(5, 3)
    q0 = net(grids, feats, torch.zeros(5))
    q8 = net(grids, feats, torch.full((5,), 8.0))
    assert q0.shape == (5, N_ACTIONS) and not torch.allclose(q0, q8)  # alpha changes the values
    with pytest.raises(ValueError, match="needs alpha"):
        net(grids, feats)
    with pytest.raises(ValueError, match="needs alpha"):
        plain(grids, feats, torch.zeros(5))
    # the input is log(1 + alpha) / log(49): 0 at 0, 1 at the grid's largest alpha
    assert alpha_input(torch.tensor([0.0, 48.0])).tolist() == pytest.approx([0.0, 1.0])
    assert ALPHA_INPUT_SCALE == pytest.approx(math.log(49.0))


def _transitions(n: int, conditioned: bool) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(1)
    out = {
        "grids": (rng.random((n, *GRID_SHAPE)) < 0.2).astype(np.uint8),
        "features": rng.normal(size=(n, 3)).astype(np.float32),
        "actions": rng.integers(0, N_ACTIONS, n),
        "rewards": np.arange(n, dtype=np.float32),
        "next_grids": np.zeros((n, *GRID_SHAPE), np.uint8),
        "next_features": np.zeros((n, 3), np.float32),
        "dones": np.zeros(n, np.float32),
    }
    if conditioned:
        out["alphas"] = np.full(n, 2.0, np.float32)
        out["lane_changes"] = (np.arange(n) % 2).astype(np.float32)  # odd rows changed lane once
    return out


def test_replay_carries_alpha_and_relabels_rewards_by_the_lane_changes() -> None:
    buf = ReplayBuffer(32, conditioned=True)
    buf.add_batch(**_transitions(10, True))
    rng = np.random.default_rng(0)
    kept = buf.sample(64, rng)  # no relabelling: every transition at its own alpha and reward
    assert kept.alphas is not None and set(kept.alphas.tolist()) == {2.0}
    moved = buf.sample(256, rng, relabel=1.0)  # every transition at an alpha drawn from the grid
    assert moved.alphas is not None and set(moved.alphas.tolist()) <= set(PAPER_ALPHAS)
    assert len(set(moved.alphas.tolist())) > 3
    ids = moved.features  # the reward stored was the row's index; recover it from the features
    rows = {tuple(np.round(f, 5)): i for i, f in enumerate(_transitions(10, True)["features"])}
    for f, r, a in zip(ids.numpy(), moved.rewards.numpy(), moved.alphas.numpy(), strict=True):
        i = rows[tuple(np.round(f, 5))]
        assert r == pytest.approx(i + (2.0 - a) * (i % 2))  # r' = r + (alpha - alpha') x lane changes
    # the pure relabelling
    np.testing.assert_allclose(relabelled(np.array([1.0]), np.array([2.0]), np.array([1.0]), np.array([8.0])), [-5.0])
    # a conditioned buffer needs alphas, another takes none; a snapshot keeps them
    with pytest.raises(ValueError, match="conditioned"):
        buf.add_batch(**_transitions(2, False))
    with pytest.raises(ValueError, match="conditioned"):
        ReplayBuffer(8).add_batch(**_transitions(2, True))
    other = ReplayBuffer(32, conditioned=True)
    other.load_state_dict(buf.state_dict())
    assert other.sample(4, np.random.default_rng(3)).alphas is not None
    with pytest.raises(ValueError, match="fields"):
        ReplayBuffer(32).load_state_dict(buf.state_dict())


def test_training_alpha_is_drawn_from_the_grid_per_period_and_repeats_exactly() -> None:
    period = 3000
    draws = [training_alpha(7, k * period, period) for k in range(60)]
    assert set(draws) <= set(PAPER_ALPHAS) and len(set(draws)) >= 8  # the grid is covered
    assert all(training_alpha(7, k * period + j, period) == draws[k] for k in (0, 5) for j in (1, period - 1))
    assert draws == [training_alpha(7, k * period, period) for k in range(60)]
    assert draws != [training_alpha(8, k * period, period) for k in range(60)]


def test_alpha_draw_max_keeps_the_draws_and_the_relabelling_within_the_paper_alphas_up_to_it() -> None:
    assert conditioned_alphas(DQNConfig()) == PAPER_ALPHAS  # 48: all twelve, as before the option
    up_to_8 = conditioned_alphas(DQNConfig(alpha_draw_max=8.0))
    assert up_to_8 == (0.0, 0.125, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0)
    period = 3000
    draws = [training_alpha(7, k * period, period, up_to_8) for k in range(60)]
    assert set(draws) == set(up_to_8)  # every one of the eight, none above
    assert [training_alpha(7, k * period, period, PAPER_ALPHAS) for k in range(60)] == [
        training_alpha(7, k * period, period) for k in range(60)]  # fmt: skip
    buf = ReplayBuffer(32, conditioned=True)
    buf.add_batch(**_transitions(10, True))
    moved = buf.sample(512, np.random.default_rng(0), relabel=1.0, relabel_to=up_to_8)
    assert moved.alphas is not None and set(moved.alphas.tolist()) == set(up_to_8)
    assert DQNConfig(alpha_draw_max=0.5).validate() is None
    with pytest.raises(ConfigError, match="alpha_draw_max"):
        DQNConfig(alpha_draw_max=-1.0).validate()


def test_a_conditioned_training_keeps_the_worlds_alpha_at_zero() -> None:
    cfg = TrainConfig(sim=SimConfig(reward=RewardConfig(alpha=2.0), policy="dqn"),
                      dqn=replace(DQNConfig(), alpha_conditioned=True))  # fmt: skip
    with pytest.raises(ConfigError, match="draws alpha itself"):
        cfg.validate()


def test_validation_alphas_judge_a_conditioned_snapshot_at_each_alpha(tmp_path: Path) -> None:
    """--validation-alphas: every validation run once per alpha (the same seeds), the weights trained unchanged."""
    from coopsumo.agents import selection
    from coopsumo.studies.engine.model_store import without_selection

    def request_of(dq: DQNConfig, name: str) -> dict[str, Any]:
        cfg = TrainConfig(sim=SimConfig(steps=90_000, seed=3, policy="dqn"), dqn=dq)
        cfg.validate()
        selection.snapshot_dir(tmp_path / name, 15_000).mkdir(parents=True)
        return dict(json.loads((selection.request(tmp_path / name, cfg, 15_000) / selection.REQUEST).read_text()))

    cond = replace(DQNConfig(), alpha_conditioned=True)
    three = request_of(replace(cond, validation_alphas=(0.0, 1.0, 8.0)), "three")
    one = request_of(cond, "one")
    assert three["drive_alphas"] == [0.0] * 6 + [1.0] * 6 + [8.0] * 6  # 3 demands, free flow and accident
    runs_of = lambda req: [(r["seed"], r["steps"], r["demand"], r["accident"]) for r in req["runs"]]  # noqa: E731
    assert runs_of(three) == runs_of(one) * 3 and one["drive_alphas"] == [0.0] * 6
    assert request_of(DQNConfig(), "plain")["drive_alphas"] == [None] * 6
    assert without_selection(to_dict(TrainConfig(dqn=replace(cond, validation_alphas=(0.0, 8.0))))) \
        == without_selection(to_dict(TrainConfig(dqn=cond)))  # fmt: skip
    for bad in ((-1.0,), (1.0, 1.0), tuple(float(a) for a in range(11))):
        with pytest.raises(ConfigError, match="validation_alphas"):
            replace(cond, validation_alphas=bad).validate()
    with pytest.raises(ConfigError, match="alpha-conditioned"):
        replace(DQNConfig(), validation_alphas=(0.0, 8.0)).validate()


def test_a_conditioned_snapshot_is_validated_in_sumo_at_each_alpha(tmp_path: Path) -> None:
    """The hand-made network changes lanes at alpha 0 and never at alpha 8: validated at both, its runs say so, and
    the score is the mean of the two."""
    from coopsumo.agents import selection

    dq = replace(DQNConfig(), observation="paper", dueling=False, alpha_conditioned=True, change_margin=0.0,
                 validation_t_ups=(1.0,),
                 validation_steps=600, validation_accident_steps=0, validation_alphas=(0.0, 8.0))  # fmt: skip
    cfg = TrainConfig(sim=SimConfig(steps=90_000, seed=3, policy="dqn"), dqn=dq)
    folder = selection.snapshot_dir(tmp_path, 15_000)
    folder.mkdir(parents=True)
    save_model(folder / "model.pt", _handmade_conditioned_net(), {"config": to_dict(cfg)})
    result = selection.validate(selection.request(tmp_path, cfg, 15_000))
    runs = {r["alpha"]: r for r in result["runs"]}
    assert sorted(runs) == [0.0, 8.0] and runs[0.0]["seed"] == runs[8.0]["seed"]
    assert runs[0.0]["lane_changes_per_vehicle"] > 0 and runs[8.0]["lane_changes_per_vehicle"] == 0
    assert result["score"] == pytest.approx((runs[0.0]["mean_reward"] + runs[8.0]["mean_reward"]) / 2)
    assert all(r["collisions"] == 0 and r["teleports"] == 0 for r in result["runs"])
    selection.write_table(tmp_path)
    table = pd.read_csv(tmp_path / "validation.csv")
    assert {"lane_changes_per_vehicle_t1_alpha0", "lane_changes_per_vehicle_t1_alpha8"} <= set(table.columns)


# -- driving at an alpha (no SUMO) -----------------------------------------------------------------
def _handmade_conditioned_net() -> QNetwork:
    """Q(left) = Q(right) = 1 - 2 x alpha_input (>= 0), Q(speedup) = 0.5, Q(none) = 0: a lane change is worth it
    only at a small alpha (alpha_input < 0.25, i.e. alpha < about 1.6)."""
    net = QNetwork(30.0, conditioned=True)
    with torch.no_grad():
        for p in net.parameters():
            p.zero_()
        net.fc1.weight[0, -1] = -2.0  # unit 0 = relu(1 - 2 x alpha input)
        net.fc1.bias[0] = 1.0
        net.fc2.weight[0, 0] = 1.0
        net.out.weight[LEFT, 0] = 1.0
        net.out.weight[1, 0] = 1.0
        net.out.bias[SPEEDUP] = 0.5
    return net


def test_a_conditioned_model_driven_at_two_alphas_changes_lanes_at_two_rates(
    observation_of: Callable[..., Observation],
) -> None:
    from coopsumo.agents.dqn_policy import DQNPolicy

    net = _handmade_conditioned_net()
    obs = observation_of([1, 1, 1, 1], [20.0, 80.0, 140.0, 200.0], [20.0] * 4, [25.0] * 4)  # room on both sides
    rates = {}
    for alpha in (0.0, 8.0):
        policy = DQNPolicy(net, alpha=alpha)
        actions = policy.act(obs)
        rates[alpha] = float(np.isin(actions, [0, 1]).mean())
    assert rates == {0.0: 1.0, 8.0: 0.0}
    with pytest.raises(ValueError, match="conditioned"):
        DQNPolicy(net)  # a conditioned network needs an alpha or a rule
    adaptive = DQNPolicy(net, rule=AdaptiveRule(((3, 1.0, 0.0), (3, 10.0, 8.0))), lanes=3)
    assert np.isin(adaptive.act(obs), [0, 1]).all()  # starts at the emptiest point's alpha, 0
    adaptive.loop_interval(interval_measures(60.0, np.array([10, 12]), np.array([9.0, 12.0]),
                                             np.array([15.0, 14.0]), 60.0))  # fmt: skip
    assert adaptive.alpha == 8.0 and not np.isin(adaptive.act(obs), [0, 1]).any()  # the cache did not hold it
    assert adaptive.alpha_log[0]["alpha"] == 8.0 and adaptive.alpha_log[0]["occupancy_pct"] == pytest.approx(10.5)


def test_a_conditioned_model_file_records_it_and_an_older_reader_cannot_load_it(tmp_path: Path) -> None:
    path = tmp_path / "model.pt"
    save_model(path, _handmade_conditioned_net(), {})
    net, _ = load_model(path)
    assert net.conditioned
    payload = torch.load(path, weights_only=True)
    assert payload["alpha_conditioned"] is True
    # what a coopsumo from before conditioned networks reads: no flag, so a plain network, whose first layer
    # does not fit the weights -> one line naming the problem
    del payload["alpha_conditioned"]
    torch.save(payload, path)
    with pytest.raises(ModelFileError, match="incompatible weights") as info:
        load_model(path)
    assert "\n" not in str(info.value)
    payload["alpha_conditioned"] = "yes"
    torch.save(payload, path)
    with pytest.raises(ModelFileError, match="alpha_conditioned"):
        load_model(path)


@pytest.mark.parametrize(
    "spec, expected",
    [
        ("dqn:a/model.pt", ("a/model.pt", None)),
        ("dqn:a/model.pt,alpha=0.25", ("a/model.pt", 0.25)),
        ("dqn:a/model.pt,alpha=1000", ("a/model.pt", 1000.0)),
        ("dqn:a/model.pt,alpha=adaptive", ("a/model.pt", ADAPTIVE)),
    ],
)
def test_dqn_specs_split_into_model_and_alpha(spec: str, expected: tuple[str, object]) -> None:
    assert split_dqn_spec(spec) == expected


@pytest.mark.parametrize("tail", ["alpha=-1", "alpha=1000.5", "alpha=nan", "alpha=x", "alpha=", "beta=1"])
def test_bad_alpha_options_are_one_line_usage_errors(tail: str) -> None:
    with pytest.raises(UsageError) as info:
        split_dqn_spec(f"dqn:m.pt,{tail}")
    assert "\n" not in str(info.value)


# -- the adaptive rule (no SUMO) ---------------------------------------------------------------------
def test_loop_measurements_reduce_to_one_interval() -> None:
    counts = np.array([20.0, 10.0, 0.0])
    iv = interval_measures(120.0, counts, np.array([6.0, 3.0, 0.0]), np.array([20.0, 26.0, -1.0]), 60.0)
    assert iv.time_s == 120.0
    assert iv.flow_veh_h_per_lane == pytest.approx(10.0 / 60 * 3600)  # mean count 10 per detector
    assert iv.occupancy_pct == pytest.approx(3.0)
    assert iv.speed_mps == pytest.approx((20 * 20 + 10 * 26) / 30)  # count-weighted; -1 (no vehicle) left out
    empty = interval_measures(60.0, np.zeros(3), np.zeros(3), np.full(3, -1.0), 60.0)
    assert empty.flow_veh_h_per_lane == 0 and math.isnan(empty.speed_mps)


def test_the_adaptive_rule_takes_the_alpha_of_the_nearest_measured_occupancy() -> None:
    rule = AdaptiveRule(((2, 5.0, 0.5), (3, 2.0, 0.0), (3, 6.0, 1.0), (3, 12.0, 8.0), (4, 5.0, 4.0)), "hand-made")
    assert choose_alpha(rule, 3, 0.0) == 0.0
    assert choose_alpha(rule, 3, 3.9) == 0.0
    assert choose_alpha(rule, 3, 4.1) == 1.0
    assert choose_alpha(rule, 3, 40.0) == 8.0  # a jam beyond the measured range keeps the densest point's alpha
    assert choose_alpha(rule, 3, 4.0) == 1.0  # a tie goes to the denser point
    assert choose_alpha(rule, 2, 50.0) == 0.5 and choose_alpha(rule, 6, 0.0) == 4.0  # nearest lane count
    assert choose_alpha(rule, 3, math.nan) == 0.0


# -- with SUMO -----------------------------------------------------------------------------------------
def _train(out: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "coopsumo.train", *args, "--out", str(out), "--quiet"],
                          capture_output=True, text=True, cwd=ROOT, check=False)  # fmt: skip


def _simulate(out: Path, policy: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "coopsumo.simulate", "--policy", policy, "--out", str(out),
                           "--quiet", *args], capture_output=True, text=True, cwd=ROOT, check=False)  # fmt: skip


@pytest.fixture(scope="module")
def conditioned_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("cond") / "train"
    res = _train(out, "--alpha-conditioned", "--alpha-period", "300", "--steps", "1200", "--eval-steps", "300")
    assert res.returncode == 0, res.stderr
    return out / "model.pt"


@pytest.mark.sumo
def test_conditioned_training_logs_its_alphas_and_drives_at_any_alpha(conditioned_model: Path, tmp_path: Path) -> None:
    log = pd.read_csv(conditioned_model.parent / "train_log.csv")
    assert set(log["alpha"]) <= set(PAPER_ALPHAS)
    config = json.loads((conditioned_model.parent / "config.json").read_text())["config"]
    assert config["dqn"]["alpha_conditioned"] is True and config["sim"]["reward"]["alpha"] == 0
    evaluated = json.loads((conditioned_model.parent / "eval" / "config.json").read_text())
    assert evaluated["config"]["policy"].endswith(",alpha=0")
    for alpha in ("0", "48"):
        res = _simulate(tmp_path / f"a{alpha}", f"dqn:{conditioned_model},alpha={alpha}", "--steps", "300")
        assert res.returncode == 0, res.stderr
        summary = json.loads((tmp_path / f"a{alpha}" / "summary.json").read_text())
        assert summary["collisions"] == 0 and summary["teleports"] == 0


@pytest.mark.sumo
def test_adaptive_alpha_reads_the_loops_sumo_writes(conditioned_model: Path, tmp_path: Path) -> None:
    """alpha=adaptive: one row per 60 s loop period in adaptive_alpha.csv, with the flow and occupancy SUMO's
    detectors.xml holds for that period (read live at the period's last step, SUMO counts a vehicle standing on a
    loop then: the live count lies between the XML's vehicles that passed and those that entered)."""
    import sumolib

    out = tmp_path / "adaptive"
    res = _simulate(out, f"dqn:{conditioned_model},alpha=adaptive", "--steps", "1300", "--t-up", "1")
    assert res.returncode == 0, res.stderr
    chosen = pd.read_csv(out / "adaptive_alpha.csv")
    assert chosen["time_s"].tolist() == [60.0, 120.0]
    periods: dict[float, list[tuple[int, int, float]]] = {}
    for iv in sumolib.xml.parse(str(out / "detectors.xml"), "interval"):
        periods.setdefault(float(iv.end), []).append((int(iv.nVehContrib), int(iv.nVehEntered), float(iv.occupancy)))
    for row in chosen.itertuples():
        passed, entered, occupancy = (np.array(x, float) for x in zip(*periods[row.time_s], strict=True))
        live = row.flow_veh_h_per_lane * len(passed) / 60.0  # vehicles counted over all loops in the 60 s
        assert passed.sum() - 0.01 <= live <= entered.sum() + 0.01
        assert row.occupancy_pct == pytest.approx(occupancy.mean(), abs=0.02)  # the XML rounds to 2 decimals
    assert chosen["flow_veh_h_per_lane"].iloc[1] > 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["adaptive_alpha_mean"] == pytest.approx(chosen["alpha"].mean(), abs=1e-4)


@pytest.mark.sumo
@pytest.mark.parametrize(
    "kind, fragment",
    [
        ("alpha=1001", "alpha must be"),
        ("alpha=ten", "alpha must be"),
        ("plain,alpha=1", "not alpha-conditioned"),
        ("plain,alpha=adaptive", "not alpha-conditioned"),
        ("none", "is alpha-conditioned"),
    ],
)
def test_bad_alpha_input_is_one_line_and_writes_nothing(conditioned_model: Path, tmp_path: Path, kind: str,
                                                         fragment: str, capsys: pytest.CaptureFixture[str]) -> None:
    """simulate's own main in this process (refused before SUMO starts; the one-line refusal of a command run as a
    process: tests/test_bad_inputs.py)."""
    from coopsumo import simulate

    if kind.startswith("plain,"):
        plain = tmp_path / "plain"
        net = QNetwork(110 / 3.6, dueling=True, observation=TrainConfig().dqn.observation)
        plain.mkdir()
        from coopsumo.config import to_dict

        save_model(plain / "model.pt", net, {"config": to_dict(TrainConfig())})
        policy = f"dqn:{plain / 'model.pt'},{kind.split(',', 1)[1]}"
    elif kind == "none":
        policy = f"dqn:{conditioned_model}"
    else:
        policy = f"dqn:{conditioned_model},{kind}"
    out = tmp_path / "out"
    capsys.readouterr()
    code = simulate.main(["--policy", policy, "--out", str(out), "--quiet", "--steps", "50"])
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and fragment in lines[0] and "Traceback" not in err
    assert not out.exists()


@pytest.mark.sumo
def test_alpha_conditioned_beside_alpha_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "out"
    res = _train(out, "--alpha-conditioned", "--alpha", "0", "--steps", "10")
    assert res.returncode == 2
    assert len(res.stderr.strip().splitlines()) == 1 and "leave --alpha out" in res.stderr
    assert not out.exists()
