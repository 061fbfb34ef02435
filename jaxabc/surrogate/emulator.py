"""Gaussian-process emulator of a simulator's summaries (tinygp kernels, scipy L-BFGS-B fits).

One independent GP per output, on inputs scaled to the unit box ``[0, 1]^d`` and outputs
standardised (optionally rotated onto their leading principal components).  Each GP has an
amplitude, one length scale per parameter and a nugget: the nugget is the simulator's noise
standard deviation in standardised units, fitted by type-II maximum a posteriori (marginal
likelihood plus weak log-normal priors that keep length scales off the degenerate ends).

All arrays are padded with a mask to a few fixed numbers of rows (``_fit.padded_rows``), so
that the jitted fit and prediction functions compile a handful of times per run, not once per
design size.  Padded rows get a huge diagonal and carry no information.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
import tinygp

__all__ = [
    "VARIANCE_SCALE_BOUNDS",
    "Emulator",
    "OutputTransform",
    "fit",
    "fit_noise_profile",
    "fit_transform",
    "loo_residuals",
    "noise_features",
    "noise_profile",
    "noise_sd",
    "objective",
    "predict",
    "variance_scale_mle",
]

_PAD_VARIANCE = 1e8
#: Where padding rows sit: so far outside the unit box (500 of the longest length scales) that
#: their kernel with every real row is exactly 0 in float64, and the fit cannot see them.
_PAD_X = 1e4
# Bounds of the log hyper-parameters (unit-box inputs, standardised outputs): length scales from
# 1/50 to 20 box widths, amplitudes 0.02-30, noise sd 1e-4 to 3.
_LOG_LS_BOUNDS = (np.log(0.02), np.log(20.0))
_LOG_AMP_BOUNDS = (np.log(0.02), np.log(30.0))
_LOG_NOISE_BOUNDS = (np.log(1e-4), np.log(3.0))
#: The objective's value where the marginal likelihood cannot be evaluated (a failed Cholesky).
_FAILED = 1e30


class OutputTransform(NamedTuple):
    """Affine map from raw summaries (k,) to emulated outputs (q,): ``z = ((y - mean) / scale) @ rotation``.

    Attributes
    ----------
    mean, scale : array, shape (k,)
    rotation : array, shape (k, q)
        Identity when ``q == k``; the leading principal axes otherwise.
    """

    mean: jax.Array
    scale: jax.Array
    rotation: jax.Array

    def apply(self, y: jax.Array) -> jax.Array:
        return ((y - self.mean) / self.scale) @ self.rotation


class Emulator(NamedTuple):
    """A fitted emulator (a pytree of arrays).

    Attributes
    ----------
    x : array, shape (M, d)
        Design inputs in the unit box (padded rows at 0.5).
    mask : array of bool, shape (M,)
        Rows that hold a successful simulation.
    log_amp, log_noise : array, shape (q,)
    log_ls : array, shape (q, d)
    alpha : array, shape (q, M)
        ``K^-1 z`` per output.
    chol : array, shape (q, M, M)
        Cholesky factor of ``K + diag`` per output.
    noise_coef : array, shape (q, 1 + 2 d), optional
        Heteroscedastic noise: the log noise variance of output ``j`` at ``x`` is
        ``2 log_noise_j + noise_features(x) @ noise_coef_j`` (:func:`noise_sd`); None (the
        default) for noise that does not depend on ``x``.
    var_scale : array, shape (), optional
        A factor on the GP's predictive variance (:func:`predict`), from
        :func:`variance_scale_mle`; None (the default) for the GP's own variance.
    """

    x: jax.Array
    mask: jax.Array
    log_amp: jax.Array
    log_noise: jax.Array
    log_ls: jax.Array
    alpha: jax.Array
    chol: jax.Array
    noise_coef: jax.Array | None = None
    var_scale: jax.Array | None = None


def fit_transform(y: np.ndarray, max_outputs: int) -> OutputTransform:
    """Standardise summaries ``y (n, k)`` (valid rows only) and keep at most ``max_outputs`` axes."""
    mean = y.mean(axis=0)
    scale = y.std(axis=0)
    # A summary that never changes carries no information; scale 1 keeps it harmless.
    scale = np.where(scale > 1e-12 * (1.0 + np.abs(mean)), scale, 1.0)
    k = y.shape[1]
    if k <= max_outputs:
        rotation = np.eye(k)
    else:
        _, _, vt = np.linalg.svd((y - mean) / scale, full_matrices=False)
        rotation = vt[:max_outputs].T
        # Rotated outputs get unit variance too, so hyper-parameter bounds mean the same.
        spread = ((y - mean) / scale @ rotation).std(axis=0)
        rotation = rotation / np.where(spread > 0, spread, 1.0)
    return OutputTransform(jnp.asarray(mean), jnp.asarray(scale), jnp.asarray(rotation))


def _kernel(log_amp: jax.Array, log_ls: jax.Array) -> tinygp.kernels.Kernel:
    # Linear(1 / ell) divides each input by its own length scale (ARD).
    return jnp.exp(2.0 * log_amp) * tinygp.transforms.Linear(jnp.exp(-log_ls), tinygp.kernels.ExpSquared())


def _diag(log_noise: jax.Array, mask: jax.Array, profile: jax.Array) -> jax.Array:
    # The profile is zeroed on padded rows before the exp: at the far-away padding inputs its
    # quadratic overflows, and an inf in the branch ``where`` discards still makes the gradient
    # NaN, which stopped every heteroscedastic fit at its start.
    return jnp.where(mask, jnp.exp(2.0 * log_noise + jnp.where(mask, profile, 0.0)), _PAD_VARIANCE)


def noise_features(x: jax.Array) -> jax.Array:
    """Features ``(n, 1 + 2 d)`` of the log noise variance at unit-box points ``x (n, d)``:
    1, then ``x - 1/2`` and ``(x - 1/2)^2`` per parameter (a quadratic without cross terms)."""
    u = x - 0.5
    return jnp.concatenate([jnp.ones((x.shape[0], 1), x.dtype), u, u * u], axis=1)


def noise_profile(emulator: Emulator, x: jax.Array) -> jax.Array:
    """The log noise variance at ``x (n, d)`` relative to ``2 log_noise``: ``(n, q)``, zero for
    a homoscedastic emulator."""
    if emulator.noise_coef is None:
        return jnp.zeros((x.shape[0], emulator.log_noise.shape[0]), x.dtype)
    return noise_features(x) @ emulator.noise_coef.T


def noise_sd(emulator: Emulator, x: jax.Array) -> jax.Array:
    """The simulator noise sd of every output at unit-box points ``x (n, d)``: ``(n, q)``."""
    return jnp.exp(emulator.log_noise[None, :] + 0.5 * noise_profile(emulator, x))


def _neg_log_posterior(params: jax.Array, x: jax.Array, z: jax.Array, mask: jax.Array, profile: jax.Array) -> jax.Array:
    """Sum over outputs of ``-log p(z | theta) - log prior(theta)``; ``params`` is (q, d + 2),
    ``profile (M, q)`` each row's log noise variance relative to ``2 log_noise``."""
    d = x.shape[1]

    def one(p: jax.Array, zj: jax.Array, prof: jax.Array) -> jax.Array:
        log_amp, log_ls, log_noise = p[0], p[1 : 1 + d], p[1 + d]
        gp = tinygp.GaussianProcess(_kernel(log_amp, log_ls), x, diag=_diag(log_noise, mask, prof))
        # Weak priors (log-normal): length scale around half the box, amplitude around the
        # standardised output's sd.  They only matter when the data cannot decide.
        log_prior = -0.5 * jnp.sum(((log_ls - jnp.log(0.5)) / 1.5) ** 2) - 0.5 * (log_amp / 1.5) ** 2
        return -gp.log_probability(jnp.where(mask, zj, 0.0)) - log_prior

    return jnp.sum(jax.vmap(one)(params, z.T, profile.T))


