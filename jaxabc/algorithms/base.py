"""The shape shared by every ABC algorithm: pure ``init`` / ``propose`` / ``update`` functions.

Simulators may be external programs, so simulation cannot happen inside a jitted step.  An
algorithm therefore splits a step at the simulator boundary:

``propose(key, state) -> Proposal``
    where to simulate next (parameters plus a mask of which slots need a simulation);
``update(key, state, proposal, distances) -> (State, Info)``
    what to keep, given the distances of the proposed particles.

The host driver (:mod:`jaxabc.run`) calls ``propose``, sends the active parameters to an
executor, computes distances and calls ``update``.  For a pure-JAX simulator
:func:`make_jax_step` fuses the three into one jittable ``step(key, state)``, blackjax-style.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple, Protocol

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "ABCAlgorithm",
    "Info",
    "Proposal",
    "StepInfo",
    "default_stop_reason",
    "make_jax_step",
    "masked_percentile",
    "no_extras",
]


# What a field holds: jax arrays from jitted algorithms, NumPy arrays or scalars from host ones
# (``ABCAlgorithm.host``).
HostArray = jax.Array | np.ndarray | np.bool_ | np.number


class Proposal(NamedTuple):
    """Parameters to simulate.

    Attributes
    ----------
    thetas : jax.Array, shape (m, d)
        Proposed parameter vectors.
    active : jax.Array, shape (m,)
        Which slots need a simulation; inactive slots get distance ``+inf`` and cost nothing.
    ok : jax.Array, shape ()
        False when the truncated perturbation kernel could not reach the prior's support
        (see :func:`jaxabc.kernels.truncated_gaussian_sample`); the driver raises.
    """

    thetas: jax.Array | np.ndarray
    active: jax.Array | np.ndarray
    ok: HostArray


class Info(NamedTuple):
    """Diagnostics of one ``init`` or ``update`` call (all shape ()).

    Attributes
    ----------
    generation_done : jax.Array
        True when a generation (an ABC step, a subset-simulation level) was completed by this
        call; multi-round algorithms (PMC refills, subset-simulation chain moves) return False
        in between.
    stop : jax.Array
        The algorithm's own stopping rule fired (e.g. APMCABC's acceptance cutoff).
    threshold : jax.Array
        The tolerance of the current population.
    acceptance_rate : jax.Array
        Fraction of this call's simulations that met the previous threshold (APMCABC), were
        accepted (PMC, rejection), or chain-move acceptance over the level (ABCsubsim).
    ess : jax.Array
        Effective sample size of the current posterior population.
    """

    generation_done: HostArray
    stop: HostArray
    threshold: HostArray
    acceptance_rate: HostArray
    ess: HostArray


class StepInfo(Protocol):
    """What the driver reads from the info of an ``init`` or ``update`` call: :class:`Info`, or
    an algorithm's own NamedTuple with these attributes (e.g.
    :class:`jaxabc.surrogate.SurrogateInfo`, whose own fields say what they hold).  The driver
    records ``threshold``, ``acceptance_rate`` and ``ess`` in the result's history."""

    @property
    def generation_done(self) -> HostArray: ...

    @property
    def stop(self) -> HostArray: ...

    @property
    def threshold(self) -> HostArray: ...

    @property
    def acceptance_rate(self) -> HostArray: ...

    @property
    def ess(self) -> HostArray: ...


def default_stop_reason(settings: dict, info: Info) -> str:
    """The stop reason of an algorithm that does not say why its own rule fired."""
    del settings, info
    return "the algorithm's stopping rule fired"


def no_extras(state: Any) -> dict:
    """The result extras of an algorithm that has none."""
    del state
    return {}


