"""The surrogate's state: every real simulation in fixed-size buffers, the pending batch, the
current posterior and the last validation; its phases, and the bookkeeping that adds runs and
restores checkpoints."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import numpy as np
from jax.tree_util import keystr, tree_flatten_with_path

from jaxabc.algorithms.base import Proposal
from jaxabc.surrogate._fit import ROLE_EMPTY
from jaxabc.surrogate._settings import SurrogateSettings

__all__ = [
    "LATER_FIELDS",
    "PHASE_DESIGN",
    "PHASE_DONE",
    "PHASE_VALIDATING",
    "SurrogateState",
    "add_runs",
    "budget_allows_batch",
    "budget_allows_validation",
    "calibration_pending",
    "empty_state",
    "numpy_seed",
    "pending_batch",
    "restore_state",
]

#: ``SurrogateState.phase``: choosing design runs, waiting for held-out runs, finished.
PHASE_DESIGN, PHASE_VALIDATING, PHASE_DONE = 0, 1, 2


class SurrogateState(NamedTuple):
    """Everything a surrogate run has learnt (fixed shapes; ``M = max_simulations``).

    Attributes
    ----------
    thetas : array, shape (M, d)
        Every real simulation's parameters, in the prior's units.
    summaries : array, shape (M, k)
        Flattened summaries; NaN for failed runs and unused rows.
    ok : array of bool, shape (M,)
    role : array of int, shape (M,)
        -1 unused, 0 design, 1 held out (not in the fit), 2 held out in a failed validation
        and then added to the design.
    group : array of int, shape (M,)
        Replicate group, -1 for unreplicated runs.
    count : array, shape ()
        Rows used.
    phase : array, shape ()
        0 design, 1 validating, 2 done.
    round : array, shape ()
        Updates so far.
    pending : array, shape (B, d)
        The next proposal's parameters (first ``num_pending`` rows).
    num_pending : array, shape ()
    pending_group : array of int, shape (B,)
        Replicate group of each pending run (-1: none).
    draws : array, shape (P, d + G)
        The current posterior draws (theta, then the ``G`` discrepancy sds when the run has a
        discrepancy) (importance resampled during design; NUTS, or the APMCABC
        population in ABC mode, once validating).
    log_weights : array, shape (P,)
        Their log weights (zero except for the APMCABC population).
    hyper : array, shape (q, d + 2)
        Emulator log hyper-parameters (amplitude, length scales, noise sd) of the last fit.
    holdout_errors : array, shape (H, q)
        Standardised errors of the last validation (NaN for failed runs).
    validated, lack_of_fit_ok : array of bool, shape ()
    coverage, mean_squared_error, emulator_ratio : array, shape ()
        Held-out 95 % coverage and mean squared standardised error; posterior mean of
        ``mean_j var_j / noise_j^2`` at the last fit.
    joint_mean_squared_error, joint_ok : array, shape ()
        Held-out Mahalanobis distance per output under the fitted noise correlation, and
        whether it passed (:func:`.diagnostics.holdout_check`).
    rhat : array, shape (d + G,)
        Split-R-hat of the NUTS chains (NaN before, and in ABC mode).
    abc_threshold, abc_generations, abc_emulated : array, shape ()
        ABC mode: final tolerance, APMCABC generations and emulated simulations of the last
        posterior (NaN / 0 otherwise).
    untested_share : array, shape ()
        Posterior weight, at the last validation, where the success classifier is below the
        design level (:func:`.design.design_level`): a band no design run enters (NaN before).
    targeted_max_error, targeted_ok : array, shape ()
        The largest standardised error of the targeted held-out runs at the last validation
        and whether they passed (:func:`.diagnostics.local_check`; NaN / True before).
    posterior_shift, log_sd_change : array, shape (d + G,)
        How the posterior moved, in posterior sds and in log sd, when the last validation's
        held-out runs joined the fit (:func:`._validation.posterior_shift`; NaN before).
    stable : array of bool, shape ()
        Whether that move stayed within its bounds (True before).
    variance_scale : array, shape ()
        The factor on the GP's predictive variance in use (``emulator_variance``; 1 for "gp").
    judged_residual, judged_emulator_var, judged_noise_var : array, shape (M, q)
        For every held-out run already judged: its output minus the emulator's mean, the GP's
        unscaled variance and the noise variance there, as the emulator then fitted predicted
        (NaN elsewhere); what a calibrated ``variance_scale`` is estimated from.
    """

    thetas: Any
    summaries: Any
    ok: Any
    role: Any
    group: Any
    count: Any
    phase: Any
    round: Any
    pending: Any
    num_pending: Any
    draws: Any
    log_weights: Any
    hyper: Any
    holdout_errors: Any
    validated: Any
    lack_of_fit_ok: Any
    coverage: Any
    mean_squared_error: Any
    emulator_ratio: Any
    rhat: Any
    abc_threshold: Any
    abc_generations: Any
    abc_emulated: Any
    joint_mean_squared_error: Any
    joint_ok: Any
    pending_group: Any
    untested_share: Any
    targeted_max_error: Any
    targeted_ok: Any
    posterior_shift: Any
    log_sd_change: Any
    stable: Any
    variance_scale: Any
    judged_residual: Any
    judged_emulator_var: Any
    judged_noise_var: Any


#: Fields added after the first release: a checkpoint without them restores with their
#: :func:`empty_state` values.
LATER_FIELDS = (
    ".log_weights",
    ".abc_threshold",
    ".abc_generations",
    ".abc_emulated",
    ".joint_mean_squared_error",
    ".joint_ok",
    ".pending_group",
    ".untested_share",
    ".targeted_max_error",
    ".targeted_ok",
    ".posterior_shift",
    ".log_sd_change",
    ".stable",
    ".variance_scale",
    ".judged_residual",
    ".judged_emulator_var",
    ".judged_noise_var",
)


def empty_state(settings: SurrogateSettings) -> SurrogateState:
    """The state before any simulation: empty buffers, no posterior, phase design."""
    m, d, k = settings.max_simulations, settings.box.num_theta, settings.num_summaries
    q, b, p = settings.num_outputs, settings.pending_rows, settings.num_particles
    return SurrogateState(
        thetas=np.zeros((m, d)),
        summaries=np.full((m, k), np.nan),
        ok=np.zeros(m, bool),
        role=np.full(m, ROLE_EMPTY, np.int8),
        group=np.full(m, -1, np.int32),
        count=np.int64(0),
        phase=np.int64(PHASE_DESIGN),
        round=np.int64(0),
        pending=np.zeros((b, d)),
        num_pending=np.int64(0),
        draws=np.zeros((p, settings.box.num_sampled)),
        log_weights=np.zeros(p),
        hyper=np.zeros((q, d + 2)),
        holdout_errors=np.full((settings.num_holdout, q), np.nan),
        validated=np.bool_(False),
        lack_of_fit_ok=np.bool_(True),
        coverage=np.float64(np.nan),
        mean_squared_error=np.float64(np.nan),
        emulator_ratio=np.float64(np.nan),
        rhat=np.full(settings.box.num_sampled, np.nan),
        abc_threshold=np.float64(np.nan),
        abc_generations=np.int64(0),
        abc_emulated=np.int64(0),
        joint_mean_squared_error=np.float64(np.nan),
        joint_ok=np.bool_(True),
        pending_group=np.full(b, -1, np.int32),
        untested_share=np.float64(np.nan),
        targeted_max_error=np.float64(np.nan),
        targeted_ok=np.bool_(True),
        posterior_shift=np.full(settings.box.num_sampled, np.nan),
        log_sd_change=np.full(settings.box.num_sampled, np.nan),
        stable=np.bool_(True),
        variance_scale=np.float64(1.0 if isinstance(settings.emulator_variance, str) else settings.emulator_variance),
        judged_residual=np.full((m, q), np.nan),
        judged_emulator_var=np.full((m, q), np.nan),
        judged_noise_var=np.full((m, q), np.nan),
    )


def add_runs(
    settings: SurrogateSettings,
    state: SurrogateState,
    proposal: Proposal,
    summaries: Any,
    role: int,
    group: np.ndarray | None,
) -> SurrogateState:
    """``state`` with the proposal's active runs appended in ``role``.

    ``summaries`` has shape ``(m, *observed.shape)`` (NaN rows for failed runs); ``group``
    ``(m,)`` the replicate group of each slot, or None.

    Raises
    ------
    ValueError
        Summaries of another size than the observed ones.
    RuntimeError
        The runs would exceed ``max_simulations``.
    """
    k, m = settings.num_summaries, settings.max_simulations
    active = np.asarray(proposal.active, bool)
    th = np.asarray(proposal.thetas, np.float64)[active]
    s = np.asarray(summaries, np.float64)
    s = s.reshape(s.shape[0], -1)
    if s.shape[1] != k:
        raise ValueError(f"summaries have {s.shape[1]} values per simulation but observed has {k}")
    s = s[active]
    n, c = th.shape[0], int(state.count)
    if c + n > m:
        raise RuntimeError(f"surrogate: {c + n} simulations would exceed max_simulations={m}")
    ok = np.all(np.isfinite(s), axis=1)
    thetas, summ = state.thetas.copy(), state.summaries.copy()
    oks, roles, groups = state.ok.copy(), state.role.copy(), state.group.copy()
    thetas[c : c + n], summ[c : c + n] = th, np.where(ok[:, None], s, np.nan)
    oks[c : c + n], roles[c : c + n] = ok, role
    if group is not None:
        groups[c : c + n] = group[active]
    return state._replace(thetas=thetas, summaries=summ, ok=oks, role=roles, group=groups, count=np.int64(c + n))


def pending_batch(settings: SurrogateSettings, thetas: np.ndarray) -> np.ndarray:
    """``thetas (n, d)`` as the state's ``pending`` buffer: ``(B, d)``, zero below row ``n``."""
    pending = np.zeros((settings.pending_rows, settings.box.num_theta))
    pending[: len(thetas)] = thetas
    return pending


