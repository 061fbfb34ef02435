"""Population Monte Carlo ABC (Beaumont, Cornuet, Marin & Robert 2009), and rejection ABC.

PMC-ABC fills each generation of ``N`` particles by repeated rounds: every empty slot draws a
parent from the previous generation, perturbs it with a truncated Gaussian of twice the
previous weighted covariance, simulates, and is filled when the distance is at most the
generation's threshold.  The weights are ``prior / sum_j w_j K(theta | theta_j)``.  Thresholds
come from a schedule or, by default, the ``quantile`` of the previous generation's distances.

Rejection ABC is the same filling loop with the prior as proposal and a single generation; with
``threshold=None`` it instead simulates ``ceil(N / quantile)`` prior draws and keeps the best
``N`` (then ``quantile`` is the acceptance rate).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxabc import kernels
from jaxabc.algorithms.base import ABCAlgorithm, Info, Proposal
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
        Counters over the generation being filled (for the acceptance rate).
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


def build(
    prior: Prior,
    num_particles: int,
    thresholds: Sequence[float] | None = None,
    quantile: float = 0.5,
    covariance_factor: float = 2.0,
    max_tries: int = 10_000,
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
    """
    n = int(num_particles)
    if not 0.0 < quantile < 1.0:
        raise ValueError(f"quantile must lie in (0, 1), got {quantile}")
    schedule = jnp.asarray(list(thresholds) if thresholds else [jnp.inf], dtype=prior.low.dtype)
    num_scheduled = len(thresholds) if thresholds else 0
    if thresholds and any(b > a for a, b in itertools.pairwise(thresholds)):
        raise ValueError(f"thresholds must be non-increasing, got {list(thresholds)}")
    low, high = prior.low, prior.high

    def _start_generation(key, particles, log_weights, distances, generation):
        cov = covariance_factor * kernels.weighted_covariance(particles, log_weights)
        chol = jnp.linalg.cholesky(kernels.regularize_covariance(cov, low, high))
        log_norm = kernels.log_truncation_normalizer(key, particles, chol, low, high)
        # ``generation`` is the number of completed generations (0: the prior sample); the
        # next one uses the schedule while it lasts, then the adaptive quantile.
        adaptive = kernels.weighted_quantile(distances, jnp.zeros_like(distances), quantile)
        scheduled = schedule[jnp.minimum(generation, max(num_scheduled - 1, 0))]
        threshold = jnp.where(generation < num_scheduled, scheduled, adaptive)
        return PMCState(
            particles=particles, log_weights=log_weights, distances=distances,
            filled=jnp.zeros((n,), bool), parents=particles, parent_log_weights=log_weights,
            chol=chol, log_normalizer=log_norm, threshold=threshold, generation=generation,
            round_simulations=jnp.int32(0), round_accepted=jnp.int32(0),
        )

    def initial_proposal(key):
        return Proposal(prior.sample(key, n), jnp.ones((n,), bool), jnp.bool_(True))

    def init(key, proposal, distances):
        dtype = proposal.thetas.dtype
        log_w = jnp.zeros((n,), dtype)
        state = _start_generation(key, proposal.thetas, log_w, distances, jnp.int32(0))
        info = Info(jnp.bool_(True), jnp.bool_(False), jnp.asarray(jnp.inf, dtype),
                    jnp.asarray(1.0, dtype), jnp.asarray(n, dtype))
        return state, info

    def propose(key, state):
        k1, k2 = jax.random.split(key)
        parents = kernels.resample_indices(k1, state.parent_log_weights, n)
        draw = kernels.truncated_gaussian_sample(
            k2, state.parents[parents], state.chol, low, high, max_tries
        )
        active = ~state.filled
        return Proposal(draw.samples, active, jnp.all(draw.ok | ~active))

    def update(key, state, proposal, distances):
        accept = proposal.active & (distances <= state.threshold)
        new_lw = kernels.mixture_log_weights(
            proposal.thetas, prior.log_prob(proposal.thetas), state.parents,
            state.parent_log_weights, state.chol, state.log_normalizer,
        )
        particles = jnp.where(accept[:, None], proposal.thetas, state.particles)
        log_weights = jnp.where(accept, new_lw, state.log_weights)
        dists = jnp.where(accept, distances, state.distances)
        filled = state.filled | accept
        sims = state.round_simulations + jnp.sum(proposal.active, dtype=jnp.int32)
        acc = state.round_accepted + jnp.sum(accept, dtype=jnp.int32)
        done = jnp.all(filled)
        rate = (acc / jnp.maximum(sims, 1)).astype(particles.dtype)

        def finish(_):
            return _start_generation(key, particles, log_weights, dists, state.generation + 1)

        def carry_on(_):
            return state._replace(particles=particles, log_weights=log_weights, distances=dists,
                                  filled=filled, round_simulations=sims, round_accepted=acc)

        new_state = jax.lax.cond(done, finish, carry_on, None)
        ess = kernels.effective_sample_size(log_weights)
        return new_state, Info(done, jnp.bool_(False), state.threshold, rate, ess)

    def posterior(state):
        # After a completed generation, particles hold it (and parents equal particles).
        return state.parents, state.parent_log_weights

    settings = {
        "num_particles": n,
        "thresholds": list(thresholds) if thresholds else None,
        "quantile": quantile,
        "covariance_factor": covariance_factor,
    }
    return ABCAlgorithm("pmcabc", initial_proposal, init, propose, update, posterior, settings,
                        needs_stopping_rule=True)


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
        return PMCState(particles, lw, distances, filled, particles, lw,
                        jnp.eye(particles.shape[1], dtype=dtype), jnp.zeros((n,), dtype), thr,
                        jnp.int32(0), sims, acc)

    def initial_proposal(key):
        return Proposal(prior.sample(key, batch), jnp.ones((batch,), bool), jnp.bool_(True))

    def init(key, proposal, distances):
        del key
        dtype = proposal.thetas.dtype
        if quantile is not None:
            order = jnp.argsort(distances, stable=True)[:n]
            thr = distances[order[-1]]
            state = _state(proposal.thetas[order], distances[order], jnp.ones((n,), bool), thr,
                           jnp.int32(batch), jnp.int32(n), dtype)
            info = Info(jnp.bool_(True), jnp.bool_(True), thr, jnp.asarray(n / batch, dtype),
                        jnp.asarray(n, dtype))
            return state, info
        empty = _state(proposal.thetas, jnp.full((n,), jnp.inf, dtype), jnp.zeros((n,), bool),
                       jnp.asarray(threshold, dtype), jnp.int32(0), jnp.int32(0), dtype)
        return update(None, empty, proposal, distances)

    def propose(key, state):
        return Proposal(prior.sample(key, n), ~state.filled, jnp.bool_(True))

    def update(key, state, proposal, distances):
        del key
        accept = proposal.active & (distances <= state.threshold)
        # Compact: the i-th accepted proposal of this round fills the i-th empty slot, so a
        # round never wastes an accepted simulation on an already filled slot.
        empty_rank = jnp.cumsum(~state.filled) - 1
        acc_rank = jnp.cumsum(accept) - 1
        num_empty = jnp.sum(~state.filled)
        src = jnp.full((n,), -1).at[jnp.where(accept & (acc_rank < num_empty), acc_rank, n)].set(
            jnp.arange(n), mode="drop")
        take = (~state.filled) & (empty_rank < jnp.sum(accept))
        source = jnp.where(take, src[jnp.clip(empty_rank, 0, n - 1)], 0)
        particles = jnp.where(take[:, None], proposal.thetas[source], state.particles)
        dists = jnp.where(take, distances[source], state.distances)
        filled = state.filled | take
        sims = state.round_simulations + jnp.sum(proposal.active, dtype=jnp.int32)
        acc = state.round_accepted + jnp.sum(take, dtype=jnp.int32)
        done = jnp.all(filled)
        dtype = particles.dtype
        new_state = state._replace(particles=particles, distances=dists, filled=filled,
                                   parents=particles, round_simulations=sims, round_accepted=acc)
        rate = (acc / jnp.maximum(sims, 1)).astype(dtype)
        return new_state, Info(done, done, state.threshold, rate, jnp.asarray(n, dtype))

    def posterior(state):
        return state.particles, jnp.where(state.filled, 0.0, -jnp.inf).astype(state.particles.dtype)

    settings = {"num_particles": n, "threshold": threshold, "quantile": quantile}
    # With a threshold nothing bounds the number of rounds: an unreachable one would run forever.
    return ABCAlgorithm("rejection", initial_proposal, init, propose, update, posterior, settings,
                        stop_reason=_rejection_stop_reason, needs_stopping_rule=threshold is not None)


def _rejection_stop_reason(settings: dict, info: Info) -> str:
    if settings["threshold"] is not None:
        return f"{settings['num_particles']} particles within threshold {settings['threshold']}"
    return f"kept the {settings['num_particles']} closest (quantile {settings['quantile']})"
