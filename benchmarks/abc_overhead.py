"""Whole ABC runs end to end, cold: jaxabc (fused and host driver) against ELFI, pyABC and ABCpy.

Every method calibrates the same problem with the same population sizes and the same
tolerance schedule: a 2-D Gaussian mean (``x = theta + N(0, I)``, observed ``x = 0``, prior
``U(-10, 10)^2``, Euclidean distance), ABC-SMC / PMC-ABC generations at the tolerances given by
``--thresholds``.  Each run is a fresh Python process (cold: imports, tracing, compilation and
the run itself), timed from outside; the peers run in their own virtual environments, made by
this script under ``--cache-dir`` (``python -m venv`` + ``pip install`` from PyPI): ELFI 0.8.x
(``elfi.SMC``) and pyABC 0.13 (``ABCSMC``, single-core sampler, SQLite history in a temporary
folder) and ABCpy 0.6.3 (``PMCABC``, serial backend; installed without its ``glmnet``
dependency, which does not build on this Python and serves only features this problem does not
use, with the NumPy names NumPy 2 removed restored in its script).  A peer that does not finish
within ``--timeout`` is recorded as such, with the lower bound its timeout puts on the ratio.

Accuracy is measured against the exact posterior ``N(0, I)`` (the prior's truncation is
negligible): the error of the weighted mean, ``|mean|``, and of the weighted covariance,
``||cov - I||_F``.  At final tolerance ``eps`` the ABC posterior itself has covariance
``(1 + eps^2 / 4) I``, so no method can do better than that bias at that tolerance.

jaxabc's runs: a plain ``jaxabc.run`` call (PMC-ABC; for a JAX simulator it runs the fused
program, :func:`jaxabc.run_fused`) in a fresh process with an empty persistent compilation
cache (cold), then a second time in the same process (warm: compiled chunks reused), then in
another fresh process that finds the persistent cache filled (cold, cached), and
``run_fused(fast_compile=True)`` in a fresh process with no persistent cache (the fused path
keeps one in ``~/.cache/jaxabc/xla`` by default: every cold row here sets
``JAXABC_COMPILATION_CACHE``).  The host driver (``jaxabc.run(executor="vmap")``) runs cold
once per size.  The compiled-step floor is the least any cold process pays before its first
PMC-ABC iteration when that iteration is a compiled JAX program: interpreter start, imports,
tracing, lowering and compiling a single ``make_jax_step`` step, with no persistent cache, at
XLA's default optimisation and with ``run_fused``'s fast-compile options (median of three
processes).  A last part compares PMC-ABC's and APMCABC's steady-state cost per simulation in
the host driver at the largest size.

Writes ``benchmarks/results/abc_overhead.json``.  Usage::

    python -m benchmarks.abc_overhead                 # N in {1000, 5000}
    python -m benchmarks.abc_overhead --sizes 1000 --skip-peers
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

# The jaxabc runs happen in child processes; importing what they run here puts those modules
# in this result's fingerprint, so an edit to the fused path marks the result stale.
import jaxabc.driver.fused  # noqa: F401
from benchmarks._common import write_result
from benchmarks._venv import make_venv

ROOT = Path(__file__).resolve().parents[1]

PEERS = {
    "elfi_smc": {"requirement": "elfi>=0.8,<0.9", "module": "elfi"},
    "pyabc_abcsmc": {"requirement": "pyabc>=0.13,<0.14", "module": "pyabc"},
    # ABCpy 0.6.3 requires glmnet, whose Fortran build fails on this Python, for two features this
    # problem does not use (logistic-regression distance and likelihood): install it without its
    # dependencies, then what PMCABC imports (sphinx, coverage and mpi4py are not needed either).
    "abcpy_pmcabc": {
        "requirement": "abcpy==0.6.3",
        "module": "abcpy",
        "install": [
            ["--no-deps", "abcpy==0.6.3"],
            ["numpy", "scipy", "scikit-learn", "tqdm", "matplotlib", "pot", "cloudpickle"],
        ],
    },
}

ELFI_SCRIPT = r"""
import time
t_start = time.perf_counter()
import json, sys
import numpy as np
import elfi
n, seed, thresholds = int(sys.argv[1]), int(sys.argv[2]), json.loads(sys.argv[3])
t_import = time.perf_counter() - t_start

