"""Model choice by surrogate evidence: one GP-surrogate calibration per model, probabilities
from the synthetic-likelihood evidences (:mod:`jaxabc.surrogate.evidence`).

Each model runs :func:`jaxabc.run` with the surrogate on its own budget, seed and checkpoint
folder, so a long comparison resumes model by model.  The probabilities are

    P(m | s_obs) = p(m) Z_m / sum_k p(k) Z_k,

with the delta-method standard errors of :func:`probabilities_with_errors` from each ``log Z``'s
importance-sampling error.  Compared with ABC-SMC model choice this needs a few hundred
simulations per model instead of thousands, and its probabilities are those of the synthetic
likelihood (Gaussian summaries within the simulator's noise), not of an ABC tolerance.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from jaxabc.checkpoint import CHECKPOINT_NAME
from jaxabc.driver.calibrate import calibrate
from jaxabc.driver.options import Checkpointing, Execution, RunOptions, Stopping
from jaxabc.errors import PriorEdgeWarning
from jaxabc.model_choice.core import Model, as_models, normalise_model_prior
from jaxabc.model_choice.result import ModelChoiceResult, check_prior_edges, file_stem, probabilities_with_errors
from jaxabc.results import ABCResult
from jaxabc.seeding import seed_from_key

__all__ = ["METHOD", "MISFIT_ALPHA", "choose_by_surrogate", "probability_intervals", "run_model_choice_surrogate"]

METHOD = (
    "GP-surrogate synthetic likelihood per model, evidence by importance sampling over the prior "
    "box (jaxabc.surrogate.evidence); standard errors by the delta method"
)

#: Level of the observed-data misfit check below which a model counts as not reproducing the data.
MISFIT_ALPHA = 0.01


def probability_intervals(
    log_z: np.ndarray, log_z_se: np.ndarray, model_prior: np.ndarray, rng: np.random.Generator, draws: int = 20_000
) -> np.ndarray:
    """2.5 and 97.5 % points ``(K, 2)`` of each model probability, every ``log Z_m`` drawn from
    ``N(log_z_m, log_z_se_m^2)`` independently (NaN for a model with a NaN evidence)."""
    sample = log_z + np.nan_to_num(log_z_se, nan=0.0) * rng.standard_normal((draws, log_z.size))
    probs, _ = probabilities_with_errors(sample, np.zeros_like(sample), model_prior)
    return np.nanpercentile(probs, [2.5, 97.5], axis=0).T


def run_model_choice_surrogate(
    models: Sequence[Any],
    observed: Any,
    simulations_per_model: int,
    num_particles: int = 2000,
    seed: int = 0,
    *,
    executor: Any = None,
    model_prior: Sequence[float] | None = None,
    checkpoint_dir: str | Path | None = None,
    resume: bool = False,
    overwrite: bool = False,
    simulator_id: str | None = None,
    progress: bool = False,
    metadata: dict | None = None,
    driver: Callable[..., Any] | None = None,
    observation_error: Any = None,
    discrepancy: Any = None,
    **surrogate_options: Any,
) -> ModelChoiceResult:
    """Posterior probabilities of competing models from their surrogate evidences.

    Parameters
    ----------
    models : sequence
        Two or more of ``(simulate, prior)``, ``(name, simulate, prior)`` or
        :class:`jaxabc.Model`; uniform priors (the surrogate's box).
    observed : array_like
        The measured summaries; every model's simulator returns this shape.
    simulations_per_model : int
        Real simulations per model (design and held-out validation); through
        ``jaxabc.run(models, ..., method="surrogate")`` it is ``max_simulations`` split evenly.
    num_particles : int
        Posterior draws per model.
    seed : int
        The comparison's only source of randomness; model ``m`` runs with a seed drawn from
        ``fold_in(key(seed), m)``.
    executor, progress, overwrite :
        As for :func:`jaxabc.run`, for every model.
    model_prior : sequence of float, optional
        Prior model probabilities (default uniform).
    checkpoint_dir : path, optional
        Model ``m``'s run checkpoints to ``checkpoint_dir/<model name>``; with ``resume`` a
        model whose folder holds a checkpoint continues (or, finished, returns at once).
    simulator_id : str, optional
        Prefix of each model's simulator identity in its checkpoint (``<id>:<model name>``).
    driver : callable, optional
        Calibrates each model, with :func:`jaxabc.run`'s signature (default: the calibration
        :func:`jaxabc.run` itself runs).
    observation_error, discrepancy : optional
        The data's measurement error and a model discrepancy, as for :func:`jaxabc.run`, the
        same for every model: given to each model's surrogate builder, so each synthetic
        likelihood, and so each evidence, includes them.
    **surrogate_options
        Passed to :func:`jaxabc.surrogate.build` (not ``mode``, ``max_outputs`` or
        ``observed``: the evidence needs the synthetic likelihood on the raw summaries).

    Returns
    -------
    ModelChoiceResult
        ``threshold`` is NaN (there is no ABC tolerance), one history row; each posterior's
        ``diagnostics`` holds its validation and ``log_evidence_se``; ``metadata["validated"]``
        lists per model whether its emulator passed validation, and
        ``metadata["probability_interval_95"]`` (K, 2) the probabilities' 2.5 and 97.5 %
        points with each ``log Z`` drawn from its normal error (the delta-method
        ``standard_errors`` understate once those errors approach 1).  A model whose emulator
        failed is flagged in ``stop_reason``.  When every model fails the observed-data misfit
        check (p < :data:`MISFIT_ALPHA`), ``metadata["misspecified"]`` is True and
        ``stop_reason`` says so: the probabilities then rank misfits.

    Raises
    ------
    ValueError
        Options the evidence cannot use, or models whose likelihoods use different summaries
        (their evidences would be densities of different data).
    """
    options = RunOptions.from_keywords(
        seed=seed,
        executor=executor,
        checkpoint_dir=checkpoint_dir,
        resume=resume,
        overwrite=overwrite,
        simulator_id=simulator_id,
        progress=progress,
        metadata=metadata,
    )
    return choose_by_surrogate(
        models,
        observed,
        simulations_per_model,
        num_particles,
        options,
        model_prior=model_prior,
        observation_error=observation_error,
        discrepancy=discrepancy,
        surrogate_options=surrogate_options,
        driver=driver,
    )


def choose_by_surrogate(
    models: Sequence[Any],
    observed: Any,
    simulations_per_model: int,
    num_particles: int,
    options: RunOptions,
    *,
    model_prior: Sequence[float] | None = None,
    observation_error: Any = None,
    discrepancy: Any = None,
    surrogate_options: dict[str, Any] | None = None,
    driver: Callable[..., Any] | None = None,
) -> ModelChoiceResult:
    """:func:`run_model_choice_surrogate` with its run options in ``options`` (seed, executor,
    checkpointing, progress and metadata are read)."""
    t0 = time.perf_counter()
    surrogate_options = dict(surrogate_options or {})
    banned = sorted({"mode", "max_outputs", "observed", "max_simulations"} & set(surrogate_options))
    if banned:
        raise ValueError(
            f"surrogate model choice sets {banned} itself: the evidence needs the synthetic likelihood "
            "of all the raw summaries (no principal-component projection)"
        )
    ms = as_models(list(models))
    prior_m = normalise_model_prior(model_prior, len(ms))
    obs = np.asarray(observed, np.float64)
    if int(simulations_per_model) < 1:
        raise ValueError(f"simulations_per_model must be positive, got {simulations_per_model}")
    measured = {
        k: v for k, v in (("observation_error", observation_error), ("discrepancy", discrepancy)) if v is not None
    }
    posteriors = [
        _calibrate_model(
            m, model, obs, int(simulations_per_model), num_particles, options, measured, surrogate_options, driver
        )
        for m, model in enumerate(ms)
    ]
    result = _result(ms, posteriors, prior_m, options, measured, t0)
    result.sensitivity()
    return result


def _calibrate_model(
    index: int,
    model: Model,
    observed: np.ndarray,
    simulations: int,
    num_particles: int,
    options: RunOptions,
    measured: dict[str, Any],
    surrogate_options: dict[str, Any],
    driver: Callable[..., Any] | None,
) -> ABCResult:
    """Model ``index``'s surrogate calibration, with its evidence, on its own seed and folder."""
    from jaxabc.surrogate import build
    from jaxabc.surrogate.evidence import with_evidence

    model_seed = seed_from_key(jax.random.fold_in(jax.random.key(options.seed), index))
    algo = build(
        model.prior,
        num_particles,
        observed=observed,
        max_simulations=simulations,
        max_outputs=max(observed.size, 1),
        **measured,
        **surrogate_options,
    )
    algo = with_evidence(algo, model.prior, observed, seed=model_seed)
    model_options = _model_options(model.name, model_seed, simulations, options)
    with warnings.catch_warnings():
        # A model finished in an earlier sitting is reused on purpose: no "nothing was run".
        warnings.filterwarnings("ignore", message="the run in .* had already ended")
        # The prior-edge check runs once for all models, naming each.
        warnings.simplefilter("ignore", PriorEdgeWarning)
        if driver is not None:
            return driver(algo, model.simulate, model.prior, observed, **model_options.keywords())
        return calibrate(algo, model.simulate, model.prior, observed, None, "mean_abs", model_options)


