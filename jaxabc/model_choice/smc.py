"""One model's population in ABC model choice: proposals, importance weights, evidence, tolerance.

Host code in NumPy float64: the populations change size every generation, and jitting these
small computations for every new size would cost more than running them.  The only JAX calls
are the prior's own ``sample`` and ``log_prob`` and the splitting of keys, made in chunks of
one fixed size so that each compiles once.  Randomness still flows from the run's key: the
resampling and the kernel's Gaussian noise come from a NumPy generator seeded with the
generation's key data.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import jax
import numpy as np
from scipy.linalg import solve_triangular
from scipy.special import logsumexp

from jaxabc.driver.checks import shapes_compatible
from jaxabc.driver.context import Recorder, mark_bad_distances
from jaxabc.errors import STATUS_OK, TooManyFailures
from jaxabc.executors import Executor
from jaxabc.priors import Uniform
from jaxabc.results import ABCResult, versions

__all__ = [
    "ALGORITHM_NAME",
    "HISTORY_KEYS",
    "Context",
    "ModelTrack",
    "Population",
    "Settings",
    "evidence_estimate",
    "fraction_within",
    "next_threshold",
    "propose",
    "simulation_keys",
    "weighted_quantile",
]

_CACHE_SIZE = 32
_prior_functions: collections.OrderedDict[Any, Callable] = collections.OrderedDict()
# Rows of the (proposals x centres) kernel matrix evaluated at once: bounds memory.
_CHUNK = 2048
# Calls into JAX (prior draws and densities, key splitting) go in chunks of this fixed size, so
# that they compile once, whatever the number of proposals.
_JAX_CHUNK = 256


class Population(NamedTuple):
    """One model's accepted particles at one tolerance.

    Attributes
    ----------
    particles : numpy.ndarray, shape (n, d)
    log_weights : numpy.ndarray, shape (n,)
        Unnormalised log importance weights ``log prior - log proposal``.
    distances : numpy.ndarray, shape (n,)
    """

    particles: np.ndarray
    log_weights: np.ndarray
    distances: np.ndarray


def _chunks(num: int, size: int) -> list[tuple[int, int]]:
    return [(start, min(start + size, num)) for start in range(0, num, size)]


def _jitted(prior: Any, method: str) -> Callable:
    """``jax.jit(prior.<method>)``, reused across runs.

    A :class:`~jaxabc.priors.Uniform` is defined by its box, so equal boxes share the compiled
    function (the driver hands every run a fresh copy of the prior); any other prior is keyed
    on the object itself, which the cache holds, so its id cannot be reused.
    """
    ident = (
        (np.asarray(prior.low).tobytes(), np.asarray(prior.high).tobytes(), np.asarray(prior.low).dtype.str)
        if type(prior) is Uniform
        else prior
    )
    try:
        key: Any = (ident, method)
        hit = _prior_functions.get(key)
    except TypeError:  # an unhashable prior: compile per run
        key, hit = None, None
    if hit is not None:
        _prior_functions.move_to_end(key)
        return hit
    fn = getattr(prior, method)
    fn = jax.jit(fn, static_argnums=1) if method == "sample" else jax.jit(fn)
    if key is not None:
        _prior_functions[key] = fn
        while len(_prior_functions) > _CACHE_SIZE:
            _prior_functions.popitem(last=False)
    return fn


def prior_sample(prior: Any, key: jax.Array, num: int) -> np.ndarray:
    """``num`` prior draws, shape (num, d): chunk ``c`` of ``_JAX_CHUNK`` draws from
    ``fold_in(key, c)``, so one compiled shape serves every ``num``."""
    sample = _jitted(prior, "sample")
    pieces = [
        np.asarray(sample(jax.random.fold_in(key, c), _JAX_CHUNK))[: stop - start]
        for c, (start, stop) in enumerate(_chunks(num, _JAX_CHUNK))
    ]
    return np.concatenate(pieces) if pieces else np.zeros((0, prior.dim))


def prior_log_prob(prior: Any, thetas: np.ndarray) -> np.ndarray:
    """Normalised log prior density, shape (m,); ``-inf`` outside the support."""
    log_prob = _jitted(prior, "log_prob")
    dtype = np.asarray(prior.low).dtype
    out = np.empty(thetas.shape[0])
    for start, stop in _chunks(thetas.shape[0], _JAX_CHUNK):
        rows = thetas[start:stop]
        padded = np.concatenate([rows, np.repeat(rows[:1], _JAX_CHUNK - rows.shape[0], axis=0)]).astype(dtype)
        out[start:stop] = np.asarray(log_prob(padded), np.float64)[: stop - start]
    return out


def simulation_keys(key: jax.Array, num: int) -> np.ndarray:
    """One raw key (``uint32`` key data) per proposal slot, shape (num, ...): chunk ``c`` is
    ``split(fold_in(key, c), _JAX_CHUNK)``, so slot ``i``'s key does not depend on ``num``."""
    pieces = [
        np.asarray(jax.random.key_data(jax.random.split(jax.random.fold_in(key, c), _JAX_CHUNK)))[: stop - start]
        for c, (start, stop) in enumerate(_chunks(num, _JAX_CHUNK))
    ]
    return np.concatenate(pieces)


