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

import itertools
import math
from collections.abc import Sequence
from typing import NamedTuple, cast

import jax
import jax.numpy as jnp

from jaxabc import kernels
from jaxabc.algorithms.base import ABCAlgorithm, Info, Proposal
from jaxabc.distances import AdaptivePNorm, adaptive_weights
from jaxabc.priors import Prior

__all__ = ["PMCState", "build", "build_rejection"]


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
    num_scheduled = len(thresholds) if thresholds else 0
    if thresholds and any(b > a for a, b in itertools.pairwise(thresholds)):
        raise ValueError(f"thresholds must be non-increasing, got {list(thresholds)}")
    low, high = prior.low, prior.high
    # ``spec``, not ``adaptive``: that name is the quantile threshold in _start_generation.
    spec = adaptive_distance
    if spec is not None and not spec.observed:
        raise ValueError("adaptive_distance must be bound to the observed data: use AdaptivePNorm(...).bind(observed)")

    def _start_generation(key, particles, log_weights, distances, generation, acceptance, summaries=None, buffer=None):
        dweights = count = None
        if spec is not None:
            assert summaries is not None and buffer is not None, "adaptive states carry summaries"
            # Prangle: the new scales come from this generation's simulations, and its
            # particles are re-measured with them before the next threshold is chosen.
            buffer, num_rows = buffer
            dweights = adaptive_weights(buffer, jnp.arange(buffer.shape[0]) < num_rows)
            distances = spec.distances(summaries, dweights, jnp.isfinite(distances))
            count = jnp.int32(0)
        cov = covariance_factor * kernels.weighted_covariance(particles, log_weights)
        chol = jnp.linalg.cholesky(kernels.regularize_covariance(cov, low, high))
        log_norm = kernels.log_truncation_normalizer(key, particles, chol, low, high)
        # ``generation`` is the number of completed generations (0: the prior sample); the
        # next one uses the schedule while it lasts, then the adaptive quantile.
        adaptive = kernels.weighted_quantile(distances, jnp.zeros_like(distances), quantile)
        scheduled = schedule[jnp.minimum(generation, max(num_scheduled - 1, 0))]
        threshold = jnp.where(generation < num_scheduled, scheduled, adaptive)
        return PMCState(
            particles=particles,
            log_weights=log_weights,
            distances=distances,
            filled=jnp.zeros((n,), bool),
            parents=particles,
            parent_log_weights=log_weights,
            chol=chol,
            log_normalizer=log_norm,
            threshold=threshold,
            generation=generation,
            round_simulations=jnp.int32(0),
            round_accepted=jnp.int32(0),
            acceptance_estimate=jnp.asarray(acceptance, particles.dtype),
            summaries=summaries,
            distance_weights=dweights,
            scale_buffer=buffer,
            scale_count=count,
        )

    def initial_proposal(key):
        return Proposal(prior.sample(key, n), jnp.ones((n,), bool), jnp.bool_(True))

    def init(key, proposal, distances, summaries=None):
        dtype = proposal.thetas.dtype
        log_w = jnp.zeros((n,), dtype)
        buffer = None
        if spec is not None:
            summaries = spec.summaries_of(summaries, distances, dtype)
            # The prior sample is generation 0's simulations; the buffer then holds the next
            # generation's (its shape fixed by batch_size).
            rows = jnp.full((m, summaries.shape[1]), jnp.nan, dtype).at[: min(m, n)].set(summaries[: min(m, n)])
            buffer = (rows, jnp.int32(min(m, n)))
        # Before any round, guess that the first generation accepts about ``quantile`` of its
        # proposals (exact if the proposal were the prior itself).
        state = _start_generation(key, proposal.thetas, log_w, distances, jnp.int32(0), quantile, summaries, buffer)
        info = Info(
            jnp.bool_(True),
            jnp.bool_(False),
            jnp.asarray(jnp.inf, dtype),
            jnp.asarray(1.0, dtype),
            jnp.asarray(n, dtype),
        )
        return state, info

    def propose(key, state):
        k1, k2 = jax.random.split(key)
        missing = jnp.sum(~state.filled).astype(state.acceptance_estimate.dtype)
        # Enough proposals that the round fills every slot with high probability: the
        # accepted count is binomial, so ask for two standard deviations more than missing.
        want = (missing + 2.0 * jnp.sqrt(missing) + 1.0) / state.acceptance_estimate
        count = jnp.minimum(jnp.ceil(want), m).astype(jnp.int32)
        parents = kernels.resample_indices(k1, state.parent_log_weights, m)
        draw = kernels.truncated_gaussian_sample(k2, state.parents[parents], state.chol, low, high, max_tries)
        active = (jnp.arange(m) < count) & (missing > 0)
        return Proposal(draw.samples, active, jnp.all(draw.ok | ~active))

    def update(key, state, proposal, distances, summaries=None):
        summ = buffer = None
        if spec is not None:
            summaries = spec.summaries_of(summaries, distances, state.particles.dtype)
            finite = proposal.active & jnp.isfinite(distances)
            distances = spec.distances(summaries, state.distance_weights, finite)
            # Append this round's finite simulations to the generation's scale sample; rows
            # beyond the buffer are dropped.
            row = jnp.where(finite, state.scale_count + jnp.cumsum(finite) - 1, m)
            rows = cast(jax.Array, state.scale_buffer).at[row].set(summaries, mode="drop")
            buffer = (rows, jnp.minimum(state.scale_count + jnp.sum(finite, dtype=jnp.int32), m))
        accept = proposal.active & (distances <= state.threshold)
        take, source = _fill_in_order(state.filled, accept)
        particles = jnp.where(take[:, None], proposal.thetas[source], state.particles)
        dists = jnp.where(take, distances[source], state.distances)
        if summaries is not None:
            summ = jnp.where(take[:, None], summaries[source], state.summaries)
        filled = state.filled | take
        sims = state.round_simulations + jnp.sum(proposal.active, dtype=jnp.int32)
        acc = state.round_accepted + jnp.sum(accept, dtype=jnp.int32)
        done = jnp.all(filled)
        dtype = particles.dtype
        rate = (acc / jnp.maximum(sims, 1)).astype(dtype)
        # Half an acceptance when none was seen keeps the next round finite and large.
        estimate = jnp.where(sims > 0, jnp.maximum(acc, 0.5) / jnp.maximum(sims, 1), state.acceptance_estimate).astype(
            dtype
        )

        def finish(_):
            # The single weight pass of the generation: the weights depend only on the kept
            # particle and the previous generation, not on the round that proposed it.
            log_weights = kernels.mixture_log_weights(
                particles,
                prior.log_prob(particles),
                state.parents,
                state.parent_log_weights,
                state.chol,
                state.log_normalizer,
            )
            return _start_generation(key, particles, log_weights, dists, state.generation + 1, estimate, summ, buffer)

        def carry_on(_):
            out = state._replace(
                particles=particles,
                distances=dists,
                filled=filled,
                round_simulations=sims,
                round_accepted=acc,
                acceptance_estimate=estimate,
            )
            if buffer is not None:
                out = out._replace(summaries=summ, scale_buffer=buffer[0], scale_count=buffer[1])
            return out

        new_state = jax.lax.cond(done, finish, carry_on, None)
        ess = kernels.effective_sample_size(new_state.parent_log_weights)
        return new_state, Info(done, jnp.bool_(False), state.threshold, rate, ess)

    def posterior(state):
        # After a completed generation, particles hold it (and parents equal particles).
        return state.parents, state.parent_log_weights

    settings = {
        "num_particles": n,
        "thresholds": list(thresholds) if thresholds else None,
        "quantile": quantile,
        "covariance_factor": covariance_factor,
        "batch_size": m,
    }
    if spec is not None:
        settings["adaptive_distance"] = spec.settings()
    return ABCAlgorithm(
        "pmcabc",
        initial_proposal,
        init,
        propose,
        update,
        posterior,
        settings,
        needs_stopping_rule=True,
        uses_summaries=spec is not None,
    )


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
    """
    n = int(num_particles)
    if (threshold is None) == (quantile is None):
        raise ValueError("rejection ABC needs exactly one of threshold= or quantile=")
    if quantile is not None and not 0.0 < quantile <= 1.0:
        raise ValueError(f"quantile must lie in (0, 1], got {quantile}")
    if threshold is not None and not threshold > 0:
        raise ValueError(f"threshold must be positive, got {threshold}")
    batch = n if quantile is None else math.ceil(n / quantile)

    def _state(particles, distances, filled, thr, sims, acc, dtype):
        lw = jnp.zeros((n,), dtype)
        return PMCState(
            particles,
            lw,
            distances,
            filled,
            particles,
            lw,
            jnp.eye(particles.shape[1], dtype=dtype),
            jnp.zeros((n,), dtype),
            thr,
            jnp.int32(0),
            sims,
            acc,
            jnp.asarray(1.0, dtype),
        )

    def initial_proposal(key):
        return Proposal(prior.sample(key, batch), jnp.ones((batch,), bool), jnp.bool_(True))

    def init(key, proposal, distances):
        del key
        dtype = proposal.thetas.dtype
        if quantile is not None:
            order = jnp.argsort(distances, stable=True)[:n]
            thr = distances[order[-1]]
            state = _state(
                proposal.thetas[order],
                distances[order],
                jnp.ones((n,), bool),
                thr,
                jnp.int32(batch),
                jnp.int32(n),
                dtype,
            )
            info = Info(jnp.bool_(True), jnp.bool_(True), thr, jnp.asarray(n / batch, dtype), jnp.asarray(n, dtype))
            return state, info
        empty = _state(
            proposal.thetas,
            jnp.full((n,), jnp.inf, dtype),
            jnp.zeros((n,), bool),
            jnp.asarray(threshold, dtype),
            jnp.int32(0),
            jnp.int32(0),
            dtype,
        )
        return update(None, empty, proposal, distances)

    def propose(key, state):
        return Proposal(prior.sample(key, n), ~state.filled, jnp.bool_(True))

    def update(key, state, proposal, distances):
        del key
        accept = proposal.active & (distances <= state.threshold)
        # Compact: the i-th accepted proposal of this round fills the i-th empty slot, so a
        # round never wastes an accepted simulation on an already filled slot.
        take, source = _fill_in_order(state.filled, accept)
        particles = jnp.where(take[:, None], proposal.thetas[source], state.particles)
        dists = jnp.where(take, distances[source], state.distances)
        filled = state.filled | take
        sims = state.round_simulations + jnp.sum(proposal.active, dtype=jnp.int32)
        acc = state.round_accepted + jnp.sum(take, dtype=jnp.int32)
        done = jnp.all(filled)
        dtype = particles.dtype
        new_state = state._replace(
            particles=particles,
            distances=dists,
            filled=filled,
            parents=particles,
            round_simulations=sims,
            round_accepted=acc,
        )
        rate = (acc / jnp.maximum(sims, 1)).astype(dtype)
        return new_state, Info(done, done, state.threshold, rate, jnp.asarray(n, dtype))

    def posterior(state):
        return state.particles, jnp.where(state.filled, 0.0, -jnp.inf).astype(state.particles.dtype)

    settings = {"num_particles": n, "threshold": threshold, "quantile": quantile}
    # With a threshold nothing bounds the number of rounds: an unreachable one would run forever.
    return ABCAlgorithm(
        "rejection",
        initial_proposal,
        init,
        propose,
        update,
        posterior,
        settings,
        stop_reason=_rejection_stop_reason,
        needs_stopping_rule=threshold is not None,
    )


def _rejection_stop_reason(settings: dict, info: Info) -> str:
    if settings["threshold"] is not None:
        return f"{settings['num_particles']} particles within threshold {settings['threshold']}"
    return f"kept the {settings['num_particles']} closest (quantile {settings['quantile']})"
