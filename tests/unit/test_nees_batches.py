"""The consistency test of the benchmarks (``bench.synthetic.nees_over_batches``): the mean
NEES of correlated samples judged over independent batches."""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from bench.synthetic import nees_over_batches

DIMENSION = 6


def correlated_nees(rng: np.random.Generator, samples: int, rho: float, scale: float) -> np.ndarray:
    """NEES of ``samples`` errors of an AR(1) process (correlation ``rho`` from one to the
    next) whose covariance is the identity times ``scale``, judged against the identity: an
    honest covariance for ``scale`` 1, a conservative one below."""
    errors = np.empty((samples, DIMENSION))
    errors[0] = rng.standard_normal(DIMENSION)
    for k in range(1, samples):
        errors[k] = rho * errors[k - 1] + np.sqrt(1 - rho**2) * rng.standard_normal(DIMENSION)
    return scale * np.sum(errors**2, axis=1)


def batch_means(rng: np.random.Generator, batches: int, scale: float = 1.0) -> list[float]:
    return [float(correlated_nees(rng, 60, 0.9, scale).mean()) for _ in range(batches)]


def test_honest_correlated_samples_are_judged_consistent_about_95_percent_of_the_time() -> None:
    rng = np.random.default_rng(29)
    trials = 300
    covered_by_batches = sum(
        nees_over_batches(batch_means(rng, 12))["consistent"] for _ in range(trials)
    )
    # The same samples as if independent: one batch's chi-square interval.
    covered_as_independent = 0
    for _ in range(trials):
        values = correlated_nees(rng, 60, 0.9, 1.0)
        n = len(values)
        low, high = chi2.ppf(0.025, DIMENSION * n) / n, chi2.ppf(0.975, DIMENSION * n) / n
        covered_as_independent += low <= values.mean() <= high
    assert 0.90 * trials <= covered_by_batches <= 0.99 * trials
    assert covered_as_independent < 0.6 * trials  # far from the 95 % it claims


def test_a_conservative_covariance_is_found_with_enough_batches() -> None:
    rng = np.random.default_rng(30)
    found = sum(
        not nees_over_batches(batch_means(rng, 40, scale=0.8))["consistent"] for _ in range(50)
    )
    assert found >= 45


def test_fewer_than_two_batches_have_no_interval_and_missing_means_are_skipped() -> None:
    assert nees_over_batches([5.0]) is None
    assert nees_over_batches([None, 5.0]) is None
    result = nees_over_batches([5.0, None, 7.0])
    assert result["batch_means"] == [5.0, 7.0] and result["mean"] == 6.0
    assert result["interval_95"][0] < 6.0 < result["interval_95"][1]
