"""Priors built from numpyro distributions: independent parameters, each truncated to a box.

``Independent(sigma=dist.Normal(0.3, 0.05), epsilon=dist.LogNormal(-1.0, 0.5))`` is accepted
wherever :class:`jaxabc.Uniform` is.  The perturbation kernels of APMCABC and PMC-ABC are
truncated to the box ``[low, high]``, their covariance jitter and the surrogate's coordinates
scale with it, and their importance weights divide by the prior's log density, so every
parameter lives in a finite box.  A side of the box is, in order of precedence, the ``bounds``
the user gives, the distribution's support, or (an unbounded side: a Normal's two, a
LogNormal's upper one) the far quantile ``tail`` (default ``1e-9``) of the distribution:
truncation there leaves out at most ``tail`` of the prior's mass per side, reported as
:attr:`Independent.tail_mass`.  Truncation renormalises the density by the base distribution's
mass in the box, and sampling uses the inverse CDF; a distribution whose numpyro quantile
function is missing (Gamma, Beta, StudentT without TensorFlow Probability) is inverted by
bisection of its ``cdf``, so each base distribution must implement ``cdf``.
"""

from __future__ import annotations

import inspect
import warnings
from collections.abc import Mapping
from typing import Any, cast

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["Independent"]


#: Default prior mass left out on each unbounded side of a distribution by the automatic box:
#: its lower bound is the ``TAIL`` quantile, its upper bound the ``1 - TAIL`` quantile.
TAIL = 1e-9

#: An automatic box wider than this many interquartile ranges of its distribution gets a
#: warning: the kernels' covariance jitter (``1e-6`` of the box width as a standard deviation)
#: and the surrogate's coordinates scale with the box.
WIDE_BOX = 1e3

#: Bisection steps of the inverse CDF for distributions without a numpyro ``icdf``: enough to
#: reach adjacent floating-point numbers in float64 from any finite box.
_BISECTIONS = 80


def _numpyro_distributions():
    try:
        import numpyro.distributions as dist
    except ImportError as exc:
        raise ImportError("jaxabc.Independent needs numpyro: pip install numpyro") from exc
    return dist


def _has_icdf(d: Any) -> bool:
    try:
        return bool(np.isfinite(float(d.icdf(jnp.asarray(0.5)))))
    except (NotImplementedError, ImportError, AttributeError):
        return False


def _fixed_support(d: Any) -> bool:
    """Whether ``d``'s support is fixed by its class (Exponential: positive) rather than set by
    its arguments (Uniform(low, high): a ``dependent_property``)."""
    support = inspect.getattr_static(type(d), "support", None)
    return support is not None and not isinstance(support, property)


def _bisect_icdf(d: Any, u: jax.Array, lo: jax.Array, hi: jax.Array) -> jax.Array:
    """``x`` in ``[lo, hi]`` with ``d.cdf(x) = u`` by bisection, for distributions without
    ``icdf`` (jittable; shape of ``u``)."""

    def step(_, bracket):
        a, b = bracket
        m = 0.5 * (a + b)
        below = d.cdf(m) < u
        return jnp.where(below, m, a), jnp.where(below, b, m)

    a, b = jax.lax.fori_loop(0, _BISECTIONS, step, (jnp.full_like(u, lo), jnp.full_like(u, hi)))
    return 0.5 * (a + b)


def _quantile(d: Any, q: float, has_icdf: bool, s_lo: float, s_hi: float) -> float:
    """The ``q``-quantile of ``d`` in float64: ``icdf`` where numpyro has it, else bisection of
    ``cdf`` in a bracket grown geometrically from the mean (or the support's edge)."""
    with jax.enable_x64(True):
        if has_icdf:
            x = float(d.icdf(jnp.asarray(q, jnp.float64)))
            if np.isfinite(x):
                return x

        def cdf(x: float) -> float:
            return float(d.cdf(jnp.asarray(x, jnp.float64)))

        try:
            centre, scale = float(d.mean), float(np.sqrt(d.variance))
        except (NotImplementedError, ZeroDivisionError, TypeError, ValueError):
            centre, scale = np.nan, np.nan
        if not (np.isfinite(centre) and s_lo < centre < s_hi):
            centre = s_lo + 1.0 if np.isfinite(s_lo) else (s_hi - 1.0 if np.isfinite(s_hi) else 0.0)
        if not (np.isfinite(scale) and scale > 0):
            scale = 1.0
        a, b = centre, centre
        for k in range(1100):  # grow the bracket until it holds the quantile (or hits the support)
            if cdf(a) <= q or a <= s_lo:
                break
            a = max(centre - scale * 2.0**k, s_lo)
        for k in range(1100):
            if cdf(b) >= q or b >= s_hi:
                break
            b = min(centre + scale * 2.0**k, s_hi)
        if not (np.isfinite(a) and np.isfinite(b)):
            raise ValueError(f"{type(d).__name__}: no finite {q:g}-quantile found")
        for _ in range(200):
            m = 0.5 * (a + b)
            if not a < m < b:
                break
            a, b = (m, b) if cdf(m) < q else (a, m)
        return 0.5 * (a + b)


