"""The surrogate posterior: a synthetic likelihood on emulated summaries, sampled with blackjax NUTS.

``log p(theta | s_obs) = log N(z_obs; mu(theta), Sigma_noise + diag(var(theta)))
+ log p_feasible(theta) + const`` on the prior box, where ``mu`` and ``var`` are the emulator's
latent mean and variance, ``Sigma_noise`` the simulator's noise covariance (the fitted nuggets
with the correlation of the leave-one-out residuals), and ``p_feasible`` the probability that a
simulation at ``theta`` succeeds (:func:`feasibility`).  Adding the emulator's own variance
keeps the posterior honest where the design is thin.  Outputs that never varied over the design
are left out (they say nothing about ``theta``).

Where ``p_feasible`` is below ``min_feasibility`` the posterior is cut off (a probabilistic
constraint, as in constrained Bayesian optimisation, Gelbart et al. 2014).  Failed runs teach
the emulator nothing, so its variance stays at its prior level where runs fail; when no
parameter reproduces the data to within the simulator's noise (measured data, a misspecified
model), that variance makes the infeasible region look like the best fit, and a soft factor
``p_feasible`` (a few nats even after hundreds of failures) cannot outweigh it.

NUTS runs on ``u = logit(x)`` with ``x`` the unit-box coordinates, so draws never leave the
prior's support.

Measured data: the covariance ``M`` of the observed summaries' measurement error (summary
units) enters as ``T M T^T``, ``T`` the linear part of the output transform
(:func:`output_map`), so that ``Sigma = Sigma_noise + diag(var) + T M T^T`` (Wilkinson 2013).
A model discrepancy with ``G`` group sds ``delta_g ~ U(0, max_sd_g)`` adds
``sum_g delta_g^2 T diag(membership_g) T^T``; the group sds are then sampled with ``theta``:
points have ``d + G`` unit-box columns, of which the emulator and the feasibility classifier
see the first ``d``.
"""

from __future__ import annotations

import warnings
from functools import partial
from typing import Any, NamedTuple, cast

import blackjax
import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
import scipy.special

from jaxabc.surrogate.emulator import Emulator, noise_sd, predict

__all__ = [
    "Feasibility",
    "GPClassifier",
    "LikelihoodModel",
    "discrepancy_cov",
    "feasibility",
    "fit_feasibility",
    "fit_gp_classifier",
    "gp_log_success",
    "log_feasibility",
    "log_feasibility_term",
    "log_level",
    "log_posterior",
    "nearest_runs_cut",
    "nearest_runs_succeed",
    "num_parameters",
    "nuts",
    "output_map",
    "quadratic_log_success",
    "split_rhat",
    "theta_columns",
]


class GPClassifier(NamedTuple):
    """The Laplace-approximated GP classifier of :class:`Feasibility`, as arrays for JAX.

    Latent mean ``k(x)^T alpha`` and variance ``amp - |L^-1 (w_sr * k(x))|^2`` with ``k(x) =
    amp exp(-|x - x_i|^2_ls / 2)`` (Rasmussen & Williams 2006, algorithm 3.2), then ``p =
    sigmoid(mean / sqrt(1 + pi var / 8))`` (MacKay's probit approximation).  Rows beyond the
    fitted runs are padding (far outside the box, ``alpha`` and ``w_sr`` 0, ``L`` the identity).

    Attributes
    ----------
    x : array, shape (m, d)
    alpha : array, shape (m,)
        ``y - pi`` at the Laplace mode (``y`` 1 for success).
    w_sr : array, shape (m,)
        ``sqrt(pi (1 - pi))``.
    chol : array, shape (m, m)
        Lower Cholesky factor of ``I + W^1/2 K W^1/2``.
    log_amp : array, shape ()
    log_ls : array, shape (d,)
    active : array of bool, shape ()
    """

    x: jax.Array
    alpha: jax.Array
    w_sr: jax.Array
    chol: jax.Array
    log_amp: jax.Array
    log_ls: jax.Array
    active: jax.Array


#: The GP classifier is fitted once this many runs (of both outcomes) are known.
GP_MIN_RUNS = 6
#: Bounds of its kernel amplitude and length scales (unit-box widths).  Deterministic failures
#: beyond a sharp boundary are separable data, whose marginal likelihood grows with the
#: amplitude without end: the cap keeps the boundary steep but finite.
GP_AMP_BOUNDS = (1e-2, 1e3)
GP_LS_BOUNDS = (1e-2, 1e1)


