"""Draws from the surrogate posterior: importance samples over the unit box (the design phase,
and where NUTS chains do not mix), NUTS chains on the synthetic likelihood, and the effective
sample size of what is reported."""

from __future__ import annotations

import warnings
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.surrogate import design, sampling
from jaxabc.surrogate._settings import SurrogateSettings
from jaxabc.surrogate._support import log_posterior_terms

__all__ = [
    "IMPORTANCE_POOL_PER_DRAW",
    "MAX_MEAN_SHIFT",
    "RHAT_MAX",
    "ImportanceSample",
    "chains_disagree",
    "importance_draws",
    "importance_sample",
    "nuts_chains",
    "posterior_ess",
]

#: Split R-hat above which the NUTS chains are taken not to agree (e.g. in different modes of
#: a multimodal posterior); the reported draws are then importance-resampled instead.
RHAT_MAX = 1.05
#: Also when the chains' mean is this many importance-sample posterior sds from the importance
#: sample's mean (all chains in one of several modes passes R-hat).
MAX_MEAN_SHIFT = 0.5
#: Importance-sample points per posterior draw in that case.
IMPORTANCE_POOL_PER_DRAW = 16
#: NUTS tries, each with half the previous step size, while a chain's acceptance is below
#: Stan's default target or any of its kept steps diverged: a step that only just passes a
#: low bar leaves curved posteriors' tails unvisited (a banana's sd came out 0.76-0.85x exact).
_NUTS_TRIES = 6
_MIN_ACCEPTANCE = 0.8
_MAX_DIVERGENT = 0.0


class ImportanceSample(NamedTuple):
    """Points of the augmented unit box with self-normalised importance weights of the
    surrogate posterior.

    Attributes
    ----------
    points : array, shape (n, d + G)
    log_density : array, shape (n,)
        Unnormalised log posterior density.
    emulator_ratio : array, shape (n,)
        ``mean_j var_j / noise_j^2`` of the emulator at each point.
    weights : array, shape (n,)
        Non-negative, summing to one.
    """

    points: np.ndarray
    log_density: np.ndarray
    emulator_ratio: np.ndarray
    weights: np.ndarray