def simulate(a, b, batch_size=1, random_state=None):
    rs = random_state or np.random
    theta = np.column_stack([np.broadcast_to(a, batch_size), np.broadcast_to(b, batch_size)])
    return theta + rs.standard_normal((batch_size, 2))

m = elfi.new_model()
a = elfi.Prior("uniform", -10, 20, model=m, name="a")
b = elfi.Prior("uniform", -10, 20, model=m, name="b")
y = elfi.Simulator(simulate, a, b, observed=np.zeros((1, 2)), name="y")
d = elfi.Distance("euclidean", y, name="d")
t0 = time.perf_counter()
res = elfi.SMC(d, batch_size=n, seed=seed).sample(n, thresholds=thresholds)
run_s = time.perf_counter() - t0
x = np.column_stack([res.samples["a"], res.samples["b"]])
w = np.ones(len(x)) if res.weights is None else np.asarray(res.weights, float)
print(json.dumps({"particles": x.tolist(), "weights": w.tolist(), "num_simulations": int(res.n_sim),
                  "import_s": t_import, "run_s": run_s, "version": elfi.__version__,
                  "numpy": np.__version__}))
"""

PYABC_SCRIPT = r"""
import time
t_start = time.perf_counter()
import json, logging, os, sys, tempfile
import numpy as np
import pyabc
n, seed, thresholds = int(sys.argv[1]), int(sys.argv[2]), json.loads(sys.argv[3])
t_import = time.perf_counter() - t_start
for name in ("ABC", "Sampler", "Epsilon", "History", "Distance", "Acceptor", "Transition"):
    logging.getLogger(name).setLevel(logging.WARNING)
np.random.seed(seed)

def model(p):
    return {"x": np.array([p["a"], p["b"]]) + np.random.standard_normal(2)}

def distance(x, y):
    return float(np.linalg.norm(x["x"] - y["x"]))

prior = pyabc.Distribution(a=pyabc.RV("uniform", -10, 20), b=pyabc.RV("uniform", -10, 20))
t0 = time.perf_counter()
abc = pyabc.ABCSMC(model, prior, distance, population_size=n, eps=pyabc.ListEpsilon(thresholds),
                   sampler=pyabc.sampler.SingleCoreSampler())
with tempfile.TemporaryDirectory() as tmp:
    abc.new("sqlite:///" + os.path.join(tmp, "abc.db"), {"x": np.zeros(2)})
    h = abc.run(max_nr_populations=len(thresholds))
    df, w = h.get_distribution(m=0, t=h.max_t)
    sims = int(h.total_nr_simulations)
run_s = time.perf_counter() - t0
print(json.dumps({"particles": df[["a", "b"]].to_numpy().tolist(),
                  "weights": np.asarray(w, float).tolist(), "num_simulations": sims,
                  "import_s": t_import, "run_s": run_s, "version": pyabc.__version__,
                  "numpy": np.__version__}))
"""

# ABCpy's PMCABC (Beaumont et al. 2009, as jaxabc's pmcabc): the threshold of step t is the larger
# of the schedule's and the epsilon_percentile of the previous distances; a percentile near zero
# leaves the schedule in charge.  Serial backend (BackendDummy), one simulation per parameter.
ABCPY_SCRIPT = r"""
import time
t_start = time.perf_counter()
import importlib.metadata, json, logging, sys, types
import numpy as np
sys.modules["glmnet"] = types.ModuleType("glmnet")
sys.modules["glmnet"].LogitNet = None  # only the logistic-regression distance uses it
# Names NumPy 2 removed that ABCpy 0.6.3 still uses (not np.bool: NumPy 2 has its own again).
np.float, np.int, np.product, np.infty = float, int, np.prod, np.inf
import abcpy
from abcpy.backends import BackendDummy
from abcpy.continuousmodels import Uniform
from abcpy.distances import Euclidean
from abcpy.inferences import PMCABC
from abcpy.probabilisticmodels import Continuous, InputConnector, ProbabilisticModel
from abcpy.statistics import Identity
n, seed, thresholds = int(sys.argv[1]), int(sys.argv[2]), json.loads(sys.argv[3])
t_import = time.perf_counter() - t_start
logging.getLogger("abcpy").setLevel(logging.WARNING)


