"""The surrogate's ABC mode: the project's APMCABC, vmapped in-process, on emulated summaries.

A draw of the emulated simulator at ``theta`` is what a real run there would give if the emulator
were the truth, with its own ignorance added:

``z = mu(x) + sqrt(var(x)) * e1 + D L e2``,  ``y = mean + scale * (z @ pinv(R))``

with ``x`` the unit-box coordinates of ``theta``, ``mu`` and ``var`` the emulator's latent mean
and variance, ``D`` the fitted noise sds (nuggets), ``L`` the Cholesky factor of the noise
correlation, ``e1, e2 ~ N(0, I)`` independent per call, and ``(mean, scale, R)`` the
:class:`~jaxabc.surrogate.emulator.OutputTransform` undone, so that the user's distance compares
summaries in their own units.  A draw fails (NaN, distance ``+inf``) with probability
``1 - p_feasible(x)``, as a real run would.  With more summaries than emulated outputs (PCA),
the observed vector is projected onto the same principal subspace before the comparison.

Measured data add their error to every draw, in summary units before the transform: the
measurement error ``F e3`` (``F F^T = M``, the builder's ``observation_error``) and, with a
model discrepancy, ``sqrt(delta^2 @ membership) * e4``, ``delta`` the group sds that then
extend ``theta`` (and APMCABC's prior box, by ``[0, max_sd]``).

APMCABC (:mod:`jaxabc.algorithms.apmc`) then runs on this simulator through
:func:`jaxabc.algorithms.make_jax_step`: every generation is one jitted call, the emulator and
the observed data are traced arguments (a refitted emulator or new data never recompile), and
the compiled functions are cached per (prior box, population, alpha, cutoff, distance).

Its posterior is that of ABC at the final threshold ``eps``: wider than the synthetic
likelihood's by the tolerance (for the Euclidean distance on ``k`` summaries, about an extra
``eps^2 / (k + 2)`` of variance per summary, the variance of a uniform ball of radius ``eps``).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.algorithms import apmc
from jaxabc.algorithms.base import make_jax_step
from jaxabc.distances import get_distance
from jaxabc.priors import Uniform
from jaxabc.surrogate.emulator import Emulator, OutputTransform, predict
from jaxabc.surrogate.emulator import noise_sd as emulator_noise_sd
from jaxabc.surrogate.sampling import Feasibility, feasibility, log_feasibility, log_level, nearest_runs_cut

#: Tags of the keys of the measurement and discrepancy errors, folded from a draw's key.
_MEASUREMENT_TAG = 0x6D656173  # "meas"
_DISCREPANCY_TAG = 0x64697363  # "disc"

__all__ = ["ABCPosterior", "EmulatedSimulator", "emulated_simulator", "emulated_summaries", "run_abc"]


class EmulatedSimulator(NamedTuple):
    """Everything an emulated simulation needs (a pytree of arrays).

    Attributes
    ----------
    emulator : Emulator
    noise_chol : array, shape (q, q)
        Cholesky factor of the simulator noise correlation in emulated-output coordinates.
    feasible : Feasibility
    summary_mean, summary_scale : array, shape (k,)
        The output transform's centring and scaling (raw summary units).
    back_rotation : array, shape (q, k)
        Pseudo-inverse of the transform's rotation (identity without PCA).
    low, high : array, shape (d,)
        The prior box.
    log_min_feasibility : float or array, shape ()
        Where ``log p_feasible`` is below this, every emulated run fails (the posterior's
        constraint, see :mod:`.sampling`).
    rotation : array, shape (k, q), optional
        The transform's rotation (to map raw-unit errors into emulated outputs).
    observation_factor : array, shape (k, k), optional
        ``F`` with ``F F^T = M``, the measurement covariance (summary units): each draw adds
        ``F e3``, ``e3 ~ N(0, I)``.
    membership : array, shape (G, k), optional
        Discrepancy groups; ``theta`` then has ``d + G`` entries, the last ``G`` the group sds
        (``low``, ``high`` the augmented box), and each draw adds ``sqrt(delta^2 @ membership)
        * e4``.
    """

    emulator: Emulator
    noise_chol: jax.Array
    feasible: Feasibility
    summary_mean: jax.Array
    summary_scale: jax.Array
    back_rotation: jax.Array
    low: jax.Array
    high: jax.Array
    log_min_feasibility: jax.Array | float = float("-inf")
    rotation: jax.Array | None = None
    observation_factor: jax.Array | None = None
    membership: jax.Array | None = None


class ABCPosterior(NamedTuple):
    """Outcome of :func:`run_abc`.

    Attributes
    ----------
    particles : numpy.ndarray, shape (P, d)
        The kept APMCABC population, in the prior's units.
    log_weights : numpy.ndarray, shape (P,)
        Its unnormalised log importance weights (all finite).
    threshold : float
        The final ABC tolerance, in the distance's units.
    generations : int
    num_emulated : int
        Emulated simulations (cheap draws, no real runs).
    stopped : bool
        APMCABC's acceptance cutoff fired (False: ``max_generations`` ended the run).
    """

    particles: np.ndarray
    log_weights: np.ndarray
    threshold: float
    generations: int
    num_emulated: int
    stopped: bool


def emulated_simulator(
    emulator: Emulator,
    transform: OutputTransform,
    noise_chol: jax.Array,
    feasible: Feasibility,
    low: np.ndarray,
    high: np.ndarray,
    min_feasibility: float = 0.0,
    observation_error: np.ndarray | None = None,
    discrepancy: Any = None,
) -> EmulatedSimulator:
    """Bundle a fitted emulator and its output transform into an :class:`EmulatedSimulator`.

    ``observation_error`` (k, k): the measurement covariance in summary units, drawn into every
    emulated simulation.  ``discrepancy`` (a :class:`jaxabc.noise.ResolvedDiscrepancy`): its group
    sds join ``theta`` (the box ``low``, ``high`` is extended by ``[0, max_sd]``) and draw a
    discrepancy error of their size.
    """
    back = jnp.linalg.pinv(transform.rotation)
    low, high = np.asarray(low, np.float64), np.asarray(high, np.float64)
    factor = membership = None
    if observation_error is not None:
        # A square root that allows a singular covariance (sd 0 where the data state none).
        vals, vecs = np.linalg.eigh(np.asarray(observation_error, np.float64))
        factor = jnp.asarray(vecs * np.sqrt(np.maximum(vals, 0.0)))
    if discrepancy is not None:
        membership = jnp.asarray(np.asarray(discrepancy.membership, np.float64))
        low = np.concatenate([low, np.zeros(len(discrepancy.max_sd))])
        high = np.concatenate([high, np.asarray(discrepancy.max_sd, np.float64)])
    return EmulatedSimulator(
        emulator,
        jnp.asarray(noise_chol),
        feasible,
        transform.mean,
        transform.scale,
        back,
        jnp.asarray(low),
        jnp.asarray(high),
        log_level(min_feasibility),
        transform.rotation if (factor is not None or membership is not None) else None,
        factor,
        membership,
    )


def emulated_summaries(model: EmulatedSimulator, key: jax.Array, theta: jax.Array) -> jax.Array:
    """One emulated simulation at ``theta (d,)`` (prior units; ``(d + G,)`` with a discrepancy):
    summaries ``(k,)``, NaN when the draw lands in the fitted failure region.  A pure-JAX
    ``simulate(key, theta)`` once ``model`` is bound.

    Measurement and discrepancy errors are drawn in summary units and mapped into emulated
    outputs like the summaries (``z = T y + c``): with a projection their part along the dropped
    principal directions is dropped too, as the observed data's is (:func:`project_observed`)."""
    d = model.emulator.x.shape[1]
    x = ((theta - model.low) / (model.high - model.low))[:d]
    mean, var = predict(model.emulator, x[None, :])
    k_latent, k_noise, k_fail = jax.random.split(key, 3)
    q = mean.shape[1]
    noise_sd = emulator_noise_sd(model.emulator, x[None, :])[0]
    z = (
        mean[0]
        + jnp.sqrt(var[0]) * jax.random.normal(k_latent, (q,), mean.dtype)
        + noise_sd * (model.noise_chol @ jax.random.normal(k_noise, (q,), mean.dtype))
    )
    if model.rotation is not None:
        k = model.summary_mean.shape[0]
        # Keys folded from the draw's key: without these terms the stream is unchanged.
        error = jnp.zeros(k, mean.dtype)
        if model.observation_factor is not None:
            e3 = jax.random.normal(jax.random.fold_in(key, _MEASUREMENT_TAG), (k,), mean.dtype)
            error = error + model.observation_factor @ e3
        if model.membership is not None:
            e4 = jax.random.normal(jax.random.fold_in(key, _DISCREPANCY_TAG), (k,), mean.dtype)
            error = error + jnp.sqrt(theta[d:] ** 2 @ model.membership) * e4
        z = z + (error / model.summary_scale) @ model.rotation
    y = model.summary_mean + model.summary_scale * (z @ model.back_rotation)
    ok = jax.random.uniform(k_fail, (), mean.dtype) < feasibility(model.feasible, x[None, :])[0]
    # The cuts of the synthetic likelihood (sampling.log_feasibility_term), as hard failures.
    ok = ok & (log_feasibility(model.feasible, x[None, :])[0] >= model.log_min_feasibility)
    ok = ok & ~nearest_runs_cut(model.feasible, x[None, :])[0]
    return jnp.where(ok, y, jnp.nan)


