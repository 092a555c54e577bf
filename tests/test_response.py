"""Claim (b)'s primary measure (coopsumo/studies/scenario2/response.py): the slope of speed over log2(1 + alpha) per
condition, its bootstrap over models, and the paper's two trends with Holm's correction, on made-up evaluations
whose answer is known."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from coopsumo.studies.engine.stats import bootstrap_p
from coopsumo.studies.scenario2.plan import t_up_for
from coopsumo.studies.scenario2.response import (
    RESPONSE_ALPHAS,
    condition_responses,
    holm,
    model_scores,
    models_to_decide,
    response_x,
    slope,
    trends,
)

LOADS = (0.25, 0.5, 0.75, 1.0)


def made_up_evals(true_slope, lanes=(2, 3, 4), seeds=6, noise=0.05, seed=0) -> pd.DataFrame:
    """Evaluations of one model per lane count, alpha and seed, each driven at every load on 2 evaluation seeds;
    a model's speed is 20 + true_slope(lanes, load) x log2(1 + alpha) + its own offset + evaluation noise."""
    rng = np.random.default_rng(seed)
    rows = []
    for n in lanes:
        for a in (*RESPONSE_ALPHAS, 32.0):
            for s in range(1, seeds + 1):
                offset = rng.normal(0, noise)
                for q in LOADS:
                    for e in (2001, 2002):
                        v = 20 + true_slope(n, q) * response_x(a) + offset + rng.normal(0, noise / 2)
                        rows.append({"lanes": n, "t_up_s": t_up_for(n, q), "load": q, "policy": "dqn", "alpha": a,
                                     "seed": s, "eval_seed": e, "full_road_speed_mps": float(v)})  # fmt: skip
    rows.append({"lanes": 2, "t_up_s": 4.0, "load": 0.25, "policy": "keep", "alpha": math.nan, "seed": math.nan,
                 "eval_seed": 2001, "full_road_speed_mps": 1.0})  # fmt: skip
    return pd.DataFrame(rows)


def _all(table: pd.DataFrame) -> set[tuple[int, float]]:
    return {(int(r.lanes), float(r.t_up_s)) for r in table.itertuples()}


def test_the_slope_is_least_squares_over_log2_one_plus_alpha() -> None:
    x = response_x([0, 1, 3, 7])
    assert x.tolist() == [0, 1, 2, 3]
    assert slope(x, 5 - 0.5 * x) == pytest.approx(-0.5)
    assert math.isnan(slope(np.ones(3), np.arange(3.0)))


def test_model_scores_average_a_models_evaluations_and_leave_out_alpha_32_and_baselines() -> None:
    scores = model_scores(made_up_evals(lambda n, q: 0.0), "full_road_speed_mps")
    assert set(scores["alpha"]) == set(RESPONSE_ALPHAS)
    assert len(scores) == 3 * len(RESPONSE_ALPHAS) * 6 * len(LOADS)


def test_noise_free_slopes_are_recovered_exactly_with_a_zero_width_interval() -> None:
    evals = made_up_evals(lambda n, q: -0.1 * n + 0.2 * q, noise=0.0)
    table = condition_responses(model_scores(evals, "full_road_speed_mps"), reps=200).table
    expected = [-0.1 * r.lanes + 0.2 * r.load for r in table.itertuples()]
    assert np.allclose(table["slope_mps"], expected)
    assert np.allclose(table["slope_low"], table["slope_high"])
    assert (table["models"] == 6).all() and len(table) == 12


def test_a_load_trend_in_the_papers_direction_holds_and_no_lane_trend_cannot_decide() -> None:
    responses = condition_responses(model_scores(made_up_evals(lambda n, q: -0.2 + 0.2 * q),
                                                 "full_road_speed_mps"), reps=1000)  # fmt: skip
    found = trends(responses, _all(responses.table))
    assert found["load"]["verdict"] == "holds" and found["load"]["low"] > 0
    assert found["lanes"]["verdict"] == "cannot decide" and found["lanes"]["low"] < 0 < found["lanes"]["high"]
    assert found["lanes"]["models_to_decide"] is None or found["lanes"]["models_to_decide"] > 6


def test_trends_against_the_paper_are_reported_reversed() -> None:
    responses = condition_responses(model_scores(made_up_evals(lambda n, q: -0.4 + 0.1 * n - 0.2 * q),
                                                 "full_road_speed_mps"), reps=1000)  # fmt: skip
    found = trends(responses, _all(responses.table))
    assert found["lanes"]["verdict"] == "reversed" and found["load"]["verdict"] == "reversed"


def test_the_trend_plane_uses_only_the_conditions_that_pass_the_gate() -> None:
    responses = condition_responses(model_scores(made_up_evals(lambda n, q: -0.2 + 0.2 * q),
                                                 "full_road_speed_mps"), reps=200)  # fmt: skip
    kept = {k for k in _all(responses.table) if k[0] != 4}
    assert trends(responses, kept)["n"] == 8
    assert "error" in trends(responses, {k for k in kept if k[0] == 2})  # one lane count spans no plane


def test_one_draw_per_lane_count_serves_all_its_loads() -> None:
    """A model offset shared by the loads moves every load's slope together in a replicate: the replicates of two
    loads of one lane count correlate, those of two lane counts do not."""
    responses = condition_responses(model_scores(made_up_evals(lambda n, q: 0.0, noise=0.3),
                                                 "full_road_speed_mps"), reps=2000)  # fmt: skip
    reps = responses.replicates
    assert np.corrcoef(reps[0], reps[1])[0, 1] > 0.8  # 2 lanes, loads 0.25 and 0.5
    assert abs(np.corrcoef(reps[0], reps[4])[0, 1]) < 0.1  # 2 lanes against 3 lanes


def test_holm_steps_down_over_the_two_trends() -> None:
    assert holm({"lanes": 0.01, "load": 0.08}) == {"lanes": True, "load": True}
    assert holm({"lanes": 0.06, "load": 0.08}) == {"lanes": False, "load": False}
    assert holm({"lanes": 0.2, "load": 0.04}) == {"lanes": False, "load": True}


def test_bootstrap_p_and_models_to_decide() -> None:
    assert bootstrap_p(np.array([1.0, 2.0, 3.0, -1.0])) == 0.5
    assert bootstrap_p(np.array([1.0, 2.0])) == 0.0
    assert models_to_decide(-0.035, -0.079, 0.009, 5) == 8
    assert models_to_decide(0.16, 0.10, 0.21, 5) is None
    assert models_to_decide(0.0, -1.0, 1.0, 5) is None
