"""Shared helpers of the surrogate's steps and of :mod:`.evidence`: the surrogate posterior's
log density on host arrays, its weight where runs are not expected to succeed, and a
single-threaded BLAS for the small matrices of the fits."""

from __future__ import annotations

import contextlib

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.surrogate import design, sampling

__all__ = ["log_posterior_terms", "single_threaded_blas", "untested_share"]


def single_threaded_blas() -> contextlib.AbstractContextManager:
    """Limit BLAS to one thread: the matrices here are small (hundreds of rows), and a
    multi-threaded OpenBLAS on a loaded machine spins orders of magnitude slower.  A no-op
    without ``threadpoolctl``."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # optional: without it only speed suffers
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


@jax.jit
def _log_posterior_terms(model: sampling.LikelihoodModel, x: jax.Array) -> tuple[jax.Array, jax.Array]:
    loglik, ratio = sampling.log_likelihood_terms(model, x)
    return loglik + sampling.log_feasibility_term(model, x), ratio


def log_posterior_terms(model: sampling.LikelihoodModel, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The surrogate posterior's unnormalised log density at unit-box points ``x (n, d + G)``
    and the emulator-to-noise variance ratio ``mean_j var_j / noise_j^2`` there, both ``(n,)``
    float64 (one compilation per shape of ``x``)."""
    lp, ratio = _log_posterior_terms(model, jnp.asarray(x))
    return np.asarray(lp, np.float64), np.asarray(ratio, np.float64)


def untested_share(
    model: sampling.LikelihoodModel, candidates: np.ndarray, draws: np.ndarray, log_weights: np.ndarray
) -> float:
    """Posterior weight of unit-box ``draws (P, d)`` (``log_weights (P,)``, ``-inf`` pads) where the
    success classifier is below :func:`.design.design_level` over ``candidates (n, d)`` (extra
    columns, the discrepancy sds of augmented points, are ignored); in ``[0, 1]``."""
    candidates = np.asarray(sampling.theta_columns(model, np.asarray(candidates)))
    draws = np.asarray(sampling.theta_columns(model, np.asarray(draws)))
    level = design.design_level(np.asarray(sampling.feasibility(model.feasible, jnp.asarray(candidates))))
    p = np.asarray(sampling.feasibility(model.feasible, jnp.asarray(draws)))
    lw = np.asarray(log_weights, np.float64)
    w = np.exp(lw - np.max(lw))
    return float(w @ (p < level) / w.sum())
