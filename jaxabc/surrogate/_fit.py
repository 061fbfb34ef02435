"""The synthetic-likelihood model from a run's simulations: one fit for the design loop
(:mod:`.algorithm`) and for the evidence (:mod:`.evidence`), with the noise correlation it
carries."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc.surrogate import emulator, sampling
from jaxabc.surrogate._settings import SurrogateSettings

__all__ = [
    "HETEROSCEDASTIC_LEVEL",
    "NOISE_MODELS",
    "ROLE_DESIGN",
    "ROLE_EMPTY",
    "ROLE_FAILED_HOLDOUT",
    "ROLE_HOLDOUT",
    "fit_likelihood",
    "fit_surrogate",
    "measured_data_terms",
    "noise_correlation",
    "noise_profile_choice",
    "padded_rows",
]

#: Roles of a state's rows: unused, design, held out, held out in a failed validation (then design).
ROLE_EMPTY, ROLE_DESIGN, ROLE_HOLDOUT, ROLE_FAILED_HOLDOUT = -1, 0, 1, 2


def fit_likelihood(
    state,
    low: np.ndarray,
    high: np.ndarray,
    observed: np.ndarray,
    max_outputs: int,
    max_simulations: int,
    log_min_feasibility: jax.Array,
    drop: np.ndarray | None = None,
    *,
    observation_error: np.ndarray | None = None,
    discrepancy: Any = None,
    noise_model: str = "homoscedastic",
    warm_start: np.ndarray | None = None,
    variance_scale: float = 1.0,
) -> tuple[emulator.OutputTransform, emulator.Emulator, sampling.LikelihoodModel, np.ndarray]:
    """Emulator on the successful design rows of ``state`` (a SurrogateState); ``drop`` (bool,
    shape (M,)) leaves rows out.  Returns (transform, emulator, likelihood model, z_all), z_all
    every row's summaries in emulated-output coordinates.

    ``observation_error`` (k, k), the measurement covariance in summary units, and
    ``discrepancy`` (a :class:`jaxabc.noise.ResolvedDiscrepancy`) are mapped into the emulated
    outputs' coordinates (:func:`.sampling.output_map`) and carried by the model.
    ``noise_model`` is :func:`noise_profile_choice`'s.  ``warm_start`` (q, d + 2), an earlier
    fit's hyper-parameters, is the optimiser's first start besides the fixed ones
    (:func:`.emulator.fit`'s ``init``): the best optimum is kept, so a fit of the same rows
    warm-started from its own result is that result again.
    ``variance_scale`` multiplies the GP's predictive variance (``Emulator.var_scale``; 1 leaves
    the emulator as fitted).

    Raises
    ------
    RuntimeError
        Fewer than 3 successful design runs.
    """
    thetas = np.asarray(state.thetas, np.float64)
    summaries = np.asarray(state.summaries, np.float64)
    role, ok = np.asarray(state.role), np.asarray(state.ok, bool)
    used = role != ROLE_EMPTY
    if drop is not None:
        used = used & ~drop
    rows = used & ok & (role != ROLE_HOLDOUT)
    if rows.sum() < 3:
        raise RuntimeError(
            f"surrogate: only {int(rows.sum())} of {int(used.sum())} simulations succeeded; "
            "the emulator needs at least 3. Check the simulator or narrow the prior"
        )
    transform = emulator.fit_transform(summaries[rows], max_outputs)
    z_all = np.asarray(transform.apply(jnp.asarray(np.nan_to_num(summaries))))
    x_all = (thetas - low) / (high - low)
    # The GP sees the fitted rows only, padded to a few sizes: its cost grows with the square
    # of its rows, so padding to the whole budget made a run's cost follow the budget, not
    # the simulations made.
    n = int(rows.sum())
    size = padded_rows(n, len(rows))
    x_fit, z_fit = np.full((size, x_all.shape[1]), 0.5), np.zeros((size, z_all.shape[1]))
    x_fit[:n], z_fit[:n] = x_all[rows], z_all[rows]
    fit_rows = np.arange(size) < n
    emu = emulator.fit(x_fit, z_fit, fit_rows, init=warm_start)
    loo = np.asarray(emulator.loo_residuals(emu))[:n]
    # An output constant over the design (a summary the data set does not measure, zeroed by
    # the simulator) carries no information about theta: out of the likelihood.
    active = np.std(z_all[rows], axis=0) > 1e-9
    coef = noise_profile_choice(noise_model, x_all[rows], loo, active)
    if coef is not None:
        # Started from the homoscedastic optimum: the profile only reshapes the noise.
        emu = emulator.fit(x_fit, z_fit, fit_rows, starts=(), noise_coef=coef, init=np.asarray(_hyper(emu)))
        loo = np.asarray(emulator.loo_residuals(emu))[:n]
        # Correlation of the residuals in noise-sd units: their scale varies with theta.
        loo = loo / np.asarray(emulator.noise_sd(emu, jnp.asarray(x_all[rows])))
    corr = noise_correlation(loo, active)
    if float(variance_scale) != 1.0:
        emu = emu._replace(var_scale=jnp.asarray(float(variance_scale)))
    feas = sampling.fit_feasibility(x_all[used], ok[used], size=padded_rows(int(used.sum()), int(max_simulations)))
    z_obs = transform.apply(jnp.asarray(np.asarray(observed, np.float64).reshape(-1)))
    extra = measured_data_terms(transform, observation_error, discrepancy)
    model = sampling.LikelihoodModel(
        emu, z_obs, jnp.linalg.cholesky(jnp.asarray(corr)), feas, jnp.asarray(active), log_min_feasibility, *extra
    )
    return transform, emu, model, z_all


#: The least number of rows the emulator and the feasibility model are padded to; above it,
#: the next power of two up to :data:`PADDED_ROWS_STEP_FROM`, then the next multiple of
#: :data:`PADDED_ROWS_STEP` (at most the budget): a handful of compilations per run.
MIN_PADDED_ROWS = 64
#: Above this many rows a doubling would cost up to 8x in the cubic fit; steps of
#: :data:`PADDED_ROWS_STEP` cost a compilation each instead.
PADDED_ROWS_STEP_FROM = 256
PADDED_ROWS_STEP = 64


def padded_rows(n: int, cap: int) -> int:
    """Rows to pad ``n`` fitted rows to (see :data:`MIN_PADDED_ROWS`), at most ``cap`` (the
    budget) and at least ``n``."""
    size = MIN_PADDED_ROWS
    while size < n and size < PADDED_ROWS_STEP_FROM:
        size *= 2
    if size < n:
        size = -(-n // PADDED_ROWS_STEP) * PADDED_ROWS_STEP
    return max(n, min(size, cap))


def measured_data_terms(
    transform: emulator.OutputTransform, observation_error: np.ndarray | None, discrepancy: Any
) -> tuple[jax.Array | None, jax.Array | None, jax.Array | None]:
    """``(observation_cov (q, q), discrepancy_basis (G, q, q), discrepancy_max_sd (G,))`` of
    :class:`.sampling.LikelihoodModel` (None where not given): ``T M T^T`` and ``T diag(m_g) T^T``."""
    t = sampling.output_map(transform)
    obs_cov = basis = max_sd = None
    if observation_error is not None:
        m = np.asarray(observation_error, np.float64)
        c = t @ m @ t.T
        obs_cov = jnp.asarray(0.5 * (c + c.T))
    if discrepancy is not None:
        member = np.asarray(discrepancy.membership, np.float64)
        basis = jnp.asarray(np.einsum("qk,gk,pk->gqp", t, member, t))
        max_sd = jnp.asarray(np.asarray(discrepancy.max_sd, np.float64))
    return obs_cov, basis, max_sd


def _hyper(emu: emulator.Emulator) -> jax.Array:
    """An emulator's hyper-parameters ``(q, d + 2)``: log amplitude, log length scales, log noise."""
    return jnp.column_stack([emu.log_amp, emu.log_ls, emu.log_noise])


