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

The kept particles are not independent: new ones are drawn around resampled kept ones, and kept
ones survive for generations, so their Monte Carlo error is larger than Kish's ESS of the
weights says.  The state records each particle's lineage (its ancestor ``LINEAGE_LAG`` to
``2 LINEAGE_LAG - 1`` generations back, or its prior draw before that), and :func:`finalize`
reports the MCSE of the posterior mean from the spread between lineages
(:func:`lineage_mcse`).  The parent of a new particle is not kept by ``propose``; ``update``
draws it from its conditional distribution given the particle,
``w_j K(theta | theta_j) / sum_k w_k K(theta | theta_k)``, with a key of its own, so the
recorded genealogy has the law of the true one and the sampling is untouched.
"""

from __future__ import annotations

import functools
import math
from typing import Any, NamedTuple, cast

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import logsumexp

from jaxabc import kernels
from jaxabc.algorithms.base import ABCAlgorithm, Info, Proposal, masked_percentile
from jaxabc.diagnostics import cluster_variance, count_distinct, effective_lineages, importance_variance
from jaxabc.distances import AdaptivePNorm, adaptive_weights
from jaxabc.priors import Prior

__all__ = [
    "LINEAGE_LAG",
    "APMCConfig",
    "APMCState",
    "build",
    "finalize",
    "impute_parents",
    "init",
    "initial_proposal",
    "lineage_mcse",
    "posterior",
    "propose",
    "update",
]

WEIGHT_MODES = ("lenormand", "abcpy")

# Lineages are traced back between LINEAGE_LAG and 2 LINEAGE_LAG - 1 generations: far enough
# that the correlation of relatives is inside them, near enough that many lineages remain
# (tracing to the prior draws leaves a handful after a few dozen generations).
LINEAGE_LAG = 8


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
    lineage : jax.Array, shape (N, 2), int32
        Each particle's ancestor (a slot index) at the last two generations that are multiples
        of ``LINEAGE_LAG`` (both at generation 0 before the first); column 0 groups the
        particles for the MCSE.  Bookkeeping only: the sampling never reads it.
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
    # A default only so that the field can follow the optional ones; _finish always sets it.
    lineage: jax.Array | None = None


class APMCConfig(NamedTuple):
    """APMCABC's configuration, fixed by :func:`build` and bound to the pure functions.

    Attributes
    ----------
    prior : Prior
        Its box is the kernel's support.
    num_particles : int
        ``N``, the merged population size.
    num_kept : int
        ``n_alpha = ceil(alpha N)``, the particles kept each step (at least 2).
    alpha : float
    acceptance_cutoff : float
    covariance_factor : float
    abcpy : bool
        ABCpy 0.6's weights, threshold and kernel (see the module docstring).
    max_tries : int
        Bound on truncated-kernel redraws per particle.
    adaptive_distance : AdaptivePNorm or None
        Bound to the observed vector; then ``init`` and ``update`` take summaries.
    """

    prior: Prior
    num_particles: int
    num_kept: int
    alpha: float
    acceptance_cutoff: float
    covariance_factor: float
    abcpy: bool
    max_tries: int
    adaptive_distance: AdaptivePNorm | None

    @property
    def num_new(self) -> int:
        """``N - n_alpha``, the particles proposed (and simulated) each step."""
        return self.num_particles - self.num_kept


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

    Returns
    -------
    ABCAlgorithm
        The functions of this module with an :class:`APMCConfig` bound by ``functools.partial``.

    Raises
    ------
    ValueError
        For an option out of range, fewer than 2 kept or 1 new particle, or an adaptive
        distance not bound to the observed data.
    """
    n = int(num_particles)
    n_alpha = _num_kept(n, alpha, acceptance_cutoff, covariance_factor, weights, adaptive_distance)
    config = APMCConfig(
        prior, n, n_alpha, alpha, acceptance_cutoff, covariance_factor, weights == "abcpy", max_tries, adaptive_distance
    )
    settings = {
        "num_particles": n,
        "alpha": alpha,
        "num_kept": n_alpha,
        "acceptance_cutoff": acceptance_cutoff,
        "covariance_factor": covariance_factor,
        "weights": weights,
    }
    if adaptive_distance is not None:
        settings["adaptive_distance"] = adaptive_distance.settings()
    bound_posterior = functools.partial(posterior, config)
    return ABCAlgorithm(
        "apmcabc",
        functools.partial(initial_proposal, config),
        functools.partial(init, config),
        functools.partial(propose, config),
        functools.partial(update, config),
        bound_posterior,
        settings,
        stop_reason=_stop_reason,
        finalize=functools.partial(finalize, posterior=bound_posterior),
        # A zero cutoff never fires: the run needs another rule.
        needs_stopping_rule=acceptance_cutoff == 0.0,
        uses_summaries=adaptive_distance is not None,
    )


