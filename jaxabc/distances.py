"""Distances between observed and simulated summaries, in JAX.

Every distance is a pure function ``distance(observed, simulated) -> scalar`` that can be
``jax.vmap``-ed over the simulated argument.  :func:`get_distance` resolves the names accepted
by :func:`jaxabc.run`.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "DISTANCES",
    "AdaptivePNorm",
    "DistanceFn",
    "adaptive_weights",
    "as_adaptive",
    "check_kl_observed",
    "euclidean",
    "gaussian_kde_density",
    "get_distance",
    "is_adaptive",
    "kl_divergence",
    "mad_scales",
    "mean_abs",
    "standardized_euclidean",
    "weighted_pnorm",
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
        Non-negative; zero only for identical densities.  NaN if a series has fewer than two
        values, is constant or contains non-finite values: its KDE has no bandwidth.  A
        degenerate simulated series is recorded by the driver as a failed simulation; a
        degenerate observed series is refused before the run (``check_observed``).
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
    # A zero or undefined bandwidth makes p NaN, and the p > 0 mask above would turn that into
    # 0: "identical to everything".  Say NaN instead, as for a degenerate q.
    defined = jnp.all(jnp.isfinite(p))
    return jnp.where(defined, jnp.maximum(jnp.sum(terms), 0.0), jnp.nan)


def check_kl_observed(observed: Any) -> None:
    """Refuse an observed series whose KL density cannot be estimated.

    Parameters
    ----------
    observed : array_like
        The observed series (flattened).

    Raises
    ------
    ValueError
        Fewer than two values, or all equal: the Gaussian KDE's bandwidth (a standard deviation)
        is then undefined or zero, and :func:`kl_divergence` is NaN for every simulation.
    """
    obs = np.ravel(np.asarray(observed, np.float64))
    if obs.size < 2:
        reason = f"the observed data has {obs.size} element"
    elif np.ptp(obs) == 0:
        reason = f"all {obs.size} observed values equal {obs[0]:.6g} (zero spread)"
    else:
        return
    raise ValueError(
        f"distance='kl' compares kernel density estimates of two series, but {reason}, so the "
        "density of the observed series cannot be estimated: pass the observed series itself "
        "(at least two distinct values), or use a distance for summary vectors ('euclidean', "
        "'mean_abs')"
    )


# KL compares two samples of a distribution: the observed series may be longer than a
# simulated one (the paper's observed helium run is 4x longer), so the driver does not require
# equal shapes for it.
kl_divergence.compares_samples = True  # type: ignore[attr-defined]
# The drivers call a distance's check_observed(observed) before the run (validate_observed).
kl_divergence.check_observed = check_kl_observed  # type: ignore[attr-defined]

DISTANCES: dict[str, DistanceFn] = {
    "mean_abs": mean_abs,
    "euclidean": euclidean,
    "kl": kl_divergence,
    "kl_divergence": kl_divergence,
}


def get_distance(distance: str | DistanceFn) -> DistanceFn:
    """Resolve a distance name (``"mean_abs"``, ``"euclidean"``, ``"kl"``) or pass a callable.

    ``"adaptive"`` (or an :class:`AdaptivePNorm`) is refused here with a message: its weights
    change every generation, so only :func:`jaxabc.run` with an algorithm that re-estimates them
    can use it.
    """
    if is_adaptive(distance):
        raise ValueError(
            "distance='adaptive' is re-weighted every generation by the algorithm itself, so it "
            "cannot be used as a fixed distance function (e.g. by jaxabc.run_fused): call "
            "jaxabc.run(..., distance='adaptive') with algorithm 'apmcabc' or 'pmcabc'"
        )
    if callable(distance):
        return distance
    try:
        return DISTANCES[distance]
    except KeyError:
        raise ValueError(
            f"unknown distance {distance!r}: use one of {sorted(DISTANCES)} or pass a function "
            "distance(observed, simulated) -> scalar"
        ) from None


# ----------------------------------------------------------------------------- adaptive p-norm


def weighted_pnorm(observed: jax.Array, simulated: jax.Array, weights: jax.Array, p: float = 2.0) -> jax.Array:
    """``(sum_k |w_k (x_k - y_k)|^p)^(1/p)`` for flat summary vectors.

    Parameters
    ----------
    observed, simulated, weights : jax.Array, shape (s,)
    p : float
        The norm's order, at least 1.

    Returns
    -------
    jax.Array, shape ()
        NaN when ``simulated`` holds NaN (a failed simulation).
    """
    diff = jnp.abs(weights * (jnp.asarray(simulated) - jnp.asarray(observed)))
    if p == 2.0:
        return jnp.sqrt(jnp.sum(diff**2))
    return jnp.sum(diff**p) ** (1.0 / p)


def _masked_median(x: jax.Array, valid: jax.Array) -> jax.Array:
    """Median of ``x[valid]`` for a fixed-size ``x`` (shape (m,)); NaN when nothing is valid."""
    xs = jnp.sort(jnp.where(valid, x, jnp.inf))
    n = jnp.sum(valid)
    lo = jnp.maximum((n - 1) // 2, 0)
    hi = jnp.maximum(n // 2, 0)
    return jnp.where(n > 0, 0.5 * (xs[lo] + xs[hi]), jnp.nan)


def mad_scales(summaries: jax.Array, valid: jax.Array) -> jax.Array:
    """Median absolute deviation of each summary over the valid rows.

    Parameters
    ----------
    summaries : jax.Array, shape (m, s)
    valid : jax.Array, shape (m,)
        Rows to use; rows holding a non-finite value are dropped as well.

    Returns
    -------
    jax.Array, shape (s,)
        ``median_i |x_ik - median_j x_jk|``; NaN when no row is valid.
    """
    valid = valid & jnp.all(jnp.isfinite(summaries), axis=1)

    def column(x):
        med = _masked_median(x, valid)
        return _masked_median(jnp.abs(x - med), valid)

    return jax.vmap(column, in_axes=1)(summaries)


def adaptive_weights(summaries: jax.Array, valid: jax.Array) -> jax.Array:
    """Prangle's (2017) weights ``1 / MAD`` of one generation's simulated summaries.

    A summary with zero (or undefined) MAD gets weight 0: it did not vary over the generation,
    so it cannot rank the particles, and ``1 / 0`` would swamp the others.

    Parameters
    ----------
    summaries : jax.Array, shape (m, s)
    valid : jax.Array, shape (m,)

    Returns
    -------
    jax.Array, shape (s,)
    """
    scale = mad_scales(summaries, valid)
    ok = jnp.isfinite(scale) & (scale > 0)
    return jnp.where(ok, 1.0 / jnp.where(ok, scale, 1.0), 0.0)


@dataclasses.dataclass(frozen=True)
class AdaptivePNorm:
    """The adaptive weighted p-norm of Prangle (2017), pyABC's ``AdaptivePNormDistance``.

    Each generation, the weight of summary ``k`` becomes ``1 / MAD_k`` of the summaries simulated
    in that generation (every proposal, accepted or not); the kept particles' distances are
    recomputed with the new weights before the next threshold is chosen, so old and new
    particles are compared on one scale.  MAD rather than the standard deviation, following
    Prangle: one wild simulation (a crystallised water box, a diverging run) does not blow up a
    summary's scale.

    Pass ``distance="adaptive"`` (``p = 2``) or ``distance=AdaptivePNorm(p=...)`` to
    :func:`jaxabc.run`; the driver binds the observed vector with :meth:`bind`.

    Attributes
    ----------
    p : float
        Order of the norm, at least 1.
    observed : tuple of float
        The flat observed summary vector (empty until bound).
    """

    p: float = 2.0
    observed: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if not (isinstance(self.p, int | float) and self.p >= 1.0 and np.isfinite(self.p)):
            raise ValueError(f"the adaptive p-norm needs a finite p >= 1, got p={self.p!r}")

    def bind(self, observed: Any) -> AdaptivePNorm:
        """This norm with ``observed`` (shape (s,)) attached; other shapes are refused."""
        obs = np.asarray(observed, np.float64)
        if obs.ndim != 1:
            raise ValueError(
                f"distance='adaptive' weights each summary separately, so the observed data must "
                f"be a flat vector of summaries; got shape {obs.shape}: flatten it (and make the "
                "simulator return the same flat vector)"
            )
        return dataclasses.replace(self, observed=tuple(float(v) for v in obs))

    def settings(self) -> dict:
        """The JSON form stored in the algorithm's settings."""
        return {"p": float(self.p), "scale": "mad"}

    def summaries_of(self, summaries: Any, distances: jax.Array, dtype: Any) -> jax.Array:
        """The driver's summaries (m, s) in ``dtype``, NaN where the simulation failed.

        Raises ValueError for anything but a batch of flat vectors of the observed length.
        """
        if summaries is None or summaries.ndim != 2 or summaries.shape[1] != len(self.observed):
            raise ValueError(
                "the adaptive distance needs flat summary vectors of the observed length "
                f"{len(self.observed)}, as a batch of shape (m, {len(self.observed)}); got "
                f"{None if summaries is None else tuple(summaries.shape)}"
            )
        summaries = jnp.asarray(summaries, dtype)
        return jnp.where(jnp.isfinite(distances)[:, None], summaries, jnp.nan)

    def distances(self, summaries: jax.Array, weights: jax.Array, valid: jax.Array) -> jax.Array:
        """Distances of ``summaries`` (m, s) to the observed vector; ``+inf`` where not ``valid``."""
        obs = jnp.asarray(self.observed, summaries.dtype)
        d = jax.vmap(weighted_pnorm, in_axes=(None, 0, None, None))(obs, summaries, weights, self.p)
        return jnp.where(valid & jnp.isfinite(d), d, jnp.inf)

    def record_distance(self) -> DistanceFn:
        """The unit-weight p-norm that the driver records for every simulation."""
        return _unit_pnorm(float(self.p))


@functools.cache
def _unit_pnorm(p: float) -> DistanceFn:
    # One function object per p, so the driver's compiled distance is reused across runs.
    def distance(observed: jax.Array, simulated: jax.Array) -> jax.Array:
        return weighted_pnorm(observed, simulated, jnp.ones_like(jnp.asarray(observed)), p)

    distance.__name__ = distance.__qualname__ = f"adaptive_pnorm_unit_weights(p={p:g})"
    return distance


def is_adaptive(distance: Any) -> bool:
    """Whether ``distance`` asks for the adaptive p-norm (``"adaptive"`` or an AdaptivePNorm)."""
    return isinstance(distance, AdaptivePNorm) or (isinstance(distance, str) and distance == "adaptive")


def as_adaptive(distance: Any, observed: Any) -> AdaptivePNorm:
    """The :class:`AdaptivePNorm` that ``distance`` asks for, bound to ``observed``."""
    spec = distance if isinstance(distance, AdaptivePNorm) else AdaptivePNorm()
    return spec.bind(observed)
