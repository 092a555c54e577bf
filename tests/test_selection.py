"""Model selection on held-out demand (agents/selection.py) and the learner protocol's statistics
(studies/engine/stats.py)."""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from conftest import assert_refused_in_one_line, main_here

from coopsumo.agents import selection
from coopsumo.agents.model_file import load_model
from coopsumo.agents.train import train
from coopsumo.config import SimConfig, TrainConfig, to_dict
from coopsumo.dqn_config import PAPER_DQN, DQNConfig, dqn_config_from_dict
from coopsumo.errors import ConfigError
from coopsumo.studies.engine import stats

ROOT = Path(__file__).resolve().parent.parent
selection_start = selection.start


def _fake_result(out: Path, step: int, score: float) -> None:
    folder = selection.snapshot_dir(out, step)
    folder.mkdir(parents=True, exist_ok=True)
    torch.save({"step": step}, folder / "model.pt")
    (folder / selection.RESULT).write_text(json.dumps({"step": step, "score": score, "runs": []}))


def test_the_best_validated_snapshot_becomes_model_pt(tmp_path: Path) -> None:
    for step, score in ((100, -0.3), (200, -0.1), (300, -0.2), (400, -0.1)):  # a tie: the earlier wins
        _fake_result(tmp_path, step, score)
    chosen = selection.install_best(tmp_path)
    assert chosen is not None and chosen["step"] == 200
    assert torch.load(tmp_path / "model.pt")["step"] == 200
    assert not list(tmp_path.glob(".model.pt.*"))  # no temporary file left


def test_snapshots_without_a_result_are_pending_and_never_chosen(tmp_path: Path) -> None:
    _fake_result(tmp_path, 100, -0.5)
    unfinished = selection.snapshot_dir(tmp_path, 200)
    unfinished.mkdir(parents=True)
    torch.save({}, unfinished / "model.pt")
    (unfinished / selection.REQUEST).write_text("{}")
    assert selection.pending(tmp_path) == [unfinished]
    assert [r["step"] for r in selection.results(tmp_path)] == [100]
    assert selection.best([]) is None


def test_selection_needs_two_candidates() -> None:
    cfg = TrainConfig(sim=SimConfig(steps=1000, policy="dqn"))
    assert not selection.selecting(cfg)  # 1,000 steps <= 15,000: the last weights are the only candidate
    assert selection.selecting(dataclasses.replace(cfg, dqn=dataclasses.replace(cfg.dqn, select_every_steps=400)))
    assert not selection.selecting(dataclasses.replace(cfg, dqn=PAPER_DQN))


def test_diagnosis_counts_actions_and_near_ties() -> None:
    # Q (left, right, speedup, none), offered, action
    rows = [np.array([[1.0, 0.0, 0.99, 0.5, 1, 1, 1, 1, 2],   # change and stay within 5%: a near tie
                      [0.0, 0.0, 2.0, 1.0, 1, 0, 1, 1, 2],    # stay clearly better
                      [3.0, 0.0, 2.0, 1.0, 1, 1, 1, 1, 0],    # change clearly better, chosen
                      [0.0, 0.0, 1.0, 2.0, 0, 0, 1, 1, 3]])]  # no change offered  # fmt: skip
    d = selection.diagnosis(rows)
    assert d["share_speedup"] == 0.5 and d["share_left"] == 0.25 and d["share_none"] == 0.25
    assert d["change_offered_share"] == 0.75
    assert d["near_tie_share"] == pytest.approx(1 / 3)
    assert d["change_chosen_share"] == pytest.approx(1 / 3)


def test_validation_demands_and_seeds_are_checked() -> None:
    with pytest.raises(ConfigError, match="validation_t_ups"):
        DQNConfig(validation_t_ups=()).validate()
    with pytest.raises(ConfigError, match="validation_t_ups"):
        DQNConfig(validation_t_ups=(1.0, 0.0)).validate()
    overlap = TrainConfig(sim=SimConfig(seed=DQNConfig().validation_seed + 1, policy="dqn"))
    with pytest.raises(ConfigError, match="overlap the training seed"):
        overlap.validate()
    # a learner written before selection existed keeps the last weights, and the tuple survives JSON
    old = {k: v for k, v in json.loads(json.dumps(to_dict(DQNConfig()))).items()
           if not k.startswith(("select", "validation"))}  # fmt: skip
    assert dqn_config_from_dict(old).select_every_steps == 0
    assert dqn_config_from_dict(json.loads(json.dumps(to_dict(DQNConfig())))) == DQNConfig()


