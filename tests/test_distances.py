import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import gaussian_kde

from jaxabc import distances


def test_mean_abs_and_euclidean():
    a, b = jnp.array([1.0, 2.0, 3.0]), jnp.array([1.5, 2.0, 1.0])
    assert float(distances.mean_abs(a, b)) == pytest.approx(2.5 / 3)
    assert float(distances.euclidean(a, b)) == pytest.approx(np.sqrt(0.25 + 4.0))
    std = distances.standardized_euclidean(jnp.array([0.5, 1.0, 2.0]))
    assert float(std(a, b)) == pytest.approx(np.sqrt(1.0 + 1.0))


def test_kde_matches_scipy():
    x = np.random.default_rng(0).normal(size=300)
    grid = np.linspace(-4, 4, 50)
    ours = np.asarray(distances.gaussian_kde_density(jnp.asarray(x, jnp.float32), jnp.asarray(grid, jnp.float32)))
    np.testing.assert_allclose(ours, gaussian_kde(x)(grid), rtol=2e-4, atol=1e-6)


def test_kl_zero_for_same_series_and_positive_otherwise():
    x = jax.random.normal(jax.random.key(0), (500,))
    assert float(distances.kl_divergence(x, x)) == pytest.approx(0.0, abs=1e-6)
    assert float(distances.kl_divergence(x, x + 1.0)) > 0.2


def test_kl_estimates_gaussian_kl():
    # KL(N(0,1) || N(1,1)) = 0.5.  The KDE estimate from 4000 samples each is biased by the
    # bandwidth (it compares N(0, 1+h^2) with N(1, 1+h^2): 0.5 / (1 + h^2), h = 4000^-0.2 * 1)
    # and scattered by sampling (sd about 0.03, measured over seeds); check within 0.1.
    k1, k2 = jax.random.split(jax.random.key(1))
    x = jax.random.normal(k1, (4000,))
    y = jax.random.normal(k2, (4000,)) + 1.0
    h2 = 4000 ** (-0.4)
    assert float(distances.kl_divergence(x, y)) == pytest.approx(0.5 / (1 + h2), abs=0.1)


def test_kl_vmaps_and_is_nan_for_constant_series():
    obs = jax.random.normal(jax.random.key(2), (200,))
    sims = jax.random.normal(jax.random.key(3), (8, 200)) * jnp.arange(1, 9)[:, None]
    out = jax.vmap(distances.kl_divergence, in_axes=(None, 0))(obs, sims)
    assert out.shape == (8,) and bool(jnp.all(jnp.isfinite(out)))
    assert float(out[0]) < float(out[-1])
    assert not np.isfinite(float(distances.kl_divergence(obs, jnp.ones(200))))


def test_unknown_distance_name():
    with pytest.raises(ValueError, match="unknown distance 'manhattan'"):
        distances.get_distance("manhattan")
