"""Measurement error on simulated summaries: ``simulate(key, theta) + e``, ``e ~ N(0, diag(sd^2))``.

Measured data carry their own error.  Adding it to every simulation makes ABC, and the
surrogate's synthetic likelihood, target the posterior of the model *plus* that error:
Wilkinson (2013), "Approximate Bayesian computation (ABC) gives exact results under the
assumption of model error", Stat. Appl. Genet. Mol. Biol. 12, 129.  Without it a summary
measured to +-1 kJ/mol but simulated to +-0.05 is fitted as if exact, and a model that misses
it by one measurement error is rejected by twenty simulation errors.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["Discrepancy", "MeasurementError", "ResolvedDiscrepancy", "observation_covariance"]

# The error's key is folded from the simulation's key with this tag, so it never equals a key
# the simulator itself draws from.
_TAG = 0x6E6F6973  # "nois"
_DISCREPANCY_TAG = 0x64697363  # "disc"


class MeasurementError:
    """``simulate`` with independent Gaussian measurement error added to its summaries.

    Picklable when ``simulate`` is, so it runs on process pools and MPI like the simulator.

    Parameters
    ----------
    simulate : callable ``(key, theta) -> summaries``
        A JAX function (typed keys, ``vmap``) or a host simulator (raw ``uint32[2]`` keys).
    sd : array_like, shape of the summaries
        Standard deviation of each summary's measurement error, in the summaries' units;
        0 where the data state none.  Non-negative and finite.

    Notes
    -----
    The error is drawn from ``fold_in(key, tag)``, so a seed fixes it on every executor; failed
    simulations (NaN summaries, :class:`jaxabc.SimulationFailure`) stay failed.
    """

    def __init__(self, simulate: Callable, sd: Any) -> None:
        if not callable(simulate):
            raise TypeError("simulate must be a callable simulate(key, theta) -> summaries")
        sd = np.asarray(sd, np.float64)
        if not np.all(np.isfinite(sd)) or np.any(sd < 0):
            raise ValueError(f"measurement sd must be finite and >= 0 (0 where none is stated), got {sd.tolist()}")
        self.simulate = simulate
        self.sd = sd
        # Checkpoints name the simulator by module:qualname: say what is wrapped, and with what.
        inner = getattr(simulate, "__qualname__", type(simulate).__qualname__)
        self.__qualname__ = f"MeasurementError[{inner}, sd={sd.tolist()}]"

    def __repr__(self) -> str:
        return f"MeasurementError({self.simulate!r}, sd={self.sd.tolist()})"

    def __call__(self, key: Any, theta: Any) -> Any:
        out = self.simulate(key, theta)
        if jnp.issubdtype(getattr(key, "dtype", np.uint32), jax.dtypes.prng_key):
            e = jax.random.normal(jax.random.fold_in(key, _TAG), jnp.shape(out), jnp.result_type(out))
            return out + jnp.asarray(self.sd, jnp.result_type(out)) * e
        raw = jax.random.wrap_key_data(jnp.asarray(np.asarray(key), dtype=jnp.uint32))
        e = np.asarray(jax.random.normal(jax.random.fold_in(raw, _TAG), np.shape(out), jnp.float32), np.float64)
        out = np.asarray(out, np.float64)
        if self.sd.shape not in ((), out.shape):
            raise ValueError(f"measurement sd has shape {self.sd.shape}, the summaries {out.shape}")
        return out + self.sd * e


def observation_covariance(error: Any, shape: tuple[int, ...]) -> np.ndarray:
    """The covariance ``(n, n)`` of the observed summaries' measurement error.

    Parameters
    ----------
    error : float, array of the summaries' shape, array (n,), or array (n, n)
        A standard deviation for every summary, one per summary, or a covariance matrix over the
        flattened summaries (``n = prod(shape)``).  Standard deviations are ``>= 0`` (0 where the
        data state none); a covariance is symmetric positive semi-definite.
    shape : tuple of int
        The observed summaries' shape.

    Raises
    ------
    ValueError
        Non-finite or negative values, a covariance that is not symmetric or not positive
        semi-definite, or a shape that fits neither form; the message says which.
    """
    n = int(np.prod(shape)) if len(shape) else 1
    e = np.asarray(error, np.float64)
    if not np.all(np.isfinite(e)):
        raise ValueError("observation_error must be finite")
    if e.shape == (n, n) and not (e.shape == tuple(shape) and n > 1 and len(shape) == 2):
        if not np.allclose(e, e.T, rtol=1e-10, atol=1e-12 * max(float(np.abs(e).max()), 1e-300)):
            raise ValueError("observation_error given as a covariance (n, n) must be symmetric")
        low = float(np.linalg.eigvalsh(e).min()) if n else 0.0
        if low < -1e-10 * max(float(np.abs(np.diag(e)).max()), 1e-300):
            raise ValueError(
                f"observation_error given as a covariance (n, n) must be positive semi-definite; "
                f"its smallest eigenvalue is {low:.3g}"
            )
        return e.copy()
    if e.shape in ((), (n,), tuple(shape)):
        sd = np.broadcast_to(e, tuple(shape)).reshape(n)
        if np.any(sd < 0):
            bad = np.flatnonzero(sd < 0).tolist()
            raise ValueError(f"observation_error standard deviations must be >= 0; negative at summaries {bad}")
        return np.diag(sd**2)
    raise ValueError(
        f"observation_error has shape {e.shape}; give a standard deviation per summary (shape "
        f"{tuple(shape)} or ({n},)), one for all, or a covariance ({n}, {n})"
    )


class ResolvedDiscrepancy(NamedTuple):
    """A :class:`Discrepancy` checked against the summaries it applies to.

    Attributes
    ----------
    membership : numpy.ndarray, shape (G, n)
        1 where summary ``j`` (flattened) belongs to group ``g``.
    max_sd : numpy.ndarray, shape (G,)
        Upper bound of each group's uniform prior on its discrepancy standard deviation.
    names : tuple of str, length G
        Parameter names, ``"discrepancy_sd[<group>]"``.
    """

    membership: np.ndarray
    max_sd: np.ndarray
    names: tuple[str, ...]

    def variance(self, delta: Any) -> Any:
        """Per-summary discrepancy variance ``(n,)`` for group standard deviations ``delta (G,)``."""
        m = jnp.asarray(self.membership) if isinstance(delta, jax.Array) else self.membership
        return (delta**2) @ m


class Discrepancy:
    """Model discrepancy: an unknown extra standard deviation per group of summaries.

    The simulator is taken to reproduce the observed summaries up to independent Gaussian
    errors of standard deviation ``delta_g`` for the summaries of group ``g``, with ``delta_g``
    unknown and inferred jointly with the parameters: Kennedy & O'Hagan (2001), kept to a
    variance per group, with no correlation in it.  Each ``delta_g`` has a uniform prior on
    ``[0, max_sd_g]`` (weakly informative for a scale when ``max_sd_g`` is several times the
    misfit one expects; Gelman 2006).  The run's posterior has ``G`` more columns, named
    ``discrepancy_sd[<group>]``.

    Parameters
    ----------
    max_sd : float or sequence of float
        Upper bound of each group's prior, in the summaries' units; one for all groups or one per
        group.  Positive and finite.
    groups : mapping of str to sequence of int, optional
        Group name to the (flattened) indices of its summaries.  Default: every summary its own
        group, named by its index.  Groups may not overlap.
    """

    def __init__(self, max_sd: Any, groups: dict[str, Any] | None = None) -> None:
        self.groups = None if groups is None else {str(k): [int(i) for i in np.ravel(v)] for k, v in groups.items()}
        self.max_sd = np.asarray(max_sd, np.float64)
        if not np.all(np.isfinite(self.max_sd)) or np.any(self.max_sd <= 0):
            raise ValueError(f"Discrepancy max_sd must be positive and finite, got {self.max_sd.tolist()}")
        if self.groups is not None and not self.groups:
            raise ValueError("Discrepancy groups is empty: give at least one group, or None for one per summary")

    def __repr__(self) -> str:
        return f"Discrepancy(max_sd={self.max_sd.tolist()}, groups={self.groups})"

    def describe(self) -> dict:
        """JSON-able description, for fingerprints and result metadata."""
        return {"max_sd": self.max_sd.tolist(), "groups": self.groups}

    def resolve(self, shape: tuple[int, ...]) -> ResolvedDiscrepancy:
        """Check the groups against summaries of ``shape``; a clear ``ValueError`` otherwise."""
        n = int(np.prod(shape)) if len(shape) else 1
        groups = self.groups if self.groups is not None else {str(j): [j] for j in range(n)}
        membership = np.zeros((len(groups), n))
        for g, (name, idx) in enumerate(groups.items()):
            if not idx:
                raise ValueError(f"Discrepancy group {name!r} has no summaries")
            bad = [i for i in idx if not 0 <= i < n]
            if bad:
                raise ValueError(
                    f"Discrepancy group {name!r} names summaries {bad}, which do not exist: the "
                    f"observed data have {n} summaries (indices 0..{n - 1})"
                )
            if membership[:, idx].any() or len(set(idx)) != len(idx):
                raise ValueError(f"Discrepancy group {name!r} repeats a summary of another group or of itself")
            membership[g, idx] = 1.0
        max_sd = np.broadcast_to(self.max_sd, (len(groups),)) if self.max_sd.ndim == 0 else self.max_sd
        if max_sd.shape != (len(groups),):
            raise ValueError(f"Discrepancy max_sd has {max_sd.size} values for {len(groups)} groups")
        names = tuple(f"discrepancy_sd[{name}]" for name in groups)
        return ResolvedDiscrepancy(membership, np.array(max_sd, np.float64), names)