def _kernel_log_density(thetas: np.ndarray, centres: np.ndarray, log_w: np.ndarray, chol: np.ndarray) -> np.ndarray:
    """``log sum_j w_j N(theta_i | centre_j, L L^T)`` with normalised ``w``, shape (m,)."""
    d = thetas.shape[1]
    origin = centres.mean(axis=0)  # whitening about a common origin keeps |a - b|^2 accurate
    a = solve_triangular(chol, (thetas - origin).T, lower=True).T
    b = solve_triangular(chol, (centres - origin).T, lower=True).T
    b2 = np.sum(b**2, axis=1)
    log_norm = np.sum(np.log(np.diag(chol))) + 0.5 * d * math.log(2.0 * math.pi)
    out = np.empty(thetas.shape[0])
    for start in range(0, thetas.shape[0], _CHUNK):
        rows = a[start : start + _CHUNK]
        sq = np.maximum(np.sum(rows**2, axis=1)[:, None] + b2[None, :] - 2.0 * rows @ b.T, 0.0)
        out[start : start + _CHUNK] = logsumexp(-0.5 * sq + log_w[None, :], axis=1)
    return out - log_norm


def propose(
    key: jax.Array,
    prior: Any,
    population: Population | None,
    num: int,
    covariance_factor: float,
    defensive_fraction: float,
) -> tuple[np.ndarray, np.ndarray]:
    """``num`` proposals and their log importance weights ``log prior - log proposal``.

    With no population (the first generation) the proposal is the prior and every weight is
    one.  Otherwise the first ``ceil(defensive_fraction num)`` slots are prior draws and the
    rest perturbations of resampled particles by a Gaussian of ``covariance_factor`` times
    their weighted covariance; the weights use the mixture of the two with exactly these
    fractions (deterministic-mixture weights), so ``sum(weights * accepted) / num`` is an
    unbiased estimate of the model's ABC evidence.  Perturbations are not truncated to the
    prior's box: one that leaves it gets weight zero and needs no simulation, which keeps the
    proposal density exact (no truncation constants to estimate).

    Returns
    -------
    thetas : numpy.ndarray, shape (num, d)
        In the prior's dtype.
    log_weights : numpy.ndarray, shape (num,)
        ``-inf`` outside the prior's support.
    """
    dtype = np.asarray(prior.low).dtype
    k_prior, k_kernel = jax.random.split(key)
    if population is None:
        return prior_sample(prior, k_prior, num).astype(dtype), np.zeros(num)
    num_prior = min(num, math.ceil(defensive_fraction * num))
    num_kernel = num - num_prior
    centres = population.particles
    log_w = population.log_weights - logsumexp(population.log_weights)
    w = np.exp(log_w)
    low, high = np.asarray(prior.low, np.float64), np.asarray(prior.high, np.float64)
    # numpy's reliability-weighted covariance, as kernels.weighted_covariance; a single
    # effective particle has none, and the jitter keeps the Cholesky factor defined.
    cov = np.cov(centres, aweights=w, rowvar=False) if np.sum(w > 0) > 1 else np.zeros((len(low),) * 2)
    cov = covariance_factor * np.atleast_2d(np.nan_to_num(cov))
    cov = 0.5 * (cov + cov.T) + np.diag(1e-10 * (high - low) ** 2)
    chol = np.linalg.cholesky(cov)
    # The run's key fixes this generator: every draw still comes from the one seed.
    rng = np.random.default_rng(np.asarray(jax.random.key_data(k_kernel), np.uint32))
    parents = np.minimum(np.searchsorted(np.cumsum(w), rng.random(num_kernel) * w.sum(), side="right"), len(w) - 1)
    kernel_draws = centres[parents] + rng.standard_normal((num_kernel, centres.shape[1])) @ chol.T
    thetas = np.concatenate([prior_sample(prior, k_prior, num_prior), kernel_draws]).astype(dtype)
    x = thetas.astype(np.float64)
    log_prior = prior_log_prob(prior, thetas)
    inside = np.isfinite(log_prior)
    log_kernel = np.full(num, -np.inf)
    if inside.any():
        log_kernel[inside] = _kernel_log_density(x[inside], centres, log_w, chol)
    eta = num_prior / num
    with np.errstate(divide="ignore", invalid="ignore"):
        log_proposal = np.logaddexp(math.log(eta) + log_prior, math.log1p(-eta) + log_kernel)
        log_weights = np.where(inside, log_prior - log_proposal, -np.inf)
    return thetas, log_weights


