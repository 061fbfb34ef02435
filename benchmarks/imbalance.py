"""Imbalance: wall time of single simulations over prior draws (paper Figure 3).

Dutta, Brotzakis & Mira (2018), section "Time imbalance and dynamic allocation for MPI", show that
simulation time varies strongly with the force-field parameters, which is why they allocate tasks
dynamically.  This script measures that distribution here:

``water``
    GROMACS TIP4P ``quick`` preset (216 molecules, 20 ps, one single-threaded ``gmx mdrun`` per
    task, ``md.water.make_simulator("quick")``) at ``--num`` draws from the paper's prior
    U[0.281, 0.53] nm x U[0.2, 0.9] kJ/mol, run ``--workers`` at a time with
    :class:`jaxabc.ProcessPoolExecutor`.  Failed draws (vaporised or collapsed boxes, GROMACS
    errors) are part of the distribution: their time and status are recorded.
``helium``
    jax-md Lennard-Jones helium (``md.helium.make_simulator``, preset ``--helium-preset``) at
    ``--helium-num`` draws from U[0.1, 0.8] nm x U[0.01, 1.0] zJ, one jitted simulation at a time
    in this process (after one compilation, which is reported separately).  With the ``cpu``
    preset (all pairs, fixed number of steps) the cost cannot depend on theta, so this measures
    the engine's floor of imbalance; the ``paper`` preset's neighbour list can (``--helium-preset
    paper`` with ``--helium-override production_ps=20`` etc., and much more time).

Times are wall seconds per simulation measured inside the worker; the machine is shared, so the
load average before and after is recorded with them.

Usage::

    nice -n 5 python -m benchmarks.imbalance                       # water 24 + helium 32, ~5 min
    python -m benchmarks.imbalance --systems water --num 96 --workers 8
    python -m benchmarks.imbalance --systems helium --helium-num 64

Writes ``benchmarks/results/imbalance.json`` (merging systems already there that were not rerun)
and ``benchmarks/results/imbalance.png`` (drawn by ``paper_figures/figure3_imbalance.py``).
"""

from __future__ import annotations

import argparse
import json
import os
import runpy
import time
from pathlib import Path

import jax
import numpy as np

import jaxabc
from benchmarks._common import command_line, machine, write_result
from jaxabc.errors import STATUS_NAMES, STATUS_OK

ROOT = Path(__file__).resolve().parents[1]

RESULTS = ROOT / "benchmarks" / "results"
#: The paper's water prior (sigma_OW nm, epsilon_OW kJ/mol).
WATER_PRIOR = ((0.281, 0.2), (0.53, 0.9))


def describe(times: np.ndarray) -> dict:
    """Summary of a sample of durations (seconds): moments, quantiles and a lognormal fit."""
    times = np.asarray(times, np.float64)
    if times.size == 0:
        return {"count": 0}
    logs = np.log(times)
    return {
        "count": int(times.size),
        "mean": float(times.mean()),
        "std": float(times.std(ddof=1)) if times.size > 1 else 0.0,
        "cv": float(times.std(ddof=1) / times.mean()) if times.size > 1 else 0.0,
        "min": float(times.min()),
        "median": float(np.median(times)),
        "max": float(times.max()),
        "q10": float(np.quantile(times, 0.1)),
        "q90": float(np.quantile(times, 0.9)),
        "max_over_mean": float(times.max() / times.mean()),
        # Maximum-likelihood lognormal: log t ~ N(mu, s^2); speedup.py falls back to it.
        "lognormal_mu": float(logs.mean()),
        "lognormal_sigma": float(logs.std(ddof=0)),
    }


def _draws(seed: int, num: int, low, high) -> tuple[np.ndarray, np.ndarray]:
    key_prior, key_sim = jax.random.split(jax.random.key(seed))
    prior = jaxabc.Uniform(list(low), list(high))
    thetas = np.asarray(prior.sample(key_prior, num), np.float64)
    keys = np.asarray(jax.random.key_data(jax.random.split(key_sim, num)))
    return keys, thetas


def measure_water(num: int, workers: int, seed: int) -> dict:
    from md.water import make_simulator

    simulate = make_simulator("quick")
    keys, thetas = _draws(seed, num, *WATER_PRIOR)
    executor = jaxabc.ProcessPoolExecutor(max_workers=workers)
    load_before = list(os.getloadavg())
    t0 = time.perf_counter()
    try:
        batch = executor.map(simulate, keys, thetas)
    finally:
        executor.close()
    elapsed = time.perf_counter() - t0
    return _record(
        thetas,
        batch.wall_time,
        batch.status,
        batch.reasons,
        {
            "simulator": "md.water.make_simulator('quick'): GROMACS TIP4P, 216 molecules, 20 ps NPT, "
            "one single-threaded gmx mdrun per task, plus trajectory analysis",
            "theta_names": ["sigma_ow_nm", "epsilon_ow_kj_mol"],
            "prior_low": WATER_PRIOR[0],
            "prior_high": WATER_PRIOR[1],
            "how": f"jaxabc.ProcessPoolExecutor(max_workers={workers})",
            "concurrent_workers": workers,
            "batch_wall_seconds": elapsed,
            "load_average_before": load_before,
            "load_average_after": list(os.getloadavg()),
            "worker": batch.worker.tolist(),
        },
    )


