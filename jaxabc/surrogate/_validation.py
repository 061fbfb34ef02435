"""Validation of the emulator: the posterior that is to be reported (NUTS on the synthetic
likelihood, or APMCABC on emulated summaries), held-out runs, and three checks of them.

The held-out runs are of two kinds.  Most are drawn from the posterior.  The last
:func:`num_targeted` are placed where the emulator is least sure among the parameters that
could still fit the data (:func:`targeted_points`): a posterior computed from a wrong emulator
puts few draws where the emulator is wrong (a step it smooths over gets almost none), so
posterior draws alone rarely test it there.  The checks:

1. all held-out runs against the emulator's predictions (:func:`.diagnostics.holdout_check`);
2. the targeted runs alone (:func:`.diagnostics.local_check`): a few large errors where the
   emulator was unsure would vanish among the posterior draws' errors;
3. stability: the posterior refitted with the held-out runs added must agree with the one to be
   reported, within :data:`MAX_MEAN_SHIFT` posterior sds in mean and :data:`MAX_LOG_SD_CHANGE`
   in log sd (plus three Monte Carlo errors).  What moves when 20 more runs are added is the
   emulator's share of the error, which the first two checks cannot see where the emulator is
   honestly unsure; its size is also part of the reported MCSE (:mod:`._report`).
"""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import scipy.stats

from jaxabc.surrogate import abc_mode, design, diagnostics, emulator, sampling
from jaxabc.surrogate._fit import ROLE_DESIGN, ROLE_FAILED_HOLDOUT, ROLE_HOLDOUT, fit_surrogate
from jaxabc.surrogate._posterior import (
    ImportanceSample,
    chains_disagree,
    evaluate_in_chunks,
    importance_draws,
    importance_sample,
    nuts_chains,
)
from jaxabc.surrogate._settings import AbcSettings, SurrogateSettings
from jaxabc.surrogate._state import PHASE_VALIDATING, SurrogateState, numpy_seed, pending_batch
from jaxabc.surrogate._support import untested_share

__all__ = [
    "MAX_LOG_SD_CHANGE",
    "MAX_MEAN_SHIFT",
    "TARGETED_SHARE",
    "check_holdout",
    "demote_holdout",
    "num_targeted",
    "posterior_shift",
    "start_abc_validation",
    "start_validation",
    "targeted_points",
]

#: Share of each validation's held-out runs placed by :func:`targeted_points` (the others are
#: posterior draws).
TARGETED_SHARE = 0.25
#: A point "could fit the data" when the observed summaries lie within the chi-square 0.999
#: quantile of the emulator's mean, with the emulator's variance inflated by this many sds
#: squared on top of the simulator noise, the measurement error and the largest discrepancy.
OPTIMISTIC_SDS = 3.0
#: Stability bounds: the posterior with the held-out runs in the fit may move its mean by at
#: most this many posterior sds...
MAX_MEAN_SHIFT = 0.2
#: ...and each sd by at most this much in log (about 10 %), each plus three Monte Carlo errors.
MAX_LOG_SD_CHANGE = 0.1
#: The least posterior sd (unit box) the stability check divides by.
MIN_SD = 1e-3


def num_targeted(num_holdout: int) -> int:
    """Targeted held-out runs of a validation with ``num_holdout`` runs (at least 1)."""
    return max(1, round(TARGETED_SHARE * num_holdout))


