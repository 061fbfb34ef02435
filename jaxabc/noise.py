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

__all__ = [
    "DISCREPANCY_PREFIX",
    "Discrepancy",
    "MeasurementError",
    "ModelDiscrepancy",
    "ResolvedDiscrepancy",
    "observation_covariance",
    "wrap_for_abc",
]

#: Name prefix of the model-discrepancy sds a run appends to the parameters
#: (``discrepancy_sd[<group>]``).
DISCREPANCY_PREFIX = "discrepancy_sd["

# The error's key is folded from the simulation's key with this tag, so it never equals a key
# the simulator itself draws from.
_TAG = 0x6E6F6973  # "nois"
_DISCREPANCY_TAG = 0x64697363  # "disc"


def _is_typed_key(key: Any) -> bool:
    return bool(jnp.issubdtype(getattr(key, "dtype", np.uint32), jax.dtypes.prng_key))


def _host_normal(key: Any, tag: int, shape: tuple[int, ...]) -> np.ndarray:
    """Standard normals (float64) from a raw ``uint32[2]`` key folded with ``tag``: the same
    float32 draws a typed key gives under ``vmap``, so every executor sees the same error."""
    raw = jax.random.wrap_key_data(jnp.asarray(np.asarray(key), dtype=jnp.uint32))
    return np.asarray(jax.random.normal(jax.random.fold_in(raw, tag), shape, jnp.float32), np.float64)


def _inner_name(simulate: Callable) -> str:
    return getattr(simulate, "__qualname__", type(simulate).__qualname__)


def _square_root(cov: np.ndarray) -> np.ndarray:
    """A factor ``L`` with ``L @ L.T == cov``: Cholesky, or an eigen square root when ``cov`` is
    positive semi-definite but singular (a summary that is an exact function of others)."""
    try:
        return np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        w, v = np.linalg.eigh(cov)
        return v * np.sqrt(np.clip(w, 0.0, None))


class MeasurementError:
    """``simulate`` with Gaussian measurement error added to its summaries.

    Picklable when ``simulate`` is, so it runs on process pools and MPI like the simulator.

    Parameters
    ----------
    simulate : callable ``(key, theta) -> summaries``
        A JAX function (typed keys, ``vmap``) or a host simulator (raw ``uint32[2]`` keys).
    sd : array_like, shape of the summaries, optional
        Standard deviation of each summary's independent measurement error, in the summaries'
        units; 0 where the data state none.  Non-negative and finite.
    cov : array_like, shape (n, n), optional
        Instead of ``sd``: the covariance of the error over the flattened summaries
        (``n = summaries.size``), symmetric positive semi-definite, in squared summary units.
        The error is ``L @ z`` with ``z`` standard normal and ``L`` the Cholesky factor of
        ``cov`` (an eigen square root when ``cov`` is singular).  A diagonal ``cov`` is the
        ``sd = sqrt(diag(cov))`` form, draw for draw.

    Notes
    -----
    The error is drawn from ``fold_in(key, tag)``, so a seed fixes it on every executor; failed
    simulations (NaN summaries, :class:`jaxabc.SimulationFailure`) stay failed.
    """

    def __init__(self, simulate: Callable, sd: Any = None, *, cov: Any = None) -> None:
        if not callable(simulate):
            raise TypeError("simulate must be a callable simulate(key, theta) -> summaries")
        if (sd is None) == (cov is None):
            raise TypeError("MeasurementError takes a standard deviation sd or a covariance cov, exactly one")
        self.simulate = simulate
        self.factor: np.ndarray | None = None
        if cov is not None:
            cov = np.asarray(cov, np.float64)
            if cov.ndim != 2 or cov.shape[0] != cov.shape[1] or cov.shape[0] == 0:
                raise ValueError(f"measurement covariance must be a square matrix (n, n), got shape {cov.shape}")
            cov = observation_covariance(cov, (cov.shape[0],))  # finite, symmetric, PSD
            if np.count_nonzero(cov - np.diag(np.diag(cov))) == 0:
                sd = np.sqrt(np.diag(cov))
            else:
                self.factor = _square_root(cov)
        if self.factor is None:
            sd = np.asarray(sd, np.float64)
            if not np.all(np.isfinite(sd)) or np.any(sd < 0):
                raise ValueError(f"measurement sd must be finite and >= 0 (0 where none is stated), got {sd.tolist()}")
            self.sd: np.ndarray | None = sd
            what = f"sd={sd.tolist()}" if sd.size <= 16 else f"sd=<{sd.size} values>"
        else:
            self.sd = None
            n = self.factor.shape[0]
            what = f"cov=<{n}x{n}>"
        # Checkpoints name the simulator by module:qualname: say what is wrapped, and with what.
        self.__qualname__ = f"MeasurementError[{_inner_name(simulate)}, {what}]"

    def __repr__(self) -> str:
        if self.factor is not None:
            return f"MeasurementError({self.simulate!r}, cov={(self.factor @ self.factor.T).tolist()})"
        return f"MeasurementError({self.simulate!r}, sd={np.asarray(self.sd).tolist()})"

    def _key(self) -> tuple:
        arr = self.factor if self.factor is not None else self.sd
        assert arr is not None
        return (self.factor is not None, arr.shape, arr.tobytes())

    def __eq__(self, other: object) -> bool:
        # Equal wrappers share compiled programs (the fused and vmap caches are keyed on them).
        if type(other) is not type(self):
            return NotImplemented
        assert isinstance(other, MeasurementError)
        return self.simulate == other.simulate and self._key() == other._key()

    def __hash__(self) -> int:
        return hash((type(self).__name__, self.simulate, self._key()))

    def _check(self, shape: tuple[int, ...]) -> None:
        n = int(np.prod(shape)) if len(shape) else 1
        if self.factor is not None:
            if self.factor.shape[0] != n:
                raise ValueError(
                    f"measurement covariance is {self.factor.shape[0]}x{self.factor.shape[0]}, but the "
                    f"summaries have {n} values (shape {tuple(shape)})"
                )
        elif self.sd is not None and self.sd.shape not in ((), tuple(shape)) and self.sd.size != n:
            raise ValueError(f"measurement sd has shape {self.sd.shape}, the summaries {tuple(shape)}")

    def _sd(self, shape: tuple[int, ...]) -> np.ndarray:
        assert self.sd is not None
        return self.sd if self.sd.shape in ((), tuple(shape)) else self.sd.reshape(shape)

    def __call__(self, key: Any, theta: Any) -> Any:
        out = self.simulate(key, theta)
        if _is_typed_key(key):
            shape, dtype = jnp.shape(out), jnp.result_type(out)
            self._check(shape)
            z = jax.random.normal(jax.random.fold_in(key, _TAG), shape, dtype)
            if self.factor is None:
                return out + jnp.asarray(self._sd(shape), dtype) * z
            return out + jnp.reshape(jnp.asarray(self.factor, dtype) @ jnp.ravel(z), shape)
        out = np.asarray(out, np.float64)
        self._check(out.shape)
        z = _host_normal(key, _TAG, out.shape)
        if self.factor is None:
            return out + self._sd(out.shape) * z
        return out + (self.factor @ z.ravel()).reshape(out.shape)


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
        names = tuple(f"{DISCREPANCY_PREFIX}{name}]" for name in groups)
        return ResolvedDiscrepancy(membership, np.array(max_sd, np.float64), names)


