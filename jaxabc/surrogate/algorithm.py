"""Surrogate-accelerated calibration as an :class:`~jaxabc.algorithms.base.ABCAlgorithm`.

Each ``update`` adds a batch of real simulations to fixed-size buffers, refits the emulator and
decides what to simulate next:

1. *design*: a Sobol start (``initial_proposal``), replicate runs at two successful sites
   once there are enough successes, then acquisition batches (:mod:`.design`) until the
   emulator's variance over the posterior is small next to the simulator noise
   (``tolerance``) or the design budget is spent;
2. *validation*: draws from the surrogate posterior (NUTS on the synthetic likelihood, or with
   ``mode="abc"`` APMCABC on emulated summaries, :mod:`.abc_mode`); ``num_holdout`` of them are
   simulated for real and compared with the emulator's predictions (:mod:`.diagnostics`).  Pass: stop with
   that posterior.  Fail: the held-out runs join the design and step 1 resumes while the budget
   allows; otherwise the run stops flagged as unvalidated (or raises, ``on_failure="raise"``).

All functions are host code (``host=True``) calling jitted JAX; arithmetic is float64.
"""

from __future__ import annotations

import contextlib
import warnings
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.tree_util import keystr, tree_flatten_with_path

from jaxabc.algorithms.base import ABCAlgorithm, Info, Proposal
from jaxabc.distances import get_distance
from jaxabc.surrogate import abc_mode, design, diagnostics, emulator, evidence, sampling
from jaxabc.surrogate._fit import (
    ROLE_DESIGN,
    ROLE_EMPTY,
    ROLE_FAILED_HOLDOUT,
    ROLE_HOLDOUT,
    fit_likelihood,
    measured_data_settings,
)
from jaxabc.surrogate._support import _FLAG, _evaluate, _failure_text, _misfit_text, _untested_share

__all__ = ["MODES", "EmulatorFailure", "SurrogateAlgorithm", "SurrogateState", "build"]

MODES = ("synthetic_likelihood", "abc")

DESIGN, VALIDATING, DONE = 0, 1, 2


class EmulatorFailure(RuntimeError):
    """The emulator failed its held-out or lack-of-fit checks and the budget is spent."""


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


# Fields added after the first release: a checkpoint without them restores with these values.
_LATER_FIELDS = (
    ".log_weights",
    ".abc_threshold",
    ".abc_generations",
    ".abc_emulated",
    ".joint_mean_squared_error",
    ".joint_ok",
    ".pending_group",
    ".untested_share",
)


def _single_threaded_blas() -> contextlib.AbstractContextManager:
    """Limit BLAS to one thread: the matrices here are small (hundreds of rows), and a
    multi-threaded OpenBLAS on a loaded machine spins orders of magnitude slower."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # optional: without it only speed suffers
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


#: Split R-hat above which the NUTS chains are taken not to agree (e.g. in different modes of
#: a multimodal posterior); the reported draws are then importance-resampled instead.
RHAT_MAX = 1.05
#: Also when the chains' mean is this many importance-sample posterior sds from the importance
#: sample's mean (all chains in one of several modes passes R-hat).
MAX_MEAN_SHIFT = 0.5
#: Importance-sample points per posterior draw in that case.
_IS_POOL = 16


def posterior_ess(state: Any, num_chains: int, abc: bool) -> float:
    """ESS of the reported draws: Kish's of the weights in ABC mode (and before NUTS has run),
    ArviZ's multi-chain ESS of the NUTS chains otherwise -- equal weights say nothing of the
    chains' autocorrelation."""
    draws = np.asarray(state.draws, np.float64)
    rhat = np.asarray(state.rhat)
    resampled = np.any(np.asarray(state.log_weights) != 0)
    if abc or not np.all(np.isfinite(rhat)) or resampled or len(draws) % num_chains:
        # Weighted draws: APMCABC's population, the design phase's importance sample, or the
        # importance resample that replaced chains which did not mix.
        return design.kish_ess(state.log_weights)
    from jaxabc.diagnostics import chain_ess

    return chain_ess(draws.reshape(num_chains, -1, draws.shape[1]))


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


def _observation_error(error: Any, shape: tuple[int, ...]) -> np.ndarray | None:
    """``observation_error`` as the (k, k) covariance of :func:`jaxabc.noise.observation_covariance`."""
    if error is None:
        return None
    from jaxabc.noise import observation_covariance

    try:
        return observation_covariance(error, tuple(shape))
    except ValueError as exc:
        raise ValueError(f"surrogate: {exc}") from None


