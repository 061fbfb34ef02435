"""ABC model choice: which of several simulators explains the observed data, and how surely.

The method: one ABC-SMC population per model, all at a **shared tolerance** in every
generation, and each model's ABC evidence ``Z_m(eps) = P(d(S_sim, S_obs) <= eps | m)``
estimated by importance sampling (the per-model evidence route of Didelot, Everitt, Johansen
& Lawson 2011, *Bayesian Analysis* 6, 49-76; populations move as in Beaumont, Cornuet, Marin &
Robert 2009).  The model probabilities at the shared tolerance are

    P(m | S_obs) = p(m) Z_m(eps) / sum_k p(k) Z_k(eps),

the quantity that the joint-space ABC-SMC of Toni et al. (2009) estimates by the share of
particles each model keeps.  Here each model keeps its own population of about
``num_particles``, however improbable it is, so its evidence has a small relative error and its
posterior stays usable; a model dies out only when not one of its proposals meets the
tolerance, and then it gets a 95% upper bound instead of a standard error.

One generation:

1. the tolerance is the ``quantile`` of the distances under the current joint ABC posterior
   over (model, parameters), each model's weights scaled by its probability (Toni et al.'s
   rule), clipped at ``final_threshold``: it follows the models that fit;
2. per living model, ``M`` proposals: a share ``defensive_fraction`` from the prior, the rest
   from the previous population perturbed by a Gaussian of ``covariance_factor`` times its
   weighted covariance; ``M`` is set from past generations so that about ``num_particles``
   are accepted (at most ``50 num_particles``);
3. proposals outside the prior's box get weight zero and cost no simulation; the others are
   simulated, and those within the tolerance are accepted with weight
   ``prior / (eta prior + (1 - eta) kernel mixture)``, ``eta`` the prior share (Hesterberg's
   defensive mixture, 1995: weights are at most ``1 / eta``, so the evidence estimate has a
   finite variance even when a population has collapsed);
4. ``Z_m = sum(accepted weights) / M``: unbiased given the past, because the tolerance, the
   proposal and ``M`` are fixed before the generation's simulations.

Monte Carlo error: the standard error of each ``Z_m`` is the sample standard deviation of the
``M`` terms over ``sqrt(M)``; the probabilities' standard errors follow by the delta method
(the models' estimates are independent).  They are conditional on the tolerance reached.

Randomness: generation ``t`` of model ``m`` uses ``fold_in(fold_in(key(seed), t), m)`` only,
and each proposal slot gets its own simulation key, so a seed fixes the whole run on any
executor.  Failed simulations get distance ``+inf``, are recorded with their reason, and stop
the run (:class:`jaxabc.TooManyFailures`) when more than ``max_failure_fraction`` of a
model's simulations (after its first 20) fail.

What the probabilities mean: ABC model choice compares the models' predictions of the
*summaries*.  As the tolerance goes to zero the probabilities converge to those of the Bayes
factor of the summaries, which equals the Bayes factor of the full data only when the
summaries are sufficient across the models jointly (Robert, Cornuet, Marin & Pillai 2011,
PNAS 108, 15112; Didelot et al. 2011): the sum of counts is sufficient for a Poisson and for a
geometric model separately, but not for choosing between them.

What the prior boxes do: an evidence averages the likelihood over the prior, so a box twice as
wide where the data say nothing halves it.  Every result carries
:meth:`ModelChoiceResult.sensitivity` rows (each model's box, and all of them, scaled by 0.5
and 2 about the centre): a narrower box is computed from the run, ``Z' = Z P(theta in B' |
data) vol(B) / vol(B')``, with no new simulation; a wider one is reported as needing
simulations there, with the lower bound the run does give, and :func:`with_boxes`
computes it.  :meth:`ModelChoiceResult.verdict` names a preferred model only when its
probability interval clears every other model's at the run's boxes and in every computed row;
each model whose posterior piles against a bound of its box gets a
:class:`jaxabc.PriorEdgeWarning` naming it.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.distances import get_distance
from jaxabc.driver.checks import cast_prior, check_traced_shape, precision, shapes_compatible, validate_observed
from jaxabc.driver.context import Recorder, make_distance_fn, open_executor
from jaxabc.driver.options import RunOptions
from jaxabc.errors import PriorEdgeWarning, caller_stacklevel
from jaxabc.executors import Executor
from jaxabc.model_choice import checkpoint as _ckpt
from jaxabc.model_choice.result import (
    STATUS_NEEDS_SIMULATIONS,
    STATUS_REUSED,
    ModelChoiceResult,
    SensitivityRow,
    Verdict,
    check_prior_edges,
    load_model_choice,
    probabilities_with_errors,
)
from jaxabc.model_choice.smc import ALGORITHM_NAME, Context, ModelTrack, Settings, next_threshold
from jaxabc.noise import observation_covariance, wrap_for_abc
from jaxabc.results import versions

__all__ = [
    "ALGORITHM_NAME",
    "STATUS_NEEDS_SIMULATIONS",
    "STATUS_REUSED",
    "Model",
    "ModelChoiceResult",
    "SensitivityRow",
    "Verdict",
    "as_models",
    "choose_models",
    "load_model_choice",
    "normalise_model_prior",
    "run_model_choice",
    "with_boxes",
]

#: How the probabilities were computed, for result metadata.
METHOD = (
    "ABC-SMC per model at a shared tolerance, importance-sampling evidence with a defensive "
    "prior mixture (Didelot et al. 2011); standard errors by the delta method"
)


class Model(NamedTuple):
    """One candidate model.

    Attributes
    ----------
    name : str
        Used in results and messages; unique among the models compared.
    simulate : callable ``(key, theta) -> summaries``
        As for :func:`jaxabc.run`: one parameter vector in, a fixed-shape summary array out;
        every model's summaries must have the observed data's shape.
    prior : Uniform or Independent
        The model's parameter prior (its box bounds the perturbation kernel).
    """

    name: str
    simulate: Callable
    prior: Any


def as_models(models: Any) -> list[Model]:
    """Normalise ``models`` to a list of :class:`Model`, refusing bad input clearly.

    Accepts :class:`Model` objects, ``(simulate, prior)`` pairs (named ``model0``, ``model1``,
    ...) and ``(name, simulate, prior)`` triples.
    """
    if isinstance(models, Model) or not isinstance(models, list | tuple):
        raise TypeError(
            "models must be a list of models: [(simulate_a, prior_a), (simulate_b, prior_b)], "
            "(name, simulate, prior) triples or jaxabc.Model(name, simulate, prior) objects"
        )
    if len(models) == 0:
        raise ValueError(
            "the list of models is empty: give at least two, e.g. jaxabc.run([(simulate_a, prior_a), "
            "(simulate_b, prior_b)], observed=...)"
        )
    out = []
    for i, entry in enumerate(models):
        if isinstance(entry, Model):
            model = entry
        elif isinstance(entry, tuple | list) and len(entry) == 2:
            model = Model(f"model{i}", entry[0], entry[1])
        elif isinstance(entry, tuple | list) and len(entry) == 3 and isinstance(entry[0], str):
            model = Model(*entry)
        else:
            raise TypeError(
                f"model {i} is a {type(entry).__name__}: give (simulate, prior), "
                "(name, simulate, prior) or jaxabc.Model(name, simulate, prior)"
            )
        if not callable(model.simulate):
            raise TypeError(f"model {model.name!r}: simulate must be a callable simulate(key, theta) -> summaries")
        if not hasattr(model.prior, "sample") or not hasattr(model.prior, "low"):
            raise TypeError(
                f"model {model.name!r}: the prior must be a jaxabc prior such as jaxabc.Uniform(low, high, names)"
            )
        out.append(model)
    if len(out) < 2:
        raise ValueError(
            "model choice needs at least two models; to calibrate one model use "
            "jaxabc.run(algorithm, simulate, prior, observed)"
        )
    names = [m.name for m in out]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise ValueError(f"model names must be unique, got {duplicates} more than once")
    return out


def normalise_model_prior(model_prior: Sequence[float] | None, num_models: int) -> np.ndarray:
    """Prior model probabilities summing to one (uniform when ``model_prior`` is None).

    Raises
    ------
    ValueError
        Not one positive, finite entry per model.
    """
    if model_prior is None:
        return np.full(num_models, 1.0 / num_models)
    p = np.asarray(model_prior, np.float64).reshape(-1)
    if p.shape != (num_models,):
        raise ValueError(f"model_prior has {p.size} entries for {num_models} models: give one per model")
    if not np.all(np.isfinite(p)) or np.any(p <= 0):
        raise ValueError(f"model_prior entries must be positive and finite, got {p.tolist()}")
    return p / p.sum()


# ----------------------------------------------------------------------------- the run


def _check_summary_shapes(models: list[Model], priors: list[Any], observed: np.ndarray, distance: Any) -> None:
    """Trace every JAX model once; refuse models whose summaries differ from each other or the data."""
    shapes = {}
    for model, prior in zip(models, priors, strict=True):
        try:
            out = jax.eval_shape(model.simulate, jax.random.key(0), jnp.zeros((prior.dim,), prior.low.dtype))
        except Exception:
            # Raises with the tracing error and what to do about it.
            check_traced_shape(
                model.simulate, prior, observed, distance, prior.low.dtype, f"Model {model.name!r} on the vmap executor"
            )
            raise
        shapes[model.name] = tuple(out.shape)
    if len(set(shapes.values())) > 1:
        listing = ", ".join(f"{name!r} {shape}" for name, shape in shapes.items())
        raise ValueError(
            f"the models return summaries of different shapes ({listing}): model choice compares every "
            f"model with the same observed summaries (shape {observed.shape}), so they must agree"
        )
    for name, shape in shapes.items():
        if not shapes_compatible(shape, observed.shape, distance):
            raise ValueError(
                f"model {name!r} returns summaries of shape {shape} but the observed data has shape "
                f"{observed.shape}: they must match"
            )


def _loop(
    ctx: Context,
    tracks: list[ModelTrack],
    thresholds: list[float],
    model_prior: np.ndarray,
    progress: bool,
    after_generation: Callable[[list[float]], None],
    stop_after_generations: int | None,
) -> str:
    """Run generations until a stopping rule fires, appending to ``thresholds`` (empty for a
    fresh run, the saved ones on resume); returns the stop reason."""
    s = ctx.settings

    def run_generation(eps: float, nums: list[int]) -> None:
        index = len(thresholds)
        key = jax.random.fold_in(ctx.root, index)
        for m, (track, num) in enumerate(zip(tracks, nums, strict=True)):
            track.generation(ctx, index, jax.random.fold_in(key, m), eps, num)
        thresholds.append(eps)
        after_generation(thresholds)

    def stop_reason() -> str:
        eps = thresholds[-1]
        if not any(t.alive for t in tracks):
            return f"no simulation of any model met the tolerance {eps:.4g}"
        if s.num_steps is not None and len(thresholds) >= s.num_steps:
            return f"{s.num_steps} steps done"
        if s.final_threshold is not None and eps <= s.final_threshold:
            return f"final threshold {s.final_threshold} reached"
        if s.max_wall_time is not None and time.perf_counter() - ctx.t_start > s.max_wall_time:
            return f"wall time {s.max_wall_time} s reached"
        if stop_after_generations is not None and len(thresholds) >= stop_after_generations:
            return f"stopped after {len(thresholds)} generations (resumable)"
        return ""

    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=s.num_steps, desc="model choice", unit="step", initial=max(0, len(thresholds) - 1))
    try:
        if not thresholds:
            run_generation(math.inf, [s.num_particles] * len(tracks))
        while True:
            if bar is not None:
                bar.update(1)
                bar.set_postfix(threshold=f"{thresholds[-1]:.4g}", sims=sum(t.num_simulations for t in tracks))
            reason = stop_reason()
            if reason:
                return reason
            populations = [t.population if t.alive else None for t in tracks]
            log_z = np.array([t.history["log_evidence"][-1] for t in tracks])
            rel = np.array([t.history["relative_error"][-1] for t in tracks])
            probabilities = probabilities_with_errors(log_z, rel, model_prior)[0]
            eps = next_threshold(populations, probabilities, thresholds[-1], s.quantile, s.final_threshold)
            if eps is None:
                return (
                    f"the tolerance cannot go below {thresholds[-1]:.6g}: every accepted simulation of every "
                    "model is at that distance"
                )
            nums = [t.num_proposals(eps, s.num_particles) for t in tracks]
            spent = sum(t.num_simulations for t in tracks)
            if s.max_simulations is not None and spent + sum(nums) > s.max_simulations:
                return f"simulation budget {s.max_simulations} reached"
            run_generation(eps, nums)
    finally:
        if bar is not None:
            bar.close()


def _assemble(
    ctx: Context,
    tracks: list[ModelTrack],
    thresholds: list[float],
    stop_reason: str,
    model_prior: np.ndarray,
    dtype: str,
    metadata: dict | None,
) -> ModelChoiceResult:
    log_z = np.array([t.history["log_evidence"] for t in tracks]).T  # (g, K)
    rel = np.array([t.history["relative_error"] for t in tracks]).T
    probs, errors = probabilities_with_errors(log_z, rel, model_prior)
    # The answer is at the last tolerance some model reached (all die only in the last step).
    final = max(i for i in range(len(thresholds)) if np.any(np.isfinite(log_z[i])))
    wall = time.perf_counter() - ctx.t_start
    bounds = _upper_bounds(tracks, final, log_z[final], model_prior, ctx.settings.defensive_fraction)
    dead = [f"{t.name} (below {bounds[i]:.2g})" for i, t in enumerate(tracks) if np.isfinite(bounds[i])]
    if dead:
        warnings.warn(
            f"no simulation of {', '.join(dead)} met the tolerance {thresholds[final]:.4g}: its probability "
            "is estimated as 0 with a zero standard error; the 95% upper bound given here is in "
            "probability_upper_bounds",
            UserWarning,
            stacklevel=caller_stacklevel(),
        )
    with warnings.catch_warnings():
        # The prior-edge check runs once below, per model and naming it (not per ABCResult).
        warnings.simplefilter("ignore", PriorEdgeWarning)
        posteriors = tuple(t.result(ctx, final, dtype, wall, stop_reason) for t in tracks)
    names = tuple(t.name for t in tracks)
    edges = check_prior_edges(names, posteriors)
    meta: dict[str, Any] = {
        "versions": versions(),
        "executor": ctx.executor.name,
        "settings": ctx.settings._asdict(),
        "dtype": dtype,
        "method": METHOD,
    }
    meta.update(metadata or {})
    result = ModelChoiceResult(
        names=names,
        probabilities=probs[final],
        standard_errors=errors[final],
        log_evidence=log_z[final],
        log_evidence_errors=rel[final],
        model_prior=model_prior,
        threshold=float(thresholds[final]),
        thresholds=np.asarray(thresholds[: final + 1], np.float64),
        probability_upper_bounds=bounds,
        probability_history=probs[: final + 1],
        standard_error_history=errors[: final + 1],
        simulations_per_step=np.array([t.history["sims"][: final + 1] for t in tracks]).T,
        posteriors=posteriors,
        num_simulations=sum(t.num_simulations for t in tracks),
        seed=ctx.seed,
        stop_reason=stop_reason,
        wall_time=wall,
        metadata=meta,
        prior_edge=edges,
    )
    result.sensitivity()
    return result


def _upper_bounds(
    tracks: list[ModelTrack], final: int, log_z: np.ndarray, model_prior: np.ndarray, defensive_fraction: float
) -> np.ndarray:
    """95% upper bounds on the probabilities of models with no accepted simulation (else NaN).

    A prior draw meets the tolerance with probability ``Z`` exactly, so none among the
    ``ceil(defensive_fraction M)`` prior draws of the generation where the model died gives
    ``Z < 3 / ceil(defensive_fraction M)`` with 95% confidence (the rule of three); the
    evidence at the final tolerance is no larger.  The other models' evidence is taken at its
    estimate.
    """
    out = np.full(len(tracks), np.nan)
    z = np.exp(log_z)
    for i, t in enumerate(tracks):
        if t.died_at is None or t.died_at > final:
            continue
        num = t.history["proposals"][t.died_at]
        z_up = 3.0 / math.ceil(defensive_fraction * num) if t.died_at > 0 else 3.0 / num
        others = np.sum(np.delete(model_prior * z, i))
        out[i] = model_prior[i] * z_up / (model_prior[i] * z_up + others)
    return out


def run_model_choice(
    models: Sequence[Model | tuple],
    observed: Any,
    num_particles: int = 1000,
    num_steps: int | None = None,
    distance: str | Callable = "mean_abs",
    seed: int = 0,
    *,
    executor: str | Executor | None = None,
    final_threshold: float | None = None,
    max_simulations: int | None = None,
    max_wall_time: float | None = None,
    max_failure_fraction: float = 0.5,
    quantile: float = 0.5,
    model_prior: Sequence[float] | None = None,
    covariance_factor: float = 2.0,
    defensive_fraction: float = 0.05,
    checkpoint_dir: str | Path | None = None,
    resume: bool = False,
    overwrite: bool = False,
    simulator_id: str | None = None,
    stop_after_generations: int | None = None,
    keep_summaries: bool = True,
    progress: bool = False,
    dtype: str = "float32",
    metadata: dict | None = None,
    observation_error: Any = None,
    discrepancy: Any = None,
) -> ModelChoiceResult:
    """Posterior probabilities of competing models at a shared ABC tolerance.

    Also reached as ``jaxabc.run(models, observed=..., ...)``.  The method, its Monte Carlo
    error and what the probabilities mean are described in :mod:`jaxabc.model_choice`.

    Parameters
    ----------
    models : sequence
        Two or more of ``(simulate, prior)``, ``(name, simulate, prior)`` or :class:`Model`.
        Every ``simulate`` returns summaries of the shape of ``observed``.
    observed : array_like
        The measured summaries.
    num_particles : int
        At least 2: prior draws per model in the first generation, and the accepted particles
        each later generation aims at per model.
    num_steps, final_threshold, max_simulations, max_wall_time : optional
        Stopping rules, at least one: generations (the prior sample included), a shared
        tolerance (non-negative; the schedule never goes below it), a budget over all models
        (checked before each generation), seconds (checked after each).
    distance, seed, executor, max_failure_fraction, keep_summaries, progress, dtype, metadata
        As for :func:`jaxabc.run`, the same for every model (``max_failure_fraction`` per model).
    quantile : float
        In (0, 1); each tolerance is this quantile of the distances under the joint ABC
        posterior over (model, parameters) of the previous generation.
    model_prior : sequence of float, optional
        Prior model probabilities (default uniform); normalised.
    covariance_factor : float
        Kernel covariance over the population's weighted covariance (Beaumont et al.'s 2).
    defensive_fraction : float
        In (0, 1); the share of each generation's proposals drawn from the prior.
    checkpoint_dir, resume, overwrite, simulator_id : optional
        As for :func:`jaxabc.run`, a checkpoint after every generation; the fingerprint covers
        the models, priors, simulators, observed data, distance, settings, seed and dtype.
    stop_after_generations : int, optional
        At least 1: stop, resumably, after this many generations.
    observation_error, discrepancy : optional
        As for :func:`jaxabc.run`: every model's simulator and prior are wrapped by
        :func:`jaxabc.noise.wrap_for_abc` alike, so each model is compared *with* them.

    Returns
    -------
    ModelChoiceResult
        With each model's prior-edge check (``prior_edge``; a :class:`jaxabc.PriorEdgeWarning`
        names each model whose posterior piles against a bound), the box-sensitivity rows for
        scales 0.5 and 2 (``sensitivity_table``) and :meth:`~ModelChoiceResult.verdict`.

    Raises
    ------
    TypeError, ValueError
        Bad models or options (the message says what to give instead).
    TooManyFailures
        Too many simulations of one model failed.
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
        stop_after=stop_after_generations,
        keep_summaries=keep_summaries,
        progress=progress,
        dtype=dtype,
        metadata=metadata,
    )
    method = {"quantile": quantile, "covariance_factor": covariance_factor, "defensive_fraction": defensive_fraction}
    measured = {"observation_error": observation_error, "discrepancy": discrepancy}
    return choose_models(
        models, observed, num_particles, distance, options, model_prior=model_prior, **method, **measured
    )


