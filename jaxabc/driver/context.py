"""The driver's parts: the problem, compiled-algorithm cache, distances, executors, the
simulation record.

:func:`jaxabc.driver.calibrate.calibrate` assembles these; nothing here knows an algorithm by
name.
"""

from __future__ import annotations

import collections
import contextlib
import inspect
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple, cast

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc import algorithms as _algorithms
from jaxabc import checkpoint
from jaxabc.algorithms.base import ABCAlgorithm
from jaxabc.distances import get_distance
from jaxabc.driver.checks import check_distance_shape
from jaxabc.driver.options import RunOptions, Stopping
from jaxabc.errors import STATUS_BAD_DISTANCE, STATUS_NAMES, STATUS_OK
from jaxabc.executors import Executor, VmapExecutor, get_executor

__all__ = [
    "Compiled",
    "Context",
    "Problem",
    "Progress",
    "Recorder",
    "SharedVmapExecutor",
    "compile_algorithm",
    "make_distance_fn",
    "open_executor",
    "posterior_distances",
    "with_run_values",
]

_CACHE_SIZE = 32
_compiled_cache: collections.OrderedDict[Any, Compiled] = collections.OrderedDict()
_distance_cache: collections.OrderedDict[Any, Callable] = collections.OrderedDict()
_simulator_cache: collections.OrderedDict[Any, Callable] = collections.OrderedDict()


class Compiled(NamedTuple):
    """An algorithm with its functions wrapped by ``jax.jit`` (or not, for host algorithms)."""

    algorithm: ABCAlgorithm
    initial_proposal: Callable
    init: Callable
    propose: Callable
    update: Callable
    posterior: Callable


def _freeze(value: Any) -> Any:
    """A hashable stand-in for an option value (lists and dicts become tuples)."""
    if isinstance(value, dict):
        return tuple(sorted((k, _freeze(v)) for k, v in value.items()))
    if isinstance(value, list | tuple):
        return tuple(_freeze(v) for v in value)
    if isinstance(value, np.ndarray | jax.Array):
        return ("array", np.asarray(value).dtype.str, np.asarray(value).shape, np.asarray(value).tobytes())
    hash(value)  # raises TypeError for an unhashable option: then the call is not cached
    return value


def _prior_key(prior: Any) -> Any:
    return (
        type(prior),
        np.asarray(prior.low).tobytes(),
        np.asarray(prior.high).tobytes(),
        np.asarray(prior.low).dtype.str,
        tuple(getattr(prior, "names", ())),
    )


def _wrap(algo: ABCAlgorithm) -> Compiled:
    jit = (lambda f: f) if algo.host else jax.jit
    return Compiled(
        algo, jit(algo.initial_proposal), jit(algo.init), jit(algo.propose), jit(algo.update), jit(algo.posterior)
    )


def _remember(cache: collections.OrderedDict, key: Any, value: Any) -> Any:
    cache[key] = value
    cache.move_to_end(key)
    while len(cache) > _CACHE_SIZE:
        cache.popitem(last=False)
    return value


def build_by_name(name: str, prior: Any, num_particles: int | None, options: dict) -> ABCAlgorithm:
    """``BUILDERS[name](prior, num_particles, **options)`` with clear errors."""
    try:
        builder = _algorithms.BUILDERS[name]
    except KeyError:
        raise ValueError(f"unknown algorithm {name!r}: use one of {sorted(_algorithms.BUILDERS)}") from None
    params = inspect.signature(builder).parameters
    if num_particles is None:
        slot = params.get("num_particles")
        if slot is None or slot.default is inspect.Parameter.empty:
            raise TypeError(f"{name!r} needs num_particles= (the population size)")
        num_particles = cast(int, slot.default)
    try:
        return builder(prior, int(num_particles), **options)
    except TypeError as exc:
        raise TypeError(f"bad option for {name!r}: {exc}") from None


def builder_accepts(name: str, option: str) -> bool:
    """Whether the registered builder ``name`` names the keyword ``option`` among its parameters."""
    builder = _algorithms.BUILDERS.get(name)
    return builder is not None and option in inspect.signature(builder).parameters


