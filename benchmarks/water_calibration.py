"""Calibrate TIP4P's oxygen Lennard-Jones parameters with APMCABC and real GROMACS runs.

Reproduces the water section of Dutta, Brotzakis & Mira, J. Chem. Phys. 149, 154110 (2018):

* ``--data simulated``: observed = TIP4P's own parameters (0.315365 nm, 0.648520 kJ/mol)
  simulated with the same preset; checks that the truth lies in the 50 % highest-posterior-
  density region and reports the correlation (paper: -0.994);
* ``--data xray`` / ``--data neutron``: Skinner 2013 / Soper 2013 (see ``md.water.datasets``);
  Bayes estimates and correlations next to the paper's (0.326, 0.607, -0.99) and
  (0.319, 0.614, -0.95).

Each run writes ``benchmarks/results/water_<data>.json`` (one entry per statistics variant,
updated in place), ``water_<data>_<variant>.npz`` (the full ABC record), a posterior figure and,
with ``--predictive N``, posterior-predictive g_OO bands (min-max and quartiles over N posterior
draws) against the measured curve, as the paper's Figures 7-8.  ``--validation-ps T`` adds the
paper's Table 2 properties (density, C_p, kappa_T, dielectric constant at 298 K) at the Bayes
estimate and at TIP4P, from ``gmx energy`` / ``gmx dipoles`` on NPT runs of T ps.

Usage (all cores, one single-threaded ``gmx mdrun`` per worker)::

    python -m benchmarks.water_calibration --data simulated --statistics robust
    python -m benchmarks.water_calibration --data xray --statistics paper --predictive 20
    python -m benchmarks.water_calibration --data neutron --statistics robust --validation-ps 1000
    python -m benchmarks.water_calibration --quick --data simulated    # a few min: 30 particles, 2 steps,
                                                                       # 5 ps runs, into results/quick/
    python -m benchmarks.water_calibration --data simulated --algorithm surrogate --max-simulations 300
    mpiexec -n 9 python -m mpi4py.futures benchmarks/water_calibration.py --data xray --executor mpi

Executors: ``--executor pool`` (default) runs ``--workers`` local processes; ``--executor mpi``
uses the other ranks of an ``mpiexec ... -m mpi4py.futures`` job (dynamic allocation).  Either
way a second bar counts finished simulations as they finish (from a progress file that every
worker appends to, see ``logged_simulator``), with the rate and an ETA against the budget.

``--algorithm surrogate`` calibrates through ``jaxabc.run("surrogate", ...)`` (a GP emulator of
the nine statistics, sequential design, held-out validation) within ``--max-simulations`` GROMACS
runs; ``--surrogate-mode abc`` samples it with APMCABC on emulated statistics (same distance as
APMCABC) instead of the synthetic likelihood.  It needs no pilot scaling (the emulator
standardises the statistics), so ``--scale`` defaults to ``none`` there.  Its results go to
``water_<data>_surrogate.json`` and ``water_<data>_<variant>_surrogate.npz`` (``_surrogate_abc`` in ABC
mode).

Failures: with the paper's prior U[0.281, 0.53] x U[0.2, 0.9] most draws do not stay liquid at
298 K and 1 atm (measured with 2 ps quick runs: 11 of 12 prior draws vaporised, density < 500
kg/m3, or collapsed); GROMACS itself does not fail there.  They are recorded as failures (distance
+inf) with their reason, so ``--max-failure-fraction`` defaults to 0.95.

Distances: ``paper`` statistics use the paper's mean absolute difference.  ``robust``
statistics put S9 in 1e-5 cm^2/s, where an unweighted mean would be dominated by diffusion, so by
default each statistic is divided by its median absolute deviation over a pilot sample of
``--pilot`` prior-predictive simulations (recorded in the JSON); ``--scale none`` turns that off.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import contextlib
import itertools
import json
import multiprocessing
import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxabc
from benchmarks._common import (
    QUICK_RESULTS,
    code_hash,
    command_line,
    declare_input,
    guard_resume,
    write_result,
)
from jaxabc.checkpoint import simulator_identity
from jaxabc.executors.cache import RunCache
from jaxabc.executors.progress import ProgressLog, ProgressMonitor, SittingClock
from jaxabc.surrogate.design import MIN_DESIGN_SUCCESS
from md.water import datasets, make_simulator
from md.water.gromacs import TIP4P_PARAMETERS, find_gmx
from md.water.models import PAPER_TIP4P_ESTIMATES
from md.water.statistics import ROBUST_GRID_NM, STATISTIC_NAMES, STATISTIC_UNITS

ROOT = Path(__file__).resolve().parents[1]

TIP4P_THETA = np.array([TIP4P_PARAMETERS.sigma_ow_nm, TIP4P_PARAMETERS.epsilon_ow_kj_mol])
PRIOR_LOW, PRIOR_HIGH = (0.281, 0.2), (0.53, 0.9)
PAPER = PAPER_TIP4P_ESTIMATES  # Dutta et al. 2018, by dataset
# Experimental values at 298 K and 1 bar, as in the paper's Table 2 (Vega & Abascal 2011).
EXPERIMENT_298K = {
    "density_kg_m3": 997.0,
    "heat_capacity_j_mol_k": 75.3,
    "compressibility_per_bar": 45.3e-6,
    "dielectric_constant": 78.5,
}
OBSERVED_KEY = 2**31 - 7  # the "simulated observed" data use a key no particle gets


def parse_arguments(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--data", choices=("simulated", "xray", "neutron"), required=True)
    parser.add_argument("--statistics", choices=("paper", "robust"), default="robust")
    parser.add_argument("--preset", choices=("quick", "paper"), default="quick")
    parser.add_argument(
        "--particles", type=int, default=None, help="APMCABC population (default 100); surrogate draws (default 2000)"
    )
    parser.add_argument("--steps", type=int, default=10, help="APMCABC steps (paper: 10)")
    parser.add_argument("--alpha", type=float, default=0.1)
    parser.add_argument("--acceptance-cutoff", type=float, default=0.03)
    parser.add_argument("--workers", type=int, default=os.cpu_count(), help="process-pool workers")
    parser.add_argument(
        "--executor",
        choices=("pool", "mpi"),
        default="pool",
        help="pool: --workers local processes; mpi: the worker ranks of `mpiexec -n K python -m "
        "mpi4py.futures benchmarks/water_calibration.py ...` (dynamic allocation)",
    )
    parser.add_argument("--algorithm", choices=("apmcabc", "surrogate"), default="apmcabc")
    parser.add_argument(
        "--max-simulations",
        type=int,
        default=None,
        help="simulation budget (surrogate: required in effect, default 300; APMCABC: optional cap)",
    )
    parser.add_argument(
        "--surrogate-mode",
        choices=("synthetic_likelihood", "abc"),
        default="synthetic_likelihood",
        help="surrogate posterior: NUTS on the synthetic likelihood, or APMCABC on emulated statistics",
    )
    parser.add_argument("--surrogate-batch", type=int, default=None, help="design batch (default: the workers)")
    parser.add_argument(
        "--surrogate-initial",
        type=int,
        default=32,
        help="Sobol start; most of the prior box fails (vapour, collapse), and the run needs at "
        "least 3 liquid runs before an emulator is fitted, so more than the library's default 20",
    )
    parser.add_argument(
        "--surrogate-replicates",
        type=int,
        default=8,
        help="replicate runs measuring the noise, at two liquid runs of the start (the library "
        "places them once the start has found liquid; 0: none, the noise is then the nugget "
        "fitted to scattered runs)",
    )
    parser.add_argument("--surrogate-holdout", type=int, default=20, help="held-out runs per validation")
    parser.add_argument(
        "--surrogate-min-feasibility",
        type=float,
        default=MIN_DESIGN_SUCCESS,
        help="cut the posterior where the fitted chance of a liquid run is below this (the library's "
        "min_feasibility; default: the level design runs must reach, design.MIN_DESIGN_SUCCESS, "
        "below which no design run goes and the emulator is not trusted)",
    )
    parser.add_argument(
        "--surrogate-tolerance",
        type=float,
        default=None,
        help="stop the design once the posterior mean of the emulator-to-noise variance ratio is "
        "below this (the library's tolerance, default 0.01). The synthetic likelihood carries the "
        "emulator's variance, so a larger value widens the posterior a little, it does not bias it; "
        "0.04 puts the emulator's error at a fifth of the noise sd, posterior means within about a "
        "fifth of a posterior sd. Near a narrow mode the ratio falls about as 1/k with k runs there, "
        "so each halving of the tolerance doubles the runs the design spends at the mode",
    )
    parser.add_argument(
        "--stop-after-iterations",
        type=int,
        default=None,
        help="stop (resumably, with --checkpoint-dir) after this many driver iterations",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    parser.add_argument(
        "--run-cache",
        type=Path,
        default=None,
        help="keep every finished GROMACS run here (summaries or failure reason, keyed on the "
        "simulator, its code, the key and theta), so that a sitting cut short replays the runs of "
        "an unfinished batch instead of repeating them",
    )
    parser.add_argument(
        "--order",
        choices=("fifo", "longest_first"),
        default="longest_first",
        help="task order of the process pool (jaxabc.executors.scheduling); never changes results",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--diffusion",
        default="experiment",
        choices=("experiment", "paper_text", "paper_stored"),
        help="observed S9 for measured data (md.water.datasets)",
    )
    parser.add_argument(
        "--scale",
        choices=("pilot", "none"),
        default=None,
        help="distance scaling (default: pilot for robust, none for paper)",
    )
    parser.add_argument(
        "--pilot",
        type=int,
        default=100,
        help="prior-predictive simulations for the robust scales; only liquid "
        "runs count (about 1 in 10 of the prior here, see below)",
    )
    parser.add_argument(
        "--max-failure-fraction",
        type=float,
        default=0.95,
        help="most of the paper's prior box vaporises or collapses (measured: "
        "11 of 12 prior draws), so failures are expected, not an error",
    )
    parser.add_argument("--predictive", type=int, default=0, help="posterior draws for predictive g_OO bands (0: skip)")
    parser.add_argument(
        "--validation-ps", type=float, default=0.0, help="length of the Table-2 validation runs in ps (0: skip)"
    )
    parser.add_argument(
        "--validation-preset",
        choices=("quick", "paper"),
        default="paper",
        help="GROMACS preset of the validation runs (default: the paper's 515 molecules)",
    )
    parser.add_argument(
        "--validation-only",
        type=Path,
        default=None,
        metavar="RESULT_NPZ",
        help="skip the calibration: add the Table-2 properties at this saved "
        "result's Bayes estimate (and TIP4P) to its JSON entry",
    )
    parser.add_argument("--md-steps", type=int, default=None, help="override the preset's NPT steps (smoke tests only)")
    parser.add_argument("--out-dir", type=Path, default=ROOT / "benchmarks" / "results")
    parser.add_argument("--checkpoint-dir", type=Path, default=None)
    parser.add_argument("--resume", action="store_true")
    parser.add_argument(
        "--continue",
        dest="continue_run",
        action="store_true",
        help="resume when --checkpoint-dir holds a checkpoint, else start (one command for a run "
        "that spans several sittings)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="reproduction check: 30 particles, 2 steps, 5 ps MD runs, unscaled distance (a pilot "
        "of prior draws, mostly vapour, would need ~100 runs), no predictive or validation "
        "runs, written to benchmarks/results/quick/",
    )
    args = parser.parse_args(argv)
    if args.particles is None:
        args.particles = 2000 if args.algorithm == "surrogate" else 100
    if args.algorithm == "surrogate":
        if args.max_simulations is None:
            args.max_simulations = 300
        if args.scale is None:
            args.scale = "none"
    if args.quick:
        # 30 particles keep 3 (APMCABC needs 2) although ~90 % of prior draws vaporise.
        if args.algorithm == "apmcabc":
            args.particles, args.steps = 30, 2
        args.md_steps, args.scale = 2500, "none"
        args.predictive, args.validation_ps, args.out_dir = 0, 0.0, QUICK_RESULTS
    return args


def protocol_overrides(args) -> dict:
    if args.md_steps is None:
        return {}
    return {"num_steps": args.md_steps, "analysis_start_ps": 0.2 * args.md_steps * 0.002}


def observed_vector(args, simulate) -> np.ndarray:
    if args.data == "simulated":
        return simulate(np.array([0, OBSERVED_KEY], np.uint32), TIP4P_THETA)
    return datasets.observed_statistics(args.data, args.statistics, args.diffusion)


def _has_checkpoint(args) -> bool:
    """``--continue`` and a checkpoint to continue from."""
    return bool(args.continue_run and args.checkpoint_dir and (args.checkpoint_dir / "checkpoint.npz").exists())


def pilot_scales(args, simulate, prior, executor) -> np.ndarray:
    """Median absolute deviation of each statistic over prior-predictive simulations."""
    key = jax.random.key(args.seed + 1_000_003)
    thetas = np.asarray(prior.sample(key, args.pilot), dtype=np.float64)
    keys = np.asarray(jax.random.key_data(jax.random.split(jax.random.key(args.seed + 7), args.pilot)))
    batch = executor.map(simulate, keys, thetas)
    good = batch.summaries[batch.status == 0]
    if good.shape[0] < 5:
        reasons = "\n  ".join(sorted(set(batch.reasons)))
        raise RuntimeError(f"only {good.shape[0]} of {args.pilot} pilot simulations succeeded; reasons:\n  {reasons}")
    mad = np.median(np.abs(good - np.median(good, axis=0)), axis=0)
    # Unobserved (zeroed) statistics have MAD 0; they contribute 0 whatever the scale.
    return np.where(mad > 0, mad, 1.0)


def scaled_mean_abs(scale: np.ndarray):
    # The closure's variable names enter checkpoint fingerprints: keep `scale`.
    scale = jnp.asarray(scale, dtype=jnp.float32)  # pyright: ignore[reportAssignmentType]

    def distance(observed, simulated):
        return jnp.mean(jnp.abs(jnp.asarray(observed) - jnp.asarray(simulated)) / scale)

    return distance


def truth_in_hpd(result, truth: np.ndarray, level: float = 0.5) -> bool:
    """Whether ``truth`` lies in the weighted-KDE highest-posterior-density region of mass
    ``level``."""
    from scipy.stats import gaussian_kde

    kde = gaussian_kde(result.particles.T, weights=result.weights)
    density = kde(result.particles.T)
    order = np.argsort(density)[::-1]
    mass = np.cumsum(result.weights[order])
    threshold = density[order][np.searchsorted(mass, level)]
    return bool(kde(truth[:, None])[0] >= threshold)


def truth_credibility(result, truth: np.ndarray) -> dict:
    """At which credible level the truth sits: the posterior mass denser than the truth.

    ``hpd_level`` is :meth:`jaxabc.ABCResult.credible_level` (weighted KDE, the truth and the
    particles ranked alike, so a truth drawn from the posterior gets a uniform level even for
    APMCABC's small final population of ``N alpha`` particles).  ``gaussian_level`` is the
    chi-square level of the truth's Mahalanobis distance from the posterior mean, a rough
    parametric cross-check.  ``in_sample_kde_level`` is the estimate reported before 2026-11-22:
    each particle's KDE density includes its own kernel, which biases it high at small ``n``
    (see ``credible_level``); it is kept only to connect with older numbers.
    """
    from scipy.stats import chi2, gaussian_kde

    kde = gaussian_kde(result.particles.T, weights=result.weights)
    in_sample = float(result.weights[kde(result.particles.T) > kde(truth[:, None])[0]].sum())
    x = truth - result.bayes_estimate()
    mahalanobis2 = float(x @ np.linalg.solve(result.covariance(), x))
    return {
        "hpd_level": result.credible_level(truth),
        "gaussian_level": float(chi2.cdf(mahalanobis2, truth.size)),
        "in_sample_kde_level": in_sample,
        "posterior_particles": int(result.particles.shape[0]),
        "effective_sample_size": float(result.effective_sample_size()),
    }


# ---------------------------------------------------------------------------- predictive bands


def _predictive_goo(task):
    """Worker: g_OO on the robust grid for one posterior draw (None if the run failed)."""
    preset, overrides, seed, theta = task
    from jaxabc.errors import SimulationFailure
    from md.water import make_simulator as make

    simulate = make(preset, "robust", **overrides)
    try:
        curves = simulate.run(np.array([1, seed], np.uint32), theta).curves
    except SimulationFailure:
        return None
    return np.interp(ROBUST_GRID_NM, curves.r_oo_nm, curves.g_oo)


def predictive_bands(args, result) -> dict:
    draws = result.resample(args.predictive, seed=args.seed)
    tasks = [(args.preset, protocol_overrides(args), i, draws[i]) for i in range(len(draws))]
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(args.workers, mp_context=context) as pool:
        curves = [c for c in pool.map(_predictive_goo, tasks) if c is not None]
    bands = {"r_nm": ROBUST_GRID_NM.tolist(), "num_curves": len(curves), "num_failed": len(tasks) - len(curves)}
    if not curves:
        # Every posterior draw failed (gas, collapse): no band, and the result says so rather
        # than losing the whole run to an error after hours of simulation.
        print(f"warning: all {len(tasks)} posterior-predictive runs failed; no g_OO band", file=sys.stderr)
        return bands
    quantiles = np.quantile(np.array(curves), [0.0, 0.25, 0.5, 0.75, 1.0], axis=0)
    names = ("min", "q25", "median", "q75", "max")
    return {**bands, **{name: q.tolist() for name, q in zip(names, quantiles, strict=True)}}


def plot_bands(bands: dict, data: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r = np.array(bands["r_nm"])
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.fill_between(r, bands["min"], bands["max"], color="C0", alpha=0.25, label="min-max")
    ax.fill_between(r, bands["q25"], bands["q75"], color="C0", alpha=0.5, label="quartiles")
    curve = datasets.xray_goo() if data == "xray" else datasets.neutron_curves()["OO"]
    if data != "simulated":
        ax.plot(curve.r_nm, curve.g, "k-", lw=1, label=data)
    ax.set_xlim(0.2, 0.8)
    ax.set_xlabel("r [nm]")
    ax.set_ylabel("g_OO(r)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


# ---------------------------------------------------------------------------- Table 2


def _xvg_columns(path: Path) -> dict[str, np.ndarray]:
    """Columns of an ``.xvg`` by legend; ``gmx energy`` orders them as the energy file does,
    not as they were asked for."""
    legends = [
        line.split('legend "')[1].rstrip('"\n')
        for line in path.read_text().splitlines()
        if line.startswith("@ s") and 'legend "' in line
    ]
    table = np.loadtxt(path, comments=["#", "@"], ndmin=2)
    return {name: table[:, i + 1] for i, name in enumerate(legends)}


def validation_properties(preset: str, run_ps: float, theta: np.ndarray) -> dict:
    """Density, C_p, kappa_T and epsilon at 298 K from one NPT run of ``run_ps`` picoseconds.

    Fluctuation formulas over the frames after the preset's equilibration:
    ``kappa_T = var(V) / (k_B T <V>)``, ``C_p = var(H) / (R T^2) / N`` (classical, no quantum
    correction), epsilon from ``gmx dipoles -temp 298`` (needs >= 1 ns to mean anything).
    Each property also gets a standard error from five blocks of the analysed frames, so the
    table says which differences are resolved at this run length.
    """
    import tempfile

    num_steps = round(run_ps / 0.002)
    default_start = make_simulator(preset, "robust").protocol.analysis_start_ps
    simulate = make_simulator(preset, "robust", num_steps=num_steps, analysis_start_ps=min(default_start, 0.2 * run_ps))
    gmx = find_gmx()
    start = str(simulate.protocol.analysis_start_ps)
    env = dict(os.environ, GMX_MAXBACKUP="-1")
    temperature = simulate.protocol.temperature_k
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="jaxabc-validation-") as tmp:
        workdir = Path(tmp)
        output = simulate.run(np.array([2, 0], np.uint32), theta, keep_directory=workdir)
        subprocess.run(
            [gmx, "energy", "-f", "npt.edr", "-o", "energy.xvg", "-b", start],
            input="Density\nVolume\nEnthalpy\n\n",
            text=True,
            cwd=workdir,
            check=True,
            capture_output=True,
            env=env,
        )
        columns = _xvg_columns(workdir / "energy.xvg")
        blocks = []
        edges = np.linspace(float(start), run_ps, 6)
        windows = [(float(start), None), *itertools.pairwise(edges)]  # whole run, 5 blocks
        for b0, b1 in windows:
            cmd = [gmx, "dipoles", "-f", "npt.xtc", "-s", "npt.tpr", "-temp", str(temperature), "-b", str(b0)]
            if b1 is not None:
                cmd += ["-e", str(b1)]
            done = subprocess.run(cmd, input="0\n", text=True, cwd=workdir, check=True, capture_output=True, env=env)
            text = done.stdout + done.stderr
            blocks.append(float(text.split("Epsilon =")[1].split()[0]) if "Epsilon =" in text else np.nan)
        num_molecules = output.run.num_molecules
    density, volume_nm3 = columns["Density"], columns["Volume"]
    enthalpy_kj_mol = columns["Enthalpy"]
    kt_bar_nm3 = 1.380649e-23 * temperature / 1e-22  # 1 bar nm^3 = 1e-22 J

    def props(v, h, d):
        return (
            float(d.mean()),
            float(v.var() / (kt_bar_nm3 * v.mean())),
            float(h.var() / (8.314462618e-3 * temperature**2) / num_molecules * 1e3),
        )

    whole = props(volume_nm3, enthalpy_kj_mol, density)
    per_block = np.array(
        [
            props(v, h, d)
            for v, h, d in zip(
                np.array_split(volume_nm3, 5),
                np.array_split(enthalpy_kj_mol, 5),
                np.array_split(density, 5),
                strict=True,
            )
        ]
    )
    se = per_block.std(axis=0, ddof=1) / np.sqrt(5)
    eps_blocks = np.array(blocks[1:])
    return {
        "theta": np.asarray(theta).tolist(),
        "preset": preset,
        "run_ps": run_ps,
        "analysed_from_ps": float(start),
        "num_molecules": int(num_molecules),
        "density_kg_m3": whole[0],
        "density_se": float(se[0]),
        "compressibility_per_bar": whole[1],
        "compressibility_se": float(se[1]),
        "heat_capacity_j_mol_k": whole[2],
        "heat_capacity_se": float(se[2]),
        # the total-dipole fluctuation converges over nanoseconds (a 4 ps run gives 7.4 for
        # TIP4P, whose literature value is ~50); the paper used 5 ns runs.  The block SE
        # (fluctuations within 1/5 of the run) understates the error of a long-tailed quantity,
        # so it is labelled a lower bound.
        "dielectric_constant": blocks[0],
        "dielectric_constant_block_se_lower_bound": float(
            np.nanstd(eps_blocks, ddof=1) / np.sqrt(np.isfinite(eps_blocks).sum())
        ),
        "block_se": "standard error from 5 consecutive blocks of the analysed frames",
        "wall_time_s": time.perf_counter() - t0,
    }


VALIDATION_CACHE = "water_validation_runs.json"


def _validation_task(task):
    preset, run_ps, theta = task
    return validation_properties(preset, run_ps, np.asarray(theta))


def validation_table(args, estimate: np.ndarray) -> dict:
    """Table-2 properties at the Bayes estimate and at TIP4P, runs in parallel, cached by
    (preset, length, theta) in ``VALIDATION_CACHE`` so TIP4P runs once for every dataset."""
    cache_path = args.out_dir / VALIDATION_CACHE
    cache = json.loads(cache_path.read_text()) if cache_path.exists() else {}
    points = {"bayes_estimate": np.asarray(estimate, np.float64), "tip4p": TIP4P_THETA}
    keys = {
        name: f"{args.validation_preset}|{args.validation_ps:g}|{theta[0]:.6f}|{theta[1]:.6f}"
        for name, theta in points.items()
    }
    todo = [name for name in points if keys[name] not in cache]
    if todo:
        context = multiprocessing.get_context("spawn")
        with concurrent.futures.ProcessPoolExecutor(min(len(todo), args.workers), mp_context=context) as pool:
            tasks = [(args.validation_preset, args.validation_ps, points[n].tolist()) for n in todo]
            for name, props in zip(todo, pool.map(_validation_task, tasks), strict=True):
                cache = json.loads(cache_path.read_text()) if cache_path.exists() else {}
                cache[keys[name]] = props
                cache_path.write_text(json.dumps(cache, indent=2))
    return {**{name: cache[keys[name]] for name in points}, "experiment": EXPERIMENT_298K}


# ---------------------------------------------------------------------------- progress
# The executors report a batch only when all of it is done, and a water step is one batch of
# hundreds of GROMACS runs, so the driver's per-step bar stands still for an hour.  Here the
# simulator leaves a trace instead: jaxabc's ProgressLog appends one JSON line per run to a file,
# in whichever worker process or MPI rank ran it, and ProgressMonitor, a thread in the driver,
# reads it once a second for a bar with rate and ETA.  With --run-cache a RunCache inside the log
# replays finished runs.  The file lives on the driver's file system (a process pool, MPI on one
# node or on a shared file system).  The wrappers pass keys, parameters, results and exceptions
# through unchanged, and the run gets the inner simulator's identity (simulator_id), so results
# and checkpoints do not depend on them.


def run_cache_identity(simulate) -> str:
    """What a cached GROMACS run depends on: the simulator (its repr names preset, statistics
    and ``gmx``), its protocol and the code of ``md/water`` (:func:`benchmarks._common.code_hash`
    of each module, so an edit of a comment keeps the cache and any other edit empties it): runs of
    other simulator code are never replayed.

    The same string as the benchmark's own cache used before it moved to
    :class:`jaxabc.executors.cache.RunCache`, which hashes a string identity alike, so folders
    written then are still replayed.
    """
    code = sorted(str(f.relative_to(ROOT)) + code_hash(f) for f in (ROOT / "md" / "water").glob("*.py"))
    return repr((simulate, getattr(simulate, "protocol", None), code))


def logged_simulator(
    simulate: Callable, progress_file: str | os.PathLike, run_cache: str | os.PathLike | None = None
) -> ProgressLog:
    """``simulate`` with a line in ``progress_file`` per run and, with ``run_cache``, a
    :class:`~jaxabc.executors.cache.RunCache` in that folder (see :func:`run_cache_identity`).

    Picklable when ``simulate`` is; results are those of ``simulate``.
    """
    inner = simulate if run_cache is None else RunCache(simulate, run_cache, identity=run_cache_identity(simulate))
    progress_file = Path(progress_file)
    return ProgressLog(inner, progress_file.parent, progress_file.name)


def sitting_clock(args, stem: str, resuming: bool, heartbeat_s: float = 30.0) -> SittingClock | None:
    """The wall-time clock of a ``--checkpoint-dir`` run (None without one), in
    ``<checkpoint-dir>/<stem>.sittings.json``.

    A run started over forgets the earlier sittings, unless ``--run-cache`` holds finished runs:
    those replayed runs were paid for in the earlier sittings, so they still count.  A sitting
    that is killed counts up to its last heartbeat (every ``heartbeat_s`` seconds).
    """
    if args.checkpoint_dir is None:
        return None
    cached_runs = args.run_cache is not None and RunCache.stats(args.run_cache)["entries"] > 0
    path = args.checkpoint_dir / f"{stem}.sittings.json"
    return SittingClock(path, heartbeat_s=heartbeat_s, fresh=not resuming and not cached_runs)


# ---------------------------------------------------------------------------- main


def make_executor(args, timeout_s: float):
    """The process pool (``--workers``) or the MPI pool of an ``mpiexec`` job."""
    if args.executor == "mpi":
        return jaxabc.MPIExecutor(allocation="dynamic", timeout=timeout_s, order=args.order)
    return jaxabc.ProcessPoolExecutor(max_workers=args.workers, order=args.order, timeout=timeout_s)


def num_workers(args, executor) -> int:
    return int(executor.num_workers) if args.executor == "mpi" else int(args.workers)


def algorithm_options(args, executor, distance) -> dict:
    """Builder options of ``--algorithm``."""
    if args.algorithm == "apmcabc":
        return {"alpha": args.alpha, "acceptance_cutoff": args.acceptance_cutoff}
    options = {
        # One design batch per round of the workers keeps them all busy.
        "batch_size": args.surrogate_batch or num_workers(args, executor),
        "num_replicates": args.surrogate_replicates,
        "num_holdout": args.surrogate_holdout,
        "min_feasibility": args.surrogate_min_feasibility,
    }
    if args.surrogate_tolerance is not None:
        options["tolerance"] = args.surrogate_tolerance
    options["num_initial"] = args.surrogate_initial
    if args.surrogate_mode == "abc":
        options |= {"mode": "abc", "abc_distance": distance}
    return options


def expected_simulations(args, scale_mode: str) -> int:
    """Simulations this invocation will run at most (the bar's total; the ETA assumes it)."""
    pilot = args.pilot if scale_mode == "pilot" else 0
    if args.algorithm == "surrogate":
        return pilot + args.max_simulations
    kept = int(np.ceil(args.alpha * args.particles))
    budget = args.particles + (args.steps - 1) * (args.particles - kept)
    return pilot + (budget if args.max_simulations is None else min(budget, args.max_simulations))


def _command(argv: list[str] | None) -> str:
    return command_line(None if argv is None else [__file__, *argv])


def _suffix(args: argparse.Namespace) -> str:
    """File-name suffix of a calibration's results: by algorithm, and the surrogate's ABC mode apart."""
    if args.algorithm != "surrogate":
        return ""
    return "_surrogate_abc" if args.surrogate_mode == "abc" else "_surrogate"


def validation_only(args, argv: list[str] | None = None) -> dict:
    """Add the Table-2 properties to an existing calibration's JSON entry."""
    if not args.validation_ps:
        raise SystemExit("--validation-only needs --validation-ps (the run length in ps, e.g. 1000)")
    result = jaxabc.load(args.validation_only)
    path = args.out_dir / f"water_{args.data}{_suffix(args)}.json"
    everything = json.loads(path.read_text()) if path.exists() else {}
    if args.statistics not in everything:
        raise SystemExit(f"{path} has no {args.statistics!r} entry: run the calibration first")
    everything[args.statistics]["validation"] = validation_table(args, result.bayes_estimate())
    write_result(path, everything, part=args.statistics, inputs=[args.validation_only], command=_command(argv))
    print(json.dumps(everything[args.statistics]["validation"], indent=1))
    return everything[args.statistics]


def main(argv=None) -> dict:
    args = parse_arguments(argv)
    find_gmx()  # refuse early, with the install command, if GROMACS is missing
    if args.validation_only is not None:
        return validation_only(args, argv)
    scale_mode = args.scale or ("pilot" if args.statistics == "robust" else "none")
    kind = "simulated" if args.data == "simulated" else args.data
    simulate = make_simulator(args.preset, args.statistics, observed_kind=kind, **protocol_overrides(args))
    prior = jaxabc.Uniform(PRIOR_LOW, PRIOR_HIGH, names=("sigma_OW", "epsilon_OW"), units=("nm", "kJ/mol"))
    executor = make_executor(args, simulate.protocol.timeout_s + 60)
    surrogate = args.algorithm == "surrogate"
    suffix = _suffix(args)
    stem = f"water_{args.data}_{args.statistics}{suffix}"
    args.out_dir.mkdir(parents=True, exist_ok=True)
    # Workers report each finished run to the progress file; results are those of `simulate`.
    # (The name ends in .progress, which .gitignore keeps out of the results.)
    counted = logged_simulator(simulate, args.out_dir / f".{stem}.progress", args.run_cache)
    started = time.perf_counter()
    resuming = args.resume or _has_checkpoint(args)
    if args.checkpoint_dir is not None:
        guard_resume(args.checkpoint_dir, resuming, modules=("jaxabc.surrogate",) if surrogate else ())
    clock = sitting_clock(args, stem, resuming)
    observed = observed_vector(args, simulate)
    monitor = (
        contextlib.nullcontext()
        if args.no_progress
        else ProgressMonitor(counted.path, expected_simulations(args, scale_mode), f"{args.algorithm} GROMACS runs")
    )
    try:
        with monitor, clock if clock is not None else contextlib.nullcontext():
            if scale_mode == "pilot":
                scale = pilot_scales(args, counted, prior, executor)
                distance = scaled_mean_abs(scale)
            else:
                scale, distance = np.ones(9), "mean_abs"
            result = jaxabc.run(
                args.algorithm,
                counted,
                prior,
                observed,
                num_particles=args.particles,
                num_steps=None if surrogate else args.steps,
                distance=distance,
                seed=args.seed,
                executor=executor,
                max_simulations=args.max_simulations,
                max_failure_fraction=args.max_failure_fraction,
                checkpoint_dir=args.checkpoint_dir,
                resume=resuming,
                stop_after_iterations=args.stop_after_iterations,
                simulator_id=simulator_identity(simulate, None),
                progress=not args.no_progress,
                metadata={"data": args.data, "statistics": args.statistics, "preset": args.preset},
                **algorithm_options(args, executor, distance),
            )
    finally:
        executor.close()
    result.save(args.out_dir / f"{stem}.npz", overwrite=True)
    truth = TIP4P_THETA if args.data == "simulated" else None
    result.plot_posterior(args.out_dir / f"{stem}_posterior.png", truth=truth)
    failures = result.records["status"] != 0
    entry = {
        "statistics": args.statistics,
        "preset": args.preset,
        "protocol": {k: v for k, v in vars(simulate.protocol).items() if k != "extra_mdp"},
        "observed": observed.tolist(),
        "statistic_names": list(STATISTIC_NAMES),
        "statistic_units": list(STATISTIC_UNITS[args.statistics]),
        "diffusion": args.diffusion if args.data != "simulated" else "simulated",
        "distance": "mean_abs" if scale_mode == "none" else "mean_abs / pilot MAD",
        "scale": np.asarray(scale).tolist(),
        "settings": {
            "algorithm": args.algorithm,
            "particles": args.particles,
            "max_simulations": args.max_simulations,
            "seed": args.seed,
            "executor": args.executor,
            "workers": num_workers(args, executor),
            "order": args.order,
            **(
                {}
                if surrogate
                else {"steps": args.steps, "alpha": args.alpha, "acceptance_cutoff": args.acceptance_cutoff}
            ),
            **(result.settings if surrogate else {}),
        },
        "bayes_estimate": result.bayes_estimate().tolist(),
        "correlation": float(result.correlation()[0, 1]),
        "credible_interval_95": result.credible_interval(0.95).tolist(),
        "final_threshold": float(result.thresholds[-1]),
        "num_simulations": int(result.num_simulations),
        "num_failures": int(failures.sum()),
        "failure_reasons": sorted({r for r, f in zip(result.records["reasons"], failures, strict=True) if f})[:20],
        # Over every sitting of a resumed run (the calibration; predictive and validation runs of
        # the last sitting follow).
        "wall_time_s": clock.total_seconds() if clock is not None else time.perf_counter() - started,
        "sittings": clock.num_sittings if clock is not None else 1,
        "stop_reason": result.stop_reason,
        "paper": PAPER[args.data],
    }
    if surrogate:
        # The design points and held-out checks: how many real runs, and how well they are predicted.
        entry["surrogate"] = {k: v for k, v in result.diagnostics.items() if k != "holdout_errors"}
    if truth is not None:
        entry["truth"] = truth.tolist()
        entry["truth_in_50pct_hpd"] = truth_in_hpd(result, truth)
        entry["truth_credibility"] = truth_credibility(result, truth)
    if args.predictive:
        entry["predictive_goo"] = predictive_bands(args, result)
        if entry["predictive_goo"]["num_curves"]:
            plot_bands(entry["predictive_goo"], args.data, args.out_dir / f"{stem}_predictive.png")
    if args.validation_ps:
        entry["validation"] = validation_table(args, result.bayes_estimate())
    path = args.out_dir / f"water_{args.data}{suffix}.json"
    everything = json.loads(path.read_text()) if path.exists() else {}
    everything[args.statistics] = entry
    declare_input(datasets.DATA_DIR)
    write_result(path, everything, part=args.statistics, command=_command(argv))
    print(result.summary())
    print(f"wrote {path}")
    return entry


if __name__ == "__main__":
    main()
