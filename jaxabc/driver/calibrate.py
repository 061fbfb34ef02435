"""One calibration, as :func:`jaxabc.run` runs it: the problem checked, the algorithm built, and
the driver chosen (the compiled loop of :mod:`.fused` or the host loop of :mod:`.host`)."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc import algorithms, checkpoint
from jaxabc.algorithms.base import ABCAlgorithm
from jaxabc.distances import AdaptivePNorm, as_adaptive, get_distance, is_adaptive
from jaxabc.driver.checks import (
    cast_prior,
    precision,
    shapes_compatible,
    validate_model,
    validate_num_particles,
    validate_observed,
)
from jaxabc.driver.context import (
    Compiled,
    Problem,
    builder_accepts,
    builder_passes_on,
    compile_algorithm,
    with_run_values,
)
from jaxabc.driver.fused import DRIVER as FUSED_DRIVER
from jaxabc.driver.fused import run_compiled
from jaxabc.driver.host import run_host
from jaxabc.driver.options import RunOptions
from jaxabc.noise import Discrepancy, ResolvedDiscrepancy, observation_covariance, wrap_for_abc
from jaxabc.results import ABCResult

__all__ = ["ABC_ALGORITHMS", "calibrate"]

#: The ABC algorithms: measurement error and discrepancy enter them through the simulator and
#: the prior (noisy ABC).  Other builders (the surrogate) take them as builder options.
ABC_ALGORITHMS = ("apmcabc", "pmcabc", "abcsubsim", "rejection")


def calibrate(
    algorithm: str | ABCAlgorithm,
    simulate: Callable,
    prior: Any,
    observed: Any,
    num_particles: int | None,
    distance: Any,
    options: RunOptions,
    *,
    observation_error: Any = None,
    discrepancy: Discrepancy | None = None,
    algorithm_options: dict | None = None,
) -> ABCResult:
    """Calibrate ``simulate`` against ``observed``: :func:`jaxabc.run` for one model.

    The arguments are :func:`jaxabc.run`'s, its run options in ``options`` and its
    ``**algorithm_options`` in ``algorithm_options``; it returns and raises what
    :func:`jaxabc.run` does for one model.
    """
    t_start = time.perf_counter()
    num_particles = validate_num_particles(num_particles)
    validate_model(simulate, prior)
    obs = validate_observed(observed, options.execution.dtype, distance)
    builder_options = dict(algorithm_options or {})
    # Noisy ABC and discrepancy: a wrapped simulator and an augmented prior (or builder options).
    simulate, prior, measured = _measured_data(
        algorithm, simulate, prior, obs, observation_error, discrepancy, builder_options
    )
    if isinstance(distance, AdaptivePNorm) or is_adaptive(distance):
        # The algorithm computes the adaptive distances; the driver records a fixed one.
        distance = _adaptive_setup(distance, algorithm, obs, builder_options)
    with precision(options.execution.dtype):
        prior = cast_prior(prior, options.execution.jdtype)
        compiled = _compiled(algorithm, prior, num_particles, obs, options, builder_options, measured)
        options.stopping.check_algorithm(compiled.algorithm)
        problem = Problem(simulate, prior, obs, distance, num_particles)
        if options.execution.executor is None and _fused_applies(compiled.algorithm, problem, options):
            return run_compiled(compiled.algorithm, problem, options)
        return run_host(compiled, problem, options, t_start)


def _compiled(
    algorithm: str | ABCAlgorithm,
    prior: Any,
    num_particles: int | None,
    observed: np.ndarray,
    options: RunOptions,
    builder_options: dict,
    measured: dict,
) -> Compiled:
    """The algorithm, built with the run's values it takes, and its settings holding ``measured``."""
    builder_options = with_run_values(algorithm, builder_options, options.stopping, observed)
    compiled = compile_algorithm(algorithm, prior, num_particles, builder_options, options.execution.dtype)
    if not measured:
        return compiled
    # In the settings, so that results record them and a resume with others is refused (the
    # checkpoint fingerprint holds the settings), on the fused and the host driver.
    extra = {k: v for k, v in measured.items() if k not in compiled.algorithm.settings}
    settings = {**compiled.algorithm.settings, **extra}
    return compiled._replace(algorithm=compiled.algorithm._replace(settings=settings))


