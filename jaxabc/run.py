"""The public entry point :func:`run`: one calibration, or model choice for a list of models.

Its run options become one :class:`~jaxabc.driver.options.RunOptions`; a calibration then goes to
:func:`jaxabc.driver.calibrate.calibrate` (the compiled loop for JAX simulators, else the host
loop), a list of models to :mod:`jaxabc.model_choice`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast, overload

from jaxabc.algorithms.base import ABCAlgorithm
from jaxabc.checkpoint import CHECKPOINT_NAME
from jaxabc.distances import AdaptivePNorm
from jaxabc.driver.calibrate import calibrate
from jaxabc.driver.options import RunOptions
from jaxabc.executors import Executor
from jaxabc.noise import Discrepancy
from jaxabc.priors import Uniform
from jaxabc.results import ABCResult

if TYPE_CHECKING:  # model choice is imported only when a list of models is run
    from jaxabc.model_choice import ModelChoiceResult

__all__ = ["CHECKPOINT_NAME", "run"]


@overload
def run(
    algorithm: list[Any] | tuple[Any, ...],
    simulate: None = None,
    prior: None = None,
    observed: Any = None,
    **options: Any,
) -> ModelChoiceResult: ...


@overload
def run(
    algorithm: str | ABCAlgorithm,
    simulate: Callable,
    prior: Uniform,
    observed: Any,
    **options: Any,
) -> ABCResult: ...


def run(
    algorithm: str | ABCAlgorithm | Sequence[Any],
    simulate: Callable | None = None,
    prior: Uniform | None = None,
    observed: Any = None,
    num_particles: int | None = None,
    num_steps: int | None = None,
    distance: str | Callable | AdaptivePNorm = "mean_abs",
    seed: int = 0,
    *,
    executor: str | Executor | None = None,
    final_threshold: float | None = None,
    max_simulations: int | None = None,
    max_wall_time: float | None = None,
    max_failure_fraction: float = 0.5,
    checkpoint_dir: str | Path | None = None,
    resume: bool = False,
    overwrite: bool = False,
    simulator_id: str | None = None,
    stop_after_iterations: int | None = None,
    keep_summaries: bool = True,
    progress: bool = False,
    dtype: str = "float32",
    metadata: dict | None = None,
    observation_error: Any = None,
    discrepancy: Discrepancy | None = None,
    **algorithm_options: Any,
) -> ABCResult | ModelChoiceResult:
    """Calibrate ``simulate`` against ``observed`` with an ABC algorithm.

    Parameters
    ----------
    algorithm : {"apmcabc", "abcsubsim", "pmcabc", "rejection", "surrogate"} or ABCAlgorithm
        A name is built from :data:`jaxabc.algorithms.BUILDERS` with ``prior``,
        ``num_particles`` and ``**algorithm_options``; an object is used as it is.  A list of
        models, ``run([(simulate_a, prior_a), (simulate_b, prior_b)], observed=...)``, runs
        model choice instead (:func:`jaxabc.model_choice.run_model_choice`, or surrogate
        evidence with ``method="surrogate"``) and returns a ``ModelChoiceResult``.
    simulate : callable ``(key, theta) -> summaries``
        A fixed-shape summary array (or a scalar) per parameter vector: JAX code for ``"vmap"``,
        any picklable callable for the process executors (the key as raw ``uint32[2]``).  It
        fails by raising :class:`jaxabc.SimulationFailure` or returning NaN.
    prior : Uniform
    observed : array_like
        The measured summaries, the shape of ``simulate``'s output.
    num_particles : int, optional
        Population size (``"surrogate"``: posterior draws, default 2000).
    num_steps, final_threshold, max_simulations, max_wall_time, stop_after_iterations : optional
        Stopping rules (:class:`~jaxabc.driver.options.Stopping`): generations including the
        prior sample, a threshold, a budget (not below the first iteration's simulations),
        seconds; a resumable pause after so many iterations.  A run stopped before its first
        generation completed returns the particles accepted so far, flagged ``incomplete``.
    distance : str, callable or AdaptivePNorm
        ``"mean_abs"``, ``"euclidean"``, ``"kl"`` or ``distance(observed, simulated) -> scalar``
        (NaN for a successful simulation counts as a failure).  ``"adaptive"``, for
        ``"apmcabc"`` and ``"pmcabc"`` with flat summaries: Prangle's p-norm re-weighted each
        generation (weights in ``result.diagnostics["distance_weights"]``).
    seed : int
        The run's only source of randomness, ``0 <= seed < 2**32``.
    executor : str or Executor, optional
        ``"vmap"``, ``"serial"``, ``"process_pool"``, ``"mpi"``, ``"mpi_static"`` or an object.
        Default: the compiled loop (:func:`jaxabc.run_fused`) when the algorithm is a JAX one
        and JAX can trace ``simulate`` and the distance, else ``"vmap"``; both give the same
        iterations up to floating-point rounding.
    max_failure_fraction : float
        Stop with :class:`jaxabc.TooManyFailures` when more than this share of the simulations
        (after the first 20), or all of them, failed.
    checkpoint_dir, resume, overwrite, simulator_id : optional
        Checkpointing (:class:`~jaxabc.driver.options.Checkpointing`): ``checkpoint.npz`` after
        every iteration; ``resume`` gives the uninterrupted run's result and is refused for
        another problem (fingerprint) or a folder in use; a run ended on a stopping rule goes
        on when this call's rules allow more.  ``simulator_id`` names a simulator that cannot
        be fingerprinted.
    keep_summaries, progress : bool
        Keep every simulation's summaries in the record; show a progress bar.
    dtype : {"float32", "float64"}
        Working precision (``float64`` enables ``jax_enable_x64`` for this run only).
    metadata : dict, optional
        Stored in the result.
    observation_error : float, array_like or (n, n) array, optional
        The data's measurement error (:func:`jaxabc.noise.observation_covariance`): the ABC
        algorithms run noisy ABC (Wilkinson 2013), ``"surrogate"`` adds it to its likelihood.
    discrepancy : jaxabc.Discrepancy, optional
        Model discrepancy: for the ABC algorithms one extra uniform sd per group of summaries
        (``discrepancy_sd[<group>]`` columns); ``"surrogate"`` takes the groups itself.  Both
        are recorded in ``result.settings`` and the checkpoint fingerprint.
    **algorithm_options
        The algorithm's builder options (for model choice: ``method``, ``quantile``, ...).

    Returns
    -------
    ABCResult or ModelChoiceResult

    Raises
    ------
    TooManyFailures, NoPosterior, jaxabc.checkpoint.CheckpointError, FileExistsError
    ValueError, TypeError
        Bad arguments or data, a distance negative on the first population, complex summaries.
    """
    options = RunOptions.from_keywords(
        seed=seed,
        executor=executor,
        num_steps=num_steps,
        final_threshold=final_threshold,
        max_simulations=max_simulations,
        max_wall_time=max_wall_time,
        max_failure_fraction=max_failure_fraction,
        checkpoint_dir=checkpoint_dir,
        resume=resume,
        overwrite=overwrite,
        simulator_id=simulator_id,
        stop_after=stop_after_iterations,
        keep_summaries=keep_summaries,
        progress=progress,
        dtype=dtype,
        metadata=metadata,
    )
    measured = {"observation_error": observation_error, "discrepancy": discrepancy}
    if _is_model_list(algorithm, simulate):
        # Model choice, imported here so that a calibration never loads it.
        from jaxabc.model_choice import run_from_driver

        return run_from_driver(
            algorithm,
            simulate,
            prior,
            observed,
            num_particles,
            distance,
            options,
            **measured,
            method_options=algorithm_options,
        )
    if simulate is None or prior is None:
        raise TypeError("run() needs simulate and prior (for model choice: a list of models first)")
    return calibrate(
        cast(str | ABCAlgorithm, algorithm),
        simulate,
        prior,
        observed,
        num_particles,
        distance,
        options,
        **measured,
        algorithm_options=algorithm_options,
    )


def _is_model_list(algorithm: object, simulate: object) -> bool:
    """Whether :func:`run` was given a list of models (model choice) rather than one model."""
    return type(algorithm) in (list, tuple) or type(simulate) in (list, tuple)