def _round_outward(x: float, automatic: bool, outward: float) -> float:
    """``x`` in JAX's default float type, moved one step towards ``outward`` where rounding
    went inwards and the bound is automatic."""
    dtype = np.dtype(jnp.asarray(0.0).dtype)
    r = np.asarray(x, dtype)
    if automatic and (r > x if outward < 0 else r < x):
        r = np.nextafter(r, np.asarray(outward, dtype))
    return float(r)


class Independent:
    """Independent parameters with numpyro distributions, each truncated to ``[low, high]``.

    A distribution with unbounded support is accepted as it is: an unbounded side of its box is
    set at a far quantile, ``tail`` (default :data:`TAIL` ``= 1e-9``) below or above, so that
    ``Independent(t=dist.Normal(1.0, 0.5))`` samples ``t`` from ``N(1, 0.5)`` truncated to its
    ``1e-9`` and ``1 - 1e-9`` quantiles, ``[-1.998, 3.998]``.

    Why truncation and not an unconstrained space: every algorithm perturbs particles with
    Gaussians truncated to the prior's box ``[low, high]``, divides importance weights by the
    prior's normalised log density, regularises covariances and scales the surrogate's
    coordinates by the box width, and reports results and prior-edge diagnostics in the
    parameters' own units; a far-quantile box keeps all of that as it is for every algorithm,
    where a transformed space would change each algorithm's kernels and weights.  The price is
    the mass left out, at most ``tail`` per unbounded side and reported per parameter as
    :attr:`tail_mass`: the prior used differs from the given one by a total variation of
    ``1 - prod(1 - tail_mass)`` (at most ``sum(tail_mass)``), and the posterior by its own mass
    outside the box, small unless the data pull the parameter into the prior's far tail; that
    shows as posterior mass piled at the bound, noted in ``diagnostics["prior_edge"]``
    (``at_physical_limits``).  These automatic bounds are marked as physical limits
    (:attr:`limits`): widening the box there would add at most ``tail`` of prior mass, so no
    :class:`jaxabc.PriorEdgeWarning` asks for it; so are the bounds of a support the
    distribution fixes (an Exponential's or LogNormal's 0, a Beta's 0 and 1), which no box can
    pass, unlike a Uniform's or LogUniform's, set by the arguments the user chose.  A heavy-tailed distribution (Cauchy,
    LogNormal with a large ``sigma``) gets a box many interquartile ranges wide, and a warning
    above :data:`WIDE_BOX` of them: give ``bounds`` there.

    Parameters
    ----------
    bounds : mapping of str to (float, float), optional
        Truncation box per parameter, intersected with the distribution's support; an infinite
        side (``(0.0, np.inf)``) is set at the far quantile like an unbounded support.
    units : mapping of str to str, optional
        Unit per parameter, for reports and plots.
    limits : mapping of str to (bool, bool), optional
        Per parameter, whether its lower and upper bounds are physical limits rather than
        choices, as in :class:`jaxabc.Uniform`; automatic far-quantile bounds and the bounds of a
        support fixed by the distribution (not set by its arguments) always are.
    tail : float
        Prior mass left out on each unbounded side, in (0, 0.1); default :data:`TAIL`.
    **distributions : numpyro.distributions.Distribution
        One univariate distribution per parameter, in the order of the parameter vector.

    Attributes
    ----------
    low, high : jax.Array, shape (d,)
        The box.
    limits : tuple of (bool, bool)
        Per parameter, whether each bound is a physical limit (see ``limits`` above).
    tail_mass : numpy.ndarray, shape (d,)
        Per parameter, the base distribution's mass outside the automatic bounds (0 for a
        parameter whose box is its support or the given ``bounds``); each at most
        ``2 * tail``.

    Raises
    ------
    ValueError
        A distribution is not univariate, a box is empty or outside the support, or holds no
        probability mass, or ``tail`` is outside (0, 0.1).
    TypeError
        A distribution lacks ``cdf`` (needed for truncation).

    Warns
    -----
    UserWarning
        An automatic box wider than :data:`WIDE_BOX` interquartile ranges.

    Examples
    --------
    >>> import numpyro.distributions as dist
    >>> prior = Independent(sigma=dist.Normal(0.3, 0.05), epsilon=dist.LogUniform(0.01, 1.0),
    ...                     bounds={"sigma": (0.1, 0.5)}, units={"sigma": "nm"})
    >>> prior.sample(jax.random.key(0), 4).shape
    (4, 2)
    >>> Independent(t=dist.Normal(1.0, 0.5)).tail_mass  # doctest: +SKIP
    array([2.e-09])
    """

    def __init__(
        self,
        bounds: Mapping[str, tuple[float, float]] | None = None,
        units: Mapping[str, str] | None = None,
        limits: Mapping[str, tuple[bool, bool]] | None = None,
        tail: float = TAIL,
        **distributions: Any,
    ) -> None:
        dist = _numpyro_distributions()
        if not distributions:
            raise ValueError(
                "give one numpyro distribution per parameter, e.g. Independent(sigma=dist.Normal(0.3, 0.05))"
            )
        tail = float(tail)
        if not 0.0 < tail < 0.1:
            raise ValueError(f"tail must be the prior mass left out per unbounded side, in (0, 0.1), got {tail!r}")
        bounds = dict(bounds or {})
        units = dict(units or {})
        user_limits = dict(limits or {})
        unknown = (set(bounds) | set(units) | set(user_limits)) - set(distributions)
        if unknown:
            raise ValueError(
                f"bounds/units/limits name unknown parameters {sorted(unknown)}; "
                f"the parameters are {list(distributions)}"
            )
        low, high, log_mass, tail_mass, flags, inverses, automatic = [], [], [], [], [], [], []
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
            lo, hi = bounds.get(name, (-np.inf, np.inf))
            lo, hi = max(float(lo), s_lo), min(float(hi), s_hi)
            if not lo < hi:
                raise ValueError(f"prior box for {name!r} is empty: [{lo}, {hi}] (within the support [{s_lo}, {s_hi}])")
            try:
                d.cdf(jnp.asarray(0.5 * (lo + hi) if np.isfinite(lo + hi) else 1.0))
            except (NotImplementedError, ImportError, AttributeError) as exc:
                raise TypeError(f"prior for {name!r}: {type(d).__name__} needs a cdf for truncation ({exc})") from None
            has_icdf = _has_icdf(d)
            auto = (not np.isfinite(lo), not np.isfinite(hi))
            # The support's own bound (an Exponential's 0, a Beta's 0 and 1) where the distribution
            # fixes it: the box cannot be widened there either.  A Uniform's or LogUniform's
            # support is set by its arguments, a box the user chose.
            fixed = _fixed_support(d)
            physical = (auto[0] or (fixed and lo == s_lo), auto[1] or (fixed and hi == s_hi))
            if auto[0]:
                lo = _quantile(d, tail, has_icdf, s_lo, s_hi)
            if auto[1]:
                hi = _quantile(d, 1.0 - tail, has_icdf, s_lo, s_hi)
            if not lo < hi:
                raise ValueError(
                    f"prior box for {name!r} is empty: [{lo:g}, {hi:g}], the given bound beyond the "
                    f"distribution's far quantile ({tail:g}); give both bounds"
                )
            # Round to the working precision, automatic sides outward: the box stored is the box
            # whose mass is computed, and it leaves out at most ``tail`` per side.
            lo, hi = _round_outward(lo, auto[0], -np.inf), _round_outward(hi, auto[1], np.inf)
            with jax.enable_x64(True):
                c_lo, c_hi = (float(d.cdf(jnp.asarray(x, jnp.float64))) for x in (lo, hi))
            mass = c_hi - c_lo
            if not mass > 0:
                raise ValueError(f"prior for {name!r} has no probability mass in [{lo}, {hi}]")
            if any(auto):
                self._warn_if_wide(name, d, lo, hi, has_icdf, s_lo, s_hi)
            given = tuple(bool(f) for f in user_limits.get(name, (False, False)))
            if len(given) != 2:
                raise ValueError(f"limits for {name!r} must be a (lower, upper) pair of flags, got {given}")
            low.append(lo)
            high.append(hi)
            log_mass.append(np.log(mass))
            tail_mass.append((c_lo if auto[0] else 0.0) + (1.0 - c_hi if auto[1] else 0.0))
            flags.append((given[0] or physical[0], given[1] or physical[1]))
            inverses.append(has_icdf)
            automatic.append(auto)
        self.distributions = dict(distributions)
        self.names = tuple(distributions)
        self.units = tuple(units.get(n, "") for n in self.names)
        self.low = jnp.asarray(low)
        self.high = jnp.asarray(high)
        self.limits = tuple(flags)
        self.tail = tail
        self.tail_mass = np.asarray(tail_mass, np.float64)
        self._has_icdf = tuple(inverses)
        self._automatic = tuple(automatic)
        self._log_mass = jnp.asarray(log_mass, self.low.dtype)

    @staticmethod
    def _warn_if_wide(name: str, d: Any, lo: float, hi: float, has_icdf: bool, s_lo: float, s_hi: float) -> None:
        iqr = _quantile(d, 0.75, has_icdf, s_lo, s_hi) - _quantile(d, 0.25, has_icdf, s_lo, s_hi)
        if iqr > 0 and (hi - lo) > WIDE_BOX * iqr:
            warnings.warn(
                f"the automatic box of {name!r} ({type(d).__name__}) is [{lo:.6g}, {hi:.6g}], "
                f"{(hi - lo) / iqr:.3g} interquartile ranges wide: the kernels' jitter and the "
                f"surrogate's coordinates scale with it; give bounds={{'{name}': (low, high)}} for a "
                "narrower one",
                UserWarning,
                stacklevel=3,
            )

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
            x = d.icdf(u) if self._has_icdf[j] else _bisect_icdf(d, u, lo, hi)
            columns.append(jnp.clip(x, lo, hi))
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
        out = {
            "type": "Independent",
            "distributions": dists,
            "names": list(self.names),
            "units": list(self.units),
            "low": np.asarray(self.low).tolist(),
            "high": np.asarray(self.high).tolist(),
        }
        # Absent for boxes the user gave in full: older files stay identical.
        if any(any(pair) for pair in self._automatic) or any(any(pair) for pair in self.limits):
            out["limits"] = [list(pair) for pair in self.limits]
            out["automatic"] = [list(pair) for pair in self._automatic]
            out["tail"] = self.tail
            out["tail_mass"] = self.tail_mass.tolist()
        return out

    @classmethod
    def from_dict(cls, data: dict) -> Independent:
        """Inverse of :meth:`to_dict` (numpyro distributions rebuilt by class name)."""
        dist = _numpyro_distributions()
        distributions = {}
        for name in data["names"]:
            spec = data["distributions"][name]
            distributions[name] = getattr(dist, spec["class"])(**spec["params"])
        names = data["names"]
        automatic = data.get("automatic") or [[False, False]] * len(names)
        # Automatic sides are recomputed from the distribution (and the stored tail).
        bounds = {
            n: (-np.inf if auto_lo else lo, np.inf if auto_hi else hi)
            for n, lo, hi, (auto_lo, auto_hi) in zip(names, data["low"], data["high"], automatic, strict=True)
        }
        units = dict(zip(names, data.get("units") or [""] * len(names), strict=True))
        limits = dict(zip(names, (tuple(p) for p in data["limits"]), strict=True)) if data.get("limits") else None
        return cls(bounds=bounds, units=units, limits=limits, tail=data.get("tail", TAIL), **distributions)

    def __repr__(self) -> str:
        parts = ", ".join(
            f"{n}~{type(d).__name__}[{float(lo):g}, {float(hi):g}]" + (f" (tail {m:.2g} left out)" if m > 0 else "")
            for (n, d), lo, hi, m in zip(self.distributions.items(), self.low, self.high, self.tail_mass, strict=True)
        )
        return f"Independent({parts})"


def prior_from_dict(data: dict) -> Any:
    """The prior a result file describes: :class:`jaxabc.Uniform` or :class:`Independent`."""
    if data.get("type") == "Independent":
        return Independent.from_dict(data)
    from jaxabc.priors.uniform import Uniform

    return Uniform.from_dict(data)
