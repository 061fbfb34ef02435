"""Helium, CPU preset: the surrogate's noise model against replicate runs at its posterior.

The surrogate's synthetic likelihood models the noise by per-summary GP nuggets, constant or (by
``noise_model="auto"``, its default, when an F-test finds it) following a log-linear profile in
theta, and a correlation from the leave-one-out residuals.  The 16 quantiles of helium's f_B series
are heteroscedastic, so this checks what the run's noise model does at the posterior (same data,
seed and summaries as ``surrogate_helium.py``):

- replicate runs at the posterior mean and at design points give the noise there (sd per
  summary, mean absolute correlation);
- the posterior sd of a Laplace approximation (the emulator's mean gradient at the posterior
  mean) under the model's covariance, under the empirical one at the posterior mean, and with
  each one's sds and the other's correlations, beside the surrogate's posterior sd;
- exact posteriors on a grid around the surrogate's, one ingredient changed at a time: the
  surrogate's own log-likelihood (checks the sampler), without the emulator's variance, with
  the replicate mean in place of the emulated one, with the replicates' covariance pooled over
  the grid (``surrogate_helium``'s reference) and with it local to each point, log-determinant
  included (the synthetic likelihood of Wood 2010, whose covariance varies with theta).

It explains the width of the surrogate's posterior against ``surrogate_helium``'s grid reference,
whose covariance is pooled over a box around the posterior.

Usage::

    python -m benchmarks.surrogate_helium_noise
    python -m benchmarks.surrogate_helium_noise --quick     # plumbing check: results/quick/
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxabc
from benchmarks._common import write_result
from benchmarks._helium_quantiles import quantile_problem
from jaxabc import checkpoint
from jaxabc.surrogate import build, emulator, sampling
from jaxabc.surrogate._fit import fit_likelihood

ROOT = Path(__file__).resolve().parents[1]


def _mean_abs_corr(cov: np.ndarray) -> float:
    sd = np.sqrt(np.diag(cov))
    corr = cov / np.outer(sd, sd)
    return float(np.mean(np.abs(corr[np.triu_indices(len(sd), 1)])))


def posterior_weights(loglik: np.ndarray) -> np.ndarray:
    """Normalised weights of grid points under a uniform prior."""
    w = np.exp(loglik - loglik.max())
    return w / w.sum()


def grid_moments(grid: np.ndarray, loglik: np.ndarray, size: int) -> dict:
    """Mean, sd, correlation and the weight on the edge of a ``size x size`` grid posterior."""
    w = posterior_weights(loglik)
    mean = w @ grid
    sd = np.sqrt(w @ (grid - mean) ** 2)
    corr = float(w @ np.prod(grid - mean, axis=1) / np.prod(sd))
    square = w.reshape(size, size)
    edge = float(square[[0, -1], :].sum() + square[1:-1, [0, -1]].sum())
    return {"mean": mean.tolist(), "sd": sd.tolist(), "correlation": corr, "weight_on_edge": edge}


def local_covariances(resid: np.ndarray, size: int, half: int) -> np.ndarray:
    """Per grid point, the covariance of the replicate residuals ``resid (size^2, R, q)`` pooled
    over the ``(2 half + 1)^2`` neighbouring points (their own means removed): (size^2, q, q)."""
    r, q = resid.shape[1], resid.shape[2]
    square = resid.reshape(size, size, r, q)
    out = np.empty((size * size, q, q))
    for i in range(size):
        for j in range(size):
            block = square[max(0, i - half) : i + half + 1, max(0, j - half) : j + half + 1].reshape(-1, q)
            points = block.shape[0] // r
            out[i * size + j] = block.T @ block / (points * (r - 1))
    return out


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--budget", type=int, default=100, help="the surrogate's max_simulations")
    parser.add_argument("--preset", default="cpu")
    parser.add_argument("--seed", type=int, default=0, help="data and inference seed (as surrogate_helium.py)")
    parser.add_argument("--draws", type=int, default=2000)
    parser.add_argument("--replicates", type=int, default=600, help="runs at the posterior mean")
    parser.add_argument("--design-sites", type=int, default=8, help="design points given replicates too")
    parser.add_argument("--design-replicates", type=int, default=200)
    parser.add_argument("--grid", type=int, default=41, help="grid points per parameter")
    parser.add_argument("--grid-width", type=float, default=8.0, help="half-width in surrogate posterior sd")
    parser.add_argument("--grid-replicates", type=int, default=40, help="runs per grid point")
    parser.add_argument("--neighbourhood", type=int, default=3, help="half-width in points of the local covariance")
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    if args.quick:
        args.budget, args.replicates, args.design_sites, args.design_replicates = 60, 100, 2, 50
        args.grid, args.grid_replicates = 11, 20

    simulate_quantiles, prior, _, observed_q, _ = quantile_problem(args.preset, args.seed)
    batched = jax.jit(jax.vmap(simulate_quantiles))

    def runs(keys: jax.Array, thetas: np.ndarray, chunk: int = 8192) -> np.ndarray:
        """One simulation per (key, theta) row, in chunks that bound the vmapped batch's memory."""
        points = jnp.asarray(thetas, jnp.float32)
        return np.concatenate(
            [
                np.asarray(batched(keys[i : i + chunk], points[i : i + chunk]), np.float64)
                for i in range(0, len(points), chunk)
            ]
        )

    def replicates(theta: np.ndarray, count: int, seed: int) -> np.ndarray:
        return runs(jax.random.split(jax.random.key(seed), count), np.tile(theta, (count, 1)))

    with tempfile.TemporaryDirectory() as folder:
        result = jaxabc.run(
            "surrogate",
            simulate_quantiles,
            prior,
            observed_q,
            max_simulations=args.budget,
            num_particles=args.draws,
            seed=args.seed,
            checkpoint_dir=folder,
        )
        stored = checkpoint.load(Path(folder) / "checkpoint.npz")
    algorithm = build(prior, args.draws, observed=observed_q, max_simulations=args.budget)
    state = algorithm.restore_state(stored.state_leaves)
    draws = np.asarray(result.particles, np.float64)
    centre = draws.mean(axis=0)
    low, high = np.asarray(prior.low, np.float64), np.asarray(prior.high, np.float64)

    at_centre = replicates(centre, args.replicates, 1)
    rng = np.random.default_rng(args.seed)
    design = np.asarray(state.thetas)[np.asarray(state.ok) & (np.asarray(state.role) >= 0)]
    sites = design[rng.choice(len(design), size=min(args.design_sites, len(design)), replace=False)]
    at_sites = [replicates(s, args.design_replicates, 2 + i) for i, s in enumerate(sites)]

    # The grid around the surrogate's posterior, each point with its own replicate runs.
    spread = args.grid_width * draws.std(axis=0)
    axes = [
        np.linspace(max(c - w, lo), min(c + w, hi), args.grid)
        for c, w, lo, hi in zip(centre, spread, low, high, strict=True)
    ]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 2)
    keys = jax.random.split(jax.random.key(args.seed + 100), len(grid) * args.grid_replicates)
    at_grid = runs(keys, np.repeat(grid, args.grid_replicates, axis=0))

    with jax.enable_x64(True):
        # The run's own noise model: "auto" decides, per fit, whether the noise sd follows theta.
        transform, emu, model, _ = fit_likelihood(
            state,
            low,
            high,
            observed_q,
            16,
            args.budget,
            sampling.log_level(0.01),
            noise_model=algorithm.settings["noise_model"],
        )
        heteroscedastic = bool(np.any(np.asarray(emu.noise_coef) != 0)) if emu.noise_coef is not None else False
        u_centre = jnp.asarray([(centre - low) / (high - low)])
        noise_sd = np.asarray(emulator.noise_sd(emu, u_centre), np.float64)[0]
        chol = np.asarray(model.noise_chol, np.float64)
        corr_model = chol @ chol.T
        cov_model = np.outer(noise_sd, noise_sd) * corr_model
        cov_centre = np.cov(np.asarray(transform.apply(jnp.asarray(at_centre))).T)
        cov_sites = [np.cov(np.asarray(transform.apply(jnp.asarray(r))).T) for r in at_sites]
        # The emulator's mean gradient at the posterior mean, per parameter unit.
        u, h = (centre - low) / (high - low), 1e-3
        columns = []
        for j in range(len(u)):
            step = np.zeros_like(u)
            step[j] = h
            up, _ = emulator.predict(emu, jnp.asarray([u + step]))
            down, _ = emulator.predict(emu, jnp.asarray([u - step]))
            columns.append((np.asarray(up)[0] - np.asarray(down)[0]) / (2 * h * (high[j] - low[j])))
        jac = np.stack(columns, axis=1)
        u_grid = jnp.asarray((grid - low) / (high - low))
        loglik_surrogate, _ = sampling.log_likelihood_terms(model, u_grid)
        emulated, _ = emulator.predict(emu, u_grid)
        noise_grid = np.asarray(emulator.noise_sd(emu, u_grid), np.float64)
        z_grid = np.asarray(transform.apply(jnp.asarray(at_grid)), np.float64)
        active = np.asarray(model.active, bool)
        z_obs = np.asarray(model.z_obs, np.float64)

    sd_centre = np.sqrt(np.diag(cov_centre))
    corr_centre = cov_centre / np.outer(sd_centre, sd_centre)

    def laplace_sd(cov: np.ndarray) -> list[float]:
        return np.sqrt(np.diag(np.linalg.inv(jac.T @ np.linalg.solve(cov, jac)))).tolist()

    reps = args.grid_replicates
    z_grid = z_grid.reshape(len(grid), reps, -1)[:, :, active]
    rep_mean = z_grid.mean(axis=1)
    resid = z_grid - rep_mean[:, None]
    emulated = np.asarray(emulated, np.float64)[:, active]
    inflate = 1.0 + 1.0 / reps  # the replicate mean's own error

    def gaussian_loglik(means: np.ndarray, cov: np.ndarray) -> np.ndarray:
        """Log-likelihood of the data at every grid point; ``cov`` (q, q) or per point (n, q, q)."""
        diff = z_obs[active] - means
        if cov.ndim == 2:
            return -0.5 * np.einsum("ni,ni->n", diff, np.linalg.solve(cov, diff.T).T)
        _, logdet = np.linalg.slogdet(cov)
        return -0.5 * np.einsum("ni,ni->n", diff, np.linalg.solve(cov, diff[..., None])[..., 0]) - 0.5 * logdet

    # The model's noise covariance at each grid point (it varies only under a noise profile).
    sd_grid = noise_grid[:, active]
    corr_active = corr_model[np.ix_(active, active)]
    model_cov = sd_grid[:, :, None] * corr_active[None] * sd_grid[:, None, :]
    pooled = resid.reshape(-1, resid.shape[-1])
    pooled_cov = pooled.T @ pooled / (len(grid) * (reps - 1))
    local = local_covariances(resid, args.grid, args.neighbourhood)
    size = args.grid
    decomposition = {
        "surrogate_log_likelihood": grid_moments(grid, np.asarray(loglik_surrogate, np.float64), size),
        "emulated_mean_model_covariance_no_emulator_variance": grid_moments(
            grid, gaussian_loglik(emulated, model_cov), size
        ),
        "replicate_mean_model_covariance": grid_moments(grid, gaussian_loglik(rep_mean, model_cov * inflate), size),
        "replicate_mean_pooled_covariance": grid_moments(grid, gaussian_loglik(rep_mean, pooled_cov * inflate), size),
        "replicate_mean_local_covariance": grid_moments(grid, gaussian_loglik(rep_mean, local * inflate), size),
    }
    # The emulated mean's error where the surrogate's posterior lies, in noise sd per output.
    weights = posterior_weights(np.asarray(loglik_surrogate, np.float64))
    mean_error = np.sqrt(weights @ ((emulated - rep_mean) / sd_grid) ** 2)

    entry = {
        "benchmark": "surrogate_helium_noise",
        "description": (__doc__ or "").split("\n\n")[0],
        "setup": {
            "preset": args.preset,
            "seed": args.seed,
            "budget": args.budget,
            "summaries": "16 quantiles of f_B, levels 0.03..0.97 (as surrogate_helium)",
            "replicates_at_posterior_mean": args.replicates,
            "design_sites": len(sites),
            "replicates_per_design_site": args.design_replicates,
            "coordinates": "the emulator's standardised outputs",
        },
        "surrogate": {
            "simulations": int(result.num_simulations),
            "validated": bool(result.diagnostics.get("validated", False)),
            "noise_model_setting": algorithm.settings["noise_model"],
            "noise_sd_varies_with_theta": heteroscedastic,
            "posterior_mean": centre.tolist(),
            "posterior_sd": draws.std(axis=0).tolist(),
        },
        "noise_sd_model_over_posterior_mean": (noise_sd / sd_centre).tolist(),
        "noise_sd_design_sites_over_posterior_mean": [(np.sqrt(np.diag(c)) / sd_centre).tolist() for c in cov_sites],
        "mean_abs_correlation": {
            "model": _mean_abs_corr(cov_model),
            "posterior_mean": _mean_abs_corr(cov_centre),
            "design_sites": [_mean_abs_corr(c) for c in cov_sites],
        },
        "laplace_sd": {
            "model_covariance": laplace_sd(cov_model),
            "empirical_at_posterior_mean": laplace_sd(cov_centre),
            "model_sd_empirical_correlation": laplace_sd(np.outer(noise_sd, noise_sd) * corr_centre),
            "empirical_sd_model_correlation": laplace_sd(np.outer(sd_centre, sd_centre) * corr_model),
        },
        "grid": {
            "points_per_parameter": args.grid,
            "half_width_in_surrogate_sd": args.grid_width,
            "replicates_per_point": reps,
            "simulations": int(len(grid) * reps),
            "local_covariance_neighbourhood": 2 * args.neighbourhood + 1,
            "low": grid.min(axis=0).tolist(),
            "high": grid.max(axis=0).tolist(),
            "posteriors": decomposition,
            "emulated_mean_rms_error_in_noise_sd": mean_error.tolist(),
        },
    }
    print(
        f"surrogate sd {np.round(draws.std(axis=0), 5)}; Laplace sd, model covariance "
        f"{np.round(entry['laplace_sd']['model_covariance'], 5)}, empirical at the posterior mean "
        f"{np.round(entry['laplace_sd']['empirical_at_posterior_mean'], 5)}",
        flush=True,
    )
    write_result("surrogate_helium_noise", entry, quick=args.quick)
    return entry


if __name__ == "__main__":
    main()
