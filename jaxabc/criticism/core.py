"""The criticism loop: predictive -> misfits -> causes -> extension -> gain -> report."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.criticism.causes import Catalogue
from jaxabc.criticism.extend import refit
from jaxabc.criticism.gain import held_out_gain
from jaxabc.criticism.pipeline import Diagnosis, Pipeline
from jaxabc.criticism.power import (
    CandidateObservables,
    EffectPower,
    annotate_causes,
    design_advice,
    detection_power,
    power_key,
)
from jaxabc.criticism.predictive import (
    IndexSpec,
    PosteriorPredictive,
    normalise_groups,
    normalise_mask,
    posterior_predictive,
    simulate_many,
)
from jaxabc.criticism.report import CritiqueReport
from jaxabc.executors import get_executor
from jaxabc.noise import DISCREPANCY_PREFIX
from jaxabc.priors import Uniform
from jaxabc.results import ABCResult

__all__ = ["critique", "without_discrepancy"]


def without_discrepancy(result: ABCResult) -> ABCResult:
    """``result``'s marginal over the simulator's own parameters: the discrepancy sds dropped.

    A calibration with a model-discrepancy term (``jaxabc.run(..., discrepancy=...)``) appends
    one ``discrepancy_sd[<group>]`` column per group; the simulator takes only the others, and
    so does :func:`critique`.  Weights, thresholds and the run's effective sample size are kept;
    per-parameter diagnostics and the simulation records (full theta) are dropped, since their
    columns would no longer match.  Returns ``result`` itself when it has no such column.

    Raises
    ------
    TypeError
        For a prior that is not a :class:`jaxabc.Uniform` box (the only kind a discrepancy fit
        builds).
    """
    keep = [i for i, n in enumerate(result.names) if not n.startswith(DISCREPANCY_PREFIX)]
    if len(keep) == len(result.names):
        return result
    prior = result.prior
    if not isinstance(prior, Uniform):
        raise TypeError(f"without_discrepancy needs a Uniform prior, got {type(prior).__name__}")
    sub = Uniform(
        low=np.asarray(prior.low)[keep].tolist(),
        high=np.asarray(prior.high)[keep].tolist(),
        names=tuple(prior.names[i] for i in keep),
        units=tuple(prior.units[i] for i in keep) if prior.units else None,
    )
    particles = np.asarray(result.particles)[:, keep]
    return replace(result, particles=particles, prior=sub, diagnostics={}, records={}, check=False)


def _refuse_discrepancy(result: ABCResult) -> None:
    extra = [n for n in result.names if n.startswith(DISCREPANCY_PREFIX)]
    if extra:
        raise ValueError(
            f"result has model-discrepancy columns {extra}: critique asks what the simulator itself "
            "misses, and simulate_with_effects takes the simulator's parameters only.  Pass "
            "jaxabc.criticism.without_discrepancy(result), its marginal over those parameters"
        )


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
    base_prior: str | tuple[Any, Any] = "free",
) -> CritiqueReport:
    """Criticise a calibrated simulator: what it gets wrong, why, the extension, and the gain.

    Parameters
    ----------
    result : ABCResult
        The base calibration, particles (n, d); not a fit with discrepancy columns (ValueError).
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
        families).  1 % by default, because the tests linearise the model around the fit and
        curvature adds false alarms beyond the nominal level.
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
    base_prior : {"free", "prior"} or (mean, sd)
        What the base parameters may absorb: anything (``"free"``), or only what a Gaussian
        prior allows -- ``result.prior``'s mean and covariance, or ``(mean, sd)`` of shape (d,)
        -- as a MAP refit with the prior's spread in the null (for a box that is knowledge).

    Returns
    -------
    CritiqueReport
    """
    obs = _validated_observed(observed, result, catalogue)
    prior_precision, prior_centre = _base_prior_moments(base_prior, result)
    ex = executor if hasattr(executor, "map") else get_executor(executor)
    if getattr(ex, "name", "") == "vmap":
        _check_simulator(simulate_with_effects, result.prior.dim + len(catalogue), obs.size)
    names = list(summary_names) if summary_names is not None else [f"s{i}" for i in range(obs.size)]
    group_idx = normalise_groups(groups, obs.size)
    held = normalise_mask(held_out, obs.size, group_idx)
    problem = _Problem(
        result, simulate_with_effects, obs, catalogue, held, group_idx, ex, seed, num_draws, num_replicates
    )
    root = jax.random.key(seed)
    k_pred, k_ext, k_base, k_epred, k_bpred = jax.random.split(root, 5)
    pred = _base_predictive(problem, k_pred, names)
    num_grad = num_gradient_replicates or min(len(pred.replicate_keys), 64)
    settings = dict(
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
        base_prior=base_prior if isinstance(base_prior, str) else "gaussian",
    )
    pipeline = _make_pipeline(problem, num_refit_iterations, settings)
    pipeline.prior_precision, pipeline.prior_centre = prior_precision, prior_centre
    diagnosis = pipeline.diagnose(obs, pred)
    powers, advice = _power_and_advice(problem, pipeline, diagnosis, pred, root, settings, candidates)
    annotate_causes((causes := diagnosis.causes).causes, catalogue, powers, advice, causes.needed, power_threshold)
    report = _initial_report(problem, diagnosis, settings, powers, advice)
    visible = [c for c in causes.causes if not c.invisible]
    if extend and diagnosis.misfits.flagged and visible:
        keys = (k_ext, k_base, k_epred, k_bpred)
        _add_extension(report, problem, diagnosis, visible[0].name, keys, refit_base, extend_options)
    return report


def _base_prior_moments(base_prior: Any, result: ABCResult) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(precision (d, d), centre (d,)) of the base parameters' Gaussian prior, or (None, None).

    Raises ValueError for an unknown name, wrongly shaped or non-positive sds.
    """
    d = result.prior.dim
    if isinstance(base_prior, str):
        if base_prior == "free":
            return None, None
        if base_prior != "prior":
            raise ValueError(f"base_prior={base_prior!r}: use 'free', 'prior' or a (mean, sd) pair")
        prior = result.prior
        if type(prior).__name__ == "Uniform":
            lo, hi = np.asarray(prior.low, float), np.asarray(prior.high, float)
            return np.diag(12.0 / (hi - lo) ** 2), 0.5 * (lo + hi)
        draws = np.asarray(prior.sample(jax.random.key(0), 20000), float)  # moments only: fixed key
        return np.linalg.inv(np.cov(draws.T).reshape(d, d)), draws.mean(0)
    try:
        mean, sd = (np.asarray(x, float).reshape(-1) for x in base_prior)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"base_prior must be 'free', 'prior' or (mean, sd) arrays of shape ({d},)") from exc
    if mean.shape != (d,) or sd.shape != (d,):
        raise ValueError(f"base_prior (mean, sd) must each have shape ({d},), got {mean.shape} and {sd.shape}")
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(sd)) and np.all(sd > 0)):
        raise ValueError("base_prior sds must be finite and positive and its mean finite")
    return np.diag(sd**-2.0), mean


