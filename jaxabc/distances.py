"""Distances between observed and simulated summaries, in JAX.

Every distance is a pure function ``distance(observed, simulated) -> scalar`` that can be
``jax.vmap``-ed over the simulated argument.  :func:`get_distance` resolves the names accepted
by :func:`jaxabc.run`.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

__all__ = [
    "DISTANCES",
    "DistanceFn",
    "euclidean",
    "gaussian_kde_density",
    "get_distance",
    "kl_divergence",
    "mean_abs",
    "standardized_euclidean",
]

DistanceFn = Callable[[jax.Array, jax.Array], jax.Array]


def mean_abs(observed: jax.Array, simulated: jax.Array) -> jax.Array:
    """Mean absolute difference of two summary vectors (the paper's water distance).

    Parameters
    ----------
    observed, simulated : jax.Array, shape (s,)

    Returns
    -------
    jax.Array, shape ()
    """
    return jnp.mean(jnp.abs(jnp.asarray(observed) - jnp.asarray(simulated)))


def euclidean(observed: jax.Array, simulated: jax.Array) -> jax.Array:
    """Euclidean distance of two summary vectors, shape (s,) each."""
    return jnp.sqrt(jnp.sum((jnp.asarray(observed) - jnp.asarray(simulated)) ** 2))


def standardized_euclidean(scale: jax.Array) -> DistanceFn:
    """Euclidean distance after dividing each summary by ``scale`` (shape (s,)).

    A common choice of ``scale`` is the prior-predictive standard deviation (or MAD) of each
    summary, so that summaries with large natural spread do not dominate the distance.
    """
    scale = jnp.asarray(scale)

    def distance(observed: jax.Array, simulated: jax.Array) -> jax.Array:
        return jnp.sqrt(jnp.sum(((jnp.asarray(observed) - jnp.asarray(simulated)) / scale) ** 2))

    return distance


def _scott_bandwidth(x: jax.Array) -> jax.Array:
    # scipy.stats.gaussian_kde's default: std * n^(-1/5) (one dimension, ddof=1).
    n = x.shape[0]
    return jnp.std(x, ddof=1) * n ** (-1.0 / 5.0)


def gaussian_kde_density(samples: jax.Array, grid: jax.Array) -> jax.Array:
    """Gaussian KDE of 1-D ``samples`` (shape (n,)) evaluated on ``grid`` (shape (g,)).

    Uses Scott's bandwidth as :class:`scipy.stats.gaussian_kde` does, so the two agree.
    """
    samples = jnp.asarray(samples)
    h = _scott_bandwidth(samples)
    z = (grid[:, None] - samples[None, :]) / h
    return jnp.mean(jnp.exp(-0.5 * z**2), axis=1) / (h * jnp.sqrt(2.0 * jnp.pi))


def kl_divergence(observed: jax.Array, simulated: jax.Array, num_grid: int = 100) -> jax.Array:
    """KL(p_obs || p_sim) of Gaussian-KDE densities of two sampled series (the helium distance).

    Both densities are evaluated on a common grid of ``num_grid`` points spanning the pooled
    range of the two series, normalised to sum to one on that grid, and compared by
    ``sum p log(p / q)``.  A floor of 1e-300 (float64) or the smallest normal float (float32)
    on ``q`` keeps the result finite when the series do not overlap; it is then large.

    Parameters
    ----------
    observed : jax.Array, shape (n,)
        The observed time series (e.g. f_B sampled at a fixed interval).
    simulated : jax.Array, shape (m,)
        A simulated series; ``m`` may differ from ``n``.
    num_grid : int
        Number of grid points (the paper's 100).

    Returns
    -------
    jax.Array, shape ()
        Non-negative; zero only for identical densities.  NaN if a series is constant or
        contains non-finite values (a degenerate simulation), which the driver records as
        a failed simulation.
    """
    observed = jnp.ravel(jnp.asarray(observed))
    simulated = jnp.ravel(jnp.asarray(simulated))
    lo = jnp.minimum(jnp.min(observed), jnp.min(simulated))
    hi = jnp.maximum(jnp.max(observed), jnp.max(simulated))
    grid = jnp.linspace(lo, hi, num_grid)
    p = gaussian_kde_density(observed, grid)
    q = gaussian_kde_density(simulated, grid)
    p = p / jnp.sum(p)
    q = q / jnp.sum(q)
    tiny = jnp.finfo(q.dtype).tiny
    q = jnp.maximum(q, tiny)
    terms = jnp.where(p > 0, p * (jnp.log(jnp.maximum(p, tiny)) - jnp.log(q)), 0.0)
    return jnp.maximum(jnp.sum(terms), 0.0)


# KL compares two samples of a distribution: the observed series may be longer than a
# simulated one (the paper's observed helium run is 4x longer), so the driver does not require
# equal shapes for it.
kl_divergence.compares_samples = True  # type: ignore[attr-defined]

DISTANCES: dict[str, DistanceFn] = {
    "mean_abs": mean_abs,
    "euclidean": euclidean,
    "kl": kl_divergence,
    "kl_divergence": kl_divergence,
}


def get_distance(distance: str | DistanceFn) -> DistanceFn:
    """Resolve a distance name (``"mean_abs"``, ``"euclidean"``, ``"kl"``) or pass a callable."""
    if callable(distance):
        return distance
    try:
        return DISTANCES[distance]
    except KeyError:
        raise ValueError(
            f"unknown distance {distance!r}: use one of {sorted(DISTANCES)} or pass a function "
            "distance(observed, simulated) -> scalar"
        ) from None