def choose_models(
    models: Sequence[Model | tuple],
    observed: Any,
    num_particles: int,
    distance: str | Callable,
    options: RunOptions,
    *,
    quantile: float = 0.5,
    model_prior: Sequence[float] | None = None,
    covariance_factor: float = 2.0,
    defensive_fraction: float = 0.05,
    observation_error: Any = None,
    discrepancy: Any = None,
) -> ModelChoiceResult:
    """:func:`run_model_choice` with its run options in ``options``."""
    t_start = time.perf_counter()
    model_list = as_models(models)
    settings = _settings(num_particles, options, quantile, covariance_factor, defensive_fraction)
    p_model = normalise_model_prior(model_prior, len(model_list))
    obs = validate_observed(observed, options.execution.dtype, distance)
    get_distance(distance)  # an unknown name fails here, before any simulation
    model_list, measured = _with_measurement(model_list, obs, observation_error, discrepancy)
    with precision(options.execution.dtype):
        ctx, tracks, thresholds, stop_reason = _run_models(
            model_list, obs, distance, settings, p_model, options, t_start
        )
    metadata = {**measured, **(options.metadata or {})}
    return _assemble(ctx, tracks, thresholds, stop_reason, p_model, options.execution.dtype, metadata)


def _settings(
    num_particles: Any, options: RunOptions, quantile: float, covariance_factor: float, defensive_fraction: float
) -> Settings:
    """The method's settings (recorded in every result and the fingerprint), after refusing
    values it cannot use."""
    stopping = options.stopping
    if not isinstance(num_particles, int | np.integer) or num_particles < 2:
        raise ValueError(f"num_particles must be an integer of at least 2, got {num_particles!r}")
    if not stopping.has_rule:
        raise ValueError(
            "model choice needs a stopping rule: give num_steps, final_threshold, max_simulations or max_wall_time"
        )
    if stopping.final_threshold is not None and not stopping.final_threshold >= 0:
        raise ValueError(f"final_threshold must be a non-negative number, got {stopping.final_threshold}")
    if not 0.0 < quantile < 1.0:
        raise ValueError(f"quantile must lie in (0, 1), got {quantile}")
    if not covariance_factor > 0:
        raise ValueError(f"covariance_factor must be positive, got {covariance_factor}")
    if not 0.0 < defensive_fraction < 1.0:
        raise ValueError(
            f"defensive_fraction must lie in (0, 1), got {defensive_fraction}: some prior draws keep "
            "the evidence estimate's variance finite"
        )
    if stopping.stop_after is not None and stopping.stop_after < 1:
        raise ValueError(f"stop_after_generations must be at least 1, got {stopping.stop_after}")
    return Settings(
        num_particles=int(num_particles),
        quantile=quantile,
        covariance_factor=covariance_factor,
        defensive_fraction=defensive_fraction,
        max_failure_fraction=options.execution.max_failure_fraction,
        num_steps=stopping.num_steps,
        final_threshold=stopping.final_threshold,
        max_simulations=stopping.max_simulations,
        max_wall_time=stopping.max_wall_time,
    )


