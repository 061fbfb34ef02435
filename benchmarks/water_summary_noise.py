"""Is the water summaries' simulator noise Gaussian?  Replicates at each model's posterior estimate.

The model choice's emulators meet held-out errors with heavier tails than the normal their checks
and the Gaussian synthetic likelihood assume (``water_emulator_failures``).  Those errors mix the
simulator's noise with the emulator's error; replicates at one point measure the noise alone.
For each water model, ``--runs`` independent keys at its posterior Bayes estimate in the model
choice (``water_model_choice.json``, physical parameters only), on the model choice's own
protocol (quick preset, the data's temperature, Yeh-Hummer corrected D); per fitted summary the
mean, sd, skewness and excess kurtosis with bootstrap 95 % intervals, the share beyond 3 sd and
the Shapiro-Wilk p.  Pooled over the models (each standardised by its own mean and sd); the
results page sets its excess kurtosis beside that of the held-out errors, which it reads from
``water_emulator_failures.json`` itself (this result does not depend on that one).

Usage (from the repository root)::

    python -m benchmarks.water_summary_noise --runs 40 --workers 2
    python -m benchmarks.water_summary_noise --quick      # 3 runs of 5 ps per model
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import multiprocessing
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import scipy.stats

from benchmarks._common import RESULTS, RUNS, command_line, write_result
from benchmarks._water_data import DATA_FILES
from md.water.joint_data import joint_observed
from md.water.model_simulator import JOINT_SUMMARY_NAMES, CachedSummaries, WaterModelSimulator
from md.water.models import MODELS

ROOT = Path(__file__).resolve().parents[1]
#: Bootstrap resamples of the moment intervals (fixed seed).
BOOTSTRAP = 2000
#: Key stream of these runs (first word), apart from the model choice's and the predictive's.
KEY_STREAM = 7


def _one(task: tuple) -> tuple[str, list[float] | None, str]:
    """Worker: one run (cached), all joint summaries, or the failure's reason."""
    name, data, theta, overrides, seed, cache_dir = task
    from jaxabc.errors import SimulationFailure

    simulate = WaterModelSimulator(MODELS[name], "quick", "robust", data, **overrides)
    cached = CachedSummaries(simulate, np.ones(len(JOINT_SUMMARY_NAMES), bool), cache_dir)
    try:
        return name, cached.full(np.array([KEY_STREAM, seed], np.uint32), np.asarray(theta)).tolist(), ""
    except SimulationFailure as failure:
        return name, None, str(failure)


def moments(x: np.ndarray, rng: np.random.Generator) -> dict[str, Any]:
    """Sd, skewness and excess kurtosis of ``x (n,)`` with percentile-bootstrap 95 % intervals,
    the share beyond 3 sd and the Shapiro-Wilk p (NaN for a constant ``x``)."""
    n = x.size
    boot = x[rng.integers(0, n, size=(BOOTSTRAP, n))]
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # resamples of one repeated value
        skew, kurt = scipy.stats.skew(boot, axis=1), scipy.stats.kurtosis(boot, axis=1)
        sd = x.std(ddof=1)
        z = (x - x.mean()) / sd if sd > 0 else np.zeros_like(x)

    def interval(v: np.ndarray) -> list[float]:
        return np.nanpercentile(v, [2.5, 97.5]).tolist()

    return {
        "n": int(n),
        "mean": float(x.mean()),
        "sd": float(sd),
        "skewness": float(scipy.stats.skew(x)),
        "skewness_95": interval(skew),
        "excess_kurtosis": float(scipy.stats.kurtosis(x)),
        "excess_kurtosis_95": interval(kurt),
        "share_beyond_3sd": float(np.mean(np.abs(z) > 3)),
        "shapiro_p": float(scipy.stats.shapiro(x).pvalue) if sd > 0 and n >= 3 else float("nan"),
    }


