"""The paper's helium Table 1 on a CPU: APMCABC against ABCsubsim on the same problem.

Both algorithms calibrate (sigma, epsilon) of the helium Lennard-Jones model from the same
'observed' f_B series (simulated at sigma 0.2556 nm, epsilon 0.141 zJ with a run
``observed_factor`` times longer than the model's, as in the paper), with the same prior,
KL-divergence distance, particle count and N_step = 6; APMCABC uses alpha 0.1 and acceptance
cutoff 0.03, ABCsubsim P0 = 0.2.  For each algorithm the JSON holds d_E (Euclidean distance of
the Bayes estimate from the truth, in nm and zJ as in the paper), gamma_final (the final
threshold), simulations, wall time, the Bayes estimate and the posterior correlation; the
figure is the paper's Figure 5 (posterior contours, Bayes estimate, truth) for both.

Paper (5000 particles, 1000 atoms, 5 ns runs vs a 20 ns observed run): APMCABC d_E 0.00744,
gamma_final 0.0138; ABCsubsim (as reported by Kulakova et al. 2016) d_E 0.03365,
gamma_final 0.67.

Usage::

    python -m benchmarks.helium_table1                      # cpu64 preset, 300 particles
    python -m benchmarks.helium_table1 --num-particles 1000
    python -m benchmarks.helium_table1 --quick              # 50 particles, 3 steps, seed 0: ~1 min,
                                                            # writes benchmarks/results/quick/ only
    python -m benchmarks.helium_table1 --preset cpu64 --num-particles 25000 --batch-size 5000 \
        --output OUT/helium_table1.json                     # on a GPU (members per compiled batch)

``--batch-size`` only sets how many members run in one compiled batch: a member's trajectory does
not depend on which others share its batch (``md.helium.make_batch_simulator``), so it changes
the speed, not the result (up to the device's floating-point arithmetic).  After every seed the
rows so far are written to ``helium_table1.partial.json`` beside the output, so a run stopped early keeps its seeds.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

import jaxabc
from benchmarks._common import RESULTS, relative, write_result
from md import helium
from md.helium_calibration import make_model

PAPER = {"apmcabc": {"d_E": 0.00744, "gamma_final": 0.0138}, "abcsubsim": {"d_E": 0.03365, "gamma_final": 0.67}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--num-particles", type=int, default=300)
    parser.add_argument("--num-steps", type=int, default=6)
    parser.add_argument("--preset", default="cpu64", help="helium preset (md.helium.PRESETS)")
    parser.add_argument(
        "--seeds",
        type=int,
        nargs="+",
        default=[0, 1, 2],
        help="independent repetitions (observed data and inference); the figure and the "
        "saved result files are the first seed's",
    )
    parser.add_argument(
        "--batch-size",
        type=int,
        default=None,
        help="members per compiled batch (default: the preset's); speed only, not the result",
    )
    parser.add_argument(
        "--output",
        type=Path,
        default=None,
        help="result JSON (default benchmarks/results/helium_table1.json); the figure and the "
        "posterior files go beside it",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="reproduction check: 50 particles, 3 steps, seed 0, written to results/quick/ (no figure or .npz)",
    )
    args = parser.parse_args()
    if args.quick:
        args.num_particles, args.num_steps, args.seeds = 50, 3, [0]
    if args.num_particles % 5:
        parser.error("--num-particles must be a multiple of 5 (ABCsubsim with P0 = 0.2)")
    preset = helium.get_preset(args.preset)
    if args.batch_size is not None:
        preset = helium.get_preset(preset, batch_size=args.batch_size)
    simulate, prior = make_model(preset)
    truth = np.asarray(helium.TRUE_THETA)
    out_dir = RESULTS if args.output is None else args.output.parent
    partial = None if args.quick else (out_dir / "helium_table1.partial.json")
    t_start = time.perf_counter()
    per_seed = []
    for seed in args.seeds:
        rows, results, observed_len = run_seed(simulate, prior, truth, args, seed)
        per_seed.append({"seed": seed, "algorithms": rows})
        if seed == args.seeds[0]:
            first_rows, first_results = rows, results
        if seed == args.seeds[0] and not args.quick:
            for name, result in results.items():
                result.save(out_dir / f"helium_table1_{name}.npz", overwrite=True)
            draw_figure(results, truth, out_dir / "helium_table1.png")
        if partial is not None:
            partial.write_text(
                json.dumps({"per_seed": per_seed, "wall_s": time.perf_counter() - t_start}, default=float)
            )
    summary = {}
    for name in ("apmcabc", "abcsubsim"):
        for key in ("d_E", "gamma_final", "simulations", "wall_time_s", "effective_sample_size"):
            vals = np.array([p["algorithms"][name][key] for p in per_seed], dtype=float)
            summary[f"{name}_{key}_mean"] = float(vals.mean())
            summary[f"{name}_{key}_sd"] = float(vals.std(ddof=1)) if vals.size > 1 else None
        summary[f"{name}_effective_sample_size_min"] = float(
            min(p["algorithms"][name]["effective_sample_size"] for p in per_seed)
        )
        # Coverage of the truth: the share of repetitions whose 95 % interval holds it, per parameter.
        covered = np.array([p["algorithms"][name]["truth_in_95_interval"] for p in per_seed], dtype=float)
        summary[f"{name}_coverage_95"] = covered.mean(axis=0).tolist()
    ratios_gamma = [
        p["algorithms"]["apmcabc"]["gamma_final"] / p["algorithms"]["abcsubsim"]["gamma_final"] for p in per_seed
    ]
    ratios_de = [p["algorithms"]["apmcabc"]["d_E"] / p["algorithms"]["abcsubsim"]["d_E"] for p in per_seed]
    checks = {
        "gamma_ratio_apmc_over_subsim_per_seed": ratios_gamma,
        "dE_ratio_apmc_over_subsim_per_seed": ratios_de,
        "target_gamma_ratio_at_most": 0.1,
        "target_dE_ratio_at_most": 0.5,
        "gamma_target_met_all_seeds": bool(all(r <= 0.1 for r in ratios_gamma)),
        "dE_target_met_all_seeds": bool(all(r <= 0.5 for r in ratios_de)),
    }
    path = write_result(
        "helium_table1" if args.output is None else args.output,
        {
            "description": __doc__.split("\n\n")[0],
            "setup": {
                "preset": args.preset,
                "preset_fields": preset.__dict__,
                "device": _device(),
                "num_particles": args.num_particles,
                "num_steps": args.num_steps,
                "seeds": args.seeds,
                "distance": "kl",
                "truth": truth.tolist(),
                "prior_low": list(helium.PRIOR_LOW),
                "prior_high": list(helium.PRIOR_HIGH),
                "observed_length": observed_len,
            },
            "algorithms": first_rows,
            "per_seed": per_seed,
            "summary_over_seeds": summary,
            "comparison": checks,
            "paper": PAPER,
            "figure": None if args.quick else relative(out_dir / "helium_table1.png"),
            "total_wall_time_s": time.perf_counter() - t_start,
        },
        quick=args.quick,
    )
    del first_results
    if partial is not None:
        partial.unlink(missing_ok=True)
    print(f"wrote {path}")


def _device() -> dict:
    d = jax.devices()[0]
    return {"platform": d.platform, "device_kind": d.device_kind}


def run_seed(simulate, prior, truth: np.ndarray, args, seed: int):
    """Both algorithms on one observed data set (its own key), with the same inference seed."""
    observed = helium.observed_series(jax.random.key(10_000 + seed), args.preset)
    rows, results = {}, {}
    for algorithm, options in (("apmcabc", {"alpha": 0.1, "acceptance_cutoff": 0.03}), ("abcsubsim", {"p0": 0.2})):
        result = jaxabc.run(
            algorithm,
            simulate,
            prior,
            observed,
            num_particles=args.num_particles,
            num_steps=args.num_steps,
            distance="kl",
            seed=seed,
            keep_summaries=False,
            progress=True,
            **options,
        )
        results[algorithm] = result
        est = result.bayes_estimate()
        ci = np.asarray(result.credible_interval(0.95))
        rows[algorithm] = {
            "d_E": float(np.linalg.norm(est - truth)),
            "gamma_final": float(result.thresholds[-1]),
            "num_steps": len(result.thresholds),
            "simulations": int(result.num_simulations),
            "failures": int(result.num_failures),
            "wall_time_s": float(result.wall_time),
            "bayes_estimate": est.tolist(),
            "credible_interval_95": ci.tolist(),
            "truth_in_95_interval": ((ci[:, 0] <= truth) & (truth <= ci[:, 1])).tolist(),
            "posterior_sd": np.sqrt(np.diag(result.covariance())).tolist(),
            "correlation": float(result.correlation()[0, 1]),
            # ABCsubsim chains that rarely move leave duplicates: the distinct count and the ESS
            # say how many particles the posterior really rests on.
            "distinct_particles": len(np.unique(result.particles, axis=0)),
            "effective_sample_size": result.effective_sample_size(),
            "acceptance_rates": result.acceptance_rates.tolist(),
            "thresholds": result.thresholds.tolist(),
            "simulations_per_step": result.simulations_per_step.tolist(),
            "stop_reason": result.stop_reason,
            "log_evidence": result.log_evidence,
            "paper": PAPER[algorithm],
        }
        print(
            seed,
            algorithm,
            {k: rows[algorithm][k] for k in ("d_E", "gamma_final", "simulations", "wall_time_s")},
            flush=True,
        )
    return rows, results, int(observed.size)


def draw_figure(results: dict, truth: np.ndarray, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(5 * len(results), 4))
    for ax, (name, result) in zip(np.atleast_1d(axes), results.items(), strict=True):
        result.plot_posterior(ax=ax, truth=truth)
        ax.set_title(f"{name}: gamma_final {result.thresholds[-1]:.3g}, corr {result.correlation()[0, 1]:+.2f}")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