class Shift(ProbabilisticModel, Continuous):
    # x = theta + N(0, I_2)
    def __init__(self, parameters, name="x"):
        super().__init__(InputConnector.from_list(parameters), name)

    def _check_input(self, input_values):
        return True

    def _check_output(self, values):
        return True

    def get_output_dimension(self):
        return 2

    def forward_simulate(self, input_values, k, rng=np.random.RandomState(), mpi_comm=None):
        theta = np.array(input_values[:2], float)
        return [theta + rng.standard_normal(2) for _ in range(k)]

    def pdf(self, input_values, x):
        raise NotImplementedError


a = Uniform([[-10.0], [10.0]], name="a")
b = Uniform([[-10.0], [10.0]], name="b")
x = Shift([a, b])
sampler = PMCABC([x], [Euclidean(Identity(degree=1, cross=False))], BackendDummy(), seed=seed)
t0 = time.perf_counter()
journal = sampler.sample([[np.zeros(2)]], steps=len(thresholds), epsilon_init=np.array(thresholds),
                         n_samples=n, n_samples_per_param=1, epsilon_percentile=1e-6)
run_s = time.perf_counter() - t0
params = journal.get_accepted_parameters()
particles = np.array([[float(np.ravel(p[0])[0]), float(np.ravel(p[1])[0])] for p in params])
w = np.asarray(journal.get_weights(), float).ravel()
sims = int(journal.number_of_simulations[-1])  # cumulative
print(json.dumps({"particles": particles.tolist(), "weights": w.tolist(), "num_simulations": sims,
                  "import_s": t_import, "run_s": run_s, "version": importlib.metadata.version("abcpy"),
                  "numpy": np.__version__}))
"""

JAXABC_SCRIPT = r"""
import time
t_start = time.perf_counter()
import json, sys
import numpy as np
import jax
import jaxabc
n, seed, thresholds, mode, repeats = (int(sys.argv[1]), int(sys.argv[2]), json.loads(sys.argv[3]),
                                      sys.argv[4], int(sys.argv[5]))
t_import = time.perf_counter() - t_start

def simulate(key, theta):
    return theta + jax.random.normal(key, theta.shape)

prior = jaxabc.Uniform([-10.0, -10.0], [10.0, 10.0], names=("a", "b"))
# "fused": a plain jaxabc.run call (its default for a JAX simulator); "host": the host driver.
runner = jaxabc.run_fused if mode == "fused_fast_compile" else jaxabc.run
extra = {"fast_compile": True} if mode == "fused_fast_compile" else {"executor": "vmap"} if mode == "host" else {}
out = []
for i in range(repeats):
    t0 = time.perf_counter()
    r = runner("pmcabc", simulate, prior, np.zeros(2), num_particles=n, distance="euclidean",
               seed=seed + i, thresholds=thresholds, num_steps=len(thresholds) + 1,
               keep_summaries=False, **extra)
    run_s = time.perf_counter() - t0
    out.append({"particles": r.particles.tolist(), "weights": r.weights.tolist(),
                "num_simulations": int(r.num_simulations), "import_s": t_import, "run_s": run_s,
                "since_start_s": time.perf_counter() - t_start,
                "iterations": int(r.records["iteration"].max()) + 1})
print(json.dumps(out))
"""

# The least a process must do before it can run one PMC-ABC iteration as a compiled JAX program:
# start, import JAX and jaxabc, trace and lower ``make_jax_step``'s step (propose, the vmapped
# simulator and update in one jit; no records, no loop, no initial generation) and compile it.
# No persistent cache: this is the cost a machine's first run cannot avoid.
FLOOR_SCRIPT = r"""
import time
t0 = time.perf_counter()
import json, sys
import jax
t_jax = time.perf_counter() - t0
import jax.numpy as jnp
import jaxabc
from jaxabc.algorithms import pmc
from jaxabc.algorithms.base import make_jax_step
from jaxabc.distances import get_distance
from jaxabc.driver.fused import _FAST_COMPILE
t_jaxabc = time.perf_counter() - t0 - t_jax
n, thresholds, mode = int(sys.argv[1]), json.loads(sys.argv[2]), sys.argv[3]

