"""The driver's input checks: fail early, in Python, with messages that say what to do."""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Callable, Iterator
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.distances import DISTANCES, get_distance
from jaxabc.errors import caller_stacklevel
from jaxabc.executors import Executor
from jaxabc.executors.workers import complex_summaries_message
from jaxabc.priors import Uniform

__all__ = [
    "SEED_LIMIT",
    "cast_prior",
    "check_distance_shape",
    "check_first_distances",
    "check_first_iteration_budget",
    "check_shape",
    "precision",
    "shapes_compatible",
    "validate_model",
    "validate_num_particles",
    "validate_observed",
    "validate_seed",
]

#: Seeds are integers in ``[0, SEED_LIMIT)``.  ``jax.random.key`` keeps only the low 32 bits
#: without ``jax_enable_x64`` (2**32 gives the key of 0) and all 64 with it, so a larger or
#: negative seed would name a different stream in float32 and float64 runs, or collide with
#: another seed; inside the range every seed is its own key, ``[0, seed]``, in both precisions.
SEED_LIMIT = 2**32


def validate_seed(seed: Any) -> int:
    """The run's seed as a Python ``int``, or a one-line error giving the accepted range.

    Parameters
    ----------
    seed : int or numpy.integer
        ``0 <= seed < 2**32``.  ``bool``, floats, strings and ``None`` are refused rather than
        converted: ``seed=1.5`` or ``seed="0"`` is a mistake to report, not to guess at.

    Returns
    -------
    int
        The same value; ``jax.random.key`` maps it to the key it always did.

    Raises
    ------
    TypeError
        ``seed`` is not an integer.
    ValueError
        ``seed`` is outside ``[0, 2**32)``.
    """
    accepted = "seed must be an integer with 0 <= seed < 2**32"
    if isinstance(seed, bool | np.bool_) or not isinstance(seed, int | np.integer):
        raise TypeError(f"{accepted}, got {seed!r} of type {type(seed).__name__}")
    if not 0 <= int(seed) < SEED_LIMIT:
        raise ValueError(f"{accepted}, got {int(seed)}")
    return int(seed)


def validate_observed(observed: Any, dtype: str = "float64", distance: Any = None) -> np.ndarray:
    """The observed data as float64, refused when no run in ``dtype`` could use it.

    Parameters
    ----------
    observed : array_like
    dtype : {"float32", "float64"}
        The run's working precision: a value beyond its range would become ``inf`` there, and
        every distance with it, which looks like a failing simulator.
    distance : str or callable, optional
        A distance with a ``check_observed(observed)`` attribute (``"kl"``) checks that it can
        compare anything with this data.

    Raises
    ------
    ValueError
        Empty, non-numeric or non-finite data, a value beyond ``dtype``'s range, or data the
        distance cannot use.
    """
    try:
        obs = np.asarray(observed, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"observed data must be a numeric array: {exc}") from None
    if obs.size == 0:
        raise ValueError("observed data is empty: pass the measured summary vector or series")
    bad = ~np.isfinite(obs)
    if np.any(bad):
        raise ValueError(
            f"observed data contains {int(bad.sum())} NaN or infinite values (first at flat "
            f"index {int(np.flatnonzero(bad.ravel())[0])}): clean or drop them before calibrating"
        )
    limit = float(np.finfo(np.dtype(dtype)).max)
    over = np.abs(obs) > limit
    if np.any(over):
        first = int(np.flatnonzero(over.ravel())[0])
        raise ValueError(
            f"observed value {obs.ravel()[first]:.4g} (flat index {first}) overflows {dtype} "
            f"(largest {limit:.4g}): run with dtype='float64', or rescale the summaries (and the "
            "simulator's output) to a smaller unit"
        )
    fn = DISTANCES.get(distance) if isinstance(distance, str) else distance
    check = getattr(fn, "check_observed", None)
    if check is not None:
        check(obs)
    return obs


def check_first_distances(distances: np.ndarray) -> None:
    """Refuse a distance that cannot be one; warn when it cannot tell parameters apart.

    Called on the distances of the first population (prior draws, so they span what the
    distance will see).  Failed simulations (``inf``) are ignored.

    Raises
    ------
    ValueError
        A negative distance: thresholds would go below zero and "closer than an exact match"
        would win (typically ``observed - simulated`` without ``abs``).

    Warns
    -----
    UserWarning
        Every distance is the same value: the posterior will be the prior.  Not an error,
        because that is the right answer for a simulator that ignores its parameters or a
        summary they do not move; but it is also what a distance that ignores its input gives.
    """
    d = np.asarray(distances, np.float64)
    d = d[np.isfinite(d)]
    if d.size == 0:
        return
    low = float(d.min())
    if low < 0.0:
        raise ValueError(
            f"the distance returned negative values (min {low:.4g}, {int(np.sum(d < 0))} of {d.size} "
            "simulations of the first population): a distance must be >= 0, with 0 for a perfect "
            "match; wrap it in abs() or a norm"
        )
    if d.size > 1 and low == float(d.max()):
        warnings.warn(
            f"all {d.size} distances of the first population equal {low:.6g}: the distance does not "
            "tell the parameters apart, so the posterior will be the prior. Expected if the "
            "simulator ignores its parameters; otherwise check that the distance depends on the "
            "simulated summaries",
            UserWarning,
            stacklevel=caller_stacklevel(),
        )