def test_accident_validation_adds_one_run_per_demand_through_an_accident() -> None:
    dq = dataclasses.replace(DQNConfig(), validation_t_ups=(2.0, 1.0), validation_steps=3000,
                             validation_accident_steps=0)
    cfg = TrainConfig(sim=SimConfig(steps=90_000, seed=3, policy="dqn"), dqn=dq)
    free = selection.validation_configs(cfg, Path("m.pt"))
    assert [(c.demand.t_up_s, c.seed, c.accident.enabled) for c in free] == [(2.0, 900_000, False),
                                                                             (1.0, 900_001, False)]
    cfg = dataclasses.replace(cfg, dqn=dataclasses.replace(dq, validation_accident_steps=6000))
    runs = selection.validation_configs(cfg, Path("m.pt"))
    assert runs[:2] == free  # the free-flow runs are unchanged: a model chosen before is judged the same there
    assert [(c.demand.t_up_s, c.seed, c.steps) for c in runs[2:]] == [(2.0, 900_002, 6000), (1.0, 900_003, 6000)]
    assert all(c.accident.enabled and c.accident.start_step == 500 and c.accident.duration_steps == 5000
               for c in runs[2:])  # fmt: skip
    assert all(c.policy == "dqn:m.pt" for c in runs)
    # its seeds count in the overlap check, and a learner written before the field existed had none
    with pytest.raises(ConfigError, match="overlap the training seed"):
        dataclasses.replace(cfg, sim=dataclasses.replace(cfg.sim, seed=900_003)).validate()
    dataclasses.replace(cfg, sim=dataclasses.replace(cfg.sim, seed=900_004)).validate()
    old = {k: v for k, v in json.loads(json.dumps(to_dict(DQNConfig()))).items() if k != "validation_accident_steps"}
    assert dqn_config_from_dict(old).validation_accident_steps == 0
    with pytest.raises(ConfigError, match="validation_accident_steps"):
        DQNConfig(validation_accident_steps=599).validate()


@pytest.mark.parametrize(("name", "kept", "other"), [("n_step", 1, 3), ("validation_queue", False, True),
                                                     ("weights_ema", 0.0, 0.99),
                                                     ("exit_transition", "drop", "terminal")])  # fmt: skip
def test_a_retired_setting_keeps_its_models_at_its_one_value_and_refuses_another(
    name: str, kept: object, other: object
) -> None:
    """Issue 80: n-step returns, validation with the queue rule, the moving average of the weights and a leaving
    vehicle's last transition stored as terminal were tried and not adopted, and retired. A configuration stored
    while they existed holds them at their one value: it is read as it was meant and keeps its model's identity (so
    no stored model is trained again); another value is refused in one line naming the setting and the commit that
    trains it."""
    from coopsumo.dqn_config import RETIRED_AT
    from coopsumo.studies.engine.model_store import model_id

    stored = json.loads(json.dumps(to_dict(TrainConfig())))
    stored["dqn"][name] = kept
    assert dqn_config_from_dict(stored["dqn"]) == DQNConfig()
    assert model_id(stored) == model_id(to_dict(TrainConfig()))
    stored["dqn"][name] = other
    with pytest.raises(ConfigError, match=f"learner setting {name} was retired .*commit {RETIRED_AT}"):
        dqn_config_from_dict(stored["dqn"])


