"""What a surrogate run reports: the per-update :class:`SurrogateInfo`, the stop reason, and
the result's diagnostics (design, validation, emulator, posterior predictive check)."""

from __future__ import annotations

import warnings
from typing import Any, NamedTuple

import jax
import numpy as np

from jaxabc.surrogate import diagnostics, emulator, evidence
from jaxabc.surrogate._fit import ROLE_DESIGN, ROLE_FAILED_HOLDOUT, ROLE_HOLDOUT, fit_surrogate
from jaxabc.surrogate._posterior import IMPORTANCE_POOL_PER_DRAW, posterior_ess
from jaxabc.surrogate._settings import SurrogateSettings
from jaxabc.surrogate._state import PHASE_DONE, SurrogateState
from jaxabc.surrogate._support import single_threaded_blas

__all__ = [
    "MISFIT",
    "NOT_VALIDATED",
    "UNTESTED_SHARE_WARN",
    "SurrogateInfo",
    "failure_text",
    "finalize",
    "misfit_text",
    "step_info",
    "stop_reason",
]

#: The start of a stop reason whose posterior the emulator's validation does not back.
NOT_VALIDATED = "NOT VALIDATED: "
#: The start of a stop reason whose observed summaries the fitted model does not reproduce.
MISFIT = "MISFIT: "
#: Posterior share below the design level from which a failed validation names that band.
UNTESTED_SHARE_WARN = 0.25


class SurrogateInfo(NamedTuple):
    """What one surrogate ``init`` or ``update`` reports (all shape ()).

    The driver records ``threshold`` and ``acceptance_rate`` (properties, the names every
    algorithm's info has) in the result's history: ``result.thresholds`` is the held-out mean
    squared standardised error (``inf`` while the emulator is not trusted),
    ``result.acceptance_rates`` the held-out coverage.

    Attributes
    ----------
    generation_done : numpy.bool_
        Always True: every update is one round of design or validation.
    stop : numpy.bool_
        The run is over: validated, or flagged (or raised) with the budget spent.
    holdout_coverage : numpy.float64
        Share of held-out outputs inside their 95 % predictive intervals at the last
        validation; NaN before the first.
    holdout_mean_squared_error : numpy.float64
        Mean squared standardised error of the held-out outputs at the last validation; NaN
        before the first.
    emulator_trusted : numpy.bool_
        The lack-of-fit test and the joint (Mahalanobis) check have not failed, and the
        emulator-to-noise variance ratio over the posterior is at most ``max_emulator_ratio``
        (False while that ratio is unknown).
    ess : numpy.float64
        Effective sample size of the current posterior draws.
    validated : numpy.bool_
        Every check of the last validation passed (False before the first).
    failure : str
        Why the last validation failed, in words (empty when it passed or before one).
    """

    generation_done: np.bool_
    stop: np.bool_
    holdout_coverage: np.float64
    holdout_mean_squared_error: np.float64
    emulator_trusted: np.bool_
    ess: np.float64
    validated: np.bool_ = np.bool_(False)
    failure: str = ""

    @property
    def threshold(self) -> np.float64:
        """The history's ``threshold``: ``holdout_mean_squared_error`` when the emulator is
        trusted, ``inf`` otherwise."""
        return np.float64(float(self.holdout_mean_squared_error) if self.emulator_trusted else np.inf)

    @property
    def acceptance_rate(self) -> np.float64:
        """The history's ``acceptance``: ``holdout_coverage``."""
        return self.holdout_coverage


def step_info(settings: SurrogateSettings, state: SurrogateState) -> SurrogateInfo:
    """The :class:`SurrogateInfo` of ``state`` after an update."""
    trusted = (
        bool(state.lack_of_fit_ok)
        and bool(state.joint_ok)
        and float(state.emulator_ratio) <= settings.max_emulator_ratio
    )
    return SurrogateInfo(
        generation_done=np.bool_(True),
        stop=np.bool_(int(state.phase) == PHASE_DONE),
        holdout_coverage=np.float64(state.coverage),
        holdout_mean_squared_error=np.float64(state.mean_squared_error),
        emulator_trusted=np.bool_(trusted),
        ess=np.float64(posterior_ess(state, settings.num_chains, settings.abc is not None)),
        validated=np.bool_(state.validated),
        failure="" if bool(state.validated) else failure_text(state, settings.max_emulator_ratio),
    )


