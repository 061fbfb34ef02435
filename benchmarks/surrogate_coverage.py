"""Do the surrogate's 95 % intervals hold the truth 95 % of the time?  Simulation-based calibration.

The pure-JAX toy of ``benchmarks/coverage.py``: ``x = theta + L z`` with ``Cov(L z) = [[1, 0.8],
[0.8, 1]]`` and a flat prior U[-10, 10]^2; data uniform in [-6, 6]^2, then the truth from the exact
posterior ``N(x, Sigma)`` (``jaxabc.examples.correlated_truth_and_data``), so every (truth, data)
pair is an exact draw and a calibrated method's ``q`` intervals hold the truth in a fraction ``q``
of the data sets.

``jaxabc.coverage_study`` vmaps a fused algorithm over all data sets at once; the surrogate is
host code (scipy fits, a NUTS sampler per run) and cannot be vmapped, so this script runs
``jaxabc.run("surrogate", ...)`` once per data set and fills the same
:class:`jaxabc.coverage.CoverageStudy` record (HPD levels from ``credible_level``, equal-tailed
intervals from ``credible_interval``).  ``jaxabc.coverage_study("apmcabc", ...)`` on the same data
sets (same seed) is the reference: APMCABC with as many simulations per data set as it needs.

Coverage fractions come with their binomial standard error ``sqrt(p (1 - p) / R)``; the pooled
figure over both parameters counts ``2 R`` intervals, which are correlated within a data set, so
its quoted error is a lower bound.

Usage::

    python -m benchmarks.surrogate_coverage --datasets 40    # about 20 min of CPU
    python -m benchmarks.surrogate_coverage --quick          # 6 data sets: results/quick/
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import numpy as np

import jaxabc
from benchmarks._common import command_line, write_result
from jaxabc.coverage import CoverageStudy
from jaxabc.examples import correlated_simulate, correlated_truth_and_data

ROOT = Path(__file__).resolve().parents[1]

INTERVAL_LEVELS = (0.5, 0.9, 0.95)
PROBLEM = (
    "x = theta + L z, Cov = [[1, 0.8], [0.8, 1]], prior U[-10, 10]^2; data uniform in [-6, 6]^2, "
    "truth from the exact posterior N(x, Sigma)"
)


def surrogate_study(args, prior) -> tuple[CoverageStudy, dict]:
    """One surrogate run per data set; the record of :func:`jaxabc.coverage_study`."""
    keys = jax.random.split(jax.random.key(args.seed), args.datasets)
    truths, observed, levels, thresholds, ess, sizes, rounds = [], [], [], [], [], [], []
    inside = {q: [] for q in INTERVAL_LEVELS}
    sims, validated, seconds = [], [], []
    for r in range(args.datasets):
        # coverage_study splits each data set's key in three and draws the data with the first.
        truth, obs = (np.asarray(a, np.float64) for a in correlated_truth_and_data(jax.random.split(keys[r], 3)[0]))
        t0 = time.perf_counter()
        result = jaxabc.run(
            "surrogate",
            correlated_simulate,
            prior,
            obs,
            max_simulations=args.budget,
            num_particles=args.particles,
            seed=args.seed + r,
            mode=args.mode,
            abc_distance="euclidean",
        )
        seconds.append(time.perf_counter() - t0)
        truths.append(truth)
        observed.append(obs)
        levels.append(result.credible_level(truth))
        for q in INTERVAL_LEVELS:
            ci = result.credible_interval(q)
            inside[q].append((ci[:, 0] <= truth) & (truth <= ci[:, 1]))
        thresholds.append(float(result.thresholds[-1]))
        ess.append(result.effective_sample_size())
        sizes.append(result.particles.shape[0])
        rounds.append(int(result.diagnostics.get("rounds", 0)))
        sims.append(int(result.num_simulations))
        validated.append(bool(result.diagnostics.get("validated", False)))
        so_far = np.mean(inside[0.95])
        print(
            f"data set {r + 1}/{args.datasets}: {sims[-1]} simulations, validated {validated[-1]}, "
            f"{seconds[-1]:.0f} s; 95 % intervals so far {so_far:.3f}",
            flush=True,
        )
    study = CoverageStudy(
        truths=np.array(truths),
        observed=np.array(observed),
        levels=np.array(levels),
        inside_intervals={q: np.array(v) for q, v in inside.items()},
        thresholds=np.array(thresholds),
        generations=np.array(rounds),
        ess=np.array(ess),
        posterior_size=np.array(sizes),
        settings={
            "algorithm": "surrogate",
            "mode": args.mode,
            "num_particles": args.particles,
            "max_simulations": args.budget,
            "seed": args.seed,
            "data": "jaxabc.examples.correlated_truth_and_data",
        },
    )
    extra = {
        "simulations_per_dataset": {"median": float(np.median(sims)), "max": int(np.max(sims))},
        "validated_fraction": float(np.mean(validated)),
        "seconds_per_dataset": {"median": float(np.median(seconds)), "total": float(np.sum(seconds))},
    }
    return study, extra


def pooled(study: CoverageStudy, level: float) -> list[float]:
    """Coverage over all parameters and data sets, and its (lower-bound) binomial error."""
    hits = study.inside_intervals[level]
    p = float(hits.mean())
    return [p, float(np.sqrt(max(p * (1 - p), 1e-12) / hits.size))]


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--datasets", type=int, default=40)
    parser.add_argument("--budget", type=int, default=200, help="max_simulations per surrogate run")
    parser.add_argument("--particles", type=int, default=1000)
    parser.add_argument("--mode", choices=("synthetic_likelihood", "abc"), default="synthetic_likelihood")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-reference", action="store_true", help="skip the APMCABC coverage_study")
    parser.add_argument("--output", type=Path, default=None)
    parser.add_argument("--quick", action="store_true", help="6 data sets, written to results/quick/")
    args = parser.parse_args(argv)
    if args.quick:
        args.datasets = 6
    name = "surrogate_coverage" if args.mode == "synthetic_likelihood" else "surrogate_coverage_abc"
    prior = jaxabc.Uniform([-10.0, -10.0], [10.0, 10.0], names=("a", "b"))
    study, extra = surrogate_study(args, prior)
    out = {
        "problem": PROBLEM,
        "surrogate": {
            **study.to_dict(),
            **extra,
            "interval_coverage_pooled": {str(q): pooled(study, q) for q in INTERVAL_LEVELS},
        },
    }
    if not args.no_reference:
        t0 = time.perf_counter()
        reference = jaxabc.coverage_study(
            "apmcabc",
            correlated_simulate,
            prior,
            num_datasets=args.datasets,
            num_particles=args.particles,
            num_steps=10,
            seed=args.seed,
            sample_data=correlated_truth_and_data,
            interval_levels=INTERVAL_LEVELS,
            alpha=0.1,
        )
        out["apmcabc_reference"] = {
            **reference.to_dict(),
            "interval_coverage_pooled": {str(q): pooled(reference, q) for q in INTERVAL_LEVELS},
            "seconds": time.perf_counter() - t0,
        }
        same = np.allclose(reference.observed, study.observed)
        out["apmcabc_reference"]["same_datasets"] = bool(same)
    pooled95 = out["surrogate"]["interval_coverage_pooled"]["0.95"]
    print(f"surrogate 95 % interval coverage (pooled): {pooled95[0]:.3f} +- {pooled95[1]:.3f}")
    path = write_result(
        args.output or name,
        out,
        quick=args.quick and args.output is None,
        command=None if argv is None else command_line([__file__, *argv]),
    )
    print(f"wrote {path}")
    return out


if __name__ == "__main__":
    main()
