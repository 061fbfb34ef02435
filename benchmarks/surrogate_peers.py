"""The GP surrogate against the peers a user would pick instead: sbi, ELFI's BOLFI and pyABC.

Five problems with exact posteriors (the goal's), and an 8-parameter linear one and a
5-parameter nonlinear one for the scaling in dimension, the same simulation budgets for every method, one run.  For
each problem and seed ``s`` a truth ``theta*`` is drawn uniformly from a fixed inner region of the
prior box (generator seeded by ``s`` and the problem's name), ``x_obs`` is simulated from the
problem's own noise, and the exact posterior for ``x_obs`` (flat prior on the box) is drawn:

- ``linear`` (d = 2): ``x = theta + L z``, ``Cov(L z) = [[1, 0.8], [0.8, 1]]``, prior U[-10, 10]^2;
  exact ``N(x_obs, Cov)`` truncated to the box (rejection).
- ``banana`` (d = 2): ``x = (theta_1 + z_1, theta_2 + 0.5 (theta_1^2 - 1) + 0.5 z_2)``, prior
  U[-6, 6] x U[-12, 6]; exact by direct sampling, ``theta_1 ~ N(x_1, 1)``, then
  ``theta_2 ~ N(x_2 - 0.5 (theta_1^2 - 1), 0.5^2)``, truncated to the box (rejection).
- ``heteroscedastic`` (d = 2): ``x = theta + sd(theta) * (L z)`` with ``sd_j = 0.5 exp(0.25 theta_j)``
  and ``Corr(L z) = 0.5``, prior U[-6, 6]^2; exact by a two-stage grid (a 300^2 grid over the box
  finds the posterior's support, a 1000^2 grid over that region is sampled, jittered uniformly
  inside its cells).
- ``correlated5`` (d = 5): ``x = A theta + z``, ``A^T A`` the inverse of a covariance with sds
  (1, 0.5, 1.5, 0.8, 1.2) and AR(1) correlations 0.8 with alternating signs (|rho| 0.8 between
  neighbours), prior U[-10, 10]^5; exact ``N(A^-1 x_obs, (A^T A)^-1)`` truncated (rejection).
- ``correlated8`` (d = 8): the same with sds (1, 0.5, 1.5, 0.8, 1.2, 0.7, 1.3, 0.9); with ``linear``
  and ``correlated5`` it gives the scaling in dimension (2, 5, 8 parameters), not the goal.
- ``banana5`` (d = 5): the banana in five parameters, every later summary bent by the first,
  ``x_1 = theta_1 + z_1``, ``x_k = theta_k + b_k (theta_1^2 - 1) + s_k z_k`` with ``b = (0.5, 0.4,
  0.3, 0.5)``, ``s = (0.5, 0.4, 0.6, 0.5)``, prior U[-6, 6] x U[-12, 6]^4; the map from theta to the
  noise-free summaries has unit Jacobian, so the exact posterior is drawn directly as for ``banana``;
  with ``banana`` it gives the scaling in dimension on a nonlinear problem, not the goal.
- ``student`` (d = 2): ``x = theta + 0.7 L t``, ``t`` two independent Student-t with 3 degrees of
  freedom, ``Corr`` 0.5 in ``L``, prior U[-10, 10]^2; heavy-tailed, not elliptical; exact
  ``theta = x_obs - 0.7 L t`` (a location family under a flat prior), truncated (rejection).

The likelihoods, the NumPy simulators (run by the peers, and by this script for ``x_obs``) and
the direct exact samplers are written once, in the block between the ``problems: begin`` and
``problems: end`` markers below, which is shipped verbatim to the peers' child processes; the
JAX simulators that ``jaxabc.run`` calls mirror them (``tests/test_surrogate_peers.py`` checks
both against the likelihoods).  The exact posterior's mean and covariance come from 200 000
exact draws (the grid's weights for the grid problem); the metrics use 2000 further draws.

Methods, each with at most ``B`` simulations (``--budgets``), 1000 posterior draws, seed ``s``,
in its own process with one thread (``OMP/MKL/OPENBLAS_NUM_THREADS=1``, XLA's single-thread
flags, ``torch.set_num_threads(1)``); the peers in their own virtual environments, made by this
script with ``benchmarks/_venv.py``'s ``make_venv`` under ``--venv-dir`` (``venv-<peer>-<version>``;
sbi's installs ``torch==2.13.0`` first, so that pip takes the CPU wheel, then ``sbi==0.27.0``):

- ``jaxabc_surrogate``: ``jaxabc.run("surrogate", ...)`` (synthetic-likelihood mode, NUTS);
- ``jaxabc_surrogate_abc``: the same with ``mode="abc"`` (ABC on emulated summaries);
- ``sbi_npe`` / ``sbi_nle``: sbi 0.27.0 on torch 2.13.0 (CPU wheel), ``NPE`` (NPE-C, MAF) and
  ``NLE`` (NLE-A, MAF) trained once on ``B`` prior simulations with sbi's defaults except the
  training batch, ``min(50, max(10, B / 10))`` (sbi's 200 is one optimiser step per epoch at these
  budgets: on linear and banana, seeds 0-2, it left NPE's energy distance at B = 200 up to ten times
  larger); NLE's posterior drawn by sbi's ``slice_np_vectorized`` MCMC (20 chains, 200 warm-up
  steps, no thinning, ``resample`` init);
- ``sbi_snpe`` / ``sbi_snle``: the same in two rounds of ``B / 2`` (the second drawn from the
  first round's posterior; NPE-C's atomic loss corrects for the proposal); only for ``B >= 200``,
  recorded as skipped below;
- ``bolfi``: ELFI 0.8.8 ``BOLFI`` on the log Euclidean discrepancy (``min(10 d, B / 2)`` initial
  points, GP updated every 10, ``acq_noise_var`` 0.1), 4 NUTS chains of 1000 over the fitted GP
  (half warm-up); its posterior is its own ABC approximation at the GP's minimum discrepancy;
- ``pyabc_abcsmc``: pyABC 0.13.0 ``ABCSMC`` (Euclidean distance, adaptive median epsilon,
  population ``max(10, B / 4)``, single-core sampler), stopped by ``max_total_nr_simulations = B``
  (checked at generation ends, so it can overshoot: the simulations used are recorded).

Metrics, per (problem, budget, seed, method), in the exact posterior's standardised coordinates
(whitened with the exact mean and covariance, so numbers compare across problems): the energy
distance (U-statistic; 0 for equal laws) between the method's draws (at most 1000, resampled by
weight) and 2000 exact draws; the Mahalanobis error of the posterior mean in exact sd; each
parameter's sd over the exact sd; whether the truth lies in the method's central 90 % marginal
interval (per parameter and all at once), summarised over seeds as coverage; the simulations used;
the wall time of the run (imports excluded) and of its process (left out of the time summaries
for cells run with ``--cpu-shared``, beside other work).  The jaxabc children share JAX's
persistent compilation cache (``--cache-dir/xla``; ``--no-compilation-cache`` to compile afresh):
the same executables, so the same draws, but XLA compiles each shape once for the whole grid
rather than once per cell, as a user's second run would.  Each jaxabc cell records whether the
cache was on.  An ``exact`` row (1000 independent exact draws) gives the energy distance's floor
and the exact posterior's coverage.

Every finished cell (the method's draws and what it reported, or its error) is appended to
``--cache-dir/cells.jsonl``, keyed by (problem, method, budget, seed, the problem's numerical
fingerprint (:func:`problem_hash`: adding a problem keeps the others' cells), a hash of the
method's code: the peer's child script and settings or, for jaxabc, every module under
``jaxabc/``); a rerun skips finished cells, so a long run can be done in several sittings, and
scores every cell again from its stored draws (a change of the metrics needs no rerun).  A jaxabc
change that should not move these runs' numbers (a refactor, a fix of a path they do not take)
need not rerun the grid: ``--carry-over N`` reruns N cells of the earlier code and, only if each
gives the same draws, re-keys the rest to the current code (:func:`carry_over`).  A jaxabc change
that does move them reruns the jaxabc cells alone: the peers' cells, which do not depend on
jaxabc, are taken from the saved result with ``--import-cells`` where the problem, the peer and
the metric code are unchanged (:func:`import_cells`; their wall times count only when measured
on a machine like this one).  The
result is assembled from the cached cells of the requested grid, with a summary per (problem,
budget, method), which method is closest at each budget and whether the surrogate is (the goal
reads budgets up to 200).

Usage::

    python -m benchmarks.surrogate_peers                  # all: 7 problems, B 50 100 200 500, seeds 0-4
    python -m benchmarks.surrogate_peers --quick          # linear + banana, B 60, seed 0: results/quick/
    python -m benchmarks.surrogate_peers --cached-only    # the result from the cached cells alone
    python -m benchmarks.surrogate_peers --carry-over 10  # after a jaxabc change: check 10 cells, carry the rest
    # after a jaxabc change that moves its numbers: rerun jaxabc's cells, the peers' from the result
    python -m benchmarks.surrogate_peers --import-cells benchmarks/results/surrogate_peers.json
    # a subset, written elsewhere than benchmarks/results/:
    python -m benchmarks.surrogate_peers --problems banana --budgets 50 --seeds 0 --methods bolfi --output /tmp/p.json
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import inspect
import io
import json
import math
import os
import re
import subprocess
import sys
import tarfile
import tempfile
import textwrap
import time
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

# ---- problems: begin (NumPy only: shipped verbatim to the peers' child processes)

_LINEAR_COV = np.array([[1.0, 0.8], [0.8, 1.0]])
_LINEAR_CHOL = np.linalg.cholesky(_LINEAR_COV)
_BANANA = {"b": 0.5, "s1": 1.0, "s2": 0.5}
_HETERO = {"s0": 0.5, "c": 0.25}
_HETERO_CORR = np.array([[1.0, 0.5], [0.5, 1.0]])
_HETERO_CHOL = np.linalg.cholesky(_HETERO_CORR)
_BANANA5 = {"b": np.array([0.5, 0.4, 0.3, 0.5]), "s1": 1.0, "s": np.array([0.5, 0.4, 0.6, 0.5])}
_STUDENT = {"df": 3.0, "scale": 0.7}
_STUDENT_CHOL = np.linalg.cholesky(np.array([[1.0, 0.5], [0.5, 1.0]]))


def _correlated(sd: list[float], sign: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """``(A, A^-1)`` of ``x = A theta + z`` whose posterior covariance (before truncation) has sds
    ``sd`` and AR(1) correlations 0.8^|i-j| with the signs ``sign``: ``A^T A = Cov^-1``."""
    d = len(sd)
    corr = (0.8 ** np.abs(np.subtract.outer(np.arange(d), np.arange(d)))) * np.outer(sign, sign)
    a = np.linalg.cholesky(np.linalg.inv(corr * np.outer(sd, sd))).T
    return a, np.linalg.inv(a)


_C5_A, _C5_A_INV = _correlated([1.0, 0.5, 1.5, 0.8, 1.2], [1.0, -1.0, 1.0, 1.0, -1.0])
_C8_A, _C8_A_INV = _correlated([1.0, 0.5, 1.5, 0.8, 1.2, 0.7, 1.3, 0.9], [1.0, -1.0, 1.0, 1.0, -1.0, 1.0, -1.0, 1.0])

PROBLEMS = {
    "linear": {
        "d": 2,
        "low": [-10.0, -10.0],
        "high": [10.0, 10.0],
        "truth_low": [-5.0, -5.0],
        "truth_high": [5.0, 5.0],
        "exact": "direct",
        "description": "x = theta + L z, Cov(L z) = [[1, 0.8], [0.8, 1]]; prior U[-10, 10]^2; "
        "exact N(x_obs, Cov) truncated to the box",
    },
    "banana": {
        "d": 2,
        "low": [-6.0, -12.0],
        "high": [6.0, 6.0],
        "truth_low": [-2.0, -2.0],
        "truth_high": [2.0, 2.0],
        "exact": "direct",
        "description": "x = (theta_1 + z_1, theta_2 + 0.5 (theta_1^2 - 1) + 0.5 z_2); prior U[-6, 6] x U[-12, 6]; "
        "exact theta_1 ~ N(x_1, 1), theta_2 | theta_1 ~ N(x_2 - 0.5 (theta_1^2 - 1), 0.25), truncated",
    },
    "heteroscedastic": {
        "d": 2,
        "low": [-6.0, -6.0],
        "high": [6.0, 6.0],
        "truth_low": [-4.0, -4.0],
        "truth_high": [4.0, 4.0],
        "exact": "grid",
        "description": "x = theta + sd(theta) L z, sd_j = 0.5 exp(0.25 theta_j), Corr(L z) = 0.5; "
        "prior U[-6, 6]^2; exact by a 1000^2 grid over the posterior's support",
    },
    "correlated5": {
        "d": 5,
        "low": [-10.0] * 5,
        "high": [10.0] * 5,
        "truth_low": [-4.0] * 5,
        "truth_high": [4.0] * 5,
        "exact": "direct",
        "description": "x = A theta + z (5 summaries), posterior sds (1, 0.5, 1.5, 0.8, 1.2), AR(1) correlations "
        "0.8^|i-j| with alternating signs; prior U[-10, 10]^5; exact N(A^-1 x_obs, (A^T A)^-1) truncated",
    },
    "correlated8": {
        "d": 8,
        "low": [-10.0] * 8,
        "high": [10.0] * 8,
        "truth_low": [-4.0] * 8,
        "truth_high": [4.0] * 8,
        "exact": "direct",
        "description": "x = A theta + z (8 summaries), posterior sds (1, 0.5, 1.5, 0.8, 1.2, 0.7, 1.3, 0.9), AR(1) "
        "correlations 0.8^|i-j| with alternating signs; prior U[-10, 10]^8; exact N(A^-1 x_obs, (A^T A)^-1) truncated",
    },
    "banana5": {
        "d": 5,
        "low": [-6.0] + [-12.0] * 4,
        "high": [6.0] * 5,
        "truth_low": [-2.0] * 5,
        "truth_high": [2.0] * 5,
        "exact": "direct",
        "description": "x_1 = theta_1 + z_1, x_k = theta_k + b_k (theta_1^2 - 1) + s_k z_k (k = 2..5), "
        "b = (0.5, 0.4, 0.3, 0.5), s = (0.5, 0.4, 0.6, 0.5); prior U[-6, 6] x U[-12, 6]^4; exact theta_1 ~ N(x_1, 1), "
        "theta_k | theta_1 ~ N(x_k - b_k (theta_1^2 - 1), s_k^2), truncated",
    },
    "student": {
        "d": 2,
        "low": [-10.0, -10.0],
        "high": [10.0, 10.0],
        "truth_low": [-5.0, -5.0],
        "truth_high": [5.0, 5.0],
        "exact": "direct",
        "description": "x = theta + 0.7 L t, t_j independent Student-t (3 dof), Corr 0.5 in L; prior U[-10, 10]^2; "
        "exact theta = x_obs - 0.7 L t truncated to the box (heavy tails)",
    },
}


def simulate_np(name: str, theta: np.ndarray, rng) -> np.ndarray:
    """Summaries ``(n, k)`` for parameters ``theta (n, d)``; ``rng`` a NumPy Generator or RandomState."""
    theta = np.atleast_2d(np.asarray(theta, float))
    n = len(theta)
    if name == "linear":
        return theta + rng.standard_normal((n, 2)) @ _LINEAR_CHOL.T
    if name == "banana":
        z = rng.standard_normal((n, 2))
        x1 = theta[:, 0] + _BANANA["s1"] * z[:, 0]
        x2 = theta[:, 1] + _BANANA["b"] * (theta[:, 0] ** 2 - 1.0) + _BANANA["s2"] * z[:, 1]
        return np.column_stack([x1, x2])
    if name == "heteroscedastic":
        sd = _HETERO["s0"] * np.exp(_HETERO["c"] * theta)
        return theta + sd * (rng.standard_normal((n, 2)) @ _HETERO_CHOL.T)
    if name == "correlated5":
        return theta @ _C5_A.T + rng.standard_normal((n, 5))
    if name == "correlated8":
        return theta @ _C8_A.T + rng.standard_normal((n, 8))
    if name == "banana5":
        z = rng.standard_normal((n, 5))
        bent = theta[:, 1:] + _BANANA5["b"] * (theta[:, :1] ** 2 - 1.0) + _BANANA5["s"] * z[:, 1:]
        return np.column_stack([theta[:, 0] + _BANANA5["s1"] * z[:, 0], bent])
    if name == "student":
        return theta + _STUDENT["scale"] * (rng.standard_t(_STUDENT["df"], (n, 2)) @ _STUDENT_CHOL.T)
    raise KeyError(name)


def _log_normal(u: np.ndarray, chol: np.ndarray) -> np.ndarray:
    """log N(u; 0, chol chol^T) for rows of ``u``."""
    w = np.linalg.solve(chol, u.T).T
    return -0.5 * np.sum(w**2, axis=1) - np.log(np.diag(chol)).sum() - 0.5 * u.shape[1] * np.log(2 * np.pi)


def log_likelihood(name: str, theta: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Exact ``log p(x | theta)`` for rows of ``theta (n, d)`` and ``x (k,)`` or ``(n, k)``: the density
    of :func:`simulate_np`'s summaries."""
    theta, x = np.atleast_2d(np.asarray(theta, float)), np.asarray(x, float)
    if name == "linear":
        return _log_normal(x - theta, _LINEAR_CHOL)
    if name == "banana":
        mean2 = theta[:, 1] + _BANANA["b"] * (theta[:, 0] ** 2 - 1.0)
        r1, r2 = (x[..., 0] - theta[:, 0]) / _BANANA["s1"], (x[..., 1] - mean2) / _BANANA["s2"]
        return -0.5 * (r1**2 + r2**2) - np.log(_BANANA["s1"] * _BANANA["s2"]) - np.log(2 * np.pi)
    if name == "heteroscedastic":
        sd = _HETERO["s0"] * np.exp(_HETERO["c"] * theta)
        return _log_normal((x - theta) / sd, _HETERO_CHOL) - np.log(sd).sum(axis=1)
    if name == "correlated5":
        return _log_normal(x - theta @ _C5_A.T, np.eye(5))
    if name == "correlated8":
        return _log_normal(x - theta @ _C8_A.T, np.eye(8))
    if name == "banana5":
        sd = np.concatenate([[_BANANA5["s1"]], _BANANA5["s"]])
        mean = np.column_stack([theta[:, 0], theta[:, 1:] + _BANANA5["b"] * (theta[:, :1] ** 2 - 1.0)])
        r = (x - mean) / sd
        return -0.5 * np.sum(r**2, axis=1) - np.log(sd).sum() - 2.5 * np.log(2 * np.pi)
    if name == "student":
        nu, s = _STUDENT["df"], _STUDENT["scale"]
        t = np.linalg.solve(_STUDENT_CHOL, ((x - theta) / s).T).T
        const = math.lgamma((nu + 1) / 2) - math.lgamma(nu / 2) - 0.5 * math.log(nu * math.pi)
        log_t = const - (nu + 1) / 2 * np.log1p(t**2 / nu)
        return log_t.sum(axis=1) - np.log(np.diag(_STUDENT_CHOL)).sum() - 2 * np.log(s)
    raise KeyError(name)