def fit_gp_classifier(x: np.ndarray, ok: np.ndarray, size: int | None = None) -> GPClassifier:
    """Fit :class:`GPClassifier` to unit-box inputs ``x (n, d)`` and outcomes ``ok (n,)``,
    padded to ``size`` rows; inactive (``p = 1``) with fewer than ``GP_MIN_RUNS`` runs or one
    outcome only.  Deterministic: the optimiser starts from fixed values, with no restarts."""
    x = np.asarray(x, np.float64)
    ok = np.asarray(ok, bool)
    n, d = x.shape
    m = max(n, size or 0)
    xs = np.full((m, d), _PAD_COORD)
    xs[:n] = x
    alpha, w_sr, chol = np.zeros(m), np.zeros(m), np.eye(m)
    log_amp, log_ls, active = 0.0, np.zeros(d), False
    if n >= GP_MIN_RUNS and 0 < ok.sum() < n:
        from sklearn.exceptions import ConvergenceWarning
        from sklearn.gaussian_process import GaussianProcessClassifier
        from sklearn.gaussian_process.kernels import RBF, ConstantKernel

        # An array length scale makes the RBF anisotropic; sklearn's annotation says float.
        ls0 = np.full(d, 0.2)
        kernel = ConstantKernel(1.0, GP_AMP_BOUNDS) * RBF(ls0, GP_LS_BOUNDS)  # pyright: ignore[reportArgumentType]
        with warnings.catch_warnings():
            # A hyper-parameter at its bound is expected (the amplitude, see GP_AMP_BOUNDS).
            warnings.simplefilter("ignore", ConvergenceWarning)
            gpc = GaussianProcessClassifier(kernel).fit(x, ok.astype(np.int64))
        # The binary Laplace classifier's factors (Rasmussen & Williams, algorithm 3.2); sklearn
        # types base_estimator_ as the multi-class wrappers it uses for more than two classes.
        fitted: Any = gpc.base_estimator_
        params = cast(Any, gpc.kernel_).get_params()
        alpha[:n] = fitted.y_train_ - fitted.pi_
        w_sr[:n] = fitted.W_sr_
        chol[:n, :n] = fitted.L_
        log_amp = float(np.log(params["k1__constant_value"]))
        log_ls = np.log(np.broadcast_to(params["k2__length_scale"], (d,)))
        active = True
    return GPClassifier(
        x=jnp.asarray(xs),
        alpha=jnp.asarray(alpha),
        w_sr=jnp.asarray(w_sr),
        chol=jnp.asarray(chol),
        log_amp=jnp.asarray(log_amp),
        log_ls=jnp.asarray(log_ls),
        active=jnp.asarray(active),
    )


def gp_log_success(gp: GPClassifier, x: jax.Array) -> jax.Array:
    """``log p_gp`` of success at unit-box points ``x (n, d)``: (n,), 0 where ``gp`` is inactive."""
    ls = jnp.exp(gp.log_ls)
    r2 = jnp.sum(((gp.x[:, None, :] - x[None, :, :]) / ls) ** 2, axis=-1)
    amp = jnp.exp(gp.log_amp)
    k = amp * jnp.exp(-0.5 * r2)  # (m, n)
    mean = k.T @ gp.alpha
    v = jax.scipy.linalg.solve_triangular(gp.chol, gp.w_sr[:, None] * k, lower=True)
    var = jnp.maximum(amp - jnp.sum(v * v, axis=0), 0.0)
    return jnp.where(gp.active, jax.nn.log_sigmoid(mean / jnp.sqrt(1.0 + jnp.pi * var / 8.0)), 0.0)