def _validated_observed(observed: Any, result: ABCResult, catalogue: Any) -> np.ndarray:
    """``observed`` as a float64 vector (s,), after the checks that need no simulation.

    Raises ValueError for non-finite data, particles that do not match the prior or
    model-discrepancy columns, and TypeError when ``catalogue`` is not a :class:`Catalogue`.
    """
    _refuse_discrepancy(result)
    obs = np.asarray(observed, np.float64).reshape(-1)
    if not np.all(np.isfinite(obs)):
        raise ValueError("observed contains NaN or infinite values: drop or impute them first")
    if not isinstance(catalogue, Catalogue):
        raise TypeError("catalogue must be a jaxabc.criticism.Catalogue of Effect objects")
    d = result.prior.dim
    if result.particles.shape[1] != d:
        raise ValueError(f"result particles have {result.particles.shape[1]} columns, its prior {d}")
    return obs


@dataclass(frozen=True)
class _Problem:
    """The validated inputs that every step of one :func:`critique` call shares.

    ``observed`` has shape (s,), ``held_out`` is a boolean mask (s,), ``groups`` maps names to
    index arrays; ``simulate`` takes ``theta_full`` (d + K,).
    """

    result: ABCResult
    simulate: Callable
    observed: np.ndarray
    catalogue: Catalogue
    held_out: np.ndarray
    groups: dict[str, np.ndarray]
    executor: Any
    seed: int
    num_draws: int
    num_replicates: int

    @property
    def num_base(self) -> int:
        """Number ``d`` of base parameters."""
        return self.result.prior.dim

    def with_nulls(self, theta: np.ndarray) -> np.ndarray:
        """Base parameters, shape (n, d) or (d,), followed by the effects' nulls; (n, d + K)."""
        rows = np.atleast_2d(theta)
        return np.concatenate([rows, np.repeat(self.catalogue.nulls()[None], rows.shape[0], 0)], 1)

    def with_effect(self, theta: np.ndarray, effect: str) -> np.ndarray:
        """Rows (n, d + 1) of an extension's parameters, base then ``effect``, as simulator
        inputs (n, d + K) with the other effects at null."""
        d = self.num_base
        out = self.with_nulls(theta[:, :d])
        out[:, d + self.catalogue.index(effect)] = theta[:, d]
        return out

    def simulate_at(self, key: jax.Array, thetas: np.ndarray) -> np.ndarray:
        """One simulation per row of ``thetas`` (n, d + K), each with its own key split from
        ``key``; (n, s), NaN rows where a simulation failed."""
        return simulate_many(self.simulate, jax.random.split(key, thetas.shape[0]), thetas, self.executor)


