"""Model criticism of the preferred water model on the joint measured data (issue 17).

Starts from ``benchmarks/water_model_choice.py``'s result: the model with the highest
probability (or ``--model``) and its surrogate posterior of (sigma_OO, epsilon_OO), fitted to
the joint summaries the data file marks *fitted* (g(r) statistics, self-diffusion, enthalpy of
vaporisation), the density held out.  Then :func:`jaxabc.criticism.critique` with the water
catalogue for that model (:func:`md.water.joint_criticism.joint_catalogue`: hydrogen charge,
M site, effective temperature, finite-box diffusion, O-H contamination of the X-ray g_OO):
posterior predictive, misfits, ranked causes, the extension of the top cause, and the gain on
the held-out density.  Both refits (base and extended) go through the GP surrogate
(``--refit-budget`` GROMACS runs each, 2000 draws), so their ESS is in the thousands, not 2.
The base posterior is already such a fit: the model choice's surrogate posterior, on the same
fitted summaries with the same measurement errors, 2000 draws and a 200-run budget.  So by
default the gain compares the extension's refit with it and the base is not refit again
(about 300 GROMACS runs saved); ``--refit-base`` refits it with the criticism's own seed.

The measurement errors the data state are added to every simulation, as in the model choice
(:class:`jaxabc.noise.MeasurementError`).  Every simulation is cached under ``--cache-dir``
(keyed by model, protocol, key and parameters), so rerunning the same command after an
interruption replays the finished simulations and continues.

Usage::

    python -m benchmarks.criticism_water_joint --data xray --workers 2    # hours of GROMACS
    python -m benchmarks.criticism_water_joint --tiny                     # plumbing smoke test

``--model M --name criticism_water_joint_m`` criticises another model into its own result.

``--tiny`` uses 2 ps runs, a handful of draws and the tiny model-choice result
(``water_model_choice.py --tiny``); its numbers mean nothing.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import jaxabc
from benchmarks._common import QUICK_RESULTS, RESULTS, RUNS, command_line, model_selection_record, write_result
from benchmarks._water_model_choice_paths import model_choice_folder, physical_marginal
from jaxabc.criticism import critique
from jaxabc.model_choice import load_model_choice
from jaxabc.noise import MeasurementError
from md.water.joint_criticism import WaterModelWithEffects
from md.water.joint_data import JOINT_DATA_FILE, joint_observed, joint_record
from md.water.model_simulator import CachedSummaries

ROOT = Path(__file__).resolve().parents[1]

GROUPS = {
    "g_OH (S1-S3)": [0, 1, 2],
    "g_OO overall (S4)": [3],
    "g_OO first shell (S5-S8)": [4, 5, 6, 7],
    "self-diffusion": [8],
    "density": [9],
    "enthalpy of vaporisation": [10],
}


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--data", choices=("xray", "neutron"), default="xray")
    p.add_argument("--model", default=None, help="default: the most probable model of the model choice")
    p.add_argument("--model-choice", type=Path, default=None, help="saved model-choice folder")
    p.add_argument(
        "--model-choice-result",
        default="water_model_choice",
        help="or the registry result whose saved model choice to start from (e.g. water_model_choice_no_discrepancy)",
    )
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--num-draws", type=int, default=100)
    p.add_argument("--num-replicates", type=int, default=64)
    p.add_argument("--num-gradient-replicates", type=int, default=8)
    p.add_argument("--num-refit-iterations", type=int, default=2)
    p.add_argument("--refit-budget", type=int, default=200, help="GROMACS runs per surrogate refit")
    p.add_argument(
        "--refit-base",
        action="store_true",
        help="also refit the base model (default: the model choice's own surrogate posterior is the base)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--name",
        default="criticism_water_joint",
        help="result name: <name>.json and the report folder <name>_<data>/ (one per criticised model)",
    )
    p.add_argument("--cache-dir", type=Path, default=None)
    p.add_argument("--tiny", action="store_true", help="smoke test: 2 ps runs, tiny budgets, quick JSON")
    args = p.parse_args(argv)
    suffix = f"{args.data}_quick" + ("_tiny" if args.tiny else "")
    # The folder the registry's model choice saved (its JSON records it), or the smoke test's.
    args.model_choice = args.model_choice or model_choice_folder(args.data, args.tiny, args.model_choice_result)
    args.cache_dir = args.cache_dir or (RUNS / "criticism_water_joint" / suffix)
    if args.tiny:
        args.num_draws, args.num_replicates, args.num_gradient_replicates = 10, 12, 2
        args.num_refit_iterations, args.refit_budget = 1, 80
    return args


def main(argv=None) -> dict:
    args = parse_args(argv)
    t0 = time.perf_counter()
    if args.tiny and not (args.model_choice / "model_choice.json").exists():
        # The smoke test needs the tiny model choice (minutes): run it, or replay its checkpoints.
        from benchmarks import water_model_choice

        water_model_choice.main(["--tiny", "--resume", "--no-progress", "--workers", str(args.workers)])
    choice = load_model_choice(args.model_choice)
    name = args.model or choice.best
    base = physical_marginal(choice.posterior(name))
    data = joint_observed(args.data)
    overrides = {"num_steps": 1000, "analysis_start_ps": 0.4} if args.tiny else {}
    effects = WaterModelWithEffects(name, "quick", "robust", args.data, **overrides)
    cached = CachedSummaries(effects, np.ones(len(data.names), bool), args.cache_dir)
    sd = np.where(np.isfinite(data.errors), data.errors, 0.0)
    simulate = MeasurementError(cached, sd)
    catalogue = effects.catalogue
    measured = data.observed != 0.0  # X-ray: S1..S3 unmeasured, 0.0 in data and simulation
    held_out = data.held_out & measured
    executor = jaxabc.ProcessPoolExecutor(max_workers=args.workers, timeout=effects.protocol.timeout_s + 60)
    try:
        report = critique(
            base,
            simulate,
            data.observed,
            catalogue,
            held_out=held_out,
            seed=args.seed,
            summary_names=list(data.names),
            groups=GROUPS,
            num_draws=args.num_draws,
            num_replicates=args.num_replicates,
            num_gradient_replicates=args.num_gradient_replicates,
            num_refit_iterations=args.num_refit_iterations,
            refit_base=args.refit_base,
            executor=executor,
            extend_options=dict(
                algorithm="surrogate",
                num_particles=2000,
                max_simulations=args.refit_budget,
                max_failure_fraction=0.95,
            ),
        )
    finally:
        executor.close()
    folder = QUICK_RESULTS if args.tiny else RESULTS
    out_dir = folder / f"{args.name}_{args.data}"
    report.write(out_dir)
    base_source = "refit by the criticism" if report.base_refit is not None else "the model choice's posterior"
    refits = {
        label: None
        if res is None
        else {
            "algorithm": res.algorithm,
            "num_simulations": res.num_simulations,
            "ess": res.effective_sample_size(),
            "validated": res.diagnostics.get("validated"),
            "source": source,
        }
        for label, res, source in (
            ("extension", report.extension, "refit by the criticism"),
            ("base", report.base_refit or base, base_source),
        )
    }
    payload = {
        "benchmark": args.name,
        "data": args.data,
        **model_selection_record(choice, name, bool(args.model), args.model_choice),
        "preset": "quick" + (" (tiny smoke: 2 ps runs, numbers meaningless)" if args.tiny else ""),
        "summaries": {
            "names": list(data.names),
            "observed": data.observed.tolist(),
            "fitted": [n for n, f in zip(data.names, data.fitted & measured, strict=True) if f],
            "held_out": [n for n, h in zip(data.names, held_out, strict=True) if h],
            "measurement_sd_added": sd.tolist(),
        },
        "data_record": joint_record(),
        "catalogue": [e.name for e in catalogue],
        "refits": refits,
        "budget": {
            k: getattr(args, k)
            for k in (
                "num_draws",
                "num_replicates",
                "num_gradient_replicates",
                "num_refit_iterations",
                "refit_budget",
                "refit_base",
                "workers",
            )
        },
        "wall_time_s": time.perf_counter() - t0,
        **report.to_dict(),
    }
    path = write_result(
        folder / f"{args.name}.json",
        json.loads(json.dumps(payload, default=float)),
        inputs=[JOINT_DATA_FILE, args.model_choice / "model_choice.json"],
        command=command_line(argv),
    )
    print(report.verdict)
    print(f"wrote {path}")
    return payload


if __name__ == "__main__":
    main()
