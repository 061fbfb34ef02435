"""Which helium set-up lets the KL distance of f_B series tell parameters apart, cheaply?

For each candidate preset (atoms, pressure, time step, equilibration, production length, sampling
interval) this script

1. makes an 'observed' series at the truth (0.2556 nm, 0.141 zJ) with a run
   ``observed_factor`` times longer than a simulation (as the paper: 20 ns vs 5 ns),
2. simulates ``--seeds`` series at the truth with independent keys: their KL distances to the
   observed series are the seed noise (what the distance of a perfect parameter looks like),
3. simulates one series at every point of a (sigma, epsilon) grid spanning the prior plus a few
   points near the truth, and records its KL distance to the observed series,
4. times the batch (after compilation) to give seconds per simulation on this machine.

A grid point is *separated* when its KL exceeds the 95th percentile of the seed noise.  Writes
``benchmarks/results/helium_identifiability.json``.

Run: ``nice -n 5 python -m benchmarks.helium_identifiability`` (about 10 minutes on 2 cores for
the default candidates; ``--quick`` for a 2-minute smoke run).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks._common import QUICK_RESULTS, write_result
from md import helium

try:  # the core's definition; a local copy with the same definition until it exists
    from jaxabc.distances import kl_divergence
except ImportError:  # pragma: no cover

    def kl_divergence(x, y, num_grid=100):  # type: ignore[no-redef]
        x, y = jnp.ravel(x), jnp.ravel(y)
        grid = jnp.linspace(jnp.minimum(x.min(), y.min()), jnp.maximum(x.max(), y.max()), num_grid)

        def kde(s):
            h = jnp.std(s, ddof=1) * s.shape[0] ** -0.2
            z = (grid[:, None] - s[None, :]) / h
            return jnp.mean(jnp.exp(-0.5 * z**2), 1) / (h * jnp.sqrt(2 * jnp.pi))

        p, q = kde(x), kde(y)
        p, q = p / p.sum(), jnp.maximum(q / q.sum(), jnp.finfo(q.dtype).tiny)
        return jnp.maximum(jnp.sum(jnp.where(p > 0, p * (jnp.log(p) - jnp.log(q)), 0.0)), 0.0)


RESULTS = Path(__file__).resolve().parent / "results" / "helium_identifiability.json"

#: Candidate presets: overrides of the ``cpu`` preset (the paper preset is far too slow here).
CANDIDATES: dict[str, dict] = {
    "64at_100atm_10ps_dt4fs_every0.1ps": {"num_atoms": 64},
    "64at_100atm_10ps_dt4fs_every0.1ps_tauP2ps": {"num_atoms": 64, "tau_p_ps": 2.0},
    "32at_100atm_10ps_dt4fs_every0.1ps": {"num_atoms": 32},
    "32at_100atm_20ps_dt4fs_every0.1ps": {"num_atoms": 32, "production_ps": 20.0},
    "16at_100atm_10ps_dt4fs_every0.1ps": {"num_atoms": 16},
    "64at_100atm_20ps_dt4fs_every0.1ps": {"num_atoms": 64, "production_ps": 20.0},
    "64at_100atm_10ps_dt4fs_every0.5ps": {"num_atoms": 64, "sample_every_ps": 0.5},
    "125at_100atm_10ps_dt4fs_every0.1ps": {"num_atoms": 125},
    "64at_10atm_10ps_dt4fs_every0.1ps": {"num_atoms": 64, "pressure_atm": 10.0},
    "64at_1atm_10ps_dt4fs_every0.1ps": {"num_atoms": 64, "pressure_atm": 1.0},
}

SIGMAS = (0.15, 0.2, 0.2556, 0.3, 0.4, 0.6, 0.8)
EPSILONS = (0.05, 0.141, 0.3, 1.0)
NEAR_TRUTH = ((0.23, 0.141), (0.28, 0.141), (0.2556, 0.08), (0.2556, 0.25))


def evaluate(name: str, overrides: dict, num_seeds: int, num_observed: int, key: jax.Array) -> dict:
    """Run one candidate and return its record."""
    truth = np.asarray(helium.TRUE_THETA, np.float32)
    grid = [(s, e) for s in SIGMAS for e in EPSILONS] + list(NEAR_TRUTH)
    thetas = np.asarray([truth] * num_seeds + grid, np.float32)
    batch_size = len(thetas)
    preset = helium.get_preset("cpu", batch_size=batch_size, **overrides)
    k_obs, k_sim = jax.random.split(key)
    t0 = time.perf_counter()
    observed = [helium.observed_series(k, preset) for k in jax.random.split(k_obs, num_observed)]
    t_obs = (time.perf_counter() - t0) / num_observed
    simulate_batch = helium.make_batch_simulator(preset)
    keys = jax.random.split(k_sim, len(thetas))
    t0 = time.perf_counter()
    f_b, ok = simulate_batch(keys, thetas)
    t_first = time.perf_counter() - t0
    # Time a second, already compiled batch with fresh keys (same shape: no recompilation).
    t0 = time.perf_counter()
    simulate_batch(jax.random.split(jax.random.fold_in(k_sim, 1), len(thetas)), thetas)
    t_run = time.perf_counter() - t0
    # "Clearly wrong": more than 10% of the prior width away from the truth in either parameter;
    # "near": the four points within 10% (sigma 0.23 / 0.28 nm, epsilon 0.08 / 0.25 zJ).
    width = np.asarray(helium.PRIOR_HIGH) - np.asarray(helium.PRIOR_LOW)
    offsets = np.abs(np.asarray(grid) - truth) / width
    clearly_wrong = offsets.max(axis=1) > 0.1
    near = ~clearly_wrong & (offsets.max(axis=1) > 0.0)
    per_observed = []
    for obs in observed:
        kl = np.asarray(jax.vmap(lambda y, o=obs: kl_divergence(jnp.asarray(o), y))(jnp.asarray(f_b)))
        kl = np.where(ok, kl, np.inf)
        seed_kl, grid_kl = kl[:num_seeds], kl[num_seeds:]
        q95 = float(np.percentile(seed_kl, 95))
        separated = grid_kl > q95
        per_observed.append(
            {
                "observed_mean": float(np.mean(obs)),
                "observed_std": float(np.std(obs)),
                "seed_kl": seed_kl.tolist(),
                "seed_kl_median": float(np.median(seed_kl)),
                "seed_kl_q95": q95,
                "grid_kl": grid_kl.tolist(),
                "fraction_clearly_wrong_separated": float(np.mean(separated[clearly_wrong])),
                "fraction_near_truth_separated": float(np.mean(separated[near])),
                "min_kl_clearly_wrong": float(np.min(grid_kl[clearly_wrong])),
            }
        )

    def avg(field: str) -> float:
        return float(np.mean([r[field] for r in per_observed]))

    return {
        "name": name,
        "overrides": overrides,
        "preset": dict(vars(preset)),
        "num_samples": preset.num_samples,
        "steps_per_simulation": round((preset.equilibration_ps + preset.production_ps) / preset.dt_ps),
        "seconds_per_simulation_batched": t_run / len(thetas),
        "compile_and_run_seconds": t_first,
        "observed_run_seconds": t_obs,
        "grid": [
            {
                "sigma_nm": float(s),
                "epsilon_zj": float(e),
                "ok": bool(o),
                "f_b_mean": float(np.nanmean(f)) if o else None,
                "kl_mean_over_observed": float(np.mean([r["grid_kl"][i] for r in per_observed])),
            }
            for i, ((s, e), o, f) in enumerate(zip(grid, ok[num_seeds:], f_b[num_seeds:], strict=True))
        ],
        "truth_f_b_mean": float(np.nanmean(f_b[:num_seeds])),
        "per_observed": per_observed,
        "seed_kl_median": avg("seed_kl_median"),
        "seed_kl_q95": avg("seed_kl_q95"),
        "fraction_clearly_wrong_separated": avg("fraction_clearly_wrong_separated"),
        "fraction_near_truth_separated": avg("fraction_near_truth_separated"),
        "min_kl_clearly_wrong": avg("min_kl_clearly_wrong"),
        "num_failed": int((~ok).sum()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=24, help="simulations at the truth")
    parser.add_argument("--observed", type=int, default=3, help="independent observed series")
    parser.add_argument("--only", nargs="*", help="candidate names to run (default all)")
    parser.add_argument("--quick", action="store_true", help="first two candidates, 6 seeds, written to results/quick/")
    parser.add_argument(
        "--output",
        type=Path,
        default=None,
        help="default: results/helium_identifiability.json (results/quick/ with --quick)",
    )
    args = parser.parse_args()
    if args.output is None:
        args.output = QUICK_RESULTS / RESULTS.name if args.quick else RESULTS
    names = list(CANDIDATES)
    if args.only:
        names = [n for n in names if n in args.only]
    if args.quick:
        names, args.seeds, args.observed = names[:2], 6, 1
    records = []
    existing = {}
    if args.output.exists():  # keep earlier candidates when re-running a subset
        existing = {r["name"]: r for r in json.loads(args.output.read_text())["candidates"]}
    for i, name in enumerate(names):
        rec = evaluate(name, CANDIDATES[name], args.seeds, args.observed, jax.random.PRNGKey(100 + i))
        print(
            f"{name:40s} seed KL median {rec['seed_kl_median']:.3f} q95 {rec['seed_kl_q95']:.3f} | "
            f"separated: clearly wrong {rec['fraction_clearly_wrong_separated']:.2f}, "
            f"near {rec['fraction_near_truth_separated']:.2f} | min wrong KL "
            f"{rec['min_kl_clearly_wrong']:.3f} | "
            f"{rec['seconds_per_simulation_batched']:.3f} s/sim",
            flush=True,
        )
        existing[name] = rec
        records = list(existing.values())
        write_result(
            args.output,
            {
                "description": __doc__,
                "sigmas": SIGMAS,
                "epsilons": EPSILONS,
                "near_truth": NEAR_TRUTH,
                "truth": helium.TRUE_THETA,
                "candidates": records,
            },
        )


if __name__ == "__main__":
    main()
