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

from jaxabc.errors import PriorEdgeWarning
from jaxabc.model_choice.result import ModelChoiceResult, _file_stem, check_prior_edges, probabilities_with_errors
from jaxabc.seeding import seed_from_key

__all__ = ["METHOD", "MISFIT_ALPHA", "probability_intervals", "run_from_driver", "run_model_choice_surrogate"]

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
        :func:`jaxabc.run`, which calibrates each model (``jaxabc.run`` passes itself; the
        default imports it).
    observation_error, discrepancy : optional
        The data's measurement error and a model discrepancy, as for :func:`jaxabc.run`, the
        same for every model: given to each model's surrogate builder
        (:func:`jaxabc.surrogate.build`, which takes the raw values), so each synthetic
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
        ``standard_errors`` understate once those errors approach 1).  A model whose emulator failed
        is flagged in ``stop_reason``: its evidence is not trustworthy.  When every model fails
        the observed-data misfit check (:func:`jaxabc.surrogate.evidence.observed_misfit`,
        p < :data:`MISFIT_ALPHA`), ``metadata["misspecified"]`` is True and ``stop_reason`` says
        so: the probabilities then rank misfits.

    Raises
    ------
    ValueError
        Options the evidence cannot use, or models whose likelihoods use different summaries (a
        summary constant over one model's design but not another's): their evidences would be
        densities of different data.
    """
    import importlib

    # By name at call time when not given: the driver imports this module, not the other way.
    calibrate: Callable[..., Any] = driver if driver is not None else importlib.import_module("jaxabc.run").run
    from jaxabc.model_choice.core import _model_prior, as_models
    from jaxabc.surrogate import build
    from jaxabc.surrogate.evidence import with_evidence

    t0 = time.perf_counter()
    banned = sorted({"mode", "max_outputs", "observed", "max_simulations"} & set(surrogate_options))
    if banned:
        raise ValueError(
            f"surrogate model choice sets {banned} itself: the evidence needs the synthetic likelihood "
            "of all the raw summaries (no principal-component projection)"
        )
    ms = as_models(list(models))
    prior_m = _model_prior(model_prior, len(ms))
    obs = np.asarray(observed, np.float64)
    if int(simulations_per_model) < 1:
        raise ValueError(f"simulations_per_model must be positive, got {simulations_per_model}")
    key = jax.random.key(seed)
    folder = None if checkpoint_dir is None else Path(checkpoint_dir)
    posteriors = []
    measured = {
        k: v for k, v in (("observation_error", observation_error), ("discrepancy", discrepancy)) if v is not None
    }
    for m, model in enumerate(ms):
        model_seed = seed_from_key(jax.random.fold_in(key, m))
        algo = build(
            model.prior,
            num_particles,
            observed=obs,
            max_simulations=int(simulations_per_model),
            max_outputs=max(obs.size, 1),
            **measured,
            **surrogate_options,
        )
        algo = with_evidence(algo, model.prior, obs, seed=model_seed)
        ckpt = None if folder is None else folder / _file_stem(model.name)
        model_resume = bool(resume and ckpt is not None and (ckpt / "checkpoint.npz").exists())
        with warnings.catch_warnings():
            # A model finished in an earlier sitting is reused on purpose: no "nothing was run".
            warnings.filterwarnings("ignore", message="the run in .* had already ended")
            # The prior-edge check runs once below, per model and naming it.
            warnings.simplefilter("ignore", PriorEdgeWarning)
            posterior = calibrate(
                algo,
                model.simulate,
                model.prior,
                obs,
                seed=model_seed,
                executor=executor,
                max_simulations=int(simulations_per_model),
                checkpoint_dir=ckpt,
                resume=model_resume,
                overwrite=overwrite and not model_resume,
                simulator_id=None if simulator_id is None else f"{simulator_id}:{model.name}",
                progress=progress,
                dtype="float64",
                metadata={"model": model.name},
            )
        posteriors.append(posterior)
    actives = [tuple(p.diagnostics["evidence_active"]) for p in posteriors]
    if len(set(actives)) > 1:
        listing = ", ".join(f"{m.name!r}: {list(a)}" for m, a in zip(ms, actives, strict=True))
        raise ValueError(
            "the models' likelihoods use different summaries (a summary constant over one model's "
            f"design is left out of its likelihood): {listing}; drop the summaries that do not vary"
        )
    log_z = np.array([np.nan if p.log_evidence is None else p.log_evidence for p in posteriors], np.float64)
    log_z_se = np.array([p.diagnostics["log_evidence_se"] for p in posteriors], np.float64)
    probs, ses = probabilities_with_errors(log_z, log_z_se, prior_m)
    interval = probability_intervals(log_z, log_z_se, prior_m, np.random.default_rng(seed))
    validated = [bool(p.diagnostics.get("validated", False)) for p in posteriors]
    failed = [m.name for m, v in zip(ms, validated, strict=True) if not v]
    stop = "every model's emulator validated on held-out simulations"
    if failed:
        stop = f"UNTRUSTED: the emulator of {failed} failed validation, so its evidence is not trustworthy"
    misfit_p = [(p.diagnostics.get("observed_misfit") or {}).get("p_value") for p in posteriors]
    misspecified = bool(all(v is not None and v < MISFIT_ALPHA for v in misfit_p))
    if misspecified:
        stop += (
            f"; MISSPECIFIED: no model reproduces the observed summaries within the noise (misfit p < "
            f"{MISFIT_ALPHA} for every model), so the probabilities rank misfits, not models that could "
            "have made the data"
        )
    sims = np.array([[p.num_simulations for p in posteriors]])
    names = tuple(m.name for m in ms)
    edges = check_prior_edges(names, posteriors)
    result = ModelChoiceResult(
        names=names,
        probabilities=probs,
        standard_errors=ses,
        log_evidence=log_z,
        log_evidence_errors=log_z_se,
        probability_upper_bounds=np.full(len(ms), np.nan),
        model_prior=prior_m,
        threshold=float("nan"),
        thresholds=np.array([np.nan]),
        probability_history=probs[None, :],
        standard_error_history=ses[None, :],
        simulations_per_step=sims,
        posteriors=tuple(posteriors),
        num_simulations=int(sims.sum()),
        seed=int(seed),
        stop_reason=stop,
        wall_time=time.perf_counter() - t0,
        metadata={
            "method": METHOD,
            "validated": validated,
            "probability_interval_95": interval.tolist(),
            "misfit_p_values": misfit_p,
            "misspecified": misspecified,
            **{k: _jsonable(v) for k, v in measured.items()},
            **(metadata or {}),
        },
        prior_edge=edges,
    )
    result.sensitivity()
    return result


def _jsonable(value: Any) -> Any:
    """A measurement error or discrepancy for the result's metadata."""
    if hasattr(value, "describe"):
        return value.describe()
    try:
        return np.asarray(value, np.float64).tolist()
    except (TypeError, ValueError):
        return repr(value)


