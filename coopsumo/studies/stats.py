"""Statistics over trained models (the unit of replication), with rliable (Agarwal et al., NeurIPS 2021).

Pure functions on arrays: a score matrix has one row per trained model and one column per task (an evaluation
condition); higher is better (negate a cost such as total time spent before calling).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

REPS = 2000
"""bootstrap resamples"""
CONFIDENCE = 0.95
SEED = 20211206
"""seed of the bootstrap"""


def iqm(scores: np.ndarray) -> float:
    """Interquartile mean of every entry of the (models x tasks) matrix: the mean of the middle half, as
    rliable's aggregate_iqm (scipy's trim_mean cutting 25% at each end); the tests check it against rliable."""
    from scipy.stats import trim_mean

    return float(trim_mean(np.asarray(scores, float), proportiontocut=0.25, axis=None))


def stratified_bootstrap(scores: tuple[np.ndarray, ...], func: Callable[..., float], reps: int = REPS,
                         seed: int = SEED) -> tuple[float, float, float]:  # fmt: skip
    """(func(*scores), low, high): the percentile interval of func over `reps` resamples in which, within each task
    (column), every matrix's runs (rows) are drawn with replacement: rliable's stratified bootstrap.

    Written here because rliable's `library` cannot be imported beside pandas 3 (its dependency arch 7 fails on
    import, and arch 8 breaks rliable's bootstrap); rliable's `metrics` give the point values."""
    rng = np.random.default_rng(seed)
    mats = [np.asarray(s, float) for s in scores]
    values = np.empty(reps)
    for i in range(reps):
        drawn = []
        for m in mats:
            rows = rng.integers(0, m.shape[0], size=m.shape)  # per task (column) its own resample of the runs
            drawn.append(np.take_along_axis(m, rows, axis=0))
        values[i] = func(*drawn)
    tail = (1 - CONFIDENCE) / 2 * 100
    low, high = np.percentile(values, [tail, 100 - tail])
    return float(func(*mats)), float(low), float(high)


def iqm_interval(scores: np.ndarray, reps: int = REPS) -> tuple[float, float, float]:
    """(IQM, low, high): the IQM with its stratified bootstrap interval (models resampled within each task)."""
    return stratified_bootstrap((scores,), iqm, reps)


def improvement(x: np.ndarray, y: np.ndarray, reps: int = REPS) -> tuple[float, float, float]:
    """(P, low, high): the probability that a run of x beats a run of y on a random task (ties count a half;
    rliable's probability_of_improvement), with its stratified bootstrap interval. x, y: (runs x tasks)."""
    return stratified_bootstrap((x, y), probability_of_improvement, reps)


def probability_of_improvement(x: np.ndarray, y: np.ndarray) -> float:
    """P(X > Y) + P(X = Y) / 2 for a run X of x and a run Y of y on the same task, averaged over tasks: rliable's
    probability_of_improvement (its Mann-Whitney U statistic over runs), written in numpy for the bootstrap's
    thousands of calls; the tests check it against rliable."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    a, b = x[:, None, :], y[None, :, :]
    return float(((a > b) + 0.5 * (a == b)).mean(axis=(0, 1)).mean())
