"""Helpers of :mod:`jaxabc.surrogate.algorithm`: failure text, noise correlation, emulator calls."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.surrogate import design, diagnostics, sampling

_FLAG = "NOT VALIDATED: "

#: Posterior share below the design level from which a failed validation names that band.
UNTESTED_SHARE_WARN = 0.25


def _untested_share(
    model: sampling.LikelihoodModel, candidates: np.ndarray, draws: np.ndarray, log_weights: np.ndarray
) -> float:
    """Posterior weight of unit-box ``draws (P, d)`` (``log_weights (P,)``, ``-inf`` pads) where the
    success classifier is below :func:`.design.design_level` over ``candidates (n, d)`` (extra
    columns, the discrepancy sds of augmented points, are ignored)."""
    candidates = np.asarray(sampling.theta_columns(model, np.asarray(candidates)))
    draws = np.asarray(sampling.theta_columns(model, np.asarray(draws)))
    level = design.design_level(np.asarray(sampling.feasibility(model.feasible, jnp.asarray(candidates))))
    p = np.asarray(sampling.feasibility(model.feasible, jnp.asarray(draws)))
    lw = np.asarray(log_weights, np.float64)
    w = np.exp(lw - np.max(lw))
    return float(w @ (p < level) / w.sum())


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
    if not bool(state.joint_ok):
        parts.append(
            f"held-out joint (Mahalanobis) error {float(state.joint_mean_squared_error):.2f} per output, "
            "too large for the modelled noise correlation: the summaries' joint noise is not captured"
        )
    errors = np.asarray(state.holdout_errors)
    num_run = int(np.sum(np.any(np.isfinite(errors), axis=1)))
    if num_run < errors.shape[0]:
        text = f"{errors.shape[0] - num_run} of {errors.shape[0]} held-out runs failed"
        if num_run < diagnostics.MIN_HOLDOUT_RUNS:
            text += f", fewer than {diagnostics.MIN_HOLDOUT_RUNS} succeeded: too few to check the emulator"
        parts.append(text)
    share = float(state.untested_share)
    if num_run < errors.shape[0] and share >= UNTESTED_SHARE_WARN:
        parts.append(
            f"{share:.0%} of the posterior lies where the success classifier is below the design "
            "level (design.MIN_DESIGN_SUCCESS), a band no design run enters: its fit there rests on "
            "the emulator's extrapolation. More budget lets the failed held-out runs join the "
            "design; for failures that are phase changes, set min_feasibility to the design level"
        )
    if np.isfinite(state.coverage):
        parts.append(
            f"held-out 95 % coverage {float(state.coverage):.2f}, mean squared standardised "
            f"error {float(state.mean_squared_error):.2f}"
        )
    return "; ".join(parts)


def _misfit_text(misfit: dict) -> str:
    residuals = misfit["standardised_residuals"]
    worst = sorted((i for i, r in enumerate(residuals) if r is not None), key=lambda i: -abs(residuals[i]))[:3]
    which = "principal component" if misfit["projected"] else "summary"
    named = ", ".join(f"{which} {i} ({residuals[i]:+.1f} sd)" for i in worst)
    return (
        f"surrogate: the observed summaries lie outside the model's posterior predictive "
        f"(squared Mahalanobis distance {misfit['mahalanobis_squared']:.3g} on {misfit['dof']} outputs, "
        f"p = {misfit['p_value']:.2g}; largest mean standardised residuals: {named}). No parameter value "
        "reproduces the data within the simulator noise: the posterior is the best fit of a "
        "misspecified model, and its width reflects the simulator noise, not the misfit. Add the "
        "data's measurement error (jaxabc.noise.MeasurementError) or read the interval as conditional "
        "on the model"
    )


def _noise_correlation(residuals: np.ndarray, active: np.ndarray | None = None) -> np.ndarray:
    """Correlation ``(q, q)`` of leave-one-out residuals ``(n, q)``, Ledoit-Wolf shrunk.

    Summaries of one trajectory (RDF features) are strongly correlated, so the synthetic
    likelihood needs their joint noise.  A sample correlation of ~100 residuals in ~10 outputs
    has spuriously small eigenvalues, along which the likelihood becomes far too sharp (water,
    2026-11-24: held-out Mahalanobis distances 5x their chi-square mean).  Shrinkage towards the
    identity with the Ledoit-Wolf intensity (scikit-learn) keeps it well conditioned.  Only the
    ``active`` outputs (default all) are correlated; the others get identity rows.
    """
    n, q = residuals.shape
    out = np.eye(q)
    keep = np.ones(q, bool) if active is None else np.asarray(active, bool)
    sd = residuals.std(axis=0)
    # An output whose residuals do not vary (a constant summary) has no correlation to estimate.
    keep = keep & np.isfinite(sd) & (sd > 0)
    if keep.sum() < 2 or n < 5:
        return out
    from sklearn.covariance import ledoit_wolf

    cov, _ = ledoit_wolf(residuals[:, keep] / sd[keep])
    s = np.sqrt(np.diag(cov))
    out[np.ix_(keep, keep)] = cov / np.outer(s, s)
    return out


@jax.jit
def _evaluate_jit(model: sampling.LikelihoodModel, x: jax.Array) -> tuple[jax.Array, jax.Array]:
    loglik, ratio = sampling.log_likelihood_terms(model, x)
    return loglik + sampling.log_feasibility_term(model, x), ratio


def _evaluate(model: sampling.LikelihoodModel, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lp, ratio = _evaluate_jit(model, jnp.asarray(x))
    return np.asarray(lp, np.float64), np.asarray(ratio, np.float64)
