"""Calibration runs on real MPI ranks for test_mpi.py.

Launched as ``mpiexec -n K python -m mpi4py.futures tests/_mpi_job.py OUT.json [--flaky]``; rank 0
runs this script, ranks 1..K-1 are the pool's workers.  Writes the particles, weights and task
records of an APMCABC run under dynamic and static MPI allocation (and, with ``--flaky``, a serial
reference run and the failure statuses of ``flaky_simulate``; with ``--longest-first``, a dynamic run
whose tasks are queued longest-predicted-first) to ``OUT.json``.
"""

from __future__ import annotations

import json
import os
import sys
import time

import jax
import numpy as np

import jaxabc
from jaxabc.examples import flaky_simulate, host_gaussian_simulate
from jaxabc.executors.mpi import MPIExecutor

# Shared with test_mpi.py, which checks the serial run against the MPI runs of other launches.
SETTINGS = {"num_particles": 40, "num_steps": 3, "seed": 7}
# theta[0] of flaky_simulate: raises, NaN, crashes its process, hangs (sleep 60 s), succeeds.
FLAKY_THETAS = [0.05, 0.15, 0.27, 0.22, 0.5, 0.7]
FLAKY_TIMEOUT = 2.0


def _calibrate(executor: str | object) -> dict:
    t0 = time.perf_counter()
    prior = jaxabc.Uniform([-10.0], [10.0], names=("mu",))
    result = jaxabc.run("apmcabc", host_gaussian_simulate, prior, np.array([0.0]), executor=executor, **SETTINGS)
    rec = result.records
    return {
        "particles": result.particles.tolist(),
        "weights": result.weights.tolist(),
        "executor": result.metadata["executor"],
        "worker": rec["worker"].tolist(),
        "iteration": rec["iteration"].tolist(),
        "status": rec["status"].tolist(),
        "seconds": time.perf_counter() - t0,
    }


def _flaky() -> dict:
    keys = np.asarray(jax.random.key_data(jax.random.split(jax.random.key(3), len(FLAKY_THETAS))))
    thetas = np.asarray(FLAKY_THETAS)[:, None]
    ex = MPIExecutor("dynamic", timeout=FLAKY_TIMEOUT)
    try:
        batch = ex.map(flaky_simulate, keys, thetas)
        # The pool must still work after a crash and a timeout (isolation replaced the children).
        again = ex.map(host_gaussian_simulate, keys, thetas)
    finally:
        ex.close()
    # A whole run over the full prior U[0, 1]: 30 prior draws meet every kind of failure (raise,
    # NaN, crash, hang) and the run must still finish, with each failure recorded.
    prior = jaxabc.Uniform([0.0], [1.0], names=("a",))
    ex_run = MPIExecutor("dynamic", timeout=FLAKY_TIMEOUT)
    try:
        run_result = jaxabc.run(
            "rejection", flaky_simulate, prior, np.array([0.6]), num_particles=15, executor=ex_run, seed=1, quantile=0.5
        )
    finally:
        ex_run.close()
    return {
        "status": batch.status.tolist(),
        "reasons": list(batch.reasons),
        "summaries": np.where(np.isfinite(batch.summaries), batch.summaries, None).tolist(),
        "worker": batch.worker.tolist(),
        "again_status": again.status.tolist(),
        "again_summaries": again.summaries.tolist(),
        "run_status": run_result.records["status"].tolist(),
        "run_reasons": run_result.records["reasons"],
    }


def main() -> None:
    # Share compiled programs between this job's runs and the test's other launch: every
    # jaxabc.run compiles its kernels afresh, which costs more than the simulations here.
    cache = os.environ.get("JAXABC_TEST_JAX_CACHE")
    if cache:
        jax.config.update("jax_compilation_cache_dir", cache)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    t0 = time.perf_counter()
    probe = MPIExecutor()
    out = {"num_workers": probe.num_workers}
    probe.close()
    out["mpi"] = _calibrate("mpi")
    out["mpi_static"] = _calibrate("mpi_static")
    if "--longest-first" in sys.argv:
        ex = MPIExecutor("dynamic", order="longest_first")
        try:
            out["mpi_longest_first"] = _calibrate(ex)
            out["mpi_longest_first"]["history"] = ex.cost_model.history_size
        finally:
            ex.close()
    if "--flaky" in sys.argv:
        out["serial"] = _calibrate("serial")
        out["flaky"] = _flaky()
    out["seconds"] = time.perf_counter() - t0
    with open(sys.argv[1], "w") as fh:
        json.dump(out, fh)


if __name__ == "__main__":
    main()