class Feasibility(NamedTuple):
    """A probabilistic classifier of successful simulations: the lesser of two.

    ``p(x) = min(sigmoid(w . phi(x)), p_gp(x))``.  The first is quadratic logistic regression,
    ``phi`` the constant, linear and quadratic terms of ``x - 1/2`` (unit-box coordinates): it
    extrapolates a boundary to corners where no run was made (a phase beyond a plane), where a
    kernel method says nothing.  The second, a Gaussian-process classifier
    (:class:`GPClassifier`, once runs of both outcomes are known), is local: it follows a
    curved or narrow failure region that lies across the quadratic's boundary (water, paper
    statistics: most design runs placed on the quadratic's ``p = 0.5`` contour failed).  A run
    is expected to succeed only where both expect it; far from every run the GP says 0.5.
    ``p`` is exactly 1 when nothing has failed.

    Beside it, the distinct run sites, for :func:`nearest_runs_succeed`: a k-nearest-neighbour
    classifier, local and sharp where the quadratic boundary is neither (a narrow band of
    success between two failing phases).  Replicate runs at one site count once, with their
    fraction of failures: otherwise a replicated site fills every neighbourhood around it and
    shields the failures next to it from the cut (water, paper preset: a replicate site nearby
    kept the design returning to a spot where every run had failed).

    Attributes
    ----------
    weights : array, shape (f,)
        ``f = 1 + d + d (d + 1) / 2``.
    active : array of bool, shape ()
        False when every run succeeded (then ``p = 1``).
    runs_x : array, shape (m, d)
        Unit-box points of the distinct run sites (padding rows far outside the box).
    runs_failed : array, shape (m,)
        The fraction of the runs at each site that failed (padding rows 0).
    gp : GPClassifier
        The Gaussian-process classifier (``gp.active`` False: not fitted, only one outcome seen).
    """

    weights: jax.Array
    active: jax.Array
    runs_x: jax.Array
    runs_failed: jax.Array
    gp: GPClassifier


#: The k-nearest-neighbour cut: a point is infeasible when at least ``KNN_MAX_FAILED`` of its
#: ``KNN_K`` nearest run sites failed, the nearest among them.  4 of 5 cuts a deterministic
#: failure region once a few runs have failed there, and almost never a region where runs fail
#: at random (30 % failures: P(>= 4 of 5) = 0.03).
KNN_K = 5
KNN_MAX_FAILED = 4
_PAD_COORD = 1e3

#: Default L2 penalty of :func:`fit_feasibility`: a Gaussian prior of sd 100 on the weights,
#: steep enough for the sharp boundaries of deterministic failures (a phase change).
FEASIBILITY_PENALTY = 1e-4


def _features(x: jax.Array) -> jax.Array:
    c = x - 0.5
    d = x.shape[-1]
    i, j = jnp.triu_indices(d)
    return jnp.concatenate([jnp.ones((*x.shape[:-1], 1)), c, c[..., i] * c[..., j]], axis=-1)


def fit_feasibility(
    x: np.ndarray, ok: np.ndarray, penalty: float = FEASIBILITY_PENALTY, size: int | None = None
) -> Feasibility:
    """Fit :class:`Feasibility` to unit-box inputs ``x (n, d)`` and outcomes ``ok (n,)``.

    An L2 penalty on the non-constant weights keeps a perfectly separable design (the usual
    case: runs fail beyond a sharp boundary) at finite, steep weights.  ``size`` pads the stored
    sites to a fixed number of rows (one compilation per budget, not per design size).
    """
    phi = np.asarray(_features(jnp.asarray(x)))
    d = x.shape[1]
    sites, site_of = np.unique(x, axis=0, return_inverse=True)
    site_of = site_of.reshape(-1)
    failed = np.bincount(site_of, weights=~np.asarray(ok, bool), minlength=len(sites))
    m = max(len(sites), size or 0)
    runs_x = np.full((m, d), _PAD_COORD)
    runs_x[: len(sites)] = sites
    runs_failed = np.zeros(m)
    runs_failed[: len(sites)] = failed / np.bincount(site_of, minlength=len(sites))
    runs = (jnp.asarray(runs_x), jnp.asarray(runs_failed))
    gp = fit_gp_classifier(x, ok, size)
    if np.all(ok):
        return Feasibility(jnp.zeros(phi.shape[1]), jnp.asarray(False), *runs, gp)
    y = np.where(ok, 1.0, -1.0)

    def loss(w: np.ndarray) -> tuple[float, np.ndarray]:
        m = y * (phi @ w)
        value = np.sum(np.logaddexp(0.0, -m)) + 0.5 * penalty * np.sum(w[1:] ** 2)
        grad = -phi.T @ (y * scipy.special.expit(-m))
        grad[1:] += penalty * w[1:]
        return float(value), grad

    res = scipy.optimize.minimize(loss, np.zeros(phi.shape[1]), jac=True, method="L-BFGS-B")
    return Feasibility(jnp.asarray(res.x), jnp.asarray(True), *runs, gp)