def simulate(key, theta):
    return theta + jax.random.normal(key, theta.shape)

prior = jaxabc.Uniform([-10.0, -10.0], [10.0, 10.0], names=("a", "b"))
algo = pmc.build(prior, n, thresholds=thresholds)
init, step = make_jax_step(algo, simulate, get_distance("euclidean"), jnp.zeros(2, jnp.float32))
key = jax.random.key(0)
state = jax.eval_shape(init, key)[0]
t = time.perf_counter()
lowered = jax.jit(step).lower(key, state)
t_lower = time.perf_counter() - t
t = time.perf_counter()
lowered.compile(_FAST_COMPILE if mode == "fast" else None)
t_compile = time.perf_counter() - t
print(json.dumps({"import_jax_s": t_jax, "import_jaxabc_s": t_jaxabc, "trace_lower_s": t_lower,
                  "compile_s": t_compile}))
"""

PER_SIMULATION_SCRIPT = r"""
import json, sys
import numpy as np
import jax
import jaxabc
n = int(sys.argv[1])

def simulate(key, theta):
    return theta + jax.random.normal(key, theta.shape)

prior = jaxabc.Uniform([-10.0, -10.0], [10.0, 10.0], names=("a", "b"))
out = {}
for name, kw in (("apmcabc", dict(num_steps=7, acceptance_cutoff=0.0)),
                 ("pmcabc", dict(num_steps=6))):
    # The host driver: it times each generation (a fused run sees only its chunks).
    r = jaxabc.run(name, simulate, prior, np.zeros(2), num_particles=n, distance="euclidean",
                   keep_summaries=False, executor="vmap", **kw)
    walls = np.diff(r.metadata["generation_wall_times"])
    sims = r.simulations_per_step[1:]
    # Generations 0-1 compile the kernels; 2 onwards are the steady state.
    out[name] = {"us_per_simulation": 1e6 * float(walls[1:].sum() / sims[1:].sum()),
                 "simulations_per_generation": r.simulations_per_step.tolist(),
                 "iterations": int(r.records["iteration"].max()) + 1,
                 "thresholds": r.thresholds.tolist()}
