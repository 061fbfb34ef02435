"""Surrogate-accelerated calibration as an :class:`~jaxabc.algorithms.base.ABCAlgorithm`.

Each ``update`` adds a batch of real simulations to fixed-size buffers, refits the emulator and
decides what to simulate next:

1. *design* (:mod:`._design_loop`): a Sobol start (``initial_proposal``), replicate runs at two
   successful sites once there are enough successes, then acquisition batches (:mod:`.design`)
   until the emulator's variance over the posterior is small next to the simulator noise
   (``tolerance``) or the design budget is spent;
2. *validation* (:mod:`._validation`): draws from the surrogate posterior (NUTS on the synthetic
   likelihood, or with ``mode="abc"`` APMCABC on emulated summaries, :mod:`.abc_mode`);
   ``num_holdout`` of them are simulated for real and compared with the emulator's predictions
   (:mod:`.diagnostics`).  Pass: stop with that posterior.  Fail: the held-out runs join the
   design and step 1 resumes while the budget allows; otherwise the run stops flagged as
   unvalidated (or raises, ``on_failure="raise"``).

The steps are module-level functions of a :class:`._settings.SurrogateSettings`, built once by
:func:`build`, and of a :class:`SurrogateState`; each update reports a :class:`SurrogateInfo`
(:mod:`._report`).  All functions are host code (``host=True``) calling jitted JAX; arithmetic
is float64.
"""

from __future__ import annotations

import warnings
from functools import partial
from typing import Any

import jax
import numpy as np

from jaxabc.algorithms.base import ABCAlgorithm, Proposal
from jaxabc.surrogate import design, emulator
from jaxabc.surrogate._design_loop import design_step
from jaxabc.surrogate._fit import ROLE_DESIGN, ROLE_HOLDOUT
from jaxabc.surrogate._report import SurrogateInfo, failure_text, finalize, step_info, stop_reason
from jaxabc.surrogate._settings import MODES, SurrogateSettings, make_settings, settings_record
from jaxabc.surrogate._state import (
    PHASE_DONE,
    PHASE_VALIDATING,
    SurrogateState,
    add_runs,
    budget_allows_batch,
    budget_allows_validation,
    empty_state,
    numpy_seed,
    restore_state,
)
from jaxabc.surrogate._support import single_threaded_blas
from jaxabc.surrogate._validation import check_holdout, demote_holdout

__all__ = ["MODES", "EmulatorFailure", "SurrogateAlgorithm", "SurrogateInfo", "SurrogateState", "build"]


class EmulatorFailure(RuntimeError):
    """The emulator failed its held-out or lack-of-fit checks and the budget is spent."""


class SurrogateAlgorithm(ABCAlgorithm):
    """The surrogate's :class:`~jaxabc.algorithms.base.ABCAlgorithm`, with the prior of its
    posterior's columns (``_replace`` keeps the class, and this reads ``settings``)."""

    __slots__ = ()

    @property
    def augmented_prior(self) -> Any:
        """The :class:`jaxabc.Uniform` of the posterior draws, theta's box then ``[0, max_sd_g]``
        per discrepancy group (names ``discrepancy_sd[<group>]``); None without a discrepancy,
        when the draws are theta's and the prior is the one given to the builder."""
        spec = self.settings.get("augmented_prior")
        if spec is None:
            return None
        from jaxabc.priors import Uniform

        return Uniform.from_dict(spec)