_value_and_grad = jax.jit(jax.value_and_grad(_neg_log_posterior))


@jax.jit
def _factor(
    params: jax.Array, x: jax.Array, z: jax.Array, mask: jax.Array, profile: jax.Array
) -> tuple[jax.Array, jax.Array]:
    d = x.shape[1]

    def one(p: jax.Array, zj: jax.Array, prof: jax.Array):
        kern = _kernel(p[0], p[1 : 1 + d])
        cov = kern(x, x) + jnp.diag(_diag(p[1 + d], mask, prof))
        chol = jnp.linalg.cholesky(cov)
        alpha = jax.scipy.linalg.cho_solve((chol, True), jnp.where(mask, zj, 0.0))
        return alpha, chol

    return jax.vmap(one)(params, z.T, profile.T)


def _condition(
    params: jax.Array, x: jax.Array, z: jax.Array, mask: jax.Array, noise_coef: jax.Array | None = None
) -> Emulator:
    """The emulator at hyper-parameters ``params (q, d + 2)`` (log amplitude, log length
    scales, log noise) on inputs ``x (M, d)``, outputs ``z (M, q)``, rows ``mask (M,)``."""
    d = x.shape[1]
    profile = jnp.zeros((x.shape[0], z.shape[1]), x.dtype) if noise_coef is None else noise_features(x) @ noise_coef.T
    alpha, chol = _factor(params, x, z, mask, profile)
    return Emulator(x, mask, params[:, 0], params[:, 1 + d], params[:, 1 : 1 + d], alpha, chol, noise_coef)