out["pmc_over_apmc"] = out["pmcabc"]["us_per_simulation"] / out["apmcabc"]["us_per_simulation"]
print(json.dumps(out))
"""


def run_process(argv: list[str], timeout: float, env: dict | None = None) -> dict:
    """Run one cold process; its wall time includes interpreter start and imports."""
    t0 = time.perf_counter()
    try:
        out = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, env={**os.environ, **(env or {})})
    except subprocess.TimeoutExpired:
        return {"error": f"did not finish in {timeout:.0f} s", "process_wall_s": timeout}
    wall = time.perf_counter() - t0
    if out.returncode != 0:
        tail = out.stderr.strip().splitlines()[-3:] if out.stderr else ["failed"]
        return {"error": " | ".join(tail), "process_wall_s": wall}
    return {"output": json.loads(out.stdout.strip().splitlines()[-1]), "process_wall_s": wall}


def accuracy(particles: list, weights: list, final_threshold: float) -> dict:
    x, w = np.asarray(particles, float), np.asarray(weights, float)
    w = w / w.sum()
    mean = w @ x
    cov = np.cov(x, aweights=w, rowvar=False)
    abc_cov = (1 + final_threshold**2 / 4) * np.eye(2)
    return {
        "mean": mean.tolist(),
        "cov": cov.tolist(),
        "mean_error": float(np.linalg.norm(mean)),
        "cov_error_vs_exact": float(np.linalg.norm(cov - np.eye(2))),
        "cov_error_vs_abc_limit": float(np.linalg.norm(cov - abc_cov)),
        "ess": float(1.0 / np.sum(w**2)),
    }


def summarise(output: dict, wall: float, final_threshold: float) -> dict:
    row = {
        "num_simulations": output["num_simulations"],
        "process_wall_s": wall,
        "run_s": output["run_s"],
        "import_s": output["import_s"],
        "us_per_simulation_whole_process": 1e6 * wall / output["num_simulations"],
        "us_per_simulation_run": 1e6 * output["run_s"] / output["num_simulations"],
        **accuracy(output["particles"], output["weights"], final_threshold),
    }
    for key in ("version", "numpy", "iterations"):
        if key in output:
            row[key] = output[key]
    return row


def jaxabc_rows(n: int, seed: int, thresholds: list, timeout: float, cache: Path) -> dict:
    env = {"PYTHONPATH": str(ROOT), "JAX_PLATFORMS": os.environ.get("JAX_PLATFORMS", "cpu")}
    rows: dict = {}
    script = ["-c", JAXABC_SCRIPT, str(n), str(seed), json.dumps(thresholds)]
    xla = Path(tempfile.mkdtemp(prefix="jaxabc-xla-", dir=cache))
    try:
        cold = run_process(
            [sys.executable, *script, "fused", "2"], timeout, {**env, "JAXABC_COMPILATION_CACHE": str(xla)}
        )
        if "error" in cold:
            rows["fused_cold"] = cold
        else:
            first, second = cold["output"]
            # The first run's process wall: everything up to its end (start, imports, run).
            rows["fused_cold"] = summarise(first, cold["process_wall_s"] - second["run_s"], thresholds[-1])
            rows["fused_warm"] = summarise(second, second["run_s"], thresholds[-1])
            rows["fused_warm"]["note"] = "second run in the same process: compiled chunks reused"
        cached = run_process(
            [sys.executable, *script, "fused", "1"], timeout, {**env, "JAXABC_COMPILATION_CACHE": str(xla)}
        )
        rows["fused_cold_persistent_cache"] = (
            cached if "error" in cached else summarise(cached["output"][0], cached["process_wall_s"], thresholds[-1])
        )
    finally:
        shutil.rmtree(xla, ignore_errors=True)
    # run_fused keeps a persistent cache in ~/.cache by default: these rows are cold only without it.
    env = {**env, "JAXABC_COMPILATION_CACHE": "off"}
    fast = run_process([sys.executable, *script, "fused_fast_compile", "1"], timeout, env)
    rows["fused_cold_fast_compile"] = (
        fast if "error" in fast else summarise(fast["output"][0], fast["process_wall_s"], thresholds[-1])
    )
    host = run_process([sys.executable, *script, "host", "1"], timeout, env)
    rows["host_driver_cold"] = (
        host if "error" in host else summarise(host["output"][0], host["process_wall_s"], thresholds[-1])
    )
    return rows


def floor_rows(n: int, thresholds: list, timeout: float, repeats: int = 3) -> dict:
    """The compiled-step floor (``FLOOR_SCRIPT``) at default and fast compilation: medians of
    ``repeats`` fresh processes, and the bare interpreter's start for comparison."""
    env = {
        "PYTHONPATH": str(ROOT),
        "JAX_PLATFORMS": os.environ.get("JAX_PLATFORMS", "cpu"),
        "JAXABC_COMPILATION_CACHE": "off",
    }
    bare = [run_process([sys.executable, "-c", "print('{}')"], timeout)["process_wall_s"] for _ in range(repeats)]
    out: dict = {"python_start_s": float(np.median(bare)), "repeats": repeats}
    for mode in ("default", "fast"):
        runs = [
            run_process([sys.executable, "-c", FLOOR_SCRIPT, str(n), json.dumps(thresholds), mode], timeout, env)
            for _ in range(repeats)
        ]
        bad = [r for r in runs if "error" in r]
        if bad:
            out[mode] = bad[0]
            continue
        parts = {k: float(np.median([r["output"][k] for r in runs])) for k in runs[0]["output"]}
        out[mode] = {**parts, "process_wall_s": float(np.median([r["process_wall_s"] for r in runs]))}
    return out


