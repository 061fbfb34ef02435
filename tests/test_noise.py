"""jaxabc.noise.MeasurementError: Gaussian measurement error added to simulated summaries."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from jaxabc.noise import MeasurementError

SD = np.array([0.0, 0.5, 2.0])


def jax_simulate(key, theta):
    return theta * np.ones(3)


def host_simulate(key, theta):
    return np.array([theta[0], theta[0], np.nan])


def test_the_error_has_the_stated_sd_under_vmap_and_is_fixed_by_the_key():
    noisy = MeasurementError(jax_simulate, SD)
    keys = jax.random.split(jax.random.key(0), 4000)
    out = np.asarray(jax.vmap(noisy, in_axes=(0, None))(keys, np.array([1.5], np.float32)))
    e = out - 1.5
    assert np.all(e[:, 0] == 0.0)
    # sd of a sample sd of n normals is sd / sqrt(2 (n - 1)); four of those.
    tol = 4.0 * SD[1:] / np.sqrt(2 * (len(e) - 1))
    assert np.all(np.abs(e[:, 1:].std(axis=0, ddof=1) - SD[1:]) < tol)
    assert np.all(np.abs(e[:, 1:].mean(axis=0)) < 4.0 * SD[1:] / np.sqrt(len(e)))
    np.testing.assert_array_equal(np.asarray(noisy(keys[7], np.array([1.5], np.float32))), out[7])


def test_host_simulators_get_the_error_from_raw_keys_and_failures_stay_failed():
    noisy = MeasurementError(host_simulate, SD)
    raw = np.asarray(jax.random.key_data(jax.random.key(3)))
    a, b = noisy(raw, np.array([1.0])), noisy(raw, np.array([1.0]))
    np.testing.assert_array_equal(a, b)
    assert a[0] == 1.0 and a[1] != 1.0 and np.isnan(a[2])
    other = noisy(np.asarray(jax.random.key_data(jax.random.key(4))), np.array([1.0]))
    assert other[1] != a[1]
    assert "sd=[0.0, 0.5, 2.0]" in noisy.__qualname__


def test_bad_measurement_sd_is_refused():
    with pytest.raises(ValueError, match="finite and >= 0"):
        MeasurementError(host_simulate, [0.1, -1.0, 0.0])
    with pytest.raises(ValueError, match="shape"):
        MeasurementError(host_simulate, [0.1, 0.2])(np.zeros(2, np.uint32), np.array([1.0]))
    with pytest.raises(TypeError):
        MeasurementError("not a function", 0.1)