def build(
    prior: Any,
    num_particles: int = 2000,
    *,
    observed: Any,
    max_simulations: int,
    num_initial: int | None = None,
    num_replicates: int | None = None,
    batch_size: int | None = None,
    num_holdout: int | None = None,
    tolerance: float = 0.01,
    max_outputs: int = 16,
    num_candidates: int = 4096,
    num_chains: int = 4,
    num_warmup: int = 200,
    thin: int = 2,
    max_emulator_ratio: float = 1.0,
    min_feasibility: float = 0.01,
    on_failure: str = "flag",
    mode: str = "synthetic_likelihood",
    abc_distance: str | Any = "mean_abs",
    abc_alpha: float = 0.5,
    abc_acceptance_cutoff: float = 0.03,
    abc_max_generations: int = 60,
    observation_error: Any = None,
    discrepancy: Any = None,
    noise_model: str = "auto",
    emulator_variance: str | float = "gp",
) -> Any:
    """Build the surrogate (GP-emulator synthetic-likelihood) algorithm.

    Parameters
    ----------
    prior : Uniform
        The box the design, the emulator's input scaling and the posterior live in.
    num_particles : int
        Posterior draws (at least 1000), a multiple of ``num_chains``.
    observed : array_like
        The measured summaries, the simulator's output shape.
    max_simulations : int
        Real simulations in all, design plus held-out validation; never exceeded.
    num_initial : int, optional
        Sobol points of the start.  This and the next three default to sizes that follow the
        budget (:func:`._settings.design_defaults`), so that a small budget still pays for
        acquisition rounds.
    num_replicates : int, optional
        Repeat runs that measure the simulator's noise, at two successful runs away from the
        failed ones, once ``max(3, d + 1)`` runs have succeeded (0: none; the lack-of-fit test
        is then skipped, and the nugget rests on the design's scatter alone).
    batch_size : int, optional
        Simulations per acquisition batch (match the number of workers).
    num_holdout : int, optional
        Held-out simulations per validation.
    tolerance : float
        Design stops once the posterior mean of ``mean_j var_j / noise_j^2`` (emulator over
        simulator variance) is below this: 0.01 keeps the emulator's error near a tenth of the
        noise, so posterior means move by about a tenth of a posterior sd.  0 turns the early
        stop off: the design spends the budget.
    max_outputs : int
        Summaries beyond this many are projected onto their leading principal components.
    num_candidates : int
        Points on which the acquisition and the design-phase posterior are evaluated.
    num_chains, num_warmup, thin : int
        NUTS chains, discarded steps per chain, steps per kept draw.
    max_emulator_ratio : float
        Validation also fails when the posterior mean of ``mean_j var_j / noise_j^2`` stays
        above this: the posterior would then describe the emulator's ignorance, not the data
        (a simulator too rough for the GP, e.g. chaotic or discontinuous, or a budget too small).
    min_feasibility : float
        The posterior is cut off where the fitted chance that a run succeeds is below this
        (0: never).  Failed runs teach the emulator nothing, so where runs fail its variance
        stays at its prior level; with data no parameter reproduces within the noise (a
        misspecified model) that variance would otherwise pull the posterior, and every new
        run, into the failing region (see :mod:`.sampling`).
    on_failure : {"flag", "raise"}
        When validation fails with the budget spent: stop with an unvalidated, flagged result
        and a warning, or raise :class:`EmulatorFailure`.
    mode : {"synthetic_likelihood", "abc"}
        The posterior: NUTS on the synthetic likelihood (equal weights), or APMCABC on emulated
        summaries with emulator and simulator noise added (:mod:`.abc_mode`; weighted, wider by
        the ABC tolerance).  The sequential design is the same in both.
    abc_distance : str or callable
        ABC mode: a :mod:`jaxabc.distances` name or ``distance(observed, simulated) -> scalar``
        on the raw summaries.  :func:`jaxabc.run` does not hand its own ``distance`` to
        builders: pass the same one here.
    abc_alpha, abc_acceptance_cutoff : float
        ABC mode: APMCABC's kept fraction and stopping cutoff; it runs ``num_particles /
        abc_alpha`` particles and returns the ``num_particles`` kept.
    abc_max_generations : int
        ABC mode: a bound on APMCABC generations (emulated simulations are cheap; the cutoff
        normally ends the run first).
    observation_error : array (k, k), optional
        Covariance of the observed summaries' measurement error over the flattened summaries,
        in summary units (:func:`jaxabc.noise.observation_covariance` gives it; a standard
        deviation per summary, or one for all, is normalised with it).  Added to the synthetic
        likelihood's covariance wherever it is used (design, posterior, evidence, the observed-
        data misfit) and drawn into every emulated simulation in ABC mode; mapped into the
        emulated outputs as ``T M T^T`` (:func:`.sampling.output_map`; with a projection onto
        principal components, its part along the dropped directions is dropped with them).  The
        held-out validation compares real simulations with the emulator and does not use it.
    discrepancy : ResolvedDiscrepancy or Discrepancy, optional
        Model discrepancy: ``G`` group sds ``delta_g ~ U(0, max_sd_g)`` sampled with ``theta``,
        adding ``diag(discrepancy.variance(delta))`` (summary units) to the likelihood's
        covariance.  The posterior draws then have ``d + G`` columns; the returned algorithm's
        ``augmented_prior`` is the matching :class:`jaxabc.Uniform` (names
        ``discrepancy.names``).  A :class:`jaxabc.noise.Discrepancy` is resolved against
        ``observed``.
    noise_model : {"auto", "homoscedastic", "heteroscedastic"}
        The simulator noise: the same for every theta, or a log variance quadratic in theta
        fitted to the emulator's leave-one-out residuals (:func:`.emulator.fit_noise_profile`),
        used by the emulator fit, the likelihood, validation and ABC mode.  ``"auto"`` takes the
        profile of each output whose F-test rejects a constant variance (level 1e-3 over the
        outputs) at each refit.
    emulator_variance : "gp", "calibrated" or float
        The emulator's predictive variance everywhere it is used: the GP's own; times a factor
        fitted to failed validations' held-out runs (:func:`.emulator.variance_scale_mle`; the
        design keeps the runs of a second validation, which judges it); or times a fixed factor
        (at least 1).  Reported as ``emulator_variance_scale`` in the diagnostics.

    Returns
    -------
    ABCAlgorithm
        ``host=True``, ``uses_summaries=True``; ``init`` and ``update`` report a
        :class:`SurrogateInfo`, ``finalize`` returns the diagnostics.  A
        :class:`SurrogateAlgorithm`, whose ``augmented_prior`` is the prior of the posterior's
        columns (None without a discrepancy: the prior given).

    Raises
    ------
    ValueError
        Bad settings; an ``observation_error`` or ``discrepancy`` that does not fit the
        observed summaries (the message says which shape was expected).
    """
    # First statement: ``locals()`` holds exactly the parameters, by name.
    settings = make_settings(**locals())
    return SurrogateAlgorithm(
        name="surrogate",
        initial_proposal=partial(initial_proposal, settings),
        init=partial(init, settings),
        propose=partial(propose, settings),
        update=partial(update, settings),
        posterior=posterior,
        settings=settings_record(settings),
        stop_reason=stop_reason,
        finalize=partial(finalize, settings),
        needs_stopping_rule=False,
        host=True,
        uses_summaries=True,
        restore_state=partial(restore_state, settings),
    )


