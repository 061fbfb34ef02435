"""Does the ABC posterior cover the truth as often as it claims?  Simulation-based calibration.

For a pure-JAX simulator, :func:`coverage_study` draws ``R`` (truth, data) pairs, runs the
algorithm on every data set at once (one ``jax.vmap`` over the fused ``init``/``step`` of
:func:`jaxabc.algorithms.make_jax_step`, with the algorithm's own stopping rule) and records
where each truth falls in its posterior: its highest-density credible level
(:meth:`jaxabc.ABCResult.credible_level`) and whether each equal-tailed interval holds it.

For an exact posterior a truth drawn with its data sits at a uniform level, so the
``q`` region holds it in a fraction ``q`` of the data sets (Talts et al. 2018).  An ABC posterior
at tolerance ``eps > 0`` is wider than the exact one and should cover *more*; covering less
means the algorithm is overconfident.  One run on real data says little (the truth of a
calibrated posterior is inside its 50 % region on half of all data sets); this is the check
behind such statements.

Usage::

    study = jaxabc.coverage_study("apmcabc", simulate, prior, num_datasets=400,
                                  num_particles=1000, seed=0, num_steps=6, alpha=0.1)
    study.hpd_coverage(0.9)        # (fraction, standard error)
    study.interval_coverage(0.95)  # per parameter
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.algorithms import BUILDERS, make_jax_step
from jaxabc.distances import get_distance
from jaxabc.priors import Uniform
from jaxabc.results import ABCResult

__all__ = ["CoverageStudy", "coverage_study"]


@dataclass
class CoverageStudy:
    """Where each truth fell in its posterior, over ``R`` simulated data sets.

    Attributes
    ----------
    truths : numpy.ndarray, shape (R, d)
    observed : numpy.ndarray, shape (R, ...)
    levels : numpy.ndarray, shape (R,)
        Highest-density credible level of each truth (below ``q``: inside the ``q`` region).
    inside_intervals : dict of float to numpy.ndarray, shape (R, d)
        For each interval level, whether the equal-tailed interval of each parameter held the truth.
    thresholds : numpy.ndarray, shape (R,)
        Final tolerance of each run.
    generations : numpy.ndarray, shape (R,)
    ess : numpy.ndarray, shape (R,)
        Kish effective sample size of each final posterior.
    posterior_size : numpy.ndarray, shape (R,)
        Particles with non-zero weight.
    settings : dict
    """

    truths: np.ndarray
    observed: np.ndarray
    levels: np.ndarray
    inside_intervals: dict[float, np.ndarray]
    thresholds: np.ndarray
    generations: np.ndarray
    ess: np.ndarray
    posterior_size: np.ndarray
    settings: dict

    def hpd_coverage(self, level: float) -> tuple[float, float]:
        """Fraction of data sets whose truth lies inside the ``level`` HPD region, and its
        binomial standard error."""
        p = float(np.mean(self.levels < level))
        return p, float(np.sqrt(max(p * (1 - p), 1e-12) / self.levels.size))

    def interval_coverage(self, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
        """Per parameter: fraction of equal-tailed ``level`` intervals holding the truth, and
        standard errors."""
        if level not in self.inside_intervals:
            raise ValueError(f"interval level {level} was not computed; have {sorted(self.inside_intervals)}")
        p = self.inside_intervals[level].mean(axis=0)
        return p, np.sqrt(np.maximum(p * (1 - p), 1e-12) / self.levels.size)

    def to_dict(self) -> dict:
        """JSON-ready summary (no per-data-set arrays)."""
        return {
            "settings": self.settings,
            "num_datasets": int(self.levels.size),
            "hpd_coverage": {str(q): self.hpd_coverage(q) for q in (0.5, 0.8, 0.9, 0.95)},
            "interval_coverage": {
                str(q): [v.tolist() for v in self.interval_coverage(q)] for q in sorted(self.inside_intervals)
            },
            "mean_level": float(self.levels.mean()),
            "median_threshold": float(np.median(self.thresholds)),
            "median_ess": float(np.median(self.ess)),
            "median_posterior_size": float(np.median(self.posterior_size)),
            "median_generations": float(np.median(self.generations)),
        }


def coverage_study(
    algorithm: str,
    simulate: Callable[[jax.Array, jax.Array], jax.Array],
    prior: Uniform,
    *,
    num_datasets: int,
    num_particles: int,
    num_steps: int,
    seed: int = 0,
    distance: str | Callable = "euclidean",
    sample_data: Callable[[jax.Array], tuple[jax.Array, jax.Array]] | None = None,
    interval_levels: tuple[float, ...] = (0.5, 0.9, 0.95),
    **options,
) -> CoverageStudy:
    """Run ``algorithm`` on ``num_datasets`` simulated data sets at once and locate each truth.

    Parameters
    ----------
    algorithm : str
        A key of :data:`jaxabc.ALGORITHMS`.
    simulate : callable ``(key, theta) -> summaries``
        A pure-JAX simulator (it is vmapped over particles and over data sets).
    prior : Uniform
    num_datasets : int
        ``R``; coverage fractions carry a binomial error ``sqrt(q (1 - q) / R)``.
    num_particles : int
    num_steps : int
        Generations per run; the algorithm's own stopping rule (e.g. APMCABC's acceptance
        cutoff) may end a run earlier, as in :func:`jaxabc.run`.
    seed : int
        The only source of randomness: data sets and runs.
    distance : str or callable
    sample_data : callable ``(key) -> (truth, observed)``, optional
        How (truth, data) pairs are drawn; by default the truth from ``prior`` and the data from
        ``simulate``.  Any rule works as long as the truth is distributed as the exact posterior
        given the data (e.g. data first, then the truth from a known posterior).
    interval_levels : tuple of float
        Equal-tailed interval levels to check.
    **options
        Passed to the algorithm's builder (``alpha``, ``acceptance_cutoff``, ...).

    Returns
    -------
    CoverageStudy
    """
    if algorithm not in BUILDERS:
        raise ValueError(f"unknown algorithm {algorithm!r}; choose one of {sorted(BUILDERS)}")
    if num_datasets < 2 or num_steps < 1:
        raise ValueError("need num_datasets >= 2 and num_steps >= 1")
    algo = BUILDERS[algorithm](prior, num_particles, **options)
    dist = get_distance(distance)

    def default_data(key: jax.Array) -> tuple[jax.Array, jax.Array]:
        k1, k2 = jax.random.split(key)
        truth = prior.sample(k1, 1)[0]
        return truth, simulate(k2, truth)

    draw = sample_data or default_data
    max_calls = 1000 * num_steps  # multi-round generations; a guard, never reached in practice

    def one(key: jax.Array):
        k_data, k_init, k_run = jax.random.split(key, 3)
        truth, observed = draw(k_data)
        init, step = make_jax_step(algo, simulate, dist, observed)
        state, info = init(k_init)

        def cond(carry):
            _, _, info, gens, calls = carry
            return (gens < num_steps) & ~info.stop & (calls < max_calls)

        def body(carry):
            key, state, _, gens, calls = carry
            key, sub = jax.random.split(key)
            state, info = step(sub, state)
            return key, state, info, gens + info.generation_done.astype(jnp.int32), calls + 1

        carry = (k_run, state, info, info.generation_done.astype(jnp.int32), jnp.int32(0))
        _, state, info, gens, calls = jax.lax.while_loop(cond, body, carry)
        particles, log_w = algo.posterior(state)
        return truth, observed, particles, log_w, info.threshold, gens, calls >= max_calls

    keys = jax.random.split(jax.random.key(seed), num_datasets)
    truths, observed, particles, log_w, thresholds, gens, stuck = jax.device_get(jax.jit(jax.vmap(one))(keys))
    if np.any(stuck):
        raise RuntimeError(
            f"{int(np.sum(stuck))} of {num_datasets} runs had not completed {num_steps} generations "
            f"after {max_calls} steps (e.g. a rejection threshold that almost nothing meets); "
            "loosen the tolerance or use a quantile"
        )

    levels = np.empty(num_datasets)
    inside = {q: np.zeros((num_datasets, prior.dim), bool) for q in interval_levels}
    ess, size = np.empty(num_datasets), np.empty(num_datasets, int)
    for r in range(num_datasets):
        lw = np.asarray(log_w[r], np.float64)
        keep = np.isfinite(lw)
        if not keep.any():
            raise RuntimeError(
                f"data set {r}: the run ended with an empty posterior after {int(gens[r])} "
                f"generations; raise num_steps or loosen the algorithm's options"
            )
        w = np.exp(lw[keep] - lw[keep].max())
        post = ABCResult.from_sample(np.asarray(particles[r])[keep], w, prior, algorithm)
        levels[r] = post.credible_level(truths[r])
        for q in interval_levels:
            ci = post.credible_interval(q)
            inside[q][r] = (ci[:, 0] <= truths[r]) & (truths[r] <= ci[:, 1])
        ess[r], size[r] = post.effective_sample_size(), keep.sum()
    settings = {
        "algorithm": algorithm,
        "num_particles": num_particles,
        "num_steps": num_steps,
        "seed": seed,
        "distance": distance if isinstance(distance, str) else getattr(distance, "__name__", "custom"),
        "data": "custom sample_data" if sample_data else "truth from the prior, data from simulate",
        **{k: v for k, v in algo.settings.items() if k not in ("num_particles",)},
    }
    return CoverageStudy(
        truths=np.asarray(truths),
        observed=np.asarray(observed),
        levels=levels,
        inside_intervals=inside,
        thresholds=np.asarray(thresholds, np.float64),
        generations=np.asarray(gens),
        ess=ess,
        posterior_size=size,
        settings=settings,
    )
