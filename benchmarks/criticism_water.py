"""Model criticism of calibrated TIP4P water (issue 6): what it gets wrong, why, and the gain.

On the X-ray (Skinner 2013) or neutron (Soper 2013) data, with GROMACS's ``quick`` preset
(216 molecules, 20 ps: a preset for turnaround, not for production numbers, and the report
says so):

1. calibrate (sigma_OW, epsilon_OW) with APMCABC on the g_OO/g_OH statistics (S1..S8; S1..S3
   are not measured by X-ray), holding out self-diffusion (S9) and the density;
2. :func:`jaxabc.criticism.critique` with the water catalogue of
   :mod:`md.criticism_catalogue` (hydrogen-charge scaling, M-site shift, O-H contamination of
   the X-ray g_OO) -- posterior predictive, calibrated misfits, ranked causes, refit of the top
   cause, held-out gain;
3. write ``benchmarks/results/criticism_water_<data>.json`` (or ``criticism_water.json`` for
   the X-ray default) and the Markdown/PNG report in ``benchmarks/results/criticism_water_<data>/``.

Cost: every simulation is one GROMACS run (~10 s on one core with ``quick``); the default
budget is a few thousand runs, for a cluster or a long afternoon on a workstation.  ``--tiny``
runs the whole loop with a handful of very short runs (a smoke test of the plumbing, numbers
meaningless).

Usage::

    python -m benchmarks.criticism_water --data xray --workers 16
    python -m benchmarks.criticism_water --tiny
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import jaxabc
from benchmarks._common import QUICK_RESULTS, command_line, declare_input, write_result
from jaxabc.criticism import critique
from md.water.criticism import WaterSimulatorWithEffects, water_catalogue

RESULTS = Path(__file__).resolve().parent / "results"
#: Density of water at 298.15 K, 1 atm (kg/m^3).
DENSITY_298K = 997.05
PRIOR_LOW, PRIOR_HIGH = (0.281, 0.2), (0.53, 0.9)


class BaseWater:
    """Picklable base simulator: effects at null, fitted summaries only (for jaxabc.run)."""

    def __init__(self, simulate: WaterSimulatorWithEffects, num_effects: int, fitted: np.ndarray):
        self.simulate, self.num_effects, self.fitted = simulate, num_effects, np.asarray(fitted)

    def __call__(self, key, theta) -> np.ndarray:
        full = np.concatenate([np.asarray(theta, np.float64), np.zeros(self.num_effects)])
        return self.simulate(key, full)[self.fitted]


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", choices=("xray", "neutron"), default="xray")
    p.add_argument("--statistics", choices=("robust", "paper"), default="robust")
    p.add_argument("--workers", type=int, default=None, help="process-pool workers (default: all cores)")
    p.add_argument("--num-particles", type=int, default=100)
    p.add_argument("--num-steps", type=int, default=None, help="APMCABC step cap (default: acceptance rule)")
    p.add_argument("--num-draws", type=int, default=100)
    p.add_argument("--num-replicates", type=int, default=64)
    p.add_argument("--num-gradient-replicates", type=int, default=16)
    p.add_argument(
        "--base-result",
        type=Path,
        default=None,
        help="reuse a saved base calibration (.npz); give --held-out to match what it fitted",
    )
    p.add_argument(
        "--held-out",
        choices=("diffusion+density", "density"),
        default="diffusion+density",
        help="summaries never fitted (density: for a base fit that used S9, such as "
        "water_calibration.py's robust runs)",
    )
    p.add_argument("--num-refit-iterations", type=int, default=3, help="Gauss-Newton steps before testing")
    p.add_argument(
        "--refit-particles", type=int, default=None, help="particles of the two refits (default --num-particles)"
    )
    p.add_argument("--refit-steps", type=int, default=None, help="APMCABC step cap of the refits")
    p.add_argument("--refit-alpha", type=float, default=None, help="APMCABC alpha of the refits (default 0.1)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--tiny",
        action="store_true",
        help="smoke run: tiny budgets and 5 ps GROMACS runs, written to results/quick/ (the quick mode)",
    )
    return p.parse_args(argv)


def main(argv=None) -> dict:
    args = parse_args(argv)
    from md.water import datasets

    overrides = {}
    if args.tiny:
        overrides = {"num_steps": 2500, "analysis_start_ps": 1.0}  # 5 ps with the quick preset's 2 fs step
        # 20 particles: APMCABC keeps N alpha >= 2 (alpha 0.1), and most prior draws vaporise.
        args.num_particles, args.num_steps, args.num_draws = 20, 2, 10  # the predictive needs 10 draws
        args.num_replicates, args.num_gradient_replicates = 12, 4
    simulate = WaterSimulatorWithEffects("quick", args.statistics, args.data, with_density=True, **overrides)
    catalogue = water_catalogue()
    observed = np.append(datasets.observed_statistics(args.data, args.statistics), DENSITY_298K)
    names = list(WaterSimulatorWithEffects.NAMES)
    held_out = np.zeros(observed.size, bool)
    # Never fitted, the main evidence: S9 (self-diffusion) and the density, or the density alone
    # when the reused base fit used S9 (declaring a fitted summary held out would overstate it).
    held_out[[8, 9] if args.held_out == "diffusion+density" else [9]] = True
    measured = observed != 0.0  # X-ray: S1..S3 unmeasured (0.0 in both vectors)
    fitted = measured & ~held_out
    groups = {
        "g_OH (S1-S3)": [0, 1, 2],
        "g_OO first shell (S5-S8)": [4, 5, 6, 7],
        "g_OO overall (S4)": [3],
        "self-diffusion": [8],
        "density": [9],
    }
    executor = jaxabc.ProcessPoolExecutor(args.workers) if args.workers else "process_pool"
    prior = jaxabc.Uniform(PRIOR_LOW, PRIOR_HIGH, names=("sigma_ow_nm", "epsilon_ow_kj_mol"), units=("nm", "kJ/mol"))
    t0 = time.perf_counter()
    if args.base_result is not None:
        base = jaxabc.load(args.base_result)
    else:
        scale = np.where(fitted, np.abs(observed) + 1e-12, 1.0)[fitted]
        base = jaxabc.run(
            "apmcabc",
            BaseWater(simulate, len(catalogue), fitted),
            prior,
            observed[fitted] / 1.0,
            num_particles=args.num_particles,
            num_steps=args.num_steps,
            distance=jaxabc.distances.standardized_euclidean(scale),
            seed=args.seed,
            executor=executor,
            max_failure_fraction=0.95,
        )
    report = critique(
        base,
        simulate,
        observed,
        catalogue,
        held_out=held_out,
        seed=args.seed,
        summary_names=names,
        groups=groups,
        num_draws=args.num_draws,
        num_replicates=args.num_replicates,
        num_gradient_replicates=args.num_gradient_replicates,
        num_refit_iterations=1 if args.tiny else args.num_refit_iterations,
        executor=executor,
        extend_options=dict(
            num_particles=args.refit_particles or args.num_particles,
            num_steps=args.refit_steps or args.num_steps,
            max_failure_fraction=0.95,
            **({"alpha": args.refit_alpha} if args.refit_alpha else {}),
        ),
    )
    tag = "" if args.data == "xray" else f"_{args.data}"
    folder = QUICK_RESULTS if args.tiny else RESULTS
    out_dir = folder / f"criticism_water{tag}"
    report.write(out_dir)
    payload = {
        "benchmark": "criticism_water",
        "data": args.data,
        "statistics": args.statistics,
        "preset": "quick" + (" (tiny smoke: 2 ps runs, numbers meaningless)" if args.tiny else ""),
        "observed": observed.tolist(),
        "held_out": [n for n, h in zip(names, held_out, strict=True) if h],
        "base_result": str(args.base_result) if args.base_result else "fitted here (APMCABC, standardised |S|)",
        "budget": {
            k: getattr(args, k)
            for k in (
                "num_particles",
                "num_steps",
                "num_draws",
                "num_replicates",
                "num_gradient_replicates",
                "num_refit_iterations",
                "refit_particles",
                "refit_steps",
                "refit_alpha",
                "workers",
            )
        },
        "wall_time_s": time.perf_counter() - t0,
        **report.to_dict(),
    }
    declare_input(datasets.DATA_DIR)
    write_result(
        folder / f"criticism_water{tag}.json",
        payload,
        inputs=[args.base_result] if args.base_result else [],
        command=command_line([__file__, *(argv if argv is not None else sys.argv[1:])]),
    )
    print(report.verdict)
    return payload


if __name__ == "__main__":
    main()
