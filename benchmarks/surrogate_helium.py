"""Helium, CPU preset: the GP surrogate against APMCABC, like for like, over five data sets.

Each data set is the Table 1 observed f_B series of one seed (``--seeds``, default 0-4).  The GP
needs summaries of fixed shape, so every run here sees the 16 quantiles of f_B (levels
0.03 .. 0.97); Table 1's KL distance on the series is not used.  The common target is the ABC
posterior of the Euclidean distance on those quantiles, measured by a long APMCABC **reference**
(by default 1500 particles, 8 generations).  Against it, on the same data:

- APMCABC at Table 1's settings (500 particles, 6 generations, alpha 0.1: 2750 simulations);
- APMCABC at each surrogate budget (``--budgets``, default 100 and 200): alpha 0.5, four
  generations, as many particles as the budget allows;
- the surrogate in ABC mode (``mode="abc"``, the same distance on the same summaries: the same
  target) and in synthetic-likelihood mode (a Gaussian likelihood of the quantiles: another
  target, so it is also measured against its exact version on a grid).

Accuracy is the energy distance to the reference draws, coordinates divided by the prior widths
(Szekely & Rizzo; 0 for equal laws), averaged over ``--ed-repeats`` subsample pairs with its
standard error; alongside, means and sds in reference sds.  The summary gives, per run kind,
the mean over data sets with its standard error, and per budget and mode the number of data sets
in which the validated surrogate is as close to the reference as APMCABC at the same budget and
at 2750 simulations (within two combined standard errors).  The reference is itself an ABC run
with a finite ESS and threshold: its own error is the floor of every distance.

Usage::

    python -m benchmarks.surrogate_helium                 # its cost is recorded in the JSON
    python -m benchmarks.surrogate_helium --quick         # plumbing check: results/quick/
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

import jaxabc
from benchmarks._common import write_result
from benchmarks._helium_quantiles import LEVELS, quantile_problem
from md import helium

ROOT = Path(__file__).resolve().parents[1]


def energy_distance(a: np.ndarray, b: np.ndarray, scale: np.ndarray, num: int, rng: np.random.Generator) -> float:
    """Energy distance between two samples (rows), from ``num`` rows of each, coordinates / ``scale``."""
    a = a[rng.choice(len(a), min(num, len(a)), replace=False)] / scale
    b = b[rng.choice(len(b), min(num, len(b)), replace=False)] / scale

    def mean_dist(x: np.ndarray, y: np.ndarray) -> float:
        return float(np.mean(np.linalg.norm(x[:, None] - y[None], axis=-1)))

    return 2 * mean_dist(a, b) - mean_dist(a, a) - mean_dist(b, b)


def accuracy(draws: np.ndarray, reference: np.ndarray, scale: np.ndarray, args, seed: int) -> dict:
    """Energy distance to the reference (mean and SE over repeats) and moments in reference sd."""
    rng = np.random.default_rng(seed)
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
    simulate, prior, observed, particles: int, steps: int, seed: int, distance: str, alpha: float = 0.1
) -> tuple[jaxabc.ABCResult, float]:
    """APMCABC with Table 1's acceptance cutoff 0.03 (and its alpha 0.1 by default)."""
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
        alpha=alpha,
        acceptance_cutoff=0.03,
    )
    return result, time.perf_counter() - t0


#: APMCABC's alpha at a surrogate's budget: Table 1's 0.1 would keep 2-8 of the 16-80 particles
#: such budgets allow.
BUDGET_ALPHA = 0.5


def _budget_apmcabc(budget: int) -> tuple[int, int]:
    """APMCABC (alpha :data:`BUDGET_ALPHA`) particles and generations whose simulations stay
    within ``budget``: four generations, ``N + 3 (1 - alpha) N <= budget``."""
    return max(10, int(budget / (1 + 3 * (1 - BUDGET_ALPHA)))), 4


def _surrogate_row(result: jaxabc.ABCResult, budget: int, mode: str, seconds: float, truth, against) -> dict:
    diag = result.diagnostics
    draws = np.asarray(result.resample(len(result.particles), seed=0))
    return {
        "budget": budget,
        "mode": mode,
        "simulations": int(result.num_simulations),
        "failed_simulations": int(diag.get("num_failed_simulations", 0)),
        "wall_time_s": seconds,
        "stop_reason": result.stop_reason,
        "validated": bool(diag.get("validated", False)),
        "holdout_coverage_95": diag.get("holdout_coverage_95"),
        "effective_sample_size": float(result.effective_sample_size()),
        "d_E": float(np.linalg.norm(draws.mean(axis=0) - truth)),
        "against": {name: against(draws, name) for name in ("quantiles", "synthetic_likelihood")},
    }