def evidence_estimate(log_weights: np.ndarray, accepted: np.ndarray) -> tuple[float, float]:
    """``(log Z, relative standard error)`` of ``Z = mean(weights * accepted)`` over all slots.

    The relative standard error is ``sd / (sqrt(M) mean)`` of the ``M`` terms; ``(-inf, inf)``
    when nothing was accepted.
    """
    m = log_weights.shape[0]
    if m == 0 or not np.any(accepted):
        return -math.inf, math.inf
    shift = float(np.max(log_weights[accepted]))
    y = np.zeros(m)
    y[accepted] = np.exp(log_weights[accepted] - shift)
    mean = float(y.mean())
    sd = float(y.std(ddof=1)) if m > 1 else 0.0
    return shift + math.log(mean), sd / (math.sqrt(m) * mean)


def weighted_quantile(x: np.ndarray, log_weights: np.ndarray, q: float) -> float:
    """The smallest ``x_i`` whose weighted CDF reaches ``q`` (as :func:`jaxabc.kernels.weighted_quantile`)."""
    order = np.argsort(x, kind="stable")
    w = np.exp(log_weights[order] - np.max(log_weights))
    cdf = np.cumsum(w)
    idx = int(np.searchsorted(cdf, q * cdf[-1] * (1.0 - 1e-12), side="left"))
    return float(x[order][min(idx, x.size - 1)])


def next_threshold(
    populations: Sequence[Population | None],
    probabilities: np.ndarray,
    current: float,
    quantile: float,
    floor: float | None,
) -> float | None:
    """The next shared tolerance, or None when no particle of any model is below ``current``.

    The weighted ``quantile`` of the distances under the joint ABC posterior over (model,
    parameters): each living model's normalised weights scaled by its probability, as the
    joint population of Toni et al. (2009) would hold them.  Where ties of a discrete distance
    keep that at ``current``, the largest distance below ``current`` is taken instead.  The
    result is never below ``floor``.

    Parameters
    ----------
    populations : sequence of Population or None, length K
        None for a model that has died out.
    probabilities : numpy.ndarray, shape (K,)
        The models' current probabilities.
    current : float
    quantile : float
    floor : float or None
    """
    distances, log_weights = [], []
    for pop, prob in zip(populations, probabilities, strict=True):
        if pop is None or not prob > 0:
            continue
        distances.append(pop.distances)
        log_weights.append(pop.log_weights - logsumexp(pop.log_weights) + math.log(prob))
    if not distances:
        return None
    d, log_w = np.concatenate(distances), np.concatenate(log_weights)
    eps = weighted_quantile(d, log_w, quantile)
    if eps >= current:
        below = d[d < current]
        if below.size == 0:
            return None
        eps = float(below.max())
    return eps if floor is None else max(eps, floor)


