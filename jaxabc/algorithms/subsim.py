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
A move is accepted iff the proposal lies in the prior box, meets the level's threshold and
passes the Metropolis test on the prior ratio (always, under a uniform prior); proposals outside
the box are rejected without simulating.

The chains of a level are sequential: ``1 / P0 - 1`` rounds of ``N P0`` parallel simulations.
That is why ABCsubsim parallelises less well than APMCABC (``N - N alpha`` independent
simulations per step), which the speedup benchmark shows.

A level's ``N`` particles are not ``N`` independent draws: they are ``N P0`` chains of
``1 / P0`` states, and the chains share ancestors (the seeds of a level are states of the
previous level's chains, often repeated).  As the threshold shrinks, moves are rejected and the
population collapses onto a few points.  ``Info.ess`` is therefore :func:`population_ess_bound`
(distinct particles, independent lineages, batch means over lineages), :func:`finalize` adds
ArviZ's autocorrelation-aware estimate along the chains, and a ``UserWarning`` names the level
whose chains stopped moving; ``min_distinct_fraction`` and ``acceptance_floor`` stop the run
there instead.  The Monte Carlo standard error of the posterior mean comes from the spread
between the level-0 lineages (:func:`lineage_mcse`): a population left with three effective
lineages or fewer has collapsed, and its MCSE is ``inf``, not the spread of a few repeated
points.
"""

from __future__ import annotations

import functools
import math
import warnings
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc import kernels
from jaxabc.algorithms.base import ABCAlgorithm, Info, Proposal
from jaxabc.diagnostics import chain_ess, effective_lineages, lineage_variance
from jaxabc.diagnostics import count_distinct as count_distinct_host
from jaxabc.priors import Prior

__all__ = [
    "SubsimConfig",
    "SubsimState",
    "build",
    "chain_diagnostics",
    "count_distinct",
    "finalize",
    "init",
    "initial_proposal",
    "level_chains",
    "lineage_mcse",
    "log_evidence",
    "population_ess_bound",
    "posterior",
    "propose",
    "stop_reason",
    "update",
]


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
    ancestors : jax.Array, shape (N,), int32
        For each particle of ``particles``, the index of its level-0 (prior draw) ancestor.
    chain_ancestors : jax.Array, shape (C,), int32
        The level-0 ancestor of each chain of the level being built.
    num_distinct : jax.Array, shape (), int32
        Distinct parameter vectors in ``particles``.

    Notes
    -----
    ``particles`` and ``buffer`` are stored step-major: row ``s C + c`` is chain ``c`` after
    ``s`` moves, so ``particles.reshape(1 / P0, C, d).swapaxes(0, 1)`` gives the chains
    (see :func:`level_chains`).
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
    ancestors: jax.Array
    chain_ancestors: jax.Array
    num_distinct: jax.Array


class SubsimConfig(NamedTuple):
    """ABCsubsim's configuration, fixed by :func:`build` and bound to the pure functions.

    Attributes
    ----------
    prior : Prior
    num_particles : int
        ``N = C / P0``.
    num_chains : int
        ``C = N P0``, at least 2.
    chain_length : int
        ``1 / P0``, the seed included.
    final_threshold, acceptance_floor, min_distinct_fraction : float
        The stopping rules (see :func:`build`).
    initial_scale : float
        Starting ``lambda``.
    """

    prior: Prior
    num_particles: int
    num_chains: int
    chain_length: int
    final_threshold: float
    acceptance_floor: float
    initial_scale: float
    min_distinct_fraction: float


class _ChainMoves(NamedTuple):
    """One round of chain moves (fields as in :class:`SubsimState`); ``rate`` is the level's
    move acceptance so far."""

    buffer: jax.Array
    buffer_distances: jax.Array
    chain_position: jax.Array
    chain_distance: jax.Array
    chain_step: jax.Array
    moves_accepted: jax.Array
    moves_proposed: jax.Array
    rate: jax.Array


def build(
    prior: Prior,
    num_particles: int,
    p0: float = 0.2,
    final_threshold: float = 0.0,
    acceptance_floor: float = 0.0,
    initial_scale: float = 1.0,
    min_distinct_fraction: float = 0.0,
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
    min_distinct_fraction : float
        Stop when a level holds fewer than ``min_distinct_fraction * N`` distinct particles (the
        chains have stopped moving; the population is a few points repeated), in [0, 1].

    Returns
    -------
    ABCAlgorithm
        The functions of this module with a :class:`SubsimConfig` bound by ``functools.partial``.

    Raises
    ------
    ValueError
        For ``p0`` or ``min_distinct_fraction`` out of range, ``1 / p0`` or ``N p0`` not whole
        numbers, or fewer than 2 chains.

    Notes
    -----
    ``Info.ess`` is :func:`population_ess_bound` (jittable); :func:`finalize` adds ArviZ's
    autocorrelation-aware estimate along the chains on the host and warns when the chains of
    the last level stopped moving.
    """
    if not 0.0 <= min_distinct_fraction <= 1.0:
        raise ValueError(f"min_distinct_fraction must lie in [0, 1], got {min_distinct_fraction}")
    n = int(num_particles)
    num_chains, chain_length = _chains(n, p0)
    config = SubsimConfig(
        prior, n, num_chains, chain_length, final_threshold, acceptance_floor, initial_scale, min_distinct_fraction
    )
    settings = {
        "num_particles": n,
        "p0": p0,
        "chain_length": chain_length,
        "num_chains": num_chains,
        "final_threshold": final_threshold,
        "acceptance_floor": acceptance_floor,
        "initial_scale": initial_scale,
        "min_distinct_fraction": min_distinct_fraction,
    }
    return ABCAlgorithm(
        "abcsubsim",
        functools.partial(initial_proposal, config),
        functools.partial(init, config),
        functools.partial(propose, config),
        functools.partial(update, config),
        functools.partial(posterior, config),
        settings,
        stop_reason=stop_reason,
        finalize=functools.partial(finalize, settings=settings),
        needs_stopping_rule=not (final_threshold > 0 or acceptance_floor > 0),
    )


def _chains(n: int, p0: float) -> tuple[int, int]:
    """``(N P0, 1 / P0)``, the number and length of the chains; ``ValueError`` unless both are
    whole numbers, ``p0`` lies in (0, 0.5] and there are at least 2 chains."""
    if not 0.0 < p0 <= 0.5:
        raise ValueError(f"p0 must lie in (0, 0.5], got {p0}; Chiachio et al. use 0.1-0.2")
    chain_length = round(1.0 / p0)
    num_chains = round(n * p0)
    if not math.isclose(chain_length * p0, 1.0, rel_tol=1e-9) or num_chains * chain_length != n:
        raise ValueError(
            f"ABCsubsim needs 1/p0 and num_particles*p0 to be whole numbers: p0={p0}, "
            f"num_particles={n}; e.g. p0=0.2 with num_particles a multiple of 5"
        )
    if num_chains < 2:
        raise ValueError(f"num_particles*p0 = {num_chains} chains: need at least 2")
    return num_chains, chain_length


def initial_proposal(config: SubsimConfig, key: jax.Array) -> Proposal:
    """``N`` prior draws, all active."""
    n = config.num_particles
    return Proposal(config.prior.sample(key, n), jnp.ones((n,), bool), jnp.bool_(True))


def init(config: SubsimConfig, key: jax.Array, proposal: Proposal, distances: jax.Array) -> tuple[SubsimState, Info]:
    """Level 0 (the prior draws, distances (N,), at tolerance ``+inf``) and level 1's seeds."""
    del key
    thetas = jnp.asarray(proposal.thetas)
    dtype = thetas.dtype
    state = _new_level(
        config,
        thetas,
        distances,
        jnp.arange(config.num_particles, dtype=jnp.int32),
        jnp.asarray(config.initial_scale, dtype),
        jnp.int32(0),
        jnp.asarray(1.0, dtype),
    )
    # Level 0's population is the prior sample, at tolerance +inf.
    return state, _info(state, jnp.bool_(True), jnp.bool_(False), jnp.asarray(jnp.inf, dtype), jnp.asarray(1.0, dtype))


def propose(config: SubsimConfig, key: jax.Array, state: SubsimState) -> Proposal:
    """One Gaussian random-walk move per chain, shape (C, d); moves outside the prior's box are
    inactive (rejected without a simulation)."""
    z = jax.random.normal(key, state.chain_position.shape, state.chain_position.dtype)
    proposal = state.chain_position + jnp.sqrt(state.scale) * z @ state.chol.T
    inside = config.prior.contains(proposal)
    return Proposal(proposal, inside, jnp.bool_(True))


def update(
    config: SubsimConfig, key: jax.Array, state: SubsimState, proposal: Proposal, distances: jax.Array
) -> tuple[SubsimState, Info]:
    """Accept or reject each chain's move (distances (C,)); start the next level after the
    last chain step.  ``Info.stop`` fires at a completed level when a stopping rule holds."""
    num_chains, prior = config.num_chains, config.prior
    thetas = jnp.asarray(proposal.thetas)
    # Metropolis within the level: the prior ratio (one inside the box for a uniform prior,
    # so then every proposal meeting the threshold is accepted) and the threshold.
    log_ratio = prior.log_prob(thetas) - prior.log_prob(state.chain_position)
    log_u = jnp.log(jax.random.uniform(key, (num_chains,), state.chain_position.dtype))
    accept = proposal.active & (distances < state.threshold) & (log_u < log_ratio)
    position = jnp.where(accept[:, None], thetas, state.chain_position)
    chain_d = jnp.where(accept, distances, state.chain_distance)
    start = state.chain_step * num_chains
    particles = jax.lax.dynamic_update_slice(state.buffer, position, (start, jnp.int32(0)))
    dists = jax.lax.dynamic_update_slice(state.buffer_distances, chain_d, (start,))
    accepted = state.moves_accepted + jnp.sum(accept, dtype=jnp.int32)
    proposed = state.moves_proposed + num_chains
    step = state.chain_step + 1
    level_done = step == config.chain_length
    rate = accepted / jnp.maximum(proposed, 1)
    rate = rate.astype(particles.dtype)
    moves = _ChainMoves(particles, dists, position, chain_d, step, accepted, proposed, rate)
    new_state = jax.lax.cond(level_done, functools.partial(_complete_level, config), _continue_level, state, moves)
    stop = level_done & (
        (state.threshold <= config.final_threshold)
        | (rate < config.acceptance_floor)
        | (new_state.num_distinct < config.min_distinct_fraction * config.num_particles)
    )
    return new_state, _info(new_state, level_done, stop, state.threshold, rate)


def posterior(config: SubsimConfig, state: SubsimState) -> tuple[jax.Array, jax.Array]:
    """The last completed level, with equal weights; shapes (N, d) and (N,)."""
    return state.particles, jnp.zeros((config.num_particles,), state.particles.dtype)


def _complete_level(config: SubsimConfig, state: SubsimState, moves: _ChainMoves) -> SubsimState:
    """Adapt ``lambda`` and start the next level from the completed one (a ``lax.cond`` branch)."""
    rate = moves.rate
    out_of_band = (rate < 0.2) | (rate > 0.5)
    factor = jnp.where(out_of_band, jnp.clip(rate / 0.35, 0.5, 2.0), 1.0)
    # The level's population (all below state.threshold) is the posterior at that
    # tolerance; the next level's seeds and threshold come from it.
    ancestors = jnp.tile(state.chain_ancestors, config.chain_length)
    return _new_level(
        config, moves.buffer, moves.buffer_distances, ancestors, state.scale * factor, state.level + 1, rate
    )


def _continue_level(state: SubsimState, moves: _ChainMoves) -> SubsimState:
    """The level with this round's chain states recorded (a ``lax.cond`` branch)."""
    return state._replace(
        buffer=moves.buffer,
        buffer_distances=moves.buffer_distances,
        chain_position=moves.chain_position,
        chain_distance=moves.chain_distance,
        chain_step=moves.chain_step,
        moves_accepted=moves.moves_accepted,
        moves_proposed=moves.moves_proposed,
    )


def _new_level(
    config: SubsimConfig,
    particles: jax.Array,
    distances: jax.Array,
    ancestors: jax.Array,
    scale: jax.Array,
    level: jax.Array,
    level_acceptance: jax.Array,
) -> SubsimState:
    """The state of a completed level (N particles): its ``C`` best particles seed the chains,
    and the next threshold lies halfway between the ``C``-th and the next smallest distance."""
    num_chains = config.num_chains
    order = jnp.argsort(distances, stable=True)
    sorted_d = distances[order]
    threshold = 0.5 * (sorted_d[num_chains - 1] + sorted_d[num_chains])
    # With ties the midpoint equals both; keep the seeds' own largest distance then, so the
    # seeds are inside their level.
    threshold = jnp.where(sorted_d[num_chains] > sorted_d[num_chains - 1], threshold, sorted_d[num_chains - 1])
    seeds = particles[order[:num_chains]]
    seed_d = sorted_d[:num_chains]
    cov = kernels.weighted_covariance(seeds, jnp.zeros((num_chains,), seeds.dtype))
    chol = jnp.linalg.cholesky(kernels.regularize_covariance(cov, config.prior.low, config.prior.high))
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
        ancestors=ancestors,
        chain_ancestors=ancestors[order[:num_chains]],
        num_distinct=count_distinct(particles),
    )


