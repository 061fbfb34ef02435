"""The GP surrogate against the peers a user would pick instead: ELFI's BOLFI and pyABC's ABC-SMC.

One problem with an exact posterior, the same simulation budgets for every method, in one run:
``x = theta + L z`` with ``Cov(L z) = [[1, 0.8], [0.8, 1]]``, a flat prior U[-10, 10]^2 and one
observed ``x`` (``--observed``), so the posterior is ``N(x, Sigma)`` (the prior's truncation is
negligible).  Each method gets at most ``B`` simulations for each budget in ``--budgets`` and
each seed in ``--seeds``:

- ``jaxabc.run("surrogate", ...)``, synthetic-likelihood mode, 1000 posterior draws;
- ELFI 0.8 ``BOLFI`` on the log Euclidean discrepancy (as in ELFI's tutorial: 20 initial
  points, GP updated every 10, ``acq_noise_var`` 0.1), 1000 NUTS draws over the fitted GP
  (4 chains); BOLFI's posterior is its own approximation at the minimum of the GP mean;
- pyABC 0.13 ``ABCSMC`` (Euclidean distance, adaptive median epsilon, population ``B / 4``)
  stopped by ``max_total_nr_simulations = B``.

The peers run in their own virtual environments made by ``benchmarks/abc_overhead.py``'s
``make_venv`` under ``--cache-dir``.  Accuracy against the exact posterior: the error of the
posterior mean in exact-posterior sd (Mahalanobis), each parameter's sd over the exact one, the
correlation (exact 0.8), and the energy distance to 2000 exact draws (0 for equal laws).  Wall
time is each method's run in its own process, imports excluded.

Usage::

    python -m benchmarks.surrogate_peers                  # budgets 50 100 200, seed 0
    python -m benchmarks.surrogate_peers --quick          # budget 60, seed 0: results/quick/
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

import jaxabc
from benchmarks._common import command_line, write_result
from benchmarks.abc_overhead import PEERS, make_venv, run_process
from jaxabc.examples import correlated_simulate

ROOT = Path(__file__).resolve().parents[1]

COV = np.array([[1.0, 0.8], [0.8, 1.0]])
PROBLEM = "x = theta + L z, Cov(L z) = [[1, 0.8], [0.8, 1]], prior U[-10, 10]^2, posterior N(x_obs, Cov)"

BOLFI_SCRIPT = r"""
import json, sys, time, logging
import numpy as np
import elfi
logging.getLogger("elfi").setLevel(logging.WARNING)
budget, seed, obs, draws = int(sys.argv[1]), int(sys.argv[2]), json.loads(sys.argv[3]), int(sys.argv[4])
L = np.linalg.cholesky(np.array([[1.0, 0.8], [0.8, 1.0]]))

def simulate(a, b, batch_size=1, random_state=None):
    rs = random_state or np.random
    theta = np.column_stack([np.broadcast_to(a, batch_size), np.broadcast_to(b, batch_size)])
    return theta + rs.standard_normal((batch_size, 2)) @ L.T

m = elfi.new_model()
a = elfi.Prior("uniform", -10, 20, model=m, name="a")
b = elfi.Prior("uniform", -10, 20, model=m, name="b")
y = elfi.Simulator(simulate, a, b, observed=np.asarray(obs)[None], name="y")
d = elfi.Distance("euclidean", y, name="d")
log_d = elfi.Operation(np.log, d, name="log_d")
t0 = time.perf_counter()
bolfi = elfi.BOLFI(log_d, batch_size=1, initial_evidence=20, update_interval=10,
                   bounds={"a": (-10, 10), "b": (-10, 10)}, acq_noise_var=0.1, seed=seed)
bolfi.fit(n_evidence=budget)
res = bolfi.sample(draws, n_chains=4)
run_s = time.perf_counter() - t0
x = np.column_stack([res.samples["a"], res.samples["b"]])
print(json.dumps({"particles": x.tolist(), "weights": np.ones(len(x)).tolist(),
                  "num_simulations": int(bolfi.n_evidence), "run_s": run_s, "version": elfi.__version__}))
