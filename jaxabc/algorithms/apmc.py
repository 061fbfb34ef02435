"""Adaptive population Monte Carlo ABC (Lenormand, Jabot & Deffuant 2013).

Each step keeps the ``n_alpha = ceil(alpha N)`` best particles, draws ``N - n_alpha`` new ones
from the kept population perturbed by a truncated Gaussian with twice its weighted covariance,
and stops when the fraction of new particles below the previous threshold falls under the
acceptance cutoff.  The threshold is never chosen by hand: it is the ``alpha`` quantile of the
merged population.

Two weight modes:

``"lenormand"`` (default)
    Faithful to the paper and EasyABC: a new particle's weight is
    ``prior(theta) / sum_j w~_j K(theta | theta_j)`` and the kept particles' weights are carried
    unchanged, so old and new weights share one scale (prior over proposal density).  The
    posterior is the ``n_alpha`` kept particles.  The kernel density includes its truncation
    normaliser (EasyABC omits it; it matters for particles near the prior's edges).
``"abcpy"``
    ABCpy 0.6's behaviour, kept for reproducing the paper: the kept weights are renormalised to
    sum to one before being concatenated with the new, unnormalised ones, the threshold is
    ``numpy.percentile`` with strict ``<``, the kernel is not normalised, and the posterior is
    the whole merged population.  Mixing two weight scales over-weights whichever group has
    the larger scale; on a Gaussian toy it underestimates the posterior variance (see
    ``tests/test_algorithms.py``).

With ``adaptive_distance`` (:class:`jaxabc.distances.AdaptivePNorm`, what
``jaxabc.run(..., distance="adaptive")`` builds) the algorithm computes distances itself from
the summaries: a new particle is counted as accepted when it is within the previous threshold
under the previous weights; then the weights are re-estimated from the step's ``N - n_alpha``
simulations and the whole merged population's distances are recomputed with them before the
alpha selection (Prangle 2017).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.scipy.special import logsumexp

from jaxabc import kernels
from jaxabc.algorithms.base import ABCAlgorithm, Info, Proposal, masked_percentile
from jaxabc.distances import AdaptivePNorm, adaptive_weights
from jaxabc.priors import Prior

__all__ = ["APMCState", "build"]

WEIGHT_MODES = ("lenormand", "abcpy")


class APMCState(NamedTuple):
    """State of APMCABC.

    Attributes
    ----------
    particles : jax.Array, shape (N, d)
        Merged population (kept particles first, then the newest ones).
    log_weights : jax.Array, shape (N,)
        Unnormalised log weights of the merged population.
    distances : jax.Array, shape (N,)
    valid : jax.Array, shape (N,)
        Slots holding a particle (all, except in ``abcpy`` mode where fewer than ``n_alpha``
        may be kept).
    kept : jax.Array, shape (N,)
        The alpha-selected particles that seed the next step.
    threshold : jax.Array, shape ()
    chol : jax.Array, shape (d, d)
        Cholesky factor of the perturbation covariance (2 x weighted covariance of the kept).
    generation : jax.Array, shape ()
    summaries : jax.Array, shape (N, s), or None
        With an adaptive distance: the merged population's summaries (NaN for failed slots).
    distance_weights : jax.Array, shape (s,), or None
        With an adaptive distance: the weights of ``distances`` and ``threshold``.
    """

    particles: jax.Array
    log_weights: jax.Array
    distances: jax.Array
    valid: jax.Array
    kept: jax.Array
    threshold: jax.Array
    chol: jax.Array
    generation: jax.Array
    # None (no pytree leaves) without an adaptive distance, so such states and checkpoints are
    # exactly those of a fixed distance.
    summaries: jax.Array | None = None
    distance_weights: jax.Array | None = None


def build(
    prior: Prior,
    num_particles: int,
    alpha: float = 0.1,
    acceptance_cutoff: float = 0.03,
    covariance_factor: float = 2.0,
    weights: str = "lenormand",
    max_tries: int = 10_000,
    adaptive_distance: AdaptivePNorm | None = None,
) -> ABCAlgorithm:
    """Build APMCABC.

    Parameters
    ----------
    prior : Prior
        Its box is the kernel's support.
    num_particles : int
        ``N``, the population size; ``N - ceil(alpha N)`` simulations per step after the first.
    alpha : float
        Fraction kept each step, in (0, 1) (the paper: 0.1).
    acceptance_cutoff : float
        Stop when the fraction of new particles below the previous threshold is below this
        (the paper: 0.03).
    covariance_factor : float
        Kernel covariance = factor x weighted covariance of the kept particles (Lenormand: 2).
    weights : {"lenormand", "abcpy"}
        See the module docstring.
    max_tries : int
        Bound on truncated-kernel redraws per particle before reporting an unreachable support.
    adaptive_distance : AdaptivePNorm, optional
        Bound to the observed vector; the algorithm then receives the summaries and computes
        its own distances (see the module docstring).
    """
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must lie in (0, 1), got {alpha}; the paper used 0.1")
    if not 0.0 <= acceptance_cutoff < 1.0:
        raise ValueError(f"acceptance_cutoff must lie in [0, 1), got {acceptance_cutoff}")
    if weights not in WEIGHT_MODES:
        raise ValueError(f"weights must be one of {WEIGHT_MODES}, got {weights!r}")
    if covariance_factor <= 0:
        raise ValueError(f"covariance_factor must be positive, got {covariance_factor}")
    n = int(num_particles)
    n_alpha = math.ceil(alpha * n)
    if n_alpha < 2 or n - n_alpha < 1:
        raise ValueError(
            f"num_particles={n} with alpha={alpha} keeps {n_alpha} particles and proposes "
            f"{n - n_alpha}: need at least 2 kept and 1 new; increase num_particles"
        )
    m = n - n_alpha
    low, high = prior.low, prior.high
    abcpy = weights == "abcpy"
    adaptive = adaptive_distance
    if adaptive is not None and not adaptive.observed:
        raise ValueError("adaptive_distance must be bound to the observed data: use AdaptivePNorm(...).bind(observed)")

    def _select(distances, valid, log_weights):
        """Alpha selection; returns kept mask, threshold, and the population compacted so that
        kept particles come first."""
        if abcpy:
            threshold = masked_percentile(distances, valid, alpha)
            kept = valid & (distances < threshold)
        else:
            order = jnp.argsort(jnp.where(valid, distances, jnp.inf), stable=True)
            rank = jnp.empty_like(order).at[order].set(jnp.arange(n))
            kept = rank < n_alpha
            threshold = jnp.sort(jnp.where(valid, distances, jnp.inf))[n_alpha - 1]
        # Kept particles first (stable), so the next step can overwrite slots n_alpha.. with
        # new particles.  At most n_alpha are kept in either mode (see masked_percentile).
        order = jnp.argsort(~kept, stable=True)
        return order, kept[order], threshold

    def _chol(particles, log_weights, kept):
        lw = jnp.where(kept, log_weights, -jnp.inf)
        cov = covariance_factor * kernels.weighted_covariance(particles, lw)
        return jnp.linalg.cholesky(kernels.regularize_covariance(cov, low, high))

    def _finish(particles, log_weights, distances, valid, generation, acceptance, summaries=None, dweights=None):
        order, kept, threshold = _select(distances, valid, log_weights)
        particles, log_weights = particles[order], log_weights[order]
        distances, valid = distances[order], valid[order]
        chol = _chol(particles, log_weights, kept)
        if summaries is not None:
            summaries = summaries[order]
        state = APMCState(
            particles, log_weights, distances, valid, kept, threshold, chol, generation, summaries, dweights
        )
        stop = acceptance < acceptance_cutoff
        post_lw = posterior(state)[1]
        info = Info(jnp.bool_(True), stop, threshold, acceptance, kernels.effective_sample_size(post_lw))
        return state, info

    def initial_proposal(key):
        return Proposal(prior.sample(key, n), jnp.ones((n,), bool), jnp.bool_(True))

    def _rescale(simulated, population):
        """New weights from this step's ``simulated`` summaries; distances of ``population``."""
        assert adaptive is not None, "only called with an adaptive distance"
        dweights = adaptive_weights(simulated, jnp.all(jnp.isfinite(simulated), axis=1))
        return adaptive.distances(population, dweights, jnp.ones(population.shape[0], bool)), dweights

    def init(key, proposal, distances, summaries=None):
        del key
        dtype = proposal.thetas.dtype
        log_w = jnp.zeros((n,), dtype)
        dweights = None
        if adaptive is not None:
            summaries = adaptive.summaries_of(summaries, distances, dtype)
            distances, dweights = _rescale(summaries, summaries)
        return _finish(
            proposal.thetas,
            log_w,
            distances,
            jnp.ones((n,), bool),
            jnp.int32(0),
            jnp.asarray(1.0, dtype),
            summaries,
            dweights,
        )

    def propose(key, state):
        k1, k2 = jax.random.split(key)
        lw = jnp.where(state.kept, state.log_weights, -jnp.inf)
        parents = kernels.resample_indices(k1, lw, m)
        draw = kernels.truncated_gaussian_sample(k2, state.particles[parents], state.chol, low, high, max_tries)
        return Proposal(draw.samples, jnp.ones((m,), bool), jnp.all(draw.ok))

    def update(key, state, proposal, distances, summaries=None):
        theta = proposal.thetas
        # Kept particles occupy the first n_alpha slots (compacted by _select), so the kernel
        # mixture only needs those centres: (m, n_alpha) work instead of (m, N).
        head = slice(0, n_alpha)
        centres = state.particles[head]
        centre_lw = jnp.where(state.kept[head], state.log_weights[head], -jnp.inf)
        if abcpy:
            log_norm = None
        else:
            log_norm = kernels.log_truncation_normalizer(key, centres, state.chol, low, high)
            log_norm = jnp.where(state.kept[head], log_norm, 0.0)
        new_lw = kernels.mixture_log_weights(theta, prior.log_prob(theta), centres, centre_lw, state.chol, log_norm)
        merged_summaries = dweights = None
        if adaptive is not None:
            summaries = adaptive.summaries_of(summaries, distances, theta.dtype)
            # Acceptance against the previous threshold, measured with the previous weights.
            distances = adaptive.distances(summaries, state.distance_weights, jnp.ones((m,), bool))
            merged_summaries = jnp.concatenate([state.summaries[head], summaries])
        if abcpy:
            acceptance = jnp.mean(distances < state.threshold)
            kept_lw = centre_lw - logsumexp(centre_lw)
        else:
            acceptance = jnp.mean(distances <= state.threshold)
            kept_lw = centre_lw
        # Slots [0, n_alpha) hold the kept particles (compacted); [n_alpha, N) the new ones.
        particles = jnp.concatenate([centres, theta])
        log_weights = jnp.concatenate([kept_lw, new_lw])
        dists = jnp.concatenate([state.distances[head], distances])
        valid = jnp.concatenate([state.kept[head], jnp.ones((m,), bool)])
        log_weights = jnp.where(valid, log_weights, -jnp.inf)
        if merged_summaries is not None:
            # Old and new particles on one scale: everyone is re-measured with the new weights.
            dists, dweights = _rescale(summaries, merged_summaries)
        return _finish(
            particles,
            log_weights,
            dists,
            valid,
            state.generation + 1,
            acceptance.astype(theta.dtype),
            merged_summaries,
            dweights,
        )

    def posterior(state):
        if abcpy:
            return state.particles, jnp.where(state.valid, state.log_weights, -jnp.inf)
        return state.particles, jnp.where(state.kept, state.log_weights, -jnp.inf)

    settings = {
        "num_particles": n,
        "alpha": alpha,
        "num_kept": n_alpha,
        "acceptance_cutoff": acceptance_cutoff,
        "covariance_factor": covariance_factor,
        "weights": weights,
    }
    if adaptive is not None:
        settings["adaptive_distance"] = adaptive.settings()
    return ABCAlgorithm(
        "apmcabc",
        initial_proposal,
        init,
        propose,
        update,
        posterior,
        settings,
        stop_reason=_stop_reason,
        # A zero cutoff never fires: the run needs another rule.
        needs_stopping_rule=acceptance_cutoff == 0.0,
        uses_summaries=adaptive is not None,
    )


def _stop_reason(settings: dict, info: Info) -> str:
    return f"acceptance {float(info.acceptance_rate):.4f} < cutoff {settings['acceptance_cutoff']}"
