"""The driver's input checks: fail early, in Python, with messages that say what to do."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.algorithms.base import ABCAlgorithm
from jaxabc.distances import get_distance
from jaxabc.executors import Executor
from jaxabc.priors import Uniform

__all__ = [
    "cast_prior",
    "check_shape",
    "check_stopping_rule",
    "precision",
    "shapes_compatible",
    "validate_arguments",
    "validate_observed",
]


def validate_observed(observed: Any) -> np.ndarray:
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
    return obs


def validate_arguments(
    dtype: str, num_particles: Any, num_steps: int | None, max_failure_fraction: float, simulate: Any, prior: Any
) -> None:
    if dtype not in ("float32", "float64"):
        raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype!r}")
    if num_particles is not None and (not isinstance(num_particles, int | np.integer) or num_particles < 1):
        raise ValueError(f"num_particles must be a positive integer, got {num_particles!r}")
    if num_steps is not None and num_steps < 1:
        raise ValueError(f"num_steps must be at least 1, got {num_steps}")
    if not 0.0 < max_failure_fraction <= 1.0:
        raise ValueError(f"max_failure_fraction must lie in (0, 1], got {max_failure_fraction}")
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
    if not shapes_compatible(tuple(out.shape), observed.shape, distance):
        raise ValueError(
            f"the simulator returns summaries of shape {tuple(out.shape)} but the observed data "
            f"has shape {observed.shape}: they must match"
        )


def check_stopping_rule(algo: ABCAlgorithm, *rules: Any) -> None:
    if algo.needs_stopping_rule and all(rule is None for rule in rules):
        raise ValueError(
            f"{algo.name} with these settings may never stop by itself: give num_steps, "
            "final_threshold, max_simulations or max_wall_time (it needs a stopping rule)"
        )


@contextlib.contextmanager
def precision(dtype: str) -> Iterator[None]:
    """Double precision for this run only: the process-wide flag is restored afterwards."""
    if dtype == "float64":
        with jax.enable_x64(True):
            yield
    else:
        yield