def initial_proposal(settings: SurrogateSettings, key: jax.Array) -> Proposal:
    """The Sobol start: ``num_initial`` points over the prior's box (replicates come later, at
    sites known to succeed)."""
    with jax.enable_x64(True):
        x, _ = design.initial_design(numpy_seed(key), settings.box.num_theta, settings.num_initial, 0)
    return Proposal(settings.box.unit_to_theta(x), np.ones(len(x), bool), np.bool_(True))


def propose(settings: SurrogateSettings, key: jax.Array, state: SurrogateState) -> Proposal:
    """The pending batch chosen by the last update."""
    del settings, key  # the batch was chosen by the last update
    n = int(state.num_pending)
    return Proposal(np.array(state.pending[:n]), np.ones(n, bool), np.bool_(True))


def init(
    settings: SurrogateSettings, key: jax.Array, proposal: Proposal, distances: Any, summaries: Any
) -> tuple[SurrogateState, SurrogateInfo]:
    """The state after the Sobol start's runs (``summaries (num_initial, *observed.shape)``,
    NaN rows for failed runs; ``distances`` are not used).

    Raises
    ------
    ValueError
        A proposal other than :func:`initial_proposal`'s.
    """
    del distances  # the surrogate works on the summaries
    if np.asarray(proposal.thetas).shape[0] != settings.num_initial:
        raise ValueError(f"surrogate: init expects the initial proposal of {settings.num_initial} points")
    state = add_runs(settings, empty_state(settings), proposal, summaries, ROLE_DESIGN, None)
    return advance(settings, key, state._replace(round=np.int64(-1)))


