"""Robust statistics of scores over seeds (rliable's estimators, Agarwal et al. 2021, in NumPy):
interquartile mean (IQM), percentile stratified-bootstrap confidence intervals, probability of
improvement and performance profiles. Scores are unitless (P/Pmax or P/P_best); a score matrix is
(runs, tasks): seeds x modes or levels.
"""

from __future__ import annotations

import numpy as np

REPS = 2000  # bootstrap resamples
CONFIDENCE = 0.95
SEED = 0  # the bootstrap's generator seed: every report's intervals are reproducible
NOTE = (
    "IQM: interquartile mean, the mean of the middle 50 % of the scores (25 % cut at each end); "
    f"[lo, hi]: its {100 * CONFIDENCE:.0f} % percentile stratified-bootstrap confidence interval "
    f"({REPS:,} resamples of the seeds, within each task; rliable's estimators)."
)


def _matrix(scores, name: str = "scores") -> np.ndarray:
    """``scores`` as a (runs, tasks) float array: a 1-D array is one task."""
    x = np.asarray(scores, float)
    x = x[:, None] if x.ndim == 1 else x
    if x.ndim != 2 or x.shape[0] < 1 or x.shape[1] < 1:
        raise ValueError(
            f"{name} must be a non-empty (runs,) or (runs, tasks) array, got shape "
            f"{np.shape(scores)}"
        )
    return x


def iqm(scores) -> float:
    """Interquartile mean over every run and task: the mean after cutting int(25 % of n) scores at
    each end (scipy's ``trim_mean(scores, 0.25, axis=None)``, rliable's ``aggregate_iqm``)."""
    x = np.sort(_matrix(scores).ravel())
    cut = int(0.25 * x.size)
    return float(x[cut : x.size - cut].mean())


def bootstrap_ci(
    scores, statistic=iqm, reps: int = REPS, confidence: float = CONFIDENCE, seed: int = SEED
):
    """(point estimate, lo, hi) of ``statistic`` (a function of a (runs, tasks) matrix): percentile
    interval of its values on ``reps`` stratified bootstrap resamples, each task's runs resampled
    with replacement."""
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    if int(reps) < 1:
        raise ValueError(f"reps must be an integer >= 1, got {reps!r}")
    x = _matrix(scores)
    samples = _resamples(x, reps, seed)
    if statistic is iqm:  # all resamples at once
        flat = np.sort(samples.reshape(len(samples), -1), axis=1)
        cut = int(0.25 * flat.shape[1])
        values = flat[:, cut : flat.shape[1] - cut].mean(axis=1)
    else:
        values = np.array([statistic(sample) for sample in samples])
    tail = 100 * (1 - confidence) / 2
    lo, hi = np.percentile(values, [tail, 100 - tail])
    return float(statistic(x)), float(lo), float(hi)


def _resamples(x: np.ndarray, reps: int, seed: int) -> np.ndarray:
    """(reps, runs, tasks): each task's runs drawn with replacement, independently per task
    (stratified)."""
    runs, tasks = x.shape
    idx = np.random.default_rng(seed).integers(0, runs, size=(int(reps), runs, tasks))
    return x[idx, np.arange(tasks)]


def probability_of_improvement(scores_x, scores_y) -> float:
    """P(X > Y) + P(X = Y) / 2 for a random run of X and one of Y on the same task, averaged over
    tasks (the Mann-Whitney U statistic over n_x n_y per task; rliable's
    ``probability_of_improvement``)."""
    x, y = _matrix(scores_x, "scores_x"), _matrix(scores_y, "scores_y")
    if x.shape[1] != y.shape[1]:
        raise ValueError(
            f"scores_x and scores_y must have as many tasks, got {x.shape[1]} and {y.shape[1]}"
        )
    a, b = x[:, None, :], y[None, :, :]
    return float(np.mean(np.mean((a > b) + 0.5 * (a == b), axis=(0, 1))))


def performance_profile(scores, taus) -> np.ndarray:
    """The score distribution: for each threshold tau, the fraction of all (run, task) scores above
    tau."""
    x = _matrix(scores).ravel()
    return np.array([np.mean(x > t) for t in np.asarray(taus, float)])


def profile_ci(scores, taus, reps: int = REPS, confidence: float = CONFIDENCE, seed: int = SEED):
    """(profile, lo, hi) arrays over ``taus``: the performance profile and its percentile
    stratified-bootstrap band (the same resamples at every tau)."""
    x, taus = _matrix(scores), np.asarray(taus, float)
    samples = _resamples(x, reps, seed).reshape(int(reps), -1)
    values = (samples[:, :, None] > taus).mean(axis=1)
    tail = 100 * (1 - confidence) / 2
    lo, hi = np.percentile(values, [tail, 100 - tail], axis=0)
    return performance_profile(x, taus), lo, hi


def cell(scores) -> str:
    """``IQM [lo, hi]`` of one table cell's seeds, 3 decimals."""
    point, lo, hi = bootstrap_ci(scores)
    return f"{point:.3f} [{lo:.3f}, {hi:.3f}]"