def exact_direct(name: str, x: np.ndarray, n: int, rng) -> np.ndarray:
    """``n`` draws of the posterior under a flat prior on R^d (untruncated), for ``exact == "direct"``."""
    x = np.asarray(x, float)
    if name == "linear":
        return x - rng.standard_normal((n, 2)) @ _LINEAR_CHOL.T
    if name == "banana":
        t1 = x[0] - _BANANA["s1"] * rng.standard_normal(n)
        t2 = x[1] - _BANANA["b"] * (t1**2 - 1.0) - _BANANA["s2"] * rng.standard_normal(n)
        return np.column_stack([t1, t2])
    if name == "correlated5":
        return (x - rng.standard_normal((n, 5))) @ _C5_A_INV.T
    if name == "correlated8":
        return (x - rng.standard_normal((n, 8))) @ _C8_A_INV.T
    if name == "banana5":
        t1 = x[0] - _BANANA5["s1"] * rng.standard_normal(n)
        rest = x[1:] - _BANANA5["b"] * (t1[:, None] ** 2 - 1.0) - _BANANA5["s"] * rng.standard_normal((n, 4))
        return np.column_stack([t1, rest])
    if name == "student":
        return x - _STUDENT["scale"] * (rng.standard_t(_STUDENT["df"], (n, 2)) @ _STUDENT_CHOL.T)
    raise KeyError(f"{name} has no direct exact sampler")


# ---- problems: end