def _num_kept(
    n: int,
    alpha: float,
    acceptance_cutoff: float,
    covariance_factor: float,
    weights: str,
    adaptive_distance: AdaptivePNorm | None,
) -> int:
    """``ceil(alpha n)`` after checking :func:`build`'s options; raises ``ValueError``."""
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must lie in (0, 1), got {alpha}; the paper used 0.1")
    if not 0.0 <= acceptance_cutoff < 1.0:
        raise ValueError(f"acceptance_cutoff must lie in [0, 1), got {acceptance_cutoff}")
    if weights not in WEIGHT_MODES:
        raise ValueError(f"weights must be one of {WEIGHT_MODES}, got {weights!r}")
    if covariance_factor <= 0:
        raise ValueError(f"covariance_factor must be positive, got {covariance_factor}")
    n_alpha = math.ceil(alpha * n)
    if n_alpha < 2 or n - n_alpha < 1:
        raise ValueError(
            f"num_particles={n} with alpha={alpha} keeps {n_alpha} particles and proposes "
            f"{n - n_alpha}: need at least 2 kept and 1 new; increase num_particles"
        )
    if adaptive_distance is not None and not adaptive_distance.observed:
        raise ValueError("adaptive_distance must be bound to the observed data: use AdaptivePNorm(...).bind(observed)")
    return n_alpha


def initial_proposal(config: APMCConfig, key: jax.Array) -> Proposal:
    """``N`` prior draws, all active."""
    n = config.num_particles
    return Proposal(config.prior.sample(key, n), jnp.ones((n,), bool), jnp.bool_(True))


def init(
    config: APMCConfig, key: jax.Array, proposal: Proposal, distances: jax.Array, summaries: jax.Array | None = None
) -> tuple[APMCState, Info]:
    """The first population from the prior draws of :func:`initial_proposal`.

    ``distances`` has shape (N,); ``summaries`` (N, s) is required with an adaptive distance
    and ignored otherwise.  The acceptance rate of the first step is 1.
    """
    del key
    n = config.num_particles
    thetas = jnp.asarray(proposal.thetas)
    dtype = thetas.dtype
    log_w = jnp.zeros((n,), dtype)
    distance_weights = None
    if config.adaptive_distance is not None:
        summaries = config.adaptive_distance.summaries_of(summaries, distances, dtype)
        distances, distance_weights = _rescale(config.adaptive_distance, summaries, summaries)
    return _finish(
        config,
        thetas,
        log_w,
        distances,
        jnp.ones((n,), bool),
        jnp.int32(0),
        jnp.asarray(1.0, dtype),
        # Each prior draw its own lineage (any distinct labels; generation 0 relabels).
        jnp.tile(jnp.arange(n, dtype=jnp.int32)[:, None], (1, 2)),
        summaries,
        distance_weights,
    )


def propose(config: APMCConfig, key: jax.Array, state: APMCState) -> Proposal:
    """``N - n_alpha`` kept particles, resampled by weight and perturbed by the truncated kernel.

    ``Proposal.ok`` is False when some draw found no point of the prior's box in ``max_tries``.
    """
    k_parents, k_kernel = jax.random.split(key)
    lw = jnp.where(state.kept, state.log_weights, -jnp.inf)
    parents = kernels.resample_indices(k_parents, lw, config.num_new)
    draw = kernels.truncated_gaussian_sample(
        k_kernel, state.particles[parents], state.chol, config.prior.low, config.prior.high, config.max_tries
    )
    return Proposal(draw.samples, jnp.ones((config.num_new,), bool), jnp.all(draw.ok))