def fraction_within(pop: Population, eps: float) -> float:
    """Weighted fraction of ``pop`` with distance at most ``eps``."""
    w = np.exp(pop.log_weights - pop.log_weights.max())
    return float(np.sum(w * (pop.distances <= eps)) / np.sum(w))


# ----------------------------------------------------------------------------- one model's run

#: The ``algorithm`` recorded in each model's :class:`~jaxabc.results.ABCResult`.
ALGORITHM_NAME = "abcsmc_model_choice"

_MIN_FOR_FAILURE_CHECK = 20
# The number of proposals of a generation is num_particles / (predicted acceptance), with the
# prediction floored here: at most 50 N proposals per model and generation.
_MIN_PREDICTED_ACCEPTANCE = 0.02
# Before a model has a generation of its own to learn from, assume the Gaussian kernel keeps
# half of the proposals that land where the population is within the new tolerance.
_INITIAL_KERNEL_EFFICIENCY = 0.5


class Settings(NamedTuple):
    """The run's configuration (stored in each model's result)."""

    num_particles: int
    quantile: float
    covariance_factor: float
    defensive_fraction: float
    max_failure_fraction: float
    num_steps: int | None
    final_threshold: float | None
    max_simulations: int | None
    max_wall_time: float | None


@dataclass
class Context:
    """What stays fixed during a run."""

    settings: Settings
    executor: Executor
    distances_of: Callable
    observed: np.ndarray
    distance: Any
    root: jax.Array
    seed: int
    t_start: float