def _fused_applies(algo: ABCAlgorithm, problem: Problem, options: RunOptions) -> bool:
    """Whether the whole calibration can run as compiled programs (:func:`~.fused.run_compiled`):
    a JAX algorithm, and a simulator and distance JAX can trace.  A resumed run stays on the
    driver that wrote its checkpoint."""
    if algo.host or algo.uses_summaries or problem.num_particles is None:
        return False
    folder = options.checkpointing.folder
    if options.checkpointing.resume and folder is not None and (Path(folder) / checkpoint.CHECKPOINT_NAME).exists():
        try:
            stored = checkpoint.load(Path(folder) / checkpoint.CHECKPOINT_NAME).fingerprint
        except checkpoint.CheckpointError:
            return False  # the host driver reports it
        return stored.get("driver") == FUSED_DRIVER
    jdtype = options.execution.jdtype
    try:
        out = jax.eval_shape(problem.simulate, jax.random.key(0), jnp.zeros((problem.prior.dim,), jdtype))
        jax.eval_shape(get_distance(problem.distance), jnp.zeros(problem.observed.shape, jdtype), out)
    except Exception:
        # Not traceable (NumPy, an external program, Python control flow on values): this is a
        # probe, and the host driver gives such simulators their own clear errors.
        return False
    return shapes_compatible(tuple(out.shape), problem.observed.shape, problem.distance)


def _adaptive_setup(distance: Any, algorithm: Any, obs: np.ndarray, options: dict) -> Callable:
    """Hand the bound adaptive norm to the algorithm (into ``options``); return the distance
    the driver records."""
    spec = as_adaptive(distance, obs)
    if isinstance(algorithm, ABCAlgorithm):
        if "adaptive_distance" not in algorithm.settings:
            raise ValueError(
                f"distance='adaptive' is computed by the algorithm, but this {algorithm.name} "
                "object was built without adaptive_distance=: build it with "
                "adaptive_distance=AdaptivePNorm().bind(observed), or pass its name"
            )
    elif builder_accepts(algorithm, "adaptive_distance"):
        options["adaptive_distance"] = spec
    else:
        raise ValueError(
            f"distance='adaptive' works with the SMC algorithms 'apmcabc' and 'pmcabc', not "
            f"{algorithm!r}: choose one of them or a fixed distance"
        )
    return spec.record_distance()


def _takes_measured(name: str, option: str) -> bool:
    """Whether the builder ``name`` takes ``option``: it names it, or passes its keywords on
    (``**options``, as the surrogate's to :func:`jaxabc.surrogate.build`)."""
    return builder_accepts(name, option) or builder_passes_on(name)


def _measured_data(
    algorithm: str | ABCAlgorithm,
    simulate: Callable,
    prior: Any,
    obs: np.ndarray,
    observation_error: Any,
    discrepancy: Any,
    options: dict,
) -> tuple[Callable, Any, dict]:
    """Apply ``observation_error`` and ``discrepancy`` to a calibration.

    Returns the simulator and prior the algorithm runs with (wrapped and augmented for the ABC
    algorithms; unchanged for other builders, which get them in ``options``) and the settings
    to record, JSON-normal, for the result and the checkpoint fingerprint.
    """
    if observation_error is None and discrepancy is None:
        return simulate, prior, {}
    cov = None if observation_error is None else observation_covariance(observation_error, obs.shape)
    if discrepancy is not None and not isinstance(discrepancy, Discrepancy):
        raise TypeError(f"discrepancy must be a jaxabc.Discrepancy(max_sd, groups), got {type(discrepancy).__name__}")
    resolved: ResolvedDiscrepancy | None = None if discrepancy is None else discrepancy.resolve(obs.shape)
    settings: dict[str, Any] = {}
    if cov is not None:
        settings["observation_error"] = cov.tolist()
    if discrepancy is not None:
        settings["discrepancy"] = discrepancy.describe()
    name = algorithm if isinstance(algorithm, str) else algorithm.name
    if isinstance(algorithm, str) and name not in ABC_ALGORITHMS and name in algorithms.BUILDERS:
        # Not an ABC algorithm (the surrogate): it models the error in its likelihood.
        for option, value in (("observation_error", cov), ("discrepancy", resolved)):
            if value is None:
                continue
            if not _takes_measured(name, option):
                raise ValueError(
                    f"the {name} in this version does not take {option}: run an ABC algorithm "
                    f"({', '.join(ABC_ALGORITHMS)}) with it, or leave it out"
                )
            options[option] = value
        return simulate, prior, settings
    if isinstance(algorithm, ABCAlgorithm) and name not in ABC_ALGORITHMS:
        raise ValueError(
            f"observation_error and discrepancy reach an algorithm object {name!r} only through its "
            "builder: pass the algorithm by name, or give them to the function that built it"
        )
    simulate, augmented = wrap_for_abc(simulate, prior, obs.shape, cov, resolved)
    if isinstance(algorithm, ABCAlgorithm) and resolved is not None:
        dim = jax.eval_shape(algorithm.initial_proposal, jax.random.key(0)).thetas.shape[-1]
        if dim != augmented.dim:
            raise ValueError(
                f"with a discrepancy the run has {augmented.dim} parameters ({prior.dim} of the model, "
                f"{len(resolved.names)} discrepancy sds), but this {name} object was built for {dim}: "
                "pass the algorithm by name, or build it with the prior of jaxabc.noise.wrap_for_abc"
            )
    return simulate, augmented, settings