def feasibility(model: Feasibility, x: jax.Array) -> jax.Array:
    """Probability of success at unit-box points ``x (n, d)``: array (n,)."""
    return jnp.exp(log_feasibility(model, x))


def nearest_runs_succeed(model: Feasibility, x: jax.Array) -> jax.Array:
    """False where at least ``KNN_MAX_FAILED`` of the ``KNN_K`` run sites nearest to ``x (n, d)``
    (unit box, Euclidean) failed, a replicated site counting its fraction of failures, and most
    runs at the nearest site failed: bool array (n,).

    The second condition keeps the cell around a site where runs succeed, even amid failures:
    a successful site is never cut off.
    """
    k = min(KNN_K, model.runs_x.shape[0])
    d2 = jnp.sum((x[:, None, :] - model.runs_x[None, :, :]) ** 2, axis=-1)
    _, idx = jax.lax.top_k(-d2, k)
    failed = jnp.sum(model.runs_failed[idx], axis=1)
    return (failed < min(KNN_MAX_FAILED, k)) | (model.runs_failed[idx[:, 0]] <= 0.5)


def log_level(min_feasibility: float) -> jax.Array:
    """``log min_feasibility`` as the array the models carry (``-inf`` for 0: never cut)."""
    if not 0.0 <= min_feasibility < 1.0:
        raise ValueError(f"min_feasibility must be in [0, 1), got {min_feasibility}")
    return jnp.asarray(np.log(min_feasibility) if min_feasibility > 0 else -np.inf)


def nearest_runs_cut(model: Feasibility, x: jax.Array) -> jax.Array:
    """True where the nearest-run rule cuts ``x (n, d)`` off: most of its nearest runs failed
    (never while no run has failed, ``model.active`` False)."""
    return model.active & ~nearest_runs_succeed(model, x)


def quadratic_log_success(model: Feasibility, x: jax.Array) -> jax.Array:
    """``log p`` of the quadratic logistic classifier alone at unit-box ``x (n, d)``: array (n,),
    0 while no run has failed (``model.active`` False)."""
    return jnp.where(model.active, jax.nn.log_sigmoid(_features(x) @ model.weights), 0.0)


def log_feasibility(model: Feasibility, x: jax.Array) -> jax.Array:
    """``log p_feasible`` at unit-box points ``x (n, d)``: array (n,), finite where p underflows.
    The lesser of :func:`quadratic_log_success` and :func:`gp_log_success`."""
    return jnp.minimum(quadratic_log_success(model, x), gp_log_success(model.gp, x))


class LikelihoodModel(NamedTuple):
    """Everything the synthetic likelihood needs (a pytree).

    Attributes
    ----------
    emulator : Emulator
    z_obs : array, shape (q,)
        Observed summaries in emulated-output coordinates.
    noise_chol : array, shape (q, q)
        Cholesky factor of the noise correlation (``Sigma_noise = D R D``, ``D`` the nuggets).
    feasible : Feasibility
    active : array of bool, shape (q,)
        Outputs in the likelihood (those that varied over the design).
    log_min_feasibility : array, shape ()
        ``log`` of the constraint level; below it the log density drops by
        ``_CUT_SLOPE`` per nat.
    observation_cov : array, shape (q, q), optional
        Covariance of the observed summaries' measurement error mapped into emulated-output
        coordinates (``T M T^T``, :func:`output_map`); added to the likelihood's covariance.
    discrepancy_basis : array, shape (G, q, q), optional
        ``T diag(membership_g) T^T`` per discrepancy group: the covariance of a unit discrepancy
        sd in group ``g``, in emulated-output coordinates.  With it the model's points have
        ``d + G`` columns, the last ``G`` the unit-box coordinates of the group sds.
    discrepancy_max_sd : array, shape (G,), optional
        Upper bounds of the group sds' uniform priors (summary units): ``delta = x[d:] * max_sd``.
    """

    emulator: Emulator
    z_obs: jax.Array
    noise_chol: jax.Array
    feasible: Feasibility
    active: jax.Array
    log_min_feasibility: jax.Array
    observation_cov: jax.Array | None = None
    discrepancy_basis: jax.Array | None = None
    discrepancy_max_sd: jax.Array | None = None