def _with_measurement(
    models: list[Model], observed: np.ndarray, observation_error: Any, discrepancy: Any
) -> tuple[list[Model], dict[str, Any]]:
    """The models with the data's measurement error and discrepancy, and those to record."""
    if observation_error is None and discrepancy is None:
        return models, {}
    shape = tuple(observed.shape)
    # Noisy ABC for every model alike (Wilkinson 2013): the error is the data's, not a model's.
    models = [Model(m.name, *wrap_for_abc(m.simulate, m.prior, shape, observation_error, discrepancy)) for m in models]
    measured: dict[str, Any] = {}
    if observation_error is not None:
        measured["observation_error"] = observation_covariance(observation_error, shape).tolist()
    if discrepancy is not None:
        measured["discrepancy"] = discrepancy.describe() if hasattr(discrepancy, "describe") else repr(discrepancy)
    return models, measured


def _run_models(
    models: list[Model],
    observed: np.ndarray,
    distance: Any,
    settings: Settings,
    model_prior: np.ndarray,
    options: RunOptions,
    t_start: float,
) -> tuple[Context, list[ModelTrack], list[float], str]:
    """Every model's track after the run (or the checkpoint's, for a run that had ended), its
    tolerances and its stop reason; call it in the run's precision."""
    execution, checkpointing = options.execution, options.checkpointing
    priors = [cast_prior(m.prior, execution.jdtype) for m in models]
    with open_executor(execution.executor, observed, distance) as executor:
        if executor.name == "vmap" and not any(hasattr(m.simulate, "simulate_batch") for m in models):
            _check_summary_shapes(models, priors, observed, distance)
        ctx = Context(
            settings=settings,
            executor=executor,
            distances_of=make_distance_fn(distance, observed, execution.jdtype),
            observed=observed,
            distance=distance,
            root=jax.random.key(options.seed),
            seed=options.seed,
            t_start=t_start,
        )
        tracks = [
            ModelTrack(model.name, model.simulate, prior, Recorder(execution.keep_summaries))
            for model, prior in zip(models, priors, strict=True)
        ]
        fp = _ckpt.problem_fingerprint(
            tracks, settings, model_prior, observed, distance, options.seed, execution.dtype, checkpointing.simulator_id
        )
        for track in tracks:
            checkpointing.require_fingerprintable(track.simulate, distance)
        # One run per folder; and only now, with every input checked, may overwrite=True
        # delete an old checkpoint.
        with checkpointing.locked():
            ckpt_path = checkpointing.prepare()
            thresholds, stop_reason = _generations(ctx, tracks, model_prior, options, fp, ckpt_path)
    return ctx, tracks, thresholds, stop_reason


