"""Population Monte Carlo ABC (Beaumont, Cornuet, Marin & Robert 2009), and rejection ABC.

PMC-ABC fills each generation of ``N`` particles by rounds of over-proposal: a round draws
parents from the previous generation, perturbs them with a truncated Gaussian of twice the
previous weighted covariance and simulates about ``missing / acceptance`` of them (the
acceptance estimated from the rounds so far); the accepted ones (distance at most the
generation's threshold) fill the empty slots in proposal order, and accepted proposals beyond
the missing count are discarded.  Every kept particle is an independent draw from the same
distribution as in the one-proposal-per-slot scheme of Beaumont et al.  The weights
``prior / sum_j w_j K(theta | theta_j)`` depend only on the particle and the previous
generation, so they are computed once per generation, for the ``N`` kept particles.
Thresholds come from a schedule or, by default, the ``quantile`` of the previous generation's
distances.

Rejection ABC is the same filling loop with the prior as proposal and a single generation; with
``threshold=None`` it instead simulates ``ceil(N / quantile)`` prior draws and keeps the best
``N`` (then ``quantile`` is the acceptance rate).

With ``adaptive_distance`` (:class:`jaxabc.distances.AdaptivePNorm`, what
``jaxabc.run(..., distance="adaptive")`` builds) PMC-ABC follows Prangle's (2017) algorithm 4:
a generation accepts proposals within its threshold under the previous generation's weights;
when it is complete, the weights are re-estimated from its simulations (accepted or not; at
most ``batch_size`` of them, the first ones, which are i.i.d. draws from the same proposal as
the rest), its particles' distances are recomputed with them, and the next threshold is their
``quantile``.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Sequence
from typing import Any, NamedTuple, cast

import jax
import jax.numpy as jnp

from jaxabc import kernels
from jaxabc.algorithms.base import ABCAlgorithm, Info, Proposal
from jaxabc.distances import AdaptivePNorm, adaptive_weights
from jaxabc.priors import Prior

__all__ = [
    "PMCConfig",
    "PMCState",
    "RejectionConfig",
    "build",
    "build_rejection",
    "init",
    "initial_proposal",
    "posterior",
    "propose",
    "rejection_init",
    "rejection_initial_proposal",
    "rejection_posterior",
    "rejection_propose",
    "rejection_update",
    "update",
]


class PMCState(NamedTuple):
    """State of PMC-ABC / rejection ABC.

    Attributes
    ----------
    particles, log_weights, distances : shapes (N, d), (N,), (N,)
        The generation being filled (complete when ``filled`` is all True).
    filled : jax.Array, shape (N,)
    parents, parent_log_weights : shapes (N, d), (N,)
        The previous, complete generation (the proposal mixture).
    chol : jax.Array, shape (d, d)
        Kernel Cholesky factor (2 x previous weighted covariance).
    log_normalizer : jax.Array, shape (N,)
        Log truncation normaliser of each parent's kernel (fixed within a generation).
    threshold : jax.Array, shape ()
        The tolerance of the generation being filled.
    generation : jax.Array, shape ()
    round_simulations, round_accepted : jax.Array, shape ()
        Counters over the generation being filled: simulations and accepted proposals (the
        acceptance rate; discarded surplus acceptances included).
    acceptance_estimate : jax.Array, shape ()
        Acceptance rate used to size the next round before this generation has any of its own.
    summaries : jax.Array, shape (N, s), or None
        With an adaptive distance: the summaries of ``particles``.
    distance_weights : jax.Array, shape (s,), or None
        With an adaptive distance: the weights of ``threshold`` (estimated from the previous
        generation's simulations).
    scale_buffer : jax.Array, shape (batch_size, s), or None
        With an adaptive distance: this generation's first finite simulated summaries.
    scale_count : jax.Array, shape (), or None
        Rows of ``scale_buffer`` in use.
    """

    particles: jax.Array
    log_weights: jax.Array
    distances: jax.Array
    filled: jax.Array
    parents: jax.Array
    parent_log_weights: jax.Array
    chol: jax.Array
    log_normalizer: jax.Array
    threshold: jax.Array
    generation: jax.Array
    round_simulations: jax.Array
    round_accepted: jax.Array
    acceptance_estimate: jax.Array
    # None (no pytree leaves) without an adaptive distance, so such states and checkpoints are
    # exactly those of a fixed distance.
    summaries: jax.Array | None = None
    distance_weights: jax.Array | None = None
    scale_buffer: jax.Array | None = None
    scale_count: jax.Array | None = None


def _fill_in_order(filled: jax.Array, accept: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The i-th accepted proposal (in proposal order) fills the i-th empty slot.

    Returns ``take (N,)``, which slots get a proposal, and ``source (N,)``, its index in the
    proposal batch (0 where nothing is taken).
    """
    n, m = filled.shape[0], accept.shape[0]
    empty_rank = jnp.cumsum(~filled) - 1
    acc_rank = jnp.cumsum(accept) - 1
    num_empty = jnp.sum(~filled)
    slot = jnp.where(accept & (acc_rank < num_empty), acc_rank, n)
    src = jnp.zeros((n,), jnp.int32).at[slot].set(jnp.arange(m, dtype=jnp.int32), mode="drop")
    take = (~filled) & (empty_rank < jnp.sum(accept))
    return take, jnp.where(take, src[jnp.clip(empty_rank, 0, n - 1)], 0)


class PMCConfig(NamedTuple):
    """PMC-ABC's configuration, fixed by :func:`build` and bound to the pure functions.

    Attributes
    ----------
    prior : Prior
        Its box is the kernel's support.
    num_particles : int
        ``N``, the generation size.
    batch_size : int
        ``m``, proposal slots per round.
    quantile : float
        The adaptive tolerance rule, in (0, 1).
    covariance_factor : float
    max_tries : int
        Bound on truncated-kernel redraws per particle.
    schedule : jax.Array, shape (max(k, 1),)
        The ``k`` scheduled tolerances (``[inf]`` when none), in the prior's dtype.
    num_scheduled : int
        ``k``.
    adaptive_distance : AdaptivePNorm or None
        Bound to the observed vector; then ``init`` and ``update`` take summaries.
    """

    prior: Prior
    num_particles: int
    batch_size: int
    quantile: float
    covariance_factor: float
    max_tries: int
    schedule: jax.Array
    num_scheduled: int
    adaptive_distance: AdaptivePNorm | None


class _Round(NamedTuple):
    """What a round added to the generation being filled (fields as in :class:`PMCState`)."""

    particles: jax.Array
    distances: jax.Array
    filled: jax.Array
    round_simulations: jax.Array
    round_accepted: jax.Array
    acceptance_estimate: jax.Array
    summaries: jax.Array | None
    scale_buffer: jax.Array | None
    scale_count: jax.Array | None


def build(
    prior: Prior,
    num_particles: int,
    thresholds: Sequence[float] | None = None,
    quantile: float = 0.5,
    covariance_factor: float = 2.0,
    max_tries: int = 10_000,
    batch_size: int | None = None,
    adaptive_distance: AdaptivePNorm | None = None,
) -> ABCAlgorithm:
    """Build PMC-ABC.

    Parameters
    ----------
    prior : Prior
    num_particles : int
    thresholds : sequence of float, optional
        Decreasing tolerances for generations 1, 2, ...; generation 0 is the prior.  When the
        schedule runs out (or is not given) the next tolerance is the ``quantile`` of the
        previous generation's distances.
    quantile : float
        In (0, 1); the adaptive tolerance rule.
    covariance_factor : float
        Beaumont et al.'s 2.
    batch_size : int, optional
        Proposal slots per round (default ``4 N``); a round simulates only as many of them as
        it expects to need.  Larger batches mean fewer rounds; a fused JAX run
        (:func:`jaxabc.run_fused`) evaluates every slot, so there a larger batch costs compute.
    adaptive_distance : AdaptivePNorm, optional
        Bound to the observed vector; the algorithm then receives the summaries and computes
        its own distances (see the module docstring).  Scheduled ``thresholds`` are then on
        the scale of the previous generation's weights.

    Returns
    -------
    ABCAlgorithm
        The functions of this module with a :class:`PMCConfig` bound by ``functools.partial``.

    Raises
    ------
    ValueError
        For a batch size below 1, a quantile outside (0, 1), increasing thresholds, or an
        adaptive distance not bound to the observed data.
    """
    n = int(num_particles)
    # Four slots per particle: a round can then fill a generation whose acceptance is down to
    # about a quarter; proposals are cheap, and only the active slots are simulated.
    m = 4 * n if batch_size is None else int(batch_size)
    if m < 1:
        raise ValueError(f"batch_size must be a positive integer, got {batch_size}")
    if not 0.0 < quantile < 1.0:
        raise ValueError(f"quantile must lie in (0, 1), got {quantile}")
    schedule = jnp.asarray(list(thresholds) if thresholds else [jnp.inf], dtype=prior.low.dtype)
    if thresholds and any(b > a for a, b in itertools.pairwise(thresholds)):
        raise ValueError(f"thresholds must be non-increasing, got {list(thresholds)}")
    if adaptive_distance is not None and not adaptive_distance.observed:
        raise ValueError("adaptive_distance must be bound to the observed data: use AdaptivePNorm(...).bind(observed)")
    num_scheduled = len(thresholds) if thresholds else 0
    config = PMCConfig(prior, n, m, quantile, covariance_factor, max_tries, schedule, num_scheduled, adaptive_distance)
    settings = {
        "num_particles": n,
        "thresholds": list(thresholds) if thresholds else None,
        "quantile": quantile,
        "covariance_factor": covariance_factor,
        "batch_size": m,
    }
    if adaptive_distance is not None:
        settings["adaptive_distance"] = adaptive_distance.settings()
    return ABCAlgorithm(
        "pmcabc",
        functools.partial(initial_proposal, config),
        functools.partial(init, config),
        functools.partial(propose, config),
        functools.partial(update, config),
        functools.partial(posterior, config),
        settings,
        needs_stopping_rule=True,
        uses_summaries=adaptive_distance is not None,
    )


def initial_proposal(config: PMCConfig, key: jax.Array) -> Proposal:
    """``N`` prior draws, all active."""
    n = config.num_particles
    return Proposal(config.prior.sample(key, n), jnp.ones((n,), bool), jnp.bool_(True))


def init(
    config: PMCConfig, key: jax.Array, proposal: Proposal, distances: jax.Array, summaries: jax.Array | None = None
) -> tuple[PMCState, Info]:
    """Generation 0 (the prior draws, distances (N,)) and an empty generation 1 to fill.

    ``summaries`` (N, s) is required with an adaptive distance and ignored otherwise.
    """
    n, m = config.num_particles, config.batch_size
    thetas = jnp.asarray(proposal.thetas)
    dtype = thetas.dtype
    log_w = jnp.zeros((n,), dtype)
    scale_buffer = scale_count = None
    if config.adaptive_distance is not None:
        summaries = config.adaptive_distance.summaries_of(summaries, distances, dtype)
        # The prior sample is generation 0's simulations; the buffer then holds the next
        # generation's (its shape fixed by batch_size).
        scale_buffer = jnp.full((m, summaries.shape[1]), jnp.nan, dtype).at[: min(m, n)].set(summaries[: min(m, n)])
        scale_count = jnp.int32(min(m, n))
    # Before any round, guess that the first generation accepts about ``quantile`` of its
    # proposals (exact if the proposal were the prior itself).
    state = _start_generation(
        config, key, thetas, log_w, distances, jnp.int32(0), config.quantile, summaries, scale_buffer, scale_count
    )
    info = Info(
        jnp.bool_(True),
        jnp.bool_(False),
        jnp.asarray(jnp.inf, dtype),
        jnp.asarray(1.0, dtype),
        jnp.asarray(n, dtype),
    )
    return state, info


def propose(config: PMCConfig, key: jax.Array, state: PMCState) -> Proposal:
    """A round of ``batch_size`` kernel draws around resampled parents; the first ones active.

    As many slots are active as the round is expected to need to fill the empty slots (none
    once the generation is full).  ``Proposal.ok`` is False when an active draw found no point
    of the prior's box in ``max_tries``.
    """
    m = config.batch_size
    k_parents, k_kernel = jax.random.split(key)
    missing = jnp.sum(~state.filled).astype(state.acceptance_estimate.dtype)
    # Enough proposals that the round fills every slot with high probability: the
    # accepted count is binomial, so ask for two standard deviations more than missing.
    want = (missing + 2.0 * jnp.sqrt(missing) + 1.0) / state.acceptance_estimate
    count = jnp.minimum(jnp.ceil(want), m).astype(jnp.int32)
    parents = kernels.resample_indices(k_parents, state.parent_log_weights, m)
    draw = kernels.truncated_gaussian_sample(
        k_kernel, state.parents[parents], state.chol, config.prior.low, config.prior.high, config.max_tries
    )
    active = (jnp.arange(m) < count) & (missing > 0)
    return Proposal(draw.samples, active, jnp.all(draw.ok | ~active))


def update(
    config: PMCConfig,
    key: jax.Array,
    state: PMCState,
    proposal: Proposal,
    distances: jax.Array,
    summaries: jax.Array | None = None,
) -> tuple[PMCState, Info]:
    """Fill empty slots with this round's accepted proposals; weigh a generation once it is full.

    ``distances`` has shape (batch_size,); ``summaries`` (batch_size, s) is required with an
    adaptive distance.  ``Info.generation_done`` is True when the generation was completed.
    """
    thetas, active = jnp.asarray(proposal.thetas), jnp.asarray(proposal.active)
    scale_buffer = scale_count = None
    if config.adaptive_distance is not None:
        summaries = config.adaptive_distance.summaries_of(summaries, distances, state.particles.dtype)
        distances, scale_buffer, scale_count = _measure_round(config, state, active, distances, summaries)
    accept = active & (distances <= state.threshold)
    take, source = _fill_in_order(state.filled, accept)
    particles = jnp.where(take[:, None], thetas[source], state.particles)
    filled_distances = jnp.where(take, distances[source], state.distances)
    filled_summaries = None
    if summaries is not None:
        filled_summaries = jnp.where(take[:, None], summaries[source], cast(jax.Array, state.summaries))
    filled = state.filled | take
    sims = state.round_simulations + jnp.sum(active, dtype=jnp.int32)
    acc = state.round_accepted + jnp.sum(accept, dtype=jnp.int32)
    done = jnp.all(filled)
    dtype = particles.dtype
    rate = (acc / jnp.maximum(sims, 1)).astype(dtype)
    # Half an acceptance when none was seen keeps the next round finite and large.
    estimate = jnp.where(sims > 0, jnp.maximum(acc, 0.5) / jnp.maximum(sims, 1), state.acceptance_estimate).astype(
        dtype
    )
    progress = _Round(
        particles, filled_distances, filled, sims, acc, estimate, filled_summaries, scale_buffer, scale_count
    )
    new_state = jax.lax.cond(
        done, functools.partial(_complete_generation, config), _continue_generation, key, state, progress
    )
    ess = kernels.effective_sample_size(new_state.parent_log_weights)
    return new_state, Info(done, jnp.bool_(False), state.threshold, rate, ess)


def posterior(config: PMCConfig, state: PMCState) -> tuple[jax.Array, jax.Array]:
    """The last complete generation, shapes (N, d) and (N,)."""
    del config
    # After a completed generation, particles hold it (and parents equal particles).
    return state.parents, state.parent_log_weights


def _measure_round(
    config: PMCConfig, state: PMCState, active: jax.Array, distances: jax.Array, summaries: jax.Array
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """With an adaptive distance: this round's distances (m,) under the generation's weights,
    and the scale sample (rows, count) with the round's finite simulations appended (rows
    beyond ``batch_size`` are dropped)."""
    assert config.adaptive_distance is not None, "only called with an adaptive distance"
    m = config.batch_size
    finite = active & jnp.isfinite(distances)
    distances = config.adaptive_distance.distances(summaries, cast(jax.Array, state.distance_weights), finite)
    scale_count = cast(jax.Array, state.scale_count)
    row = jnp.where(finite, scale_count + jnp.cumsum(finite) - 1, m)
    rows = cast(jax.Array, state.scale_buffer).at[row].set(summaries, mode="drop")
    return distances, rows, jnp.minimum(scale_count + jnp.sum(finite, dtype=jnp.int32), m)


def _complete_generation(config: PMCConfig, key: jax.Array, state: PMCState, progress: _Round) -> PMCState:
    """Weigh a full generation and start the next one (a ``lax.cond`` branch)."""
    # The single weight pass of the generation: the weights depend only on the kept
    # particle and the previous generation, not on the round that proposed it.
    particles = progress.particles
    log_weights = kernels.mixture_log_weights(
        particles,
        config.prior.log_prob(particles),
        state.parents,
        state.parent_log_weights,
        state.chol,
        state.log_normalizer,
    )
    return _start_generation(
        config,
        key,
        particles,
        log_weights,
        progress.distances,
        state.generation + 1,
        progress.acceptance_estimate,
        progress.summaries,
        progress.scale_buffer,
        progress.scale_count,
    )


def _continue_generation(key: jax.Array, state: PMCState, progress: _Round) -> PMCState:
    """The generation with this round's particles, still not full (a ``lax.cond`` branch)."""
    del key
    out = state._replace(
        particles=progress.particles,
        distances=progress.distances,
        filled=progress.filled,
        round_simulations=progress.round_simulations,
        round_accepted=progress.round_accepted,
        acceptance_estimate=progress.acceptance_estimate,
    )
    if progress.scale_buffer is not None:
        out = out._replace(
            summaries=progress.summaries, scale_buffer=progress.scale_buffer, scale_count=progress.scale_count
        )
    return out


def _start_generation(
    config: PMCConfig,
    key: jax.Array,
    particles: jax.Array,
    log_weights: jax.Array,
    distances: jax.Array,
    generation: jax.Array,
    acceptance_estimate: jax.Array | float,
    summaries: jax.Array | None = None,
    scale_buffer: jax.Array | None = None,
    scale_count: jax.Array | None = None,
) -> PMCState:
    """The state that fills generation ``generation + 1`` from the complete one given (N slots).

    With an adaptive distance the new distance weights come from the scale sample and the
    particles' distances are recomputed with them before the next threshold is chosen.
    """
    distance_weights = None
    if config.adaptive_distance is not None:
        assert summaries is not None and scale_buffer is not None and scale_count is not None, (
            "adaptive states carry summaries"
        )
        # Prangle: the new scales come from this generation's simulations, and its
        # particles are re-measured with them before the next threshold is chosen.
        distance_weights = adaptive_weights(scale_buffer, jnp.arange(scale_buffer.shape[0]) < scale_count)
        distances = config.adaptive_distance.distances(summaries, distance_weights, jnp.isfinite(distances))
        scale_count = jnp.int32(0)
    low, high = config.prior.low, config.prior.high
    cov = config.covariance_factor * kernels.weighted_covariance(particles, log_weights)
    chol = jnp.linalg.cholesky(kernels.regularize_covariance(cov, low, high))
    log_norm = kernels.log_truncation_normalizer(key, particles, chol, low, high)
    return PMCState(
        particles=particles,
        log_weights=log_weights,
        distances=distances,
        filled=jnp.zeros((config.num_particles,), bool),
        parents=particles,
        parent_log_weights=log_weights,
        chol=chol,
        log_normalizer=log_norm,
        threshold=_next_threshold(config, distances, generation),
        generation=generation,
        round_simulations=jnp.int32(0),
        round_accepted=jnp.int32(0),
        acceptance_estimate=jnp.asarray(acceptance_estimate, particles.dtype),
        summaries=summaries,
        distance_weights=distance_weights,
        scale_buffer=scale_buffer,
        scale_count=scale_count,
    )


def _next_threshold(config: PMCConfig, distances: jax.Array, generation: jax.Array) -> jax.Array:
    """The tolerance after ``generation`` complete generations (0: the prior sample): the
    schedule while it lasts, then the ``quantile`` of ``distances`` (N,); shape ()."""
    quantile_threshold = kernels.weighted_quantile(distances, jnp.zeros_like(distances), config.quantile)
    scheduled = config.schedule[jnp.minimum(generation, max(config.num_scheduled - 1, 0))]
    return jnp.where(generation < config.num_scheduled, scheduled, quantile_threshold)


class RejectionConfig(NamedTuple):
    """Rejection ABC's configuration, fixed by :func:`build_rejection`.

    Attributes
    ----------
    prior : Prior
    num_particles : int
        ``N``, the particles kept.
    batch_size : int
        Prior draws of the first batch: ``N`` with a threshold, ``ceil(N / quantile)`` with a
        quantile.
    threshold : float or None
    quantile : float or None
        Exactly one of ``threshold`` and ``quantile`` is set.
    """

    prior: Prior
    num_particles: int
    batch_size: int
    threshold: float | None
    quantile: float | None


def build_rejection(
    prior: Prior,
    num_particles: int,
    threshold: float | None = None,
    quantile: float | None = None,
) -> ABCAlgorithm:
    """Build rejection ABC.

    Give either ``threshold`` (simulate rounds of prior draws until ``num_particles`` are
    within it) or ``quantile`` (simulate ``ceil(num_particles / quantile)`` prior draws at once
    and keep the ``num_particles`` closest).

    Raises
    ------
    ValueError
        Unless exactly one of ``threshold`` (positive) and ``quantile`` (in (0, 1]) is given.
    """
    n = int(num_particles)
    if (threshold is None) == (quantile is None):
        raise ValueError("rejection ABC needs exactly one of threshold= or quantile=")
    if quantile is not None and not 0.0 < quantile <= 1.0:
        raise ValueError(f"quantile must lie in (0, 1], got {quantile}")
    if threshold is not None and not threshold > 0:
        raise ValueError(f"threshold must be positive, got {threshold}")
    batch = n if quantile is None else math.ceil(n / quantile)
    config = RejectionConfig(prior, n, batch, threshold, quantile)
    settings = {"num_particles": n, "threshold": threshold, "quantile": quantile}
    # With a threshold nothing bounds the number of rounds: an unreachable one would run forever.
    return ABCAlgorithm(
        "rejection",
        functools.partial(rejection_initial_proposal, config),
        functools.partial(rejection_init, config),
        functools.partial(rejection_propose, config),
        functools.partial(rejection_update, config),
        functools.partial(rejection_posterior, config),
        settings,
        stop_reason=_rejection_stop_reason,
        needs_stopping_rule=threshold is not None,
    )


def rejection_initial_proposal(config: RejectionConfig, key: jax.Array) -> Proposal:
    """``batch_size`` prior draws, all active."""
    batch = config.batch_size
    return Proposal(config.prior.sample(key, batch), jnp.ones((batch,), bool), jnp.bool_(True))


def rejection_init(
    config: RejectionConfig, key: jax.Array, proposal: Proposal, distances: jax.Array
) -> tuple[PMCState, Info]:
    """With a quantile, the ``N`` closest of the first batch (done at once); with a threshold,
    the first round of filling (:func:`rejection_update`).  ``distances`` has shape (batch_size,)."""
    del key
    n = config.num_particles
    thetas = jnp.asarray(proposal.thetas)
    dtype = thetas.dtype
    if config.quantile is not None:
        order = jnp.argsort(distances, stable=True)[:n]
        threshold = distances[order[-1]]
        state = _rejection_state(
            config,
            thetas[order],
            distances[order],
            jnp.ones((n,), bool),
            threshold,
            jnp.int32(config.batch_size),
            jnp.int32(n),
            dtype,
        )
        rate = jnp.asarray(n / config.batch_size, dtype)
        return state, Info(jnp.bool_(True), jnp.bool_(True), threshold, rate, jnp.asarray(n, dtype))
    empty = _rejection_state(
        config,
        thetas,
        jnp.full((n,), jnp.inf, dtype),
        jnp.zeros((n,), bool),
        jnp.asarray(config.threshold, dtype),
        jnp.int32(0),
        jnp.int32(0),
        dtype,
    )
    return rejection_update(config, None, empty, proposal, distances)


def rejection_propose(config: RejectionConfig, key: jax.Array, state: PMCState) -> Proposal:
    """``N`` prior draws, active for the empty slots."""
    return Proposal(config.prior.sample(key, config.num_particles), ~state.filled, jnp.bool_(True))


def rejection_update(
    config: RejectionConfig, key: jax.Array | None, state: PMCState, proposal: Proposal, distances: jax.Array
) -> tuple[PMCState, Info]:
    """Fill empty slots with the proposals within the threshold; ``Info.stop`` once all are full."""
    del key
    active = jnp.asarray(proposal.active)
    accept = active & (distances <= state.threshold)
    # Compact: the i-th accepted proposal of this round fills the i-th empty slot, so a
    # round never wastes an accepted simulation on an already filled slot.
    take, source = _fill_in_order(state.filled, accept)
    particles = jnp.where(take[:, None], jnp.asarray(proposal.thetas)[source], state.particles)
    filled_distances = jnp.where(take, distances[source], state.distances)
    filled = state.filled | take
    sims = state.round_simulations + jnp.sum(active, dtype=jnp.int32)
    acc = state.round_accepted + jnp.sum(take, dtype=jnp.int32)
    done = jnp.all(filled)
    dtype = particles.dtype
    new_state = state._replace(
        particles=particles,
        distances=filled_distances,
        filled=filled,
        parents=particles,
        round_simulations=sims,
        round_accepted=acc,
    )
    rate = (acc / jnp.maximum(sims, 1)).astype(dtype)
    return new_state, Info(done, done, state.threshold, rate, jnp.asarray(config.num_particles, dtype))


def rejection_posterior(config: RejectionConfig, state: PMCState) -> tuple[jax.Array, jax.Array]:
    """The filled slots, with equal weights; shapes (N, d) and (N,)."""
    del config
    return state.particles, jnp.where(state.filled, 0.0, -jnp.inf).astype(state.particles.dtype)


def _rejection_state(
    config: RejectionConfig,
    particles: jax.Array,
    distances: jax.Array,
    filled: jax.Array,
    threshold: jax.Array,
    round_simulations: jax.Array,
    round_accepted: jax.Array,
    dtype: Any,
) -> PMCState:
    """A rejection state (a :class:`PMCState` whose kernel fields are placeholders)."""
    lw = jnp.zeros((config.num_particles,), dtype)
    return PMCState(
        particles,
        lw,
        distances,
        filled,
        particles,
        lw,
        jnp.eye(particles.shape[1], dtype=dtype),
        jnp.zeros((config.num_particles,), dtype),
        threshold,
        jnp.int32(0),
        round_simulations,
        round_accepted,
        jnp.asarray(1.0, dtype),
    )


def _rejection_stop_reason(settings: dict, info: Info) -> str:
    if settings["threshold"] is not None:
        return f"{settings['num_particles']} particles within threshold {settings['threshold']}"
    return f"kept the {settings['num_particles']} closest (quantile {settings['quantile']})"
