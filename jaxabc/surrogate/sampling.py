"""The surrogate posterior: a synthetic likelihood on emulated summaries, sampled with blackjax NUTS.

``log p(theta | s_obs) = log N(z_obs; mu(theta), Sigma_noise + diag(var(theta)))
+ log p_feasible(theta) + const`` on the prior box, where ``mu`` and ``var`` are the emulator's
latent mean and variance, ``Sigma_noise`` the simulator's noise covariance (the fitted nuggets
with the correlation of the leave-one-out residuals), and ``p_feasible`` the probability that a
simulation at ``theta`` succeeds (:func:`feasibility`).  Adding the emulator's own variance
keeps the posterior honest where the design is thin.  NUTS runs on ``u = logit(x)`` with ``x``
the unit-box coordinates, so draws never leave the prior's support.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import blackjax
import jax
import jax.numpy as jnp

from jaxabc.surrogate.emulator import Emulator, predict

__all__ = ["Feasibility", "LikelihoodModel", "feasibility", "log_posterior", "nuts", "split_rhat"]


class Feasibility(NamedTuple):
    """A kernel-smoothed classifier of successful simulations.

    ``p(x) = (1 + sum_i ok_i k_i(x)) / (1 + sum_i k_i(x))`` with Gaussian weights
    ``k_i(x) = exp(-|x - x_i|^2 / (2 h^2))`` over every simulation run so far: one pseudo
    success keeps ``p`` at 1 far from any data and exactly 1 when nothing has failed.

    Attributes
    ----------
    x : array, shape (M, d)
        Unit-box inputs of all simulations (padded rows carry ``used = False``).
    ok, used : array of bool, shape (M,)
    bandwidth : array, shape ()
        ``h`` in box widths.
    """

    x: jax.Array
    ok: jax.Array
    used: jax.Array
    bandwidth: jax.Array


def feasibility(model: Feasibility, x: jax.Array) -> jax.Array:
    """Probability of success at unit-box points ``x (n, d)``: array (n,)."""
    d2 = jnp.sum((x[:, None, :] - model.x[None, :, :]) ** 2, axis=-1)
    k = jnp.where(model.used[None, :], jnp.exp(-0.5 * d2 / model.bandwidth**2), 0.0)
    return (1.0 + k @ model.ok.astype(x.dtype)) / (1.0 + jnp.sum(k, axis=1))


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
    """

    emulator: Emulator
    z_obs: jax.Array
    noise_chol: jax.Array
    feasible: Feasibility


def log_likelihood_terms(model: LikelihoodModel, x: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Synthetic log-likelihood at unit-box points ``x (n, d)`` and the emulator-to-noise variance
    ratio ``sum_j var_j(x) / noise_j^2`` (how much the emulator's uncertainty adds), both (n,)."""
    mean, var = predict(model.emulator, x)
    noise_sd = jnp.exp(model.emulator.log_noise)
    corr = model.noise_chol @ model.noise_chol.T
    cov = noise_sd[:, None] * corr * noise_sd[None, :]

    def one(m, v):
        c = cov + jnp.diag(v)
        chol = jnp.linalg.cholesky(c)
        r = jax.scipy.linalg.solve_triangular(chol, model.z_obs - m, lower=True)
        return -0.5 * jnp.sum(r * r) - jnp.sum(jnp.log(jnp.diag(chol)))

    loglik = jax.vmap(one)(mean, var)
    ratio = jnp.sum(var / noise_sd**2, axis=1)
    return loglik, ratio


def log_posterior(model: LikelihoodModel, x: jax.Array) -> jax.Array:
    """Unnormalised log posterior at unit-box points ``x (n, d)`` (uniform prior on the box)."""
    loglik, _ = log_likelihood_terms(model, x)
    return loglik + jnp.log(feasibility(model.feasible, x))


def _logdensity_u(model: LikelihoodModel, u: jax.Array) -> jax.Array:
    x = jax.nn.sigmoid(u)
    log_jac = jnp.sum(jax.nn.log_sigmoid(u) + jax.nn.log_sigmoid(-u))
    return log_posterior(model, x[None, :])[0] + log_jac


@partial(jax.jit, static_argnames=("num_warmup", "num_draws", "thin"))
def nuts(key: jax.Array, model: LikelihoodModel, x_init: jax.Array, num_warmup: int, num_draws: int,
         thin: int) -> tuple[jax.Array, jax.Array]:
    """Sample the surrogate posterior with blackjax NUTS.

    Window adaptation (step size and diagonal mass matrix) runs on the first chain; every chain
    then samples with those parameters.

    Parameters
    ----------
    key : jax.Array
    model : LikelihoodModel
    x_init : array, shape (c, d)
        One starting point per chain, strictly inside the unit box.
    num_warmup, num_draws, thin : int
        Adaptation steps; kept draws per chain; NUTS steps per kept draw.

    Returns
    -------
    draws : array, shape (c, num_draws, d)
        Unit-box coordinates.
    acceptance : array, shape (c,)
        Mean NUTS acceptance probability per chain.
    """
    logdensity = partial(_logdensity_u, model)
    u_init = jnp.log(x_init) - jnp.log1p(-x_init)
    k_adapt, k_run = jax.random.split(key)
    adapt = blackjax.window_adaptation(blackjax.nuts, logdensity)
    (state0, params), _ = adapt.run(k_adapt, u_init[0], num_steps=num_warmup)
    kernel = blackjax.nuts(logdensity, **params)

    def chain(k, u0):
        state = kernel.init(u0)

        def step(state, k):
            state, info = kernel.step(k, state)
            return state, (state.position, info.acceptance_rate)

        _, (pos, acc) = jax.lax.scan(step, state, jax.random.split(k, num_draws * thin))
        return jax.nn.sigmoid(pos[thin - 1 :: thin]), jnp.mean(acc)

    # Chains after the first start from the adapted position's neighbourhood of their own init.
    starts = u_init.at[0].set(state0.position)
    return jax.vmap(chain)(jax.random.split(k_run, x_init.shape[0]), starts)


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
