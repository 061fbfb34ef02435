"""Posterior predictive distributions: simulations at posterior draws and replicate seeds.

Two samples answer two questions.  *Posterior draws* ``theta_m ~ p(theta | data)``, each with its
own seed, give the posterior predictive distribution of every summary (parameter uncertainty plus
simulation noise): its bands are what the report shows.  *Replicates* at the Bayes estimate, one
theta and many seeds, give the simulation noise alone: its covariance is the yardstick of every
test, and the same seeds are reused for the finite-difference sensitivities (common random
numbers) so that noise cancels in the differences.

Summary *groups* (regions) are named index sets of the summary vector, e.g.
``{"g(r) first peak": range(10, 16), "pressure": [26]}``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import jax
import numpy as np

from jaxabc.executors import Executor, get_executor

__all__ = [
    "PosteriorPredictive",
    "normalise_groups",
    "normalise_mask",
    "posterior_predictive",
    "shrunk_covariance",
    "simulate_many",
    "with_replicates",
]

IndexSpec = slice | Sequence[int] | np.ndarray | range | str


def normalise_groups(groups: Mapping[str, IndexSpec] | None, num_summaries: int) -> dict[str, np.ndarray]:
    """Turn ``{name: slice | indices}`` into ``{name: sorted int array}``, validated.

    Parameters
    ----------
    groups : mapping of str to slice or sequence of int, optional
    num_summaries : int
        Length ``s`` of the summary vector.
    """
    out: dict[str, np.ndarray] = {}
    for name, spec in (groups or {}).items():
        if isinstance(spec, slice):
            idx = np.arange(num_summaries)[spec]
        else:
            idx = np.unique(np.asarray(list(spec) if isinstance(spec, range) else spec, dtype=int))
        if idx.size == 0:
            raise ValueError(f"summary group {name!r} is empty")
        if idx.min() < 0 or idx.max() >= num_summaries:
            raise ValueError(
                f"summary group {name!r} has indices outside 0..{num_summaries - 1}: fix the group "
                "or check that the simulator returns the summaries you think it does"
            )
        out[str(name)] = idx
    return out


def normalise_mask(spec: Any, num_summaries: int, groups: Mapping[str, np.ndarray]) -> np.ndarray:
    """A boolean mask of shape (s,) from indices, a slice, a boolean mask or group names."""
    mask = np.zeros(num_summaries, bool)
    if spec is None:
        return mask
    if isinstance(spec, slice):
        mask[spec] = True
        return mask
    if isinstance(spec, str):
        spec = [spec]
    arr = np.asarray(spec)
    if arr.dtype == bool:
        if arr.shape != (num_summaries,):
            raise ValueError(f"a boolean held_out mask must have shape ({num_summaries},), got {arr.shape}")
        return arr.copy()
    for item in list(spec):
        if isinstance(item, str):
            if item not in groups:
                raise ValueError(f"unknown summary group {item!r}: groups are {sorted(groups)}")
            mask[groups[item]] = True
        else:
            i = int(item)
            if not 0 <= i < num_summaries:
                raise ValueError(f"held-out index {i} is outside 0..{num_summaries - 1}")
            mask[i] = True
    return mask


def simulate_many(simulate: Callable, keys: jax.Array, thetas: np.ndarray, executor: Executor) -> np.ndarray:
    """Run ``simulate`` at each (key, theta) on ``executor``; failures come back as NaN rows.

    Parameters
    ----------
    keys : jax.Array, shape (n,) typed PRNG keys
    thetas : numpy.ndarray, shape (n, d)

    Returns
    -------
    numpy.ndarray, shape (n, s)
    """
    raw = np.asarray(jax.random.key_data(keys))
    batch = executor.map(simulate, raw, np.asarray(thetas, np.float32))
    out = np.asarray(batch.summaries, np.float64).reshape(thetas.shape[0], -1)
    out[np.asarray(batch.status) != 0] = np.nan
    return out


def shrunk_covariance(x: np.ndarray) -> np.ndarray:
    """Ledoit-Wolf covariance of rows of ``x`` (n, p), shrinking the correlation towards identity.

    With a few hundred replicates and tens of summaries the sample covariance is noisy and
    near-singular; every test here inverts it, so it is shrunk (the amount is estimated from the
    data, Ledoit & Wolf 2004) towards its own diagonal.
    """
    n, p = x.shape
    xc = x - x.mean(axis=0)
    sd = np.sqrt(np.mean(xc**2, axis=0))
    sd_safe = np.where(sd > 0, sd, 1.0)
    z = xc / sd_safe
    s = z.T @ z / n
    target = np.eye(p)
    delta = np.sum((s - target) ** 2)
    beta = np.sum([np.sum((np.outer(r, r) - s) ** 2) for r in z]) / n**2
    lam = 1.0 if delta <= 0 else float(np.clip(beta / delta, 0.0, 1.0))
    corr = lam * target + (1.0 - lam) * s
    cov = corr * np.outer(sd, sd) * n / max(n - 1, 1)
    return cov


@dataclass
class PosteriorPredictive:
    """Simulations at posterior draws and at replicate seeds of the Bayes estimate.

    Attributes
    ----------
    theta_hat : numpy.ndarray, shape (d_full,)
        Bayes estimate of the base parameters, effect parameters at their nulls.
    draws_theta : numpy.ndarray, shape (m, d_full)
    draws : numpy.ndarray, shape (m, s)
        Posterior predictive sample (failed simulations removed).
    replicates : numpy.ndarray, shape (r, s)
        Replicate seeds at ``theta_hat`` (failed ones removed).
    replicate_keys : jax.Array, shape (r,)
        Their keys, reused for common random numbers.
    noise_cov : numpy.ndarray, shape (s, s)
        Shrunk covariance of the replicates (the simulation noise).
    active : numpy.ndarray of bool, shape (s,)
        Summaries with non-zero noise (a summary that never varies, such as g(r) inside the
        core, cannot be standardised and is not tested).
    groups : dict of str to int array
    names : list of str, length s
    """

    theta_hat: np.ndarray
    draws_theta: np.ndarray
    draws: np.ndarray
    replicates: np.ndarray
    replicate_keys: jax.Array
    noise_cov: np.ndarray
    active: np.ndarray
    groups: dict[str, np.ndarray]
    names: list[str]
    failures: int = 0
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def replicate_mean(self) -> np.ndarray:
        """Mean of the replicates, shape (s,): the expected summaries at the estimate."""
        return self.replicates.mean(axis=0)

    @property
    def noise_sd(self) -> np.ndarray:
        """Simulation-noise standard deviation per summary, shape (s,)."""
        return np.sqrt(np.diag(self.noise_cov))

    def mean(self) -> np.ndarray:
        """Posterior predictive mean, shape (s,)."""
        return self.draws.mean(axis=0)

    def band(self, level: float = 0.9, values: np.ndarray | None = None) -> np.ndarray:
        """Equal-tailed predictive band of each column of ``values`` (default: the draws), (k, 2)."""
        v = self.draws if values is None else values
        q = (1.0 - level) / 2.0
        return np.stack([np.quantile(v, q, axis=0), np.quantile(v, 1.0 - q, axis=0)], axis=-1)


def _noise_model(replicates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shrunk noise covariance of the replicates and the mask of summaries that vary."""
    cov = shrunk_covariance(replicates)
    scale = np.maximum(np.abs(replicates).max(axis=0), 1e-300)
    return cov, np.sqrt(np.diag(cov)) > 1e-9 * scale