def update(
    settings: SurrogateSettings,
    key: jax.Array,
    state: SurrogateState,
    proposal: Proposal,
    distances: Any,
    summaries: Any,
) -> tuple[SurrogateState, SurrogateInfo]:
    """The state after the pending batch's runs: design runs, or held-out runs while validating.

    Raises
    ------
    RuntimeError
        Called after the run stopped.
    EmulatorFailure
        Validation failed with the budget spent and ``on_failure="raise"``.
    """
    del distances  # the surrogate works on the summaries
    if int(state.phase) == PHASE_DONE:
        raise RuntimeError("surrogate: update called after the run stopped")
    role = ROLE_HOLDOUT if int(state.phase) == PHASE_VALIDATING else ROLE_DESIGN
    group = np.asarray(state.pending_group)[: np.asarray(proposal.thetas).shape[0]]
    state = add_runs(settings, state, proposal, summaries, role, group if np.any(group >= 0) else None)
    return advance(settings, key, state._replace(pending_group=np.full(settings.pending_rows, -1, np.int32)))


def advance(settings: SurrogateSettings, key: jax.Array, state: SurrogateState) -> tuple[SurrogateState, SurrogateInfo]:
    """One round: validate the held-out runs just made, or choose the next design batch."""
    with jax.enable_x64(True), single_threaded_blas():
        state = state._replace(round=np.int64(int(state.round) + 1))
        if int(state.phase) == PHASE_VALIDATING:
            state = validate(settings, key, state)
        else:
            state = design_step(settings, key, state)
    return state, step_info(settings, state)


def validate(settings: SurrogateSettings, key: jax.Array, state: SurrogateState) -> SurrogateState:
    """Check the held-out runs (:func:`._validation.check_holdout`) and decide.

    Pass: done, validated.  Fail: the held-out runs join the design, and design resumes while
    the budget pays another batch and validation (with ``emulator_variance="calibrated"``:
    another validation, whose runs the design kept; the factor on the emulator's variance is
    then re-estimated from every run judged so far) and the lack-of-fit test passed (more
    design may cure an under-resolved emulator, not a GP that cannot represent the simulator);
    otherwise the run stops unvalidated with a RuntimeWarning.

    Raises
    ------
    EmulatorFailure
        That last case, with ``on_failure="raise"``.
    """
    state, passed = check_holdout(settings, key, state)
    if passed:
        return state._replace(validated=np.bool_(True), phase=np.int64(PHASE_DONE), num_pending=np.int64(0))
    state = demote_holdout(state)
    calibrated = settings.emulator_variance == "calibrated"
    # A calibrated run kept the runs of a second validation (budget_allows_batch); design_step
    # starts it at once when no batch is left to pay for.
    goes_on = budget_allows_validation(settings, state) if calibrated else budget_allows_batch(settings, state)
    if goes_on and bool(state.lack_of_fit_ok):
        if calibrated:
            # From every run judged so far, each against the emulator fitted without it; the
            # next validation judges the scaled emulator on fresh runs.
            factor, _, _ = emulator.variance_scale_mle(
                state.judged_residual, state.judged_emulator_var, state.judged_noise_var
            )
            state = state._replace(variance_scale=np.float64(factor))
        return design_step(settings, jax.random.fold_in(key, 3), state)
    message = (
        f"surrogate: the emulator failed validation ({failure_text(state, settings.max_emulator_ratio)}); "
        f"{int(state.count)} real simulations used. The posterior is not trustworthy"
    )
    if settings.on_failure == "raise":
        raise EmulatorFailure(message)
    warnings.warn(message, RuntimeWarning, stacklevel=2)
    return state._replace(phase=np.int64(PHASE_DONE), num_pending=np.int64(0))


def posterior(state: SurrogateState) -> tuple[np.ndarray, np.ndarray]:
    """The current draws ``(P, d + G)`` and their log weights ``(P,)`` (``-inf`` pads)."""
    return np.array(state.draws), np.array(state.log_weights, np.float64)