def fit(
    x: np.ndarray,
    z: np.ndarray,
    mask: np.ndarray,
    starts: tuple[float, ...] = (0.3, 1.5),
    noise_coef: np.ndarray | None = None,
    init: np.ndarray | None = None,
) -> Emulator:
    """Fit one GP per output column of ``z`` by L-BFGS-B on the log hyper-parameters.

    Parameters
    ----------
    x : array, shape (M, d)
        Inputs in the unit box.
    z : array, shape (M, q)
        Transformed outputs; rows outside ``mask`` are ignored.
    mask : array of bool, shape (M,)
    starts : tuple of float
        Initial length scales (box widths) of the restarts; the best optimum is kept.
    noise_coef : array, shape (q, 1 + 2 d), optional
        A heteroscedastic noise profile (:func:`fit_noise_profile`), held fixed while the
        noise level ``log_noise`` and the other hyper-parameters are fitted.
    init : array, shape (q, d + 2), optional
        A warm start (log amplitude, log length scales, log noise per output; an earlier
        fit's), clipped into the bounds: tried first, besides ``starts`` (``starts=()``: the
        only start).  Ignored unless finite and of this shape.

    Returns
    -------
    Emulator
        The best optimum (least :func:`objective`) of all starts; deterministic given its
        inputs (fixed starts, no random restarts; ties go to ``init``).

    Raises
    ------
    FloatingPointError
        The marginal likelihood is not finite at any start (where only ``init`` was to be
        tried, ``(0.3, 1.5)`` are tried before giving up).
    """
    if int(np.sum(mask)) < 3:
        raise ValueError(f"an emulator needs at least 3 successful simulations, got {int(np.sum(mask))}")
    xj = jnp.asarray(np.where(mask[:, None], x, _PAD_X))
    zj = jnp.asarray(np.where(mask[:, None], z, 0.0))
    m = jnp.asarray(mask)
    q, d = z.shape[1], xj.shape[1]
    coef = None if noise_coef is None else jnp.asarray(np.asarray(noise_coef, np.float64).reshape(q, 1 + 2 * d))
    profile = jnp.zeros((x.shape[0], q), xj.dtype) if coef is None else noise_features(xj) @ coef.T
    bounds = [_LOG_AMP_BOUNDS, *([_LOG_LS_BOUNDS] * d), _LOG_NOISE_BOUNDS] * q

    def objective(flat: np.ndarray) -> tuple[float, np.ndarray]:
        v, g = _value_and_grad(jnp.asarray(flat.reshape(q, d + 2)), xj, zj, m, profile)
        v = float(v)
        g = np.asarray(g, np.float64).ravel()
        if not np.isfinite(v) or not np.all(np.isfinite(g)):
            # A failed Cholesky at extreme hyper-parameters: push the line search back.
            return _FAILED, np.zeros_like(flat)
        return v, g

    def best_of(inits: list[np.ndarray]) -> scipy.optimize.OptimizeResult:
        runs = [
            scipy.optimize.minimize(objective, p0, jac=True, method="L-BFGS-B", bounds=bounds, options={"maxiter": 300})
            for p0 in inits
        ]
        return min(runs, key=lambda r: r.fun)

    def default(ls: float) -> np.ndarray:
        return np.tile(np.concatenate([[0.0], np.full(d, np.log(ls)), [np.log(0.1)]]), q)

    inits = [default(ls) for ls in starts]
    if init is not None and np.shape(init) == (q, d + 2) and np.all(np.isfinite(init)):
        lo, hi = np.array(bounds, np.float64).T
        # The warm start alone would track one optimum as the design grows; the fixed starts
        # beside it keep every fit of the same rows at the same (best) optimum, whichever
        # earlier fit it was started from.
        inits = [np.clip(np.asarray(init, np.float64).ravel(), lo, hi), *inits]
    if not inits:
        raise ValueError("emulator.fit: no start (starts=() needs an init of shape (q, d + 2))")
    best = best_of(inits)
    if not best.fun < _FAILED and not starts:
        # The only start sits where the likelihood cannot be evaluated: start afresh.
        best = best_of([default(ls) for ls in (0.3, 1.5)])
    if not best.fun < _FAILED:
        raise FloatingPointError(
            f"GP fit failed: the marginal likelihood is not finite at any start ({len(inits)} starts, "
            f"{int(np.sum(mask))} rows, {q} outputs); the outputs may hold inf/NaN or identical rows"
        )
    return _condition(jnp.asarray(best.x.reshape(q, d + 2)), xj, zj, m, coef)


