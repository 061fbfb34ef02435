"""Measurement error and model discrepancy in jaxabc.run (noisy ABC; Wilkinson 2013, Kennedy &
O'Hagan 2001): exact answers on Gaussian problems, the wrappers' draws, refusals, resume."""

from __future__ import annotations

import pickle

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _misspecified import TAU, K, grid_posterior, k_values, mean_and_sd, observed

import jaxabc
import jaxabc.model_choice
from jaxabc import algorithms
from jaxabc.checkpoint import CheckpointError
from jaxabc.noise import (
    MeasurementError,
    ModelDiscrepancy,
    ResolvedDiscrepancy,
    observation_covariance,
    wrap_for_abc,
)

# ----------------------------------------------------------------------------- problems

S, M, Y = 1.0, 2.0, 1.0  # simulator sd, measurement sd, observation (1-D linear Gaussian)


def linear_gaussian(key, theta):
    """x = theta + N(0, S^2)."""
    return theta + S * jax.random.normal(key, theta.shape)


def deterministic(key, theta):
    """Two summaries with no noise of their own, NumPy or JAX alike: every draw in a run comes
    from the wrappers, so runs on different executors must agree."""
    del key
    return theta[:1] * np.array([1.0, 2.0])


PRIOR2 = jaxabc.Uniform([-3.0], [3.0])
OBS2 = np.array([0.4, 1.1])


def _moments(result, column=0):
    w, x = result.weights, result.particles[:, column]
    mean = float(w @ x)
    return mean, float(w @ (x - mean) ** 2)


# ----------------------------------------------------------------------------- noisy ABC


def test_noisy_apmcabc_posterior_variance_is_model_plus_measurement_variance():
    """Flat prior, x = theta + N(0, S^2), y measured with sd M: the exact posterior is
    N(y, S^2 + M^2) = N(1, 5); ignoring the error would give variance S^2 = 1."""
    prior = jaxabc.Uniform([-20.0], [20.0], names=("mu",))
    r = jaxabc.run(
        "apmcabc",
        linear_gaussian,
        prior,
        np.array([Y]),
        num_particles=2000,
        alpha=0.5,
        final_threshold=0.1,
        observation_error=M,
        seed=1,
    )
    assert r.metadata["executor"] == "fused"
    assert r.settings["observation_error"] == [[M**2]]
    mean, var = _moments(r)
    ess = float(r.ess[-1])
    assert ess > 300
    exact = S**2 + M**2 + r.thresholds[-1] ** 2 / 3  # the uniform ABC kernel adds eps^2 / 3
    # Monte Carlo sd of a variance estimate: var sqrt(2 / ESS) (about 0.24 here); 4 of them.
    assert abs(var - exact) < 4 * exact * np.sqrt(2 / ess), (var, exact, ess)
    assert abs(mean - Y) < 4 * np.sqrt(exact / ess), (mean, ess)


def test_diagonal_covariance_is_the_sd_form_draw_for_draw():
    keys = jax.random.split(jax.random.key(5), 64)
    theta = jnp.array([0.3], jnp.float32)
    sd = np.array([0.5, 1.5])
    by_sd = jax.vmap(MeasurementError(deterministic, sd), in_axes=(0, None))(keys, theta)
    by_cov = jax.vmap(MeasurementError(deterministic, cov=np.diag(sd**2)), in_axes=(0, None))(keys, theta)
    np.testing.assert_array_equal(np.asarray(by_sd), np.asarray(by_cov))
    # ... and through run: a per-summary sd and its diagonal covariance give the same particles.
    kw = dict(num_particles=30, threshold=1.0, max_simulations=2000, seed=2, executor="vmap")
    a = jaxabc.run("rejection", deterministic, PRIOR2, OBS2, observation_error=sd, **kw)
    b = jaxabc.run("rejection", deterministic, PRIOR2, OBS2, observation_error=np.diag(sd**2), **kw)
    np.testing.assert_array_equal(a.particles, b.particles)


CORRELATED = np.array([[1.0, 0.6, -0.3], [0.6, 2.0, 0.4], [-0.3, 0.4, 0.5]])


def _zero(key, theta):
    del key
    return jnp.zeros(3) * theta[0]


def ones(key, theta):
    del key
    return jnp.ones(3) * theta[0]


def _check_covariance(e, cov):
    n = len(e)
    emp = np.cov(e, rowvar=False)
    # Sampling sd of a covariance entry: sqrt((C_ii C_jj + C_ij^2) / n); 5 of them.
    se = np.sqrt((np.outer(np.diag(cov), np.diag(cov)) + cov**2) / n)
    assert np.all(np.abs(emp - cov) < 5 * se + 1e-9), (emp, cov)
    assert np.all(np.abs(e.mean(axis=0)) < 5 * np.sqrt(np.diag(cov) / n) + 1e-9)


