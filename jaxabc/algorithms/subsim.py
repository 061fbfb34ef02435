"""ABC subset simulation, ABCsubsim (Chiachio, Beck, Chiachio & Rus 2014).

The ABC posterior is written as a chain of nested events ``{d < eps_1} > {d < eps_2} > ...``.
Level 0 samples the prior.  At every level the best ``N P0`` particles seed ``N P0`` Markov
chains of length ``1 / P0`` (the seed included) that sample the prior restricted to
``d < eps_j``, so each level produces ``N`` particles; ``eps_{j+1}`` is halfway between the
``N P0``-th and the next smallest distance.  ``P(d < eps_j)`` is estimated by ``P0^j`` (the
model evidence at tolerance ``eps_j``).

The chains use a Gaussian random-walk proposal with covariance ``lambda x`` the seeds'
covariance, re-estimated each level; ``lambda`` is adapted from the previous level's move
acceptance rate to bring it into ``[0.2, 0.5]`` (Chiachio et al. recommend that band): it is
multiplied by ``acceptance / 0.35`` (limited to ``[0.5, 2]``) whenever the rate falls outside.
Under a uniform prior the Metropolis ratio is one inside the box, so a move is accepted iff the
proposal lies in the prior box and meets the level's threshold; proposals outside the box are
rejected without simulating.

The chains of a level are sequential: ``1 / P0 - 1`` rounds of ``N P0`` parallel simulations.
That is why ABCsubsim parallelises less well than APMCABC (``N - N alpha`` independent
simulations per step), which the speedup benchmark shows.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxabc import kernels
from jaxabc.algorithms.base import ABCAlgorithm, Info, Proposal
from jaxabc.priors import Prior

__all__ = ["SubsimState", "build"]


class SubsimState(NamedTuple):
    """State of ABCsubsim.

    Attributes
    ----------
    particles : jax.Array, shape (N, d)
        The last completed level's samples: the posterior at tolerance ``completed_threshold``.
    distances : jax.Array, shape (N,)
    buffer : jax.Array, shape (N, d)
        The level being built: the seeds, then the chain states step by step.
    buffer_distances : jax.Array, shape (N,)
    chain_position : jax.Array, shape (C, d)
        The current state of each of the ``C = N P0`` chains.
    chain_distance : jax.Array, shape (C,)
    chain_step : jax.Array, shape ()
        Next chain step to fill, in ``1 .. 1/P0``.
    threshold : jax.Array, shape ()
        ``eps_j``, the level's tolerance (``+inf`` at level 0).
    chol : jax.Array, shape (d, d)
        Cholesky factor of the seeds' covariance (before the scale ``lambda``).
    scale : jax.Array, shape ()
        ``lambda``, the adapted proposal scale.
    level : jax.Array, shape ()
        ``j``; the evidence estimate is ``P0^j``.
    moves_accepted : jax.Array, shape ()
    moves_proposed : jax.Array, shape ()
    level_acceptance : jax.Array, shape ()
        Move acceptance rate of the last completed level.
    """

    particles: jax.Array
    distances: jax.Array
    buffer: jax.Array
    buffer_distances: jax.Array
    chain_position: jax.Array
    chain_distance: jax.Array
    chain_step: jax.Array
    threshold: jax.Array
    chol: jax.Array
    scale: jax.Array
    level: jax.Array
    moves_accepted: jax.Array
    moves_proposed: jax.Array
    level_acceptance: jax.Array


def build(
    prior: Prior,
    num_particles: int,
    p0: float = 0.2,
    final_threshold: float = 0.0,
    acceptance_floor: float = 0.0,
    initial_scale: float = 1.0,
) -> ABCAlgorithm:
    """Build ABCsubsim.

    Parameters
    ----------
    prior : Prior
    num_particles : int
        ``N``; ``N P0`` and ``1 / P0`` must be whole numbers.
    p0 : float
        Conditional probability of each level, in (0, 0.5] (the paper: 0.2).
    final_threshold : float
        Stop once the level's threshold is at or below this.
    acceptance_floor : float
        Stop when a level's move acceptance rate falls below this (the chains no longer mix).
    initial_scale : float
        Starting ``lambda``.
    """
    if not 0.0 < p0 <= 0.5:
        raise ValueError(f"p0 must lie in (0, 0.5], got {p0}; Chiachio et al. use 0.1-0.2")
    chain_length = round(1.0 / p0)
    n = int(num_particles)
    num_chains = round(n * p0)
    if not math.isclose(chain_length * p0, 1.0, rel_tol=1e-9) or num_chains * chain_length != n:
        raise ValueError(
            f"ABCsubsim needs 1/p0 and num_particles*p0 to be whole numbers: p0={p0}, "
            f"num_particles={n}; e.g. p0=0.2 with num_particles a multiple of 5"
        )
    if num_chains < 2:
        raise ValueError(f"num_particles*p0 = {num_chains} chains: need at least 2")
    low, high = prior.low, prior.high

    def _new_level(particles, distances, scale, level, level_acceptance):
        order = jnp.argsort(distances, stable=True)
        sorted_d = distances[order]
        threshold = 0.5 * (sorted_d[num_chains - 1] + sorted_d[num_chains])
        # With ties the midpoint equals both; keep the seeds' own largest distance then, so the
        # seeds are inside their level.
        threshold = jnp.where(sorted_d[num_chains] > sorted_d[num_chains - 1], threshold,
                              sorted_d[num_chains - 1])
        seeds = particles[order[:num_chains]]
        seed_d = sorted_d[:num_chains]
        cov = kernels.weighted_covariance(seeds, jnp.zeros((num_chains,), seeds.dtype))
        chol = jnp.linalg.cholesky(kernels.regularize_covariance(cov, low, high))
        return SubsimState(
            particles=particles,
            distances=distances,
            buffer=particles.at[:num_chains].set(seeds),
            buffer_distances=distances.at[:num_chains].set(seed_d),
            chain_position=seeds,
            chain_distance=seed_d,
            chain_step=jnp.int32(1),
            threshold=threshold,
            chol=chol,
            scale=scale,
            level=level,
            moves_accepted=jnp.int32(0),
            moves_proposed=jnp.int32(0),
            level_acceptance=level_acceptance,
        )

    def _info(state, done, stop, threshold, acceptance):
        return Info(done, stop, threshold, acceptance, jnp.asarray(n, state.particles.dtype))

    def initial_proposal(key):
        return Proposal(prior.sample(key, n), jnp.ones((n,), bool), jnp.bool_(True))

    def init(key, proposal, distances):
        del key
        dtype = proposal.thetas.dtype
        state = _new_level(proposal.thetas, distances, jnp.asarray(initial_scale, dtype),
                           jnp.int32(0), jnp.asarray(1.0, dtype))
        # Level 0's population is the prior sample, at tolerance +inf.
        return state, _info(state, jnp.bool_(True), jnp.bool_(False),
                            jnp.asarray(jnp.inf, dtype), jnp.asarray(1.0, dtype))

    def propose(key, state):
        z = jax.random.normal(key, state.chain_position.shape, state.chain_position.dtype)
        proposal = state.chain_position + jnp.sqrt(state.scale) * z @ state.chol.T
        inside = prior.contains(proposal)
        return Proposal(proposal, inside, jnp.bool_(True))

    def update(key, state, proposal, distances):
        del key
        accept = proposal.active & (distances < state.threshold)
        position = jnp.where(accept[:, None], proposal.thetas, state.chain_position)
        chain_d = jnp.where(accept, distances, state.chain_distance)
        start = state.chain_step * num_chains
        particles = jax.lax.dynamic_update_slice(state.buffer, position, (start, jnp.int32(0)))
        dists = jax.lax.dynamic_update_slice(state.buffer_distances, chain_d, (start,))
        accepted = state.moves_accepted + jnp.sum(accept, dtype=jnp.int32)
        proposed = state.moves_proposed + num_chains
        step = state.chain_step + 1
        level_done = step == chain_length
        rate = accepted / jnp.maximum(proposed, 1)
        rate = rate.astype(particles.dtype)

        def finish(_):
            out_of_band = (rate < 0.2) | (rate > 0.5)
            factor = jnp.where(out_of_band, jnp.clip(rate / 0.35, 0.5, 2.0), 1.0)
            # The level's population (all below state.threshold) is the posterior at that
            # tolerance; the next level's seeds and threshold come from it.
            return _new_level(particles, dists, state.scale * factor, state.level + 1, rate)

        def carry_on(_):
            return state._replace(
                buffer=particles, buffer_distances=dists, chain_position=position,
                chain_distance=chain_d, chain_step=step, moves_accepted=accepted,
                moves_proposed=proposed,
            )

        new_state = jax.lax.cond(level_done, finish, carry_on, None)
        stop = level_done & ((state.threshold <= final_threshold) | (rate < acceptance_floor))
        return new_state, _info(new_state, level_done, stop, state.threshold, rate)

    def posterior(state):
        return state.particles, jnp.zeros((n,), state.particles.dtype)

    settings = {
        "num_particles": n,
        "p0": p0,
        "chain_length": chain_length,
        "num_chains": num_chains,
        "final_threshold": final_threshold,
        "acceptance_floor": acceptance_floor,
        "initial_scale": initial_scale,
    }
    def finalize(state):
        level = int(state.level)
        return {"log_evidence": log_evidence(level, p0), "level": level}

    return ABCAlgorithm("abcsubsim", initial_proposal, init, propose, update, posterior, settings,
                        stop_reason=_stop_reason, finalize=finalize,
                        needs_stopping_rule=not (final_threshold > 0 or acceptance_floor > 0))


def _stop_reason(settings: dict, info: Info) -> str:
    return (f"final threshold {settings['final_threshold']} or acceptance floor "
            f"{settings['acceptance_floor']} reached")


def log_evidence(level: int, p0: float) -> float:
    """``log P(d < eps_level)`` estimated by ABCsubsim: ``level * log(P0)``."""
    return level * math.log(p0)