def fit_surrogate(
    settings: SurrogateSettings, state: Any
) -> tuple[emulator.OutputTransform, emulator.Emulator, sampling.LikelihoodModel, np.ndarray]:
    """:func:`fit_likelihood` of a running surrogate's state (a SurrogateState) under its
    ``settings``: ``(transform, emulator, likelihood model, z_all)``, warm-started from the
    state's last fit (``state.hyper``) where it has one.

    The one fit rule of a run: the design loop's fit, whose posterior the draws come from, and
    the validation's and the report's fits of the same rows are the same fit (the best of the
    last fit and the fixed starts), so the checks judge the emulator the draws used.
    """
    hyper = np.asarray(state.hyper)
    return fit_likelihood(
        state,
        settings.box.low,
        settings.box.high,
        settings.observed,
        settings.max_outputs,
        settings.max_simulations,
        settings.log_min_feasibility,
        observation_error=settings.observation_error,
        discrepancy=settings.discrepancy,
        noise_model=settings.noise_model,
        warm_start=hyper if np.any(hyper) else None,
        variance_scale=float(state.variance_scale),
    )


#: Level of the F-test (Bonferroni over the outputs) at which ``noise_model="auto"`` takes the
#: noise to vary with theta.
HETEROSCEDASTIC_LEVEL = 1e-3
#: ``noise_model`` values.
NOISE_MODELS = ("auto", "homoscedastic", "heteroscedastic")