PROBLEM_NAMES = tuple(PROBLEMS)
#: The five problems of the goal; ``correlated8`` joins ``linear`` and ``correlated5`` in the
#: scaling in dimension (2, 5, 8 parameters), ``banana5`` joins ``banana`` (2, 5, nonlinear).
GOAL_PROBLEMS = ("linear", "banana", "heteroscedastic", "correlated5", "student")
SCALING_PROBLEMS = ("linear", "correlated5", "correlated8", "banana", "banana5")
METHODS = (
    "jaxabc_surrogate",
    "jaxabc_surrogate_abc",
    "sbi_npe",
    "sbi_nle",
    "sbi_snpe",
    "sbi_snle",
    "bolfi",
    "pyabc_abcsmc",
)
SURROGATE = "jaxabc_surrogate"
JAXABC_METHODS = ("jaxabc_surrogate", "jaxabc_surrogate_abc")
SEQUENTIAL_MIN_BUDGET = 200
GOAL_MAX_BUDGET = 200
GOAL = (
    "the surrogate (default mode) closest to exact (lowest mean energy distance) at every budget up to "
    f"{GOAL_MAX_BUDGET} on at least four of the five problems"
)
#: The scaling goal for the surrogate's own cost: this many seconds at this many parameters and budget.
COST_GOAL = {"seconds": 60.0, "parameters": 8, "budget": 500, "problem": "correlated8"}
SINGLE_THREAD = {
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "NUMEXPR_NUM_THREADS": "1",
    "XLA_FLAGS": "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1",
}
SBI_INSTALL = [["torch==2.13.0"], ["sbi==0.27.0", "torch==2.13.0"]]
NLE_MCMC = {"num_chains": 20, "warmup_steps": 200, "thin": 1, "init_strategy": "resample"}


def problem_source() -> str:
    """The text of the problems block of this file (shipped to the peers' child processes)."""
    text = Path(__file__).read_text()
    begin = text.index("# ---- problems: begin")
    end = text.index("# ---- problems: end")
    return text[text.index("\n", begin) + 1 : end]


# ----------------------------------------------------------------------------- JAX simulators


def _jax_simulators() -> dict[str, Callable]:
    """``simulate(key, theta) -> summaries`` for ``jaxabc.run``: the block's models in JAX."""
    import jax
    import jax.numpy as jnp

    def linear(key: jax.Array, theta: jax.Array) -> jax.Array:
        return theta + jnp.asarray(_LINEAR_CHOL, theta.dtype) @ jax.random.normal(key, (2,), theta.dtype)

    def banana(key: jax.Array, theta: jax.Array) -> jax.Array:
        z = jax.random.normal(key, (2,), theta.dtype)
        x2 = theta[1] + _BANANA["b"] * (theta[0] ** 2 - 1.0) + _BANANA["s2"] * z[1]
        return jnp.stack([theta[0] + _BANANA["s1"] * z[0], x2])

    def heteroscedastic(key: jax.Array, theta: jax.Array) -> jax.Array:
        sd = _HETERO["s0"] * jnp.exp(_HETERO["c"] * theta)
        return theta + sd * (jnp.asarray(_HETERO_CHOL, theta.dtype) @ jax.random.normal(key, (2,), theta.dtype))

    def correlated5(key: jax.Array, theta: jax.Array) -> jax.Array:
        return jnp.asarray(_C5_A, theta.dtype) @ theta + jax.random.normal(key, (5,), theta.dtype)

    def correlated8(key: jax.Array, theta: jax.Array) -> jax.Array:
        return jnp.asarray(_C8_A, theta.dtype) @ theta + jax.random.normal(key, (8,), theta.dtype)

    def banana5(key: jax.Array, theta: jax.Array) -> jax.Array:
        z = jax.random.normal(key, (5,), theta.dtype)
        b, s = jnp.asarray(_BANANA5["b"], theta.dtype), jnp.asarray(_BANANA5["s"], theta.dtype)
        bent = theta[1:] + b * (theta[0] ** 2 - 1.0) + s * z[1:]
        return jnp.concatenate([theta[:1] + _BANANA5["s1"] * z[:1], bent])

    def student(key: jax.Array, theta: jax.Array) -> jax.Array:
        t = jax.random.t(key, _STUDENT["df"], (2,), theta.dtype)
        return theta + _STUDENT["scale"] * (jnp.asarray(_STUDENT_CHOL, theta.dtype) @ t)

    return {
        "linear": linear,
        "banana": banana,
        "heteroscedastic": heteroscedastic,
        "correlated5": correlated5,
        "correlated8": correlated8,
        "banana5": banana5,
        "student": student,
    }


def _hash(*texts: str) -> str:
    return hashlib.sha256("\n\x00".join(texts).encode()).hexdigest()[:16]


def _ast_text(source: str) -> str:
    return ast.dump(ast.parse(textwrap.dedent(source)))


def problem_hash(name: str) -> str:
    """A problem's numerical fingerprint, what its cached cells depend on: its settings, what its
    NumPy and JAX simulators return at fixed parameters and seeds (10 and 6 significant digits),
    and the code that draws each seed's truth and ``x_obs``.  An edit elsewhere in the problems
    block (another problem added) leaves it as it is; a change of this problem's model does not."""
    import jax
    import jax.numpy as jnp

    p = PROBLEMS[name]
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    theta = rng.uniform(p["truth_low"], p["truth_high"], size=(8, p["d"]))
    x_np = simulate_np(name, theta, np.random.default_rng(0))
    keys = jax.random.split(jax.random.key(0), len(theta))
    x_jax = jax.vmap(_jax_simulators()[name])(keys, jnp.asarray(theta, jnp.float32))
    return _hash(
        json.dumps(p, sort_keys=True),
        np.array2string(x_np, precision=9, floatmode="maxprec", threshold=10**6),
        np.array2string(np.asarray(x_jax, np.float64), precision=5, floatmode="maxprec", threshold=10**6),
        _ast_text(inspect.getsource(instance)),
    )


# ----------------------------------------------------------------------------- exact posteriors