def budget_allows_batch(settings: SurrogateSettings, state: SurrogateState) -> bool:
    """Whether the simulations left pay for another design batch and a validation after it.

    With ``emulator_variance="calibrated"`` and no validation yet, two validations: a first one
    whose runs measure the emulator's error, and a second that judges the calibrated emulator.
    """
    validations = 2 if calibration_pending(settings, state) else 1
    return settings.max_simulations - int(state.count) >= settings.batch_size + validations * settings.num_holdout


def calibration_pending(settings: SurrogateSettings, state: SurrogateState) -> bool:
    """Whether a calibrated emulator variance has no judged run yet to be estimated from."""
    return settings.emulator_variance == "calibrated" and not np.any(np.isfinite(state.judged_residual))


def budget_allows_validation(settings: SurrogateSettings, state: SurrogateState) -> bool:
    """Whether the simulations left pay for one more validation."""
    return settings.max_simulations - int(state.count) >= settings.num_holdout


def restore_state(settings: SurrogateSettings, flat: dict[str, np.ndarray]) -> SurrogateState:
    """The state from a checkpoint's ``{keystr path: array}``; fields of :data:`LATER_FIELDS`
    missing from older checkpoints take their empty values.

    Raises
    ------
    ValueError
        The checkpoint lacks other fields (named in the message).
    """
    template = empty_state(settings)
    leaves = tree_flatten_with_path(template)[0]
    flat = {**{keystr(p): v for p, v in leaves if keystr(p) in LATER_FIELDS}, **flat}
    missing = [keystr(p) for p, _ in leaves if keystr(p) not in flat]
    if missing:
        raise ValueError(f"checkpoint lacks surrogate state entries {missing}")
    return SurrogateState(*[np.asarray(flat[keystr(p)], dtype=np.asarray(v).dtype) for p, v in leaves])


def numpy_seed(key: jax.Array) -> int:
    """A NumPy generator seed drawn from a JAX key."""
    return int(jax.random.randint(key, (), 0, 2**31 - 1))