def noise_profile_choice(noise_model: str, x: np.ndarray, loo: np.ndarray, active: np.ndarray) -> np.ndarray | None:
    """The noise profile to refit with (:func:`.emulator.fit_noise_profile` of the leave-one-
    out residuals ``loo (n, q)`` at unit-box ``x (n, d)``), or None for homoscedastic noise.

    ``"homoscedastic"``: None.  ``"heteroscedastic"``: every active output's profile.
    ``"auto"``: the profiles of the active outputs whose F-test rejects a constant noise
    variance at :data:`HETEROSCEDASTIC_LEVEL` over the number of active outputs (None if none).
    """
    if noise_model == "homoscedastic":
        return None
    coef, p_values = emulator.fit_noise_profile(x, loo)
    keep = np.asarray(active, bool) & np.isfinite(p_values)
    if noise_model == "auto":
        keep &= p_values < HETEROSCEDASTIC_LEVEL / max(int(np.sum(active)), 1)
    if not keep.any():
        return None
    return np.where(keep[:, None], coef, 0.0)


def noise_correlation(residuals: np.ndarray, active: np.ndarray | None = None) -> np.ndarray:
    """Correlation ``(q, q)`` of leave-one-out residuals ``(n, q)``, Ledoit-Wolf shrunk.

    Summaries of one trajectory (RDF features) are strongly correlated, so the synthetic
    likelihood needs their joint noise.  A sample correlation of ~100 residuals in ~10 outputs
    has spuriously small eigenvalues, along which the likelihood becomes far too sharp
    (held-out Mahalanobis distances several times their chi-square mean).  Shrinkage towards
    the identity with the Ledoit-Wolf intensity (scikit-learn) keeps it well conditioned.  Only
    the ``active`` outputs (default all) are correlated; the others, and outputs whose
    residuals do not vary, get identity rows.  The identity when fewer than two outputs or
    five residuals are left.
    """
    n, q = residuals.shape
    out = np.eye(q)
    keep = np.ones(q, bool) if active is None else np.asarray(active, bool)
    sd = residuals.std(axis=0)
    # An output whose residuals do not vary (a constant summary) has no correlation to estimate.
    keep = keep & np.isfinite(sd) & (sd > 0)
    if keep.sum() < 2 or n < 5:
        return out
    from sklearn.covariance import ledoit_wolf

    cov, _ = ledoit_wolf(residuals[:, keep] / sd[keep])
    s = np.sqrt(np.diag(cov))
    out[np.ix_(keep, keep)] = cov / np.outer(s, s)
    return out