def null_pooled_kurtosis(sizes: list[int], rng: np.random.Generator, draws: int = 4000) -> list[float]:
    """95 % interval of the pooled excess kurtosis of normal groups of ``sizes``, each standardised
    by its own mean and sd as the runs are (which biases it below 0 for small groups)."""
    out = np.empty(draws)
    for i in range(draws):
        parts = []
        for n in sizes:
            x = rng.standard_normal(n)
            parts.append((x - x.mean()) / x.std(ddof=1))
        out[i] = scipy.stats.kurtosis(np.concatenate(parts))
    return np.percentile(out, [2.5, 97.5]).tolist()


def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--data", choices=("xray",), default="xray")
    p.add_argument("--runs", type=int, default=40, help="replicates per model")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--model-choice", default="water_model_choice", help="result whose posterior estimates to use")
    p.add_argument("--quick", action="store_true", help="3 runs of 5 ps per model, quick JSON")
    p.add_argument("--cache-dir", type=Path, default=None)
    args = p.parse_args(argv)
    start = time.perf_counter()
    data = joint_observed(args.data)
    choice = json.loads((RESULTS / f"{args.model_choice}.json").read_text())
    if choice.get("data") != args.data:
        raise SystemExit(f"{args.model_choice} is on {choice.get('data')!r} data, not {args.data!r}")
    runs = 3 if args.quick else args.runs
    if runs < 3:
        raise SystemExit(f"--runs must be at least 3, got {runs}")
    overrides: dict[str, Any] = {"temperature_k": data.temperature_k}
    if args.quick:
        overrides |= {"num_steps": 2500, "analysis_start_ps": 1.0}
    theta = {name: choice["per_model"][name]["bayes_estimate"][:2] for name in MODELS}
    cache = args.cache_dir or RUNS / "cache" / "water_summary_noise" / ("quick" if args.quick else args.data)
    tasks = [(name, args.data, theta[name], overrides, s, str(cache)) for name in MODELS for s in range(runs)]
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(args.workers, mp_context=context) as pool:
        outputs = list(pool.map(_one, tasks))

    fitted = [n for n, f in zip(data.names, data.fitted, strict=True) if f]
    cols = [list(JOINT_SUMMARY_NAMES).index(n) for n in fitted]
    rng = np.random.default_rng(0)
    models, standardised = {}, []
    for name in MODELS:
        x = np.asarray([o for n, o, _ in outputs if n == name and o is not None], np.float64)
        failures = [r for n, o, r in outputs if n == name and o is None]
        entry: dict[str, Any] = {"theta": theta[name], "num_runs": len(x), "failures": failures}
        if len(x) >= 3:
            x = x[:, cols]
            entry["summaries"] = {n: moments(x[:, j], rng) for j, n in enumerate(fitted)}
            sd = x.std(axis=0, ddof=1)
            standardised.append((x - x.mean(axis=0)) / np.where(sd > 0, sd, 1.0))
        models[name] = entry
    pooled = np.concatenate(standardised) if standardised else np.zeros((0, len(fitted)))
    payload: dict[str, Any] = {
        "data": args.data,
        "model_choice": args.model_choice,
        "temperature_k": data.temperature_k,
        "runs_per_model": runs,
        "quick": args.quick,
        "fitted": fitted,
        "models": models,
        "pooled": {n: moments(pooled[:, j], rng) for j, n in enumerate(fitted)} if len(pooled) >= 3 else None,
        "pooled_all": moments(pooled.ravel(), rng) if len(pooled) >= 3 else None,
        "pooled_null_excess_kurtosis_95": null_pooled_kurtosis([len(z) for z in standardised], rng)
        if standardised
        else None,
        "wall_time_s": time.perf_counter() - start,
    }
    path = write_result(
        "water_summary_noise",
        payload,
        quick=args.quick,
        inputs=[*DATA_FILES[args.data], RESULTS / f"{args.model_choice}.json"],
        command=command_line(argv),
    )
    print(json.dumps({"pooled_all": payload["pooled_all"]}, indent=1))
    print(f"wrote {path}")
    return payload


if __name__ == "__main__":
    main()