@dataclass
class ModelTrack:
    """One model's population and history during a run."""

    name: str
    simulate: Callable
    prior: Any
    recorder: Recorder
    population: Population | None = None
    population_threshold: float = math.inf
    died_at: int | None = None  # the generation in which no simulation was accepted
    # Realised acceptance over the predicted fraction within the tolerance (the kernel's spread).
    efficiency: float = _INITIAL_KERNEL_EFFICIENCY
    predicted_fraction: float = 1.0
    num_simulations: int = 0
    history: dict[str, list] = field(default_factory=lambda: {k: [] for k in HISTORY_KEYS})

    @property
    def alive(self) -> bool:
        return self.died_at is None

    def num_proposals(self, eps: float, num_particles: int) -> int:
        """Proposals for the next generation, from past generations only (keeps Z unbiased)."""
        if not self.alive or self.population is None:
            return 0
        self.predicted_fraction = fraction_within(self.population, eps)
        predicted = max(_MIN_PREDICTED_ACCEPTANCE, min(1.0, self.predicted_fraction * self.efficiency))
        return math.ceil(num_particles / predicted)

    def generation(self, ctx: Context, index: int, key: jax.Array, eps: float, num: int) -> None:
        """Propose ``num``, simulate, accept within ``eps``; a dead model records an empty step."""
        h = self.history
        if not self.alive:
            for name, value in zip(HISTORY_KEYS, (eps, 0, 0, 0.0, 0.0, -math.inf, math.inf), strict=True):
                h[name].append(value)
            return
        k_prop, k_sim = jax.random.split(key)
        s = ctx.settings
        thetas, log_w = propose(k_prop, self.prior, self.population, num, s.covariance_factor, s.defensive_fraction)
        active = np.isfinite(log_w)
        sims_before = self.num_simulations
        d = self._simulate(ctx, index, k_sim, thetas, active)
        accepted = active & np.isfinite(d) & (d <= eps)
        log_z, rel = evidence_estimate(log_w, accepted)
        pop = Population(thetas[accepted].astype(np.float64), log_w[accepted], d[accepted])
        w = np.exp(pop.log_weights - pop.log_weights.max()) if accepted.any() else np.zeros(0)
        ess = float(w.sum() ** 2 / np.sum(w**2)) if accepted.any() else 0.0
        values = (eps, self.num_simulations - sims_before, num, float(accepted.mean()), ess, log_z, rel)
        for name, value in zip(HISTORY_KEYS, values, strict=True):
            h[name].append(value)
        if not accepted.any():
            self.died_at = index
            return
        if self.population is not None and self.predicted_fraction > 0:
            realised = float(accepted.mean()) / self.predicted_fraction
            self.efficiency = float(np.clip(realised, _MIN_PREDICTED_ACCEPTANCE, 1.0))
        self.population, self.population_threshold = pop, eps

    def _simulate(self, ctx: Context, index: int, key: jax.Array, thetas: np.ndarray, active: np.ndarray) -> np.ndarray:
        """Distances (M,) of the proposals, ``+inf`` where inactive or failed; records the batch."""
        m = thetas.shape[0]
        out = np.full(m, np.inf)
        if not active.any():
            return out
        keys = simulation_keys(key, m)
        batch = ctx.executor.map(self.simulate, keys[active], thetas[active])
        ok = np.asarray(batch.status) == STATUS_OK
        if ok.any() and not shapes_compatible(batch.summaries.shape[1:], ctx.observed.shape, ctx.distance):
            raise ValueError(
                f"model {self.name!r} returned summaries of shape {batch.summaries.shape[1:]} but the "
                f"observed data has shape {ctx.observed.shape}: every model's summaries must match the data"
            )
        dist, bad = ctx.distances_of(batch.summaries, ok)
        status, reasons = mark_bad_distances(batch.status, batch.reasons, bad, dist)
        out[active] = dist
        self.recorder.add(index, thetas[active], batch, dist, status, reasons)
        self.num_simulations += int(active.sum())
        self._check_failures(ctx.settings.max_failure_fraction)
        return out

    def _check_failures(self, max_failure_fraction: float) -> None:
        total, failed, examples = self.recorder.failures()
        name = self.name
        if total and failed == total:
            raise TooManyFailures(
                f"model {name!r}: all {total} simulations failed, so it cannot be compared; first "
                "failures:\n  " + "\n  ".join(examples)
            )
        if total >= _MIN_FOR_FAILURE_CHECK and failed > max_failure_fraction * total:
            raise TooManyFailures(
                f"model {name!r}: {failed} of {total} simulations failed (limit {max_failure_fraction:.0%}); "
                "first failures:\n  " + "\n  ".join(examples)
            )

    def result(self, ctx: Context, final: int, dtype: str, wall_time: float, stop_reason: str) -> ABCResult:
        """The model's posterior at generation ``final`` (or its last one with accepted particles)."""
        h = self.history
        pop = self.population
        assert pop is not None, "the first generation (a prior sample at tolerance inf) always accepts"
        w = np.exp(pop.log_weights - pop.log_weights.max())
        if self.died_at is not None and self.died_at <= final:
            stop_reason += (
                f"; no simulation of this model met the tolerance {h['threshold'][self.died_at]:.4g}: "
                f"the posterior is that of tolerance {self.population_threshold:.4g}"
            )
        log_z = h["log_evidence"][final]
        distance = ctx.distance
        return ABCResult(
            particles=pop.particles,
            weights=w / w.sum(),
            distances=pop.distances,
            thresholds=np.asarray(h["threshold"][: final + 1], np.float64),
            simulations_per_step=np.asarray(h["sims"][: final + 1]),
            acceptance_rates=np.asarray(h["acceptance"][: final + 1], np.float64),
            ess=np.asarray(h["ess"][: final + 1], np.float64),
            num_simulations=self.num_simulations,
            algorithm=ALGORITHM_NAME,
            settings={**ctx.settings._asdict(), "model": self.name},
            prior=self.prior,
            seed=ctx.seed,
            stop_reason=stop_reason,
            wall_time=wall_time,
            log_evidence=float(log_z) if math.isfinite(log_z) else None,
            records=self.recorder.arrays(),
            metadata={
                "versions": versions(),
                "executor": ctx.executor.name,
                "distance": distance if isinstance(distance, str) else getattr(distance, "__name__", "custom"),
                "dtype": dtype,
                "observed": ctx.observed.tolist() if ctx.observed.size <= 10_000 else None,
                "model": self.name,
                "evidence_relative_error": float(h["relative_error"][final]),
                "proposals_per_step": list(h["proposals"][: final + 1]),
            },
        )


HISTORY_KEYS = ("threshold", "sims", "proposals", "acceptance", "ess", "log_evidence", "relative_error")
