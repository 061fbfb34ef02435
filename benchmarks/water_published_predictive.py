"""Each water model at its published parameters, on the model choice's own protocol and summaries.

The model choice calibrates each model's O-O Lennard-Jones pair; a reader also wants to see what
the model, as published, gives on the same data: the same simulator (quick preset, the data's
temperature, Yeh-Hummer corrected D, the 14 joint summaries), ``--runs`` independent keys per
model at the published ``(sigma_OO, epsilon_OO)``.  Each summary is reported as mean and standard
deviation over the runs, beside the measured value and its stated error, with the standardised
misfit ``(mean - observed) / sqrt(sd_runs^2 / runs + error^2)``.

Usage (from the repository root)::

    python -m benchmarks.water_published_predictive --data xray --runs 3 --workers 2
"""

from __future__ import annotations

import argparse
import concurrent.futures
import multiprocessing
import time
from pathlib import Path

import numpy as np

from benchmarks._common import RUNS, command_line, write_result
from benchmarks._water_data import DATA_FILES
from md.water.joint_data import joint_observed
from md.water.model_simulator import JOINT_SUMMARY_NAMES, CachedSummaries, WaterModelSimulator
from md.water.models import MODELS

ROOT = Path(__file__).resolve().parents[1]


def _one(task: tuple) -> tuple[str, list[float] | None, str]:
    """Worker: one run (cached), all joint summaries, or the failure's reason."""
    name, data, temperature_k, seed, cache_dir = task
    from jaxabc.errors import SimulationFailure

    model = MODELS[name]
    simulate = WaterModelSimulator(model, "quick", "robust", data, temperature_k=temperature_k)
    cached = CachedSummaries(simulate, np.ones(len(JOINT_SUMMARY_NAMES), bool), cache_dir)
    key = np.array([0, 1000 + seed], np.uint32)
    try:
        return name, cached.full(key, np.asarray(model.lj, np.float64)).tolist(), ""
    except SimulationFailure as failure:
        return name, None, str(failure)


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--data", choices=("xray", "neutron"), default="xray")
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--cache-dir", type=Path, default=None)
    args = p.parse_args(argv)
    start = time.perf_counter()
    data = joint_observed(args.data)
    cache = args.cache_dir or RUNS / "cache" / "water_published_predictive" / args.data
    tasks = [(name, args.data, data.temperature_k, s, str(cache)) for name in MODELS for s in range(args.runs)]
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(args.workers, mp_context=context) as pool:
        outputs = list(pool.map(_one, tasks))
    errors = np.asarray(data.errors, np.float64)
    models = {}
    for name in MODELS:
        runs = [o for n, o, _ in outputs if n == name and o is not None]
        failures = [r for n, o, r in outputs if n == name and o is None]
        entry: dict = {"published_lj": list(MODELS[name].lj), "num_runs": len(runs), "failures": failures}
        if runs:
            x = np.asarray(runs, np.float64)
            mean, sd = x.mean(axis=0), x.std(axis=0, ddof=1) if len(runs) > 1 else np.zeros(x.shape[1])
            scale = np.sqrt(sd**2 / len(runs) + np.nan_to_num(errors, nan=0.0) ** 2)
            with np.errstate(invalid="ignore", divide="ignore"):
                z = np.where(scale > 0, (mean - data.observed) / scale, np.nan)
            entry |= {
                "mean": mean.tolist(),
                "sd": sd.tolist(),
                "z": [None if not np.isfinite(v) else float(v) for v in z],
            }
        models[name] = entry
    payload = {
        "data": args.data,
        "temperature_k": data.temperature_k,
        "runs_per_model": args.runs,
        "summary_names": list(data.names),
        "observed": np.asarray(data.observed, np.float64).tolist(),
        "stated_errors": [None if np.isnan(e) else float(e) for e in errors],
        "fitted": [bool(v) for v in data.fitted],
        "models": models,
        "wall_time_s": time.perf_counter() - start,
    }
    path = write_result("water_published_predictive", payload, inputs=DATA_FILES[args.data], command=command_line(argv))
    print(f"wrote {path}")
    return payload


if __name__ == "__main__":
    main()
