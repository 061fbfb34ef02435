"""Prior distributions over simulator parameters.

The paper's priors are independent uniforms on a box; :class:`Uniform` is that, with names and
units so that results, plots and error messages speak the user's language.  Any object with the
same methods (``sample``, ``log_prob``, ``low``, ``high``, ``names``) can serve as a prior; the
box ``[low, high]`` is the support that perturbation kernels are truncated to.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["Prior", "Uniform"]


@runtime_checkable
class Prior(Protocol):
    """What the algorithms need from a prior."""

    low: jax.Array
    high: jax.Array
    names: tuple[str, ...]

    @property
    def dim(self) -> int: ...

    def sample(self, key: jax.Array, num: int) -> jax.Array: ...

    def log_prob(self, theta: jax.Array) -> jax.Array: ...

    def contains(self, theta: jax.Array) -> jax.Array: ...


class Uniform:
    """Independent uniform prior on the box ``[low, high]``.

    Parameters
    ----------
    low, high : array_like, shape (d,)
        Lower and upper bounds; ``low < high`` element-wise and finite.
    names : sequence of str, optional
        One name per parameter (default ``theta0, theta1, ...``).
    units : sequence of str, optional
        One unit string per parameter, used in reports and plots.
    limits : sequence of (bool, bool), optional
        Per parameter, whether its lower and upper bounds are physical limits rather than choices
        (a standard deviation cannot be negative).  A posterior piled against such a bound is
        not a :class:`jaxabc.PriorEdgeWarning`: widening the box there is impossible.  Default:
        every bound is a choice.

    Examples
    --------
    >>> prior = Uniform(low=[0.1, 0.01], high=[0.8, 1.0], names=("sigma", "epsilon"),
    ...                 units=("nm", "zJ"))
    >>> prior.sample(jax.random.key(0), 3).shape
    (3, 2)
    """

    def __init__(
        self,
        low: Sequence[float] | jax.Array,
        high: Sequence[float] | jax.Array,
        names: Sequence[str] | None = None,
        units: Sequence[str] | None = None,
        limits: Sequence[Sequence[bool]] | None = None,
    ) -> None:
        low_np = np.atleast_1d(np.asarray(low, dtype=np.float64))
        high_np = np.atleast_1d(np.asarray(high, dtype=np.float64))
        if low_np.ndim != 1 or high_np.shape != low_np.shape:
            raise ValueError(
                f"prior bounds must be 1-D arrays of equal length, got low shape {low_np.shape} "
                f"and high shape {high_np.shape}"
            )
        if low_np.size == 0:
            raise ValueError("the prior has no parameters: give at least one (low, high) pair")
        names = tuple(names) if names is not None else tuple(f"theta{i}" for i in range(low_np.size))
        if len(names) != low_np.size:
            raise ValueError(f"got {len(names)} names for {low_np.size} parameters")
        if len(set(names)) != len(names):
            raise ValueError(f"parameter names must be unique, got {names}")
        units = tuple(units) if units is not None else ("",) * low_np.size
        if len(units) != low_np.size:
            raise ValueError(f"got {len(units)} units for {low_np.size} parameters")
        for name, lo, hi in zip(names, low_np, high_np, strict=True):
            if not (np.isfinite(lo) and np.isfinite(hi)):
                raise ValueError(f"prior bounds for {name!r} must be finite, got [{lo}, {hi}]")
            if lo > hi:
                raise ValueError(f"prior bounds for {name!r} are reversed: low={lo} > high={hi}; swap them")
            if lo == hi:
                raise ValueError(
                    f"prior bounds for {name!r} are degenerate: low == high == {lo}; fix the "
                    "parameter in the simulator instead of giving it a zero-width prior"
                )
        if limits is None:
            limits = ((False, False),) * low_np.size
        limits = tuple((bool(lo), bool(hi)) for lo, hi in limits)
        if len(limits) != low_np.size:
            raise ValueError(f"got {len(limits)} (lower, upper) limit flags for {low_np.size} parameters")
        self.low = jnp.asarray(low_np)
        self.high = jnp.asarray(high_np)
        self.names = names
        self.units = units
        self.limits = limits

    @property
    def dim(self) -> int:
        """Number of parameters ``d``."""
        return int(self.low.shape[0])

    @property
    def log_volume(self) -> jax.Array:
        """Log of the box volume, shape ()."""
        return jnp.sum(jnp.log(self.high - self.low))

    def sample(self, key: jax.Array, num: int) -> jax.Array:
        """Draw ``num`` parameter vectors, shape (num, d)."""
        u = jax.random.uniform(key, (num, self.dim), dtype=self.low.dtype)
        return self.low + u * (self.high - self.low)

    def contains(self, theta: jax.Array) -> jax.Array:
        """Whether ``theta`` (shape (..., d)) lies in the support, shape (...)."""
        return jnp.all((theta >= self.low) & (theta <= self.high), axis=-1)

    def log_prob(self, theta: jax.Array) -> jax.Array:
        """Normalised log density at ``theta`` (shape (..., d)), ``-inf`` outside; shape (...)."""
        return jnp.where(self.contains(theta), -self.log_volume, -jnp.inf)

    def to_dict(self) -> dict:
        """JSON-serialisable description, stored in result files."""
        out = {
            "type": "Uniform",
            "low": np.asarray(self.low).tolist(),
            "high": np.asarray(self.high).tolist(),
            "names": list(self.names),
            "units": list(self.units),
        }
        if any(any(pair) for pair in self.limits):  # absent otherwise: older files stay identical
            out["limits"] = [list(pair) for pair in self.limits]
        return out

    @classmethod
    def from_dict(cls, data: dict) -> Uniform:
        """Inverse of :meth:`to_dict`."""
        return cls(data["low"], data["high"], data.get("names"), data.get("units"), data.get("limits"))

    def __repr__(self) -> str:
        parts = ", ".join(
            f"{n}~U[{float(lo):g}, {float(hi):g}]{(' ' + u) if u else ''}"
            for n, lo, hi, u in zip(self.names, self.low, self.high, self.units, strict=True)
        )
        return f"Uniform({parts})"