def _info(state: SubsimState, done: jax.Array, stop: jax.Array, threshold: jax.Array, acceptance: jax.Array) -> Info:
    """An ``Info`` whose ESS is :func:`population_ess_bound` of ``state``."""
    return Info(done, stop, threshold, acceptance, population_ess_bound(state))


def count_distinct(x: jax.Array) -> jax.Array:
    """Number of distinct rows of ``x`` (shape (n, d) or (n,)), jittable; shape (), int32."""
    x = x.reshape(x.shape[0], -1)
    order = jnp.lexsort(tuple(x[:, j] for j in reversed(range(x.shape[1]))))
    xs = x[order]
    return (1 + jnp.sum(jnp.any(xs[1:] != xs[:-1], axis=1))).astype(jnp.int32)


def population_ess_bound(state: SubsimState) -> jax.Array:
    """A jittable bound on the effective sample size of ``state.particles``; shape ().

    The chains of a level share ancestors (seeds are repeated and descend from earlier chains),
    so their particles are correlated across chains as well as along them.  The bound is the
    smallest of the number of distinct particles, the number of distinct level-0 ancestors
    (independent lineages) and, per parameter, a batch-means estimate over lineages
    (``var / Var(mean)`` with the variance of the mean from the lineages' sums, a cluster-robust
    estimate).  With one lineage it is 1.  The host adds an autocorrelation-aware estimate along
    the chains (:func:`jaxabc.diagnostics.chain_ess`).
    """
    x = state.particles.reshape(state.particles.shape[0], -1)
    n = x.shape[0]
    dtype = x.dtype
    lineages = count_distinct(state.ancestors)
    sums = jax.ops.segment_sum(x, state.ancestors, num_segments=n)
    counts = jax.ops.segment_sum(jnp.ones((n,), dtype), state.ancestors, num_segments=n)
    mean = jnp.mean(x, axis=0)
    k = lineages.astype(dtype)
    var_of_mean = jnp.sum((sums - counts[:, None] * mean) ** 2, axis=0) / n**2 * k / jnp.maximum(k - 1.0, 1.0)
    var = jnp.var(x, axis=0, ddof=1)
    # A parameter that does not vary across lineages (or at all) carries no bound of its own.
    per_param = jnp.where(var_of_mean > 0, var / jnp.where(var_of_mean > 0, var_of_mean, 1.0), jnp.inf)
    bound = jnp.minimum(jnp.minimum(state.num_distinct, lineages).astype(dtype), jnp.min(per_param))
    return jnp.maximum(bound, 1.0)


