"""Small simulators with known answers: the README's first example and the test problems.

``gaussian``: ``x = theta + N(0, 1)``.  With the observation 0, a flat prior much wider than 1 and
the acceptance rule ``|x| < eps``, the ABC posterior is ``N(0, 1)`` convolved with
``U(-eps, eps)``: mean 0 and variance ``1 + eps^2 / 3`` (so it tends to the exact posterior
``N(0, 1)`` as ``eps -> 0``).

``correlated``: ``x = theta + L z`` with ``Cov(L z) = [[1, rho], [rho, 1]]``, ``rho = 0.8``.
With ``||x|| < eps`` the ABC posterior covariance is ``Sigma + eps^2 / 4 I`` (the covariance of
a uniform disc of radius ``eps`` is ``eps^2 / 4 I``), so its correlation is
``rho / (1 + eps^2 / 4)``.

The ``host_*`` variants do the same in NumPy (seeded from the key) for the process-pool and MPI
executors; ``flaky`` fails on purpose in every way an external program can.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.errors import SimulationFailure
from jaxabc.seeding import seed_from_key

__all__ = [
    "RHO",
    "correlated_abc_correlation",
    "correlated_simulate",
    "correlated_truth_and_data",
    "flaky_simulate",
    "gaussian_abc_variance",
    "gaussian_simulate",
    "host_gaussian_simulate",
]

RHO = 0.8
_CHOL = np.linalg.cholesky(np.array([[1.0, RHO], [RHO, 1.0]]))


def gaussian_simulate(key: jax.Array, theta: jax.Array) -> jax.Array:
    """``theta + N(0, 1)`` per component; shape (d,)."""
    return theta + jax.random.normal(key, theta.shape, theta.dtype)


def correlated_simulate(key: jax.Array, theta: jax.Array) -> jax.Array:
    """``theta + L z`` with correlation ``RHO``; theta shape (2,)."""
    return theta + jnp.asarray(_CHOL, theta.dtype) @ jax.random.normal(key, (2,), theta.dtype)


def correlated_truth_and_data(key: jax.Array, half_width: float = 6.0) -> tuple[jax.Array, jax.Array]:
    """An exact (truth, data) pair of the ``correlated`` example under a flat prior.

    The data uniform in ``[-half_width, half_width]^2``, then the truth from the exact posterior
    ``N(x, Sigma)``; with the prior box U[-10, 10]^2 and ``half_width`` 6 the box truncates the
    posterior with probability below 1e-4.  For :func:`jaxabc.coverage_study` (``sample_data``).
    """
    k1, k2 = jax.random.split(key)
    observed = jax.random.uniform(k1, (2,), minval=-half_width, maxval=half_width)
    return observed + jnp.asarray(_CHOL, observed.dtype) @ jax.random.normal(k2, (2,), observed.dtype), observed


def gaussian_abc_variance(eps: float) -> float:
    """Exact ABC posterior variance of the ``gaussian`` example at tolerance ``eps``."""
    return 1.0 + eps**2 / 3.0


def correlated_abc_correlation(eps: float) -> float:
    """Exact ABC posterior correlation of the ``correlated`` example at tolerance ``eps``."""
    return RHO / (1.0 + eps**2 / 4.0)


def host_gaussian_simulate(key: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """NumPy version of :func:`gaussian_simulate`, seeded from the task's key."""
    rng = np.random.default_rng(seed_from_key(key))
    return np.asarray(theta, np.float64) + rng.normal(size=np.shape(theta))


def flaky_simulate(key: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """A host simulator that misbehaves depending on ``theta[0]`` (prior ``U[0, 1]``).

    ``< 0.1`` raises :class:`SimulationFailure`; ``0.1-0.2`` returns NaN; ``0.2-0.25`` sleeps
    60 s (to be stopped by a timeout); ``0.25-0.3`` kills its own process (a crash);
    otherwise returns ``theta + N(0, 0.1)``.
    """
    t = float(theta[0])
    if t < 0.1:
        raise SimulationFailure(f"density {t * 100:.1f} kg/m3 below 500 kg/m3: the box vaporised")
    if t < 0.2:
        return np.full(np.shape(theta), np.nan)
    if t < 0.25:
        time.sleep(60)
    if t < 0.3:
        os._exit(9)
    rng = np.random.default_rng(seed_from_key(key))
    return np.asarray(theta, np.float64) + 0.1 * rng.normal(size=np.shape(theta))


def sleep_simulate(key: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """A host task that waits ``theta[0]`` seconds and returns ``(theta[0], finish time)``.

    Its duration is a known function of its parameter, which makes it the test case for
    duration-aware scheduling (:mod:`jaxabc.executors.scheduling`): the finish times show the order in
    which a single worker ran the tasks.
    """
    time.sleep(float(theta[0]))
    return np.array([float(theta[0]), time.time()])


def busy_child_simulate(key: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """A host task that starts a program keeping a core busy for ``theta[0]`` CPU seconds.

    Stands in for an external simulator (``gmx mdrun``, ``lmp``) in tests of CPU-time
    accounting: the cost is in a child process, not in the worker itself.
    """
    seconds = float(theta[0])
    code = f"import time\nt = time.process_time()\nwhile time.process_time() - t < {seconds!r}:\n    pass"
    subprocess.run([sys.executable, "-c", code], check=True)
    return np.array([seconds])