def project_observed(model: EmulatedSimulator, transform: OutputTransform, observed: np.ndarray) -> jax.Array:
    """The observed summaries as the emulated simulator sees them: unchanged without PCA, else
    their projection onto the emulated principal subspace."""
    z = transform.apply(jnp.asarray(observed, jnp.float64).reshape(-1))
    return model.summary_mean + model.summary_scale * (z @ model.back_rotation)


@functools.lru_cache(maxsize=8)
def _compiled(
    low: tuple[float, ...],
    high: tuple[float, ...],
    population: int,
    alpha: float,
    acceptance_cutoff: float,
    distance: Callable,
) -> tuple[Any, Callable, Callable]:
    """APMCABC and its jitted init/step on a traced emulated simulator (cached: compiling them
    costs seconds, a coverage study builds hundreds of surrogate runs)."""
    algorithm = apmc.build(Uniform(low, high), population, alpha, acceptance_cutoff)

    @jax.jit
    def init(key: jax.Array, model: EmulatedSimulator, observed: jax.Array):
        fused_init, _ = make_jax_step(algorithm, functools.partial(emulated_summaries, model), distance, observed)
        return fused_init(key)

    @jax.jit
    def step(key: jax.Array, state: Any, model: EmulatedSimulator, observed: jax.Array):
        _, fused_step = make_jax_step(algorithm, functools.partial(emulated_summaries, model), distance, observed)
        return fused_step(key, state)

    return algorithm, init, step