def evaluate_in_chunks(
    settings: SurrogateSettings, model: sampling.LikelihoodModel, x: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`._support.log_posterior_terms` in chunks of ``num_candidates`` points: one
    compiled shape, bounded memory.  NaN log densities become ``-inf`` with a ``RuntimeWarning``."""
    size = settings.num_candidates
    out = [log_posterior_terms(model, x[i : i + size]) for i in range(0, len(x), size)]
    lp = np.concatenate([o[0] for o in out])
    if np.isnan(lp).any():
        # A NaN (the emulator or the success classifier not evaluable there, far from every run)
        # would poison every importance weight; such a point gets none, and the run says so.
        warnings.warn(
            "surrogate: the log density is NaN at some candidate points (the emulator or the success "
            "classifier cannot be evaluated there); they get zero weight",
            RuntimeWarning,
            stacklevel=2,
        )
        lp = np.where(np.isnan(lp), -np.inf, lp)
    return lp, np.concatenate([o[1] for o in out])


def importance_sample(
    settings: SurrogateSettings, rng: np.random.Generator, model: sampling.LikelihoodModel, size: int | None = None
) -> ImportanceSample:
    """The surrogate posterior by :func:`.design.importance_pool`: ``size`` points in its
    second, local pass (default ``num_candidates``), in the augmented box."""
    pool, (lp, ratio) = design.importance_pool(
        rng,
        settings.box.num_sampled,
        size or settings.num_candidates,
        partial(evaluate_in_chunks, settings, model),
        first_num=settings.num_candidates,
    )
    logw = lp - pool.log_q
    w = np.exp(logw - np.max(logw))
    w /= w.sum()
    return ImportanceSample(pool.x, lp, ratio, w)


def importance_draws(
    settings: SurrogateSettings, rng: np.random.Generator, model: sampling.LikelihoodModel
) -> tuple[np.ndarray, np.ndarray]:
    """``num_particles`` draws resampled from an importance sample of
    :data:`IMPORTANCE_POOL_PER_DRAW` points per draw, for posteriors the NUTS chains do not mix
    over (several modes).

    Returns
    -------
    draws : array, shape (P, d + G)
        The distinct resampled unit-box points first, then copies of the first as padding:
        duplicates are not counted twice in the ESS.
    log_weights : array, shape (P,)
        Log of each distinct point's count; ``-inf`` for the padding.
    """
    p = settings.num_particles
    sample = importance_sample(settings, rng, model, IMPORTANCE_POOL_PER_DRAW * p)
    x = sample.points
    unique, counts = np.unique(rng.choice(len(x), size=p, p=sample.weights), return_counts=True)
    draws = np.repeat(x[unique[:1]], p, axis=0)
    draws[: len(unique)] = x[unique]
    log_weights = np.full(p, -np.inf)
    log_weights[: len(unique)] = np.log(counts)
    return draws, log_weights


def nuts_chains(
    settings: SurrogateSettings,
    key: jax.Array,
    rng: np.random.Generator,
    model: sampling.LikelihoodModel,
    sample: ImportanceSample,
) -> tuple[jax.Array, np.ndarray]:
    """NUTS on the synthetic likelihood, started from and preconditioned by ``sample``.

    The chains start at points drawn from ``sample`` (with ``rng``); the metric is the
    sample's covariance in logit coordinates.  While a chain's acceptance stays below
    :data:`_MIN_ACCEPTANCE` or any kept step diverges, the step size is halved and the chains
    rerun (the step size is traced: no recompilation), at most :data:`_NUTS_TRIES` times.

    Returns
    -------
    draws : jax.Array, shape (num_chains, num_particles // num_chains, d + G)
        Unit-box draws of each chain.
    rhat : array, shape (d + G,)
        Their split R-hat.
    """
    x, w = sample.points, sample.weights
    num_sampled = settings.box.num_sampled
    starts = np.clip(x[rng.choice(len(x), size=settings.num_chains, p=w)], 1e-6, 1 - 1e-6)
    xc = np.clip(x, 1e-9, 1 - 1e-9)
    u = np.log(xc) - np.log1p(-xc)
    mu = w @ u
    metric = (u - mu).T @ ((u - mu) * w[:, None]) + 1e-8 * np.eye(num_sampled)
    step_size = 0.9 * num_sampled**-0.25
    for _ in range(_NUTS_TRIES):
        draws, acceptance, divergent = sampling.nuts(
            jax.random.fold_in(key, 2),
            model,
            jnp.asarray(starts),
            jnp.asarray(metric),
            jnp.asarray(step_size),
            settings.num_warmup,
            settings.num_particles // settings.num_chains,
            settings.thin,
        )
        # A metric from importance weights may be off; a smaller step restores acceptance.
        if float(np.min(acceptance)) >= _MIN_ACCEPTANCE and float(np.max(divergent)) <= _MAX_DIVERGENT:
            break
        step_size /= 2
    return draws, np.asarray(sampling.split_rhat(draws))


def chains_disagree(rhat: np.ndarray, flat_draws: np.ndarray, sample: ImportanceSample) -> bool:
    """Whether NUTS chains disagree with each other (split R-hat above :data:`RHAT_MAX`) or,
    all together, with the importance ``sample`` (their mean over :data:`MAX_MEAN_SHIFT` of its
    sds away): chains in different modes, or all in one of several.  ``flat_draws (n, d + G)``
    are the chains' unit-box draws."""
    x, w = sample.points, sample.weights
    sd = np.sqrt(w @ (x - w @ x) ** 2)
    shift = np.abs(flat_draws.mean(axis=0) - w @ x) / np.maximum(sd, 1e-12)
    return bool(not np.all(rhat <= RHAT_MAX) or np.any(shift > MAX_MEAN_SHIFT))


def posterior_ess(state: Any, num_chains: int, abc: bool) -> float:
    """ESS of a state's reported draws: Kish's of the weights in ABC mode (and before NUTS has
    run, or when its chains were replaced by an importance resample), ArviZ's multi-chain ESS of
    the NUTS chains otherwise -- equal weights say nothing of the chains' autocorrelation."""
    draws = np.asarray(state.draws, np.float64)
    rhat = np.asarray(state.rhat)
    resampled = np.any(np.asarray(state.log_weights) != 0)
    if abc or not np.all(np.isfinite(rhat)) or resampled or len(draws) % num_chains:
        return design.kish_ess(state.log_weights)
    from jaxabc.diagnostics import chain_ess

    return chain_ess(draws.reshape(num_chains, -1, draws.shape[1]))