def objective(emulator: Emulator) -> float:
    """What :func:`fit` minimised, at the fitted hyper-parameters: the negative log marginal
    likelihood plus the hyper-priors' negative log density, summed over outputs.

    Comparable between fits of the same rows and outputs only (lower: the better optimum).
    The outputs are recovered from the fit (``z = L L^T alpha``).
    """
    z = jnp.einsum("qij,qkj,qk->iq", emulator.chol, emulator.chol, emulator.alpha)
    params = jnp.column_stack([emulator.log_amp, emulator.log_ls, emulator.log_noise])
    return float(_neg_log_posterior(params, emulator.x, z, emulator.mask, noise_profile(emulator, emulator.x)))


#: Mean of ``log(chi2_1)``: the bias of a log squared standard normal residual.
_LOG_CHI2_1_MEAN = -1.2703628454614782
#: Its variance (pi^2 / 2).
_LOG_CHI2_1_VAR = np.pi**2 / 2


def fit_noise_profile(x: np.ndarray, residuals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A log-variance profile of the simulator noise from residuals, and its significance.

    Least squares of ``log r_ij^2 - E log chi2_1`` on :func:`noise_features` per output (a
    log-linear variance model, as in Harvey 1976; the residuals are the homoscedastic fit's
    leave-one-out residuals), centred so that the profile averages zero over the rows: the
    fitted ``log_noise`` stays the typical noise level.

    Parameters
    ----------
    x : array, shape (n, d)
        Unit-box inputs of the residuals.
    residuals : array, shape (n, q)

    Returns
    -------
    coef : array, shape (q, 1 + 2 d)
    p_values : array, shape (q,)
        F-test of the profile against a constant log variance (small: the noise varies).
        NaN where there are too few rows (``n <= 2 (1 + 2 d)``); ``coef`` is then zero.
    """
    x = np.asarray(x, np.float64)
    r = np.asarray(residuals, np.float64)
    n, q = r.shape
    phi = np.asarray(noise_features(jnp.asarray(x)), np.float64)
    k = phi.shape[1]
    coef = np.zeros((q, k))
    p_values = np.full(q, np.nan)
    if n <= 2 * k:
        return coef, p_values
    import scipy.stats

    y = np.log(r**2 + 1e-300) - _LOG_CHI2_1_MEAN
    for j in range(q):
        c, *_ = np.linalg.lstsq(phi, y[:, j], rcond=None)
        fitted = phi @ c
        ss1 = float(np.sum((y[:, j] - fitted) ** 2))
        ss0 = float(np.sum((y[:, j] - y[:, j].mean()) ** 2))
        f = ((ss0 - ss1) / (k - 1)) / max(ss1 / (n - k), 1e-300)
        p_values[j] = float(scipy.stats.f.sf(f, k - 1, n - k))
        c[0] -= fitted.mean()  # centred: the profile averages zero over the rows
        coef[j] = c
    return coef, p_values


def predict(emulator: Emulator, x_new: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Latent mean and variance (no simulator noise) at ``x_new (n, d)``: two arrays (n, q).

    The variance is the GP's times ``emulator.var_scale`` when set.  Differentiable and
    jittable (uses the stored Cholesky factors, O(M^2) per point).
    """

    def one(log_amp, log_ls, alpha, chol):
        kstar = _kernel(log_amp, log_ls)(emulator.x, x_new)  # (M, n)
        kstar = jnp.where(emulator.mask[:, None], kstar, 0.0)
        mean = kstar.T @ alpha
        v = jax.scipy.linalg.solve_triangular(chol, kstar, lower=True)
        var = jnp.exp(2.0 * log_amp) - jnp.sum(v * v, axis=0)
        return mean, jnp.maximum(var, 1e-12)

    mean, var = jax.vmap(one)(emulator.log_amp, emulator.log_ls, emulator.alpha, emulator.chol)
    if emulator.var_scale is not None:
        var = var * emulator.var_scale
    return mean.T, var.T


#: The range of :func:`variance_scale_mle`'s factor: the GP's variance is never shrunk, and a
#: factor beyond 1000 says the GP's variance carries no information about its error.
VARIANCE_SCALE_BOUNDS = (1.0, 1000.0)


def variance_scale_mle(
    residuals: np.ndarray, emulator_var: np.ndarray, noise_var: np.ndarray
) -> tuple[float, float, int]:
    """The factor ``c`` on the emulator's variance that best explains held-out errors.

    Maximum likelihood of ``r_ij ~ N(0, c v_ij + n_ij)``, independent, with ``r`` a held-out
    run's output minus the emulator's mean, ``v`` the GP's latent variance there (unscaled) and
    ``n`` the simulator's noise variance; ``c`` in :data:`VARIANCE_SCALE_BOUNDS`.  A GP with
    type-II maximum-likelihood hyper-parameters tends to understate its error away from its
    design (where a validation's targeted runs sit), and this measures by how much.  Estimate
    it from runs other than those that will judge the scaled emulator.

    Parameters
    ----------
    residuals, emulator_var, noise_var : array, shape (n, q)
        Non-finite entries (failed runs, outputs left out) are skipped.

    Returns
    -------
    factor : float
        1 when no finite entry is left, or when the errors are no larger than the GP says.
    se_log : float
        Standard error of ``log c`` from the observed information (inf at the bounds, where
        the likelihood's maximum is not interior, or with no data).
    num : int
        Entries used.

    Raises
    ------
    ValueError
        Arrays of different shapes, or a negative variance.
    """
    r, v, n = (np.asarray(a, np.float64) for a in (residuals, emulator_var, noise_var))
    if not r.shape == v.shape == n.shape:
        raise ValueError(f"variance_scale_mle: shapes differ: {r.shape}, {v.shape}, {n.shape}")
    keep = np.isfinite(r) & np.isfinite(v) & np.isfinite(n)
    r, v, n = r[keep], v[keep], n[keep]
    if np.any(v < 0) or np.any(n < 0):
        raise ValueError("variance_scale_mle: variances must be non-negative")
    if r.size == 0 or not np.any(v > 0):
        return 1.0, float("inf"), int(r.size)
    lo, hi = np.log(VARIANCE_SCALE_BOUNDS[0]), np.log(VARIANCE_SCALE_BOUNDS[1])

    def nll(log_c: float) -> float:
        s = np.exp(log_c) * v + n
        return 0.5 * float(np.sum(np.log(s) + r * r / s))

    best = scipy.optimize.minimize_scalar(nll, bounds=(lo, hi), method="bounded", options={"xatol": 1e-6})
    log_c = float(np.clip(best.x, lo, hi))
    # The bounded search stops within its tolerance of an end: take the end when it is no worse.
    for end in (lo, hi):
        if nll(end) <= nll(log_c):
            log_c = end
    # Observed information of log c: d2/dl2 of the nll at the optimum (l = log c, a = c v).
    a = np.exp(log_c) * v
    s = a + n
    info = float(np.sum(0.5 * a / s - 0.5 * (a / s) ** 2 - 0.5 * a * r * r / s**2 + a * a * r * r / s**3))
    interior = lo < log_c < hi
    se = float(1.0 / np.sqrt(info)) if interior and info > 0 else float("inf")
    return float(np.exp(log_c)), se, int(r.size)


@jax.jit
def loo_residuals(emulator: Emulator) -> jax.Array:
    """Leave-one-out residuals ``(M, q)`` of every output (zero on padded rows).

    ``r_i = [K^-1 z]_i / [K^-1]_ii``, the closed form of refitting without row ``i`` at fixed
    hyper-parameters.
    """

    def one(alpha, chol):
        eye = jnp.eye(chol.shape[0])
        kinv = jax.scipy.linalg.cho_solve((chol, True), eye)
        return alpha / jnp.diag(kinv)

    r = jax.vmap(one)(emulator.alpha, emulator.chol).T
    return jnp.where(emulator.mask[:, None], r, 0.0)