#: Slope of the constraint below ``min_feasibility`` (per nat of log p), on top of its step
#: (``_CUT_STEP``): a gradient back towards the level for a sampler that starts outside.
_CUT_SLOPE = 1000.0
#: Log-density drop below ``min_feasibility`` and where the nearest runs failed (a step: NUTS
#: sees a divergence and stays).  It stands in for probability zero, so no likelihood may
#: outbid it: an emulator fitted to a few successes can put a failing corner 1e4 nats above
#: every feasible point (water, paper preset, X-ray data: the design then spent 29 runs
#: there), and the slope alone was outbid on the neutron data with the paper's statistics
#: (benchmarks/results/water_neutron_surrogate.json at commit ecc0ebb: every held-out run failed).
#: 1e12 still leaves float64 a 1e-4 nat resolution among cut points.
_CUT_STEP = 1e12


def output_map(transform: Any) -> np.ndarray:
    """The linear part ``T (q, k)`` of an :class:`~.emulator.OutputTransform`, ``z = T y + c``.

    A covariance ``C`` of the raw summaries is ``T C T^T`` in emulated-output coordinates.  With
    a projection (``q < k`` principal components) this is exact for the projected summaries the
    likelihood is a density of: the error along the dropped directions never enters it, just as
    the data and the simulator noise along them do not.
    """
    rotation = np.asarray(transform.rotation, np.float64)
    scale = np.asarray(transform.scale, np.float64)
    return (rotation / scale[:, None]).T


def num_parameters(model: LikelihoodModel) -> int:
    """Columns of the model's unit-box points: ``d``, plus ``G`` discrepancy sds."""
    extra = 0 if model.discrepancy_max_sd is None else int(model.discrepancy_max_sd.shape[0])
    return int(model.emulator.x.shape[1]) + extra


def theta_columns(model: LikelihoodModel, x: Any) -> Any:
    """The emulator's part ``x[..., :d]`` of augmented unit-box points (``d`` read from the
    feasibility classifier, which every model carries)."""
    return x[..., : model.feasible.runs_x.shape[-1]]


def discrepancy_cov(model: LikelihoodModel, x: jax.Array) -> jax.Array | None:
    """The discrepancy covariance ``(n, q, q)`` in emulated-output coordinates at augmented
    unit-box points ``x (n, d + G)`` (None without a discrepancy)."""
    if model.discrepancy_basis is None or model.discrepancy_max_sd is None:
        return None
    delta = x[:, model.emulator.x.shape[1] :] * model.discrepancy_max_sd
    return jnp.einsum("ng,gij->nij", delta**2, model.discrepancy_basis)