def with_replicates(predictive: PosteriorPredictive, keys: jax.Array, replicates: np.ndarray) -> PosteriorPredictive:
    """``predictive`` with its replicates at the estimate replaced by ``replicates`` (keys ``keys``).

    The noise covariance and the active mask are recomputed as :func:`posterior_predictive` does;
    the posterior draws are kept.  Used by the power estimate: a fresh noise yardstick per
    replicate data set, as a fresh run of the criticism would have.
    """
    ok = np.all(np.isfinite(replicates), axis=1)
    if ok.sum() < 10:
        raise RuntimeError(f"only {ok.sum()} of {len(ok)} replicates simulated successfully")
    cov, active = _noise_model(replicates[ok])
    return replace(
        predictive,
        replicates=replicates[ok],
        replicate_keys=keys[np.flatnonzero(ok)],
        noise_cov=cov,
        active=active,
        extra=dict(predictive.extra),
    )


def posterior_predictive(
    simulate: Callable,
    theta_draws: np.ndarray,
    theta_hat: np.ndarray,
    key: jax.Array,
    num_replicates: int,
    *,
    executor: Executor | str | None = None,
    names: Sequence[str] | None = None,
    groups: Mapping[str, IndexSpec] | None = None,
) -> PosteriorPredictive:
    """Simulate at posterior draws and at ``num_replicates`` seeds of ``theta_hat``.

    Parameters
    ----------
    simulate : callable ``(key, theta_full) -> summaries (s,)``
    theta_draws : numpy.ndarray, shape (m, d_full)
    theta_hat : numpy.ndarray, shape (d_full,)
    key : jax.Array
    num_replicates : int
    executor : Executor or str, optional
        Default: in-process ``vmap``.
    names : sequence of str, optional
        Summary names (default ``s0, s1, ...``).
    groups : mapping, optional
        Named regions of the summary vector.
    """
    ex = get_executor(executor)  # an executor object comes back as is
    k_draw, k_rep = jax.random.split(key)
    m = theta_draws.shape[0]
    draws = simulate_many(simulate, jax.random.split(k_draw, m), theta_draws, ex)
    rep_keys = jax.random.split(k_rep, num_replicates)
    reps = simulate_many(simulate, rep_keys, np.repeat(theta_hat[None], num_replicates, 0), ex)
    ok_d = np.all(np.isfinite(draws), axis=1)
    ok_r = np.all(np.isfinite(reps), axis=1)
    if ok_r.sum() < 10 or ok_d.sum() < 10:
        raise RuntimeError(
            f"only {ok_r.sum()} of {num_replicates} replicates and {ok_d.sum()} of {m} posterior "
            "draws simulated successfully: the posterior sits where the simulator fails"
        )
    s = reps.shape[1]
    names = list(names) if names is not None else [f"s{i}" for i in range(s)]
    if len(names) != s:
        raise ValueError(f"got {len(names)} summary names for {s} summaries")
    reps_ok = reps[ok_r]
    cov, active = _noise_model(reps_ok)
    return PosteriorPredictive(
        theta_hat=np.asarray(theta_hat, np.float64),
        draws_theta=theta_draws[ok_d],
        draws=draws[ok_d],
        replicates=reps_ok,
        replicate_keys=rep_keys[np.flatnonzero(ok_r)],
        noise_cov=cov,
        active=active,
        groups=normalise_groups(groups, s),
        names=names,
        failures=int((~ok_d).sum() + (~ok_r).sum()),
    )