def _generations(
    ctx: Context,
    tracks: list[ModelTrack],
    model_prior: np.ndarray,
    options: RunOptions,
    fingerprint: dict,
    ckpt_path: Path | None,
) -> tuple[list[float], str]:
    """Resume if asked, run generations until a rule stops the run, checkpoint after each;
    the tolerances and the stop reason."""
    thresholds: list[float] = []
    stop_reason = ""
    if options.checkpointing.resume:
        assert ckpt_path is not None, "prepare_folder refuses resume without a folder"
        thresholds, stop_reason = _ckpt.restore(ckpt_path, fingerprint, tracks)

    def after_generation(done: list[float]) -> None:
        if ckpt_path is not None:
            _ckpt.save(ckpt_path, fingerprint, tracks, done, "")

    if not stop_reason:
        stop_reason = _loop(
            ctx,
            tracks,
            thresholds,
            model_prior,
            options.execution.progress,
            after_generation,
            options.stopping.stop_after,
        )
        if ckpt_path is not None and "resumable" not in stop_reason:
            _ckpt.save(ckpt_path, fingerprint, tracks, thresholds, stop_reason)
    return thresholds, stop_reason


# ----------------------------------------------------------------------------- wider boxes


def _replace_box(prior: Any, value: Any, name: str) -> Any:
    """``prior`` on another box: ``value`` a width factor about the centre, ``(low, high)`` or a prior."""
    if hasattr(value, "sample") and hasattr(value, "low"):
        return value
    low0 = np.asarray(prior.low, np.float64).reshape(-1)
    high0 = np.asarray(prior.high, np.float64).reshape(-1)
    if np.ndim(value) == 0:
        scale = float(value)
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"the box factor for {name!r} must be positive and finite, got {value!r}")
        centre, half = 0.5 * (low0 + high0), 0.5 * scale * (high0 - low0)
        low, high = centre - half, centre + half
    else:
        pair = np.asarray(value, np.float64)
        if pair.shape not in ((2, low0.size), (2,)) or (pair.shape == (2,) and low0.size != 1):
            raise ValueError(
                f"the box for {name!r}: give (low, high) with {low0.size} value(s) each, a width factor "
                f"or a prior; got shape {pair.shape}"
            )
        low, high = pair.reshape(2, -1)
    if type(prior).__name__ == "Uniform":
        return type(prior)(low, high, names=prior.names, units=getattr(prior, "units", None))
    distributions = getattr(prior, "distributions", None)
    if isinstance(distributions, dict):
        bounds = {n: (float(lo), float(hi)) for n, lo, hi in zip(prior.names, low, high, strict=True)}
        units = dict(zip(prior.names, getattr(prior, "units", ("",) * len(bounds)), strict=True))
        return type(prior)(bounds=bounds, units=units, **distributions)
    raise TypeError(f"model {name!r}: cannot move the box of a {type(prior).__name__} prior; pass the new prior itself")