def measure_helium(num: int, seed: int, preset: str, overrides: dict) -> dict:
    from md import helium

    simulate = jax.jit(helium.make_simulator(preset, **overrides))
    keys, thetas = _draws(seed, num, helium.PRIOR_LOW, helium.PRIOR_HIGH)
    load_before = list(os.getloadavg())
    t0 = time.perf_counter()
    jax.block_until_ready(simulate(jax.random.wrap_key_data(keys[0]), thetas[0].astype(np.float32)))
    compile_seconds = time.perf_counter() - t0
    times, status, reasons = np.zeros(num), np.zeros(num, np.int32), [""] * num
    for i in range(num):
        t0 = time.perf_counter()
        out = np.asarray(simulate(jax.random.wrap_key_data(keys[i]), thetas[i].astype(np.float32)))
        times[i] = time.perf_counter() - t0
        if not np.all(np.isfinite(out)):
            status[i], reasons[i] = 2, "non-finite f_B (overflow, box below twice the cutoff or blow-up)"
    return _record(
        thetas,
        times,
        status,
        reasons,
        {
            "simulator": f"md.helium.make_simulator({preset!r}, **{overrides}) under jax.jit, one simulation "
            "per call on the CPU (first call, with compilation, excluded)",
            "preset": preset,
            "overrides": overrides,
            "theta_names": ["sigma_nm", "epsilon_zj"],
            "prior_low": list(helium.PRIOR_LOW),
            "prior_high": list(helium.PRIOR_HIGH),
            "how": "serial, in process",
            "concurrent_workers": 1,
            "compile_seconds": compile_seconds,
            "load_average_before": load_before,
            "load_average_after": list(os.getloadavg()),
        },
    )


def _record(thetas: np.ndarray, times: np.ndarray, status: np.ndarray, reasons: list[str], extra: dict) -> dict:
    status = np.asarray(status)
    ok = status == STATUS_OK
    return {
        **extra,
        "theta": thetas.tolist(),
        "wall_time_s": np.asarray(times).tolist(),
        "status": status.tolist(),
        "status_names": [STATUS_NAMES.get(int(s), str(s)) for s in status],
        "reasons": list(reasons),
        "stats_all": describe(times),
        "stats_ok": describe(np.asarray(times)[ok]),
        "stats_failed": describe(np.asarray(times)[~ok]),
        "failure_fraction": float(np.mean(~ok)),
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--systems", default="water,helium", help="comma-separated: water, helium")
    parser.add_argument("--num", type=int, default=24, help="water prior draws (~10 s each on one core)")
    parser.add_argument("--workers", type=int, default=2, help="water simulations run at a time")
    parser.add_argument("--helium-num", type=int, default=32, help="helium prior draws")
    parser.add_argument("--helium-preset", default="cpu", help="md.helium preset: cpu or paper")
    parser.add_argument(
        "--helium-override",
        action="append",
        default=[],
        metavar="FIELD=VALUE",
        help="HeliumPreset field override, e.g. production_ps=20 (repeatable)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--output", type=Path, default=RESULTS / "imbalance.json")
    parser.add_argument("--figure", type=Path, default=RESULTS / "imbalance.png")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="reproduction check: 4 helium draws, written to results/quick/imbalance.{json,png}",
    )
    args = parser.parse_args(argv)
    if args.quick:
        args.systems, args.helium_num = "helium", 4
        args.output, args.figure = RESULTS / "quick" / "imbalance.json", RESULTS / "quick" / "imbalance.png"
    systems = [s.strip() for s in args.systems.split(",") if s.strip()]
    unknown = set(systems) - {"water", "helium"}
    if unknown:
        parser.error(f"unknown systems {sorted(unknown)}: use water and/or helium")

    out = {}
    if args.output.exists():  # keep the systems not rerun this time
        out = json.loads(args.output.read_text())
    out.setdefault("systems", {})
    # paper_figures/figure3_imbalance.py prints the machine next to the figure.
    out["machine"] = machine()
    out["command"] = command_line(None if argv is None else [__file__, *argv])
    out["description"] = (
        "wall seconds of single simulations at prior draws (paper Figure 3); failures included with their status"
    )
    if "water" in systems:
        out["systems"]["water"] = measure_water(args.num, args.workers, args.seed)
        out["systems"]["water"]["command"] = out["command"]
        print("water:", json.dumps(out["systems"]["water"]["stats_all"]))
    if "helium" in systems:
        overrides = {}
        for item in args.helium_override:
            name, _, value = item.partition("=")
            overrides[name] = type(getattr(__import__("md.helium").helium.get_preset(args.helium_preset), name))(value)
        out["systems"]["helium"] = measure_helium(args.helium_num, args.seed, args.helium_preset, overrides)
        out["systems"]["helium"]["command"] = out["command"]
        print("helium:", json.dumps(out["systems"]["helium"]["stats_all"]))
    write_result(args.output, out, part=systems, command=out["command"])
    draw = runpy.run_path(str(ROOT / "paper_figures" / "figure3_imbalance.py"))["draw"]
    draw(args.output, args.figure)
    print(f"wrote {args.output} and {args.figure}")


if __name__ == "__main__":
    main()