"""

PYABC_SCRIPT = r"""
import json, logging, os, sys, tempfile, time
import numpy as np
import pyabc
budget, seed, obs = int(sys.argv[1]), int(sys.argv[2]), json.loads(sys.argv[3])
for name in ("ABC", "Sampler", "Epsilon", "History", "Distance", "Acceptor", "Transition"):
    logging.getLogger(name).setLevel(logging.WARNING)
np.random.seed(seed)
L = np.linalg.cholesky(np.array([[1.0, 0.8], [0.8, 1.0]]))

def model(p):
    return {"x": np.array([p["a"], p["b"]]) + L @ np.random.standard_normal(2)}

def distance(x, y):
    return float(np.linalg.norm(x["x"] - y["x"]))

prior = pyabc.Distribution(a=pyabc.RV("uniform", -10, 20), b=pyabc.RV("uniform", -10, 20))
t0 = time.perf_counter()
with tempfile.TemporaryDirectory() as tmp:
    abc = pyabc.ABCSMC(model, prior, distance, population_size=max(10, budget // 4),
                       sampler=pyabc.sampler.SingleCoreSampler())
    abc.new("sqlite:///" + os.path.join(tmp, "h.db"), {"x": np.asarray(obs)})
    h = abc.run(max_total_nr_simulations=budget, minimum_epsilon=0.0)
    df, w = h.get_distribution(m=0, t=h.max_t)
    sims = int(h.total_nr_simulations)
    generations = int(h.max_t) + 1
run_s = time.perf_counter() - t0
print(json.dumps({"particles": df[["a", "b"]].to_numpy().tolist(), "weights": np.asarray(w, float).tolist(),
                  "num_simulations": sims, "run_s": run_s, "generations": generations,
                  "version": pyabc.__version__}))
"""


def energy_distance(x: np.ndarray, wx: np.ndarray, y: np.ndarray) -> float:
    """Weighted energy distance between draws ``x`` (weights ``wx``) and equal-weight draws ``y``."""
    wx = wx / wx.sum()
    wy = np.full(len(y), 1.0 / len(y))

    def mean_dist(a, wa, b, wb):
        return float(wa @ np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1) @ wb)

    return 2 * mean_dist(x, wx, y, wy) - mean_dist(x, wx, x, wx) - mean_dist(y, wy, y, wy)


def accuracy(particles, weights, observed: np.ndarray, exact: np.ndarray, max_draws: int, seed: int) -> dict:
    """Mean error (exact sd units), sd ratios, correlation and energy distance to exact draws."""
    x, w = np.asarray(particles, float), np.asarray(weights, float)
    w = w / w.sum()
    mean = w @ x
    cov = np.cov(x, aweights=w, rowvar=False)
    diff = mean - observed
    if len(x) > max_draws:  # resample to bound the O(n^2) energy distance
        idx = np.random.default_rng(seed).choice(len(x), max_draws, p=w)
        x, w = x[idx], np.full(max_draws, 1.0 / max_draws)
    sd = np.sqrt(np.diag(cov))
    return {
        "mean": mean.tolist(),
        "mean_error_in_sd": float(np.sqrt(diff @ np.linalg.solve(COV, diff))),
        "sd_ratio": (sd / np.sqrt(np.diag(COV))).tolist(),
        "correlation": float(cov[0, 1] / (sd[0] * sd[1])),
        "energy_distance": energy_distance(x, w, exact),
    }


def jaxabc_run(budget: int, seed: int, observed: np.ndarray, draws: int) -> dict:
    prior = jaxabc.Uniform([-10.0, -10.0], [10.0, 10.0], names=("a", "b"))
    t0 = time.perf_counter()
    r = jaxabc.run(
        "surrogate", correlated_simulate, prior, observed, max_simulations=budget, num_particles=draws, seed=seed
    )
    return {
        "particles": r.particles.tolist(),
        "weights": r.weights.tolist(),
        "num_simulations": int(r.num_simulations),
        "run_s": time.perf_counter() - t0,
        "validated": bool(r.diagnostics.get("validated", False)) if isinstance(r.diagnostics, dict) else None,
        "version": jaxabc.__version__,
    }


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--budgets", type=int, nargs="+", default=[50, 100, 200])
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--observed", type=float, nargs=2, default=[1.5, -0.5])
    p.add_argument("--draws", type=int, default=1000, help="posterior draws of the surrogate and of BOLFI")
    p.add_argument("--energy-draws", type=int, default=1000, help="draws used in the energy distance")
    p.add_argument("--timeout", type=float, default=1800, help="seconds per peer process")
    p.add_argument("--cache-dir", type=Path, default=Path.home() / ".cache" / "jaxabc_benchmarks")
    p.add_argument("--quick", action="store_true", help="budget 60, seed 0, to results/quick/")
    args = p.parse_args(argv)
    if args.quick:
        args.budgets, args.seeds = [60], [0]
    t_start = time.perf_counter()
    observed = np.asarray(args.observed, float)
    exact = np.random.default_rng(12345).multivariate_normal(observed, COV, size=args.energy_draws)
    envs = {
        "bolfi": make_venv(args.cache_dir, "elfi_smc", PEERS["elfi_smc"]["requirement"], "elfi"),
        "pyabc_abcsmc": make_venv(args.cache_dir, "pyabc_abcsmc", PEERS["pyabc_abcsmc"]["requirement"], "pyabc"),
    }
    scripts = {"bolfi": BOLFI_SCRIPT, "pyabc_abcsmc": PYABC_SCRIPT}
    rows = []
    for budget in args.budgets:
        for seed in args.seeds:
            row: dict = {"budget": budget, "seed": seed}
            runs = {"jaxabc_surrogate": {"output": jaxabc_run(budget, seed, observed, args.draws)}}
            for name, env in envs.items():
                if "error" in env:
                    runs[name] = env
                    continue
                extra = [str(args.draws)] if name == "bolfi" else []
                argv_peer = [env["python"], "-c", scripts[name], str(budget), str(seed), json.dumps(observed.tolist())]
                runs[name] = run_process([*argv_peer, *extra], args.timeout)
            for name, out in runs.items():
                if "error" in out:
                    row[name] = {"error": out["error"]}
                    continue
                o = out["output"]
                row[name] = {
                    "num_simulations": o["num_simulations"],
                    "run_s": o["run_s"],
                    **{k: o[k] for k in ("version", "validated", "generations") if k in o},
                    **accuracy(o["particles"], o["weights"], observed, exact, args.energy_draws, seed),
                }
            print(json.dumps(row)[:600], flush=True)
            rows.append(row)
    methods = ("jaxabc_surrogate", "bolfi", "pyabc_abcsmc")
    summary = {}
    for m in methods:
        per_budget = {}
        for budget in args.budgets:
            ok = [r[m] for r in rows if r["budget"] == budget and "energy_distance" in r.get(m, {})]
            if ok:
                per_budget[str(budget)] = {
                    "runs": len(ok),
                    "energy_distance_mean": float(np.mean([o["energy_distance"] for o in ok])),
                    "mean_error_in_sd_mean": float(np.mean([o["mean_error_in_sd"] for o in ok])),
                    "sd_ratio_mean": np.mean([o["sd_ratio"] for o in ok], axis=0).tolist(),
                    "correlation_mean": float(np.mean([o["correlation"] for o in ok])),
                    "run_s_mean": float(np.mean([o["run_s"] for o in ok])),
                }
        summary[m] = per_budget
    payload = {
        "benchmark": "surrogate_peers",
        "description": (__doc__ or "").split("\n\n")[0],
        "problem": PROBLEM,
        "observed": observed.tolist(),
        "exact_posterior": {"mean": observed.tolist(), "cov": COV.tolist()},
        "budgets": args.budgets,
        "seeds": args.seeds,
        "draws": args.draws,
        "peers": envs,
        "rows": rows,
        "summary": summary,
        "goal": "fewer simulations than BOLFI at equal accuracy",
        "benchmark_wall_s": time.perf_counter() - t_start,
        "jax": jax.__version__,
    }
    path = write_result("surrogate_peers", payload, quick=args.quick, command=command_line())
    print(f"wrote {path}")
    return payload


if __name__ == "__main__":
    main()