def one_seed(args, seed: int) -> dict:
    """Every run of one data set (``seed``): references, APMCABC at Table 1 settings and at the
    surrogate's budgets, the surrogate in both modes at each budget."""
    simulate_quantiles, prior, _, observed_q, _ = quantile_problem(args.preset, seed)
    truth = np.asarray(helium.TRUE_THETA)
    scale = np.asarray(prior.high) - np.asarray(prior.low)
    ref_draws: dict[str, np.ndarray] = {}

    def against(draws: np.ndarray, name: str) -> dict:
        return accuracy(draws, ref_draws[name], scale, args, seed)

    # The like-for-like target: the ABC posterior of the Euclidean distance on the 16 quantiles,
    # measured by a long APMCABC run (seeds differ so that no two runs share simulation keys).
    ref, ref_seconds = apmcabc(
        simulate_quantiles,
        prior,
        observed_q,
        args.reference_particles,
        args.reference_steps,
        1010 + seed,
        "euclidean",
    )
    ref_draws["quantiles"] = ref.resample(max(4 * args.ed_num, 4000), seed=seed)
    references = {
        "quantiles": {
            "summaries": "Euclidean distance on the surrogate's 16 quantiles (ABC posterior)",
            "num_particles": args.reference_particles,
            "num_steps": args.reference_steps,
            "simulations": int(ref.num_simulations),
            "wall_time_s": ref_seconds,
            "effective_sample_size": float(ref.effective_sample_size()),
            "threshold_final": float(ref.thresholds[-1]),
            "mean": ref_draws["quantiles"].mean(axis=0).tolist(),
            "sd": ref_draws["quantiles"].std(axis=0).tolist(),
            "correlation": float(np.corrcoef(ref_draws["quantiles"].T)[0, 1]),
            "d_E": float(np.linalg.norm(ref.bayes_estimate() - truth)),
        }
    }
    # The synthetic-likelihood mode's own exact target, on a grid.
    ref_draws["synthetic_likelihood"], references["synthetic_likelihood"] = synthetic_likelihood_reference(
        simulate_quantiles,
        observed_q,
        prior,
        np.asarray(references["quantiles"]["mean"]),
        np.asarray(references["quantiles"]["sd"]),
        args,
        jax.random.key(5000 + seed),
    )

    def apmc_row(particles: int, steps: int, run_seed: int, label: str, alpha: float = 0.1) -> dict:
        base, seconds = apmcabc(simulate_quantiles, prior, observed_q, particles, steps, run_seed, "euclidean", alpha)
        draws = base.resample(args.draws, seed=seed)
        return {
            "label": label,
            "alpha": alpha,
            "num_particles": particles,
            "num_steps": steps,
            "simulations": int(base.num_simulations),
            "wall_time_s": seconds,
            "effective_sample_size": float(base.effective_sample_size()),
            "threshold_final": float(base.thresholds[-1]),
            "d_E": float(np.linalg.norm(base.bayes_estimate() - truth)),
            "against": {"quantiles": against(draws, "quantiles")},
        }

    apmc = [apmc_row(args.apmc_particles, args.apmc_steps, 100 + seed, "Table 1 settings")]
    for budget in args.budgets:
        n, steps = _budget_apmcabc(budget)
        row = apmc_row(n, steps, 200 + 10 * budget + seed, f"budget {budget}", BUDGET_ALPHA)
        apmc.append({"budget": budget, **row})

    rows = []
    for budget in args.budgets:
        for mode in args.modes:
            t0 = time.perf_counter()
            extra = {"mode": "abc", "abc_distance": "euclidean"} if mode == "abc" else {}
            result = jaxabc.run(
                "surrogate",
                simulate_quantiles,
                prior,
                observed_q,
                max_simulations=budget,
                num_particles=args.draws,
                seed=seed,
                **extra,
            )
            rows.append(_surrogate_row(result, budget, mode, time.perf_counter() - t0, truth, against))
            r = rows[-1]
            print(
                f"seed {seed} surrogate ({mode}) budget {budget}: {r['simulations']} simulations, validated "
                f"{r['validated']}, energy distance to the ABC reference "
                f"{r['against']['quantiles']['energy_distance']:.4f}"
                f", to the grid SL posterior {r['against']['synthetic_likelihood']['energy_distance']:.4f}"
                f", {r['wall_time_s']:.0f} s",
                flush=True,
            )
    for a in apmc:
        print(
            f"seed {seed} APMCABC {a['label']}: {a['simulations']} simulations, energy distance "
            f"{a['against']['quantiles']['energy_distance']:.4f}",
            flush=True,
        )
    return {"seed": seed, "references": references, "apmcabc": apmc, "surrogate": rows}


def _mean_se(values: list[float]) -> list[float | None]:
    v = np.asarray(values, float)
    return [float(v.mean()), float(v.std(ddof=1) / np.sqrt(len(v))) if len(v) > 1 else None]


