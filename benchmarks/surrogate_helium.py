"""Helium, CPU preset: how many simulations the surrogate needs against APMCABC's posterior.

SKETCH (not yet run for the record): the surrogate calibrates (sigma, epsilon) from the same
observed f_B series as ``helium_table1.py`` (seed 0), summarised by 16 quantiles, with budgets
of 50-300 real simulations; each posterior is compared with the saved APMCABC result
(``benchmarks/results/helium_table1_apmcabc.npz``, 300 particles) by the energy distance in
prior-scaled units and by the distance of its Bayes estimate from the truth (d_E).  The
issue's target is the APMCABC accuracy at >= 10x fewer simulations; a long reference
posterior (e.g. APMCABC with 5000 particles) should replace the saved run before any number
is quoted.

Usage::

    python benchmarks/surrogate_helium.py --budgets 50 100 200 300
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import RESULTS, write_result

import jaxabc
from jaxabc.executors import VmapExecutor, mark_nonfinite
from jaxabc.surrogate import build
from md import helium
from md.helium_calibration import make_model


def energy_distance(a: np.ndarray, b: np.ndarray, scale: np.ndarray, num: int = 1000, seed: int = 0) -> float:
    """Energy distance between two samples (rows), coordinates divided by ``scale``."""
    rng = np.random.default_rng(seed)
    a = a[rng.choice(len(a), min(num, len(a)), replace=False)] / scale
    b = b[rng.choice(len(b), min(num, len(b)), replace=False)] / scale

    def mean_dist(x, y):
        return float(np.mean(np.linalg.norm(x[:, None] - y[None], axis=-1)))

    return 2 * mean_dist(a, b) - mean_dist(a, a) - mean_dist(b, b)


def run_surrogate(algorithm, simulate, observed: np.ndarray, seed: int):
    """The host loop of the algorithm protocol (until ``jaxabc.run`` accepts algorithm objects)."""
    executor, root, state = VmapExecutor(), jax.random.key(seed), None
    num_sims = 0
    for iteration in range(1000):
        k_prop, k_sim, k_upd = jax.random.split(jax.random.fold_in(root, iteration), 3)
        proposal = algorithm.initial_proposal(k_prop) if state is None else algorithm.propose(k_prop, state)
        thetas = np.asarray(proposal.thetas)
        keys = np.asarray(jax.random.key_data(jax.random.split(k_sim, thetas.shape[0])))
        batch = mark_nonfinite(executor.map(simulate, keys, thetas))
        num_sims += thetas.shape[0]
        distances = np.zeros(thetas.shape[0])
        if state is None:
            state, info = algorithm.init(k_upd, proposal, distances, batch.summaries)
        else:
            state, info = algorithm.update(k_upd, state, proposal, distances, batch.summaries)
        if bool(info.stop):
            break
    return state, info, num_sims


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--budgets", type=int, nargs="+", default=[50, 100, 200, 300])
    parser.add_argument("--preset", default="cpu")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    series_simulate, prior = make_model(args.preset)
    # The observed f_B series is longer than a model run (as in the paper), and the emulator
    # needs summaries of one shape: both become 16 quantiles of f_B.
    levels = jnp.linspace(0.03, 0.97, 16)

    def simulate(key, theta):
        return jnp.quantile(series_simulate(key, theta), levels)

    observed = np.asarray(jnp.quantile(helium.observed_series(jax.random.key(10_000 + args.seed), args.preset), levels))
    reference = jaxabc.load(RESULTS / "helium_table1_apmcabc.npz")
    ref_draws = reference.resample(2000, seed=0)
    truth = np.asarray(helium.TRUE_THETA)
    scale = np.asarray(prior.high) - np.asarray(prior.low)
    rows = []
    for budget in args.budgets:
        t0 = time.perf_counter()
        algorithm = build(
            prior,
            2000,
            observed=observed,
            max_simulations=budget,
            num_initial=min(20, budget // 3),
            num_holdout=max(5, budget // 10),
        )
        state, info, num_sims = run_surrogate(algorithm, simulate, observed, args.seed)
        draws, _ = algorithm.posterior(state)
        diag = algorithm.finalize(state)["diagnostics"]
        rows.append(
            {
                "budget": budget,
                "simulations": num_sims,
                "wall_time_s": time.perf_counter() - t0,
                "stop_reason": algorithm.stop_reason(algorithm.settings, info),
                "validated": diag["validated"],
                "bayes_estimate": draws.mean(axis=0).tolist(),
                "d_E": float(np.linalg.norm(draws.mean(axis=0) - truth)),
                "energy_distance_to_apmcabc": energy_distance(draws, ref_draws, scale),
                "correlation": float(np.corrcoef(draws.T)[0, 1]),
            }
        )
        print(rows[-1], flush=True)
    path = write_result(
        "surrogate_helium",
        {
            "description": __doc__.split("\n\n")[0],
            "status": "sketch",
            "setup": {
                "preset": args.preset,
                "seed": args.seed,
                "budgets": args.budgets,
                "reference": "benchmarks/results/helium_table1_apmcabc.npz",
                "reference_simulations": int(reference.num_simulations),
            },
            "reference_d_E": float(np.linalg.norm(reference.bayes_estimate() - truth)),
            "rows": rows,
        },
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
