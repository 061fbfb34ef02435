"""Marginal likelihood (evidence) of the surrogate's synthetic likelihood, for model choice.

For a model ``m`` with a uniform prior on its box, the evidence of the observed summaries
``s_obs`` under the emulated synthetic likelihood is

    Z_m = integral over the box of  p_ok(theta) N(s_obs; mu(theta), Sigma(theta)) dtheta / volume,

``mu`` the emulated mean, ``Sigma`` the simulator's noise covariance plus the emulator's own
predictive variance, ``p_ok`` the fitted chance that a run succeeds (the same density the NUTS
posterior samples, constraints included; see :mod:`.sampling`).  In the unit box the prior
density is one, so ``Z_m`` is an expectation under the uniform distribution; it is estimated by
importance sampling with a defensive mixture (half scrambled Sobol points over the box, half a
Gaussian fitted to a first uniform pass), and its Monte Carlo standard error is the sample
standard deviation of the importance terms over ``sqrt(n)``.  The larger part of the error is
usually the design's: the noise levels, their correlation and the emulator are estimated from
a few hundred runs.  A delete-a-group jackknife (8 groups of design rows, each refit from the
rest, on the same points) measures it; the two are added in quadrature.

The emulator works on standardised summaries ``z = (s - mean) / scale``; the density of the
raw summaries carries the Jacobian ``-sum_j log scale_j``, which differs between models (each
standardises with its own design), so it is added here.  When more summaries than
``max_outputs`` were projected onto principal components the likelihood is of a model-specific
projection and no evidence comparable across models exists: the evidence is then NaN.

With measured data (the builder's ``observation_error``) ``Sigma`` holds the measurement
covariance too; with a model discrepancy (``discrepancy``) the group sds ``delta`` join
``theta``: the integral runs over the augmented unit box, the uniform prior of ``delta`` on
``[0, max_sd]`` included, and ``Sigma`` holds ``diag(variance(delta))``.

What the error does not contain: the design's own randomness beyond what the jackknife sees
(it is first order), and the choice of the design points, which follow each model's posterior.
Model probabilities from these
evidences compare how well each model reproduces the *summaries* within the simulator's noise:
under misspecification (no model fits within the noise) they are dominated by the least-bad
fit and become overconfident; read them with the misfit diagnostics.

Reference: Price, Drovandi, Lee & Nott (2018), Bayesian synthetic likelihood, JCGS 27, 1-11
(the likelihood); Hesterberg (1995) for the defensive mixture.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.surrogate import design, emulator, sampling
from jaxabc.surrogate._fit import ROLE_EMPTY, ROLE_HOLDOUT, fit_likelihood
from jaxabc.surrogate._settings import measured_data_from_settings
from jaxabc.surrogate._support import log_posterior_terms

__all__ = ["Evidence", "evidence_from_state", "likelihood_from_state", "observed_misfit", "with_evidence"]

#: Points per importance-sampling pass and per chunk of emulator evaluations.
NUM_SAMPLES = 1 << 14
#: Groups of the delete-a-group jackknife over the design.
NUM_GROUPS = 8
_CHUNK = 4096


class Evidence(NamedTuple):
    """``log Z`` of the observed summaries and its standard error; ``importance_se`` and
    ``jackknife_se`` its importance-sampling and design (emulator refit) parts;
    ``active`` (bool, shape (q,)) the summaries in the likelihood; ``num_samples`` the
    importance-sampling points."""

    log_z: float
    log_z_se: float
    importance_se: float
    jackknife_se: float
    active: np.ndarray
    num_samples: int


def likelihood_from_state(
    state: Any, low: np.ndarray, high: np.ndarray, observed: np.ndarray, settings: dict, drop: np.ndarray | None = None
) -> tuple[emulator.OutputTransform, sampling.LikelihoodModel]:
    """The synthetic-likelihood model a finished surrogate run sampled, refitted from its state.

    ``state`` is the run's :class:`~jaxabc.surrogate.SurrogateState`; ``settings`` its
    algorithm's settings (``max_outputs``, ``max_simulations``, ``min_feasibility``).  The
    refit is the run's own last fit (:func:`._fit.fit_likelihood` on the same rows, started
    from the state's hyper-parameters ``hyper`` where it has them, besides the fixed starts, as
    every fit of the run was); ``drop`` (bool, shape (M,)) leaves rows out (the jackknife).
    A measurement error and a discrepancy in ``settings`` (``observation_error``,
    ``discrepancy``) enter the model as in the run, and so does the state's factor on the
    emulator's variance (``variance_scale``, 1 where the state has none).
    """
    observation_error, discrepancy = measured_data_from_settings(settings)
    hyper = getattr(state, "hyper", None)
    transform, _, model, _ = fit_likelihood(
        state,
        low,
        high,
        observed,
        int(settings["max_outputs"]),
        int(settings["max_simulations"]),
        sampling.log_level(float(settings["min_feasibility"])),
        drop,
        observation_error=observation_error,
        discrepancy=discrepancy,
        noise_model=str(settings.get("noise_model", "homoscedastic")),
        warm_start=None if hyper is None or not np.any(hyper) else np.asarray(hyper, np.float64),
        variance_scale=float(getattr(state, "variance_scale", 1.0)),
    )
    return transform, model


def _log_density(model: sampling.LikelihoodModel, x: np.ndarray) -> np.ndarray:
    return np.concatenate([log_posterior_terms(model, x[i : i + _CHUNK])[0] for i in range(0, len(x), _CHUNK)])


def _points(model: sampling.LikelihoodModel, rng: np.random.Generator, num_samples: int) -> design.Candidates:
    """The importance-sampling points: half Sobol over the box, half a Gaussian fitted to a
    first uniform pass and refined while it resolves the density poorly (the defensive
    mixture, :func:`.design.importance_pool`), with their log proposal density."""
    d = sampling.num_parameters(model)  # theta's columns, and the discrepancy sds' if any
    try:
        points, _ = design.importance_pool(rng, d, num_samples, lambda x: (_log_density(model, x),))
    except FloatingPointError:
        raise FloatingPointError("the synthetic likelihood is not finite anywhere in the box") from None
    return points


def _estimate(
    model: sampling.LikelihoodModel, transform: emulator.OutputTransform, points: design.Candidates
) -> tuple[float, float]:
    """``log Z`` of the raw summaries and its importance-sampling standard error."""
    log_terms = _log_density(model, points.x) - points.log_q
    top = np.max(log_terms)
    terms = np.exp(log_terms - top)
    # Density of the raw summaries: the standardisation's Jacobian and the Gaussian constant.
    active = np.asarray(model.active, bool)
    scale = np.asarray(transform.scale, np.float64)
    constant = -np.sum(np.log(scale[active])) - 0.5 * active.sum() * np.log(2.0 * np.pi)
    # The relative standard error of Z is the standard error of log Z (delta method).
    rel_se = terms.std(ddof=1) / np.sqrt(len(terms)) / terms.mean()
    return float(top + np.log(terms.mean()) + constant), float(rel_se)


def evidence_from_state(
    state: Any,
    low: np.ndarray,
    high: np.ndarray,
    observed: np.ndarray,
    settings: dict,
    rng: np.random.Generator,
    num_samples: int = NUM_SAMPLES,
    num_groups: int = NUM_GROUPS,
    fitted: tuple[emulator.OutputTransform, sampling.LikelihoodModel] | None = None,
) -> Evidence:
    """``log Z`` of the raw observed summaries for a finished run, with its standard error.

    NaN (standard error NaN) when the summaries were projected (PCA): the projected likelihood
    is not a density of the raw summaries.  ``fitted``: the run's refitted
    :func:`likelihood_from_state`, when the caller has it already.
    """
    transform, model = fitted or likelihood_from_state(state, low, high, observed, settings)
    active = np.asarray(model.active, bool)
    if transform.rotation.shape[0] != transform.rotation.shape[1]:
        return Evidence(float("nan"), float("nan"), float("nan"), float("nan"), active, 0)
    points = _points(model, rng, num_samples)
    log_z, is_se = _estimate(model, transform, points)
    # Delete-a-group jackknife over the design rows (Efron & Tibshirani 1993, ch. 11): every
    # refit re-estimates the noise, the correlation and the hyper-parameters.
    role = np.asarray(state.role)
    design_rows = np.flatnonzero((role != ROLE_EMPTY) & (role != ROLE_HOLDOUT))
    labels = rng.permutation(design_rows.size) % num_groups
    replicates = []
    for g in range(num_groups):
        drop = np.zeros(role.shape, bool)
        drop[design_rows[labels == g]] = True
        t_g, m_g = likelihood_from_state(state, low, high, observed, settings, drop)
        if not np.array_equal(np.asarray(m_g.active, bool), active):
            continue
        replicates.append(_estimate(m_g, t_g, points)[0])
    r = np.asarray(replicates)
    g = r.size
    jk_se = float(np.sqrt((g - 1) / g * np.sum((r - r.mean()) ** 2))) if g >= 2 else float("nan")
    return Evidence(log_z, float(np.hypot(is_se, jk_se)), is_se, jk_se, active, len(points.x))


def observed_misfit(
    model: sampling.LikelihoodModel,
    transform: emulator.OutputTransform,
    x_draws: np.ndarray,
    weights: np.ndarray | None = None,
) -> dict[str, Any]:
    """How far the observed summaries lie from the posterior predictive of the emulated model.

    ``x_draws (P, d)``: posterior draws in the unit box (``(P, d + G)`` with a discrepancy),
    ``weights (P,)`` their weights (equal if ``None``; zero weights drop a draw).  The
    predictive covariance is the simulator's noise plus the emulator's variance plus the spread
    of the emulated mean over the draws, so the check includes the parameters' uncertainty;
    plus the measurement error and the posterior mean of the discrepancy covariance when the
    model has them (:class:`.sampling.LikelihoodModel`).  Returns the posterior mean of each
    output's standardised residual ``(z_obs - mu) / sqrt(noise^2 + var + extra)`` (``extra``
    those two terms' variance; ``None`` for outputs left
    out; in summary order unless the outputs were projected), the squared Mahalanobis distance
    of the observed summaries over the active outputs, its degrees of freedom and the
    chi-square tail probability: a small ``p_value`` says no parameter value reproduces the
    data within the noise (misspecification, or a measurement error missing).
    """
    from scipy.stats import chi2

    w = np.full(len(x_draws), 1.0) if weights is None else np.asarray(weights, np.float64)
    if w.shape != (len(x_draws),) or not np.all(w >= 0) or not w.sum() > 0:
        raise ValueError("observed_misfit: weights must be (P,), non-negative and not all zero")
    keep = w > 0
    x, w = np.asarray(x_draws)[keep], w[keep] / w[keep].sum()
    if x.shape[1] != sampling.num_parameters(model):
        raise ValueError(
            f"observed_misfit: draws have {x.shape[1]} columns, the model {sampling.num_parameters(model)} "
            "(theta, then the discrepancy sds)"
        )
    active = np.asarray(model.active, bool)
    means, variances = [], []
    for i in range(0, len(x), _CHUNK):
        m, v = emulator.predict(model.emulator, jnp.asarray(sampling.theta_columns(model, x[i : i + _CHUNK])))
        means.append(np.asarray(m, np.float64))
        variances.append(np.asarray(v, np.float64))
    mean, var = np.concatenate(means), np.concatenate(variances)
    # The noise sd at each draw (constant unless heteroscedastic), and its posterior rms.
    sd_draws = np.concatenate(
        [
            np.asarray(emulator.noise_sd(model.emulator, jnp.asarray(sampling.theta_columns(model, x[i : i + _CHUNK]))))
            for i in range(0, len(x), _CHUNK)
        ]
    ).astype(np.float64)
    noise_sd = np.sqrt(w @ sd_draws**2)
    z_obs = np.asarray(model.z_obs, np.float64)
    # Measurement error and the discrepancy's posterior mean covariance (emulated coordinates).
    extra = np.zeros((len(noise_sd), len(noise_sd)))
    if model.observation_cov is not None:
        extra += np.asarray(model.observation_cov, np.float64)
    if model.discrepancy_basis is not None and model.discrepancy_max_sd is not None:
        delta2 = (x[:, len(x[0]) - len(model.discrepancy_max_sd) :] * np.asarray(model.discrepancy_max_sd)) ** 2
        extra += np.einsum("g,gij->ij", w @ delta2, np.asarray(model.discrepancy_basis, np.float64))
    r = w @ ((z_obs - mean) / np.sqrt(sd_draws**2 + var + np.diag(extra)))
    centre = w @ mean
    chol = np.asarray(model.noise_chol, np.float64)
    cov = noise_sd[:, None] * (chol @ chol.T) * noise_sd[None, :] + np.diag(w @ var) + extra
    cov += (mean - centre).T @ ((mean - centre) * w[:, None])
    e = (z_obs - centre)[active]
    c = cov[np.ix_(active, active)]
    d2 = float(e @ np.linalg.solve(c, e))
    dof = int(active.sum())
    return {
        "standardised_residuals": [float(v) if a else None for v, a in zip(r, active, strict=True)],
        "projected": bool(transform.rotation.shape[0] != transform.rotation.shape[1]),
        "mahalanobis_squared": d2,
        "dof": dof,
        "p_value": float(chi2.sf(d2, dof)),
    }


def with_evidence(algorithm: Any, prior: Any, observed: Any, seed: int = 0) -> Any:
    """The surrogate ``algorithm`` whose ``finalize`` also reports the evidence.

    The driver puts ``log_evidence`` on the result (``result.log_evidence``); its standard
    error, the summaries in the likelihood and the sample size go to ``result.diagnostics``
    (``log_evidence_se``, ``evidence_active``, ``evidence_samples``), beside the posterior
    predictive check of the observed summaries that every surrogate run reports
    (``observed_misfit``, :func:`observed_misfit`).  Only for
    ``mode="synthetic_likelihood"``; the posterior and the checkpoints are unchanged, apart
    from the fingerprint's ``evidence_seed`` setting.
    """
    mode = algorithm.settings.get("mode", "synthetic_likelihood")
    if algorithm.name != "surrogate" or mode != "synthetic_likelihood":
        raise ValueError("the evidence is defined for the surrogate in synthetic-likelihood mode only")
    low = np.asarray(prior.low, np.float64)
    high = np.asarray(prior.high, np.float64)
    obs = np.asarray(observed, np.float64)
    settings = dict(algorithm.settings)
    finalize = algorithm.finalize

    def finalize_with_evidence(state: Any) -> dict:
        out = finalize(state)
        with jax.enable_x64(True):
            transform, model = likelihood_from_state(state, low, high, obs, settings)
            rng = np.random.default_rng(seed)
            ev = evidence_from_state(state, low, high, obs, settings, rng, fitted=(transform, model))
        out["log_evidence"] = ev.log_z
        out["diagnostics"] = dict(out["diagnostics"]) | {
            "log_evidence_se": ev.log_z_se,
            "log_evidence_importance_se": ev.importance_se,
            "log_evidence_jackknife_se": ev.jackknife_se,
            "evidence_active": ev.active.tolist(),
            "evidence_samples": ev.num_samples,
        }
        return out

    return algorithm._replace(finalize=finalize_with_evidence, settings=settings | {"evidence_seed": int(seed)})