def _base_predictive(problem: _Problem, key: jax.Array, names: list[str]) -> PosteriorPredictive:
    """The base calibration's posterior predictive (effects at null): ``num_draws`` posterior
    draws and ``num_replicates`` replicate seeds at its Bayes estimate."""
    result = problem.result
    draws = result.resample(problem.num_draws, seed=problem.seed)
    theta_hat = problem.with_nulls(result.bayes_estimate())[0]
    return posterior_predictive(
        problem.simulate,
        problem.with_nulls(draws),
        theta_hat,
        key,
        problem.num_replicates,
        executor=problem.executor,
        names=names,
        groups=problem.groups,
    )


# The settings of a critique call that the pipeline's tests take, by their Pipeline field names.
_TEST_SETTINGS = ("alpha", "correction", "cause_alpha", "ambiguity_cosine", "invisible_snr", "level")


def _make_pipeline(problem: _Problem, num_refit_iterations: int, settings: dict[str, Any]) -> Pipeline:
    """The data-dependent steps with the run's settings (levels, thresholds, gradient replicates).

    The base parameters absorb what they can: a few Gauss-Newton steps on the fitted summaries
    from the Bayes estimate, with expectations over common random numbers.  An ABC posterior
    mean is only as precise as its tolerance, and testing at a point that is off by a fraction
    of the posterior width shows that curvature as spurious misfit.  Finite-difference steps
    are half a posterior sd (at least 1e-3 of the prior range).  The same pipeline runs on the
    replicate data sets of the power estimate.
    """
    result = problem.result
    sd = np.sqrt(np.diag(result.covariance()))
    lo_b, hi_b = np.asarray(result.prior.low, float), np.asarray(result.prior.high, float)
    return Pipeline(
        simulate=problem.simulate,
        executor=problem.executor,
        catalogue=problem.catalogue,
        num_base=problem.num_base,
        held_out=problem.held_out,
        groups=problem.groups,
        low=lo_b,
        high=hi_b,
        steps=np.maximum(0.5 * sd, 1e-3 * (hi_b - lo_b)),
        num_gradient_replicates=settings["num_gradient_replicates"],
        num_refit_iterations=num_refit_iterations,
        **{name: settings[name] for name in _TEST_SETTINGS},
    )


def _power_and_advice(
    problem: _Problem,
    pipeline: Pipeline,
    diagnosis: Diagnosis,
    base_predictive: PosteriorPredictive,
    root: jax.Array,
    settings: dict[str, Any],
    candidates: CandidateObservables | None,
) -> tuple[dict[str, EffectPower], dict[str, list[dict]]]:
    """Detection power of the effects with an expected strength, and design advice.

    Power uses ``settings["num_power_replicates"]`` data sets per effect (none when 0).  Advice
    covers the effects not named whose power is below ``settings["power_threshold"]`` or,
    without a power estimate, every effect with an expected strength; ``{}`` without
    ``candidates``.
    """
    num_datasets, threshold = settings["num_power_replicates"], settings["power_threshold"]
    catalogue = problem.catalogue
    powers: dict[str, EffectPower] = {}
    if num_datasets and any(e.expected is not None for e in catalogue):
        powers = detection_power(pipeline, problem.result, base_predictive, power_key(root), num_datasets)
    if candidates is None:
        return powers, {}
    low_power = [
        n
        for n, pw in powers.items()
        if n not in diagnosis.causes.needed and not (np.isfinite(pw.power) and pw.power >= threshold)
    ]
    wanted = low_power if powers else [e.name for e in catalogue if e.expected is not None]
    return powers, (design_advice(pipeline, diagnosis, candidates, wanted) if wanted else {})


