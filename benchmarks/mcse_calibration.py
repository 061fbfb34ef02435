"""Calibration of the reported MCSE of the posterior mean (jaxabc issue item 7), printing JSON.

Problem: x = theta + N(0, 1), observation 0, prior U(-10, 10) (jaxabc.examples.gaussian_simulate).
Reference: the ABC posterior's mean is exactly 0 at *every* tolerance (prior and noise are
symmetric about the observation), so each run's estimate is compared with the exact mean of its
own ABC target at its own final threshold -- no long reference run and no ABC-vs-exact
posterior mismatch.  z = (estimate - 0) / reported MCSE per seed; rms z should be about 1.

"old" is the pre-fix MCSE, sqrt(var / ESS) with the result's ESS (unchanged by the fix); "new"
is ``result.mcse()``.  rms z is over the seeds whose MCSE is finite; an infinite MCSE is the
honest answer of a collapsed population (counted in ``n_inf``).

"old" is recomputed from each run's own covariance and ESS, so before and after come from the same
runs (the fix changed no particle).

Usage::

    python -m benchmarks.mcse_calibration                 # 20 and 200 seeds per case
    python -m benchmarks.mcse_calibration --quick         # 20 seeds, under benchmarks/results/quick
"""

from __future__ import annotations

import argparse
import time
import warnings

import jax.numpy as jnp
import numpy as np

import jaxabc
from benchmarks._common import write_result
from jaxabc import examples

CASES = {
    "abcsubsim_N300_5levels": (
        "abcsubsim",
        dict(num_particles=300, p0=0.2, num_steps=6),  # level 0 (prior) + 5 chain levels
    ),
    # Less collapsed ABCsubsim runs, where an MCSE is (sometimes) reported.
    "abcsubsim_N1000_4levels": ("abcsubsim", dict(num_particles=1000, p0=0.2, num_steps=5)),
    "abcsubsim_N2000_3levels": ("abcsubsim", dict(num_particles=2000, p0=0.2, num_steps=4)),
    # APMCABC stopped by its acceptance cutoff (0.03).
    "apmcabc_N300_alpha0.5": ("apmcabc", dict(num_particles=300, alpha=0.5)),
    "apmcabc_N1000_alpha0.1": ("apmcabc", dict(num_particles=1000, alpha=0.1)),
    "apmcabc_N300_alpha0.1": ("apmcabc", dict(num_particles=300, alpha=0.1)),
}


def _stats(est: np.ndarray, mcse: np.ndarray) -> dict:
    finite = np.isfinite(mcse) & (mcse > 0)
    z = est[finite] / mcse[finite]
    return {
        "rms_z": float(np.sqrt(np.mean(z**2))) if z.size else None,
        "n_finite": int(finite.sum()),
        "n_inf": int(np.sum(np.isinf(mcse))),
        "n_zero": int(np.sum(mcse == 0)),
        "n_beyond_4_mcse": int(np.sum(np.abs(est) > 4 * mcse)),
        # How much the error exceeds the reported MCSE, over seeds with a finite one.
        "sd_error_over_rms_mcse": float(np.sqrt(np.mean(est[finite] ** 2)) / np.sqrt(np.mean(mcse[finite] ** 2)))
        if z.size
        else None,
    }


def study(algorithm: str, options: dict, seeds: int) -> dict:
    prior = jaxabc.Uniform(low=[-10.0], high=[10.0], names=("mu",))
    est, old, new, eps, distinct, lineages, steps = [], [], [], [], [], [], []
    for seed in range(seeds):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            r = jaxabc.run(
                algorithm,
                examples.gaussian_simulate,
                prior,
                jnp.array([0.0]),
                distance="euclidean",
                seed=seed,
                **options,
            )
        est.append(float(r.bayes_estimate()[0]))
        old.append(float(np.sqrt(r.covariance()[0, 0] / r.effective_sample_size())))
        new.append(float(r.mcse()[0]))
        eps.append(float(r.thresholds[-1]))
        steps.append(len(r.thresholds))
        distinct.append(int(np.unique(r.particles[r.weights > 0], axis=0).shape[0]))
        lineages.append(r.diagnostics.get("effective_lineages"))
    est_a = np.array(est)
    return {
        "algorithm": algorithm,
        "options": options,
        "seeds": seeds,
        "median_final_threshold": float(np.median(eps)),
        "generations": [int(min(steps)), int(max(steps))],
        "median_distinct_particles": float(np.median(distinct)),
        "median_effective_lineages": None if lineages[0] is None else float(np.median(lineages)),
        "sd_of_estimate": float(np.std(est_a)),
        "before": _stats(est_a, np.array(old)),
        "after": _stats(est_a, np.array(new)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--long", type=int, default=200, help="a second, larger study (0: skip)")
    parser.add_argument("--quick", action="store_true", help="--long 0, written under benchmarks/results/quick")
    args = parser.parse_args()
    if args.quick:
        args.long = 0
    t0 = time.perf_counter()
    out: dict = {
        "problem": "x = theta + N(0,1), observed 0, prior U(-10,10), euclidean distance",
        "reference": "exact ABC-posterior mean 0 at any threshold (symmetry)",
        "z": "estimate / reported MCSE; rms over seeds with a finite MCSE",
        "cases": {},
    }
    for name, (algorithm, options) in CASES.items():
        out["cases"][name] = {f"{args.seeds}_seeds": study(algorithm, options, args.seeds)}
        if args.long:
            out["cases"][name][f"{args.long}_seeds"] = study(algorithm, options, args.long)
    out["wall_s"] = round(time.perf_counter() - t0, 1)
    print(f"wrote {write_result('mcse_calibration', out, quick=args.quick)}")


if __name__ == "__main__":
    main()
