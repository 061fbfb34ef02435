"""Helpers of :mod:`jaxabc.surrogate.algorithm`: failure text, noise correlation, emulator calls."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.surrogate import sampling

_FLAG = "NOT VALIDATED: "


def _failure_text(state: Any, max_emulator_ratio: float) -> str:
    parts = []
    if float(state.emulator_ratio) > max_emulator_ratio:
        parts.append(
            f"the emulator's variance over the posterior is {float(state.emulator_ratio):.2g} times "
            "the simulator noise: the GP does not resolve the simulator (too rough, or too few runs)"
        )
    if not bool(state.lack_of_fit_ok):
        parts.append(
            "fitted noise far above the replicate scatter: the GP cannot represent the "
            "simulator (a discontinuity or a phase change?)"
        )
    if np.isfinite(state.coverage):
        parts.append(
            f"held-out 95 % coverage {float(state.coverage):.2f}, mean squared standardised "
            f"error {float(state.mean_squared_error):.2f}"
        )
    return "; ".join(parts)


def _noise_correlation(residuals: np.ndarray) -> np.ndarray:
    """Correlation ``(q, q)`` of leave-one-out residuals ``(n, q)``, entries below three standard
    errors (``3 / sqrt(n)``) set to zero: a spurious correlation tilts the posterior, a missed
    weak one costs little."""
    n, q = residuals.shape
    if q == 1 or n < 5:
        return np.eye(q)
    corr = np.corrcoef(residuals.T)
    corr = np.where(np.isfinite(corr) & (np.abs(corr) >= 3.0 / np.sqrt(n)), corr, 0.0)
    np.fill_diagonal(corr, 1.0)
    # Thresholding can break positive definiteness: clip the spectrum and renormalise.
    w, v = np.linalg.eigh(corr)
    corr = (v * np.maximum(w, 1e-3)) @ v.T
    s = np.sqrt(np.diag(corr))
    return corr / np.outer(s, s)


@jax.jit
def _evaluate_jit(model: sampling.LikelihoodModel, x: jax.Array) -> tuple[jax.Array, jax.Array]:
    loglik, ratio = sampling.log_likelihood_terms(model, x)
    return loglik + jnp.log(jnp.maximum(sampling.feasibility(model.feasible, x), 1e-300)), ratio


def _evaluate(model: sampling.LikelihoodModel, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lp, ratio = _evaluate_jit(model, jnp.asarray(x))
    return np.asarray(lp, np.float64), np.asarray(ratio, np.float64)