def test_correlated_covariance_draws_errors_with_that_covariance():
    noisy = MeasurementError(_zero, cov=CORRELATED)
    keys = jax.random.split(jax.random.key(11), 20_000)
    e = np.asarray(jax.vmap(noisy, in_axes=(0, None))(keys, jnp.ones(1)), np.float64)
    _check_covariance(e, CORRELATED)
    # Host simulators (raw uint32[2] keys) get the same draws from the same keys.
    raw = np.asarray(jax.random.key_data(keys[:20]))
    host = np.stack([noisy(k, np.ones(1)) for k in raw])
    np.testing.assert_allclose(host, e[:20], rtol=1e-5, atol=1e-6)
    assert "cov=<3x3>" in noisy.__qualname__
    again = pickle.loads(pickle.dumps(noisy))
    assert again == noisy and hash(again) == hash(noisy)
    np.testing.assert_array_equal(again(raw[0], np.ones(1)), host[0])


def test_singular_covariance_uses_an_eigen_square_root():
    v = np.array([1.0, -2.0, 0.5])
    cov = np.outer(v, v)  # rank 1: positive semi-definite, no Cholesky factor
    noisy = MeasurementError(_zero, cov=cov)
    keys = jax.random.split(jax.random.key(12), 20_000)
    e = np.asarray(jax.vmap(noisy, in_axes=(0, None))(keys, jnp.ones(1)), np.float64)
    _check_covariance(e, cov)
    # Every draw lies on the line the covariance spans (float32 rounding aside).
    resid = e - np.outer(e @ v / (v @ v), v)
    assert np.abs(resid).max() < 1e-4 * np.abs(e).max()


def test_noisy_abc_is_reproducible_whatever_the_executor():
    """The wrappers draw from the simulation's key: a vmap run (typed keys, JAX) and a serial
    run (raw uint32[2] keys, NumPy) of the same seed keep the same particles, with an error
    covariance and a discrepancy.  (The fused path uses the vmap path's keys; the tests above
    and below run it.)"""
    prior = jaxabc.Uniform([-3.0], [3.0], names=("a",))
    kw = dict(
        num_particles=40,
        quantile=0.2,
        seed=4,
        observation_error=[[0.3, 0.1], [0.1, 0.2]],
        discrepancy=jaxabc.Discrepancy([0.5, 1.0]),
    )
    vmap = jaxabc.run("rejection", deterministic, prior, OBS2, executor="vmap", **kw)
    serial = jaxabc.run("rejection", deterministic, prior, OBS2, executor="serial", **kw)
    assert serial.metadata["executor"] == "serial"
    assert vmap.particles.shape == (40, 3)
    np.testing.assert_allclose(serial.particles, vmap.particles, rtol=1e-5, atol=1e-6)
    assert serial.prior.names == ("a", "discrepancy_sd[0]", "discrepancy_sd[1]")


# ----------------------------------------------------------------------------- discrepancy


def test_discrepancy_recovers_the_known_misspecification():
    """K values per simulation, theta + N(0, S_DISC^2); the data carry an extra N(0, TAU^2) per
    value.  With one discrepancy group over all K values, rejection ABC on the sufficient
    statistics gives the exact posterior of (theta, delta) (grid integration of the Gaussian
    likelihood) and a credible interval for delta that holds TAU.  A simulator that ignored
    delta would leave its posterior at the prior U[0, 2] (mean 1, sd 0.58) and fail."""
    y = observed(7)
    prior = jaxabc.Uniform([-1.0], [2.5], names=("theta",), units=("u",))
    r = jaxabc.run(
        "rejection",
        k_values,
        prior,
        y,
        num_particles=1000,
        quantile=0.005,
        distance=mean_and_sd,
        discrepancy=jaxabc.Discrepancy(2.0, {"all": list(range(K))}),
        seed=3,
    )
    assert r.prior.names == ("theta", "discrepancy_sd[all]")
    assert r.prior.units == ("u", "summary units")
    assert r.particles.shape == (1000, 2)
    assert r.settings["discrepancy"] == {"max_sd": 2.0, "groups": {"all": list(range(K))}}
    t, d, p = grid_posterior(y, (-1.0, 2.5), 2.0, (701, 401))
    for col, grid in ((0, t), (1, d)):
        mean, var = _moments(r, col)
        g_mean = float((p * grid).sum())
        g_sd = float(np.sqrt((p * (grid - g_mean) ** 2).sum()))
        # Posterior sds are about 0.2: Monte Carlo error of the mean 0.2 / sqrt(1000) = 0.006,
        # the tolerance (eps about 0.12 on statistics with sds 0.25 and 0.18) a few hundredths.
        assert abs(mean - g_mean) < 0.05, (col, mean, g_mean)
        assert abs(np.sqrt(var) - g_sd) < 0.25 * g_sd, (col, np.sqrt(var), g_sd)
    order = np.argsort(r.particles[:, 1])
    cdf = np.cumsum(r.weights[order])
    low, high = r.particles[order, 1][np.searchsorted(cdf, [0.05, 0.95])]
    assert low < TAU < high, (low, high)