def log_evidence(level: int, p0: float) -> float:
    """``log P(d < eps_level)`` estimated by ABCsubsim: ``level * log(P0)``."""
    return level * math.log(p0)


def level_chains(particles: Any, num_chains: int) -> np.ndarray:
    """A level's population as its chains, shape (num_chains, 1 / P0, d).

    ``particles`` (shape (N, d), as in :class:`SubsimState` and in the result) is step-major:
    row ``s C + c`` is chain ``c`` after ``s`` moves.
    """
    x = np.asarray(particles)
    if x.ndim != 2 or x.shape[0] % num_chains:
        raise ValueError(f"particles of shape {x.shape} are not {num_chains} chains of equal length")
    return x.reshape(x.shape[0] // num_chains, num_chains, x.shape[1]).swapaxes(0, 1)


def chain_diagnostics(
    particles: Any,
    settings: dict,
    level: int,
    level_acceptance: float,
    ess_bound: float | None = None,
    ancestors: Any = None,
) -> dict:
    """Host diagnostics of a completed level's population, with a warning when stuck.

    Parameters
    ----------
    particles : array_like, shape (N, d)
        The level's population in state order (see :func:`level_chains`).
    settings : dict
        The algorithm's settings (``num_chains``, ``chain_length``, ``acceptance_floor``).
    level : int
        ``j``; level 0 is the prior sample (independent draws).
    level_acceptance : float
        The level's chain-move acceptance rate.
    ess_bound : float, optional
        :func:`population_ess_bound` of the state, when the state is at hand.
    ancestors : array_like, shape (N,), optional
        Each particle's level-0 ancestor (``SubsimState.ancestors``); without it (a result
        file) the distinct particles stand in for the lineages.

    Returns
    -------
    dict
        ``ess`` (the smaller of :func:`jaxabc.diagnostics.chain_ess` and ``ess_bound``),
        ``chain_ess``, ``ess_bound``, ``num_distinct``, ``level``, ``level_acceptance``,
        ``chains_stuck`` (fewer distinct particles than chains, or acceptance below the floor),
        ``mcse`` and the fields of :func:`lineage_mcse`, and ``warning`` (the message, empty
        when neither stuck nor collapsed).
    """
    x = np.asarray(particles, np.float64)
    n, num_chains = x.shape[0], int(settings["num_chains"])
    distinct = count_distinct_host(x)
    # Level 0 is the prior sample: independent draws, not chains.
    ess = float(distinct) if level == 0 else chain_ess(level_chains(x, num_chains))
    chain_value = ess
    if ess_bound is not None:
        ess = min(ess, float(ess_bound))
    floor = float(settings.get("acceptance_floor", 0.0))
    stuck = level > 0 and (distinct < num_chains or level_acceptance < floor)
    errors = lineage_mcse(x, ess, distinct, ancestors)
    message = ""
    if stuck:
        message = (
            f"ABCsubsim level {level}: the chains have stopped moving (move acceptance "
            f"{level_acceptance:.3g}, {distinct} distinct particles of {n} for {num_chains} "
            f"chains); the effective sample size is {ess:.1f}, not {n}. Stop earlier "
            "(num_steps, final_threshold) or set acceptance_floor / min_distinct_fraction"
        )
    if errors["collapsed"]:
        note = f"ABCsubsim level {level}: {errors['mcse_note']}"
        message = f"{message}; {errors['mcse_note']}" if message else note
    return {
        "ess": ess,
        "chain_ess": chain_value,
        "ess_bound": None if ess_bound is None else float(ess_bound),
        "num_distinct": distinct,
        "level": int(level),
        "level_acceptance": float(level_acceptance),
        "chains_stuck": bool(stuck),
        **errors,
        "warning": message,
    }


# Below this many effective lineages the spread between them says next to nothing about the
# error (a t distribution with <= 2 degrees of freedom has no variance): no MCSE is reported.
MIN_EFFECTIVE_LINEAGES = 3.0


def lineage_mcse(particles: Any, ess: float, num_distinct: int, ancestors: Any = None) -> dict:
    """Monte Carlo standard error of an ABCsubsim population's mean, from its lineages.

    The particles descend from few level-0 draws and the chains barely move once the threshold
    is small, so the spread of the population underestimates the posterior's and ``var / ESS``
    the error.  The variance of the mean is the larger of ``var / ESS`` and
    :func:`jaxabc.diagnostics.lineage_variance` over the level-0 lineages, times
    ``nu / (nu - 2)`` with ``nu = K - 1`` for ``K`` effective lineages (the variance of a t
    distribution: the lineage spread is itself estimated from ``K`` values).  With
    ``K <= 3``, or a single distinct particle, the population has collapsed: the MCSE is
    ``inf``.

    Parameters
    ----------
    particles : array_like, shape (N, d)
    ess : float
        The population's effective sample size (:func:`chain_diagnostics`).
    num_distinct : int
    ancestors : array_like, shape (N,), optional
        Level-0 ancestors; without them ``K`` is bounded by the distinct particles only.

    Returns
    -------
    dict
        ``mcse`` (list of d floats, ``inf`` when collapsed), ``num_lineages`` and
        ``effective_lineages`` (None without ancestors), ``collapsed`` (bool) and
        ``mcse_note`` (why no MCSE, empty when there is one).
    """
    x = np.asarray(particles, np.float64)
    x = x.reshape(x.shape[0], -1)
    n = x.shape[0]
    weights = np.full(n, 1.0 / n)
    var = x.var(axis=0, ddof=1) if n > 1 else np.zeros(x.shape[1])
    variance = var / max(float(ess), 1.0)
    num_lineages: int | None = None
    effective: float | None = None
    if ancestors is not None:
        lineage = np.asarray(ancestors).reshape(-1)
        num_lineages, effective = effective_lineages(weights, lineage)
        variance = np.maximum(variance, lineage_variance(x, weights, lineage))
    # Without ancestors the distinct particles bound the lineages from above.
    bound = float(num_distinct) if effective is None else min(effective, float(num_distinct))
    collapsed = num_distinct <= 1 or bound <= MIN_EFFECTIVE_LINEAGES
    note = ""
    if collapsed:
        lineages = "" if num_lineages is None else f" from {num_lineages} lineage{'s' * (num_lineages != 1)}"
        effective_text = "" if effective is None else f" ({effective:.1f} effective)"
        note = (
            f"collapsed: {num_distinct} distinct particle{'s' * (num_distinct != 1)}{lineages}{effective_text}; "
            "MCSE not available (the population is a few draws repeated: run more particles "
            "or stop at an earlier level)"
        )
        mcse = np.full(x.shape[1], np.inf)
    else:
        dof = bound - 1.0
        mcse = np.sqrt(variance * dof / (dof - 2.0))
    return {
        "mcse": [float(v) for v in mcse],
        "num_lineages": num_lineages,
        "effective_lineages": effective,
        "collapsed": bool(collapsed),
        "mcse_note": note,
    }


def finalize(state: SubsimState, settings: dict) -> dict:
    """Result extras of a run that ended in ``state``: ESS, level, evidence, diagnostics.

    Warns (``UserWarning``) when the last level's chains stopped moving.

    Returns
    -------
    dict
        ``{"ess": float, "level": int, "log_evidence": float, "diagnostics": dict}`` with the
        diagnostics of :func:`chain_diagnostics`.
    """
    level = int(state.level)
    diagnostics = chain_diagnostics(
        state.particles,
        settings,
        level,
        float(state.level_acceptance),
        float(population_ess_bound(state)),
        ancestors=np.asarray(state.ancestors),
    )
    if diagnostics["warning"]:
        warnings.warn(diagnostics["warning"], UserWarning, stacklevel=2)
    return {
        "ess": diagnostics["ess"],
        "level": level,
        "log_evidence": log_evidence(level, settings["p0"]),
        "diagnostics": diagnostics,
    }


def stop_reason(settings: dict, info: Info) -> str:
    """Which of ABCsubsim's own stopping rules fired, for a level whose ``info.stop`` is set."""
    threshold, rate = float(info.threshold), float(info.acceptance_rate)
    if threshold <= settings["final_threshold"]:
        return f"final threshold {settings['final_threshold']} reached ({threshold:.4g})"
    if rate < settings["acceptance_floor"]:
        return f"chains stopped moving: move acceptance {rate:.3g} < acceptance floor {settings['acceptance_floor']}"
    return (
        f"chains stopped moving: fewer than {settings['min_distinct_fraction']} x "
        f"{settings['num_particles']} distinct particles (ESS bound {float(info.ess):.1f})"
    )