def _discrepancy(discrepancy: Any, shape: tuple[int, ...]) -> Any:
    """``discrepancy`` as a :class:`jaxabc.noise.ResolvedDiscrepancy` checked against ``shape``."""
    if discrepancy is None:
        return None
    from jaxabc.noise import Discrepancy, ResolvedDiscrepancy

    k = int(np.prod(shape)) if len(shape) else 1
    if isinstance(discrepancy, Discrepancy):
        try:
            return discrepancy.resolve(tuple(shape))
        except ValueError as exc:
            raise ValueError(f"surrogate: {exc}") from None
    if not isinstance(discrepancy, ResolvedDiscrepancy):
        raise TypeError(
            f"discrepancy must be a jaxabc.noise.Discrepancy or ResolvedDiscrepancy, got {type(discrepancy).__name__}"
        )
    member = np.asarray(discrepancy.membership, np.float64)
    max_sd = np.asarray(discrepancy.max_sd, np.float64)
    if member.ndim != 2 or member.shape[1] != k:
        raise ValueError(
            f"surrogate: discrepancy membership has shape {member.shape}, but the observed data have {k} "
            f"summaries: it must be (G, {k}) (resolve the Discrepancy against the observed summaries)"
        )
    g = member.shape[0]
    if g == 0:
        raise ValueError("surrogate: discrepancy has no groups")
    if max_sd.shape != (g,) or len(discrepancy.names) != g:
        raise ValueError(
            f"surrogate: discrepancy has {g} groups but max_sd of shape {max_sd.shape} and "
            f"{len(discrepancy.names)} names: give one of each per group"
        )
    if not np.all(np.isfinite(max_sd)) or np.any(max_sd <= 0):
        raise ValueError(f"surrogate: discrepancy max_sd must be positive and finite, got {max_sd.tolist()}")
    if not np.all((member == 0) | (member == 1)) or np.any(member.sum(axis=0) > 1):
        raise ValueError("surrogate: discrepancy membership must be 0/1 with every summary in at most one group")
    return ResolvedDiscrepancy(member, max_sd, tuple(str(n) for n in discrepancy.names))


def _int_seed(key: jax.Array) -> int:
    return int(jax.random.randint(key, (), 0, 2**31 - 1))