def test_model_discrepancy_wrapper_adds_the_group_variances():
    resolved = jaxabc.Discrepancy([1.0, 3.0], {"a": [0], "b": [1, 2]}).resolve((3,))
    wrapped = ModelDiscrepancy(ones, resolved, 1)
    keys = jax.random.split(jax.random.key(2), 20_000)
    theta = jnp.array([2.0, 0.5, 1.5])
    e = np.asarray(jax.vmap(wrapped, in_axes=(0, None))(keys, theta), np.float64) - 2.0
    _check_covariance(e, np.diag([0.25, 2.25, 2.25]))
    np.testing.assert_array_equal(np.asarray(wrapped(keys[0], jnp.array([2.0, 0.0, 0.0]))), np.full(3, 2.0))
    raw = np.asarray(jax.random.key_data(keys[:5]))
    host = np.stack([wrapped(k, np.asarray(theta, np.float64)) for k in raw])
    np.testing.assert_allclose(host - 2.0, e[:5], rtol=1e-5, atol=1e-6)
    assert pickle.loads(pickle.dumps(wrapped)) == wrapped
    assert "discrepancy_sd[a]" in wrapped.__qualname__
    with pytest.raises(ValueError, match="expects 1 parameters and 2 discrepancy sds"):
        wrapped(keys[0], jnp.array([2.0, 0.5]))


def test_wrap_for_abc_augments_the_prior_and_composes_the_wrappers():
    prior = jaxabc.Uniform([0.0], [1.0], names=("k",), units=("1/s",))
    sim, aug = wrap_for_abc(linear_gaussian, prior, (2,), 0.1, jaxabc.Discrepancy(4.0, {"both": [0, 1]}))
    assert isinstance(sim, MeasurementError) and isinstance(sim.simulate, ModelDiscrepancy)
    assert aug.names == ("k", "discrepancy_sd[both]") and aug.units == ("1/s", "summary units")
    np.testing.assert_array_equal(np.asarray(aug.high), [1.0, 4.0])
    assert wrap_for_abc(linear_gaussian, prior, (2,), None, None) == (linear_gaussian, prior)


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "options, message",
    [
        (dict(observation_error=-0.1), "must be >= 0; negative at summaries"),
        (dict(observation_error=[0.1, 0.2, 0.3]), r"observation_error has shape \(3,\)"),
        (dict(observation_error=[[1.0, 2.0], [2.0, 1.0]]), "must be positive semi-definite"),
        (dict(observation_error=[[1.0, 0.5], [0.1, 1.0]]), "must be symmetric"),
        (dict(observation_error=np.nan), "must be finite"),
        (dict(discrepancy=jaxabc.Discrepancy(1.0, {"x": [0, 2]})), r"names summaries \[2\], which do not exist"),
        (dict(discrepancy=jaxabc.Discrepancy([1.0, 2.0, 3.0])), "has 3 values for 2 groups"),
    ],
)
def test_bad_error_or_discrepancy_is_refused(options, message):
    with pytest.raises(ValueError, match=message):
        jaxabc.run("rejection", deterministic, PRIOR2, OBS2, num_particles=10, quantile=0.5, **options)


def test_bad_discrepancy_objects_are_refused():
    with pytest.raises(ValueError, match="max_sd must be positive and finite"):
        jaxabc.Discrepancy(0.0)
    with pytest.raises(ValueError, match="max_sd must be positive and finite"):
        jaxabc.Discrepancy([1.0, -1.0])
    with pytest.raises(TypeError, match=r"must be a jaxabc\.Discrepancy"):
        jaxabc.run("rejection", deterministic, PRIOR2, OBS2, num_particles=10, quantile=0.5, discrepancy=1.0)
    named = jaxabc.Uniform([-3.0], [3.0], names=("discrepancy_sd[0]",))
    with pytest.raises(ValueError, match="already has parameters named"):
        jaxabc.run(
            "rejection", deterministic, named, OBS2, num_particles=10, quantile=0.5, discrepancy=jaxabc.Discrepancy(1.0)
        )
    with pytest.raises(ValueError, match="square matrix"):
        MeasurementError(deterministic, cov=np.ones((2, 3)))
    with pytest.raises(TypeError, match="exactly one"):
        MeasurementError(deterministic)


