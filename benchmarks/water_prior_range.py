"""How far epsilon_OO can go before the quick box stops being liquid water: the wide prior's basis.

The model choice's wide prior lets each model's O-O Lennard-Jones well depth range over
:data:`md.water.models.WIDE_EPSILON_FACTORS` times its published value, at sigma within its box.
This scan runs every model at its published sigma and epsilon times each ``--factors`` value
(``--seeds`` runs per point, the model choice's protocol: quick preset, the data's temperature, the 14
joint summaries with the Yeh-Hummer corrected D), plus ``--long-ps`` runs at the upper box edge
for TIP4P and TIP3P, whose density after 20 ps is compared with that of a longer run (does the
liquid keep expanding?).  A point is liquid when GROMACS finishes, the simulator raises no
failure (vapour, collapse, crash), the density lies within ``LIQUID_DENSITY_KG_M3`` and the
molecules diffuse (D at least ``MIN_DIFFUSION``).

The verdict names the factors where any model stops being liquid, and how the structure moves
across the box (the first-minimum height and the second-shell peak of g_OO).

Usage (from the repository root)::

    python -m benchmarks.water_prior_range --workers 2       # 50 runs + 2 long ones, ~10 min on 2 cores
    python -m benchmarks.water_prior_range --quick           # TIP4P at the two box edges
"""

from __future__ import annotations

import argparse
import concurrent.futures
import multiprocessing
import re
import time
from pathlib import Path

import numpy as np

from benchmarks._common import command_line, write_result
from md.water.joint_data import JOINT_DATA_FILE, joint_observed
from md.water.model_simulator import JOINT_SUMMARY_NAMES, WaterModelSimulator
from md.water.models import MODELS, WIDE_EPSILON_FACTORS
from md.water.protocol import PRESETS

ROOT = Path(__file__).resolve().parents[1]
#: Densities (kg/m3) a liquid box at ambient pressure may have; outside: vapour-like or collapsed.
LIQUID_DENSITY_KG_M3 = (850.0, 1150.0)
#: Least self-diffusion (1e-5 cm^2/s, Yeh-Hummer corrected) of a liquid: below it, a glass or solid
#: (ice Ih at its melting point diffuses at about 1e-10 cm^2/s).
MIN_DIFFUSION = 0.1
#: Joint summaries reported per point (names of ``JOINT_SUMMARY_NAMES``).
REPORTED = ("density_kg_m3", "hvap_kj_mol", "S9", "S5", "S7", "S8", "g_oo_min1", "r_oo_max2_nm", "g_oo_max2")
#: Failure reasons of the summaries themselves (the run finished; its g_OO lacks what they read).
_UNDEFINED = ("no first peak/minimum found", "no second-shell summaries")


def _one(task: tuple) -> dict:
    """Worker: one GROMACS run of ``model`` at (published sigma, factor x published epsilon)."""
    name, factor, seed, data, temperature_k, num_steps, analysis_start_ps = task
    from jaxabc.errors import SimulationFailure

    model = MODELS[name]
    overrides: dict = {"temperature_k": temperature_k}
    if num_steps is not None:
        overrides |= {"num_steps": num_steps, "analysis_start_ps": analysis_start_ps}
    simulate = WaterModelSimulator(model, "quick", "robust", data, **overrides)
    theta = (model.lj[0], model.lj[1] * factor)
    row: dict = {"model": name, "epsilon_factor": factor, "seed": seed, "theta": [float(t) for t in theta]}
    start = time.perf_counter()
    try:
        key = np.array([0, 7 + seed], np.uint32)
        summaries = np.asarray(simulate(key, np.asarray(theta, np.float64)), np.float64)
        values = dict(zip(JOINT_SUMMARY_NAMES, summaries.tolist(), strict=True))
        row |= {"status": "ok", **{k: values[k] for k in REPORTED}}
        lo, hi = LIQUID_DENSITY_KG_M3
        row["liquid"] = bool(lo <= values["density_kg_m3"] <= hi and values["S9"] >= MIN_DIFFUSION)
    except SimulationFailure as failure:
        reason = str(failure)
        row |= {"status": "failed", "reason": reason, "liquid": False}
        density = re.search(r"density ([0-9.eE+-]+) kg/m3", reason)
        if reason.startswith(_UNDEFINED) and density is not None:
            # A finished run whose g_OO lacks the peak or minimum the summaries read: liquid or not
            # by its density, and a failed run for a calibration either way.
            row["status"], row["density_kg_m3"] = "summaries undefined", float(density.group(1))
            row["liquid"] = bool(LIQUID_DENSITY_KG_M3[0] <= row["density_kg_m3"] <= LIQUID_DENSITY_KG_M3[1])
    row["wall_s"] = time.perf_counter() - start
    return row