class ModelDiscrepancy:
    """``simulate`` with an unknown Gaussian discrepancy per group of summaries.

    Called with ``theta' = (theta, delta)``, ``theta`` the model's ``d`` parameters and ``delta``
    the ``G`` group standard deviations, it returns ``simulate(key, theta) + sqrt(v) * z`` with
    ``v = discrepancy.variance(delta)`` and ``z`` standard normal drawn from a key folded with
    its own tag (never the simulator's key, nor the measurement error's).  Picklable when
    ``simulate`` is.

    Parameters
    ----------
    simulate : callable ``(key, theta) -> summaries``
        A JAX function (typed keys) or a host simulator (raw ``uint32[2]`` keys).
    discrepancy : ResolvedDiscrepancy
        The groups, checked against the summaries (:meth:`Discrepancy.resolve`).
    num_parameters : int
        ``d``, the model's own parameters: the first ``d`` entries of ``theta'``.
    """

    def __init__(self, simulate: Callable, discrepancy: ResolvedDiscrepancy, num_parameters: int) -> None:
        if not callable(simulate):
            raise TypeError("simulate must be a callable simulate(key, theta) -> summaries")
        if not isinstance(discrepancy, ResolvedDiscrepancy):
            raise TypeError("ModelDiscrepancy needs a ResolvedDiscrepancy: call Discrepancy.resolve(shape) first")
        self.simulate = simulate
        self.discrepancy = ResolvedDiscrepancy(
            np.asarray(discrepancy.membership, np.float64),
            np.asarray(discrepancy.max_sd, np.float64),
            tuple(discrepancy.names),
        )
        self.num_parameters = int(num_parameters)
        groups = ", ".join(self.discrepancy.names)
        self.__qualname__ = f"ModelDiscrepancy[{_inner_name(simulate)}, {groups}]"

    def __repr__(self) -> str:
        return f"ModelDiscrepancy({self.simulate!r}, names={list(self.discrepancy.names)}, d={self.num_parameters})"

    def _key(self) -> tuple:
        r = self.discrepancy
        return (self.num_parameters, r.membership.shape, r.membership.tobytes(), r.max_sd.tobytes(), r.names)

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        assert isinstance(other, ModelDiscrepancy)
        return self.simulate == other.simulate and self._key() == other._key()

    def __hash__(self) -> int:
        return hash((type(self).__name__, self.simulate, self._key()))

    def _check(self, theta_shape: tuple[int, ...], out_shape: tuple[int, ...]) -> None:
        g, n = self.discrepancy.membership.shape
        if theta_shape != (self.num_parameters + g,):
            raise ValueError(
                f"ModelDiscrepancy expects {self.num_parameters} parameters and {g} discrepancy sds, "
                f"got theta of shape {theta_shape}"
            )
        size = int(np.prod(out_shape)) if len(out_shape) else 1
        if size != n:
            raise ValueError(
                f"the discrepancy groups cover {n} summaries, the simulator returned {size} (shape {out_shape})"
            )

    def __call__(self, key: Any, theta: Any) -> Any:
        d = self.num_parameters
        if _is_typed_key(key):
            out = self.simulate(key, theta[:d])
            shape, dtype = jnp.shape(out), jnp.result_type(out)
            self._check(tuple(jnp.shape(theta)), shape)
            delta = jnp.asarray(theta[d:], dtype)
            var = (delta**2) @ jnp.asarray(self.discrepancy.membership, dtype)
            z = jax.random.normal(jax.random.fold_in(key, _DISCREPANCY_TAG), shape, dtype)
            return out + jnp.reshape(jnp.sqrt(var), shape) * z
        theta = np.asarray(theta)
        out = np.asarray(self.simulate(key, theta[:d]), np.float64)
        self._check(theta.shape, out.shape)
        var = self.discrepancy.variance(np.asarray(theta[d:], np.float64))
        return out + np.sqrt(var).reshape(out.shape) * _host_normal(key, _DISCREPANCY_TAG, out.shape)


