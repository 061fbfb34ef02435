import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from jaxabc import kernels


def test_weighted_covariance_matches_numpy():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(200, 3))
    w = rng.uniform(size=200)
    ours = kernels.weighted_covariance(jnp.asarray(x), jnp.log(jnp.asarray(w)))
    np.testing.assert_allclose(ours, np.cov(x, aweights=w, rowvar=False), rtol=1e-4, atol=1e-6)


def test_ess_and_quantile():
    lw = jnp.log(jnp.array([1.0, 1.0, 2.0]))
    assert float(kernels.effective_sample_size(lw)) == pytest.approx(1 / (0.0625 + 0.0625 + 0.25))
    x = jnp.arange(10.0)
    assert float(kernels.weighted_quantile(x, jnp.zeros(10), 0.5)) == 4.0
    # All the weight on the last point moves the median there.
    lw = jnp.where(jnp.arange(10) == 9, 0.0, -jnp.inf)
    assert float(kernels.weighted_quantile(x, lw, 0.5)) == 9.0


def test_truncated_sample_is_exact_truncated_normal():
    # 1-D truncated normal N(0.9, 0.5^2) on [0, 1]: a Kolmogorov-Smirnov test against scipy.
    mean, sd = 0.9, 0.5
    draw = kernels.truncated_gaussian_sample(
        jax.random.key(0), jnp.full((5000, 1), mean), jnp.array([[sd]]), jnp.array([0.0]), jnp.array([1.0])
    )
    x = np.asarray(draw.samples[:, 0], np.float64)
    assert bool(jnp.all(draw.ok))
    assert x.min() >= 0.0 and x.max() <= 1.0
    ref = stats.truncnorm((0 - mean) / sd, (1 - mean) / sd, loc=mean, scale=sd)
    assert stats.kstest(x, ref.cdf).pvalue > 0.01
    # No mass piled on the boundary (as clipping would do).
    assert np.mean(x == 1.0) == 0.0


def test_truncated_sample_reports_unreachable_support():
    draw = kernels.truncated_gaussian_sample(
        jax.random.key(1), jnp.array([[50.0]]), jnp.array([[0.01]]), jnp.array([0.0]), jnp.array([1.0]), max_tries=100
    )
    assert not bool(draw.ok[0])


def test_truncation_normalizer_exact_diagonal_and_mc_correlated():
    low, high = jnp.array([0.0, 0.0]), jnp.array([1.0, 1.0])
    means = jnp.array([[0.5, 0.5], [0.95, 0.1], [0.0, 0.0]])
    chol_diag = jnp.diag(jnp.array([0.3, 0.2]))
    got = np.exp(np.asarray(kernels.log_truncation_normalizer(jax.random.key(0), means, chol_diag, low, high)))
    m = np.asarray(means)
    want = np.prod(stats.norm.cdf((1 - m) / [0.3, 0.2]) - stats.norm.cdf((0 - m) / [0.3, 0.2]), axis=1)
    np.testing.assert_allclose(got, want, rtol=1e-4)
    cov = np.array([[0.09, 0.05], [0.05, 0.04]])
    chol = jnp.linalg.cholesky(jnp.asarray(cov))
    got = np.exp(np.asarray(kernels.log_truncation_normalizer(jax.random.key(0), means, chol, low, high, num_mc=8192)))
    z = np.random.default_rng(5).multivariate_normal([0, 0], cov, size=400_000)
    want = np.array([np.mean(np.all((mu + z >= 0) & (mu + z <= 1), axis=1)) for mu in m])
    # Binomial error of the 8192-draw estimate, 4 SE.
    se = np.sqrt(want * (1 - want) / 8192)
    assert np.all(np.abs(got - want) < 4 * se + 1e-3)


def test_mixture_log_weights_match_direct_sum():
    rng = np.random.default_rng(3)
    centers = rng.normal(size=(7, 2))
    lw = rng.normal(size=7)
    theta = rng.normal(size=(5, 2))
    cov = np.array([[0.5, 0.1], [0.1, 0.3]])
    chol = np.linalg.cholesky(cov)
    log_prior = np.full(5, -np.log(4.0))
    log_norm = np.log(rng.uniform(0.5, 1.0, size=7))
    ours = kernels.mixture_log_weights(
        jnp.asarray(theta),
        jnp.asarray(log_prior),
        jnp.asarray(centers),
        jnp.asarray(lw),
        jnp.asarray(chol),
        jnp.asarray(log_norm),
    )
    w = np.exp(lw) / np.exp(lw).sum()
    dens = np.array(
        [
            [stats.multivariate_normal(c, cov).pdf(t) / np.exp(ln) for c, ln in zip(centers, log_norm, strict=True)]
            for t in theta
        ]
    )
    want = log_prior - np.log(dens @ w)
    np.testing.assert_allclose(ours, want, rtol=1e-4)


def test_jit_and_nojit_agree():
    x = jax.random.normal(jax.random.key(4), (100, 3))
    lw = jax.random.normal(jax.random.key(5), (100,))
    np.testing.assert_allclose(
        jax.jit(kernels.weighted_covariance)(x, lw), kernels.weighted_covariance(x, lw), rtol=1e-5, atol=1e-6
    )