def peer_row(python: str, script: str, n: int, seed: int, thresholds: list, timeout: float) -> dict:
    out = run_process([python, "-c", script, str(n), str(seed), json.dumps(thresholds)], timeout)
    if "error" in out:
        return out
    return summarise(out["output"], out["process_wall_s"], thresholds[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 5000])
    parser.add_argument("--thresholds", type=float, nargs="+", default=[6.0, 3.0, 1.5, 0.75])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--timeout", type=float, default=300, help="seconds per process before it is reported as not finished"
    )
    parser.add_argument(
        "--cache-dir",
        type=Path,
        default=Path.home() / ".cache" / "jaxabc_benchmarks",
        help="where the peers' virtual environments are made and kept",
    )
    parser.add_argument("--skip-peers", action="store_true")
    parser.add_argument("--output", type=Path, default=None, help="default: results/abc_overhead.json")
    parser.add_argument("--note", default="", help="stored in the JSON (e.g. machine load)")
    args = parser.parse_args()
    args.cache_dir.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    envs = (
        {}
        if args.skip_peers
        else {
            name: make_venv(args.cache_dir, name, spec["requirement"], spec["module"], spec.get("install"))
            for name, spec in PEERS.items()
        }
    )
    scripts = {"elfi_smc": ELFI_SCRIPT, "pyabc_abcsmc": PYABC_SCRIPT, "abcpy_pmcabc": ABCPY_SCRIPT}
    rows = []
    timed_out: dict[str, int] = {}  # peer -> the population size it did not finish
    for n in sorted(args.sizes):
        row: dict = {
            "num_particles": n,
            "jaxabc": jaxabc_rows(n, args.seed, args.thresholds, args.timeout, args.cache_dir),
            "compiled_step_floor": floor_rows(n, args.thresholds, args.timeout),
        }
        for name, env in envs.items():
            if "error" in env:
                row[name] = env
            elif name in timed_out:
                # A larger population runs more simulations under the same schedule: it would not
                # finish either, and the timeout stays a lower bound on its time.
                row[name] = {
                    "error": f"did not finish in {args.timeout:.0f} s at N = {timed_out[name]}, so not run here",
                    "process_wall_s": args.timeout,
                }
            else:
                row[name] = peer_row(env["python"], scripts[name], n, args.seed, args.thresholds, args.timeout)
                if "did not finish" in row[name].get("error", ""):
                    timed_out[name] = n
        ratios = {}
        for peer in envs:
            for mode, jrow in row["jaxabc"].items():
                if "process_wall_s" in jrow and "num_simulations" in row[peer] and "num_simulations" in jrow:
                    ratios[f"{peer}_over_jaxabc_{mode}_per_simulation"] = (
                        row[peer]["us_per_simulation_whole_process"] / jrow["us_per_simulation_whole_process"]
                    )
                    ratios[f"{peer}_over_jaxabc_{mode}_whole_run"] = (
                        row[peer]["process_wall_s"] / jrow["process_wall_s"]
                    )
                elif "process_wall_s" in jrow and "did not finish" in row[peer].get("error", ""):
                    ratios[f"{peer}_over_jaxabc_{mode}_whole_run_at_least"] = (
                        row[peer]["process_wall_s"] / jrow["process_wall_s"]
                    )
        row["ratios"] = ratios
        print(json.dumps(row, default=float)[:2000], flush=True)
        rows.append(row)
    per_sim = run_process(
        [sys.executable, "-c", PER_SIMULATION_SCRIPT, str(max(args.sizes))], args.timeout * 2, {"PYTHONPATH": str(ROOT)}
    )
    payload = {
        "description": __doc__.split("\n\n")[0],
        "problem": {
            "simulator": "x = theta + N(0, I_2)",
            "observed": [0.0, 0.0],
            "prior": "U(-10, 10)^2",
            "distance": "euclidean",
            "thresholds": args.thresholds,
            "exact_posterior": "N(0, I)",
            "abc_limit_covariance": f"(1 + {args.thresholds[-1]}^2 / 4) I",
        },
        "peers": {name: {**PEERS[name], **envs.get(name, {})} for name in PEERS},
        "rows": rows,
        "pmc_vs_apmc_host_driver_per_simulation": per_sim.get("output", per_sim),
        "benchmark_wall_s": time.perf_counter() - t_start,
        "note": args.note,
        "targets": {"jaxabc_fused_vs_peers_end_to_end_cold": ">= 10x", "pmc_over_apmc_per_simulation_at_N5000": "<= 2"},
    }
    path = write_result(args.output or "abc_overhead", payload)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
