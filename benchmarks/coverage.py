"""How often do APMCABC's credible regions hold the truth?  Simulation-based calibration.

The analytic problem of the test suite: ``x = theta + L z`` with ``Cov(L z) = [[1, 0.8], [0.8, 1]]``
and a flat prior U[-10, 10]^2.  Data first, then the truth from the exact posterior
``N(x, Sigma)`` (data drawn in [-6, 6]^2, so the prior box never truncates it), so every
(truth, data) pair is an exact draw.  For each setting, ``jaxabc.coverage_study`` runs the
algorithm on 400 data sets at once and records how often the ``q`` HPD region and the
equal-tailed ``q`` intervals hold the truth.  The analytic ABC posterior at each run's final
tolerance, ``N(x, Sigma + eps^2/4 I)`` (the exact posterior convolved with the tolerance disc,
Gaussian-approximated), says what a perfect ABC sampler would cover; rejection ABC with as
many particles as APMCABC keeps (``N alpha``) separates the algorithm from the sample size.

The water calibrations use APMCABC with N = 100, alpha = 0.1: a final posterior of 10
particles.  This benchmark measures what their "95 % intervals" are worth.

Usage::

    python -m benchmarks.coverage            # about 3 minutes on 2 cores
    python -m benchmarks.coverage --quick    # 40 data sets, N = 100: results/quick/coverage.json
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import jaxabc
from benchmarks._common import command_line, write_result
from jaxabc.examples import correlated_simulate, correlated_truth_and_data

ROOT = Path(__file__).resolve().parents[1]

RESULTS = ROOT / "benchmarks" / "results"
SIGMA = np.array([[1.0, 0.8], [0.8, 1.0]])
LEVELS = (0.5, 0.8, 0.9, 0.95)


def abc_prediction(thresholds: np.ndarray, seed: int) -> dict:
    """HPD coverage of the analytic ABC posterior N(x, Sigma + eps^2/4 I) for a truth from
    N(x, Sigma), averaged over the runs' final tolerances."""
    from scipy.stats import chi2

    z = np.random.default_rng(seed).multivariate_normal(np.zeros(2), SIGMA, 200_000)
    out = {str(q): 0.0 for q in LEVELS}
    for eps in thresholds:
        prec = np.linalg.inv(SIGMA + eps**2 / 4.0 * np.eye(2))
        level = chi2.cdf(np.einsum("ij,jk,ik->i", z, prec, z), 2)
        for q in LEVELS:
            out[str(q)] += float(np.mean(level < q)) / thresholds.size
    return out


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--datasets", type=int, default=400)
    parser.add_argument("--particles", type=int, nargs="+", default=[100, 300, 1000])
    parser.add_argument("--alpha", type=float, default=0.1)
    parser.add_argument("--acceptance-cutoff", type=float, default=0.03)
    parser.add_argument("--steps", type=int, default=10, help="APMCABC step cap (the water runs: 10)")
    parser.add_argument("--rejection-quantile", type=float, default=0.001)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--output", type=Path, default=None, help="default: results/coverage.json")
    parser.add_argument(
        "--quick", action="store_true", help="reproduction check: 40 data sets, N = 100 only, written to results/quick/"
    )
    args = parser.parse_args(argv)
    if args.quick:
        args.datasets, args.particles = 40, [100]
    if args.output is None:
        args.output = RESULTS / ("quick" if args.quick else "") / "coverage.json"

    prior = jaxabc.Uniform([-10.0, -10.0], [10.0, 10.0], names=("a", "b"))
    out = {
        "problem": "x = theta + L z, Cov = [[1, 0.8], [0.8, 1]], prior U[-10, 10]^2, euclidean distance; "
        "data uniform in [-6, 6]^2, truth from the exact posterior N(x, Sigma)",
        "levels": list(LEVELS),
        "cases": [],
    }
    for n in args.particles:
        kept = int(np.ceil(args.alpha * n))
        for name, kwargs in (
            (
                "apmcabc",
                dict(num_particles=n, num_steps=args.steps, alpha=args.alpha, acceptance_cutoff=args.acceptance_cutoff),
            ),
            ("rejection", dict(num_particles=kept, num_steps=1, quantile=args.rejection_quantile)),
        ):
            t0 = time.perf_counter()
            study = jaxabc.coverage_study(
                name,
                correlated_simulate,
                prior,
                num_datasets=args.datasets,
                seed=args.seed,
                sample_data=correlated_truth_and_data,
                **kwargs,
            )
            entry = {
                "algorithm": name,
                **study.to_dict(),
                "seconds": time.perf_counter() - t0,
                "abc_posterior_hpd_coverage": abc_prediction(study.thresholds, args.seed),
            }
            entry["hpd_coverage"] = {str(q): study.hpd_coverage(q) for q in LEVELS}
            out["cases"].append(entry)
            hpd = entry["hpd_coverage"]
            print(
                f"{name:9s} N={kwargs['num_particles']:5d} posterior {entry['median_posterior_size']:.0f} "
                f"(ESS {entry['median_ess']:.1f}), eps {entry['median_threshold']:.3f}: HPD 50/90/95 "
                f"{hpd['0.5'][0]:.3f}/{hpd['0.9'][0]:.3f}/{hpd['0.95'][0]:.3f} "
                f"(ABC posterior {entry['abc_posterior_hpd_coverage']['0.5']:.3f}/"
                f"{entry['abc_posterior_hpd_coverage']['0.9']:.3f}/"
                f"{entry['abc_posterior_hpd_coverage']['0.95']:.3f}), 95 % intervals "
                f"{np.round(entry['interval_coverage']['0.95'][0], 3).tolist()}",
                flush=True,
            )
    write_result(args.output, out, command=None if argv is None else command_line([__file__, *argv]))
    print(f"wrote {args.output}")
    return out


if __name__ == "__main__":
    main()
