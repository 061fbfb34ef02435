"""Shared fixtures: the analytic toy problems every algorithm is checked against."""

from __future__ import annotations

import os

# Tests run on the CPU with a predictable thread count, whatever the machine offers.
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax
import jax.numpy as jnp
import pytest

import jaxabc


def gaussian_simulate(key, theta):
    """x = theta + N(0, 1): with observation 0 and a wide flat prior the posterior is N(0, 1),
    and with |x| < eps the ABC posterior is N(0, 1) convolved with U(-eps, eps):
    mean 0, variance 1 + eps^2 / 3."""
    return theta + jax.random.normal(key, theta.shape)


CORR = 0.8
_CHOL = jnp.linalg.cholesky(jnp.array([[1.0, CORR], [CORR, 1.0]]))


def correlated_simulate(key, theta):
    """x = theta + L z, Cov(L z) = [[1, 0.8], [0.8, 1]]: with observation 0 the posterior is
    N(0, Sigma); with ||x|| < eps the ABC posterior covariance is Sigma + eps^2 / 4 I."""
    return theta + _CHOL @ jax.random.normal(key, (2,))


@pytest.fixture
def gaussian_problem():
    prior = jaxabc.Uniform(low=[-10.0], high=[10.0], names=("mu",))
    return prior, gaussian_simulate, jnp.array([0.0])


@pytest.fixture
def correlated_problem():
    prior = jaxabc.Uniform(low=[-10.0, -10.0], high=[10.0, 10.0], names=("a", "b"))
    return prior, correlated_simulate, jnp.array([0.0, 0.0])