def _initial_report(
    problem: _Problem,
    diagnosis: Diagnosis,
    settings: dict[str, Any],
    powers: dict[str, EffectPower],
    advice: dict[str, list[dict]],
) -> CritiqueReport:
    """The report of the diagnosis, without extension or gain."""
    mis, causes = diagnosis.misfits, diagnosis.causes
    return CritiqueReport(
        misfits=mis.flagged,
        all_misfits=mis.misfits,
        causes=causes.causes,
        extension=None,
        base_refit=None,
        gain={},
        ambiguities=causes.ambiguities,
        predictive=diagnosis.predictive,
        misfit_analysis=mis,
        cause_analysis=causes,
        catalogue=problem.catalogue,
        observed=problem.observed,
        held_out=problem.held_out,
        base_result=problem.result,
        settings=settings,
        power={n: pw.to_dict() for n, pw in powers.items()},
        design_advice=advice,
        power_estimates=powers,
    )


def _add_extension(
    report: CritiqueReport,
    problem: _Problem,
    diagnosis: Diagnosis,
    effect: str,
    keys: tuple[jax.Array, jax.Array, jax.Array, jax.Array],
    refit_base: bool,
    extend_options: dict | None,
) -> None:
    """Refit with ``effect`` added (and the base model alike) and measure the held-out gain.

    ``keys`` are the run's (extension refit, base refit, extension predictive, base
    predictive) keys.  Fills ``report.extension``, ``base_refit`` (None without
    ``refit_base``: the gain then uses the base calibration's draws), ``gain``,
    ``extension_draws`` and ``base_draws`` (simulation failures dropped).
    """
    k_ext, k_base, k_epred, k_bpred = keys
    pred, seed = diagnosis.predictive, problem.seed
    ext = _refit(problem, diagnosis, [effect], k_ext, extend_options)
    base = _refit(problem, diagnosis, [], k_base, extend_options) if refit_base else None
    k1, k2 = jax.random.split(k_epred)
    ext_draws = problem.simulate_at(k1, problem.with_effect(ext.resample(problem.num_draws, seed=seed + 1), effect))
    ext_reps = problem.simulate_at(
        k2, np.repeat(problem.with_effect(ext.bayes_estimate()[None], effect), problem.num_replicates, 0)
    )
    if base is not None:
        base_draws = problem.simulate_at(k_bpred, problem.with_nulls(base.resample(problem.num_draws, seed=seed + 2)))
    else:
        base_draws = pred.draws
    gain = held_out_gain(
        problem.observed,
        problem.held_out & pred.active,
        _finite_rows(base_draws),
        _finite_rows(ext_draws),
        _finite_rows(ext_reps),
        pred.noise_cov,
        extension=ext,
        effect=problem.catalogue[effect],
        effect_column=problem.num_base,
        level=report.settings["level"],
        seed=seed,
    )
    report.extension, report.base_refit, report.gain = ext, base, {**gain, "effect": effect}
    report.extension_draws, report.base_draws = _finite_rows(ext_draws), _finite_rows(base_draws)


def _refit(
    problem: _Problem, diagnosis: Diagnosis, effects: list[str], key: jax.Array, extend_options: dict | None
) -> ABCResult:
    """The base model plus ``effects`` refitted to the fitted summaries (:func:`refit`), with a
    seed drawn from ``key`` and the local noise covariance as the distance's metric."""
    return refit(
        problem.result,
        problem.simulate,
        problem.observed,
        problem.catalogue,
        effects,
        diagnosis.fitted,
        diagnosis.predictive.noise_cov,
        seed=int(jax.random.randint(key, (), 0, 2**30)),
        executor=problem.executor,
        **dict(extend_options or {}),
    )


def _finite_rows(a: np.ndarray) -> np.ndarray:
    """The rows of ``a`` (n, s) whose simulation succeeded (every entry finite)."""
    return a[np.all(np.isfinite(a), axis=1)]