def builder_passes_on(name: str) -> bool:
    """Whether the registered builder ``name`` takes any keyword (``**options``) to pass on."""
    builder = _algorithms.BUILDERS.get(name)
    return builder is not None and any(
        p.kind is inspect.Parameter.VAR_KEYWORD for p in inspect.signature(builder).parameters.values()
    )


#: The run's own values that a builder receives when it names them among its parameters: the
#: surrogate designs within ``max_simulations`` and fits ``observed``; ABCsubsim ends its levels
#: at ``final_threshold``.
RUN_VALUES = ("final_threshold", "observed", "max_simulations")


def with_run_values(name: Any, options: dict, stopping: Stopping, observed: np.ndarray) -> dict:
    """The keywords of the builder ``name``: ``options``, and each of :data:`RUN_VALUES` that is
    given and that the builder names (they are :func:`jaxabc.run`'s own arguments, so never
    among ``options``)."""
    if not isinstance(name, str):
        return dict(options)
    values = {
        "final_threshold": stopping.final_threshold,
        "observed": observed,
        "max_simulations": stopping.max_simulations,
    }
    return {**options, **{k: v for k, v in values.items() if v is not None and builder_accepts(name, k)}}


def compile_algorithm(
    algorithm: str | ABCAlgorithm, prior: Any, num_particles: int | None, options: dict, dtype: str
) -> Compiled:
    """The algorithm and its jitted functions, reused across calls with the same configuration.

    A name is built from :data:`jaxabc.algorithms.BUILDERS` and cached on (name, options, prior
    class, bounds and names, ``num_particles``, dtype): the builders close over the prior's
    bounds, so they are part of the key.  An algorithm object is cached on its functions'
    identities, so passing the same object again reuses its compiled code too.
    """
    if isinstance(algorithm, ABCAlgorithm):
        if options:
            raise TypeError(
                f"options {sorted(options)} cannot be applied to an algorithm object: give them "
                "to the function that built it"
            )
        key: Any = ("object", *algorithm[:6], algorithm.host, dtype)
        hit = _compiled_cache.get(key)
        if hit is not None and hit.algorithm.settings == algorithm.settings:
            _compiled_cache.move_to_end(key)
            return hit
        return _remember(_compiled_cache, key, _wrap(algorithm))
    if not isinstance(algorithm, str):
        raise TypeError(
            f"algorithm must be a name ({sorted(_algorithms.BUILDERS)}) or an ABCAlgorithm, got "
            f"{type(algorithm).__name__}"
        )
    try:
        key = ("name", algorithm, _freeze(options), _prior_key(prior), num_particles, dtype)
    except TypeError:
        return _wrap(build_by_name(algorithm, prior, num_particles, options))
    hit = _compiled_cache.get(key)
    if hit is not None:
        _compiled_cache.move_to_end(key)
        return hit
    return _remember(_compiled_cache, key, _wrap(build_by_name(algorithm, prior, num_particles, options)))