def with_boxes(models: Sequence[Model | tuple], boxes: dict[str, Any]) -> list[Model]:
    """The models with some prior boxes replaced, to run the model choice again with them.

    The rows of :meth:`ModelChoiceResult.sensitivity` whose box reaches outside a model's run
    box (status :data:`STATUS_NEEDS_SIMULATIONS`) need simulations there:
    ``jaxabc.run(with_boxes(models, boxes), **same_options)`` runs them.  With the options of the
    first run (``observed``, ``num_particles``, ``final_threshold``, ``seed``, ``method``,
    ``observation_error``, ...) the result compares like with like; its own
    :meth:`~ModelChoiceResult.verdict` then says whether the preference survives the wider box.

    Parameters
    ----------
    models : sequence
        The models of the first run (any form :func:`jaxabc.run` takes).
    boxes : dict
        ``{model name: new box}``, the box a width factor about its centre (``2.0``),
        ``(low, high)`` (one value per parameter) or a prior; models not named keep theirs.

    Returns
    -------
    list of Model

    Raises
    ------
    KeyError
        A name in ``boxes`` that is no model's.

    Examples
    --------
    >>> wide = jaxabc.run(with_boxes(models, {"near": 2.0}), observed=data, num_particles=500,
    ...                   final_threshold=0.05, num_steps=20)  # doctest: +SKIP
    >>> wide.verdict()  # doctest: +SKIP
    """
    model_list = as_models(list(models))
    names = [m.name for m in model_list]
    unknown = sorted(set(boxes) - set(names))
    if unknown:
        raise KeyError(f"no model named {unknown}: the models are {names}")
    return [
        Model(m.name, m.simulate, _replace_box(m.prior, boxes[m.name], m.name)) if m.name in boxes else m
        for m in model_list
    ]
