"""Cost of one APMCABC step without simulation: jaxabc (JAX) vs plain NumPy vs ABCpy 0.6.3.

One APMCABC step = resample ``N - N_alpha`` parents, perturb them with the truncated Gaussian
kernel, compute their importance weights against the ``N_alpha`` kept particles, merge, select
the alpha quantile, and re-estimate the covariance.  The simulator is excluded: JAX and NumPy
steps get synthetic distances; ABCpy runs with a Normal model whose simulation is negligible
next to its per-particle Python loop over the kernel mixture, and the step time is the
difference between a 2-step and a 1-step run.

Writes ``benchmarks/results/abc_overhead.json``.  Usage::

    python benchmarks/abc_overhead.py                     # N in {1000, 5000, 20000}, d in {2, 9}
    python benchmarks/abc_overhead.py --abcpy-python /path/to/venv/bin/python
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import write_result

import jaxabc
from jaxabc.algorithms import apmc


def jax_step_time(n: int, d: int, repeats: int) -> dict:
    prior = jaxabc.Uniform(np.full(d, -10.0), np.full(d, 10.0))
    algo = apmc.build(prior, n, alpha=0.1)
    key = jax.random.key(0)
    first = jax.jit(algo.initial_proposal)(key)
    dist = jnp.linalg.norm(first.thetas + jax.random.normal(key, first.thetas.shape), axis=1)
    state, _ = jax.jit(algo.init)(key, first, dist)
    propose, update = jax.jit(algo.propose), jax.jit(algo.update)

    def one(i: int):
        k1, k2, k3 = jax.random.split(jax.random.key(i), 3)
        prop = propose(k1, state)
        d_new = jnp.linalg.norm(prop.thetas + jax.random.normal(k2, prop.thetas.shape), axis=1)
        return update(k3, state, prop, d_new)

    jax.block_until_ready(one(0))  # compile
    times = []
    for i in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(one(i + 1))
        times.append(time.perf_counter() - t0)
    return {"median_s": float(np.median(times)), "min_s": float(np.min(times)), "repeats": repeats}


def driver_step_time(n: int, d: int) -> dict:
    """Whole driver iterations (host loop, executor, distances, records) with a trivial simulator."""
    prior = jaxabc.Uniform(np.full(d, -10.0), np.full(d, 10.0))

    def simulate(key, theta):
        return theta + jax.random.normal(key, theta.shape)

    kw = dict(num_particles=n, alpha=0.1, acceptance_cutoff=0.0, distance="euclidean", seed=0)
    r = jaxabc.run("apmcabc", simulate, prior, jnp.zeros(d), num_steps=8, **kw)
    walls = np.diff(r.metadata["generation_wall_times"])
    # The first two generations compile the kernels; later ones show the steady state.
    return {"per_step_s": float(np.median(walls[2:])), "compile_and_first_steps_s": float(walls[:2].sum()),
            "note": "whole driver iteration: kernels, vmapped toy simulator, distances, records"}


def numpy_step_time(n: int, d: int, repeats: int) -> dict:
    """The same step written plainly in NumPy/SciPy (vectorised, no JAX)."""
    from scipy.special import logsumexp

    rng = np.random.default_rng(0)
    low, high = np.full(d, -10.0), np.full(d, 10.0)
    n_alpha = math.ceil(0.1 * n)
    kept = rng.normal(size=(n_alpha, d))
    log_w = np.zeros(n_alpha)
    kept_d = np.abs(rng.normal(size=n_alpha))
    cov = 2 * np.cov(kept, rowvar=False)
    chol = np.linalg.cholesky(cov)

    def step():
        m = n - n_alpha
        w = np.exp(log_w - logsumexp(log_w))
        parents = rng.choice(n_alpha, size=m, p=w)
        x = kept[parents] + rng.normal(size=(m, d)) @ chol.T
        bad = ~np.all((x >= low) & (x <= high), axis=1)
        while bad.any():
            x[bad] = kept[parents[bad]] + rng.normal(size=(bad.sum(), d)) @ chol.T
            bad = ~np.all((x >= low) & (x <= high), axis=1)
        a = np.linalg.solve(chol, x.T).T
        b = np.linalg.solve(chol, kept.T).T
        sq = (a**2).sum(1)[:, None] + (b**2).sum(1)[None, :] - 2 * a @ b.T
        log_k = -0.5 * sq - np.log(np.diag(chol)).sum() - 0.5 * d * np.log(2 * np.pi)
        new_lw = -np.log(20.0) * d - logsumexp(log_k + (log_w - logsumexp(log_w))[None, :], axis=1)
        dist = np.abs(rng.normal(size=m))
        all_d = np.concatenate([kept_d, dist])
        all_x = np.concatenate([kept, x])
        all_w = np.concatenate([log_w, new_lw])
        keep = np.argsort(all_d)[:n_alpha]
        ww = np.exp(all_w[keep] - logsumexp(all_w[keep]))
        return np.cov(all_x[keep], aweights=ww, rowvar=False)

    step()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        step()
        times.append(time.perf_counter() - t0)
    return {"median_s": float(np.median(times)), "repeats": repeats,
            "note": "no truncation normaliser (it would add an MC estimate per kept particle)"}


ABCPY_SCRIPT = r'''
import json, sys, time
import numpy as np
# ABCpy 0.6.3 uses NumPy aliases removed in NumPy 1.24.
np.float = float; np.int = int; np.bool = bool
from abcpy.continuousmodels import Uniform, Normal
from abcpy.statistics import Identity
from abcpy.distances import Euclidean
from abcpy.backends import BackendDummy
from abcpy.inferences import APMCABC
n, d = int(sys.argv[1]), int(sys.argv[2])
mus = [Uniform([[-10.0], [10.0]], name=f"mu{i}") for i in range(d)]
models = [Normal([mu, 1.0], name=f"x{i}") for i, mu in enumerate(mus)]
dists = [Euclidean(Identity(degree=1, cross=False)) for _ in models]
obs = [[np.array([0.0])] for _ in models]
out = {}
for steps in (1, 2):
    s = APMCABC(models, dists, BackendDummy(), seed=1)
    t0 = time.perf_counter()
    s.sample(obs, steps=steps, n_samples=n, n_samples_per_param=1, alpha=0.1, acceptance_cutoff=0.0)
    out[steps] = time.perf_counter() - t0
print(json.dumps({"step_s": out[2] - out[1], "init_s": out[1]}))
'''


def abcpy_step_time(python: str, n: int, d: int, timeout: float) -> dict:
    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as fh:
        fh.write(ABCPY_SCRIPT)
    try:
        out = subprocess.run([python, fh.name, str(n), str(d)], capture_output=True, text=True,
                             timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"error": f"ABCpy step took longer than {timeout} s"}
    if out.returncode != 0:
        return {"error": out.stderr.strip().splitlines()[-1] if out.stderr else "failed"}
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 5000, 20000])
    parser.add_argument("--dims", type=int, nargs="+", default=[2, 9])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--abcpy-python", default=sys.executable,
                        help="interpreter with abcpy==0.6.3 installed (skipped if it cannot import it)")
    parser.add_argument("--abcpy-sizes", type=int, nargs="+", default=[1000, 5000])
    parser.add_argument("--abcpy-timeout", type=float, default=900)
    parser.add_argument("--output", type=Path, default=None, help="default: results/abc_overhead.json")
    args = parser.parse_args()
    rows = []
    for d in args.dims:
        for n in args.sizes:
            row = {"num_particles": n, "dim": d,
                   "jax_kernels": jax_step_time(n, d, args.repeats),
                   "numpy": numpy_step_time(n, d, args.repeats),
                   "jax_driver": driver_step_time(n, d)}
            if n in args.abcpy_sizes and d == args.dims[0]:
                row["abcpy_0_6_3"] = abcpy_step_time(args.abcpy_python, n, d, args.abcpy_timeout)
            j = row["jax_kernels"]["median_s"]
            row["numpy_over_jax"] = row["numpy"]["median_s"] / j
            if "step_s" in row.get("abcpy_0_6_3", {}):
                row["abcpy_over_jax"] = row["abcpy_0_6_3"]["step_s"] / j
                row["abcpy_over_jax_driver"] = row["abcpy_0_6_3"]["step_s"] / row["jax_driver"]["per_step_s"]
            print(json.dumps(row), flush=True)
            rows.append(row)
    # Realistic simulator-bound runs: one step simulates N - N_alpha particles.
    sim_costs = {"water_quick_gromacs_s_per_sim_one_core": 10.0,
                 "helium_cpu_preset_s_per_sim_batched": 0.2}
    fractions = {}
    for r in rows:
        m = r["num_particles"] - math.ceil(0.1 * r["num_particles"])
        for name, cost in sim_costs.items():
            fractions[f"N{r['num_particles']}_d{r['dim']}_{name}"] = (
                r["jax_driver"]["per_step_s"] / (r["jax_driver"]["per_step_s"] + m * cost / 2))
    path = write_result(args.output or "abc_overhead", {
        "description": __doc__.split("\n\n")[0],
        "rows": rows,
        "overhead_fraction_of_step_on_2_cores": fractions,
        "simulation_costs_assumed": sim_costs,
        "targets": {"jax_vs_abcpy_at_N5000": ">= 10x", "overhead_fraction": "< 1%"},
    })
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