def make_distance_fn(distance: Any, observed: np.ndarray, dtype: Any) -> Callable:
    """``compute(summaries, ok) -> (distances (m,), bad (m,))`` on the host.

    Failed slots (``ok`` False) get ``+inf``.  ``bad`` marks successful simulations whose
    distance is NaN or ``-inf``: the driver records them as failures.  The vmapped distance is
    jitted once per (distance, dtype) with the observed data as an argument, so a new observed
    vector does not recompile it.
    """
    dist = get_distance(distance)
    try:
        key: Any = (dist, jnp.dtype(dtype).name)
        batched = _distance_cache.get(key)
    except TypeError:
        key, batched = None, None
    if batched is None:
        batched = jax.jit(jax.vmap(dist, in_axes=(None, 0)))
        if key is not None:
            _remember(_distance_cache, key, batched)
    obs = jnp.asarray(observed, dtype)

    def compute(summaries: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        out = np.full(summaries.shape[0], np.inf)
        bad = np.zeros(summaries.shape[0], bool)
        good = summaries[ok]
        if good.shape[0]:
            # Pad to a power of two so that varying batch sizes reuse a few compiled shapes.
            size = max(64, 1 << (good.shape[0] - 1).bit_length())
            padded = np.concatenate([good, np.repeat(good[:1], size - good.shape[0], axis=0)])
            d = np.asarray(batched(obs, jnp.asarray(padded, dtype)), np.float64)[: good.shape[0]]
            check_distance_shape(d.shape[1:])
            invalid = np.isnan(d) | (d == -np.inf)
            out[ok] = np.where(invalid, np.inf, d)
            bad[ok] = invalid
        return out, bad

    return compute


class SharedVmapExecutor(VmapExecutor):
    """The default executor: a :class:`VmapExecutor` whose compiled ``jit(vmap(simulate))``
    outlives the run, keyed on the simulator object itself (held, so its id cannot be reused),
    so a second run with the same simulator does not recompile it."""

    def _batched(self, simulate: Callable) -> Callable:
        if hasattr(simulate, "simulate_batch"):
            return super()._batched(simulate)
        try:
            fn = _simulator_cache.get(simulate)
        except TypeError:  # an unhashable callable object: compile per run
            return super()._batched(simulate)
        if fn is None:
            fn = _remember(_simulator_cache, simulate, jax.jit(jax.vmap(simulate)))
        else:
            _simulator_cache.move_to_end(simulate)
        return fn


class Recorder:
    """Accumulates the record of every simulation, one chunk per iteration."""

    def __init__(self, keep_summaries: bool):
        self.keep_summaries = keep_summaries
        self.chunks: list[dict[str, Any]] = []

    def add(
        self,
        iteration: int,
        thetas: np.ndarray,
        batch: Any,
        distances: np.ndarray,
        status: np.ndarray,
        reasons: list[str],
    ) -> None:
        """Record one batch; ``status`` and ``reasons`` override the executor's."""
        self.chunks.append(
            {
                "theta": np.asarray(thetas, np.float64),
                "summaries": np.asarray(batch.summaries) if self.keep_summaries else None,
                "distance": np.asarray(distances, np.float64),
                "status": np.asarray(status, np.int32),
                "wall_time": np.asarray(batch.wall_time, np.float64),
                "cpu_time": (
                    np.full(len(distances), np.nan)
                    if batch.cpu_time is None
                    else np.asarray(batch.cpu_time, np.float64)
                ),
                "worker": np.asarray(batch.worker, np.int32),
                "iteration": np.full(len(distances), iteration, np.int32),
                "reasons": list(reasons),
            }
        )

    def arrays(self) -> dict[str, Any]:
        """The record as concatenated arrays (``summaries`` only when all shapes agree)."""
        if not self.chunks:
            return {}
        out: dict[str, Any] = {}
        for key in ("theta", "distance", "status", "wall_time", "cpu_time", "worker", "iteration"):
            out[key] = np.concatenate([c[key] for c in self.chunks])
        if self.keep_summaries:
            shapes = {c["summaries"].shape[1:] for c in self.chunks}
            if len(shapes) == 1:
                out["summaries"] = np.concatenate([c["summaries"] for c in self.chunks])
        out["reasons"] = [r for c in self.chunks for r in c["reasons"]]
        return out

    def failures(self) -> tuple[int, int, list[str]]:
        """``(total, failed, up to five examples)`` over every simulation so far."""
        total = sum(len(c["distance"]) for c in self.chunks)
        failed = sum(int(np.sum(c["status"] != STATUS_OK)) for c in self.chunks)
        examples: list[str] = []
        for c in self.chunks:
            for i in np.flatnonzero(c["status"] != STATUS_OK)[: 5 - len(examples)]:
                status = STATUS_NAMES.get(int(c["status"][i]), int(c["status"][i]))
                examples.append(f"theta={np.array2string(c['theta'][i], precision=4)}: {status}: {c['reasons'][i]}")
            if len(examples) >= 5:
                break
        return total, failed, examples


BAD_DISTANCE_REASON = (
    "the distance to the observed data was NaN or -inf for finite summaries "
    "(e.g. a KL distance of samples with no spread)"
)


def mark_bad_distances(
    status: np.ndarray, reasons: list[str], bad: np.ndarray, distances: np.ndarray
) -> tuple[np.ndarray, list[str]]:
    """Status and reasons with successful simulations of NaN / ``-inf`` distance marked failed."""
    if not np.any(bad):
        return status, reasons
    status = np.where(bad, STATUS_BAD_DISTANCE, status)
    reasons = list(reasons)
    for i in np.flatnonzero(bad):
        reasons[i] = BAD_DISTANCE_REASON
    return status, reasons


@dataclass
class Progress:
    """What changes from iteration to iteration (and what a checkpoint stores)."""

    recorder: Recorder
    state: Any = None
    iteration: int = 0
    num_sims: int = 0
    sims_this_generation: int = 0
    last_posterior: tuple | None = None
    stop_reason: str = ""
    history: dict[str, list] = field(
        default_factory=lambda: {"threshold": [], "sims": [], "acceptance": [], "ess": [], "wall": []}
    )


@dataclass(frozen=True)
class Problem:
    """A calibration problem, checked and in the run's precision.

    Attributes
    ----------
    simulate : callable
        ``simulate(key, theta) -> summaries`` (wrapped for noisy ABC where asked).
    prior : Uniform or Independent
        In the run's dtype (with the discrepancy parameters where asked).
    observed : numpy.ndarray
        float64.
    distance : str or callable
        The distance the driver computes and records.
    num_particles : int or None
    """

    simulate: Callable
    prior: Any
    observed: np.ndarray
    distance: Any
    num_particles: int | None

    def fingerprint(self, algorithm: ABCAlgorithm, options: RunOptions) -> dict:
        """The problem's identity in a checkpoint (:func:`jaxabc.checkpoint.fingerprint`)."""
        return checkpoint.fingerprint(
            algorithm=algorithm.name,
            settings=algorithm.settings,
            prior=self.prior,
            observed=self.observed,
            distance=self.distance,
            simulator_id=checkpoint.simulator_identity(self.simulate, options.checkpointing.simulator_id),
            seed=options.seed,
            num_particles=self.num_particles,
            dtype=options.execution.dtype,
        )


@contextlib.contextmanager
def open_executor(executor: Any, observed: np.ndarray, distance: Any) -> Iterator[Executor]:
    """The run's executor: the shared vmap executor for None or ``"vmap"``, a new one for
    another name (closed on exit), or the executor object given (left open)."""
    own = not hasattr(executor, "map")
    ex = SharedVmapExecutor() if executor in (None, "vmap") else get_executor(executor)
    try:
        if hasattr(ex, "summary_shape") and not getattr(get_distance(distance), "compares_samples", False):
            # A batch where every task fails keeps it (not on the Executor protocol).
            cast(Any, ex).summary_shape = tuple(observed.shape)
        yield ex
    finally:
        if own:
            ex.close()


@dataclass
class Context:
    """What stays fixed during a run of the host driver; built by :meth:`create`."""

    compiled: Compiled
    problem: Problem
    options: RunOptions
    executor: Executor
    distances_of: Callable
    root: jax.Array
    t_start: float
    ckpt_path: Path | None
    fingerprint: dict
    bar: Any = None

    @classmethod
    def create(
        cls,
        compiled: Compiled,
        problem: Problem,
        options: RunOptions,
        executor: Executor,
        ckpt_path: Path | None,
        t_start: float,
    ) -> Context:
        """The context of a run; call it in the run's precision (:func:`~.checks.precision`)."""
        return cls(
            compiled=compiled,
            problem=problem,
            options=options,
            executor=executor,
            distances_of=make_distance_fn(problem.distance, problem.observed, options.execution.jdtype),
            root=jax.random.key(options.seed),
            t_start=t_start,
            ckpt_path=ckpt_path,
            fingerprint=problem.fingerprint(compiled.algorithm, options),
        )


def posterior_distances(state: Any, n: int) -> np.ndarray:
    # The built-in states keep their distances aligned with their posterior particles.
    d = getattr(state, "distances", None)
    return np.full(n, np.nan) if d is None or np.shape(d) != (n,) else np.asarray(d)