def run_abc(
    key: jax.Array,
    model: EmulatedSimulator,
    observed: jax.Array,
    *,
    num_particles: int,
    alpha: float,
    acceptance_cutoff: float,
    distance: str | Callable,
    max_generations: int,
) -> ABCPosterior:
    """APMCABC on the emulated simulator until its acceptance cutoff or ``max_generations``.

    Parameters
    ----------
    key : jax.Array
    model : EmulatedSimulator
    observed : array, shape (k,)
        From :func:`project_observed`.
    num_particles : int
        ``P``, the kept population returned; APMCABC runs ``P / alpha`` particles.
    alpha, acceptance_cutoff : float
        APMCABC's (see :func:`jaxabc.algorithms.apmc.build`).
    distance : str or callable
        A :mod:`jaxabc.distances` name or ``distance(observed, simulated) -> scalar``.
    max_generations : int

    Returns
    -------
    ABCPosterior

    Raises
    ------
    ValueError
        When ``num_particles / alpha`` does not keep exactly ``num_particles``.
    """
    population = population_size(num_particles, alpha)
    low = tuple(float(v) for v in np.asarray(model.low))
    high = tuple(float(v) for v in np.asarray(model.high))
    algorithm, init, step = _compiled(
        low, high, population, float(alpha), float(acceptance_cutoff), get_distance(distance)
    )
    k_init, k_run = jax.random.split(key)
    state, info = init(k_init, model, observed)
    generations = 1
    while not bool(info.stop) and generations < max_generations:
        state, info = step(jax.random.fold_in(k_run, generations), state, model, observed)
        generations += 1
    particles, log_w = (np.asarray(a, np.float64) for a in algorithm.posterior(state))
    kept = np.flatnonzero(np.isfinite(log_w))
    new_per_generation = population - algorithm.settings["num_kept"]
    return ABCPosterior(
        particles=particles[kept],
        log_weights=log_w[kept],
        threshold=float(info.threshold),
        generations=generations,
        num_emulated=population + (generations - 1) * new_per_generation,
        stopped=bool(info.stop),
    )


def population_size(num_particles: int, alpha: float) -> int:
    """APMCABC's population ``N`` whose ``ceil(alpha N)`` kept particles number ``num_particles``."""
    population = round(num_particles / alpha) if 0.0 < alpha < 1.0 else 0
    # The same rounding as apmc.build, so the kept count is exactly what that builder keeps.
    if population < 2 or math.ceil(alpha * population) != num_particles:
        raise ValueError(
            f"abc_alpha={alpha} cannot keep exactly num_particles={num_particles} particles: choose "
            "abc_alpha with num_particles / abc_alpha an integer (e.g. 0.5, 0.25, 0.1)"
        )
    return population