def targeted_points(
    settings: SurrogateSettings,
    rng: np.random.Generator,
    model: sampling.LikelihoodModel,
    num: int,
    draws: np.ndarray,
    avoid: np.ndarray,
) -> np.ndarray:
    """Up to ``num`` unit-box theta points ``(n, d)`` for held-out runs that test the emulator
    where the posterior draws do not.

    Two kinds, alternately: (a) the posterior's edge, the band between the 0.9 and 0.9999
    chi-square levels of the log density below its peak, where an emulator that is confident
    and wrong (a step it smooths over) moves the posterior's boundary and width; (b) where the
    emulator is least sure (emulator-to-noise variance ratio) among the points that could fit the
    data with its variance inflated by :data:`OPTIMISTIC_SDS`.  Candidates are Sobol points
    over the box and, as many, about the posterior ``draws (P, d + G)`` (unit box); points
    likely to fail are left out, and each kind is spread out and away from ``avoid (m, d)``.
    Fewer (none) where no candidate qualifies.
    """
    d = settings.box.num_theta
    centre = draws.mean(axis=0)
    cov = np.atleast_2d(np.cov(draws, rowvar=False))
    x = design.candidates(rng, draws.shape[1], settings.num_candidates, centre, cov).x
    # Discrepancy columns (if any) at the posterior mean; the emulator sees theta only.
    x = np.clip(np.column_stack([x[:, :d], np.broadcast_to(centre[d:], (len(x), draws.shape[1] - d))]), 0, 1)
    lp, _ = evaluate_in_chunks(settings, model, x)
    lp_draws, _ = evaluate_in_chunks(settings, model, draws)
    x = x[:, :d]
    mean, var = (np.asarray(a, np.float64) for a in emulator.predict(model.emulator, jnp.asarray(x)))
    on = np.asarray(model.active, bool)
    noise_var = np.asarray(emulator.noise_sd(model.emulator, jnp.asarray(x)), np.float64) ** 2
    extra = np.zeros(noise_var.shape[1])
    if model.observation_cov is not None:
        extra += np.diag(np.asarray(model.observation_cov, np.float64))
    if model.discrepancy_basis is not None and model.discrepancy_max_sd is not None:
        basis = np.asarray(model.discrepancy_basis, np.float64)
        extra += np.einsum("g,gii->i", np.asarray(model.discrepancy_max_sd, np.float64) ** 2, basis)
    z_obs = np.asarray(model.z_obs, np.float64)
    r2 = ((z_obs - mean) ** 2 / (noise_var + extra + OPTIMISTIC_SDS**2 * var))[:, on].sum(axis=1)
    p_ok = np.asarray(sampling.feasibility(model.feasible, jnp.asarray(x)), np.float64)
    likely = p_ok >= max(settings.min_feasibility, 1e-3)
    drop = np.nanmax(np.concatenate([lp, lp_draws])) - lp
    k = draws.shape[1]
    edge = likely & (drop >= 0.5 * scipy.stats.chi2.ppf(0.9, k)) & (drop <= 0.5 * scipy.stats.chi2.ppf(0.9999, k))
    unsure = likely & (r2 <= scipy.stats.chi2.ppf(0.999, max(int(on.sum()), 1)))
    ratio = np.mean((var / noise_var)[:, on], axis=1)
    sd = np.sqrt(np.diag(cov))[:d]
    scale = design.penalty_radius(np.exp(np.min(np.asarray(model.emulator.log_ls, np.float64), axis=0)), sd)
    picks: list[np.ndarray] = []
    wanted = {"edge": (num + 1) // 2, "unsure": num // 2}
    # Weighed by the optimistic likelihood too: of the unsure points, those nearest to fitting.
    scores = {"edge": p_ok, "unsure": ratio * p_ok * np.exp(-0.5 * (r2 - np.min(r2)))}
    masks = {"edge": edge, "unsure": unsure}
    for kind in ("edge", "unsure"):
        n = min(wanted[kind], int(masks[kind].sum()))
        if n:
            taken = np.concatenate([avoid, *picks]) if picks else avoid
            picks.append(x[design.select_batch(x, np.where(masks[kind], scores[kind], 0.0), scale, n, avoid=taken)])
    return np.concatenate(picks) if picks else np.zeros((0, d))


def with_targeted(
    settings: SurrogateSettings,
    rng: np.random.Generator,
    model: sampling.LikelihoodModel,
    holdout: np.ndarray,
    draws: np.ndarray,
) -> np.ndarray:
    """The held-out unit-box theta points ``(num_holdout, d)``: the first of the posterior's
    ``holdout`` rows, then the :func:`targeted_points` about the equal-weight unit-box
    posterior ``draws (P, d + G)`` (posterior rows fill in where fewer could be targeted)."""
    n, n_t = settings.num_holdout, num_targeted(settings.num_holdout)
    targeted = targeted_points(settings, rng, model, n_t, draws, holdout[: n - n_t])
    return np.concatenate([holdout[: n - len(targeted)], targeted])


def holdout_from_chains(settings: SurrogateSettings, draws: np.ndarray) -> np.ndarray:
    """``num_holdout`` points spread over NUTS chains ``(C, n, d + G)``: evenly along the
    chains, one from each chain in turn."""
    num_chains, length, num_sampled = draws.shape
    stride = max(1, length * num_chains // settings.num_holdout)
    picks = draws[:, ::stride].transpose(1, 0, 2)
    return picks.reshape(-1, num_sampled)[: settings.num_holdout]


def holdout_from_weights(
    settings: SurrogateSettings, rng: np.random.Generator, draws: np.ndarray, log_weights: np.ndarray
) -> np.ndarray:
    """``num_holdout`` points drawn from weighted ``draws (P, d + G)`` (``-inf`` pads skipped)."""
    keep = np.flatnonzero(np.isfinite(log_weights))
    p = np.exp(log_weights[keep]) / np.exp(log_weights[keep]).sum()
    return draws[rng.choice(keep, size=settings.num_holdout, p=p)]


def start_validation(
    settings: SurrogateSettings,
    key: jax.Array,
    state: SurrogateState,
    model: sampling.LikelihoodModel,
    sample: ImportanceSample,
) -> SurrogateState:
    """Synthetic-likelihood mode: NUTS draws of the posterior, and ``num_holdout`` of them as
    the next (held-out) batch; phase validating.

    Where the chains disagree (:func:`._posterior.chains_disagree`) their draws would weigh the
    modes by where the chains started; an importance resample, which weighs them right in a
    low-dimensional box, is reported instead (R-hat stays in the diagnostics).
    """
    rng = np.random.default_rng(numpy_seed(jax.random.fold_in(key, 1)))
    chains, rhat = nuts_chains(settings, key, rng, model, sample)
    chains = np.asarray(chains)
    flat = chains.reshape(-1, settings.box.num_sampled)
    log_weights = np.zeros(settings.num_particles)
    holdout = holdout_from_chains(settings, chains)
    if chains_disagree(rhat, flat, sample):
        flat, log_weights = importance_draws(settings, rng, model)
        holdout = holdout_from_weights(settings, rng, flat, log_weights)
    d = settings.box.num_theta
    if np.any(log_weights != 0):
        p = np.exp(log_weights - np.max(log_weights))
        even = flat[rng.choice(len(flat), size=len(flat), p=p / p.sum())]
    else:
        even = flat
    holdout = with_targeted(settings, rng, model, holdout[:, :d], even)
    return state._replace(
        draws=settings.box.unit_to_draws(flat),
        log_weights=log_weights,
        untested_share=np.float64(untested_share(model, sample.points, flat, log_weights)),
        rhat=rhat,
        pending=pending_batch(settings, settings.box.unit_to_theta(holdout)),
        num_pending=np.int64(settings.num_holdout),
        phase=np.int64(PHASE_VALIDATING),
    )


def emulated_abc_posterior(
    settings: SurrogateSettings,
    abc: AbcSettings,
    key: jax.Array,
    transform: emulator.OutputTransform,
    model: sampling.LikelihoodModel,
) -> abc_mode.ABCPosterior:
    """APMCABC on the emulated simulator (:mod:`.abc_mode`); a RuntimeWarning when it stops at
    ``abc_max_generations`` before its acceptance cutoff."""
    emulated = abc_mode.emulated_simulator(
        model.emulator,
        transform,
        model.noise_chol,
        model.feasible,
        settings.box.low,
        settings.box.high,
        settings.min_feasibility,
        observation_error=settings.observation_error,
        discrepancy=settings.discrepancy,
    )
    posterior = abc_mode.run_abc(
        jax.random.fold_in(key, 4),
        emulated,
        abc_mode.project_observed(emulated, transform, settings.observed),
        num_particles=settings.num_particles,
        alpha=abc.alpha,
        acceptance_cutoff=abc.acceptance_cutoff,
        distance=abc.distance,
        max_generations=abc.max_generations,
    )
    if not posterior.stopped:
        warnings.warn(
            f"surrogate ABC mode: APMCABC reached abc_max_generations={abc.max_generations} "
            f"before its acceptance cutoff (threshold {posterior.threshold:.3g}); raise it for a "
            "smaller tolerance",
            RuntimeWarning,
            stacklevel=3,
        )
    return posterior


def start_abc_validation(
    settings: SurrogateSettings,
    abc: AbcSettings,
    key: jax.Array,
    state: SurrogateState,
    transform: emulator.OutputTransform,
    model: sampling.LikelihoodModel,
) -> SurrogateState:
    """ABC mode: the APMCABC population as the posterior, and ``num_holdout`` points
    systematically resampled from it as the next (held-out) batch; phase validating."""
    posterior = emulated_abc_posterior(settings, abc, key, transform, model)
    num_holdout, d = settings.num_holdout, settings.box.num_theta
    w = np.exp(posterior.log_weights - np.max(posterior.log_weights))
    w /= w.sum()
    rng = np.random.default_rng(numpy_seed(jax.random.fold_in(key, 5)))
    # Systematic resampling: held-out points spread over the weighted sample.
    idx = np.searchsorted(np.cumsum(w), (rng.uniform() + np.arange(num_holdout)) / num_holdout)
    holdout = posterior.particles[np.minimum(idx, settings.num_particles - 1)][:, :d]
    every = np.searchsorted(np.cumsum(w), (0.5 + np.arange(settings.num_particles)) / settings.num_particles)
    even = settings.box.draws_to_unit(np.asarray(posterior.particles)[np.minimum(every, settings.num_particles - 1)])
    holdout = settings.box.unit_to_theta(with_targeted(settings, rng, model, settings.box.theta_to_unit(holdout), even))
    candidates = design.candidates(rng, d, settings.num_candidates)
    theta_unit = settings.box.theta_to_unit(np.asarray(posterior.particles)[:, :d])
    share = untested_share(model, candidates.x, theta_unit, np.asarray(posterior.log_weights))
    return state._replace(
        draws=posterior.particles,
        log_weights=posterior.log_weights,
        untested_share=np.float64(share),
        abc_threshold=np.float64(posterior.threshold),
        abc_generations=np.int64(posterior.generations),
        abc_emulated=np.int64(posterior.num_emulated),
        pending=pending_batch(settings, holdout),
        num_pending=np.int64(num_holdout),
        phase=np.int64(PHASE_VALIDATING),
    )


def check_holdout(settings: SurrogateSettings, key: jax.Array, state: SurrogateState) -> tuple[SurrogateState, bool]:
    """Compare the held-out runs with the emulator the draws came from (the run's fit of the
    design rows, :func:`._fit.fit_surrogate`).

    Each held-out run's residual and the GP's unscaled and the noise's variance there are kept
    (``judged_*``), for a calibrated emulator variance.  Only the outputs in the likelihood are
    checked (a constant one would score 0 and dilute the errors of the others).  Returns the
    state with the check's results (``holdout_errors``,
    ``coverage``, ``mean_squared_error``, the joint check, the lack-of-fit test, the targeted
    runs' check, the posterior's shift) and whether validation passed: the marginal check, the
    targeted runs' check, the stability of the posterior (see the module docstring), the
    lack-of-fit test, at least :data:`.diagnostics.MIN_HOLDOUT_RUNS` successful held-out runs
    and an emulator-to-noise variance ratio at most ``max_emulator_ratio``.  The joint check is
    recorded, not required.
    """
    _, emu, model, z_all = fit_surrogate(settings, state)
    holdout_rows = np.flatnonzero(state.role == ROLE_HOLDOUT)
    rows = holdout_rows[state.ok[holdout_rows]]
    x_rows = jnp.asarray(settings.box.theta_to_unit(state.thetas[rows]))
    mean, var = emulator.predict(emu, x_rows)
    noise_var = np.asarray(emulator.noise_sd(emu, x_rows), np.float64) ** 2  # (h, q)
    chol = np.asarray(model.noise_chol, np.float64)
    on = np.asarray(model.active)
    check = diagnostics.holdout_check(
        z_all[rows][:, on],
        np.asarray(mean)[:, on],
        np.asarray(var)[:, on],
        noise_var[:, on],
        (chol @ chol.T)[np.ix_(on, on)],
    )
    # The targeted runs are the last of the batch (:func:`with_targeted`).
    targeted = np.isin(rows, holdout_rows[len(holdout_rows) - num_targeted(settings.num_holdout) :])
    local = diagnostics.local_check(check.errors[targeted])
    rep_var, df = diagnostics.replicate_variance(z_all, state.group, state.ok & (state.role == ROLE_DESIGN))
    # The nugget at the replicate sites (the same everywhere unless heteroscedastic).
    sites = state.group >= 0
    site_var = (
        np.mean(
            np.asarray(emulator.noise_sd(emu, jnp.asarray(settings.box.theta_to_unit(state.thetas[sites])))) ** 2,
            axis=0,
        )
        if sites.any()
        else np.exp(2 * np.asarray(emu.log_noise))
    )
    lack_of_fit_ok = diagnostics.lack_of_fit(site_var[on], rep_var[on], df)[0] is not False
    shift, log_sd_change, stable = posterior_shift(settings, key, state, model)
    errors = np.full((settings.num_holdout, settings.num_outputs), np.nan)
    errors[: len(rows), on] = check.errors
    # What a calibrated emulator variance is estimated from: the GP's own variance, unscaled.
    raw_var = np.asarray(emulator.predict(emu._replace(var_scale=None), x_rows)[1], np.float64)
    judged = [np.array(a) for a in (state.judged_residual, state.judged_emulator_var, state.judged_noise_var)]
    for target, values in zip(judged, (z_all[rows] - np.asarray(mean), raw_var, noise_var), strict=True):
        target[rows] = np.where(on[None, :], values, np.nan)
    resolved = float(state.emulator_ratio) <= settings.max_emulator_ratio
    enough = len(rows) >= diagnostics.MIN_HOLDOUT_RUNS
    state = state._replace(
        holdout_errors=errors,
        coverage=np.float64(check.coverage),
        mean_squared_error=np.float64(check.mean_squared),
        lack_of_fit_ok=np.bool_(lack_of_fit_ok),
        joint_mean_squared_error=np.float64(check.joint_mean_squared),
        joint_ok=np.bool_(not check.joint_mean_squared > check.mean_squared_max),
        targeted_max_error=np.float64(local.max_abs),
        targeted_ok=np.bool_(local.passed),
        posterior_shift=shift,
        log_sd_change=log_sd_change,
        stable=np.bool_(stable),
        judged_residual=judged[0],
        judged_emulator_var=judged[1],
        judged_noise_var=judged[2],
    )
    passed = check.passed and local.passed and stable and lack_of_fit_ok and resolved and enough
    return state, bool(passed)


def posterior_shift(
    settings: SurrogateSettings, key: jax.Array, state: SurrogateState, before: sampling.LikelihoodModel
) -> tuple[np.ndarray, np.ndarray, bool]:
    """How the posterior moves when the held-out runs join the fit.

    Importance samples (:func:`._posterior.importance_sample`, the same generator for both)
    of the model ``before`` (design rows) and of the refit with the held-out runs.  Returns
    the mean shift in posterior sds ``(d + G,)``, the log sd change ``(d + G,)`` and whether
    both stay within :data:`MAX_MEAN_SHIFT` / :data:`MAX_LOG_SD_CHANGE` plus three Monte Carlo
    errors (from the two samples' effective sizes).
    """
    _, _, after, _ = fit_surrogate(settings, demote_holdout(state))
    seed = numpy_seed(jax.random.fold_in(key, 6))
    moments = []
    for model in (before, after):
        sample = importance_sample(settings, np.random.default_rng(seed), model)
        w = sample.weights
        m = w @ sample.points
        # Floored at a thousandth of the box: a posterior piled on a bound has no sd to
        # measure a shift in.
        sd = np.sqrt(np.maximum(w @ (sample.points - m) ** 2, MIN_SD**2))
        moments.append((m, sd, 1.0 / np.sum(w**2)))
    (m0, sd0, ess0), (m1, sd1, ess1) = moments
    shift, log_sd = (m1 - m0) / sd0, np.log(sd1 / sd0)
    se_mean, se_log_sd = np.sqrt(1 / ess0 + 1 / ess1), np.sqrt(0.5 / ess0 + 0.5 / ess1)
    stable = np.all(np.abs(shift) <= MAX_MEAN_SHIFT + 3 * se_mean) and np.all(
        np.abs(log_sd) <= MAX_LOG_SD_CHANGE + 3 * se_log_sd
    )
    return shift, log_sd, bool(stable)


def demote_holdout(state: SurrogateState) -> SurrogateState:
    """After a failed validation: the held-out runs join the design (role 2)."""
    role = state.role.copy()
    role[role == ROLE_HOLDOUT] = ROLE_FAILED_HOLDOUT
    return state._replace(role=role)