# ----------------------------------------------------------------------------- other paths


class _Built(Exception):
    pass


def test_builders_other_than_abc_get_the_options_unwrapped_or_refuse_them(monkeypatch):
    seen = {}

    def taking(prior, num_particles=10, *, observed, observation_error=None, discrepancy=None):
        seen.update(prior=prior, observation_error=observation_error, discrepancy=discrepancy)
        raise _Built

    def plain(prior, num_particles=10, *, observed):
        raise AssertionError("not reached")

    monkeypatch.setitem(algorithms.BUILDERS, "taking", taking)
    monkeypatch.setitem(algorithms.BUILDERS, "plain", plain)
    with pytest.raises(_Built):
        jaxabc.run("taking", deterministic, PRIOR2, OBS2, observation_error=0.5, discrepancy=jaxabc.Discrepancy(1.0))
    np.testing.assert_array_equal(seen["observation_error"], np.diag([0.25, 0.25]))
    assert isinstance(seen["discrepancy"], ResolvedDiscrepancy)
    assert seen["discrepancy"].names == ("discrepancy_sd[0]", "discrepancy_sd[1]")
    assert seen["prior"].dim == 1  # not augmented: the builder models the discrepancy itself
    with pytest.raises(ValueError, match="the plain in this version does not take observation_error"):
        jaxabc.run("plain", deterministic, PRIOR2, OBS2, observation_error=0.5)


def test_model_choice_gets_both_options_unchanged(monkeypatch):
    seen = {}

    def capture(models, simulate, prior, observed, num_particles, distance, options, **keywords):
        seen.update(keywords)
        return "done"

    monkeypatch.setattr(jaxabc.model_choice, "run_from_driver", capture)
    disc = jaxabc.Discrepancy(1.0)
    out = jaxabc.run(
        [(deterministic, PRIOR2), (deterministic, PRIOR2)], observed=OBS2, observation_error=0.3, discrepancy=disc
    )
    assert out == "done"
    assert seen["observation_error"] == 0.3 and seen["discrepancy"] is disc


# ----------------------------------------------------------------------------- checkpoints


def test_resume_with_a_changed_error_or_discrepancy_is_refused(tmp_path):
    kw = dict(num_particles=30, threshold=1.0, max_simulations=2000, seed=6, executor="vmap")
    err = [[0.3, 0.1], [0.1, 0.2]]
    full = jaxabc.run("rejection", deterministic, PRIOR2, OBS2, observation_error=err, **kw)
    jaxabc.run(
        "rejection",
        deterministic,
        PRIOR2,
        OBS2,
        observation_error=err,
        checkpoint_dir=tmp_path,
        stop_after_iterations=1,
        **kw,
    )
    for changed, field in (
        (dict(observation_error=0.3), "settings.observation_error"),
        (dict(observation_error=None), "settings.observation_error"),
        (dict(observation_error=err, discrepancy=jaxabc.Discrepancy(1.0)), "settings.discrepancy"),
    ):
        with pytest.raises(CheckpointError, match=field.replace(".", r"\.")):
            jaxabc.run("rejection", deterministic, PRIOR2, OBS2, checkpoint_dir=tmp_path, resume=True, **changed, **kw)
    # A simulator_id names the inner simulator only: the error still enters through the settings.
    ided = tmp_path / "ided"
    jaxabc.run(
        "rejection",
        deterministic,
        PRIOR2,
        OBS2,
        observation_error=err,
        checkpoint_dir=ided,
        stop_after_iterations=1,
        simulator_id="det",
        **kw,
    )
    with pytest.raises(CheckpointError, match="observation_error"):
        jaxabc.run(
            "rejection",
            deterministic,
            PRIOR2,
            OBS2,
            observation_error=0.4,
            checkpoint_dir=ided,
            resume=True,
            simulator_id="det",
            **kw,
        )
    rest = jaxabc.run(
        "rejection", deterministic, PRIOR2, OBS2, observation_error=err, checkpoint_dir=tmp_path, resume=True, **kw
    )
    np.testing.assert_array_equal(rest.particles, full.particles)
    assert rest.settings["observation_error"] == observation_covariance(err, (2,)).tolist()
