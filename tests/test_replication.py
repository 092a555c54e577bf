"""The trained model as the unit of replication: the two-level bootstrap (pure) and the model store."""

from __future__ import annotations

import numpy as np

from coopsumo.studies import stats
from coopsumo.studies.scenario1_measures import paired_bootstrap


def _model_dominated() -> np.ndarray:
    """5 models x 5 evaluation seeds: the models differ a lot (their means 3, 2.5, -1.5, 2, -0.5), the seeds of one
    model little (+-0.1)."""
    rng = np.random.default_rng(7)
    means = np.array([3.0, 2.5, -1.5, 2.0, -0.5])
    return means[:, None] + rng.normal(0.0, 0.1, size=(5, 5))


def test_the_two_level_interval_includes_zero_where_the_one_level_one_does_not() -> None:
    table = _model_dominated()
    _, lo1, hi1 = paired_bootstrap(table.ravel())  # every run as if independent
    mean, lo2, hi2 = stats.hierarchical_bootstrap(table, reps=4000)
    assert lo1 > 0  # the one-level interval claims a difference
    assert lo2 < 0 < hi2  # the models' spread says it cannot be decided
    assert mean == np.mean(table.mean(axis=1))
    assert hi2 - lo2 > 2 * (hi1 - lo1)


def test_the_two_level_interval_narrows_when_models_agree() -> None:
    rng = np.random.default_rng(3)
    agree = 1.0 + rng.normal(0.0, 0.3, size=(5, 5))
    _, lo, hi = stats.hierarchical_bootstrap(agree, reps=2000)
    assert 0 < lo < 1 < hi


def test_one_row_is_the_bootstrap_over_seeds_and_nans_are_dropped() -> None:
    row = np.array([[1.0, 2.0, np.nan, 4.0]])
    mean, lo, hi = stats.hierarchical_bootstrap(row, reps=3000)
    assert mean == 7.0 / 3
    assert 1.0 <= lo < mean < hi <= 4.0
    assert np.isnan(stats.hierarchical_bootstrap(np.full((2, 3), np.nan))[0])
    # a model whose every value is missing is left out; the others weigh equally whatever their seed count
    mean, _, _ = stats.hierarchical_bootstrap(np.array([[1.0, 1.0, 1.0], [3.0, np.nan, np.nan], [np.nan] * 3]))
    assert mean == 2.0


def test_models_needed_grows_with_the_spread() -> None:
    assert stats.models_needed(np.array([1.0])) is None
    few = stats.models_needed(np.array([1.0, 1.2, 0.8]))
    many = stats.models_needed(np.array([3.0, -1.0, 2.0, -0.5]))
    assert few is not None and many is not None and few < many
    assert many >= 5  # more than the models there are
