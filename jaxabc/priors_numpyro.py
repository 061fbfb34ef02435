"""Priors built from numpyro distributions: independent parameters, each truncated to a box.

``Independent(sigma=dist.Normal(0.3, 0.05), epsilon=dist.LogNormal(-1.0, 0.5), bounds=...)`` is
accepted wherever :class:`jaxabc.Uniform` is.  The perturbation kernels of APMCABC and PMC-ABC
are truncated to the box ``[low, high]`` and their importance weights divide by the prior's log
density, so the box must be finite: a distribution with unbounded support (Normal, LogNormal)
needs ``bounds`` for its parameter; one with a finite support (Uniform, LogUniform) uses it.
Truncation renormalises the density by the base distribution's mass in the box, and sampling
uses the inverse CDF, so each base distribution must implement ``cdf`` and ``icdf``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, cast

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["Independent"]


def _numpyro_distributions():
    try:
        import numpyro.distributions as dist
    except ImportError as exc:
        raise ImportError("jaxabc.Independent needs numpyro: pip install numpyro") from exc
    return dist


class Independent:
    """Independent parameters with numpyro distributions, each truncated to ``[low, high]``.

    Parameters
    ----------
    bounds : mapping of str to (float, float), optional
        Truncation box per parameter; required where the distribution's support is unbounded,
        and intersected with the support otherwise.
    units : mapping of str to str, optional
        Unit per parameter, for reports and plots.
    **distributions : numpyro.distributions.Distribution
        One univariate distribution per parameter, in the order of the parameter vector.

    Raises
    ------
    ValueError
        A distribution is not univariate, a box is unbounded, empty or outside the support, or
        holds no probability mass.
    TypeError
        A distribution lacks ``cdf`` / ``icdf`` (needed for truncation).

    Examples
    --------
    >>> import numpyro.distributions as dist
    >>> prior = Independent(sigma=dist.Normal(0.3, 0.05), epsilon=dist.LogUniform(0.01, 1.0),
    ...                     bounds={"sigma": (0.1, 0.5)}, units={"sigma": "nm"})
    >>> prior.sample(jax.random.key(0), 4).shape
    (4, 2)
    """

    def __init__(
        self,
        bounds: Mapping[str, tuple[float, float]] | None = None,
        units: Mapping[str, str] | None = None,
        **distributions: Any,
    ) -> None:
        dist = _numpyro_distributions()
        if not distributions:
            raise ValueError(
                "give one numpyro distribution per parameter, e.g. "
                "Independent(sigma=dist.Normal(0.3, 0.05), bounds={'sigma': (0.1, 0.5)})"
            )
        bounds = dict(bounds or {})
        units = dict(units or {})
        unknown = (set(bounds) | set(units)) - set(distributions)
        if unknown:
            raise ValueError(
                f"bounds/units name unknown parameters {sorted(unknown)}; the parameters are {list(distributions)}"
            )
        low, high, log_mass = [], [], []
        for name, d in distributions.items():
            if not isinstance(d, dist.Distribution):
                raise TypeError(f"prior for {name!r} must be a numpyro distribution, got {type(d).__name__}")
            if d.batch_shape != () or d.event_shape != ():
                raise ValueError(
                    f"prior for {name!r} must be univariate (scalar parameters), got "
                    f"batch shape {d.batch_shape} and event shape {d.event_shape}"
                )
            s_lo = float(getattr(d.support, "lower_bound", -np.inf))
            s_hi = float(getattr(d.support, "upper_bound", np.inf))
            lo, hi = bounds.get(name, (s_lo, s_hi))
            lo, hi = max(float(lo), s_lo), min(float(hi), s_hi)
            if not (np.isfinite(lo) and np.isfinite(hi)):
                raise ValueError(
                    f"prior for {name!r} ({type(d).__name__}) has unbounded support [{lo}, {hi}]: "
                    f"give bounds={{'{name}': (low, high)}}; the kernels truncate to a finite box"
                )
            if not lo < hi:
                raise ValueError(f"prior box for {name!r} is empty: [{lo}, {hi}] (within the support [{s_lo}, {s_hi}])")
            try:
                mass = float(d.cdf(jnp.asarray(hi))) - float(d.cdf(jnp.asarray(lo)))
                d.icdf(jnp.asarray(0.5))
            except (NotImplementedError, ImportError, AttributeError) as exc:
                raise TypeError(
                    f"prior for {name!r}: {type(d).__name__} needs cdf and icdf for truncation ({exc})"
                ) from None
            if not mass > 0:
                raise ValueError(f"prior for {name!r} has no probability mass in [{lo}, {hi}]")
            low.append(lo)
            high.append(hi)
            log_mass.append(np.log(mass))
        self.distributions = dict(distributions)
        self.names = tuple(distributions)
        self.units = tuple(units.get(n, "") for n in self.names)
        self.low = jnp.asarray(low)
        self.high = jnp.asarray(high)
        self._log_mass = jnp.asarray(log_mass, self.low.dtype)

    @property
    def dim(self) -> int:
        """Number of parameters ``d``."""
        return len(self.names)

    def contains(self, theta: jax.Array) -> jax.Array:
        """Whether ``theta`` (shape (..., d)) lies in the box, shape (...)."""
        return jnp.all((theta >= self.low) & (theta <= self.high), axis=-1)

    def sample(self, key: jax.Array, num: int) -> jax.Array:
        """Draw ``num`` parameter vectors by inverse CDF within the box, shape (num, d)."""
        keys = jax.random.split(key, self.dim)
        columns = []
        for j, d in enumerate(self.distributions.values()):
            lo, hi = self.low[j], self.high[j]
            u = jax.random.uniform(keys[j], (num,), self.low.dtype, d.cdf(lo), d.cdf(hi))
            columns.append(jnp.clip(d.icdf(u), lo, hi))
        return jnp.stack(columns, axis=-1).astype(self.low.dtype)

    def log_prob(self, theta: jax.Array) -> jax.Array:
        """Normalised log density of the truncated prior at ``theta`` (shape (..., d)), ``-inf``
        outside the box; shape (...)."""
        theta = jnp.asarray(theta)
        # Evaluate inside the box only: numpyro warns about out-of-support values otherwise.
        x = jnp.clip(theta, self.low.astype(theta.dtype), self.high.astype(theta.dtype))
        # A sum of Arrays (there is at least one distribution), not the int start value.
        total = cast(
            jax.Array,
            sum(d.log_prob(x[..., j]) for j, d in enumerate(self.distributions.values())),
        )
        total = total - jnp.sum(self._log_mass).astype(total.dtype)
        return jnp.where(self.contains(theta), total, -jnp.inf)

    def to_dict(self) -> dict:
        """JSON-serialisable description, stored in result files."""
        dists = {}
        for name, d in self.distributions.items():
            params = {k: np.asarray(getattr(d, k)).tolist() for k in d.arg_constraints}
            dists[name] = {"class": type(d).__name__, "params": params}
        return {
            "type": "Independent",
            "distributions": dists,
            "names": list(self.names),
            "units": list(self.units),
            "low": np.asarray(self.low).tolist(),
            "high": np.asarray(self.high).tolist(),
        }

    @classmethod
    def from_dict(cls, data: dict) -> Independent:
        """Inverse of :meth:`to_dict` (numpyro distributions rebuilt by class name)."""
        dist = _numpyro_distributions()
        distributions = {}
        for name in data["names"]:
            spec = data["distributions"][name]
            distributions[name] = getattr(dist, spec["class"])(**spec["params"])
        bounds = {n: (lo, hi) for n, lo, hi in zip(data["names"], data["low"], data["high"], strict=True)}
        units = dict(zip(data["names"], data.get("units") or [""] * len(data["names"]), strict=True))
        return cls(bounds=bounds, units=units, **distributions)

    def __repr__(self) -> str:
        parts = ", ".join(
            f"{n}~{type(d).__name__}[{float(lo):g}, {float(hi):g}]"
            for (n, d), lo, hi in zip(self.distributions.items(), self.low, self.high, strict=True)
        )
        return f"Independent({parts})"


def prior_from_dict(data: dict) -> Any:
    """The prior a result file describes: :class:`jaxabc.Uniform` or :class:`Independent`."""
    if data.get("type") == "Independent":
        return Independent.from_dict(data)
    from jaxabc.priors import Uniform

    return Uniform.from_dict(data)
