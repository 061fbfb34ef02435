"""The sample-to-sample comparison of benchmarks/water_paper_samples.py against exact answers."""

from __future__ import annotations

import math

import numpy as np

from benchmarks.water_paper_samples import energy_distance, weighted_moments


def test_weighted_moments_with_equal_weights_are_the_sample_moments() -> None:
    rng = np.random.default_rng(0)
    x = rng.multivariate_normal([1.0, -2.0], [[1.0, 0.6], [0.6, 2.0]], size=500)
    m = weighted_moments(x, np.ones(500))
    assert np.allclose(m["mean"], x.mean(axis=0))
    assert np.allclose(m["sd"], x.std(axis=0, ddof=1))
    assert math.isclose(m["correlation"], np.corrcoef(x.T)[0, 1])
    assert math.isclose(m["ess"], 500.0)


def test_integer_weights_equal_repeated_draws() -> None:
    x = np.array([[0.0, 1.0], [1.0, 3.0], [2.0, 2.0]])
    w = np.array([1.0, 2.0, 1.0])
    repeated = np.repeat(x, [1, 2, 1], axis=0)
    assert math.isclose(energy_distance(x, w, repeated, np.ones(4)), 0.0, abs_tol=1e-12)
    assert np.allclose(weighted_moments(x, w)["mean"], repeated.mean(axis=0))


def test_energy_distance_of_shifted_gaussians_matches_the_exact_value() -> None:
    """1-D N(0, 1) against N(d, 1): 2 E|X - Y| - E|X - X'| - E|Y - Y'| with X - Y ~ N(-d, 2)."""
    d, n = 1.0, 2000
    rng = np.random.default_rng(1)
    x, y = rng.normal(0.0, 1.0, (n, 1)), rng.normal(d, 1.0, (n, 1))
    s = math.sqrt(2.0)
    mean_abs = s * math.sqrt(2 / math.pi) * math.exp(-(d**2) / (2 * s**2)) + d * math.erf(d / (s * math.sqrt(2)))
    exact = 2 * mean_abs - 2 * s * math.sqrt(2 / math.pi)
    got = energy_distance(x, np.ones(n), y, np.ones(n))
    # Its Monte Carlo sd at n = 2000 is 0.031 (30 seeds); the V-statistic's bias, about 2.3 / n, is far less.
    assert abs(got - exact) < 4 * 0.031, (got, exact)
    assert energy_distance(x, np.ones(n), x + 3.0, np.ones(n)) > exact + 4 * 0.031


def test_the_null_grows_as_the_paper_sample_loses_effective_size() -> None:
    """Under the null the paper-like sample is drawn from ours: a sample actually drawn so lies inside
    it, a shifted one outside, and fewer effective particles widen it (about 1 / ESS)."""
    from benchmarks.water_paper_samples import null_energy_distance

    rng = np.random.default_rng(2)
    x, w = rng.normal(size=(1000, 2)), np.ones(1000)
    flat, skewed = np.ones(100), np.r_[np.full(10, 9.0), np.ones(90)]  # Kish ESS 100 and about 24
    null_flat = null_energy_distance(x, w, flat, rng)
    null_skewed = null_energy_distance(x, w, skewed, rng)
    assert 2.0 < null_skewed["median"] / null_flat["median"] < 8.0
    y = x[rng.choice(1000, 100)]
    assert energy_distance(x, w, y, flat) <= null_flat["q95"]
    assert energy_distance(x, w, y + 1.0, flat) > null_flat["q95"]