def _model_options(name: str, seed: int, simulations: int, options: RunOptions) -> RunOptions:
    """One model's run: its seed, budget and checkpoint folder, in double precision."""
    base = options.checkpointing
    folder = None if base.folder is None else Path(base.folder) / file_stem(name)
    resume = bool(base.resume and folder is not None and (folder / CHECKPOINT_NAME).exists())
    return RunOptions(
        seed=seed,
        stopping=Stopping(max_simulations=simulations),
        checkpointing=Checkpointing(
            folder=folder,
            resume=resume,
            overwrite=base.overwrite and not resume,
            simulator_id=None if base.simulator_id is None else f"{base.simulator_id}:{name}",
        ),
        execution=Execution(executor=options.execution.executor, progress=options.execution.progress, dtype="float64"),
        metadata={"model": name},
    )


def _result(
    models: list[Model],
    posteriors: list[ABCResult],
    model_prior: np.ndarray,
    options: RunOptions,
    measured: dict[str, Any],
    t_start: float,
) -> ModelChoiceResult:
    """The probabilities from the models' evidences, with the checks that qualify them."""
    actives = [tuple(p.diagnostics["evidence_active"]) for p in posteriors]
    if len(set(actives)) > 1:
        listing = ", ".join(f"{m.name!r}: {list(a)}" for m, a in zip(models, actives, strict=True))
        raise ValueError(
            "the models' likelihoods use different summaries (a summary constant over one model's "
            f"design is left out of its likelihood): {listing}; drop the summaries that do not vary"
        )
    log_z = np.array([np.nan if p.log_evidence is None else p.log_evidence for p in posteriors], np.float64)
    log_z_se = np.array([p.diagnostics["log_evidence_se"] for p in posteriors], np.float64)
    probs, ses = probabilities_with_errors(log_z, log_z_se, model_prior)
    interval = probability_intervals(log_z, log_z_se, model_prior, np.random.default_rng(options.seed))
    validated = [bool(p.diagnostics.get("validated", False)) for p in posteriors]
    misfit_p = [(p.diagnostics.get("observed_misfit") or {}).get("p_value") for p in posteriors]
    misspecified = bool(all(v is not None and v < MISFIT_ALPHA for v in misfit_p))
    sims = np.array([[p.num_simulations for p in posteriors]])
    names = tuple(m.name for m in models)
    return ModelChoiceResult(
        names=names,
        probabilities=probs,
        standard_errors=ses,
        log_evidence=log_z,
        log_evidence_errors=log_z_se,
        probability_upper_bounds=np.full(len(models), np.nan),
        model_prior=model_prior,
        threshold=float("nan"),
        thresholds=np.array([np.nan]),
        probability_history=probs[None, :],
        standard_error_history=ses[None, :],
        simulations_per_step=sims,
        posteriors=tuple(posteriors),
        num_simulations=int(sims.sum()),
        seed=options.seed,
        stop_reason=_stop_reason(models, validated, misspecified),
        wall_time=time.perf_counter() - t_start,
        metadata={
            "method": METHOD,
            "validated": validated,
            "probability_interval_95": interval.tolist(),
            "misfit_p_values": misfit_p,
            "misspecified": misspecified,
            **{k: _jsonable(v) for k, v in measured.items()},
            **(options.metadata or {}),
        },
        prior_edge=check_prior_edges(names, posteriors),
    )


def _stop_reason(models: list[Model], validated: list[bool], misspecified: bool) -> str:
    failed = [m.name for m, v in zip(models, validated, strict=True) if not v]
    stop = "every model's emulator validated on held-out simulations"
    if failed:
        stop = f"UNTRUSTED: the emulator of {failed} failed validation, so its evidence is not trustworthy"
    if misspecified:
        stop += (
            f"; MISSPECIFIED: no model reproduces the observed summaries within the noise (misfit p < "
            f"{MISFIT_ALPHA} for every model), so the probabilities rank misfits, not models that could "
            "have made the data"
        )
    return stop


def _jsonable(value: Any) -> Any:
    """A measurement error or discrepancy for the result's metadata."""
    if hasattr(value, "describe"):
        return value.describe()
    try:
        return np.asarray(value, np.float64).tolist()
    except (TypeError, ValueError):
        return repr(value)
