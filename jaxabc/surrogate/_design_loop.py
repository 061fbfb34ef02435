"""The design phase: which real simulations to run next.

In order of precedence: the replicate runs (once successful runs can host them), exploration
(too few successes for an emulator), then an acquisition batch from the refitted emulator's
posterior -- or, once the emulator resolves the posterior (or the budget is spent), the start
of validation (:mod:`._validation`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.surrogate import design, emulator, sampling
from jaxabc.surrogate._fit import ROLE_DESIGN, ROLE_EMPTY, ROLE_HOLDOUT, fit_surrogate
from jaxabc.surrogate._posterior import ImportanceSample, importance_sample
from jaxabc.surrogate._settings import EXPLORE_RADIUS, SurrogateSettings
from jaxabc.surrogate._state import PHASE_DESIGN, SurrogateState, budget_allows_batch, numpy_seed, pending_batch
from jaxabc.surrogate._validation import start_abc_validation, start_validation

__all__ = ["acquisition_step", "design_step", "explore_step", "replicate_step"]


def design_step(settings: SurrogateSettings, key: jax.Array, state: SurrogateState) -> SurrogateState:
    """The next batch of the design phase, or the start of validation.

    The emulator is refitted and the posterior importance-sampled; its draws become the
    state's ``draws`` and its mean emulator-to-noise variance ratio ``emulator_ratio``.
    Validation starts when that ratio is below ``tolerance`` (from the second round on) or the
    budget cannot pay another batch and a validation.

    Raises
    ------
    RuntimeError
        Too few successful runs for an emulator and no budget left to explore.
    """
    replicated = replicate_step(settings, state)
    if replicated is not None:
        return replicated
    num_ok = int(np.sum((state.role != ROLE_EMPTY) & state.ok & (state.role != ROLE_HOLDOUT)))
    if num_ok < settings.min_successes:
        return explore_step(settings, key, state, num_ok)
    transform, emu, model, _ = fit_surrogate(settings, state)
    rng = np.random.default_rng(numpy_seed(key))
    sample = importance_sample(settings, rng, model)
    emulator_ratio = float(sample.weights @ sample.emulator_ratio)
    picks = rng.choice(len(sample.points), size=settings.num_particles, p=sample.weights)
    hyper = np.asarray(np.column_stack([emu.log_amp, emu.log_ls, emu.log_noise]))
    state = state._replace(
        draws=settings.box.unit_to_draws(sample.points[picks]),
        log_weights=np.zeros(settings.num_particles),
        hyper=hyper,
        emulator_ratio=np.float64(emulator_ratio),
    )
    converged = emulator_ratio < settings.tolerance and int(state.round) >= 1
    if converged or not budget_allows_batch(settings, state):
        if settings.abc is not None:
            return start_abc_validation(settings, settings.abc, key, state, transform, model)
        return start_validation(settings, key, state, model, sample)
    return acquisition_step(settings, state, emu, model, sample)


def acquisition_step(
    settings: SurrogateSettings,
    state: SurrogateState,
    emu: emulator.Emulator,
    model: sampling.LikelihoodModel,
    sample: ImportanceSample,
) -> SurrogateState:
    """A batch of ``batch_size`` runs where the emulator's variance weighs most in the
    posterior (:func:`.design.acquisition`), spread out and away from failed runs.

    The posterior density already holds the chance that a run succeeds once; a second factor
    is the chance that the run succeeds and teaches the emulator anything.  With a
    discrepancy the candidates are ``(theta, delta)`` points: the acquisition weighs each by
    the joint posterior, and the batch is spread over theta alone.
    """
    theta_points = sample.points[:, : settings.box.num_theta]
    p_ok = np.asarray(sampling.feasibility(model.feasible, jnp.asarray(theta_points)))
    acquisition = design.acquisition(sample.log_density, sample.emulator_ratio, p_ok)
    # Penalise around each pick on the scale of the posterior (half its sd), or of the
    # emulator where that is shorter: GP length scales often exceed the posterior, and a
    # penalty that wide would push the batch into the corners of the box.  Failed runs are
    # penalised too: the emulator learnt nothing there.
    w = sample.weights
    posterior_sd = np.sqrt(w @ (theta_points - w @ theta_points) ** 2)
    scale = design.penalty_radius(np.exp(np.min(np.asarray(emu.log_ls), axis=0)), posterior_sd)
    used = state.role != ROLE_EMPTY
    failed = settings.box.theta_to_unit(state.thetas[used & ~state.ok])
    idx = design.select_batch(theta_points, acquisition, scale, settings.batch_size, avoid=failed)
    return state._replace(
        pending=pending_batch(settings, settings.box.unit_to_theta(theta_points[idx])),
        num_pending=np.int64(settings.batch_size),
        phase=np.int64(PHASE_DESIGN),
    )


def explore_step(settings: SurrogateSettings, key: jax.Array, state: SurrogateState, num_ok: int) -> SurrogateState:
    """Too few successful runs (``num_ok``) for an emulator, as when most of the box fails: the
    next batch goes where the success classifier expects runs to succeed, spread out and away
    from the runs already made.

    Raises
    ------
    RuntimeError
        The budget cannot pay another batch and a validation.
    """
    used = state.role != ROLE_EMPTY
    if not budget_allows_batch(settings, state):
        raise RuntimeError(
            f"surrogate: only {num_ok} of {int(used.sum())} simulations succeeded and the budget is "
            f"spent; the emulator needs at least {settings.min_successes}. Check the simulator, narrow the "
            "prior to where it succeeds, or raise max_simulations"
        )
    d = settings.box.num_theta
    rng = np.random.default_rng(numpy_seed(key))
    candidates = design.candidates(rng, d, settings.num_candidates).x
    x_used = settings.box.theta_to_unit(state.thetas[used])
    # One compilation per budget: the classifier is fitted on buffers of max_simulations rows.
    feasible = sampling.fit_feasibility(x_used, state.ok[used], size=settings.max_simulations)
    acquisition = np.array(sampling.feasibility(feasible, jnp.asarray(candidates)), np.float64)
    for x0 in x_used:  # no repeats of what is known
        acquisition *= 1.0 - np.exp(-0.5 * np.sum(((candidates - x0) / EXPLORE_RADIUS) ** 2, axis=1))
    idx = design.select_batch(candidates, acquisition, np.full(d, EXPLORE_RADIUS), settings.batch_size)
    return state._replace(
        pending=pending_batch(settings, settings.box.unit_to_theta(candidates[idx])),
        num_pending=np.int64(settings.batch_size),
        phase=np.int64(PHASE_DESIGN),
    )


def replicate_step(settings: SurrogateSettings, state: SurrogateState) -> SurrogateState | None:
    """The replicate runs, once the successful design runs can host them (None: not now).

    They go to two successful runs, away from the failed ones (:func:`.design.replicate_sites`),
    which join their groups.  Never when the budget left could not also pay a validation, and
    only once.
    """
    used = state.role != ROLE_EMPTY
    good = used & state.ok & (state.role == ROLE_DESIGN)
    done = np.any(state.group[used] >= 0)
    num_replicates = settings.num_replicates
    if num_replicates == 0 or done or good.sum() < settings.min_successes:
        return None
    if settings.max_simulations - int(state.count) < num_replicates + settings.num_holdout:
        return None
    rows = np.flatnonzero(good)
    failed = settings.box.theta_to_unit(state.thetas[used & ~state.ok])
    site, count = design.replicate_sites(settings.box.theta_to_unit(state.thetas[rows]), failed, num_replicates)
    group = state.group.copy()
    group[rows[site]] = np.arange(site.size)
    pending_group = np.full(settings.pending_rows, -1, np.int32)
    pending_group[:num_replicates] = np.repeat(np.arange(site.size), count)
    return state._replace(
        group=group,
        pending=pending_batch(settings, np.repeat(state.thetas[rows[site]], count, axis=0)),
        num_pending=np.int64(num_replicates),
        pending_group=pending_group,
        phase=np.int64(PHASE_DESIGN),
    )
