"""The criticism loop: predictive -> misfits -> causes -> extension -> gain -> report."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.criticism.causes import Catalogue
from jaxabc.criticism.extend import refit
from jaxabc.criticism.gain import held_out_gain
from jaxabc.criticism.pipeline import Pipeline
from jaxabc.criticism.power import CandidateObservables, annotate_causes, design_advice, detection_power, power_key
from jaxabc.criticism.predictive import (
    IndexSpec,
    normalise_groups,
    normalise_mask,
    posterior_predictive,
    simulate_many,
)
from jaxabc.criticism.report import CritiqueReport
from jaxabc.executors import get_executor
from jaxabc.results import ABCResult

__all__ = ["critique"]


def _check_simulator(simulate: Callable, dim: int, num_summaries: int) -> None:
    try:
        out = jax.eval_shape(simulate, jax.random.key(0), jnp.zeros((dim,), jnp.float32))
    except Exception as exc:
        raise TypeError(
            f"could not trace simulate_with_effects(key, theta_full) with theta_full of shape ({dim},) "
            f"(base parameters, then one entry per catalogue effect): {exc}.  Pass executor='serial' "
            "or 'process_pool' for a simulator that is not JAX code"
        ) from exc
    if tuple(out.shape) != (num_summaries,):
        raise ValueError(
            f"simulate_with_effects returns shape {tuple(out.shape)} but observed has shape ({num_summaries},)"
        )


def critique(
    result: ABCResult,
    simulate_with_effects: Callable,
    observed: Any,
    catalogue: Catalogue,
    held_out: IndexSpec | Sequence[str] | None = None,
    seed: int = 0,
    *,
    summary_names: Sequence[str] | None = None,
    groups: Mapping[str, IndexSpec] | None = None,
    num_draws: int = 200,
    num_replicates: int = 200,
    num_gradient_replicates: int | None = None,
    num_refit_iterations: int = 4,
    alpha: float = 0.01,
    correction: str = "holm",
    cause_alpha: float = 0.01,
    ambiguity_cosine: float = 0.95,
    invisible_snr: float = 3.0,
    extend: bool = True,
    refit_base: bool = True,
    extend_options: dict | None = None,
    executor: Any = None,
    level: float = 0.9,
    num_power_replicates: int = 20,
    power_threshold: float = 0.5,
    candidates: CandidateObservables | None = None,
) -> CritiqueReport:
    """Criticise a calibrated simulator: what it gets wrong, why, the extension, and the gain.

    Parameters
    ----------
    result : ABCResult
        The base calibration (particles of shape (n, d)).
    simulate_with_effects : callable ``(key, theta_full) -> summaries``
        ``theta_full`` has shape ``(d + K,)``: the ``d`` base parameters in the order of
        ``result.prior.names``, then one parameter per effect in catalogue order; effects at their
        null values must reproduce the base simulator.  Returns shape ``(s,)`` like ``observed``.
        A JAX function (vmapped in-process) unless ``executor`` says otherwise.
    observed : array_like, shape (s,)
        All summaries: those used for the base fit and the held-out ones.
    catalogue : Catalogue
    held_out : indices, slice, boolean mask or group names, optional
        Summaries *not* used to fit ``result``: tested in their own family, and the ground on
        which the gain is measured.
    seed : int
        The only source of randomness.
    summary_names : sequence of str, optional
    groups : mapping of str to slice or indices, optional
        Named regions of the summary vector (e.g. ``{"g(r) first peak": slice(10, 16)}``).
    num_draws : int
        Posterior predictive draws (one seed each).
    num_replicates : int
        Replicate seeds at the Bayes estimate (the simulation-noise yardstick).
    num_gradient_replicates : int, optional
        Replicate keys reused for each finite difference (common random numbers); default
        ``min(num_replicates, 64)``.
    num_refit_iterations : int
        Gauss-Newton steps that move the base parameters from the Bayes estimate to the local
        best fit of the fitted summaries before testing (0: test at the Bayes estimate).
    alpha : float
        Family-wise level of the misfit tests (split equally between the fitted and held-out
        families).  1 % by default: the calibration is linearised around the local fit, and on
        the LJ surrogate the measured false-alarm rate at 1 % is about 5 % over null seeds
        (rare noise outliers plus curvature), which is the most a "flag nothing in 95 %" rule
        allows.
    correction : {"holm", "bh"}
        Holm (family-wise error) or Benjamini-Hochberg (false discovery rate).
    cause_alpha : float
        Level of the Holm-adjusted cause tests.
    ambiguity_cosine : float
        |cos| between projected effect signatures above which two effects are "ambiguous".
    invisible_snr : float
        Largest signal (noise sd) over an effect's prior below which it is "invisible".
    extend : bool
        Refit the top cause when something is flagged.
    refit_base : bool
        Also refit the base model with the extension's distance and settings, so that the gain
        compares like with like (otherwise the gain uses ``result``'s posterior).
    extend_options : dict, optional
        Passed to :func:`jaxabc.run` for the refits (``algorithm``, ``num_particles``,
        ``num_steps``, algorithm options).
    executor : str or Executor, optional
        Where simulations run (default in-process vmap).
    level : float
        Predictive band level in the report.
    num_power_replicates : int
        Replicate data sets per effect with an ``expected`` strength for its detection power
        (:mod:`jaxabc.criticism.power`): simulated from the base posterior with the effect at
        that strength, each analysed by the same refit, misfit tests, ranking and joint test as
        the observed data; the power comes with its binomial standard error (about 0.11 at 20
        data sets and power 0.5).  0 turns it off.  Each data set costs about what the analysis
        of the observed data costs without its posterior predictive draws and extension.
    power_threshold : float
        An effect not selected by the joint test whose power is below this is reported as "not
        detectable with these data (power p +- se)", never as ruled out.
    candidates : CandidateObservables, optional
        Observables or state points the user could add: for the effects that are not detectable
        (or, without a power estimate, every effect with an expected strength) the report ranks
        them by the signal each would add after the base parameters absorb what they can
        (:func:`jaxabc.criticism.power.design_advice`).

    Returns
    -------
    CritiqueReport
    """
    obs = np.asarray(observed, np.float64).reshape(-1)
    if not np.all(np.isfinite(obs)):
        raise ValueError("observed contains NaN or infinite values: drop or impute them first")
    if not isinstance(catalogue, Catalogue):
        raise TypeError("catalogue must be a jaxabc.criticism.Catalogue of Effect objects")
    d, k_eff, s = result.prior.dim, len(catalogue), obs.size
    if result.particles.shape[1] != d:
        raise ValueError(f"result particles have {result.particles.shape[1]} columns, its prior {d}")
    ex = executor if hasattr(executor, "map") else get_executor(executor)
    if getattr(ex, "name", "") == "vmap":
        _check_simulator(simulate_with_effects, d + k_eff, s)
    names = list(summary_names) if summary_names is not None else [f"s{i}" for i in range(s)]
    group_idx = normalise_groups(groups, s)
    held = normalise_mask(held_out, s, group_idx)
    nulls = catalogue.nulls()
    root = jax.random.key(seed)
    k_pred, k_ext, k_base, k_epred, k_bpred = jax.random.split(root, 5)

    draws = result.resample(num_draws, seed=seed)
    full = lambda t: np.concatenate([np.atleast_2d(t), np.repeat(nulls[None], np.atleast_2d(t).shape[0], 0)], 1)  # noqa: E731
    theta_hat = full(result.bayes_estimate())[0]
    pred = posterior_predictive(
        simulate_with_effects,
        full(draws),
        theta_hat,
        k_pred,
        num_replicates,
        executor=ex,
        names=names,
        groups=group_idx,
    )

    # The base parameters absorb what they can: a few Gauss-Newton steps on the fitted summaries
    # from the Bayes estimate, with expectations over common random numbers.  An ABC posterior
    # mean is only as precise as its tolerance, and testing at a point that is off by a fraction
    # of the posterior width shows that curvature as spurious misfit.  Then the misfit tests and
    # the cause ranking: the same step runs on the replicate data sets of the power estimate.
    sd = np.sqrt(np.diag(result.covariance()))
    lo_b, hi_b = np.asarray(result.prior.low, float), np.asarray(result.prior.high, float)
    num_grad = num_gradient_replicates or min(len(pred.replicate_keys), 64)
    pipeline = Pipeline(
        simulate=simulate_with_effects,
        executor=ex,
        catalogue=catalogue,
        num_base=d,
        held_out=held,
        groups=group_idx,
        low=lo_b,
        high=hi_b,
        steps=np.maximum(0.5 * sd, 1e-3 * (hi_b - lo_b)),
        num_gradient_replicates=num_grad,
        num_refit_iterations=num_refit_iterations,
        alpha=alpha,
        correction=correction,
        cause_alpha=cause_alpha,
        ambiguity_cosine=ambiguity_cosine,
        invisible_snr=invisible_snr,
        level=level,
    )
    diagnosis = pipeline.diagnose(obs, pred)
    base_pred, pred, mis, causes = pred, diagnosis.predictive, diagnosis.misfits, diagnosis.causes
    fitted = diagnosis.fitted
    powers = {}
    if num_power_replicates and any(e.expected is not None for e in catalogue):
        powers = detection_power(pipeline, result, base_pred, power_key(root), int(num_power_replicates))
    low_power = [
        n
        for n, pw in powers.items()
        if n not in causes.needed and not (np.isfinite(pw.power) and pw.power >= power_threshold)
    ]
    if candidates is not None:
        wanted = low_power if powers else [e.name for e in catalogue if e.expected is not None]
        advice = design_advice(pipeline, diagnosis, candidates, wanted) if wanted else {}
    else:
        advice = {}
    annotate_causes(causes.causes, catalogue, powers, advice, causes.needed, power_threshold)
    report = CritiqueReport(
        misfits=mis.flagged,
        all_misfits=mis.misfits,
        causes=causes.causes,
        extension=None,
        base_refit=None,
        gain={},
        ambiguities=causes.ambiguities,
        predictive=pred,
        misfit_analysis=mis,
        cause_analysis=causes,
        catalogue=catalogue,
        observed=obs,
        held_out=held,
        base_result=result,
        settings=dict(
            seed=seed,
            num_draws=num_draws,
            num_replicates=num_replicates,
            num_gradient_replicates=num_grad,
            alpha=alpha,
            correction=correction,
            cause_alpha=cause_alpha,
            ambiguity_cosine=ambiguity_cosine,
            invisible_snr=invisible_snr,
            level=level,
            num_power_replicates=int(num_power_replicates),
            power_threshold=power_threshold,
        ),
        power={n: pw.to_dict() for n, pw in powers.items()},
        design_advice=advice,
        power_estimates=powers,
    )
    visible = [c for c in causes.causes if not c.invisible]
    if not (extend and mis.flagged and visible):
        return report

    top = visible[0]
    opts = dict(extend_options or {})
    ext = refit(
        result,
        simulate_with_effects,
        obs,
        catalogue,
        [top.name],
        fitted,
        pred.noise_cov,
        seed=int(jax.random.randint(k_ext, (), 0, 2**30)),
        executor=ex,
        **opts,
    )
    base = None
    if refit_base:
        base = refit(
            result,
            simulate_with_effects,
            obs,
            catalogue,
            [],
            fitted,
            pred.noise_cov,
            seed=int(jax.random.randint(k_base, (), 0, 2**30)),
            executor=ex,
            **opts,
        )
    slot = catalogue.index(top.name)

    def ext_full(t: np.ndarray) -> np.ndarray:
        out = full(t[:, :d])
        out[:, d + slot] = t[:, d]
        return out

    k1, k2 = jax.random.split(k_epred)
    ext_draws = simulate_many(
        simulate_with_effects, jax.random.split(k1, num_draws), ext_full(ext.resample(num_draws, seed=seed + 1)), ex
    )
    ext_reps = simulate_many(
        simulate_with_effects,
        jax.random.split(k2, num_replicates),
        np.repeat(ext_full(ext.bayes_estimate()[None]), num_replicates, 0),
        ex,
    )
    if base is not None:
        base_draws = simulate_many(
            simulate_with_effects,
            jax.random.split(k_bpred, num_draws),
            full(base.resample(num_draws, seed=seed + 2)),
            ex,
        )
    else:
        base_draws = pred.draws
    ok = lambda a: a[np.all(np.isfinite(a), axis=1)]  # noqa: E731
    gain = held_out_gain(
        obs,
        held & pred.active,
        ok(base_draws),
        ok(ext_draws),
        ok(ext_reps),
        pred.noise_cov,
        extension=ext,
        effect=catalogue[top.name],
        effect_column=d,
        level=level,
        seed=seed,
    )
    gain["effect"] = top.name
    report.extension, report.base_refit, report.gain = ext, base, gain
    report.extension_draws, report.base_draws = ok(ext_draws), ok(base_draws)
    return report
