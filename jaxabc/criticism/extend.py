"""Extend the model: refit the base parameters plus the top effect's parameter with jaxabc.run.

The extended simulator fixes every other effect at its null; the distance is the Euclidean norm
of the noise-whitened fitted summaries (the Cholesky factor of the replicate covariance), so the
extension and the base refit it is compared with see the data through the same metric.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import jax.numpy as jnp
import numpy as np

from jaxabc.criticism.causes import Catalogue
from jaxabc.priors import Uniform
from jaxabc.results import ABCResult
from jaxabc.run import run

__all__ = ["ExtendedSimulator", "extended_prior", "extended_simulator", "refit", "whitened_distance"]


def extended_prior(base: Uniform, catalogue: Catalogue, effect_names: Sequence[str]) -> Uniform:
    """Base prior followed by the named effects' uniform priors."""
    effects = [catalogue[n] for n in effect_names]
    return Uniform(
        list(np.asarray(base.low, float)) + [e.low for e in effects],
        list(np.asarray(base.high, float)) + [e.high for e in effects],
        names=tuple(base.names) + tuple(e.name for e in effects),
        units=tuple(base.units) + tuple(e.unit for e in effects),
    )


class ExtendedSimulator:
    """``simulate(key, theta (num_base + len(effect_names),)) -> summaries[keep]``; vmappable.

    The free effects are scattered into their catalogue slots of ``theta_full``; the others stay
    at their null values.  A top-level class (not a closure) so that a process pool can pickle it
    when the simulator is a host program.
    """

    def __init__(
        self,
        simulate: Callable,
        num_base: int,
        catalogue: Catalogue,
        effect_names: Sequence[str],
        keep: np.ndarray | None = None,
    ):
        self.simulate, self.num_base = simulate, int(num_base)
        self.nulls = catalogue.nulls().astype(np.float32)
        self.slots = np.asarray([catalogue.index(n) for n in effect_names], np.int32)
        self.keep = None if keep is None else np.flatnonzero(keep)

    def __call__(self, key, theta):
        theta = jnp.asarray(theta)
        eff = jnp.asarray(self.nulls, theta.dtype)
        if self.slots.size:
            eff = eff.at[self.slots].set(theta[self.num_base :])
        out = self.simulate(key, jnp.concatenate([theta[: self.num_base], eff]))
        return out if self.keep is None else out[self.keep]


def extended_simulator(
    simulate: Callable,
    num_base: int,
    catalogue: Catalogue,
    effect_names: Sequence[str],
    keep: np.ndarray | None = None,
) -> ExtendedSimulator:
    """The simulator of the base model plus ``effect_names`` (see :class:`ExtendedSimulator`)."""
    return ExtendedSimulator(simulate, num_base, catalogue, effect_names, keep)


def whitened_distance(noise_cov: np.ndarray) -> Callable:
    """``distance(observed, simulated) = || L^-1 (simulated - observed) ||`` with ``L L' = cov``."""
    chol = np.linalg.cholesky(noise_cov + 1e-12 * np.trace(noise_cov) / len(noise_cov) * np.eye(len(noise_cov)))
    inv = jnp.asarray(np.linalg.inv(chol), jnp.float32)

    def distance(observed, simulated):
        d = inv.astype(simulated.dtype) @ (simulated - observed)
        return jnp.sqrt(jnp.sum(d * d))

    distance.__name__ = "whitened_euclidean"
    return distance


def refit(
    result: ABCResult,
    simulate: Callable,
    observed: np.ndarray,
    catalogue: Catalogue,
    effect_names: Sequence[str],
    fitted: np.ndarray,
    noise_cov: np.ndarray,
    *,
    seed: int = 0,
    executor: Any = None,
    algorithm: str | None = None,
    num_particles: int | None = None,
    num_steps: int | None = None,
    **options: Any,
) -> ABCResult:
    """Run ABC over the base parameters plus ``effect_names`` (none: a base-only refit).

    Parameters
    ----------
    result : ABCResult
        The base fit (its prior, algorithm and population size are the defaults).
    simulate : callable ``(key, theta_full) -> (s,)``
    observed : numpy.ndarray, shape (s,)
    fitted : numpy.ndarray of bool, shape (s,)
        The summaries to fit (held-out and constant ones excluded).
    noise_cov : numpy.ndarray, shape (s, s)
        Simulation-noise covariance; its fitted block defines the distance.
    algorithm, num_particles, num_steps, **options
        Passed to :func:`jaxabc.run` (defaults: the base result's algorithm and size, 8 steps).

    Returns
    -------
    ABCResult
        Particles of shape (n, d + len(effect_names)).
    """
    d = result.prior.dim
    prior = extended_prior(result.prior, catalogue, effect_names)
    sim = extended_simulator(simulate, d, catalogue, effect_names, keep=fitted)
    algo = algorithm or (result.algorithm if result.algorithm in ("apmcabc", "pmcabc", "abcsubsim") else "apmcabc")
    n = int(num_particles or max(len(result.particles), 200))
    if algo in ("pmcabc", "abcsubsim") and num_steps is None:
        num_steps = 8
    return run(
        algo,
        sim,
        prior,
        np.asarray(observed)[fitted],
        num_particles=n,
        num_steps=num_steps,
        distance=whitened_distance(noise_cov[np.ix_(fitted, fitted)]),
        seed=seed,
        executor=executor,
        metadata={"criticism": {"effects": list(effect_names)}},
        **options,
    )