def log_likelihood_terms(model: LikelihoodModel, x: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Synthetic log-likelihood at unit-box points ``x (n, d)`` and the emulator-to-noise variance
    ratio ``mean_j var_j(x) / noise_j^2`` (how much the emulator's uncertainty adds), both (n,).

    The covariance is the simulator noise plus the emulator's variance, plus the measurement
    error (``model.observation_cov``) and the discrepancy at ``x``'s group sds when the model
    has them (``x`` then has ``d + G`` columns)."""
    theta = theta_columns(model, x)
    mean, var = predict(model.emulator, theta)
    sd = noise_sd(model.emulator, theta)  # (n, q): constant rows unless heteroscedastic
    corr = model.noise_chol @ model.noise_chol.T
    active = model.active
    # Inactive outputs drop out: unit variance, no correlation, zero residual.
    both = active[:, None] & active[None, :]
    eye = jnp.eye(corr.shape[0], dtype=corr.dtype)

    def one(m, v, s, extra):
        c = s[:, None] * corr * s[None, :]
        if model.observation_cov is not None:
            c = c + model.observation_cov
        c = jnp.where(both, c, eye) + jnp.diag(jnp.where(active, v, 0.0))
        if extra is not None:
            c = c + jnp.where(both, extra, 0.0)
        chol = jnp.linalg.cholesky(c)
        r = jax.scipy.linalg.solve_triangular(chol, jnp.where(active, model.z_obs - m, 0.0), lower=True)
        return -0.5 * jnp.sum(r * r) - jnp.sum(jnp.log(jnp.diag(chol)))

    disc = discrepancy_cov(model, x)
    if disc is None:
        loglik = jax.vmap(lambda m, v, s: one(m, v, s, None))(mean, var, sd)
    else:
        loglik = jax.vmap(one)(mean, var, sd, disc)
    ratio = jnp.sum(jnp.where(active, var / sd**2, 0.0), axis=1) / jnp.maximum(jnp.sum(active), 1)
    return loglik, ratio


def log_feasibility_term(model: LikelihoodModel, x: jax.Array) -> jax.Array:
    """``log p_feasible`` plus the constraints (below ``min_feasibility``; where the nearest runs
    failed), at ``x (n, d)`` (or ``(n, d + G)``, the feasibility seeing ``theta`` only): (n,)."""
    x = theta_columns(model, x)
    lf = log_feasibility(model.feasible, x)
    below = lf < model.log_min_feasibility
    cut = jnp.where(nearest_runs_cut(model.feasible, x) | below, _CUT_STEP, 0.0)
    return lf - _CUT_SLOPE * jnp.maximum(model.log_min_feasibility - lf, 0.0) - cut


def log_posterior(model: LikelihoodModel, x: jax.Array) -> jax.Array:
    """Unnormalised log posterior at unit-box points ``x (n, d)`` (uniform prior on the box)."""
    loglik, _ = log_likelihood_terms(model, x)
    return loglik + log_feasibility_term(model, x)


def _logdensity_u(model: LikelihoodModel, u: jax.Array) -> jax.Array:
    x = jax.nn.sigmoid(u)
    log_jac = jnp.sum(jax.nn.log_sigmoid(u) + jax.nn.log_sigmoid(-u))
    return log_posterior(model, x[None, :])[0] + log_jac


@partial(jax.jit, static_argnames=("num_warmup", "num_draws", "thin"))
def nuts(
    key: jax.Array,
    model: LikelihoodModel,
    x_init: jax.Array,
    inverse_mass_matrix: jax.Array,
    step_size: jax.Array,
    num_warmup: int,
    num_draws: int,
    thin: int,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Sample the surrogate posterior with blackjax NUTS, one chain per starting point.

    The metric comes from the caller (the importance-weighted covariance of the design-phase
    posterior, in ``u`` coordinates) instead of blackjax's window adaptation: the chains start
    from posterior draws already, and one compiled kernel instead of two halves the compile time.

    Parameters
    ----------
    key : jax.Array
    model : LikelihoodModel
    x_init : array, shape (c, d)
        One starting point per chain, strictly inside the unit box.
    inverse_mass_matrix : array, shape (d, d)
        Posterior covariance estimate of ``u = logit(x)``.
    step_size : array, shape ()
    num_warmup, num_draws, thin : int
        Discarded steps per chain; kept draws per chain; NUTS steps per kept draw.

    Returns
    -------
    draws : array, shape (c, num_draws, d)
        Unit-box coordinates.
    acceptance : array, shape (c,)
        Mean NUTS acceptance probability per chain over the kept steps.
    divergent : array, shape (c,)
        Share of each chain's kept steps that diverged.
    """
    logdensity = partial(_logdensity_u, model)
    kernel = blackjax.nuts(logdensity, step_size, inverse_mass_matrix)

    # blackjax annotates init as needing rng_key (NUTS does not) and step as returning its
    # generic State/Info protocols, which lack NUTS's position and acceptance_rate.
    def chain(k, x0):
        state = kernel.init(jnp.log(x0) - jnp.log1p(-x0))  # pyright: ignore[reportCallIssue]

        def step(state, k):
            state, info = kernel.step(k, state)
            return state, (state.position, info.acceptance_rate, info.is_divergent)  # pyright: ignore[reportAttributeAccessIssue]

        k_warm, k_run = jax.random.split(k)
        state, _ = jax.lax.scan(step, state, jax.random.split(k_warm, num_warmup))
        _, (pos, acc, div) = jax.lax.scan(step, state, jax.random.split(k_run, num_draws * thin))
        return jax.nn.sigmoid(pos[thin - 1 :: thin]), jnp.mean(acc), jnp.mean(div)

    return jax.vmap(chain)(jax.random.split(key, x_init.shape[0]), x_init)


def split_rhat(draws: jax.Array) -> jax.Array:
    """Split-R-hat per parameter of ``draws (c, n, d)`` (Gelman et al. 2013): array (d,)."""
    n = draws.shape[1]
    half = n // 2
    chains = jnp.concatenate([draws[:, :half], draws[:, half : 2 * half]], axis=0)
    means = chains.mean(axis=1)
    within = chains.var(axis=1, ddof=1).mean(axis=0)
    between = half * means.var(axis=0, ddof=1)
    var_plus = (half - 1) / half * within + between / half
    return jnp.sqrt(var_plus / within)