def update(
    config: APMCConfig,
    key: jax.Array,
    state: APMCState,
    proposal: Proposal,
    distances: jax.Array,
    summaries: jax.Array | None = None,
) -> tuple[APMCState, Info]:
    """Weigh the ``N - n_alpha`` new particles, merge them with the kept ones, select again.

    ``distances`` has shape (N - n_alpha,); ``summaries`` (N - n_alpha, s) is required with an
    adaptive distance.  ``Info.stop`` fires when the acceptance falls below the cutoff.
    """
    theta = jnp.asarray(proposal.thetas)
    m, head = config.num_new, slice(0, config.num_kept)
    # Kept particles occupy the first n_alpha slots (compacted by _select), so the kernel
    # mixture only needs those centres: (m, n_alpha) work instead of (m, N).
    centres = state.particles[head]
    centre_lw = jnp.where(state.kept[head], state.log_weights[head], -jnp.inf)
    new_lw, lineage = _weigh_new_particles(config, key, state, theta, centres, centre_lw)
    adaptive = config.adaptive_distance
    merged_summaries = distance_weights = None
    if adaptive is not None:
        summaries = adaptive.summaries_of(summaries, distances, theta.dtype)
        # Acceptance against the previous threshold, measured with the previous weights.
        distances = adaptive.distances(summaries, cast(jax.Array, state.distance_weights), jnp.ones((m,), bool))
        merged_summaries = jnp.concatenate([cast(jax.Array, state.summaries)[head], summaries])
    if config.abcpy:
        acceptance = jnp.mean(distances < state.threshold)
        kept_lw = centre_lw - logsumexp(centre_lw)
    else:
        acceptance = jnp.mean(distances <= state.threshold)
        kept_lw = centre_lw
    # Slots [0, n_alpha) hold the kept particles (compacted); [n_alpha, N) the new ones.
    particles = jnp.concatenate([centres, theta])
    log_weights = jnp.concatenate([kept_lw, new_lw])
    merged_distances = jnp.concatenate([state.distances[head], distances])
    valid = jnp.concatenate([state.kept[head], jnp.ones((m,), bool)])
    log_weights = jnp.where(valid, log_weights, -jnp.inf)
    if adaptive is not None and merged_summaries is not None:
        # Old and new particles on one scale: everyone is re-measured with the new weights.
        merged_distances, distance_weights = _rescale(adaptive, cast(jax.Array, summaries), merged_summaries)
    return _finish(
        config,
        particles,
        log_weights,
        merged_distances,
        valid,
        state.generation + 1,
        acceptance.astype(theta.dtype),
        lineage,
        merged_summaries,
        distance_weights,
    )


def posterior(config: APMCConfig, state: APMCState) -> tuple[jax.Array, jax.Array]:
    """The kept particles (``abcpy``: the merged population), shapes (N, d) and (N,).

    Slots outside the posterior have log weight ``-inf``.
    """
    if config.abcpy:
        return state.particles, jnp.where(state.valid, state.log_weights, -jnp.inf)
    return state.particles, jnp.where(state.kept, state.log_weights, -jnp.inf)


def _weigh_new_particles(
    config: APMCConfig,
    key: jax.Array,
    state: APMCState,
    theta: jax.Array,
    centres: jax.Array,
    centre_lw: jax.Array,
) -> tuple[jax.Array, jax.Array]:
    """Log weights ``prior / kernel mixture`` of the new particles (m,), and the merged
    population's lineage (N, 2): the kept particles' own, then the imputed parents'."""
    prior, head = config.prior, slice(0, config.num_kept)
    if config.abcpy:
        log_norm = None
    else:
        log_norm = kernels.log_truncation_normalizer(key, centres, state.chol, prior.low, prior.high)
        log_norm = jnp.where(state.kept[head], log_norm, 0.0)
    new_lw = kernels.mixture_log_weights(theta, prior.log_prob(theta), centres, centre_lw, state.chol, log_norm)
    # The genealogy for the MCSE, from a key derived here: `key` itself is used as before.
    parents = impute_parents(jax.random.fold_in(key, 1), theta, centres, centre_lw, state.chol, log_norm)
    assert state.lineage is not None, "states are built by init/update"
    return new_lw, jnp.concatenate([state.lineage[head], state.lineage[head][parents]])