def stop_reason(record: dict, info: SurrogateInfo) -> str:
    """Why the run stopped, from the algorithm's ``settings`` record and the last info: the
    validation's numbers, prefixed :data:`NOT_VALIDATED` unless every check passed."""
    del record  # the info carries the verdict
    coverage, mean_squared = float(info.holdout_coverage), float(info.holdout_mean_squared_error)
    if bool(info.validated):
        return (
            f"emulator validated on held-out simulations (95 % coverage "
            f"{coverage:.2f}, mean squared standardised error {mean_squared:.2f})"
        )
    return NOT_VALIDATED + f"emulator failed validation ({info.failure or 'see diagnostics'})"


def finalize(settings: SurrogateSettings, state: SurrogateState) -> dict:
    """The result extras: ``{"ess": float, "diagnostics": dict}`` (JSON).

    Warns (RuntimeWarning) when the observed summaries lie outside the posterior predictive
    (p below :data:`.diagnostics.MISFIT_P_VALUE`) and when a finished run's posterior rests on
    fewer than :data:`.diagnostics.MIN_POSTERIOR_ESS` effective draws.
    """
    diag = run_diagnostics(settings, state)
    diag["observed_misfit"] = misfit = observed_misfit(settings, state)
    out: dict[str, Any] = {}
    if misfit is not None and misfit["p_value"] < diagnostics.MISFIT_P_VALUE:
        text = misfit_text(misfit)
        warnings.warn(text, RuntimeWarning, stacklevel=2)
        diag["warning"] = text
        out["stop_reason_prefix"] = (
            f"{MISFIT}the observed summaries lie outside the posterior predictive (p = {misfit['p_value']:.2g}); "
        )
    abc = settings.abc is not None
    ess = posterior_ess(state, settings.num_chains, abc)
    if int(state.phase) == PHASE_DONE:
        diag |= mcse_terms(settings, state, ess)
    if int(state.phase) == PHASE_DONE and ess < diagnostics.MIN_POSTERIOR_ESS:
        warnings.warn(
            f"surrogate: the posterior rests on an effective sample size of {ess:.0f} (below "
            f"{diagnostics.MIN_POSTERIOR_ESS}; sampler: {diag['posterior_sampler']}): its intervals and "
            "correlation are not resolved. A sharper posterior than the importance pool resolves "
            f"({IMPORTANCE_POOL_PER_DRAW} points per particle) needs more num_particles",
            RuntimeWarning,
            stacklevel=2,
        )
    if abc:
        diag |= {
            "mode": settings.mode,
            "abc_threshold": float(state.abc_threshold),
            "abc_generations": int(state.abc_generations),
            "abc_emulated_simulations": int(state.abc_emulated),
        }
    return {"ess": ess, "diagnostics": diag, **out}


def mcse_terms(settings: SurrogateSettings, state: SurrogateState, ess: float) -> dict:
    """The MCSE of the posterior mean ``(d + G,)`` with the emulator's error in it.

    ``mcse_sampling`` is the posterior sd over ``sqrt(ESS)``.  ``mcse_emulator`` is the
    posterior sd times the larger of ``sqrt(emulator_ratio)`` (an emulator error of that
    fraction of the noise shifts a likelihood's centre, and so the posterior mean, by about
    that fraction of a posterior sd) and the shift measured when the last held-out runs joined
    the fit (:func:`._validation.posterior_shift`).  ``mcse`` combines them in quadrature; it
    is what :meth:`jaxabc.ABCResult.mcse` reports.
    """
    lw = np.asarray(state.log_weights, np.float64)
    keep = np.isfinite(lw)
    draws = np.asarray(state.draws, np.float64)[keep]
    w = np.exp(lw[keep] - np.max(lw[keep]))
    w /= w.sum()
    sd = np.sqrt(w @ (draws - w @ draws) ** 2)
    sampling_part = sd / np.sqrt(max(ess, 1.0))
    ratio = float(state.emulator_ratio)
    shift = np.nan_to_num(np.abs(np.asarray(state.posterior_shift, np.float64)), nan=0.0)
    emulator_part = sd * np.maximum(np.sqrt(ratio) if np.isfinite(ratio) else np.inf, shift)
    return {
        "mcse": np.sqrt(sampling_part**2 + emulator_part**2).tolist(),
        "mcse_sampling": sampling_part.tolist(),
        "mcse_emulator": emulator_part.tolist(),
        "posterior_shift_in_sd": np.asarray(state.posterior_shift, np.float64).tolist(),
        "posterior_log_sd_change": np.asarray(state.log_sd_change, np.float64).tolist(),
    }


