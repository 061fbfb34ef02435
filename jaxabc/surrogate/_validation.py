"""Validation of the emulator: the posterior that is to be reported (NUTS on the synthetic
likelihood, or APMCABC on emulated summaries), held-out runs drawn from it, and the check of
the emulator's predictions against those runs (:mod:`.diagnostics`)."""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.surrogate import abc_mode, design, diagnostics, emulator, sampling
from jaxabc.surrogate._fit import ROLE_DESIGN, ROLE_FAILED_HOLDOUT, ROLE_HOLDOUT, fit_surrogate
from jaxabc.surrogate._posterior import ImportanceSample, chains_disagree, importance_draws, nuts_chains
from jaxabc.surrogate._settings import AbcSettings, SurrogateSettings
from jaxabc.surrogate._state import PHASE_VALIDATING, SurrogateState, numpy_seed, pending_batch
from jaxabc.surrogate._support import untested_share

__all__ = ["check_holdout", "demote_holdout", "start_abc_validation", "start_validation"]


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
    return state._replace(
        draws=settings.box.unit_to_draws(flat),
        log_weights=log_weights,
        untested_share=np.float64(untested_share(model, sample.points, flat, log_weights)),
        rhat=rhat,
        pending=pending_batch(settings, settings.box.unit_to_theta(holdout[:, :d])),
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


def check_holdout(settings: SurrogateSettings, state: SurrogateState) -> tuple[SurrogateState, bool]:
    """Compare the held-out runs with the emulator refitted on the design rows.

    Only the outputs in the likelihood are checked (a constant one would score 0 and dilute
    the errors of the others).  Returns the state with the check's results (``holdout_errors``,
    ``coverage``, ``mean_squared_error``, the joint check, the lack-of-fit test) and whether
    validation passed: the marginal check, the lack-of-fit test, at least
    :data:`.diagnostics.MIN_HOLDOUT_RUNS` successful held-out runs and an emulator-to-noise
    variance ratio at most ``max_emulator_ratio``.  The joint check is recorded, not required.
    """
    _, emu, model, z_all = fit_surrogate(settings, state)
    rows = np.flatnonzero((state.role == ROLE_HOLDOUT) & state.ok)
    mean, var = emulator.predict(emu, jnp.asarray(settings.box.theta_to_unit(state.thetas[rows])))
    noise_var = np.exp(2 * np.asarray(emu.log_noise))
    chol = np.asarray(model.noise_chol, np.float64)
    on = np.asarray(model.active)
    check = diagnostics.holdout_check(
        z_all[rows][:, on],
        np.asarray(mean)[:, on],
        np.asarray(var)[:, on],
        noise_var[on],
        (chol @ chol.T)[np.ix_(on, on)],
    )
    rep_var, df = diagnostics.replicate_variance(z_all, state.group, state.ok & (state.role == ROLE_DESIGN))
    lack_of_fit_ok = diagnostics.lack_of_fit(noise_var[on], rep_var[on], df)[0] is not False
    errors = np.full((settings.num_holdout, settings.num_outputs), np.nan)
    errors[: len(rows), on] = check.errors
    resolved = float(state.emulator_ratio) <= settings.max_emulator_ratio
    enough = len(rows) >= diagnostics.MIN_HOLDOUT_RUNS
    state = state._replace(
        holdout_errors=errors,
        coverage=np.float64(check.coverage),
        mean_squared_error=np.float64(check.mean_squared),
        lack_of_fit_ok=np.bool_(lack_of_fit_ok),
        joint_mean_squared_error=np.float64(check.joint_mean_squared),
        joint_ok=np.bool_(not check.joint_mean_squared > check.mean_squared_max),
    )
    return state, bool(check.passed and lack_of_fit_ok and resolved and enough)


def demote_holdout(state: SurrogateState) -> SurrogateState:
    """After a failed validation: the held-out runs join the design (role 2)."""
    role = state.role.copy()
    role[role == ROLE_HOLDOUT] = ROLE_FAILED_HOLDOUT
    return state._replace(role=role)