@pytest.mark.parametrize(
    "args, fragment",
    [
        (["--validation-t-up", ""], "--validation-t-up"),
        (["--validation-t-up", "1,,2"], "--validation-t-up"),
        (["--validation-t-up", "0"], "--validation-t-up"),
        (["--validation-t-up", "-1"], "--validation-t-up"),
        (["--validation-t-up", "1,1"], "--validation-t-up"),
        (["--select-every", "-1"], "--select-every"),
        (["--validation-steps", "5"], "--validation-steps"),
        (["--validation-seed", "-3"], "--validation-seed"),
        (["--seed", "900001"], "overlap the training seed"),
        (["--validation-accident-steps", "300"], "--validation-accident-steps"),
        (["--validation-accident-steps", "-1"], "--validation-accident-steps"),
        (["--validation-accident-steps", "6000", "--seed", "900005"], "overlap the training seed"),
        (["--validation-alphas", "0,8"], "--validation-alphas"),
        (["--validation-screen", "-1"], "--validation-screen"),
        (["--validation-screen", "11"], "--validation-screen"),
        (["--validation-screen", "0", "--validation-finalists", "3"], "--validation-finalists"),
        (["--validation-screen", "1", "--validation-finalists", "0"], "--validation-finalists"),
        (["--no-return", "-1"], "--no-return"),
        (["--no-return", "nan"], "--no-return"),
        (["--alpha-conditioned", "--validation-alphas", "-1"], "--validation-alphas"),
        (["--alpha-conditioned", "--validation-alphas", "1,1"], "--validation-alphas"),
        (["--alpha-conditioned", "--validation-alphas", "a"], "--validation-alphas"),
        (["--alpha-conditioned", "--select-every", "0", "--validation-alphas", "0,8"], "--validation-alphas"),
    ],
)
def test_bad_selection_flags_are_one_line_usage_errors(
    tmp_path: Path, args: list[str], fragment: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """python -m coopsumo.train's main, in this process (the one-line refusal of a command run as a process:
    tests/test_bad_inputs.py)."""
    from coopsumo import train

    out = tmp_path / "run"
    code, _, err = main_here(train.main, ["--steps", "50", "--out", str(out), *args], capsys)
    assert_refused_in_one_line(code, err, out, fragment)


def _weights(path: Path) -> dict[str, torch.Tensor]:
    return load_model(path)[0].state_dict()


def test_selection_chooses_among_real_snapshots_without_changing_training(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """In SUMO: 400 steps validated every 200 (learning from step 200 on, after the first validation); model.pt is
    the best-scoring snapshot, model_last.pt the last weights, which equal the model.pt of the same training without
    selection (validation never feeds back). Both snapshots are validated by one process (issue 77), with the same
    result as a process of their own gives."""
    base = TrainConfig(sim=SimConfig(steps=400, seed=3, policy="dqn"), eval_steps=0,
                       dqn=dataclasses.replace(DQNConfig(), select_every_steps=200, validation_steps=100,
                                               validation_t_ups=(1.5, 1.0), validation_accident_steps=600))  # fmt: skip
    started = []
    monkeypatch.setattr(selection, "start", lambda: started.append(1) or selection_start())
    summary = train(base, tmp_path / "sel", progress=False)
    assert len(started) == 1
    for step in (200, 400):
        alone = tmp_path / f"alone{step}"
        shutil.copytree(selection.snapshot_dir(tmp_path / "sel", step), alone)
        (alone / selection.RESULT).unlink()
        subprocess.run([sys.executable, "-m", "coopsumo.agents.selection", str(alone)], check=True)
        assert selection.result(alone) == selection.result(selection.snapshot_dir(tmp_path / "sel", step))
    plain = dataclasses.replace(base, dqn=dataclasses.replace(base.dqn, select_every_steps=0))
    train(plain, tmp_path / "plain", progress=False)
    results = selection.results(tmp_path / "sel")
    assert [r["step"] for r in results] == [200, 400]
    assert all([(x["t_up_s"], x["accident"]) for x in r["runs"]] == [(1.5, False), (1.0, False), (1.5, True),
                                                                       (1.0, True)] for r in results)  # fmt: skip
    assert all(r["score"] == pytest.approx(np.mean([x["mean_reward"] for x in r["runs"]])) for r in results)
    best = max(results, key=lambda r: r["score"])
    assert summary["selected_step"] == best["step"]
    chosen = _weights(tmp_path / "sel" / "model.pt")
    snap = _weights(selection.snapshot_dir(tmp_path / "sel", best["step"]) / "model.pt")
    assert all(torch.equal(chosen[k], snap[k]) for k in chosen)
    last, without = _weights(tmp_path / "sel" / selection.LAST_MODEL), _weights(tmp_path / "plain" / "model.pt")
    assert all(torch.equal(last[k], without[k]) for k in last)
    assert not (tmp_path / "plain" / selection.SNAPSHOTS).exists()
    table = (tmp_path / "sel" / "validation.csv").read_text().splitlines()[0].split(",")
    assert {"mean_speed_mps_t1.5", "lane_changes_per_vehicle_accident_t1", "mean_reward_accident_t1.5"} <= set(table)


def test_stats_match_rliable_on_a_fixed_table() -> None:
    from rliable import metrics

    rng = np.random.default_rng(7)
    x, y = rng.normal(1.0, 1.0, (10, 3)), rng.normal(0.0, 1.0, (6, 3))
    x[0, 0] = y[0, 0]  # a tie counts a half
    assert stats.iqm(x) == pytest.approx(metrics.aggregate_iqm(x))
    assert stats.probability_of_improvement(x, y) == pytest.approx(metrics.probability_of_improvement(x, y))
    point, low, high = stats.improvement(x, y, reps=300)
    assert low <= point <= high and 0.5 < point < 1
    point, low, high = stats.iqm_interval(x, reps=300)
    assert low < point < high


def test_the_stratified_bootstrap_resamples_runs_within_tasks() -> None:
    # task 0 always 0, task 1 always 10: any resample within tasks keeps the mean at exactly 5
    table = np.column_stack([np.zeros(8), np.full(8, 10.0)])
    assert stats.stratified_bootstrap((table,), lambda s: float(s.mean()), reps=50) == (5.0, 5.0, 5.0)
    # a variable table gets a real interval
    spread = np.arange(20.0)[:, None]
    _, low, high = stats.stratified_bootstrap((spread,), lambda s: float(s.mean()), reps=400)
    assert 5 < low < 9.5 < high < 14


@pytest.mark.parametrize("shape", [(10, 1), (7, 3), (5, 6)])
def test_the_batched_bootstrap_gives_the_intervals_of_one_call_per_resample(shape: tuple[int, int]) -> None:
    rng = np.random.default_rng(11)
    x, y = rng.normal(0.0, 3.0, shape), rng.normal(0.5, 3.0, (shape[0] + 2, shape[1])).round(0)
    x[0] = y[0].copy()  # ties
    for mats, func, batch in (((x,), stats.iqm, stats.iqm_batch),
                              ((x, y), stats.probability_of_improvement, stats.improvement_batch)):  # fmt: skip
        assert stats.stratified_bootstrap(mats, func, 300, batch=batch) == stats.stratified_bootstrap(mats, func, 300)


def test_the_screen_is_the_densest_demands_and_only_when_runs_are_left_for_the_finalists() -> None:
    cfg = TrainConfig(sim=SimConfig(steps=400, policy="dqn"), eval_steps=0,
                      dqn=dataclasses.replace(DQNConfig(), validation_t_ups=(2.0, 1.5, 1.0), validation_screen=2))
    assert selection.screen_t_ups(cfg) == (1.5, 1.0) and selection.screening(cfg)
    model = Path("m.pt")
    assert [c.seed for c in selection.validation_configs(cfg, model, screen=True)] == [
        c.seed for c in selection.validation_configs(cfg, model) if c.demand.t_up_s in (1.5, 1.0)]
    for n in (0, 3, 4):
        cfg = dataclasses.replace(cfg, dqn=dataclasses.replace(cfg.dqn, validation_screen=n))
        assert selection.screen_t_ups(cfg) == () and not selection.screening(cfg)


def test_a_selection_in_two_stages_runs_every_run_for_the_best_screened_alone(tmp_path: Path,
                                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """In SUMO (issue 77): 600 steps, snapshots at 200, 400 and 600 screened on the runs of T_up 1 s (free flow and
    the accident), the best 2 then validated on every run, model.pt the best of those; a screening run is the same
    run, to the bit, as in the full validation, and a finalist's full validation takes its screening runs from the
    validation process instead of running them again, with the same result."""
    dq = dataclasses.replace(DQNConfig(), select_every_steps=200, validation_steps=100, validation_t_ups=(1.5, 1.0),
                             validation_accident_steps=600, validation_screen=1)  # fmt: skip
    cfg = TrainConfig(sim=SimConfig(steps=600, seed=3, policy="dqn"), eval_steps=0, dqn=dq)
    summary = train(cfg, tmp_path / "two", progress=False)
    folders = [selection.snapshot_dir(tmp_path / "two", step) for step in (200, 400, 600)]
    screened = [selection.result(d, selection.SCREEN) for d in folders]
    assert all([(x["t_up_s"], x["accident"]) for x in r["runs"]] == [(1.0, False), (1.0, True)]
               for r in screened if r is not None)  # fmt: skip
    order = sorted(screened, key=lambda r: (-r["score"], r["step"]))  # type: ignore[index]
    final = {r["step"] for r in order[:2]}  # type: ignore[index]
    assert {r["step"] for d in folders if (r := selection.result(d)) is not None} == final
    full = selection.results(tmp_path / "two")
    assert summary["selected_step"] == max(full, key=lambda r: (r["score"], -r["step"]))["step"]
    for r in full:
        screen = next(s for s in screened if s is not None and s["step"] == r["step"])
        assert [x for x in r["runs"] if x["t_up_s"] == 1.0] == screen["runs"]
    table = pd.read_csv(tmp_path / "two" / "validation.csv")
    assert list(table["step"]) == [200, 400, 600] and sorted(table["stage"]) == ["all", "all", "screen"]
    assert table.loc[table["best"], "step"].tolist() == [summary["selected_step"]]
    step = summary["selected_step"]  # again by hand: a finalist's full validation runs only what screening did not
    shutil.copytree(selection.snapshot_dir(tmp_path / "two", step), selection.snapshot_dir(tmp_path / "again", step))
    kept: selection.Kept = {}
    folder = selection.request(tmp_path / "again", cfg, step, screen=True)
    assert selection.validate(folder, kept) == screened[[200, 400, 600].index(step)]
    ran = []
    real_run = selection.validate_run
    monkeypatch.setattr(selection, "validate_run", lambda *a: ran.append(a[0].seed) or real_run(*a))
    selection.request(tmp_path / "again", cfg, step)
    assert selection.validate(folder, kept) == selection.result(selection.snapshot_dir(tmp_path / "two", step))
    assert sorted(ran) == [dq.validation_seed, dq.validation_seed + 2] and not kept  # T_up 1.5: free, accident
    assert selection.validate(folder) == selection.result(folder)  # every run afresh: the same


def test_a_training_that_differs_only_in_validation_is_reselected_not_trained(tmp_path: Path,
                                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """In SUMO: the store holds a training validated in free flow; asking for the same training validated through an
    accident too trains nothing (its snapshots are validated again into their own folder), leaves the stored one
    as it was, and the new folder is a whole model of its own configuration that a third ask takes as it is."""
    from coopsumo.studies.engine import model_store
    from coopsumo.studies.engine.trainings import finished_training

    dq = dataclasses.replace(DQNConfig(), select_every_steps=200, validation_steps=100, validation_t_ups=(1.5,),
                             train_t_ups=(), accident_share=0.0, validation_accident_steps=0)  # fmt: skip
    free = TrainConfig(sim=SimConfig(steps=400, seed=3, policy="dqn"), eval_steps=0, dqn=dq)
    both = dataclasses.replace(free, dqn=dataclasses.replace(dq, validation_accident_steps=600))
    store = tmp_path / "models"
    model_store.train_shared(free, tmp_path / "a", store)
    src = store / model_store.model_id(to_dict(free))
    before = {p.name: p.read_bytes() for p in (src / "snapshots").rglob("*") if p.is_file()}

    def no_training(*_: object) -> None:
        raise AssertionError("trained")

    monkeypatch.setattr(model_store, "train_resuming", no_training)
    summary, resumed = model_store.train_shared(both, tmp_path / "b", store)
    dst = store / model_store.model_id(to_dict(both))
    assert dst != src and resumed is None and summary["reselected_from"] == src.name
    assert {p.name: p.read_bytes() for p in (src / "snapshots").rglob("*") if p.is_file()} == before
    assert finished_training(dst, to_dict(both)) is not None and finished_training(src, to_dict(free)) is not None
    assert (dst / "train_log.csv").read_bytes() == (src / "train_log.csv").read_bytes()
    last = _weights(dst / selection.LAST_MODEL), _weights(src / selection.LAST_MODEL)
    assert all(torch.equal(last[0][k], last[1][k]) for k in last[0])
    results = selection.results(dst)
    assert [r["step"] for r in results] == [200, 400]
    assert all([x["accident"] for x in r["runs"]] == [False, True] for r in results)
    assert summary["selected_step"] == selection.best(results)["step"]  # type: ignore[index]
    chosen = _weights(dst / "model.pt")
    snap = _weights(selection.snapshot_dir(src, summary["selected_step"]) / "model.pt")
    assert all(torch.equal(chosen[k], snap[k]) for k in chosen)
    monkeypatch.undo()  # train_resuming returns a whole stored training as it is
    stamp = (dst / "model.pt").stat().st_mtime_ns
    assert model_store.train_shared(both, tmp_path / "c", store)[0] == summary
    assert (dst / "model.pt").stat().st_mtime_ns == stamp  # neither trained nor judged again