def build(
    prior: Any,
    num_particles: int = 2000,
    *,
    observed: Any,
    max_simulations: int,
    num_initial: int | None = None,
    num_replicates: int = 8,
    batch_size: int = 10,
    num_holdout: int = 20,
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
        Sobol points of the start (default ``max(20, 10 d)``).
    num_replicates : int
        Repeat runs that measure the simulator's noise, at two successful runs away from the
        failed ones, once ``max(3, d + 1)`` runs have succeeded (0: none; the lack-of-fit test
        is then skipped, and the nugget rests on the design's scatter alone).
    batch_size : int
        Simulations per acquisition batch (match the number of workers).
    num_holdout : int
        Held-out simulations per validation.
    tolerance : float
        Design stops once the posterior mean of ``mean_j var_j / noise_j^2`` (emulator over
        simulator variance) is below this: 0.01 keeps the emulator's error near a tenth of the
        noise, so posterior means move by about a tenth of a posterior sd.
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

    Returns
    -------
    ABCAlgorithm
        ``host=True``, ``uses_summaries=True``; ``finalize`` returns the diagnostics.  A
        :class:`SurrogateAlgorithm`, whose ``augmented_prior`` is the prior of the posterior's
        columns (None without a discrepancy: the prior given).

    Raises
    ------
    ValueError
        Bad settings; an ``observation_error`` or ``discrepancy`` that does not fit the
        observed summaries (the message says which shape was expected).
    """
    low = np.asarray(prior.low, np.float64)
    high = np.asarray(prior.high, np.float64)
    d = low.size
    obs = np.asarray(observed, np.float64)
    k = obs.size
    if not np.all(np.isfinite(obs)):
        raise ValueError("observed summaries must be finite")
    obs_error = _observation_error(observation_error, obs.shape)
    disc = _discrepancy(discrepancy, obs.shape)
    # Parameters sampled: theta (d), then the discrepancy sds (G); the box of all of them.
    G = 0 if disc is None else len(disc.max_sd)
    D = d + G
    low_all = np.concatenate([low, np.zeros(G)])
    high_all = np.concatenate([high, np.zeros(0) if disc is None else disc.max_sd])
    num_initial = max(20, 10 * d) if num_initial is None else int(num_initial)
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    abc = mode == "abc"
    if abc:
        abc_mode.population_size(num_particles, abc_alpha)  # refuses an alpha that cannot keep P
        abc_distance_fn = get_distance(abc_distance)
        if abc_max_generations < 2:
            raise ValueError(f"abc_max_generations must be at least 2, got {abc_max_generations}")
    if num_particles < 1000 or (not abc and num_particles % num_chains):
        raise ValueError(
            f"num_particles must be >= 1000 and a multiple of num_chains={num_chains}, got {num_particles}"
        )
    log_min_feasibility = sampling.log_level(min_feasibility)
    if on_failure not in ("flag", "raise"):
        raise ValueError(f"on_failure must be 'flag' or 'raise', got {on_failure!r}")
    if num_replicates < 0 or batch_size < 1 or num_holdout < diagnostics.MIN_HOLDOUT_RUNS:
        raise ValueError(f"need num_replicates >= 0, batch_size >= 1 and num_holdout >= {diagnostics.MIN_HOLDOUT_RUNS}")
    first = num_initial + num_replicates
    if first + num_holdout > max_simulations:
        raise ValueError(
            f"max_simulations={max_simulations} leaves no room for validation: the start uses "
            f"{first} runs and each validation {num_holdout}; raise max_simulations or lower "
            "num_initial / num_replicates / num_holdout"
        )
    q = min(k, max_outputs)
    M = int(max_simulations)
    # Below this many successful runs the emulator is not fitted; batches explore instead.
    min_successes = max(3, d + 1)
    # Exploration spreads a batch over a tenth of the box per parameter (unit-box widths).
    explore_radius = 0.1
    B = max(first, batch_size, num_holdout)
    settings = {
        "num_particles": int(num_particles),
        "max_simulations": M,
        "num_initial": num_initial,
        "num_replicates": int(num_replicates),
        "batch_size": int(batch_size),
        "num_holdout": int(num_holdout),
        "tolerance": float(tolerance),
        "max_outputs": int(max_outputs),
        "num_candidates": int(num_candidates),
        "num_chains": int(num_chains),
        "num_warmup": int(num_warmup),
        "thin": int(thin),
        "on_failure": on_failure,
        "observed_size": k,
        "max_emulator_ratio": float(max_emulator_ratio),
        "min_feasibility": float(min_feasibility),
    }
    # Only when given, so that runs without them keep their checkpoint fingerprints.
    settings |= measured_data_settings(obs_error, disc)
    if disc is not None:
        names = tuple(getattr(prior, "names", None) or (f"theta{i}" for i in range(d)))
        units = tuple(getattr(prior, "units", None) or ("",) * d)
        settings["augmented_prior"] = {
            "type": "Uniform",
            "low": low_all.tolist(),
            "high": high_all.tolist(),
            "names": [*names, *disc.names],
            "units": [*units, *("summary units",) * G],
            # A standard deviation cannot be negative: 0 is a physical limit, max_sd a choice.
            "limits": [*([False, False] for _ in range(d)), *([True, False] for _ in range(G))],
        }
    if abc:
        # Only in ABC mode, so that synthetic-likelihood checkpoints keep their fingerprints.
        settings |= {
            "mode": mode,
            "abc_distance": abc_distance
            if isinstance(abc_distance, str)
            else getattr(abc_distance, "__name__", "custom"),
            "abc_alpha": float(abc_alpha),
            "abc_acceptance_cutoff": float(abc_acceptance_cutoff),
            "abc_max_generations": int(abc_max_generations),
        }

    def to_unit(theta: np.ndarray) -> np.ndarray:
        return (theta - low) / (high - low)

    def to_theta(x: np.ndarray) -> np.ndarray:
        return low + x * (high - low)

    def to_unit_all(values: np.ndarray) -> np.ndarray:
        """Posterior draws (theta and discrepancy sds) to the augmented unit box."""
        return (values - low_all) / (high_all - low_all)

    def to_values(x: np.ndarray) -> np.ndarray:
        """Augmented unit-box points to posterior draws (theta, then discrepancy sds)."""
        return low_all + x * (high_all - low_all)

    def empty_state() -> SurrogateState:
        return SurrogateState(
            thetas=np.zeros((M, d)),
            summaries=np.full((M, k), np.nan),
            ok=np.zeros(M, bool),
            role=np.full(M, ROLE_EMPTY, np.int8),
            group=np.full(M, -1, np.int32),
            count=np.int64(0),
            phase=np.int64(DESIGN),
            round=np.int64(0),
            pending=np.zeros((B, d)),
            num_pending=np.int64(0),
            draws=np.zeros((num_particles, D)),
            log_weights=np.zeros(num_particles),
            hyper=np.zeros((q, d + 2)),
            holdout_errors=np.full((num_holdout, q), np.nan),
            validated=np.bool_(False),
            lack_of_fit_ok=np.bool_(True),
            coverage=np.float64(np.nan),
            mean_squared_error=np.float64(np.nan),
            emulator_ratio=np.float64(np.nan),
            rhat=np.full(D, np.nan),
            abc_threshold=np.float64(np.nan),
            abc_generations=np.int64(0),
            abc_emulated=np.int64(0),
            joint_mean_squared_error=np.float64(np.nan),
            joint_ok=np.bool_(True),
            pending_group=np.full(B, -1, np.int32),
            untested_share=np.float64(np.nan),
        )

    def initial_proposal(key: jax.Array) -> Proposal:
        with jax.enable_x64(True):
            # Replicates come later, at sites known to succeed (replicate_step).
            x, _ = design.initial_design(_int_seed(key), d, num_initial, 0)
        return Proposal(to_theta(x), np.ones(len(x), bool), np.bool_(True))

    def propose(key: jax.Array, state: SurrogateState) -> Proposal:
        n = int(state.num_pending)
        return Proposal(np.array(state.pending[:n]), np.ones(n, bool), np.bool_(True))

    def add_rows(
        state: SurrogateState, proposal: Proposal, summaries: Any, role: int, group: np.ndarray | None
    ) -> SurrogateState:
        active = np.asarray(proposal.active, bool)
        th = np.asarray(proposal.thetas, np.float64)[active]
        s = np.asarray(summaries, np.float64)
        s = s.reshape(s.shape[0], -1)
        if s.shape[1] != k:
            raise ValueError(f"summaries have {s.shape[1]} values per simulation but observed has {k}")
        s = s[active]
        n, c = th.shape[0], int(state.count)
        if c + n > M:
            raise RuntimeError(f"surrogate: {c + n} simulations would exceed max_simulations={M}")
        ok = np.all(np.isfinite(s), axis=1)
        thetas, summ = state.thetas.copy(), state.summaries.copy()
        oks, roles, groups = state.ok.copy(), state.role.copy(), state.group.copy()
        thetas[c : c + n], summ[c : c + n] = th, np.where(ok[:, None], s, np.nan)
        oks[c : c + n], roles[c : c + n] = ok, role
        if group is not None:
            groups[c : c + n] = group[active]
        return state._replace(thetas=thetas, summaries=summ, ok=oks, role=roles, group=groups, count=np.int64(c + n))

    def fit(state: SurrogateState):
        """Emulator on the design rows; returns (transform, emulator, likelihood model, z_all)."""
        return fit_likelihood(
            state,
            low,
            high,
            obs,
            max_outputs,
            M,
            log_min_feasibility,
            observation_error=obs_error,
            discrepancy=disc,
        )

    def evaluate(model: sampling.LikelihoodModel, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # In chunks of the candidate count: one compiled shape, bounded memory.
        out = [_evaluate(model, x[i : i + num_candidates]) for i in range(0, len(x), num_candidates)]
        return np.concatenate([o[0] for o in out]), np.concatenate([o[1] for o in out])

    def importance_posterior(rng: np.random.Generator, model: sampling.LikelihoodModel, size: int | None = None):
        """Candidate points with self-normalised importance weights of the surrogate posterior
        (``size`` of them in the second, local pass; default ``num_candidates``), in the
        augmented box (theta, then the discrepancy sds)."""
        cand, (lp, ratio) = design.importance_pool(
            rng, D, size or num_candidates, partial(evaluate, model), first_num=num_candidates
        )
        logw = lp - cand.log_q
        w = np.exp(logw - np.max(logw))
        w /= w.sum()
        return cand.x, lp, ratio, w

    def importance_draws(rng: np.random.Generator, model: sampling.LikelihoodModel) -> tuple[np.ndarray, np.ndarray]:
        """``num_particles`` draws resampled from a large importance sample, as distinct points
        with their counts as weights (log; ``-inf`` pads): duplicates are not counted twice in
        the ESS.  For posteriors the NUTS chains do not mix over (several modes)."""
        x, _, _, w = importance_posterior(rng, model, _IS_POOL * num_particles)
        unique, counts = np.unique(rng.choice(len(x), size=num_particles, p=w), return_counts=True)
        draws = np.repeat(x[unique[:1]], num_particles, axis=0)
        draws[: len(unique)] = x[unique]
        log_weights = np.full(num_particles, -np.inf)
        log_weights[: len(unique)] = np.log(counts)
        return draws, log_weights

    def explore_step(key: jax.Array, state: SurrogateState, num_ok: int) -> SurrogateState:
        """Too few successful runs for an emulator (most of the box fails, as water's prior
        does): the next batch goes where the success classifier expects runs to succeed,
        spread out and away from the runs already made."""
        used = state.role != ROLE_EMPTY
        if M - int(state.count) < batch_size + num_holdout:
            raise RuntimeError(
                f"surrogate: only {num_ok} of {int(used.sum())} simulations succeeded and the budget is "
                f"spent; the emulator needs at least {min_successes}. Check the simulator, narrow the "
                "prior to where it succeeds, or raise max_simulations"
            )
        rng = np.random.default_rng(_int_seed(key))
        cand = design.candidates(rng, d, num_candidates)
        x_used = to_unit(state.thetas[used])
        feas = sampling.fit_feasibility(x_used, state.ok[used], size=M)  # one compilation per budget
        acquisition = np.array(sampling.feasibility(feas, jnp.asarray(cand.x)), np.float64)
        for x0 in x_used:  # no repeats of what is known
            acquisition *= 1.0 - np.exp(-0.5 * np.sum(((cand.x - x0) / explore_radius) ** 2, axis=1))
        idx = design.select_batch(cand.x, acquisition, np.full(d, explore_radius), batch_size)
        pending = np.zeros((B, d))
        pending[:batch_size] = to_theta(cand.x[idx])
        return state._replace(pending=pending, num_pending=np.int64(batch_size), phase=np.int64(DESIGN))

    def replicate_step(state: SurrogateState) -> SurrogateState | None:
        """The replicate runs, once the successful design runs can host them (None: not now).

        They go to two successful runs, away from the failed ones (:func:`.design.replicate_sites`),
        which join their groups.  Never when the budget left could not also pay a validation.
        """
        used = state.role != ROLE_EMPTY
        good = used & state.ok & (state.role == ROLE_DESIGN)
        done = np.any(state.group[used] >= 0)
        if num_replicates == 0 or done or good.sum() < min_successes:
            return None
        if M - int(state.count) < num_replicates + num_holdout:
            return None
        rows = np.flatnonzero(good)
        failed = to_unit(state.thetas[used & ~state.ok])
        site, count = design.replicate_sites(to_unit(state.thetas[rows]), failed, num_replicates)
        group = state.group.copy()
        group[rows[site]] = np.arange(site.size)
        pending = np.zeros((B, d))
        pending_group = np.full(B, -1, np.int32)
        pending[:num_replicates] = np.repeat(state.thetas[rows[site]], count, axis=0)
        pending_group[:num_replicates] = np.repeat(np.arange(site.size), count)
        return state._replace(
            group=group,
            pending=pending,
            num_pending=np.int64(num_replicates),
            pending_group=pending_group,
            phase=np.int64(DESIGN),
        )

    def design_step(key: jax.Array, state: SurrogateState) -> SurrogateState:
        replicated = replicate_step(state)
        if replicated is not None:
            return replicated
        num_ok = int(np.sum((state.role != ROLE_EMPTY) & state.ok & (state.role != ROLE_HOLDOUT)))
        if num_ok < min_successes:
            return explore_step(key, state, num_ok)
        transform, emu, model, _ = fit(state)
        rng = np.random.default_rng(_int_seed(key))
        x, lp, ratio, w = importance_posterior(rng, model)
        emulator_ratio = float(w @ ratio)
        draws = to_values(x[rng.choice(len(x), size=num_particles, p=w)])
        hyper = np.asarray(np.column_stack([emu.log_amp, emu.log_ls, emu.log_noise]))
        state = state._replace(
            draws=draws, log_weights=np.zeros(num_particles), hyper=hyper, emulator_ratio=np.float64(emulator_ratio)
        )
        room = M - int(state.count)
        converged = emulator_ratio < tolerance and int(state.round) >= 1
        if converged or room < batch_size + num_holdout:
            if abc:
                return start_abc_validation(key, state, transform, model)
            return start_validation(key, state, model, x, w)
        # The posterior density already holds p_feasible once; a second factor is the chance
        # that the run succeeds and teaches the emulator anything.
        # With a discrepancy the candidates are (theta, delta) points: the acquisition weighs
        # each by the joint posterior, and the batch is spread over theta alone.
        xt = x[:, :d]
        p_ok = np.asarray(sampling.feasibility(model.feasible, jnp.asarray(xt)))
        acquisition = design.acquisition(lp, ratio, p_ok)
        # Penalise around each pick on the scale of the posterior (half its sd), or of the
        # emulator where that is shorter: GP length scales often exceed the posterior, and a
        # penalty that wide would push the batch into the corners of the box.  Failed runs are
        # penalised too: the emulator learnt nothing there.
        post_sd = np.sqrt(w @ (xt - w @ xt) ** 2)
        scale = design.penalty_radius(np.exp(np.min(np.asarray(emu.log_ls), axis=0)), post_sd)
        used = state.role != ROLE_EMPTY
        failed = to_unit(state.thetas[used & ~state.ok])
        idx = design.select_batch(xt, acquisition, scale, batch_size, avoid=failed)
        pending = np.zeros((B, d))
        pending[:batch_size] = to_theta(xt[idx])
        return state._replace(pending=pending, num_pending=np.int64(batch_size), phase=np.int64(DESIGN))

    def start_validation(key, state, model, x, w) -> SurrogateState:
        rng = np.random.default_rng(_int_seed(jax.random.fold_in(key, 1)))
        starts = np.clip(x[rng.choice(len(x), size=num_chains, p=w)], 1e-6, 1 - 1e-6)
        xc = np.clip(x, 1e-9, 1 - 1e-9)
        u = np.log(xc) - np.log1p(-xc)
        mu = w @ u
        metric = (u - mu).T @ ((u - mu) * w[:, None]) + 1e-8 * np.eye(D)
        step_size = 0.9 * D**-0.25
        for _ in range(4):
            draws, acceptance = sampling.nuts(
                jax.random.fold_in(key, 2),
                model,
                jnp.asarray(starts),
                jnp.asarray(metric),
                jnp.asarray(step_size),
                num_warmup,
                num_particles // num_chains,
                thin,
            )
            # A metric from importance weights may be off; a smaller step restores acceptance
            # without recompiling (the step size is traced).
            if float(np.min(acceptance)) >= 0.6:
                break
            step_size /= 2
        rhat = np.asarray(sampling.split_rhat(draws))
        flat = np.asarray(draws).reshape(-1, D)
        log_weights = np.zeros(num_particles)
        # Held-out points spread over the whole sample (one from each chain in turn).
        pick = np.asarray(draws)[:, :: max(1, draws.shape[1] * num_chains // num_holdout)].transpose(1, 0, 2)
        pick = pick.reshape(-1, D)[:num_holdout]
        sd_is = np.sqrt(w @ (x - w @ x) ** 2)
        shift = np.abs(flat.mean(axis=0) - w @ x) / np.maximum(sd_is, 1e-12)
        if not np.all(rhat <= RHAT_MAX) or np.any(shift > MAX_MEAN_SHIFT):
            # The chains disagree with each other or with the importance sample (chains in
            # different modes, or all in one of several): their draws would weigh the modes by
            # where the chains started.  An importance sample weighs them right in a low-
            # dimensional box; R-hat stays in the diagnostics.
            flat, log_weights = importance_draws(rng, model)
            keep = np.flatnonzero(np.isfinite(log_weights))
            pick = flat[
                rng.choice(keep, size=num_holdout, p=np.exp(log_weights[keep]) / np.exp(log_weights[keep]).sum())
            ]
        pending = np.zeros((B, d))
        pending[:num_holdout] = to_theta(pick[:, :d])  # held-out runs at theta's columns
        return state._replace(
            draws=to_values(flat),
            log_weights=log_weights,
            untested_share=np.float64(_untested_share(model, x, flat, log_weights)),
            rhat=rhat,
            pending=pending,
            num_pending=np.int64(num_holdout),
            phase=np.int64(VALIDATING),
        )

    def start_abc_validation(key, state, transform, model) -> SurrogateState:
        """ABC mode: APMCABC on the emulated simulator, then held-out points resampled from it."""
        emulated = abc_mode.emulated_simulator(
            model.emulator,
            transform,
            model.noise_chol,
            model.feasible,
            low,
            high,
            min_feasibility,
            observation_error=obs_error,
            discrepancy=disc,
        )
        post = abc_mode.run_abc(
            jax.random.fold_in(key, 4),
            emulated,
            abc_mode.project_observed(emulated, transform, obs),
            num_particles=num_particles,
            alpha=abc_alpha,
            acceptance_cutoff=abc_acceptance_cutoff,
            distance=abc_distance_fn,
            max_generations=abc_max_generations,
        )
        if not post.stopped:
            warnings.warn(
                f"surrogate ABC mode: APMCABC reached abc_max_generations={abc_max_generations} "
                f"before its acceptance cutoff (threshold {post.threshold:.3g}); raise it for a "
                "smaller tolerance",
                RuntimeWarning,
                stacklevel=2,
            )
        w = np.exp(post.log_weights - np.max(post.log_weights))
        w /= w.sum()
        rng = np.random.default_rng(_int_seed(jax.random.fold_in(key, 5)))
        # Systematic resampling: held-out points spread over the weighted sample.
        idx = np.searchsorted(np.cumsum(w), (rng.uniform() + np.arange(num_holdout)) / num_holdout)
        pending = np.zeros((B, d))
        pending[:num_holdout] = post.particles[np.minimum(idx, num_particles - 1)][:, :d]
        cand = design.candidates(rng, d, num_candidates)
        share = _untested_share(model, cand.x, to_unit(np.asarray(post.particles)[:, :d]), np.asarray(post.log_weights))
        return state._replace(
            draws=post.particles,
            log_weights=post.log_weights,
            untested_share=np.float64(share),
            abc_threshold=np.float64(post.threshold),
            abc_generations=np.int64(post.generations),
            abc_emulated=np.int64(post.num_emulated),
            pending=pending,
            num_pending=np.int64(num_holdout),
            phase=np.int64(VALIDATING),
        )

    def validate(key: jax.Array, state: SurrogateState) -> SurrogateState:
        _, emu, model, z_all = fit(state)
        rows = np.flatnonzero((state.role == ROLE_HOLDOUT) & state.ok)
        mean, var = emulator.predict(emu, jnp.asarray(to_unit(state.thetas[rows])))
        noise_var = np.exp(2 * np.asarray(emu.log_noise))
        chol = np.asarray(model.noise_chol, np.float64)
        # Only the outputs in the likelihood are checked: a constant one would score 0 and
        # dilute the errors of the others.
        on = np.asarray(model.active)
        check = diagnostics.holdout_check(
            z_all[rows][:, on],
            np.asarray(mean)[:, on],
            np.asarray(var)[:, on],
            noise_var[on],
            (chol @ chol.T)[np.ix_(on, on)],
        )
        joint_ok = not check.joint_mean_squared > check.mean_squared_max
        rep_var, df = diagnostics.replicate_variance(z_all, state.group, state.ok & (state.role == ROLE_DESIGN))
        lof_ok, _ = diagnostics.lack_of_fit(noise_var[on], rep_var[on], df)
        errors = np.full((num_holdout, q), np.nan)
        errors[: len(rows), on] = check.errors
        resolved = float(state.emulator_ratio) <= max_emulator_ratio
        enough = len(rows) >= diagnostics.MIN_HOLDOUT_RUNS
        passed = check.passed and lof_ok is not False and resolved and enough
        state = state._replace(
            holdout_errors=errors,
            coverage=np.float64(check.coverage),
            mean_squared_error=np.float64(check.mean_squared),
            lack_of_fit_ok=np.bool_(lof_ok is not False),
            joint_mean_squared_error=np.float64(check.joint_mean_squared),
            joint_ok=np.bool_(joint_ok),
        )
        if passed:
            return state._replace(validated=np.bool_(True), phase=np.int64(DONE), num_pending=np.int64(0))
        role = state.role.copy()
        role[role == ROLE_HOLDOUT] = ROLE_FAILED_HOLDOUT
        state = state._replace(role=role)
        if M - int(state.count) >= batch_size + num_holdout and lof_ok is not False:
            # More design may cure an under-resolved emulator; a failed lack-of-fit test will not.
            return design_step(jax.random.fold_in(key, 3), state)
        message = (
            f"surrogate: the emulator failed validation ({_failure_text(state, max_emulator_ratio)}); "
            f"{int(state.count)} real simulations used. The posterior is not trustworthy"
        )
        if on_failure == "raise":
            raise EmulatorFailure(message)
        warnings.warn(message, RuntimeWarning, stacklevel=2)
        return state._replace(phase=np.int64(DONE), num_pending=np.int64(0))

    def info_of(state: SurrogateState) -> Info:
        done = int(state.phase) == DONE
        trusted = (
            bool(state.lack_of_fit_ok) and bool(state.joint_ok) and float(state.emulator_ratio) <= max_emulator_ratio
        )
        threshold = float(state.mean_squared_error) if trusted else np.inf
        return Info(
            generation_done=np.bool_(True),
            stop=np.bool_(done),
            threshold=np.float64(threshold),
            acceptance_rate=np.float64(state.coverage),
            ess=np.float64(posterior_ess(state, num_chains, abc)),
        )

    def step(key: jax.Array, state: SurrogateState) -> tuple[SurrogateState, Info]:
        with jax.enable_x64(True), _single_threaded_blas():
            state = state._replace(round=np.int64(int(state.round) + 1))
            if int(state.phase) == VALIDATING:
                state = validate(key, state)
            else:
                state = design_step(key, state)
        return state, info_of(state)

    def init(key: jax.Array, proposal: Proposal, distances: Any, summaries: Any) -> tuple[SurrogateState, Info]:
        if np.asarray(proposal.thetas).shape[0] != num_initial:
            raise ValueError(f"surrogate: init expects the initial proposal of {num_initial} points")
        state = add_rows(empty_state(), proposal, summaries, ROLE_DESIGN, None)
        return step(key, state._replace(round=np.int64(-1)))

    def update(
        key: jax.Array, state: SurrogateState, proposal: Proposal, distances: Any, summaries: Any
    ) -> tuple[SurrogateState, Info]:
        if int(state.phase) == DONE:
            raise RuntimeError("surrogate: update called after the run stopped")
        role = ROLE_HOLDOUT if int(state.phase) == VALIDATING else ROLE_DESIGN
        group = np.asarray(state.pending_group)[: np.asarray(proposal.thetas).shape[0]]
        state = add_rows(state, proposal, summaries, role, group if np.any(group >= 0) else None)
        return step(key, state._replace(pending_group=np.full(B, -1, np.int32)))

    def posterior(state: SurrogateState) -> tuple[np.ndarray, np.ndarray]:
        return np.array(state.draws), np.array(state.log_weights, np.float64)

    def stop_reason(settings: dict, info: Info) -> str:
        if not np.isfinite(float(info.threshold)) or np.isnan(float(info.acceptance_rate)):
            return _FLAG + "emulator failed validation (see diagnostics)"
        n = settings["num_holdout"] * min(settings["observed_size"], settings["max_outputs"])
        cov_min, msq_max = diagnostics.holdout_bounds(n)
        if float(info.acceptance_rate) >= cov_min and float(info.threshold) <= msq_max:
            return (
                f"emulator validated on held-out simulations (95 % coverage "
                f"{float(info.acceptance_rate):.2f}, mean squared standardised error {float(info.threshold):.2f})"
            )
        return _FLAG + (
            f"emulator failed validation (coverage {float(info.acceptance_rate):.2f}, "
            f"mean squared standardised error {float(info.threshold):.2f})"
        )

    def observed_misfit(state: SurrogateState) -> dict | None:
        """The posterior predictive check of the observed summaries (None before any posterior)."""
        if int(state.phase) != DONE:
            return None
        with jax.enable_x64(True), _single_threaded_blas():
            transform, _, model, _ = fit(state)
            lw = np.asarray(state.log_weights, np.float64)
            x = to_unit_all(np.asarray(state.draws, np.float64))
            return evidence.observed_misfit(model, transform, x, np.exp(lw - np.max(lw)))

    def finalize(state: SurrogateState) -> dict:
        c = int(state.count)
        ls = np.exp(state.hyper[:, 1 : 1 + d]) * (high - low)
        diag = {
            "validated": bool(state.validated),
            "failure": "" if bool(state.validated) else _failure_text(state, max_emulator_ratio),
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
            "emulator_to_noise_variance": float(state.emulator_ratio),
            "posterior_share_below_design_level": float(state.untested_share),
            "lengthscales": ls.tolist(),
            "amplitude_standardised": np.exp(state.hyper[:, 0]).tolist(),
            "noise_sd_standardised": np.exp(state.hyper[:, -1]).tolist(),
            "nuts_split_rhat": state.rhat.tolist(),
            "posterior_sampler": "importance resampling (the NUTS chains disagreed)"
            if not abc and np.any(np.asarray(state.log_weights) != 0)
            else ("APMCABC on the emulator" if abc else "NUTS"),
            "rounds": int(state.round),
        }
        diag["observed_misfit"] = misfit = observed_misfit(state)
        if misfit is not None and misfit["p_value"] < diagnostics.MISFIT_P_VALUE:
            warnings.warn(_misfit_text(misfit), RuntimeWarning, stacklevel=2)
        ess = posterior_ess(state, num_chains, abc)
        if int(state.phase) == DONE and ess < diagnostics.MIN_POSTERIOR_ESS:
            warnings.warn(
                f"surrogate: the posterior rests on an effective sample size of {ess:.0f} (below "
                f"{diagnostics.MIN_POSTERIOR_ESS}; sampler: {diag['posterior_sampler']}): its intervals and "
                "correlation are not resolved. A sharper posterior than the importance pool resolves "
                f"({_IS_POOL} points per particle) needs more num_particles",
                RuntimeWarning,
                stacklevel=2,
            )
        if abc:
            diag |= {
                "mode": mode,
                "abc_threshold": float(state.abc_threshold),
                "abc_generations": int(state.abc_generations),
                "abc_emulated_simulations": int(state.abc_emulated),
            }
        return {"ess": ess, "diagnostics": diag}

    def restore_state(flat: dict[str, np.ndarray]) -> SurrogateState:
        template = empty_state()
        leaves = tree_flatten_with_path(template)[0]
        flat = {**{keystr(p): v for p, v in leaves if keystr(p) in _LATER_FIELDS}, **flat}
        missing = [keystr(p) for p, _ in leaves if keystr(p) not in flat]
        if missing:
            raise ValueError(f"checkpoint lacks surrogate state entries {missing}")
        return SurrogateState(*[np.asarray(flat[keystr(p)], dtype=np.asarray(v).dtype) for p, v in leaves])

    return SurrogateAlgorithm(
        name="surrogate",
        initial_proposal=initial_proposal,
        init=init,
        propose=propose,
        update=update,
        posterior=posterior,
        settings=settings,
        stop_reason=stop_reason,
        finalize=finalize,
        needs_stopping_rule=False,
        host=True,
        uses_summaries=True,
        restore_state=restore_state,
    )