def grid_posterior(
    name: str, x: np.ndarray, coarse: int = 300, fine: int = 1000, cutoff: float = 30.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Posterior on a grid for a 2-D problem: cell centres ``(m, 2)``, probabilities, cell widths.

    A ``coarse``^2 grid over the prior box finds the cells within ``cutoff`` log units of the
    largest; a ``fine``^2 grid over their bounding box (one coarse cell wider each side, clipped
    to the prior) carries the posterior, evaluated at the cell centres.
    """
    p = PROBLEMS[name]
    low, high = np.asarray(p["low"], float), np.asarray(p["high"], float)

    def centres(lo: np.ndarray, hi: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
        h = (hi - lo) / m
        a = lo[0] + h[0] * (np.arange(m) + 0.5)
        b = lo[1] + h[1] * (np.arange(m) + 0.5)
        aa, bb = np.meshgrid(a, b, indexing="ij")
        return np.column_stack([aa.ravel(), bb.ravel()]), h

    c, h = centres(low, high, coarse)
    logp = log_likelihood(name, c, x)
    keep = c[logp > logp.max() - cutoff]
    lo = np.maximum(keep.min(axis=0) - 1.5 * h, low)
    hi = np.minimum(keep.max(axis=0) + 1.5 * h, high)
    c, h = centres(lo, hi, fine)
    logp = log_likelihood(name, c, x)
    prob = np.exp(logp - logp.max())
    return c, prob / prob.sum(), h


def grid_sample(grid: tuple[np.ndarray, np.ndarray, np.ndarray], n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` draws of a grid posterior: a cell by its probability, then uniform inside it."""
    c, prob, h = grid
    idx = rng.choice(len(c), size=n, p=prob)
    return c[idx] + (rng.random((n, c.shape[1])) - 0.5) * h


def grid_moments(grid: tuple[np.ndarray, np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of the piecewise-constant grid density."""
    c, prob, h = grid
    mean = prob @ c
    cov = (c - mean).T @ ((c - mean) * prob[:, None]) + np.diag(h**2 / 12)
    return mean, cov


def exact_sample(name: str, x: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` exact posterior draws under the prior box (direct sampling and rejection, or the grid)."""
    p = PROBLEMS[name]
    if p["exact"] == "grid":
        return grid_sample(grid_posterior(name, x), n, rng)
    low, high = np.asarray(p["low"]), np.asarray(p["high"])
    out, have = [], 0
    while have < n:
        draws = exact_direct(name, x, max(2 * (n - have), 1000), rng)
        draws = draws[np.all((draws >= low) & (draws <= high), axis=1)]
        out.append(draws)
        have += len(draws)
    return np.concatenate(out)[:n]


@dataclass
class Instance:
    """One seed's data set of a problem: truth, observation, exact posterior."""

    problem: str
    seed: int
    truth: np.ndarray
    observed: np.ndarray
    exact_mean: np.ndarray
    exact_cov: np.ndarray
    exact_draws: np.ndarray  # for the energy distance
    reference_draws: np.ndarray  # independent: the "exact" row (energy distance floor)


def instance(name: str, seed: int, exact_draws: int = 2000, moment_draws: int = 200_000) -> Instance:
    """Truth uniform in the problem's inner region, ``x_obs`` from the model, exact posterior."""
    p = PROBLEMS[name]
    tag = zlib.crc32(name.encode())
    rng = np.random.default_rng([seed, tag])
    truth = rng.uniform(p["truth_low"], p["truth_high"])
    observed = simulate_np(name, truth[None], rng)[0]
    rng_exact = np.random.default_rng([seed, tag, 1])
    if p["exact"] == "grid":
        grid = grid_posterior(name, observed)
        mean, cov = grid_moments(grid)
        draws = grid_sample(grid, exact_draws + 1000, rng_exact)
    else:
        big = exact_sample(name, observed, moment_draws, rng_exact)
        mean, cov = big.mean(axis=0), np.cov(big, rowvar=False)
        draws = exact_sample(name, observed, exact_draws + 1000, rng_exact)
    return Instance(name, seed, truth, observed, mean, cov, draws[:exact_draws], draws[exact_draws:])


# ----------------------------------------------------------------------------- metrics


def _mean_pairwise(a: np.ndarray, wa: np.ndarray, b: np.ndarray | None = None, wb: np.ndarray | None = None) -> float:
    """Weighted mean Euclidean distance between rows of ``a`` and ``b``; without ``b``, within ``a``
    excluding the pairs of a point with itself (U-statistic)."""
    other = a if b is None else b
    sq = np.sum(a**2, 1)[:, None] + np.sum(other**2, 1)[None, :] - 2 * a @ other.T
    dist = np.sqrt(np.maximum(sq, 0.0))
    if b is None:
        np.fill_diagonal(dist, 0.0)
        return float(wa @ dist @ wa / (1.0 - wa @ wa))
    return float(wa @ dist @ wb)


def energy_distance(x: np.ndarray, wx: np.ndarray, y: np.ndarray) -> float:
    """Energy distance between weighted draws ``x`` and equal-weight draws ``y`` (unbiased within-sample
    terms: about 0, possibly slightly negative, for draws of the same law)."""
    wx = np.asarray(wx, float) / np.sum(wx)
    wy = np.full(len(y), 1.0 / len(y))
    return 2 * _mean_pairwise(x, wx, y, wy) - _mean_pairwise(x, wx) - _mean_pairwise(y, wy)


def weighted_quantiles(x: np.ndarray, w: np.ndarray, q: Sequence[float]) -> np.ndarray:
    """Quantiles ``q`` of 1-D weighted draws (midpoint interpolation of the weighted CDF)."""
    order = np.argsort(x)
    xs, ws = x[order], w[order] / w.sum()
    cdf = np.cumsum(ws) - 0.5 * ws
    return np.interp(q, cdf, xs)


def thin_draws(x: np.ndarray, w: np.ndarray, max_draws: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """At most ``max_draws`` draws: a subsample when weights are equal, else systematic resampling."""
    if len(x) <= max_draws:
        return x, w
    rng = np.random.default_rng(seed)
    if np.allclose(w, w[0]):
        return x[rng.choice(len(x), max_draws, replace=False)], np.full(max_draws, 1.0 / max_draws)
    cdf = np.cumsum(w / w.sum())
    idx = np.searchsorted(cdf, (rng.random() + np.arange(max_draws)) / max_draws)
    return x[np.minimum(idx, len(x) - 1)], np.full(max_draws, 1.0 / max_draws)


def accuracy(particles: Any, weights: Any, inst: Instance, max_draws: int = 1000, seed: int = 0) -> dict[str, Any]:
    """A method's posterior against the exact one, in exact-standardised coordinates."""
    x = np.asarray(particles, float).reshape(len(particles), -1)
    w = np.asarray(weights, float)
    if not np.all(np.isfinite(x)) or not np.all(np.isfinite(w)) or w.sum() <= 0:
        raise ValueError("non-finite particles or weights")
    w = w / w.sum()
    mean = w @ x
    cov = np.atleast_2d(np.cov(x, aweights=w, rowvar=False)) if len(x) > 1 else np.zeros((x.shape[1],) * 2)
    chol = np.linalg.cholesky(inst.exact_cov)
    diff = np.linalg.solve(chol, mean - inst.exact_mean)
    sd, sd_exact = np.sqrt(np.diag(cov)), np.sqrt(np.diag(inst.exact_cov))
    bounds = np.array([weighted_quantiles(x[:, j], w, [0.05, 0.95]) for j in range(x.shape[1])])
    covered = (bounds[:, 0] <= inst.truth) & (inst.truth <= bounds[:, 1])
    below = np.array([w[x[:, j] <= inst.truth[j]].sum() for j in range(x.shape[1])])
    xt, wt = thin_draws(x, w, max_draws, seed)

    def whiten(a: np.ndarray) -> np.ndarray:
        return np.linalg.solve(chol, (a - inst.exact_mean).T).T

    return {
        "energy_distance": energy_distance(whiten(xt), wt, whiten(inst.exact_draws)),
        "mean_error_in_sd": float(np.sqrt(diff @ diff)),
        "sd_ratio": (sd / sd_exact).tolist(),
        "covered_90": covered.tolist(),
        "truth_cdf": below.tolist(),  # the method's posterior CDF at the truth, per parameter
        "mean": mean.tolist(),
        "sd": sd.tolist(),
        "ess": float(1.0 / np.sum(w**2)),
        "num_draws": len(x),
    }


# ----------------------------------------------------------------------------- methods

PEER_PRELUDE = r"""
import json, math, sys, time
import numpy as np
"""

PEER_REQUEST = r"""
req = json.loads(sys.argv[1])
NAME, SEED, BUDGET, DRAWS = req["problem"], int(req["seed"]), int(req["budget"]), int(req["draws"])
LOW, HIGH = np.asarray(PROBLEMS[NAME]["low"], float), np.asarray(PROBLEMS[NAME]["high"], float)
D = len(LOW)
OBS = np.asarray(req["observed"], float)
"""

BOLFI_SCRIPT = r"""
import logging
import elfi
logging.getLogger("elfi").setLevel(logging.WARNING)
names = [f"t{i}" for i in range(D)]

def simulator(*params, batch_size=1, random_state=None):
    rs = random_state or np.random
    theta = np.column_stack([np.broadcast_to(np.asarray(p, float), (batch_size,)) for p in params])
    return simulate_np(NAME, theta, rs)

m = elfi.new_model()
priors = [elfi.Prior("uniform", LOW[i], HIGH[i] - LOW[i], model=m, name=names[i]) for i in range(D)]
y = elfi.Simulator(simulator, *priors, observed=OBS[None], name="y")
dist = elfi.Distance("euclidean", y, name="d")
log_d = elfi.Operation(np.log, dist, name="log_d")
initial = min(10 * D, BUDGET // 2)
t0 = time.perf_counter()
bolfi = elfi.BOLFI(log_d, batch_size=1, initial_evidence=initial, update_interval=10,
                   bounds={n: (LOW[i], HIGH[i]) for i, n in enumerate(names)}, acq_noise_var=0.1, seed=SEED)
bolfi.fit(n_evidence=BUDGET)
res = bolfi.sample(DRAWS, n_chains=4)
run_s = time.perf_counter() - t0
x = np.column_stack([res.samples[n] for n in names])
print(json.dumps({"particles": x.tolist(), "weights": np.ones(len(x)).tolist(),
                  "num_simulations": int(bolfi.n_evidence), "run_s": run_s, "version": elfi.__version__,
                  "settings": {"initial_evidence": initial, "update_interval": 10, "acq_noise_var": 0.1,
                               "sampler": "NUTS, 4 chains, half warm-up"}}))
"""

PYABC_SCRIPT = r"""
import logging, os, tempfile
import pyabc
for logger in ("ABC", "Sampler", "Epsilon", "History", "Distance", "Acceptor", "Transition"):
    logging.getLogger(logger).setLevel(logging.WARNING)
np.random.seed(SEED)
names = [f"t{i}" for i in range(D)]

def model(p):
    return {"x": simulate_np(NAME, np.array([[p[n] for n in names]]), np.random)[0]}

def distance(a, b):
    return float(np.linalg.norm(a["x"] - b["x"]))

prior = pyabc.Distribution(**{n: pyabc.RV("uniform", LOW[i], HIGH[i] - LOW[i]) for i, n in enumerate(names)})
population = max(10, BUDGET // 4)
t0 = time.perf_counter()
with tempfile.TemporaryDirectory() as tmp:
    abc = pyabc.ABCSMC(model, prior, distance, population_size=population,
                       sampler=pyabc.sampler.SingleCoreSampler())
    abc.new("sqlite:///" + os.path.join(tmp, "h.db"), {"x": OBS})
    h = abc.run(max_total_nr_simulations=BUDGET, minimum_epsilon=0.0)
    df, w = h.get_distribution(m=0, t=h.max_t)
    sims = int(h.total_nr_simulations)
    generations = int(h.max_t) + 1
run_s = time.perf_counter() - t0
print(json.dumps({"particles": df[names].to_numpy().tolist(), "weights": np.asarray(w, float).tolist(),
                  "num_simulations": sims, "run_s": run_s, "generations": generations,
                  "version": pyabc.__version__, "settings": {"population_size": population}}))
"""

SBI_SCRIPT = r"""
import importlib.metadata, os, tempfile
os.chdir(tempfile.mkdtemp(prefix="sbi-"))  # sbi writes TensorBoard logs to ./sbi-logs
import torch
torch.set_num_threads(1)
torch.manual_seed(SEED)
from sbi.inference import NLE, NPE
from sbi.utils import BoxUniform
method = req["method"]
rounds = 2 if method in ("sbi_snpe", "sbi_snle") else 1
neural_likelihood = method in ("sbi_nle", "sbi_snle")
mcmc = req["mcmc"]
rng = np.random.default_rng(SEED)
prior = BoxUniform(torch.tensor(LOW, dtype=torch.float32), torch.tensor(HIGH, dtype=torch.float32))
x_o = torch.tensor(OBS, dtype=torch.float32)[None]

def simulator(theta):
    return torch.tensor(simulate_np(NAME, theta.numpy().astype(float), rng), dtype=torch.float32)

def posterior_of(inference):
    if neural_likelihood:
        return inference.build_posterior(mcmc_method="slice_np_vectorized", mcmc_parameters=dict(mcmc))
    return inference.build_posterior()

t0 = time.perf_counter()
inference = (NLE if neural_likelihood else NPE)(prior=prior, show_progress_bars=False)
proposal, used, per_round = prior, 0, [BUDGET // rounds] * rounds
per_round[-1] += BUDGET - sum(per_round)
for r, n in enumerate(per_round):
    if r == 0:
        theta = prior.sample((n,))
    else:
        theta = proposal.sample((n,), show_progress_bars=False)
    x = simulator(theta)
    used += n
    if neural_likelihood:
        inference.append_simulations(theta, x)
    else:
        inference.append_simulations(theta, x, proposal=proposal)
    inference.train(training_batch_size=int(req["training_batch_size"]), show_train_summary=False)
    posterior = posterior_of(inference)
    proposal = posterior.set_default_x(x_o)
samples = posterior.sample((DRAWS,), x=x_o, show_progress_bars=False)
run_s = time.perf_counter() - t0
sampler = "slice_np_vectorized " + json.dumps(mcmc) if neural_likelihood else "flow draws, rejected outside the prior"
print(json.dumps({"particles": samples.numpy().astype(float).tolist(), "weights": [1.0] * len(samples),
                  "num_simulations": used, "run_s": run_s, "version": importlib.metadata.version("sbi"),
                  "torch": torch.__version__,
                  "settings": {"rounds": rounds, "density_estimator": "maf", "sampler": sampler,
                               "training_batch_size": int(req["training_batch_size"])}}))
"""

PEER_SCRIPTS = {"bolfi": BOLFI_SCRIPT, "pyabc_abcsmc": PYABC_SCRIPT, "sbi": SBI_SCRIPT}


@dataclass(frozen=True)
class Peer:
    """A peer's virtual environment (``make_venv`` arguments) and child script."""

    venv: str
    requirement: str
    module: str
    script: str
    install: tuple[tuple[str, ...], ...] | None = None


def peers() -> dict[str, Peer]:
    """The peers by method: exact pins, each in a virtual environment named after its pin."""
    sbi = Peer("sbi-0.27.0", "sbi==0.27.0", "sbi", "sbi", tuple(tuple(a) for a in SBI_INSTALL))
    return {
        "bolfi": Peer("elfi-0.8.8", "elfi==0.8.8", "elfi", "bolfi"),
        "pyabc_abcsmc": Peer("pyabc-0.13.0", "pyabc==0.13.0", "pyabc", "pyabc_abcsmc"),
        **{m: sbi for m in ("sbi_npe", "sbi_nle", "sbi_snpe", "sbi_snle")},
    }


def sbi_batch_size(budget: int) -> int:
    """sbi's training batch: a tenth of the budget, between 10 and 50 (sbi's default, 200, is one
    optimiser step per epoch at these budgets, and its networks then stop far from trained)."""
    return min(50, max(10, budget // 10))


def skip_reason(method: str, budget: int) -> str | None:
    """Why a cell is not run (None when it is)."""
    if method in ("sbi_snpe", "sbi_snle") and budget < SEQUENTIAL_MIN_BUDGET:
        return f"sequential rounds (2 x B/2) only for B >= {SEQUENTIAL_MIN_BUDGET}"
    return None


#: Where a surrogate run's own time goes: (module, function) pairs timed in the child, by
#: phase.  The design rounds and the validation include the fits and pools they call.
PHASES = {
    "design_rounds": ("jaxabc.surrogate.algorithm", "design_step"),
    "validation": ("jaxabc.surrogate.algorithm", "check_holdout"),
    "final_draws": ("jaxabc.surrogate.algorithm", "finalize"),
    "gp_fits": ("jaxabc.surrogate.emulator", "fit"),
    "importance_pools": ("jaxabc.surrogate.design", "importance_pool"),
}


def _time_phases() -> dict[str, float]:
    """Wrap the functions of :data:`PHASES` (in this child process only) to add up their wall
    time into the returned dict; the wrappers only time, so the run's numbers are unchanged."""
    import importlib

    totals = dict.fromkeys(PHASES, 0.0)
    for phase, (module, name) in PHASES.items():
        mod = importlib.import_module(module)
        inner = getattr(mod, name)

        def timed(*a: Any, _inner: Callable = inner, _phase: str = phase, **k: Any) -> Any:
            t = time.perf_counter()
            try:
                return _inner(*a, **k)
            finally:
                totals[_phase] += time.perf_counter() - t

        setattr(mod, name, timed)
    return totals


def run_jaxabc_child(request: dict[str, Any]) -> dict[str, Any]:
    """One jaxabc surrogate run (in a child process): draws, simulations used, wall time and
    its split by :data:`PHASES`."""
    import jax.numpy as jnp

    import jaxabc

    phases = _time_phases()

    name = request["problem"]
    p = PROBLEMS[name]
    prior = jaxabc.Uniform(p["low"], p["high"], names=tuple(f"t{i}" for i in range(p["d"])))
    options = {"mode": "abc"} if request["method"] == "jaxabc_surrogate_abc" else {}
    t0 = time.perf_counter()
    r = jaxabc.run(
        "surrogate",
        _jax_simulators()[name],
        prior,
        jnp.asarray(request["observed"], jnp.float32),
        max_simulations=int(request["budget"]),
        num_particles=int(request["draws"]),
        seed=int(request["seed"]),
        **options,
    )
    diag = r.diagnostics if isinstance(r.diagnostics, dict) else {}
    return {
        "particles": np.asarray(r.particles, float).tolist(),
        "weights": np.asarray(r.weights, float).tolist(),
        "num_simulations": int(r.num_simulations),
        "run_s": time.perf_counter() - t0,
        "phase_s": {k: round(v, 2) for k, v in phases.items()},
        "validated": bool(diag.get("validated", False)),
        "stop_reason": str(r.stop_reason),
        "version": jaxabc.__version__,
        "settings": {"mode": diag.get("mode", options.get("mode", "synthetic likelihood"))},
    }


def jaxabc_hash() -> str:
    """Hash of the jaxabc package's code (AST, docstrings excluded) and of the child function."""
    from benchmarks._common import code_hash

    files = sorted((ROOT / "jaxabc").rglob("*.py"))
    return _hash(
        *(f"{f.relative_to(ROOT)}:{code_hash(f)}" for f in files),
        _ast_text(inspect.getsource(run_jaxabc_child)),
        _ast_text(inspect.getsource(_time_phases)),
    )


def method_hash(method: str) -> str:
    """What a method's cached cells depend on besides the problem: its code and pinned versions."""
    if method in JAXABC_METHODS:
        return jaxabc_hash()
    peer = peers()[method]
    extra = [_ast_text(inspect.getsource(request_of))]
    if peer.script == "sbi":
        extra += [json.dumps(NLE_MCMC), _ast_text(inspect.getsource(sbi_batch_size))]
    return _hash(PEER_PRELUDE, PEER_REQUEST, PEER_SCRIPTS[peer.script], peer.requirement, repr(peer.install), *extra)


def request_of(inst: Instance, method: str, budget: int, draws: int) -> dict[str, Any]:
    return {
        "problem": inst.problem,
        "method": method,
        "seed": inst.seed,
        "budget": budget,
        "draws": draws,
        "observed": inst.observed.tolist(),
        "mcmc": NLE_MCMC,
        "training_batch_size": sbi_batch_size(budget),
    }


def run_child(argv: list[str], timeout: float, env: dict[str, str]) -> dict[str, Any]:
    """Run one child process: ``{"output": <its last JSON line>, "process_wall_s": ...}``, or an ``error``."""
    t0 = time.perf_counter()
    try:
        out = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, env={**os.environ, **env})
    except subprocess.TimeoutExpired:
        return {"error": f"did not finish in {timeout:.0f} s", "process_wall_s": timeout}
    wall = time.perf_counter() - t0
    # The result is the last line's JSON object; libraries may print before it on that line (sbi
    # ends its training message without a newline).
    lines = [line[line.index("{") :] for line in out.stdout.splitlines() if "{" in line]
    if out.returncode == 0 and lines:
        try:
            return {"output": json.loads(lines[-1]), "process_wall_s": wall}
        except json.JSONDecodeError:
            pass
    tail = (out.stderr.strip() or out.stdout.strip() or "no output").splitlines()
    # A Python exception's last line names it; otherwise keep the last three lines.
    last = tail[-1] if ":" in tail[-1] and tail[-1].split(":", 1)[0].replace(".", "").isidentifier() else None
    text = last or " | ".join(tail[-3:])
    return {"error": f"exit {out.returncode}: {text[-600:]}", "process_wall_s": wall}


def compilation_cache_env(path: Path | None) -> dict[str, str]:
    """JAX's persistent compilation cache for the jaxabc children (every executable, however quick
    to compile): the same compiled code, so the same draws, without recompiling it in every cell."""
    if path is None:
        return {}
    return {
        "JAX_COMPILATION_CACHE_DIR": str(path),
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
        "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES": "0",
    }


def run_method(
    method: str,
    request: dict[str, Any],
    envs: dict[str, dict[str, Any]],
    timeout: float,
    compilation_cache: Path | None = None,
) -> dict[str, Any]:
    """Run one cell's method in a child process; ``{"output": ...}`` or ``{"error": ...}``."""
    if method in JAXABC_METHODS:
        argv = [sys.executable, "-m", "benchmarks.surrogate_peers", "--child", json.dumps(request)]
        env = {**SINGLE_THREAD, "PYTHONPATH": str(ROOT), **compilation_cache_env(compilation_cache)}
        return run_child(argv, timeout, env)
    env = envs[method]
    if "error" in env:
        return {"error": f"virtual environment: {env['error']}"}
    script = PEER_PRELUDE + problem_source() + PEER_REQUEST + PEER_SCRIPTS[peers()[method].script]
    return run_child([env["python"], "-c", script, json.dumps(request)], timeout, SINGLE_THREAD)


def make_envs(methods: Sequence[str], venv_dir: Path) -> dict[str, dict[str, Any]]:
    """The peers' virtual environments (made once, then reused), by method."""
    from benchmarks._venv import make_venv

    made: dict[str, dict[str, Any]] = {}
    envs = {}
    for method in methods:
        if method in JAXABC_METHODS:
            continue
        peer = peers()[method]
        if peer.venv not in made:
            install = [list(a) for a in peer.install] if peer.install else None
            print(f"virtual environment {peer.venv} ({peer.requirement}) ...", flush=True)
            made[peer.venv] = make_venv(venv_dir, peer.venv, peer.requirement, peer.module, install=install)
        envs[method] = made[peer.venv]
    return envs


# ----------------------------------------------------------------------------- cache


def cell_key(problem: str, method: str, budget: int, seed: int, p_hash: str, m_hash: str) -> str:
    return f"{problem}|{method}|{budget}|{seed}|{p_hash}|{m_hash}"


def load_cache(path: Path) -> dict[str, dict[str, Any]]:
    """Cells by key (the last line of a key wins); unreadable lines are ignored."""
    cells: dict[str, dict[str, Any]] = {}
    if path.is_file():
        for line in path.read_text().splitlines():
            try:
                cell = json.loads(line)
                cells[cell["key"]] = cell
            except (json.JSONDecodeError, KeyError, TypeError):
                continue
    return cells


def append_cache(path: Path, cell: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as fh:
        fh.write(json.dumps(cell) + "\n")


def carry_over(
    cached: dict[str, dict[str, Any]],
    cache_file: Path,
    grid: list[tuple[str, str, int, int]],
    p_hash: dict[str, str],
    m_hash: dict[str, str],
    num_check: int,
    run: Callable[[str, str, int, int], dict[str, Any]],
) -> int:
    """Re-key the jaxabc cells of the grid made by earlier jaxabc code, if the current code
    reproduces them: the numerical currency of cells (a refactor or a fix of a path these runs
    do not take need not rerun hours of cells; a change of numbers is caught).

    The source is the earlier code hash with the most cells of ``grid`` that the current hash
    lacks.  ``num_check`` of them, spread over problems, methods and the largest budgets, are run
    again (``run(problem, method, budget, seed)``, the raw cell); only when every one gives the
    same draws and simulations are the others appended under the current hash, each with
    ``carried_from`` (the source hash) and ``verified_by`` (the checked cells).  Returns the
    number carried.

    Raises
    ------
    SystemExit
        A checked cell differs: nothing is carried, and the differences are printed.
    """
    sources: dict[str, dict[tuple[str, str, int, int], dict[str, Any]]] = {}
    for cell in cached.values():
        p, m, b, sd = cell.get("problem"), cell.get("method"), cell.get("budget"), cell.get("seed")
        if (p, m, b, sd) not in grid or m not in JAXABC_METHODS or "particles" not in cell.get("result", {}):
            continue
        parts = cell["key"].split("|")
        if parts[4] != p_hash[p] or parts[5] == m_hash[m] or cell_key(p, m, b, sd, p_hash[p], m_hash[m]) in cached:
            continue
        sources.setdefault(parts[5], {})[(p, m, b, sd)] = cell
    if not sources:
        return 0
    source = max(sources, key=lambda h: len(sources[h]))
    cells = sources[source]
    # Largest budgets first (the longest design loops), one problem after another, the methods
    # taking turns over the problems.
    problems = sorted({c[0] for c in cells})
    methods = sorted({c[1] for c in cells})
    order = sorted(
        cells,
        key=lambda c: (
            -c[2],
            c[3],
            (methods.index(c[1]) - problems.index(c[0])) % len(methods),
            problems.index(c[0]),
        ),
    )
    checks: list[tuple[str, str, int, int]] = []
    for c in order:
        if len(checks) < num_check and c[0] not in {k[0] for k in checks}:
            checks.append(c)
    for c in order:
        if len(checks) < num_check and c not in checks:
            checks.append(c)
    print(f"carry-over: {len(cells)} cells of jaxabc code {source}; checking {len(checks)}", flush=True)
    differ = []
    for c in checks:
        old, new = cells[c]["result"], run(*c)
        same = all(old.get(k) == new.get(k) for k in ("particles", "weights", "num_simulations"))
        print(f"  {c}: {'same draws' if same else 'DIFFERENT'}", flush=True)
        if "error" not in new:
            append_cache(
                cache_file,
                {
                    "key": cell_key(*c, p_hash[c[0]], m_hash[c[1]]),
                    "problem": c[0],
                    "method": c[1],
                    "budget": c[2],
                    "seed": c[3],
                    "result": new,
                },
            )
        if not same:
            differ.append(c)
    if differ:
        raise SystemExit(f"carry-over refused: the current jaxabc code changes the draws of {differ}; rerun the cells")
    verified = [list(c) for c in checks]
    for c, cell in cells.items():
        if c in checks:
            continue
        result = {**cell["result"], "carried_from": source, "verified_by": verified}
        append_cache(cache_file, {**cell, "key": cell_key(*c, p_hash[c[0]], m_hash[c[1]]), "result": result})
    return len(cells) - len(checks)


#: The functions that turn a cell's draws into its scores: a saved scored cell can stand for a new
#: one only while these are unchanged.
SCORING_FUNCTIONS = ("_mean_pairwise", "energy_distance", "weighted_quantiles", "thin_draws", "accuracy", "score")

_HASHES_AT = """
import importlib, inspect, json, sys
m = importlib.import_module("benchmarks.surrogate_peers")  # the code of the result's commit
methods, functions = json.loads(sys.argv[1]), json.loads(sys.argv[2])
print(json.dumps({
    "method": {x: m.method_hash(x) for x in methods},
    "scoring": m._hash(*(m._ast_text(inspect.getsource(getattr(m, f))) for f in functions)),
}))
"""


def scoring_hash() -> str:
    """A hash of :data:`SCORING_FUNCTIONS`' code (docstrings and layout aside)."""
    module = sys.modules[__name__]
    return _hash(*(_ast_text(inspect.getsource(getattr(module, f))) for f in SCORING_FUNCTIONS))


def saved_hashes(saved: dict[str, Any], methods: Sequence[str]) -> dict[str, Any]:
    """The method hashes (of ``methods``) and the scoring hash of a saved result.

    Results record them (``method_hash``, ``scoring_hash``); for one made before they were
    recorded they are computed from the code of the result's commit (``git archive`` into a
    temporary folder, hashed there by that code's :func:`method_hash` and this code's rule for the
    scoring functions).

    Raises
    ------
    SystemExit
        The result records neither hashes nor a clean commit, or its commit is not in this clone.
    """
    if "method_hash" in saved and "scoring_hash" in saved:
        return {"method": saved["method_hash"], "scoring": saved["scoring_hash"]}
    prov = saved.get("provenance") or {}
    commit = prov.get("commit")
    if not commit or not prov.get("tree_clean"):
        raise SystemExit("--import-cells: the result records no method hashes and no clean commit to compute them at")
    archive = subprocess.run(
        ["git", "-C", str(ROOT), "archive", "--format=tar", commit, "benchmarks", "jaxabc", "md"],
        capture_output=True,
    )
    if archive.returncode != 0:
        raise SystemExit(f"--import-cells: commit {commit[:10]} is not in this clone: {archive.stderr.decode()[-300:]}")
    with tempfile.TemporaryDirectory() as tmp:
        with tarfile.open(fileobj=io.BytesIO(archive.stdout)) as tar:
            tar.extractall(tmp, filter="data")
        out = subprocess.run(
            [sys.executable, "-c", _HASHES_AT, json.dumps(list(methods)), json.dumps(list(SCORING_FUNCTIONS))],
            capture_output=True,
            text=True,
            cwd=tmp,
            env={**os.environ, "PYTHONPATH": tmp},
        )
    if out.returncode != 0:
        raise SystemExit(f"--import-cells: hashing the code of {commit[:10]} failed: {out.stderr.strip()[-400:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def load_saved(path: Path) -> dict[str, Any]:
    """The saved result at ``path``; a file that is not a result JSON with ``cells`` exits with a
    one-line message (``SystemExit``), not a traceback."""
    try:
        saved = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as exc:
        raise SystemExit(f"--import-cells: {path} is not a result JSON ({exc})") from None
    if not isinstance(saved, dict) or not isinstance(saved.get("cells"), list):
        raise SystemExit(f"--import-cells: {path} holds no 'cells' list; is it a surrogate_peers result?")
    return saved


def import_cells(
    saved: dict[str, Any],
    hashes: dict[str, Any],
    problems: Sequence[str],
    methods: Sequence[str],
    p_hash: dict[str, str],
    m_hash: dict[str, str],
    here: dict[str, Any],
) -> dict[tuple[str, str, int, int], dict[str, Any]]:
    """The scored peer cells of a saved result that this code would score alike, by
    (problem, method, budget, seed).

    A peer's run depends on the problem (its fingerprint), the peer's script, settings and pinned
    version (its method hash), not on jaxabc; its scores on :data:`SCORING_FUNCTIONS`.  A cell is
    taken when all three hashes equal the current ones; jaxabc cells, ``exact`` rows and cells
    the saved run did not run are never taken.  Taken cells keep their scores and wall times and
    gain ``imported_from`` (the commit that ran them, kept through later imports); their times
    count only when ``here`` (this machine's record) has the CPU, instruction sets and core count
    of the saved run's machine, else they gain ``timed_elsewhere``.  Their draws are not in the
    result, so a change of the metrics needs them run again.
    """
    from benchmarks._common import cpu_signature

    if hashes["scoring"] != scoring_hash():
        print("--import-cells: the saved cells were scored by other metric code; none imported", flush=True)
        return {}
    prov = saved.get("provenance") or {}
    there = prov.get("machine") or {}
    same = cpu_signature(there) is not None and (cpu_signature(there), there.get("cpu_count")) == (
        cpu_signature(here),
        here.get("cpu_count"),
    )
    taken: dict[tuple[str, str, int, int], dict[str, Any]] = {}
    for c in saved.get("cells", []):
        p, m = c["problem"], c["method"]
        if p not in problems or m not in methods or m in JAXABC_METHODS or m == "exact" or "not_run" in c:
            continue
        if (saved.get("problem_hash") or {}).get(p) != p_hash[p] or hashes["method"].get(m) != m_hash[m]:
            continue
        cell = {k: v for k, v in c.items() if k not in ("problem", "method", "budget", "seed")}
        cell.setdefault("imported_from", prov.get("commit"))
        if not same:
            cell["timed_elsewhere"] = True
        taken[(p, m, int(c["budget"]), int(c["seed"]))] = cell
    return taken


def run_cell(
    inst: Instance, method: str, budget: int, envs: dict[str, dict[str, Any]], args: argparse.Namespace
) -> dict[str, Any]:
    """Run a method on a data set: its draws (5 significant digits; weights only when unequal) and
    what it reports, or an ``error``.  Scoring is :func:`score`'s, from the stored draws."""
    cache = None if args.no_compilation_cache else args.cache_dir / "xla"
    out = run_method(method, request_of(inst, method, budget, args.draws), envs, args.timeout, cache)
    cell: dict[str, Any] = {"process_wall_s": out.get("process_wall_s")}
    if args.cpu_shared:
        cell["cpu_shared"] = True
    if method in JAXABC_METHODS:
        cell["compilation_cache"] = cache is not None
    if "error" in out:
        return {**cell, "error": out["error"]}
    o = out["output"]
    keep = (
        "num_simulations",
        "run_s",
        "phase_s",
        "version",
        "torch",
        "validated",
        "stop_reason",
        "generations",
        "settings",
    )
    cell.update({k: o[k] for k in keep if k in o})
    x = np.asarray(o["particles"], float).reshape(len(o["particles"]), -1)
    w = np.asarray(o["weights"], float)
    cell["particles"] = [[float(f"{v:.5g}") for v in row] for row in x]
    if len(w) and not np.allclose(w, w[0]):
        cell["weights"] = [float(f"{v:.5g}") for v in w / w.max()]
    return cell


def score(raw: dict[str, Any], inst: Instance, budget: int, max_draws: int) -> dict[str, Any]:
    """A cell as the result reports it: what the method reported and :func:`accuracy` of its draws."""
    info = {k: v for k, v in raw.items() if k not in ("particles", "weights")}
    if "error" in raw:
        return info
    x = np.asarray(raw["particles"], float)
    w = np.asarray(raw["weights"], float) if "weights" in raw else np.ones(len(x))
    try:
        scores = accuracy(x, w, inst, max_draws, inst.seed)
    except (ValueError, np.linalg.LinAlgError) as exc:
        return {**info, "error": f"scoring failed: {exc}"}
    return {**info, **scores, "over_budget": int(raw.get("num_simulations", 0)) > budget}


# ----------------------------------------------------------------------------- summary


def _mean_se(values: Sequence[float] | np.ndarray) -> list[float | None]:
    v = np.asarray(values, float)
    if len(v) == 0:
        return [None, None]
    return [float(v.mean()), float(v.std(ddof=1) / np.sqrt(len(v))) if len(v) > 1 else None]


def summarise(cells: list[dict[str, Any]]) -> dict[str, Any]:
    """Mean and standard error over seeds of a (problem, budget, method)'s cells."""
    ok = [c for c in cells if "energy_distance" in c]
    out: dict[str, Any] = {
        "seeds": len(cells),
        "seeds_ok": len(ok),
        "errors": sorted({c["error"] for c in cells if "error" in c}),
    }
    if any("not_run" in c for c in cells):
        out["not_run"] = sum("not_run" in c for c in cells)
    if not ok:
        return out
    covered = np.array([c["covered_90"] for c in ok], bool)
    sd_ratio = np.array([c["sd_ratio"] for c in ok], float)
    # Cells that ran beside other work (``cpu_shared``) or were timed on another machine
    # (``timed_elsewhere``, imported) count for accuracy, not for time.
    timed = [c for c in ok if not c.get("cpu_shared") and not c.get("timed_elsewhere")]
    out.update(
        {
            "energy_distance": _mean_se([c["energy_distance"] for c in ok]),
            "mean_error_in_sd": _mean_se([c["mean_error_in_sd"] for c in ok]),
            "sd_ratio": [_mean_se(sd_ratio[:, j]) for j in range(sd_ratio.shape[1])],
            "sd_ratio_geomean": _mean_se(np.exp(np.log(np.maximum(sd_ratio, 1e-12)).mean(axis=1))),
            "coverage_90": float(covered.mean()),  # over seeds and parameters
            "coverage_90_joint": float(covered.all(axis=1).mean()),  # all parameters at once
            "coverage_90_per_parameter": covered.mean(axis=0).tolist(),
            "num_simulations": float(np.mean([c.get("num_simulations", 0) for c in ok])),
            "max_simulations": int(max(c.get("num_simulations", 0) for c in ok)),
            "over_budget": sum(bool(c.get("over_budget")) for c in ok),
            "run_s": _mean_se([c["run_s"] for c in timed if c.get("run_s") is not None]),
            "process_wall_s": _mean_se([c["process_wall_s"] for c in timed if c.get("process_wall_s") is not None]),
            "timed_seeds": sum(c.get("run_s") is not None for c in timed),
        }
    )
    if any("validated" in c for c in ok):
        out["validated"] = sum(bool(c.get("validated")) for c in ok)
    return out


def short_error(text: str) -> str:
    """A failed cell's error without its exit-status prefix and the arrays a library printed
    (ELFI's NUTS names its start point), so that seeds failing alike read as one reason."""
    text = re.sub(r"^exit -?\d+: ", "", str(text))
    return " ".join(re.sub(r"\s*\[[^\]]*\]", "", text).split())


def _why(s: dict[str, Any]) -> list[str]:
    """Generated reasons for a surrogate's energy distance: failures, bias, width."""
    reasons = []
    if s.get("seeds_ok", 0) < s.get("seeds", 0):
        first = short_error(s["errors"][0]) if s.get("errors") else "?"
        reasons.append(f"failed on {s['seeds'] - s['seeds_ok']} of {s['seeds']} seeds ({first[:200]})")
    if "energy_distance" not in s:
        return reasons
    if s["mean_error_in_sd"][0] > 0.5:
        reasons.append(f"mean off by {s['mean_error_in_sd'][0]:.2f} exact sd")
    lo = min(r[0] for r in s["sd_ratio"])
    hi = max(r[0] for r in s["sd_ratio"])
    if lo < 0.8:
        reasons.append(f"too narrow (sd ratio down to {lo:.2f})")
    if hi > 1.25:
        reasons.append(f"too wide (sd ratio up to {hi:.2f})")
    if "validated" in s and s["validated"] < s["seeds_ok"]:
        reasons.append(f"emulator not validated on {s['seeds_ok'] - s['validated']} of {s['seeds_ok']} seeds")
    if not reasons:
        reasons.append("shape (sd and mean close, energy distance not)")
    return reasons


def closest(summary: dict[str, dict[str, Any]], n_seeds: int) -> dict[str, Any]:
    """Which method is closest to exact at one (problem, budget), and where the surrogate stands.

    Only methods that ran on every seed compete.  The surrogate is "within seed error" of the
    best peer when its mean energy distance exceeds the peer's by at most their combined
    standard error.
    """
    ranked = sorted(
        (s["energy_distance"][0], m)
        for m, s in summary.items()
        if m != "exact" and s.get("seeds_ok") == n_seeds and "energy_distance" in s
    )
    peers_ = [(ed, m) for ed, m in ranked if m not in JAXABC_METHODS]
    out: dict[str, Any] = {"ranking": [m for _, m in ranked], "closest": ranked[0][1] if ranked else None}
    sur = summary.get(SURROGATE, {})
    out["closest_peer"] = peers_[0][1] if peers_ else None
    if "energy_distance" not in sur or sur.get("seeds_ok") != n_seeds:
        out.update(surrogate_closest=False, within_seed_error=False, why=_why(sur) or ["not run"])
        return out
    if not peers_:
        out.update(surrogate_closest=True, within_seed_error=True)
        return out
    best = summary[peers_[0][1]]
    diff = sur["energy_distance"][0] - best["energy_distance"][0]
    se = math.hypot(sur["energy_distance"][1] or 0.0, best["energy_distance"][1] or 0.0)
    out.update(surrogate_closest=diff <= 0, within_seed_error=diff <= se, energy_distance_excess=diff)
    if diff > 0:
        out["why"] = _why(sur)
    return out


def assemble(
    cells: dict[tuple[str, str, int, int], dict[str, Any]],
    problems: Sequence[str],
    methods: Sequence[str],
    budgets: Sequence[int],
    seeds: Sequence[int],
) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """Summary per (problem, budget, method), the closest method per (problem, budget), the goal
    (budgets up to :data:`GOAL_MAX_BUDGET`)."""
    summary: dict[str, Any] = {}
    verdicts: dict[str, Any] = {}
    for p in problems:
        summary[p], verdicts[p] = {}, {}
        for b in budgets:
            per = {}
            for m in ["exact", *methods]:
                reason = skip_reason(m, b)
                if reason:
                    per[m] = {"skipped": reason}
                    continue
                per[m] = summarise([cells[(p, m, b, s)] for s in seeds if (p, m, b, s) in cells])
            summary[p][str(b)] = per
            verdicts[p][str(b)] = closest(per, len(seeds))  # the goal reads budgets up to 200 only
    goal_budgets = [b for b in budgets if b <= GOAL_MAX_BUDGET]
    met = {
        p: bool(goal_budgets) and all(verdicts[p][str(b)]["surrogate_closest"] for b in goal_budgets) for p in problems
    }
    misses = [
        {"problem": p, "budget": b, **{k: verdicts[p][str(b)].get(k) for k in ("closest", "within_seed_error", "why")}}
        for p in problems
        for b in goal_budgets
        if p in GOAL_PROBLEMS and not verdicts[p][str(b)]["surrogate_closest"]
    ]
    goal = {
        "statement": GOAL,
        "budgets": goal_budgets,
        "problems_met": [p for p in problems if met[p] and p in GOAL_PROBLEMS],
        "problems": [p for p in GOAL_PROBLEMS if p in problems],
        "problems_needed": 4 if set(GOAL_PROBLEMS) <= set(problems) else None,
        "met": sum(met[p] for p in GOAL_PROBLEMS) >= 4 if set(GOAL_PROBLEMS) <= set(problems) else None,
        "misses": misses,
    }
    return summary, verdicts, goal


# ----------------------------------------------------------------------------- main


def parse(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--problems", nargs="+", default=list(PROBLEM_NAMES), choices=PROBLEM_NAMES)
    p.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    p.add_argument("--budgets", type=int, nargs="+", default=[50, 100, 200, 500])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    p.add_argument("--draws", type=int, default=1000, help="posterior draws asked of each method")
    p.add_argument("--energy-draws", type=int, default=1000, help="most draws of a method in the energy distance")
    p.add_argument("--exact-draws", type=int, default=2000, help="exact draws in the energy distance")
    p.add_argument("--timeout", type=float, default=1800, help="seconds per cell's process")
    default_cache = Path.home() / ".cache" / "jaxabc_benchmarks"
    p.add_argument("--cache-dir", type=Path, default=default_cache / "surrogate_peers", help="finished cells")
    p.add_argument("--venv-dir", type=Path, default=default_cache, help="the peers' virtual environments")
    p.add_argument(
        "--no-compilation-cache",
        action="store_true",
        help="compile every jaxabc cell from scratch (default: JAX's persistent cache under --cache-dir/xla)",
    )
    p.add_argument(
        "--cached-only",
        action="store_true",
        help="assemble the result from cached cells only; the others are reported as not run",
    )
    p.add_argument(
        "--carry-over",
        type=int,
        default=0,
        metavar="N",
        help="re-key jaxabc cells of earlier jaxabc code after N of them reproduce exactly (carry_over)",
    )
    p.add_argument(
        "--cpu-shared",
        action="store_true",
        help="mark the cells this run makes as timed beside other work: they count for accuracy, not wall time",
    )
    p.add_argument(
        "--import-cells",
        type=Path,
        metavar="RESULT",
        help="take the peers' scored cells from a saved result where problem, peer and metric code are unchanged",
    )
    p.add_argument(
        "--keep-other-problems",
        action="store_true",
        help="with --import-cells: keep the saved result's cells of the problems not named in --problems "
        "(one part per problem, so a session can rerun one problem)",
    )
    p.add_argument("--fresh", action="store_true", help="rerun cells already in the cache (and append them)")
    p.add_argument("--retry-errors", action="store_true", help="rerun cached cells that ended in an error")
    p.add_argument("--quick", action="store_true", help="linear + banana, B 60, seed 0, surrogate + sbi NPE")
    p.add_argument("--output", type=Path, help="write the result here instead of benchmarks/results/")
    p.add_argument("--child", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.quick:
        args.problems, args.budgets, args.seeds = ["linear", "banana"], [60], [0]
        args.methods, args.fresh = ["jaxabc_surrogate", "sbi_npe"], True
    return args


def keep_other_problems(
    args: argparse.Namespace,
) -> tuple[dict[tuple[str, str, int, int], dict[str, Any]], dict[str, str]]:
    """The saved result's cells of the problems not in ``args.problems`` (every method, as saved),
    and those problems' fingerprints; for ``--keep-other-problems``.

    Refused with a one-line message (``SystemExit``) when the saved result cannot be merged with
    this run: no ``--import-cells`` result, other methods, budgets or seeds, other metric code, or
    a peer whose code changed (its kept cells would then mix two versions of the peer).
    """
    if args.import_cells is None or not args.import_cells.is_file():
        raise SystemExit("--keep-other-problems needs --import-cells with the saved result to keep cells from")
    saved = load_saved(args.import_cells)
    for key in ("methods", "budgets", "seeds"):
        if list(saved.get(key) or []) != list(getattr(args, key)):
            raise SystemExit(
                f"--keep-other-problems: the saved result's {key} {saved.get(key)} differ from this run's "
                f"{getattr(args, key)}; run every problem"
            )
    peer_methods = [m for m in args.methods if m not in JAXABC_METHODS]
    hashes = saved_hashes(saved, peer_methods)
    if hashes["scoring"] != scoring_hash():
        raise SystemExit("--keep-other-problems: the saved cells were scored by other metric code; run every problem")
    changed = [m for m in peer_methods if hashes["method"].get(m) != method_hash(m)]
    if changed:
        raise SystemExit(
            f"--keep-other-problems: the code of {', '.join(changed)} changed since the saved result; run every problem"
        )
    others = [p for p in saved.get("problems") or {} if p not in args.problems]
    unknown = [p for p in others if p not in PROBLEMS]
    if unknown:
        raise SystemExit(f"--keep-other-problems: the saved result has problems this script lacks: {unknown}")
    kept = {
        (c["problem"], c["method"], int(c["budget"]), int(c["seed"])): {
            k: v for k, v in c.items() if k not in ("problem", "method", "budget", "seed")
        }
        for c in saved["cells"]
        if c["problem"] in others
    }
    return kept, {p: saved["problem_hash"][p] for p in others}


def main(argv: Sequence[str] | None = None) -> dict[str, Any] | None:
    args = parse(argv)
    if args.child:
        print(json.dumps(run_jaxabc_child(json.loads(args.child))))
        return None
    # The jaxabc runs happen in child processes: importing what they run puts it in this result's
    # fingerprint.
    import jax

    import jaxabc
    import jaxabc.surrogate
    from benchmarks._common import command_line, write_result

    t_start = time.perf_counter()
    cache_file = args.cache_dir / "cells.jsonl"
    cached = load_cache(cache_file)
    p_hash = {p: problem_hash(p) for p in args.problems}
    m_hash = {m: method_hash(m) for m in args.methods}
    envs = make_envs(args.methods, args.venv_dir)
    if args.carry_over and not args.cached_only:
        grid = [
            (p, m, b, s)
            for p in args.problems
            for m in args.methods
            if m in JAXABC_METHODS
            for b in args.budgets
            if not skip_reason(m, b)
            for s in args.seeds
        ]

        def rerun(p: str, m: str, b: int, s: int) -> dict[str, Any]:
            return run_cell(instance(p, s, args.exact_draws), m, b, envs, args)

        carried = carry_over(cached, cache_file, grid, p_hash, m_hash, args.carry_over, rerun)
        print(f"carry-over: {carried} cells carried to the current jaxabc code", flush=True)
        cached = load_cache(cache_file)
    imported: dict[tuple[str, str, int, int], dict[str, Any]] = {}
    if args.import_cells and not args.import_cells.is_file():
        print(f"--import-cells: no result at {args.import_cells}; every cell not in the cache is run", flush=True)
    elif args.import_cells:
        from benchmarks._common import machine

        saved = load_saved(args.import_cells)
        peer_methods = [m for m in args.methods if m not in JAXABC_METHODS]
        hashes = saved_hashes(saved, peer_methods)
        imported = import_cells(saved, hashes, args.problems, args.methods, p_hash, m_hash, machine())
        print(f"--import-cells: {len(imported)} peer cells can be taken from {args.import_cells}", flush=True)
    kept, kept_hashes = keep_other_problems(args) if args.keep_other_problems else ({}, {})
    cells: dict[tuple[str, str, int, int], dict[str, Any]] = dict(kept)
    ran = reused = 0
    for p in args.problems:
        for s in args.seeds:
            inst = instance(p, s, args.exact_draws)
            reference = accuracy(inst.reference_draws, np.ones(len(inst.reference_draws)), inst)
            for b in args.budgets:
                cells[(p, "exact", b, s)] = reference
                for m in args.methods:
                    if skip_reason(m, b):
                        continue
                    key = cell_key(p, m, b, s, p_hash[p], m_hash[m])
                    hit = cached.get(key)
                    # A cell without draws (an earlier cache format) is run again.
                    usable = hit is not None and ("particles" in hit["result"] or "error" in hit["result"])
                    if (
                        hit is not None
                        and usable
                        and not args.fresh
                        and not (args.retry_errors and "error" in hit["result"])
                    ):
                        cells[(p, m, b, s)] = score(hit["result"], inst, b, args.energy_draws)
                        reused += 1
                        continue
                    taken = imported.get((p, m, b, s))
                    if taken is not None and not args.fresh and not (args.retry_errors and "error" in taken):
                        cells[(p, m, b, s)] = taken
                        continue
                    if args.cached_only:
                        cells[(p, m, b, s)] = {"not_run": "not in the cache (--cached-only)"}
                        continue
                    t0 = time.perf_counter()
                    raw = run_cell(inst, m, b, envs, args)
                    ran += 1
                    if not str(raw.get("error", "")).startswith("virtual environment"):
                        cell = {"key": key, "problem": p, "method": m, "budget": b, "seed": s, "result": raw}
                        append_cache(cache_file, cell)
                    result = cells[(p, m, b, s)] = score(raw, inst, b, args.energy_draws)
                    print(f"{p} B={b} seed={s} {m}: {_brief(result)} ({time.perf_counter() - t0:.0f} s)", flush=True)
    problems = [p for p in PROBLEM_NAMES if p in args.problems or p in kept_hashes]
    p_hash = {**kept_hashes, **p_hash}
    summary, verdicts, goal = assemble(cells, problems, args.methods, args.budgets, args.seeds)
    versions = {
        m: sorted({str(c.get("version")) for (_, mm, _, _), c in cells.items() if mm == m and "version" in c})
        for m in args.methods
    }
    payload = {
        "format": 2,
        "description": (__doc__ or "").split("\n\n")[0],
        "problems": {p: {k: v for k, v in PROBLEMS[p].items()} for p in problems},
        "methods": list(args.methods),
        "method_versions": versions,
        "sbi_install": SBI_INSTALL,
        "nle_mcmc": NLE_MCMC,
        "budgets": args.budgets,
        "seeds": args.seeds,
        "draws": args.draws,
        "exact_draws": args.exact_draws,
        "energy_draws": args.energy_draws,
        "problem_hash": p_hash,
        "method_hash": m_hash,
        "scoring_hash": scoring_hash(),
        "jaxabc_compilation_cache": not args.no_compilation_cache,
        "peers": {
            m: {"venv": peers()[m].venv, "requirement": peers()[m].requirement, **_only_error(envs[m])} for m in envs
        },
        "cells": [
            {"problem": p, "method": m, "budget": b, "seed": s, **c}
            for (p, m, b, s), c in sorted(cells.items(), key=lambda kv: (kv[0][0], kv[0][2], kv[0][1], kv[0][3]))
        ],
        "summary": summary,
        "closest": verdicts,
        "goal": goal,
        "cells_run": ran,
        "cells_not_run": sum("not_run" in c for c in cells.values()),
        "cells_reused": reused,
        "cells_carried": sum("carried_from" in c for c in cells.values()),
        "cells_imported": sum("imported_from" in c for c in cells.values()),
        "benchmark_wall_s": time.perf_counter() - t_start,
        # What a rerun after a jaxabc change costs: its cells run again, one after another (the
        # peers' come from the result), whatever this run reused or imported.
        "rerun_cost_s": sum(
            float(c.get("process_wall_s") or 0.0) for (_, m, _, _), c in cells.items() if m.startswith("jaxabc")
        ),
        # The same per problem: each problem is a part of the result (``--keep-other-problems``).
        "rerun_cost_s_parts": {
            p: sum(
                float(c.get("process_wall_s") or 0.0)
                for (pp, m, _, _), c in cells.items()
                if pp == p and m.startswith("jaxabc")
            )
            for p in problems
        },
        "jax": jax.__version__,
        "jaxabc": jaxabc.__version__,
    }
    name = args.output if args.output else "surrogate_peers"
    # Each problem run here is a part with this run's provenance (the quick JSON's too, so that a
    # part's quick check finds its part); a kept problem keeps its own.
    path = write_result(name, payload, quick=args.quick, command=command_line(), part=args.problems)
    print(summary_text(payload))
    print(f"wrote {path}")
    return payload


def _only_error(env: dict[str, Any]) -> dict[str, Any]:
    return {"error": env["error"]} if "error" in env else {}


def _brief(result: dict[str, Any]) -> str:
    if "error" in result:
        return f"error: {str(result['error'])[:300]}"
    sd = np.round(result["sd_ratio"], 2).tolist()
    return (
        f"ED {result['energy_distance']:.3f} mean err {result['mean_error_in_sd']:.2f} sd ratio {sd} "
        f"sims {result['num_simulations']} run {result.get('run_s', float('nan')):.1f} s"
    )


def summary_text(d: dict[str, Any]) -> str:
    """A plain-text summary of a result: energy distance per (problem, budget, method)."""
    lines = []
    for p, per_budget in d["summary"].items():
        for b, per in per_budget.items():
            lines.append(f"{p} B={b}")
            for m, s in per.items():
                if "skipped" in s:
                    continue
                if "energy_distance" not in s:
                    lines.append(f"  {m:22s} errors: {s.get('errors')}")
                    continue
                ed, se = s["energy_distance"]
                sd = "/".join(f"{r[0]:.2f}" for r in s["sd_ratio"])
                wall = s["run_s"][0] if s.get("run_s") and s["run_s"][0] is not None else float("nan")
                lines.append(
                    f"  {m:22s} ED {ed:.3f}"
                    + (f" +- {se:.3f}" if se is not None else "")
                    + f"  mean err {s['mean_error_in_sd'][0]:.2f}  sd ratio {sd}  cov90 {s['coverage_90']:.2f}"
                    + f"  sims {s['num_simulations']:.0f}  run {wall:.1f} s"
                )
            v = d["closest"].get(p, {}).get(b)
            if v:
                lines.append(f"  closest: {v['closest']}; surrogate closest: {v['surrogate_closest']}")
    lines.append(f"goal: {d['goal']}")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