def run_from_driver(arguments: dict[str, Any], driver: Callable[..., Any]) -> Any:
    """``jaxabc.run(models, observed=..., method="surrogate", max_simulations=N)`` (its
    ``locals()`` and the function itself): ``N`` split evenly over the models."""
    from jaxabc.model_choice.core import as_models, check_driver_arguments

    models = check_driver_arguments(arguments)
    options = dict(arguments["algorithm_options"])
    options.pop("method")
    unsupported = [
        k
        for k in ("num_steps", "final_threshold", "max_wall_time", "stop_after_iterations")
        if arguments[k] is not None
    ]
    if arguments["distance"] != "mean_abs":
        unsupported.append("distance")
    if unsupported:
        raise TypeError(f"model choice with method='surrogate' does not take {unsupported}")
    total = arguments["max_simulations"]
    if total is None:
        raise TypeError("method='surrogate' needs max_simulations (the total, split evenly over the models)")
    num_models = len(as_models(models))
    return run_model_choice_surrogate(
        models,
        arguments["observed"],
        int(total) // max(num_models, 1),
        2000 if arguments["num_particles"] is None else arguments["num_particles"],
        arguments["seed"],
        executor=arguments["executor"],
        checkpoint_dir=arguments["checkpoint_dir"],
        resume=arguments["resume"],
        overwrite=arguments["overwrite"],
        simulator_id=arguments["simulator_id"],
        progress=arguments["progress"],
        metadata=arguments["metadata"],
        driver=driver,
        observation_error=arguments.get("observation_error"),
        discrepancy=arguments.get("discrepancy"),
        **options,
    )
