"""Helium, CPU preset: how many simulations the GP surrogate needs to match APMCABC's accuracy.

One observed f_B series (the Table 1 data of ``helium_table1.py``'s seed) is calibrated in the
same run.  The GP needs summaries of fixed shape, so the surrogate (``jaxabc.run("surrogate",
...)``, synthetic likelihood, budgets ``--budgets``) sees 16 quantiles of f_B (levels
0.03 .. 0.97) where Table 1 uses the KL distance on the series.  These are two targets, and each
gets, with the same APMCABC settings:

- a long **reference** posterior (by default 1500 particles, 8 generations);
- **APMCABC at the Table 1 settings** (500 particles, 6 generations: 2750 simulations), the
  accuracy to match.

Accuracy is the energy distance to a target's reference draws, coordinates divided by the prior
widths (Szekely & Rizzo; 0 for equal distributions), averaged over ``--ed-repeats`` subsample
pairs with its standard error; alongside, mean and sd of each parameter in units of the reference
sd.  The ``quantiles`` target is the like-for-like comparison (same summaries); the ``kl`` one
says how far the quantile summaries take the surrogate from Table 1's posterior.  The JSON's
``summary`` gives, per target, the smallest budget whose energy distance is at or below
APMCABC's (within two combined standard errors) and the ratio of simulations (goal: >= 10).
A reference is itself an ABC run with a finite ESS and threshold: its own error is the floor of
every distance.

Usage::

    python -m benchmarks.surrogate_helium                 # its cost is recorded in the JSON
    python -m benchmarks.surrogate_helium --quick         # plumbing check: results/quick/
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxabc
from benchmarks._common import write_result
from md import helium
from md.helium_calibration import make_model

ROOT = Path(__file__).resolve().parents[1]

LEVELS = np.linspace(0.03, 0.97, 16)


def quantile_problem(preset: str, seed: int):
    """The surrogate's helium problem: ``(simulate_quantiles, prior, observed series, observed
    quantiles, simulate)``, the Table 1 data of ``seed`` summarised by the 16 quantiles of f_B."""
    simulate, prior = make_model(preset)
    observed = helium.observed_series(jax.random.key(10_000 + seed), preset)
    levels = jnp.asarray(LEVELS, jnp.float32)

    def simulate_quantiles(key, theta):
        return jnp.quantile(simulate(key, theta), levels)

    return simulate_quantiles, prior, observed, np.quantile(np.asarray(observed), LEVELS), simulate


def energy_distance(a: np.ndarray, b: np.ndarray, scale: np.ndarray, num: int, rng: np.random.Generator) -> float:
    """Energy distance between two samples (rows), from ``num`` rows of each, coordinates / ``scale``."""
    a = a[rng.choice(len(a), min(num, len(a)), replace=False)] / scale
    b = b[rng.choice(len(b), min(num, len(b)), replace=False)] / scale

    def mean_dist(x: np.ndarray, y: np.ndarray) -> float:
        return float(np.mean(np.linalg.norm(x[:, None] - y[None], axis=-1)))

    return 2 * mean_dist(a, b) - mean_dist(a, a) - mean_dist(b, b)


def accuracy(draws: np.ndarray, reference: np.ndarray, scale: np.ndarray, args) -> dict:
    """Energy distance to the reference (mean and SE over repeats) and moments in reference sd."""
    rng = np.random.default_rng(args.seed)
    eds = [energy_distance(draws, reference, scale, args.ed_num, rng) for _ in range(args.ed_repeats)]
    ref_mean, ref_sd = reference.mean(axis=0), reference.std(axis=0)
    return {
        "energy_distance": float(np.mean(eds)),
        "energy_distance_se": float(np.std(eds, ddof=1) / np.sqrt(len(eds))) if len(eds) > 1 else None,
        "mean": draws.mean(axis=0).tolist(),
        "sd": draws.std(axis=0).tolist(),
        "mean_error_in_ref_sd": ((draws.mean(axis=0) - ref_mean) / ref_sd).tolist(),
        "sd_ratio_to_ref": (draws.std(axis=0) / ref_sd).tolist(),
        "correlation": float(np.corrcoef(draws.T)[0, 1]),
    }


def _grid_loglik(simulate, observed, low, high, size: int, reps: int, key, chunk: int = 4096):
    """Gaussian synthetic log-likelihood on a ``size x size`` grid over the box [low, high]: the
    mean from ``reps`` runs per point, one covariance pooled over the points (inflated by
    1 + 1/reps for the mean's own error).  Returns (cell centres (size^2, 2), loglik, cell widths)."""
    edges = [np.linspace(lo, hi, size + 1) for lo, hi in zip(low, high, strict=True)]
    centres = [0.5 * (e[1:] + e[:-1]) for e in edges]
    grid = np.stack(np.meshgrid(*centres, indexing="ij"), -1).reshape(-1, 2)
    thetas = np.repeat(grid, reps, axis=0).astype(np.float32)
    keys = jax.random.split(key, len(thetas))
    batched = jax.jit(jax.vmap(simulate))
    out = np.concatenate(
        [np.asarray(batched(keys[i : i + chunk], thetas[i : i + chunk])) for i in range(0, len(thetas), chunk)]
    ).reshape(len(grid), reps, -1)
    mean = out.mean(axis=1)
    resid = (out - mean[:, None]).reshape(-1, out.shape[-1])
    cov = resid.T @ resid / (len(grid) * (reps - 1)) * (1.0 + 1.0 / reps)
    diff = np.asarray(observed, np.float64) - mean
    chol = np.linalg.cholesky(cov)
    z = np.linalg.solve(chol, diff.T)
    loglik = -0.5 * np.sum(z * z, axis=0)
    return grid, loglik, np.array([e[1] - e[0] for e in edges])


def synthetic_likelihood_reference(simulate, observed, prior, centre, sd, args, key) -> tuple[np.ndarray, dict]:
    """Draws from the exact synthetic-likelihood posterior of the summaries (the surrogate's own
    target, uniform prior): a coarse grid over ``centre +- 6 sd`` locates it, a fine grid over
    its mean +- 4.5 of its sd measures it; draws are grid cells by weight, jittered in the cell."""
    low, high = np.asarray(prior.low, np.float64), np.asarray(prior.high, np.float64)
    k1, k2, k3 = jax.random.split(key, 3)
    lo, hi = np.maximum(centre - 6 * sd, low), np.minimum(centre + 6 * sd, high)
    grid, ll, _ = _grid_loglik(simulate, observed, lo, hi, args.sl_coarse, args.sl_coarse_reps, k1)
    w = np.exp(ll - ll.max())
    w /= w.sum()
    m1 = w @ grid
    s1 = np.sqrt(w @ (grid - m1) ** 2)
    lo, hi = np.maximum(m1 - 4.5 * s1, low), np.minimum(m1 + 4.5 * s1, high)
    grid, ll, width = _grid_loglik(simulate, observed, lo, hi, args.sl_fine, args.sl_fine_reps, k2)
    w = np.exp(ll - ll.max())
    w /= w.sum()
    rng = np.random.default_rng(int(jax.random.randint(k3, (), 0, 2**31 - 1)))
    cells = rng.choice(len(grid), size=max(4 * args.ed_num, 4000), p=w)
    draws = grid[cells] + (rng.random((len(cells), 2)) - 0.5) * width
    edge = max(
        w.reshape(args.sl_fine, args.sl_fine)[[0, -1], :].sum(), w.reshape(args.sl_fine, args.sl_fine)[:, [0, -1]].sum()
    )
    info = {
        "summaries": "Gaussian synthetic likelihood of the 16 quantiles (the surrogate's target), on a grid",
        "simulations": int(args.sl_coarse**2 * args.sl_coarse_reps + args.sl_fine**2 * args.sl_fine_reps),
        "grid": {
            "coarse": [args.sl_coarse, args.sl_coarse_reps],
            "fine": [args.sl_fine, args.sl_fine_reps],
            "fine_box_low": lo.tolist(),
            "fine_box_high": hi.tolist(),
            "cell_width_in_sd": (width / draws.std(axis=0)).tolist(),
            "weight_on_box_edge": float(edge),
        },
        "mean": draws.mean(axis=0).tolist(),
        "sd": draws.std(axis=0).tolist(),
        "correlation": float(np.corrcoef(draws.T)[0, 1]),
    }
    return draws, info


def apmcabc(
    simulate, prior, observed, particles: int, steps: int, seed: int, distance: str
) -> tuple[jaxabc.ABCResult, float]:
    """APMCABC at the Table 1 settings (alpha 0.1, acceptance cutoff 0.03)."""
    t0 = time.perf_counter()
    result = jaxabc.run(
        "apmcabc",
        simulate,
        prior,
        observed,
        num_particles=particles,
        num_steps=steps,
        distance=distance,
        seed=seed,
        alpha=0.1,
        acceptance_cutoff=0.03,
    )
    return result, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--budgets", type=int, nargs="+", default=[60, 100, 150, 200, 300])
    parser.add_argument("--preset", default="cpu")
    parser.add_argument("--seed", type=int, default=0, help="the Table 1 seed: data and inference")
    parser.add_argument("--reference-particles", type=int, default=1500)
    parser.add_argument("--reference-steps", type=int, default=8)
    parser.add_argument("--apmc-particles", type=int, default=500)
    parser.add_argument("--apmc-steps", type=int, default=6)
    parser.add_argument("--draws", type=int, default=2000, help="surrogate posterior draws")
    parser.add_argument("--ed-num", type=int, default=1000, help="rows per energy-distance subsample")
    parser.add_argument("--ed-repeats", type=int, default=10)
    parser.add_argument("--sl-coarse", type=int, default=16, help="coarse grid points per axis")
    parser.add_argument("--sl-coarse-reps", type=int, default=8, help="runs per coarse grid point")
    parser.add_argument("--sl-fine", type=int, default=30, help="fine grid points per axis")
    parser.add_argument("--sl-fine-reps", type=int, default=12, help="runs per fine grid point")
    parser.add_argument("--quick", action="store_true", help="small everything: results/quick/")
    args = parser.parse_args(argv)
    if args.quick:
        args.budgets, args.reference_particles, args.reference_steps = [60], 200, 4
        args.apmc_particles, args.apmc_steps, args.draws, args.ed_num, args.ed_repeats = 100, 3, 1000, 300, 3
        args.sl_coarse, args.sl_coarse_reps, args.sl_fine, args.sl_fine_reps = 8, 4, 10, 6

    simulate_quantiles, prior, observed, observed_q, simulate = quantile_problem(args.preset, args.seed)
    truth = np.asarray(helium.TRUE_THETA)
    scale = np.asarray(prior.high) - np.asarray(prior.low)

    # Each target (summaries + distance) gets its own long reference and its own Table-1-sized
    # APMCABC run; seeds differ so that no two runs share their simulation keys.
    targets = {
        "kl": (simulate, observed, "kl", "KL distance on the f_B series (Table 1)"),
        "quantiles": (
            simulate_quantiles,
            observed_q,
            "euclidean",
            "Euclidean distance on the surrogate's 16 quantiles",
        ),
    }
    references, ref_draws, base_rows = {}, {}, {}
    for i, (name, (sim, obs, distance, label)) in enumerate(targets.items()):
        ref, ref_seconds = apmcabc(
            sim, prior, obs, args.reference_particles, args.reference_steps, 1000 + 10 * i + args.seed, distance
        )
        ref_draws[name] = ref.resample(max(4 * args.ed_num, 4000), seed=args.seed)
        references[name] = {
            "summaries": label,
            "num_particles": args.reference_particles,
            "num_steps": args.reference_steps,
            "simulations": int(ref.num_simulations),
            "wall_time_s": ref_seconds,
            "effective_sample_size": float(ref.effective_sample_size()),
            "threshold_final": float(ref.thresholds[-1]),
            "mean": ref_draws[name].mean(axis=0).tolist(),
            "sd": ref_draws[name].std(axis=0).tolist(),
            "correlation": float(np.corrcoef(ref_draws[name].T)[0, 1]),
            "d_E": float(np.linalg.norm(ref.bayes_estimate() - truth)),
        }
        base, base_seconds = apmcabc(
            sim, prior, obs, args.apmc_particles, args.apmc_steps, 100 * i + args.seed, distance
        )
        base_rows[name] = {
            "simulations": int(base.num_simulations),
            "wall_time_s": base_seconds,
            "effective_sample_size": float(base.effective_sample_size()),
            "threshold_final": float(base.thresholds[-1]),
            "d_E": float(np.linalg.norm(base.bayes_estimate() - truth)),
            **accuracy(base.resample(args.draws, seed=args.seed), ref_draws[name], scale, args),
        }
        print(
            f"{name}: reference {ref.num_simulations} simulations (ESS {ref.effective_sample_size():.0f}); "
            f"APMCABC {base.num_simulations} simulations, energy distance {base_rows[name]['energy_distance']:.4f}",
            flush=True,
        )

    # The surrogate's own target, exactly: its draws are measured against this one, as APMCABC's
    # against the long ABC run on the same summaries.
    ref_draws["synthetic_likelihood"], references["synthetic_likelihood"] = synthetic_likelihood_reference(
        simulate_quantiles,
        observed_q,
        prior,
        np.asarray(references["quantiles"]["mean"]),
        np.asarray(references["quantiles"]["sd"]),
        args,
        jax.random.key(5000 + args.seed),
    )
    print(
        f"synthetic-likelihood reference: {references['synthetic_likelihood']['simulations']} simulations", flush=True
    )

    rows = []
    for budget in args.budgets:
        t0 = time.perf_counter()
        result = jaxabc.run(
            "surrogate",
            simulate_quantiles,
            prior,
            observed_q,
            max_simulations=budget,
            num_particles=args.draws,
            seed=args.seed,
        )
        diag = result.diagnostics
        draws = np.asarray(result.particles)
        rows.append(
            {
                "budget": budget,
                "simulations": int(result.num_simulations),
                "failed_simulations": int(diag.get("num_failed_simulations", 0)),
                "wall_time_s": time.perf_counter() - t0,
                "stop_reason": result.stop_reason,
                "validated": bool(diag.get("validated", False)),
                "holdout_coverage_95": diag.get("holdout_coverage_95"),
                "effective_sample_size": float(result.effective_sample_size()),
                "d_E": float(np.linalg.norm(draws.mean(axis=0) - truth)),
                "against": {name: accuracy(draws, ref_draws[name], scale, args) for name in ref_draws},
            }
        )
        r = rows[-1]
        print(
            f"surrogate budget {budget}: {r['simulations']} simulations, validated {r['validated']}, "
            "energy distance "
            + ", ".join(f"{k} {v['energy_distance']:.4f}" for k, v in r["against"].items())
            + f", {r['wall_time_s']:.0f} s",
            flush=True,
        )

    def se(row: dict) -> float:
        return row["energy_distance_se"] or 0.0

    summary = {}
    for name in targets:
        base_row = base_rows[name]
        matching = [
            r
            for r in rows
            if r["validated"]
            and r["against"][name]["energy_distance"]
            <= base_row["energy_distance"] + 2 * np.hypot(se(r["against"][name]), se(base_row))
        ]
        best = min(matching, key=lambda r: r["simulations"]) if matching else None
        summary[name] = {
            "apmcabc_simulations": base_row["simulations"],
            "surrogate_simulations_to_match": None if best is None else best["simulations"],
            "simulation_ratio": None if best is None else base_row["simulations"] / best["simulations"],
        }
    # Each method against the exact version of its own target: APMCABC (quantiles) against the
    # long ABC run, the surrogate against the grid synthetic-likelihood posterior.
    base_row = base_rows["quantiles"]
    matching = [
        r
        for r in rows
        if r["validated"]
        and r["against"]["synthetic_likelihood"]["energy_distance"]
        <= base_row["energy_distance"] + 2 * np.hypot(se(r["against"]["synthetic_likelihood"]), se(base_row))
    ]
    best = min(matching, key=lambda r: r["simulations"]) if matching else None
    summary["own_targets"] = {
        "apmcabc_simulations": base_row["simulations"],
        "surrogate_simulations_to_match": None if best is None else best["simulations"],
        "simulation_ratio": None if best is None else base_row["simulations"] / best["simulations"],
        "criterion": "validated surrogate posterior whose energy distance to the grid synthetic-likelihood "
        "posterior is at most APMCABC's (quantiles) to the long ABC reference + 2 combined standard errors",
    }
    summary["goal_ratio"] = 10.0
    summary["criterion"] = (
        "validated surrogate posterior whose energy distance to the target's reference is at most that of "
        "APMCABC on the same target + 2 combined standard errors"
    )
    payload = {
        "description": (__doc__ or "").split("\n\n")[0],
        "setup": {
            "preset": args.preset,
            "seed": args.seed,
            "truth": truth.tolist(),
            "prior_low": np.asarray(prior.low).tolist(),
            "prior_high": np.asarray(prior.high).tolist(),
            "surrogate_summaries": f"{len(LEVELS)} quantiles of f_B, levels {LEVELS[0]:.2f}..{LEVELS[-1]:.2f}",
            "budgets": args.budgets,
            "draws": args.draws,
            "energy_distance": {"rows": args.ed_num, "repeats": args.ed_repeats, "scale": "prior widths"},
        },
        "references": references,
        "apmcabc": base_rows,
        "surrogate": rows,
        "summary": summary,
    }
    path = write_result("surrogate_helium", payload, quick=args.quick)
    print(f"wrote {path}: {summary}")
    return payload


if __name__ == "__main__":
    main()