def _rescale(adaptive: AdaptivePNorm, simulated: jax.Array, population: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Distance weights (s,) from this step's ``simulated`` summaries, and the distances (n,)
    of the ``population`` summaries (n, s) under them."""
    distance_weights = adaptive_weights(simulated, jnp.all(jnp.isfinite(simulated), axis=1))
    valid = jnp.ones(population.shape[0], bool)
    return adaptive.distances(population, distance_weights, valid), distance_weights


def _select(config: APMCConfig, distances: jax.Array, valid: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Alpha selection: the order (N,) that puts the kept particles first, the kept mask (N,)
    in that order, and the threshold ()."""
    if config.abcpy:
        threshold = masked_percentile(distances, valid, config.alpha)
        kept = valid & (distances < threshold)
    else:
        n = config.num_particles
        order = jnp.argsort(jnp.where(valid, distances, jnp.inf), stable=True)
        rank = jnp.empty_like(order).at[order].set(jnp.arange(n))
        kept = rank < config.num_kept
        threshold = jnp.sort(jnp.where(valid, distances, jnp.inf))[config.num_kept - 1]
    # Kept particles first (stable), so the next step can overwrite slots n_alpha.. with
    # new particles.  At most n_alpha are kept in either mode (see masked_percentile).
    order = jnp.argsort(~kept, stable=True)
    return order, kept[order], threshold


def _kernel_cholesky(config: APMCConfig, particles: jax.Array, log_weights: jax.Array, kept: jax.Array) -> jax.Array:
    """Cholesky factor (d, d) of factor x the kept particles' weighted covariance, regularised."""
    lw = jnp.where(kept, log_weights, -jnp.inf)
    cov = config.covariance_factor * kernels.weighted_covariance(particles, lw)
    return jnp.linalg.cholesky(kernels.regularize_covariance(cov, config.prior.low, config.prior.high))


def _finish(
    config: APMCConfig,
    particles: jax.Array,
    log_weights: jax.Array,
    distances: jax.Array,
    valid: jax.Array,
    generation: jax.Array,
    acceptance: jax.Array,
    lineage: jax.Array,
    summaries: jax.Array | None = None,
    distance_weights: jax.Array | None = None,
) -> tuple[APMCState, Info]:
    """Select the kept particles of a merged population (N slots) and build its state and Info."""
    order, kept, threshold = _select(config, distances, valid)
    particles, log_weights = particles[order], log_weights[order]
    distances, valid = distances[order], valid[order]
    chol = _kernel_cholesky(config, particles, log_weights, kept)
    if summaries is not None:
        summaries = summaries[order]
    lineage = lineage[order]
    # Every LINEAGE_LAG generations the newer ancestors become the grouping ones and each
    # particle starts a lineage of its own.
    lineage = jnp.where(
        generation % LINEAGE_LAG == 0,
        jnp.stack([lineage[:, 1], jnp.arange(config.num_particles, dtype=jnp.int32)], axis=1),
        lineage,
    )
    state = APMCState(
        particles=particles,
        log_weights=log_weights,
        distances=distances,
        valid=valid,
        kept=kept,
        threshold=threshold,
        chol=chol,
        generation=generation,
        summaries=summaries,
        distance_weights=distance_weights,
        lineage=lineage,
    )
    stop = acceptance < config.acceptance_cutoff
    post_lw = posterior(config, state)[1]
    info = Info(jnp.bool_(True), stop, threshold, acceptance, kernels.effective_sample_size(post_lw))
    return state, info


def _stop_reason(settings: dict, info: Info) -> str:
    return f"acceptance {float(info.acceptance_rate):.4f} < cutoff {settings['acceptance_cutoff']}"


def impute_parents(
    key: jax.Array,
    theta: jax.Array,
    centres: jax.Array,
    centre_log_weights: jax.Array,
    chol: jax.Array,
    log_normalizer: jax.Array | None = None,
) -> jax.Array:
    """A parent for each proposed particle, drawn from its conditional law given the particle.

    ``theta_i`` was drawn from the mixture ``sum_j w_j K(. | theta_j)``: given ``theta_i``
    its parent is ``j`` with probability ``w_j K(theta_i | theta_j) / sum_k w_k K(theta_i |
    theta_k)``.  Drawn independently for each particle, these parents have the joint law of
    the parents ``propose`` drew, so a genealogy built from them has the law of the true one.

    Parameters
    ----------
    key : jax.Array
    theta : jax.Array, shape (m, d)
    centres : jax.Array, shape (c, d)
    centre_log_weights : jax.Array, shape (c,)
        Unnormalised; ``-inf`` for slots that are not centres.
    chol : jax.Array, shape (d, d)
        Lower Cholesky factor of the kernel covariance.
    log_normalizer : jax.Array, shape (c,), optional
        The kernels' log truncation normalisers, as in :func:`jaxabc.kernels.mixture_log_weights`.

    Returns
    -------
    jax.Array, shape (m,), int32
        Indices into ``centres``.
    """
    log_w = centre_log_weights if log_normalizer is None else centre_log_weights - log_normalizer
    origin = jnp.mean(centres, axis=0)
    a = jax.scipy.linalg.solve_triangular(chol, (theta - origin).T, lower=True).T
    b = jax.scipy.linalg.solve_triangular(chol, (centres - origin).T, lower=True).T
    sq = jnp.maximum(jnp.sum(a**2, 1)[:, None] + jnp.sum(b**2, 1)[None, :] - 2.0 * a @ b.T, 0.0)
    logits = log_w[None, :] - 0.5 * sq
    prob = jnp.exp(logits - jnp.max(logits, axis=1, keepdims=True))
    # Inverse CDF in two stages, a block of about sqrt(c) centres and then a centre in it: a
    # cumulative sum over all c centres per particle costs several times the kernel itself
    # on the CPU, and Gumbel draws (jax.random.categorical) more.
    m, c = prob.shape
    size = math.isqrt(c - 1) + 1
    blocks = -(-c // size)
    prob = jnp.pad(prob, ((0, 0), (0, blocks * size - c))).reshape(m, blocks, size)
    k_block, k_centre = jax.random.split(key)
    block = _inverse_cdf(k_block, jnp.sum(prob, axis=2))
    centre = _inverse_cdf(k_centre, jnp.take_along_axis(prob, block[:, None, None], axis=1)[:, 0])
    return (block * size + centre).astype(jnp.int32)


def _inverse_cdf(key: jax.Array, prob: jax.Array) -> jax.Array:
    """One index per row of ``prob`` (m, c), drawn with probabilities proportional to the row."""
    cdf = jnp.cumsum(prob, axis=1)
    u = jax.random.uniform(key, (prob.shape[0], 1), cdf.dtype) * cdf[:, -1:]
    idx = jnp.sum(cdf <= u, axis=1)
    # Never a zero-probability slot, even when rounding leaves u at the top of the cdf.
    last = jnp.max(jnp.where(prob > 0, jnp.arange(prob.shape[1]), 0), axis=1)
    return jnp.minimum(idx, last)


def lineage_mcse(particles: Any, weights: Any, lineage: Any) -> dict:
    """Monte Carlo standard error of APMCABC's weighted posterior mean, from its lineages.

    The variance of the mean is the larger of the cluster-robust variance over the lineages
    (:func:`jaxabc.diagnostics.cluster_variance`) and the delta-method variance of
    self-normalised importance sampling (:func:`jaxabc.diagnostics.importance_variance`, the
    error of independent particles).  ``inf`` when fewer than two distinct particles carry
    weight.

    Parameters
    ----------
    particles : array_like, shape (n, d)
    weights : array_like, shape (n,)
        Non-negative; zero for particles outside the posterior.
    lineage : array_like, shape (n,)
        A label per particle; particles that share it share an ancestor.

    Returns
    -------
    dict
        ``mcse`` (list of d floats), ``num_distinct`` (particles with weight),
        ``num_lineages``, ``effective_lineages`` (Kish's number of the lineages' weights),
        ``collapsed`` (bool) and ``mcse_note`` (why no MCSE, empty when there is one).
    """
    x = np.asarray(particles, np.float64)
    x = x.reshape(x.shape[0], -1)
    w = np.asarray(weights, np.float64)
    lineage = np.asarray(lineage).reshape(-1)
    keep = w > 0
    distinct = count_distinct(x[keep])
    num_lineages, effective = effective_lineages(w, lineage)
    if distinct < 2:
        note = f"collapsed: {distinct} distinct particle{'s' * (distinct != 1)} with weight; MCSE not available"
        mcse = np.full(x.shape[1], np.inf)
    else:
        note = ""
        mcse = np.sqrt(np.maximum(cluster_variance(x, w, lineage), importance_variance(x[keep], w[keep])))
    return {
        "mcse": [float(v) for v in mcse],
        "num_distinct": distinct,
        "num_lineages": num_lineages,
        "effective_lineages": effective,
        "collapsed": distinct < 2,
        "mcse_note": note,
    }


def finalize(state: APMCState, posterior: Any) -> dict:
    """Result extras of a run that ended in ``state``: the lineage MCSE (:func:`lineage_mcse`).

    Parameters
    ----------
    state : APMCState
    posterior : callable ``(state) -> (particles, log_weights)``
        The algorithm's posterior (kept particles, or the merged population in ``abcpy`` mode).

    Returns
    -------
    dict
        ``{"diagnostics": dict}``; empty for a state without lineages.
    """
    if state.lineage is None:
        return {}
    particles, log_w = (np.asarray(a, np.float64) for a in posterior(state))
    keep = np.isfinite(log_w)
    if not np.any(keep):
        return {}
    w = np.where(keep, np.exp(log_w - np.max(log_w[keep])), 0.0)
    return {"diagnostics": lineage_mcse(particles, w, np.asarray(state.lineage)[:, 0])}