def run_diagnostics(settings: SurrogateSettings, state: SurrogateState) -> dict:
    """The design, validation, emulator and sampler entries of the result's diagnostics."""
    c = int(state.count)
    d = settings.box.num_theta
    abc = settings.abc is not None
    lengthscales = np.exp(state.hyper[:, 1 : 1 + d]) * (settings.box.high - settings.box.low)
    if abc:
        sampler = "APMCABC on the emulator"
    elif np.any(np.asarray(state.log_weights) != 0):
        sampler = "importance resampling (the NUTS chains disagreed)"
    else:
        sampler = "NUTS"
    return {
        "validated": bool(state.validated),
        "failure": "" if bool(state.validated) else failure_text(state, settings.max_emulator_ratio),
        "num_simulations": c,
        "num_failed_simulations": int(np.sum(~state.ok[:c])),
        "num_design": int(np.sum(np.isin(state.role[:c], (ROLE_DESIGN, ROLE_FAILED_HOLDOUT)))),
        "num_holdout": int(np.sum(state.role[:c] == ROLE_HOLDOUT)),
        "design_points": state.thetas[:c].tolist(),
        "design_ok": state.ok[:c].tolist(),
        "design_role": state.role[:c].tolist(),
        "design_replicate_group": state.group[:c].tolist(),
        "holdout_coverage_95": float(state.coverage),
        "holdout_mean_squared_error": float(state.mean_squared_error),
        "holdout_joint_mean_squared_error": float(state.joint_mean_squared_error),
        # numpy's stubs reject None as the fill (an object array, which is what JSON needs).
        "holdout_errors": np.where(np.isfinite(state.holdout_errors), state.holdout_errors, None).tolist(),  # pyright: ignore[reportAttributeAccessIssue]
        "lack_of_fit_ok": bool(state.lack_of_fit_ok),
        "targeted_holdout_max_error": float(state.targeted_max_error),
        "targeted_holdout_ok": bool(state.targeted_ok),
        "posterior_stable": bool(state.stable),
        "emulator_to_noise_variance": float(state.emulator_ratio),
        "posterior_share_below_design_level": float(state.untested_share),
        "lengthscales": lengthscales.tolist(),
        "amplitude_standardised": np.exp(state.hyper[:, 0]).tolist(),
        "noise_sd_standardised": np.exp(state.hyper[:, -1]).tolist(),
        "nuts_split_rhat": state.rhat.tolist(),
        "posterior_sampler": sampler,
        "rounds": int(state.round),
    } | emulator_variance_entries(settings, state)


def emulator_variance_entries(settings: SurrogateSettings, state: SurrogateState) -> dict:
    """The diagnostics of ``emulator_variance`` (none for ``"gp"``, so that default results
    keep their fields): the factor the last fit used (``emulator_variance_scale``), and the
    maximum-likelihood factor from every held-out run judged (``..._estimate``, with the
    standard error of its log and the number of errors it rests on), which a failed last
    validation measured but no fresh run checked."""
    if settings.emulator_variance == "gp":
        return {}
    factor, se_log, num = emulator.variance_scale_mle(
        state.judged_residual, state.judged_emulator_var, state.judged_noise_var
    )
    return {
        "emulator_variance": settings.emulator_variance,
        "emulator_variance_scale": float(state.variance_scale),
        "emulator_variance_scale_estimate": factor,
        "emulator_variance_scale_estimate_se_log": se_log if np.isfinite(se_log) else None,
        "emulator_variance_scale_estimate_errors": num,
    }


def observed_misfit(settings: SurrogateSettings, state: SurrogateState) -> dict | None:
    """The posterior predictive check of the observed summaries
    (:func:`.evidence.observed_misfit`) under the last fit; None before the run is done."""
    if int(state.phase) != PHASE_DONE:
        return None
    with jax.enable_x64(True), single_threaded_blas():
        transform, _, model, _ = fit_surrogate(settings, state)
        lw = np.asarray(state.log_weights, np.float64)
        x = settings.box.draws_to_unit(np.asarray(state.draws, np.float64))
        return evidence.observed_misfit(model, transform, x, np.exp(lw - np.max(lw)))