#: Units of the discrepancy parameters in the augmented prior.
DISCREPANCY_UNITS = "summary units"


def wrap_for_abc(
    simulate: Callable,
    prior: Any,
    observed_shape: tuple[int, ...],
    observation_error: Any = None,
    discrepancy: Discrepancy | ResolvedDiscrepancy | None = None,
) -> tuple[Callable, Any]:
    """The simulator and prior an ABC algorithm runs with measurement error and discrepancy.

    Noisy ABC (Wilkinson 2013): every simulation gets its own draw of the measurement error, so
    ABC targets the posterior of the model plus that error.  A discrepancy (Kennedy & O'Hagan
    2001) adds ``G`` parameters, the group standard deviations, each uniform on
    ``[0, max_sd_g]``, to the prior, and their Gaussian error to every simulation.

    Parameters
    ----------
    simulate : callable ``(key, theta) -> summaries``
    prior : Uniform
        With a discrepancy it must be a :class:`jaxabc.Uniform` (names and units).
    observed_shape : tuple of int
        The observed summaries' shape: the error's and the groups' frame.
    observation_error : float, array or (n, n) covariance, optional
        As :func:`observation_covariance` reads it.
    discrepancy : Discrepancy or ResolvedDiscrepancy, optional

    Returns
    -------
    simulate : callable
        ``MeasurementError(ModelDiscrepancy(simulate, ...), cov=...)``, or the parts that apply;
        ``simulate`` itself when neither is given.
    prior : Uniform
        ``prior`` with the discrepancy parameters appended (names ``discrepancy_sd[<group>]``,
        units ``"summary units"``), or ``prior`` itself.

    Raises
    ------
    ValueError
        A bad error or group (see :func:`observation_covariance`, :meth:`Discrepancy.resolve`),
        or a discrepancy name that is already a parameter's.
    TypeError
        ``discrepancy`` of another type, or a prior other than ``Uniform`` with a discrepancy.
    """
    from jaxabc.priors import Uniform

    shape = tuple(int(s) for s in observed_shape)
    if discrepancy is not None:
        if isinstance(discrepancy, Discrepancy):
            resolved = discrepancy.resolve(shape)
        elif isinstance(discrepancy, ResolvedDiscrepancy):
            resolved = discrepancy
            n = int(np.prod(shape)) if len(shape) else 1
            if resolved.membership.shape[1] != n:
                raise ValueError(f"the discrepancy covers {resolved.membership.shape[1]} summaries, the data have {n}")
        else:
            raise TypeError(f"discrepancy must be a jaxabc.Discrepancy, got {type(discrepancy).__name__}")
        if not isinstance(prior, Uniform):
            raise TypeError(
                f"a discrepancy adds uniform parameters to the prior, which must then be a jaxabc.Uniform, "
                f"not {type(prior).__name__}"
            )
        clash = sorted(set(prior.names) & set(resolved.names))
        if clash:
            raise ValueError(
                f"the prior already has parameters named {clash}: rename them, the discrepancy needs these names"
            )
        d = prior.dim
        prior = Uniform(
            np.concatenate([np.asarray(prior.low, np.float64), np.zeros(len(resolved.names))]).tolist(),
            np.concatenate([np.asarray(prior.high, np.float64), resolved.max_sd]).tolist(),
            names=(*prior.names, *resolved.names),
            units=(*getattr(prior, "units", ("",) * d), *(DISCREPANCY_UNITS,) * len(resolved.names)),
            # A standard deviation cannot be negative: 0 is a physical limit, max_sd a choice.
            limits=(*prior.limits, *((True, False),) * len(resolved.names)),
        )
        simulate = ModelDiscrepancy(simulate, resolved, d)
    if observation_error is not None:
        simulate = MeasurementError(simulate, cov=observation_covariance(observation_error, shape))
    return simulate, prior
