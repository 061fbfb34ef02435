"""Priors from numpyro distributions: truncated densities, sampling, files, analytic posteriors."""

from __future__ import annotations

import math

import jax
import numpy as np
import pytest

import jaxabc

dist = pytest.importorskip("numpyro.distributions")


def test_truncated_densities_are_normalised_and_sampled_by_them():
    prior = jaxabc.Independent(
        a=dist.Normal(1.0, 2.0),
        b=dist.LogNormal(0.0, 0.5),
        c=dist.LogUniform(0.01, 1.0),
        bounds={"a": (-1.0, 4.0), "b": (0.5, 3.0)},
        units={"a": "nm"},
    )
    np.testing.assert_allclose(prior.low, [-1.0, 0.5, 0.01])
    np.testing.assert_allclose(prior.high, [4.0, 3.0, 1.0], rtol=1e-6)
    assert prior.names == ("a", "b", "c") and prior.units == ("nm", "", "")
    # Each marginal integrates to one over its box (trapezoid on a fine grid, one call each).
    base = np.array([1.0, 1.0, 0.1], np.float32)
    for j, (lo, hi) in enumerate(zip(np.asarray(prior.low), np.asarray(prior.high), strict=True)):
        grid = np.linspace(lo, hi, 20001, dtype=np.float32)
        theta = np.repeat(base[None], grid.size, axis=0)
        theta[:, j] = grid
        joint = np.exp(np.asarray(prior.log_prob(theta), np.float64))
        others = np.prod([_marginal(prior, k, base[k]) for k in range(3) if k != j])
        assert np.trapezoid(joint / others, grid.astype(np.float64)) == pytest.approx(1.0, abs=2e-3)
    x = np.asarray(prior.sample(jax.random.key(0), 20000))
    assert np.all(prior.contains(x))
    # The truncated Normal's mean, from scipy, within 4 standard errors.
    from scipy.stats import truncnorm

    tn = truncnorm((-1.0 - 1.0) / 2.0, (4.0 - 1.0) / 2.0, loc=1.0, scale=2.0)
    assert abs(x[:, 0].mean() - tn.mean()) < 4 * tn.std() / math.sqrt(20000)
    # LogUniform: log10 uniform on [-2, 0].
    assert abs(np.log10(x[:, 2]).mean() + 1.0) < 4 * (2 / math.sqrt(12)) / math.sqrt(20000)
    assert float(prior.log_prob(np.array([5.0, 1.0, 0.1], np.float32))) == -np.inf


def _marginal(prior, j, x):
    d = list(prior.distributions.values())[j]
    lo, hi = float(prior.low[j]), float(prior.high[j])
    return math.exp(float(d.log_prob(x))) / (float(d.cdf(hi)) - float(d.cdf(lo)))


def test_bad_priors_get_clear_errors():
    # An unbounded support is cut at far quantiles (tests/test_unbounded_priors.py); the tail
    # left out must be small.
    with pytest.raises(ValueError, match="tail must be"):
        jaxabc.Independent(a=dist.Normal(0.0, 1.0), tail=0.5)
    with pytest.raises(ValueError, match="empty"):
        jaxabc.Independent(a=dist.LogNormal(0.0, 1.0), bounds={"a": (-3.0, 0.0)})
    with pytest.raises(ValueError, match="unknown parameters"):
        jaxabc.Independent(a=dist.Uniform(0.0, 1.0), bounds={"b": (0.0, 1.0)})
    with pytest.raises(ValueError, match="univariate"):
        jaxabc.Independent(a=dist.Normal(np.zeros(2), 1.0), bounds={"a": (-1.0, 1.0)})
    with pytest.raises(TypeError, match="numpyro distribution"):
        jaxabc.Independent(a=(0.0, 1.0))


def test_result_with_a_numpyro_prior_saves_and_loads(tmp_path):
    prior = jaxabc.Independent(
        a=dist.Normal(0.0, 1.0), b=dist.LogUniform(0.1, 10.0), bounds={"a": (-5.0, 5.0)}, units={"b": "zJ"}
    )
    x = np.asarray(prior.sample(jax.random.key(1), 50), np.float64)
    result = jaxabc.ABCResult.from_sample(x, np.ones(50), prior, algorithm="apmcabc")
    back = jaxabc.load(result.save(tmp_path / "r"))
    assert isinstance(back.prior, jaxabc.Independent) and back.prior.units == ("", "zJ")
    theta = np.array([[0.3, 2.0], [7.0, 1.0]], np.float32)
    np.testing.assert_allclose(back.prior.log_prob(theta), prior.log_prob(theta), rtol=1e-6)


def _normal_prior_abc_moments(observed: float, eps: float) -> tuple[float, float]:
    """theta ~ N(0, 1), x = theta + N(0, 1), accepted iff |x - observed| < eps: x ~ N(0, 2)
    restricted to the window and theta | x ~ N(x / 2, 1 / 2), so the ABC posterior has mean
    E[x | window] / 2 and variance 1 / 2 + Var(x | window) / 4."""
    from scipy.stats import truncnorm

    s = math.sqrt(2.0)
    x = truncnorm((observed - eps) / s, (observed + eps) / s, loc=0.0, scale=s)
    return x.mean() / 2.0, 0.5 + x.var() / 4.0


@pytest.mark.parametrize(
    "algorithm, z, options",
    [
        ("apmcabc", 4.0, dict(num_particles=2000, num_steps=6, alpha=0.1, acceptance_cutoff=0.03)),
        ("abcsubsim", 3.0, dict(num_particles=2000, p0=0.1, num_steps=2)),
    ],
)
def test_normal_prior_gives_the_analytic_posterior(algorithm, z, options):
    """With a N(0, 1) prior and observation 2 the posterior is N(1, 1/2) (a flat prior would give
    N(2, 1)): the importance weights (APMCABC) and the Metropolis ratio (ABCsubsim) must use the
    prior's density.  Checked within ``z`` Monte Carlo standard errors of the reported ESS; for
    ABCsubsim one level of chains of 10 (they mix) without the prior ratio in the moves gives a
    mean 3.3-4.4 standard errors too high on every one of 8 seeds."""
    from jaxabc import examples

    prior = jaxabc.Independent(mu=dist.Normal(0.0, 1.0), bounds={"mu": (-8.0, 8.0)})
    observed = 2.0
    result = jaxabc.run(
        algorithm, examples.gaussian_simulate, prior, np.array([observed]), distance="euclidean", seed=3, **options
    )
    mean, var = _normal_prior_abc_moments(observed, float(result.thresholds[-1]))
    ess = result.effective_sample_size()
    assert abs(result.bayes_estimate()[0] - mean) < z * math.sqrt(var / ess), (result.bayes_estimate(), mean, ess)
    assert abs(result.covariance()[0, 0] - var) < z * var * math.sqrt(2 / ess), (result.covariance(), var, ess)
    # The flat-prior answer (mean ~ 2) is far outside these errors.
    assert abs(result.bayes_estimate()[0] - observed) > 0.5
