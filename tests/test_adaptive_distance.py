"""The adaptive weighted p-norm (Prangle 2017) on apmcabc and pmcabc.

The accuracy problem: theta = (a, b) with a uniform prior on [-5, 5]^2 and summaries
``(a + e1, SCALE (b + e2))``, ``e ~ N(0, 1)``.  The exact posterior of ``a`` is N(a_obs, 1)
truncated to [-5, 5].  A plain Euclidean distance is dominated by the second summary, so ``a``
is barely constrained; the adaptive norm weighs each summary by ``1 / MAD`` and recovers it.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats

import jaxabc
from jaxabc import distances
from jaxabc.driver.fused import run_fused

SCALE = 1000.0
OBSERVED = np.array([0.7, -0.4 * SCALE])
BOX = 5.0


def _simulate(key, theta):
    e = jax.random.normal(key, (2,), theta.dtype)
    return jnp.stack([theta[0] + e[0], SCALE * (theta[1] + e[1])])


def _prior():
    return jaxabc.Uniform([-BOX, -BOX], [BOX, BOX], names=("a", "b"))


def _exact_a() -> tuple[float, float]:
    """Mean and sd of N(a_obs, 1) truncated to the prior box."""
    a_obs = OBSERVED[0]
    post = scipy.stats.truncnorm(-BOX - a_obs, BOX - a_obs, loc=a_obs, scale=1.0)
    return float(post.mean()), float(post.std())


def _weighted_moments(result) -> tuple[np.ndarray, np.ndarray, float]:
    w, x = result.weights, result.particles
    mean = w @ x
    sd = np.sqrt(w @ (x - mean) ** 2)
    return mean, sd, 1.0 / float(np.sum(w**2))


# ----------------------------------------------------------------------------- pieces


def test_weighted_pnorm_matches_numpy():
    rng = np.random.default_rng(0)
    x, y, w = rng.normal(size=5), rng.normal(size=5), rng.uniform(0.1, 3.0, 5)
    for p in (1.0, 2.0, 3.0):
        ours = float(distances.weighted_pnorm(jnp.asarray(x), jnp.asarray(y), jnp.asarray(w), p))
        assert ours == pytest.approx(np.sum(np.abs(w * (y - x)) ** p) ** (1 / p), rel=1e-5)


def test_mad_scales_match_scipy_and_skip_invalid_rows():
    rng = np.random.default_rng(1)
    s = rng.normal(size=(101, 3)) * np.array([1.0, 10.0, 1e3])
    valid = rng.uniform(size=101) < 0.8
    s[3] = np.nan  # a failed simulation: dropped whatever ``valid`` says
    valid[3] = True
    ours = np.asarray(distances.mad_scales(jnp.asarray(s), jnp.asarray(valid)))
    keep = valid & np.all(np.isfinite(s), axis=1)
    expected = scipy.stats.median_abs_deviation(s[keep], axis=0)
    np.testing.assert_allclose(ours, expected, rtol=1e-5)


def test_constant_summary_gets_zero_weight():
    s = np.column_stack([np.arange(10.0), np.full(10, 3.0)])
    w = np.asarray(distances.adaptive_weights(jnp.asarray(s), jnp.ones(10, bool)))
    assert w[1] == 0.0
    assert w[0] == pytest.approx(1.0 / scipy.stats.median_abs_deviation(s[:, 0]))


# ----------------------------------------------------------------------------- refusals


def test_non_flat_observed_is_refused():
    prior = _prior()

    def simulate(key, theta):
        return _simulate(key, theta).reshape(1, 2)

    with pytest.raises(ValueError, match="flat vector"):
        jaxabc.run("apmcabc", simulate, prior, OBSERVED.reshape(1, 2), num_particles=20, distance="adaptive")


@pytest.mark.parametrize("algorithm", ["rejection", "abcsubsim"])
def test_other_algorithms_refuse_adaptive(algorithm):
    with pytest.raises(ValueError, match="apmcabc' and 'pmcabc"):
        jaxabc.run(algorithm, _simulate, _prior(), OBSERVED, num_particles=20, distance="adaptive", quantile=0.5)


def test_fused_path_refuses_adaptive():
    with pytest.raises(ValueError, match="run_fused"):
        run_fused("apmcabc", _simulate, _prior(), OBSERVED, num_particles=20, num_steps=2, distance="adaptive")


def test_bad_p_is_refused():
    with pytest.raises(ValueError, match="p >= 1"):
        distances.AdaptivePNorm(p=0.5)


# ----------------------------------------------------------------------------- resume


# apmcabc shares its configuration with the fast accuracy test, so one compilation serves both.
@pytest.mark.parametrize(
    ("algorithm", "options"),
    [("apmcabc", {"num_particles": 200, "alpha": 0.5}), ("pmcabc", {"num_particles": 60})],
)
def test_adaptive_run_resumes_identically(tmp_path, algorithm, options):
    kw: dict[str, Any] = dict(distance="adaptive", seed=3, num_steps=4, **options)
    full = jaxabc.run(algorithm, _simulate, _prior(), OBSERVED, **kw)
    jaxabc.run(algorithm, _simulate, _prior(), OBSERVED, checkpoint_dir=tmp_path, stop_after_iterations=2, **kw)
    rest = jaxabc.run(algorithm, _simulate, _prior(), OBSERVED, checkpoint_dir=tmp_path, resume=True, **kw)
    np.testing.assert_array_equal(full.particles, rest.particles)
    np.testing.assert_array_equal(full.weights, rest.weights)
    np.testing.assert_array_equal(full.thresholds, rest.thresholds)
    weights = np.asarray(full.diagnostics["distance_weights"])
    assert weights.shape == (len(full.thresholds), 2)
    np.testing.assert_array_equal(weights, np.asarray(rest.diagnostics["distance_weights"]))
    assert full.settings["adaptive_distance"] == {"p": 2.0, "scale": "mad"}


# ----------------------------------------------------------------------------- accuracy


def _check_adaptive_accuracy(result) -> None:
    """Posterior of ``a`` against the exact one, within Monte Carlo error and the ABC widening.

    Every kept particle has ``w_a |y_a - a_obs| <= threshold``, so given acceptance ``a`` is the
    accepted ``y_a`` (spread at most ``h = threshold / w_a``) plus N(0, 1) noise: the ABC
    posterior's variance lies in ``[1, 1 + h^2]``.
    """
    mean_exact, sd_exact = _exact_a()
    mean, sd, ess = _weighted_moments(result)
    weights = np.asarray(result.diagnostics["distance_weights"])
    h = result.thresholds[-1] / weights[-1, 0]
    widen = np.sqrt(1.0 + h**2)
    mc = 4.0 / np.sqrt(ess)
    assert abs(mean[0] - mean_exact) < mc * sd_exact * widen
    assert 1.0 - mc < sd[0] / sd_exact < widen * (1.0 + mc)
    # 1 / MAD of (a + e1) and SCALE (b + e2): the weight ratio tends to SCALE once the two
    # posteriors have similar spreads (each MAD estimated from at least a hundred draws).
    ratio = weights[1:, 0] / weights[1:, 1]
    assert np.all(np.abs(np.log(ratio / SCALE)) < 0.5), ratio
    assert abs(np.mean(np.log(ratio / SCALE))) < 0.2, ratio


@pytest.mark.slow
@pytest.mark.parametrize(
    ("algorithm", "options"),
    [("apmcabc", {"alpha": 0.5, "num_steps": 8}), ("pmcabc", {"num_steps": 6})],
)
def test_adaptive_recovers_small_scale_parameter(algorithm, options):
    kw: dict[str, Any] = dict(num_particles=400, seed=1, **options)
    plain = jaxabc.run(algorithm, _simulate, _prior(), OBSERVED, distance="euclidean", **kw)
    _, sd_plain, _ = _weighted_moments(plain)
    # Ranked by the large summary alone, ``a`` keeps most of its prior spread (sd 10 / sqrt 12).
    assert sd_plain[0] / _exact_a()[1] > 2.0
    _check_adaptive_accuracy(jaxabc.run(algorithm, _simulate, _prior(), OBSERVED, distance="adaptive", **kw))


def test_adaptive_apmc_recovers_small_scale_parameter_fast(tmp_path):
    r = jaxabc.run(
        "apmcabc", _simulate, _prior(), OBSERVED, num_particles=200, alpha=0.5, num_steps=6, distance="adaptive", seed=2
    )
    _check_adaptive_accuracy(r)
    # The weights travel with a saved result.
    r.save(tmp_path / "r.npz")
    back = jaxabc.load(tmp_path / "r.npz")
    np.testing.assert_array_equal(
        np.asarray(back.diagnostics["distance_weights"]), np.asarray(r.diagnostics["distance_weights"])
    )
