"""Statistics over trained models (the unit of replication), with rliable (Agarwal et al., NeurIPS 2021).

Pure functions on arrays: a score matrix has one row per trained model and one column per task (an evaluation
condition); higher is better (negate a cost such as total time spent before calling); the bootstrap of every study.
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
    return float(iqm_batch(np.asarray(scores, float)[None])[0])


def iqm_batch(scores: np.ndarray) -> np.ndarray:
    """iqm of each (models x tasks) matrix of a (resamples x models x tasks) stack, computed as scipy's trim_mean
    computes it (the same partition of the flattened matrix, the mean of its middle)."""
    flat = np.asarray(scores, float).reshape(len(scores), -1)
    low = int(0.25 * flat.shape[1])
    high = flat.shape[1] - low
    return np.partition(flat, (low, high - 1), axis=1)[:, low:high].mean(axis=1)


def stratified_bootstrap(scores: tuple[np.ndarray, ...], func: Callable[..., float], reps: int = REPS,
                         seed: int = SEED,
                         batch: Callable[..., np.ndarray] | None = None) -> tuple[float, float, float]:  # fmt: skip
    """(func(*scores), low, high): the percentile interval of func over `reps` resamples in which, within each task
    (column), every matrix's runs (rows) are drawn with replacement: rliable's stratified bootstrap. batch: func of
    stacks of resamples (a leading resample axis) giving every resample's value at once, the same values as func.

    Written here because rliable's `library` cannot be imported beside pandas 3 (its dependency arch 7 fails on
    import, and arch 8 breaks rliable's bootstrap); rliable's `metrics` give the point values."""
    rng = np.random.default_rng(seed)
    mats = [np.asarray(s, float) for s in scores]
    # one draw per resample and matrix, in this order (the stream of every earlier version); per task its own draw
    draws = [[resample(rng, len(m), 1, *m.shape[1:]) for m in mats] for _ in range(reps)]
    idx = [np.concatenate(d) for d in zip(*draws, strict=True)]  # per matrix: (reps, runs, tasks)
    if batch is not None:
        values = batch(*(np.take_along_axis(m[None], i, axis=1) for m, i in zip(mats, idx, strict=True)))
    else:
        values = np.array([func(*(np.take_along_axis(m, i[r], axis=0) for m, i in zip(mats, idx, strict=True)))
                           for r in range(reps)])  # fmt: skip
    return float(func(*mats)), *interval(values, (1 - CONFIDENCE) / 2)


def iqm_interval(scores: np.ndarray, reps: int = REPS) -> tuple[float, float, float]:
    """(IQM, low, high): the IQM with its stratified bootstrap interval (models resampled within each task)."""
    return stratified_bootstrap((scores,), iqm, reps, batch=iqm_batch)


def improvement(x: np.ndarray, y: np.ndarray, reps: int = REPS) -> tuple[float, float, float]:
    """(P, low, high): the probability that a run of x beats a run of y on a random task (ties count a half;
    rliable's probability_of_improvement), with its stratified bootstrap interval. x, y: (runs x tasks)."""
    return stratified_bootstrap((x, y), probability_of_improvement, reps, batch=improvement_batch)


def improvement_batch(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """probability_of_improvement of each pair of a stack of (runs x tasks) matrices (a leading resample axis)."""
    a, b = x[:, :, None, :], y[:, None, :, :]
    return ((a > b) + 0.5 * (a == b)).mean(axis=(1, 2)).mean(axis=1)


def probability_of_improvement(x: np.ndarray, y: np.ndarray) -> float:
    """P(X > Y) + P(X = Y) / 2 for a run X of x and a run Y of y on the same task, averaged over tasks: rliable's
    probability_of_improvement (its Mann-Whitney U statistic over runs), written in numpy for the bootstrap's
    thousands of calls; the tests check it against rliable."""
    return float(improvement_batch(np.asarray(x, float)[None], np.asarray(y, float)[None])[0])


def hierarchical_bootstrap(diff: np.ndarray, reps: int = REPS, seed: int = SEED,
                           confidence: float = CONFIDENCE) -> tuple[float, float, float]:  # fmt: skip
    """(mean, low, high) of a (models x evaluation seeds) table of paired differences: the percentile interval of
    hierarchical_replicates. (nan, nan, nan) without data."""
    point, values = hierarchical_replicates(diff, reps, seed)
    return point, *interval(values, (1 - confidence) / 2)


def hierarchical_replicates(diff: np.ndarray, reps: int = REPS, seed: int = SEED) -> tuple[float, np.ndarray]:
    """(mean, the `reps` bootstrap means) of a (models x evaluation seeds) table of paired differences, by a
    two-level bootstrap: each resample draws the models with replacement, then within each drawn model its
    evaluation seeds with replacement (Davison and Hinkley 1997, sec. 3.8). The mean weighs every model equally (the
    mean over models of each model's mean over its seeds). NaN entries are dropped per model; a model without a
    value is left out. One row (no model, e.g. two baselines) is the one-level bootstrap over seeds. (nan, no
    replicates) without data."""
    d = np.atleast_2d(np.asarray(diff, float))
    valid = np.isfinite(d)
    keep = valid.any(axis=1)
    d, valid = d[keep], valid[keep]
    if d.size == 0:
        return float("nan"), np.empty(0)
    counts = valid.sum(axis=1)
    values = [row[ok] for row, ok in zip(d, valid, strict=True)]  # each model's values, in order
    packed = np.array([np.pad(v, (0, d.shape[1] - len(v))) for v in values])  # then unused zeros
    point = float(np.mean([v.mean() for v in values]))
    models, seeds = resample_two_levels(np.random.default_rng(seed), counts, packed.shape[1], reps)
    drawn = packed[models[:, :, None], seeds]  # (reps, k, s): s draws among each drawn model's own values
    return point, drawn.mean(axis=2).mean(axis=1)


def resample(rng: np.random.Generator, n: int, reps: int, *tasks: int) -> np.ndarray:
    """`reps` resamples of range(n) with replacement, one rng.integers call: (reps, n), or by task (reps, n, *tasks)."""
    return rng.integers(0, n, size=(reps, n, *tasks))


def resample_two_levels(rng: np.random.Generator, counts: np.ndarray, width: int,
                        reps: int) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(models, seeds) of a two-level bootstrap: models (reps, k) draws the k models with replacement first; then
    seeds (reps, k, width) draws `width` times among each drawn model's counts[model] seeds."""
    models = resample(rng, len(counts), reps)
    seeds = np.floor(rng.random((reps, len(counts), width)) * counts[models][:, :, None]).astype(int)
    return models, seeds


def resampled_means(values: np.ndarray, reps: int, rng: np.random.Generator) -> np.ndarray:
    """The mean of each of `reps` resamples of the 1-D values (e.g. seed-paired differences): a one-level bootstrap."""
    return values[resample(rng, len(values), reps)].mean(axis=1)


def interval(replicates: np.ndarray, tail: float) -> tuple[float, float]:
    """The percentile interval of replicates: their `tail` and 1 - `tail` quantiles (0.025: 95%); NaN without any."""
    if np.size(replicates) == 0:
        return float("nan"), float("nan")
    low, high = np.quantile(replicates, [tail, 1 - tail])
    return float(low), float(high)


def bootstrap_p(replicates: np.ndarray) -> float:
    """Two-sided bootstrap p-value of an estimate against 0: twice the smaller tail's share, at most 1."""
    r = np.asarray(replicates, float)
    return min(1.0, 2.0 * min(float(np.mean(r <= 0)), float(np.mean(r >= 0))))


def models_needed(model_means: np.ndarray, confidence: float = CONFIDENCE) -> int | None:
    """About how many models a two-sided interval at `confidence` needs to exclude zero, if the mean difference and
    the spread between models stay as measured: (z sd / mean)^2. None when it cannot be said (fewer than 2 models,
    a zero mean)."""
    from scipy.stats import norm

    m = np.asarray(model_means, float)
    m = m[np.isfinite(m)]
    if len(m) < 2 or m.mean() == 0:
        return None
    z = float(norm.ppf(0.5 + confidence / 2))
    return max(int(np.ceil((z * m.std(ddof=1) / abs(m.mean())) ** 2)), len(m) + 1)