def verdict(rows: list[dict], factors: list[float]) -> str:
    """Sentences from the scan: where a model stops being liquid, where the summaries are undefined."""
    box = f"epsilon x[{min(factors):g}, {max(factors):g}]"
    models = ", ".join(dict.fromkeys(r["model"] for r in rows))
    dense = [r["density_kg_m3"] for r in rows if r["liquid"]]
    span = f"{min(dense):.0f}-{max(dense):.0f} kg/m3" if dense else "-"

    def at(r: dict) -> str:
        return f"{r['model']} x{r['epsilon_factor']:g} seed {r['seed']}" + (
            f", {r['length_ps']:g} ps" if "length_ps" in r else ""
        )

    physical = [r for r in rows if not r["liquid"]]
    undefined = [r for r in rows if r["liquid"] and r["status"] != "ok"]
    out = [
        f"{len(rows) - len(physical)} of {len(rows)} runs of {models} over {box} at the published sigma are "
        f"liquid (densities {span}; D at least {MIN_DIFFUSION:g})."
    ]
    if physical:
        out.append(
            "Not liquid: "
            + "; ".join(f"{at(r)} ({r.get('reason') or 'density or D out of range'})" for r in physical)
            + ".  A posterior piled there meets a physical limit."
        )
    else:
        out.append("No run vaporised, collapsed, froze or failed in GROMACS: no physical limit bounds the box.")
    if undefined:
        out.append(
            "Liquid, but its g_OO lacks the peak or minimum the summaries read (a failed run for a calibration, "
            "not a phase limit): " + "; ".join(f"{at(r)} (density {r['density_kg_m3']:.0f})" for r in undefined) + "."
        )
    return "  ".join(out)


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--data", choices=("xray", "neutron"), default="xray", help="whose temperature and summaries")
    p.add_argument("--factors", type=float, nargs="+", default=[WIDE_EPSILON_FACTORS[0], 1.0, 1.6, 2.5, 3.0])
    p.add_argument("--models", nargs="+", default=list(MODELS), choices=list(MODELS))
    p.add_argument("--seeds", type=int, default=2, help="runs (independent keys) per point")
    p.add_argument("--long-ps", type=float, default=60.0, help="length of the upper-edge runs (0: none)")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--quick", action="store_true", help="TIP4P at the box edges only, no long runs")
    p.add_argument("--output", type=Path, default=None, help="result JSON (default: the registry's name)")
    args = p.parse_args(argv)
    if args.quick:
        args.models, args.factors, args.long_ps, args.seeds = ["TIP4P"], list(WIDE_EPSILON_FACTORS), 0.0, 1
    if any(f <= 0 for f in args.factors) or args.seeds < 1:
        raise SystemExit(f"--factors must be positive and --seeds at least 1, got {args.factors}, {args.seeds}")
    start = time.perf_counter()
    data = joint_observed(args.data)
    tasks = [
        (m, f, s, args.data, data.temperature_k, None, None)
        for m in args.models
        for f in args.factors
        for s in range(args.seeds)
    ]
    edge = max(WIDE_EPSILON_FACTORS)
    long_models = [m for m in ("TIP4P", "TIP3P") if m in args.models] if args.long_ps > 0 else []
    steps = round(args.long_ps / PRESETS["quick"].timestep_ps)
    tasks += [(m, edge, 0, args.data, data.temperature_k, steps, args.long_ps / 2) for m in long_models]
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(args.workers, mp_context=context) as pool:
        rows = list(pool.map(_one, tasks))
    scan, long_rows = rows[: len(rows) - len(long_models)], rows[len(rows) - len(long_models) :]
    for row in long_rows:
        short = next(r for r in scan if r["model"] == row["model"] and r["epsilon_factor"] == edge and r["seed"] == 0)
        row["length_ps"], row["analysed_from_ps"] = args.long_ps, args.long_ps / 2
        if row["status"] == "ok" and short["status"] == "ok":
            row["density_change_from_short_kg_m3"] = row["density_kg_m3"] - short["density_kg_m3"]
    payload = {
        "data": args.data,
        "temperature_k": data.temperature_k,
        "preset": "quick",
        "liquid_density_kg_m3": list(LIQUID_DENSITY_KG_M3),
        "min_diffusion_1e5_cm2_s": MIN_DIFFUSION,
        "wide_epsilon_factors": list(WIDE_EPSILON_FACTORS),
        "factors": args.factors,
        "seeds": args.seeds,
        "scan": scan,
        "long_runs": long_rows,
        "verdict": verdict(scan + long_rows, args.factors),
        "wall_time_s": time.perf_counter() - start,
    }
    path = write_result(
        "water_prior_range" if args.output is None else args.output,
        payload,
        quick=args.quick,
        inputs=[JOINT_DATA_FILE],
        command=command_line(argv),
    )
    print(payload["verdict"])
    print(f"wrote {path}")
    return payload


if __name__ == "__main__":
    main()