def failure_text(state: Any, max_emulator_ratio: float) -> str:
    """Why a validation failed, in words, from a state's validation fields
    (``emulator_ratio``, ``lack_of_fit_ok``, ``joint_ok``, ``holdout_errors``,
    ``untested_share``, ``coverage``); empty when nothing is wrong."""
    parts = []
    if float(state.emulator_ratio) > max_emulator_ratio:
        parts.append(
            f"the emulator's variance over the posterior is {float(state.emulator_ratio):.2g} times "
            "the simulator noise: the GP does not resolve the simulator (too rough, or too few runs)"
        )
    if not bool(state.lack_of_fit_ok):
        parts.append(
            "fitted noise far above the replicate scatter: the GP cannot represent the "
            "simulator (a discontinuity or a phase change?)"
        )
    if not bool(state.joint_ok):
        parts.append(
            f"held-out joint (Mahalanobis) error {float(state.joint_mean_squared_error):.2f} per output, "
            "too large for the modelled noise correlation: the summaries' joint noise is not captured"
        )
    if not bool(getattr(state, "targeted_ok", True)):
        parts.append(
            f"a held-out run where the emulator was least sure missed its prediction by "
            f"{float(state.targeted_max_error):.1f} sd: the emulator is wrong where the posterior "
            "could lie (a step or a narrow feature it smooths over?)"
        )
    if not bool(getattr(state, "stable", True)):
        shift, log_sd = np.asarray(state.posterior_shift), np.asarray(state.log_sd_change)
        parts.append(
            f"adding the held-out runs to the emulator moved the posterior (mean by up to "
            f"{np.max(np.abs(shift)):.2f} sd, an sd by up to {np.max(np.abs(np.expm1(log_sd))):.0%}): "
            "it still follows the emulator's error"
        )
    parts += holdout_failure_parts(state)
    if np.isfinite(state.coverage):
        parts.append(
            f"held-out 95 % coverage {float(state.coverage):.2f}, mean squared standardised "
            f"error {float(state.mean_squared_error):.2f}"
        )
    return "; ".join(parts)


def holdout_failure_parts(state: Any) -> list[str]:
    """The failed held-out runs, and the posterior's share in the band no design run enters
    when that share is at least :data:`UNTESTED_SHARE_WARN`, in words."""
    parts = []
    errors = np.asarray(state.holdout_errors)
    num_run = int(np.sum(np.any(np.isfinite(errors), axis=1)))
    if num_run < errors.shape[0]:
        text = f"{errors.shape[0] - num_run} of {errors.shape[0]} held-out runs failed"
        if num_run < diagnostics.MIN_HOLDOUT_RUNS:
            text += f", fewer than {diagnostics.MIN_HOLDOUT_RUNS} succeeded: too few to check the emulator"
        parts.append(text)
    share = float(state.untested_share)
    if num_run < errors.shape[0] and share >= UNTESTED_SHARE_WARN:
        parts.append(
            f"{share:.0%} of the posterior lies where the success classifier is below the design "
            "level (design.MIN_DESIGN_SUCCESS), a band no design run enters: its fit there rests on "
            "the emulator's extrapolation. More budget lets the failed held-out runs join the "
            "design; for failures that are phase changes, set min_feasibility to the design level"
        )
    return parts


def misfit_text(misfit: dict) -> str:
    """The warning for an observed-summary misfit (:func:`.evidence.observed_misfit`'s dict):
    its size and the three outputs that miss most."""
    residuals = misfit["standardised_residuals"]
    worst = sorted((i for i, r in enumerate(residuals) if r is not None), key=lambda i: -abs(residuals[i]))[:3]
    which = "principal component" if misfit["projected"] else "summary"
    named = ", ".join(f"{which} {i} ({residuals[i]:+.1f} sd)" for i in worst)
    return (
        f"surrogate: the observed summaries lie outside the model's posterior predictive "
        f"(squared Mahalanobis distance {misfit['mahalanobis_squared']:.3g} on {misfit['dof']} outputs, "
        f"p = {misfit['p_value']:.2g}; largest mean standardised residuals: {named}). No parameter value "
        "reproduces the data within the simulator noise: the posterior is the best fit of a "
        "misspecified model, and its width reflects the simulator noise, not the misfit. Add the "
        "data's measurement error (jaxabc.noise.MeasurementError) or read the interval as conditional "
        "on the model"
    )