class ABCAlgorithm(NamedTuple):
    """An ABC algorithm as pure functions, and what the driver needs to know about it.

    The driver (:func:`jaxabc.run`) never branches on ``name``: everything algorithm-specific
    comes from these fields.  States are (nested) NamedTuples of arrays, so checkpoints can store
    them as arrays keyed by ``jax.tree_util.keystr`` paths.

    Attributes
    ----------
    name : str
    initial_proposal : callable ``(key) -> Proposal``
        The first batch (prior draws).
    init : callable ``(key, proposal, distances[, summaries]) -> (state, info)``
        ``info`` an :class:`Info`, or any :class:`StepInfo`.
    propose : callable ``(key, state) -> Proposal``
    update : callable ``(key, state, proposal, distances[, summaries]) -> (state, info)``
    posterior : callable ``(state) -> (particles (n, d), log_weights (n,))``
        The current posterior sample; zero-weight slots have log weight ``-inf``.
    settings : dict
        The configuration bound in the closures, JSON-serialisable, for result files and
        checkpoint fingerprints.
    stop_reason : callable ``(settings, info) -> str``
        Why the run ended, called when ``info.stop`` fires, with that call's info.
    finalize : callable ``(state) -> dict``
        Result extras of the final state, e.g. ``{"log_evidence": float}``; the key
        ``"log_evidence"`` fills :attr:`ABCResult.log_evidence`, ``"diagnostics"`` its
        diagnostics, ``"stop_reason_prefix"`` goes in front of its stop reason (a verdict the
        final state holds, e.g. a misfit), others go to its metadata.
    needs_stopping_rule : bool
        The algorithm may never stop by itself; the driver refuses a run without ``num_steps``,
        ``final_threshold``, ``max_simulations`` or ``max_wall_time``.
    host : bool
        The functions are host (NumPy) code; the driver does not ``jax.jit`` them.
    uses_summaries : bool
        ``init`` / ``update`` also receive ``summaries``, a float64 array
        ``(m, *summary_shape)`` with NaN rows for failed or inactive slots.
    restore_state : callable ``(flat) -> state``, optional
        Rebuilds a host algorithm's state from ``{keystr path: numpy array}``; without it the
        driver rebuilds the state from ``jax.eval_shape`` of ``init``.
    """

    name: str
    initial_proposal: Callable[[jax.Array], Proposal]
    init: Callable[..., tuple[Any, StepInfo]]
    propose: Callable[[jax.Array, Any], Proposal]
    update: Callable[..., tuple[Any, StepInfo]]
    posterior: Callable[[Any], tuple[HostArray, HostArray]]
    settings: dict
    stop_reason: Callable[[dict, Any], str] = default_stop_reason
    finalize: Callable[[Any], dict] = no_extras
    needs_stopping_rule: bool = False
    host: bool = False
    uses_summaries: bool = False
    restore_state: Callable[[dict], Any] | None = None


def masked_percentile(x: jax.Array, valid: jax.Array, q: float) -> jax.Array:
    """``numpy.percentile(x[valid], 100 q)`` with linear interpolation, for a fixed-size array."""
    xs = jnp.sort(jnp.where(valid, x, jnp.inf))
    n = jnp.sum(valid)
    pos = q * (n - 1).astype(x.dtype)
    lo = jnp.floor(pos).astype(jnp.int32)
    hi = jnp.minimum(lo + 1, n - 1)
    frac = pos - lo
    return jnp.where(frac > 0, xs[lo] + frac * (xs[hi] - xs[lo]), xs[lo])


def make_jax_step(
    algorithm: ABCAlgorithm,
    simulate: Callable[[jax.Array, jax.Array], jax.Array],
    distance: Callable[[jax.Array, jax.Array], jax.Array],
    observed: jax.Array,
) -> tuple[Callable, Callable]:
    """Fuse propose, a vmapped JAX simulator and update into jittable ``init`` and ``step``.

    Returns
    -------
    init : callable ``(key) -> (state, Info)``
    step : callable ``(key, state) -> (state, Info)``

    Notes
    -----
    Non-finite summaries give distance ``+inf``.  Every slot is simulated, active or not (a
    vmapped batch has a fixed shape); inactive slots are masked out afterwards.  Use the host
    driver :func:`jaxabc.run` for failure records, checkpoints and external simulators.
    """

    def distances_of(key: jax.Array, proposal: Proposal) -> jax.Array:
        thetas = jnp.asarray(proposal.thetas)  # a no-op under jit
        keys = jax.random.split(key, thetas.shape[0])
        summaries = jax.vmap(simulate)(keys, thetas)
        dist = jax.vmap(distance, in_axes=(None, 0))(observed, summaries)
        finite = jnp.all(jnp.isfinite(summaries.reshape(summaries.shape[0], -1)), axis=1)
        dist = jnp.where(finite & jnp.isfinite(dist), dist, jnp.inf)
        return jnp.where(proposal.active, dist, jnp.inf)

    def init(key: jax.Array):
        k1, k2, k3 = jax.random.split(key, 3)
        proposal = algorithm.initial_proposal(k1)
        return algorithm.init(k3, proposal, distances_of(k2, proposal))

    def step(key: jax.Array, state):
        k1, k2, k3 = jax.random.split(key, 3)
        proposal = algorithm.propose(k1, state)
        return algorithm.update(k3, state, proposal, distances_of(k2, proposal))

    return init, step