def over_seeds(per_seed: list[dict], budgets: list[int], modes: list[str]) -> dict:
    """Per run kind: the energy distance to the ABC reference (mean and s.e. over data sets),
    simulations, validated runs; and, like for like, in how many data sets the surrogate's ABC
    mode at each budget is at least as close to the reference as APMCABC at the same budget and
    at Table 1's 2750 simulations (each within two combined standard errors)."""

    def ed(acc: dict) -> tuple[float, float]:
        return acc["energy_distance"], acc["energy_distance_se"] or 0.0

    kinds: dict[str, list[dict]] = {}
    for s in per_seed:
        for a in s["apmcabc"]:
            kinds.setdefault(f"APMCABC, {a['label']}", []).append(a)
        for r in s["surrogate"]:
            kinds.setdefault(f"surrogate ({r['mode']}), budget {r['budget']}", []).append(r)
    table = {
        k: {
            "data_sets": len(v),
            "energy_distance": _mean_se([ed(r["against"]["quantiles"])[0] for r in v]),
            "simulations": _mean_se([r["simulations"] for r in v]),
            "validated": sum(bool(r.get("validated", True)) for r in v),
            "effective_sample_size": _mean_se([r["effective_sample_size"] for r in v]),
        }
        for k, v in kinds.items()
    }
    like: dict[str, Any] = {}
    for budget in budgets:
        for mode in modes:
            at_most_budget = at_most_table1 = 0
            for s in per_seed:
                r = next(x for x in s["surrogate"] if x["budget"] == budget and x["mode"] == mode)
                same = next(a for a in s["apmcabc"] if a.get("budget") == budget)
                t1 = s["apmcabc"][0]
                e, es = ed(r["against"]["quantiles"])
                for peer, counter in ((same, "b"), (t1, "t")):
                    pe, ps = ed(peer["against"]["quantiles"])
                    if r["validated"] and e <= pe + 2 * np.hypot(es, ps):
                        if counter == "b":
                            at_most_budget += 1
                        else:
                            at_most_table1 += 1
            like[f"{mode}:{budget}"] = {
                "data_sets": len(per_seed),
                "as_close_as_apmcabc_same_budget": at_most_budget,
                "as_close_as_apmcabc_table1": at_most_table1,
            }
    return {"runs": table, "like_for_like": like}


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--budgets", type=int, nargs="+", default=[100, 200])
    parser.add_argument(
        "--modes", nargs="+", default=["abc", "synthetic_likelihood"], choices=["abc", "synthetic_likelihood"]
    )
    parser.add_argument("--preset", default="cpu")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="data sets (Table 1 seeds)")
    parser.add_argument("--reference-particles", type=int, default=1500)
    parser.add_argument("--reference-steps", type=int, default=8)
    parser.add_argument("--apmc-particles", type=int, default=500)
    parser.add_argument("--apmc-steps", type=int, default=6)
    parser.add_argument("--draws", type=int, default=2000, help="posterior draws of every run")
    parser.add_argument("--ed-num", type=int, default=1000, help="rows per energy-distance subsample")
    parser.add_argument("--ed-repeats", type=int, default=10)
    parser.add_argument("--sl-coarse", type=int, default=16, help="coarse grid points per axis")
    parser.add_argument("--sl-coarse-reps", type=int, default=8, help="runs per coarse grid point")
    parser.add_argument("--sl-fine", type=int, default=30, help="fine grid points per axis")
    parser.add_argument("--sl-fine-reps", type=int, default=12, help="runs per fine grid point")
    parser.add_argument("--quick", action="store_true", help="small everything, one seed: results/quick/")
    args = parser.parse_args(argv)
    if args.quick:
        args.budgets, args.seeds, args.reference_particles, args.reference_steps = [60], [0], 200, 4
        args.apmc_particles, args.apmc_steps, args.draws, args.ed_num, args.ed_repeats = 100, 3, 1000, 300, 3
        args.sl_coarse, args.sl_coarse_reps, args.sl_fine, args.sl_fine_reps = 8, 4, 10, 6

    _, prior, _, _, _ = quantile_problem(args.preset, args.seeds[0])
    per_seed = [one_seed(args, seed) for seed in args.seeds]
    payload = {
        "description": (__doc__ or "").split("\n\n")[0],
        "setup": {
            "preset": args.preset,
            "seeds": args.seeds,
            "truth": np.asarray(helium.TRUE_THETA).tolist(),
            "prior_low": np.asarray(prior.low).tolist(),
            "prior_high": np.asarray(prior.high).tolist(),
            "surrogate_summaries": f"{len(LEVELS)} quantiles of f_B, levels {LEVELS[0]:.2f}..{LEVELS[-1]:.2f}",
            "budgets": args.budgets,
            "modes": args.modes,
            "budget_apmcabc": {str(b): list(_budget_apmcabc(b)) for b in args.budgets},
            "draws": args.draws,
            "energy_distance": {"rows": args.ed_num, "repeats": args.ed_repeats, "scale": "prior widths"},
        },
        "per_seed": per_seed,
        "summary": over_seeds(per_seed, args.budgets, args.modes),
    }
    path = write_result("surrogate_helium", payload, quick=args.quick)
    print(f"wrote {path}: {payload['summary']['like_for_like']}")
    return payload


if __name__ == "__main__":
    main()
