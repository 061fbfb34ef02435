"""Shared fixtures: the analytic toy problems every algorithm is checked against."""

from __future__ import annotations

import functools
import gc
import os
import shutil
import subprocess
import sys

# Tests run on the CPU with a predictable thread count, whatever the machine offers.
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax
import jax.numpy as jnp
import pytest

import jaxabc


def _mpi_missing() -> str | None:
    if shutil.which("mpiexec") is None:
        return "mpiexec not found: apt-get install openmpi-bin libopenmpi-dev"
    # In a child: importing mpi4py.MPI initialises MPI, which the test process must not do.
    try:
        probe = subprocess.run([sys.executable, "-c", "import mpi4py.MPI"], capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        return "importing mpi4py.MPI hung for 120 s: check the Open MPI installation"
    if probe.returncode != 0:  # ImportError, or mpi4py built against a missing libmpi
        last = (probe.stderr.strip().splitlines() or ["no message"])[-1]
        return f"mpi4py unusable ({last}): pip install mpi4py"
    return None


# What each external-program marker needs; the function returns why the tests cannot run, or None.
_REQUIREMENTS = {
    "gromacs": lambda: None if shutil.which("gmx") else "GROMACS `gmx` not found: apt-get install gromacs",
    "lammps": lambda: None if shutil.which("lmp") else "LAMMPS `lmp` not found: apt-get install lammps",
    "mpi": _mpi_missing,
}


@pytest.fixture(scope="module", autouse=True)
def _free_compiled_programs():
    """Free each module's compiled programs when it ends.

    XLA:CPU maps every compiled program into the process; a full run keeps hundreds, and late in
    it (the water engine's large programs) mapping more failed: "LLVM compilation error: Cannot
    allocate memory" here (vm.max_map_count 65530), a segmentation fault inside jax's
    compilation-cache write on CI.  The persistent cache makes the recompilations cheap.
    """
    yield
    jax.clear_caches()
    gc.collect()


@pytest.fixture(autouse=True)
def _precision_is_left_as_found():
    """Fail the test that leaves JAX's default dtype changed.

    A process-wide ``jax_enable_x64`` switch (a benchmark's ``main`` run in-process did it)
    changed every later test: float64 priors whose ``np.asarray`` views are read-only, other
    random draws, a surrogate check failing 300 tests on.  The scoped ``jax.enable_x64(...)``
    leaves it as found.
    """
    before = jnp.zeros(()).dtype
    yield
    after = jnp.zeros(()).dtype
    if after != before:
        jax.config.update("jax_enable_x64", before == jnp.float64)
        pytest.fail(f"the test left JAX's default dtype {after} (was {before}): use the scoped jax.enable_x64(...)")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Skip tests marked ``gromacs``, ``lammps`` or ``mpi`` with a message saying what to install
    when the program is missing; each requirement is probed once, and only when a test needs it."""
    missing = {name: functools.cache(probe) for name, probe in _REQUIREMENTS.items()}
    for item in items:
        for name, probe in missing.items():
            if item.get_closest_marker(name) is not None and (reason := probe()):
                item.add_marker(pytest.mark.skip(reason=reason))


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