def validate_num_particles(num_particles: Any, required: bool = False) -> int | None:
    """``num_particles`` as an ``int``; None when it is not given and not ``required``.

    Raises
    ------
    ValueError
        Not a positive integer.
    """
    if num_particles is None and not required:
        return None
    if not isinstance(num_particles, int | np.integer) or num_particles < 1:
        raise ValueError(f"num_particles must be a positive integer, got {num_particles!r}")
    return int(num_particles)


def validate_model(simulate: Any, prior: Any) -> None:
    """Refuse a simulator that is not callable or a prior that is not a jaxabc prior (``TypeError``)."""
    if not callable(simulate):
        raise TypeError("simulate must be a callable simulate(key, theta) -> summaries")
    if not hasattr(prior, "sample") or not hasattr(prior, "low"):
        raise TypeError("prior must be a jaxabc prior such as jaxabc.Uniform(low, high, names)")


def cast_prior(prior: Uniform, dtype: Any) -> Uniform:
    if not isinstance(prior, Uniform):
        return prior
    out = Uniform.__new__(Uniform)
    out.__dict__.update(prior.__dict__)
    out.low, out.high = jnp.asarray(prior.low, dtype), jnp.asarray(prior.high, dtype)
    return out


def shapes_compatible(simulated: tuple, observed: tuple, distance: Any) -> bool:
    if getattr(get_distance(distance), "compares_samples", False):
        return len(simulated) == len(observed) == 1
    return tuple(simulated) == tuple(observed)


def check_shape(executor: Executor, simulate: Callable, prior: Uniform, observed: np.ndarray, distance: Any) -> None:
    """Fail early, with a clear message, when a JAX simulator's output shape is wrong."""
    if executor.name != "vmap" or hasattr(simulate, "simulate_batch"):
        return
    check_traced_shape(simulate, prior, observed, distance, prior.low.dtype, "A vmap executor")


def check_traced_shape(
    simulate: Callable, prior: Uniform, observed: np.ndarray, distance: Any, dtype: Any, who: str
) -> None:
    """Trace ``simulate`` once (no compilation) and compare its output shape with ``observed``.

    ``who`` names what needs a traceable simulator, for the error message.
    """
    try:
        out = jax.eval_shape(simulate, jax.random.key(0), jnp.zeros((prior.dim,), dtype))
    except Exception as exc:
        raise TypeError(
            f"could not trace simulate(key, theta) with theta of shape ({prior.dim},): {exc}. "
            f"{who} needs a JAX-traceable simulator; use jaxabc.run with executor='serial' or "
            "'process_pool' for other code"
        ) from exc
    if not hasattr(out, "shape"):  # None, a tuple, a dict: not one array
        name = f"{getattr(simulate, '__module__', '?')}:{getattr(simulate, '__qualname__', type(simulate).__name__)}"
        got = "None" if out is None else f"a {type(out).__name__}"
        raise TypeError(
            f"the simulator {name} returned {got}: simulate(key, theta) must return an array of summaries "
            f"of shape {observed.shape} (check that it ends with a return statement)"
        )
    if not shapes_compatible(tuple(out.shape), observed.shape, distance):
        raise ValueError(
            f"the simulator returns summaries of shape {tuple(out.shape)} but the observed data "
            f"has shape {observed.shape}: they must match"
        )
    if jnp.issubdtype(out.dtype, jnp.complexfloating):
        raise TypeError(complex_summaries_message(out.dtype))
    try:
        d = jax.eval_shape(get_distance(distance), jax.ShapeDtypeStruct(observed.shape, dtype), out)
    except Exception:
        return  # the run itself reports a distance that fails on these shapes
    check_distance_shape(getattr(d, "shape", None))


def check_distance_shape(shape: Any) -> None:
    """Refuse a distance that returns anything but one number per simulation.

    Parameters
    ----------
    shape : tuple or None
        The shape of one ``distance(observed, simulated)`` value.

    Raises
    ------
    ValueError
        ``shape`` is not ``()``: typically a per-summary ``jnp.abs(observed - simulated)``
        that was never reduced, which otherwise fails deep inside the algorithm.
    """
    if shape is not None and tuple(shape) != ():
        raise ValueError(
            f"the distance must return one number per simulation, but it returned shape "
            f"{tuple(shape)}: reduce it to a scalar, e.g. with jnp.sum, jnp.mean or a norm"
        )


@contextlib.contextmanager
def precision(dtype: str) -> Iterator[None]:
    """Double precision for this run only: the process-wide flag is restored afterwards."""
    if dtype == "float64":
        with jax.enable_x64(True):
            yield
    else:
        yield


def check_first_iteration_budget(first: int, max_simulations: int | None, name: str) -> None:
    """Refuse a budget below the first iteration's simulations, which always run in full.

    Raises
    ------
    ValueError
        ``max_simulations`` is smaller than ``first``, the simulations of the first iteration
        (the initial prior sample); the message names both.
    """
    if max_simulations is not None and first > max_simulations:
        raise ValueError(
            f"max_simulations={max_simulations} is below the {first} simulations of {name}'s first "
            f"iteration (its initial sample from the prior), which runs in full: raise "
            f"max_simulations to at least {first}, or lower num_particles"
        )
