"""The main job: calibrate the helium Lennard-Jones parameters from an f_B series with ABC.

``jaxabc example helium`` (or ``python -m md.helium_calibration``) simulates the 'observed'
series at the paper's truth (sigma 0.2556 nm, epsilon 0.141 zJ) with a longer run, then runs
APMCABC (alpha 0.1, acceptance cutoff 0.03, the paper's settings) with the KL-divergence
distance on the helium engine's ``cpu`` preset, batched with ``jax.vmap``, and writes the result
file, the posterior figure (truth and Bayes estimate marked) and a summary into the output
folder.  A checkpoint is written after every step; ``--resume`` continues an interrupted run.

The ``cpu`` preset is a scaled-down system (see :mod:`md.helium`); ``--preset paper`` runs the
published settings (about half an hour per simulation on 2 cores: for big machines).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import numpy as np

import jaxabc
from jaxabc.driver.fused import default_compilation_cache
from jaxabc.results import write_outputs
from md import helium

__all__ = ["calibrate", "main", "make_model"]


def make_model(preset: str | helium.HeliumPreset = "cpu"):
    """The helium simulator for :func:`jaxabc.run`: a vmappable ``simulate(key, theta)`` that
    carries the host-side batched runner (neighbour-list re-allocation) as ``simulate_batch``."""
    simulate = helium.make_simulator(preset)
    simulate.simulate_batch = helium.make_batch_simulator(preset)  # type: ignore[attr-defined]
    prior = jaxabc.Uniform(helium.PRIOR_LOW, helium.PRIOR_HIGH, names=("sigma", "epsilon"), units=("nm", "zJ"))
    return simulate, prior


def calibrate(
    algorithm: str = "apmcabc",
    preset: str = "cpu",
    num_particles: int = 500,
    num_steps: int = 6,
    seed: int = 0,
    output: str | Path | None = None,
    resume: bool = False,
    progress: bool = True,
    **options,
) -> jaxabc.ABCResult:
    """Run one helium calibration; returns the result (and writes it when ``output`` is set)."""
    simulate, prior = make_model(preset)
    # The observed data get their own key, disjoint from the inference's.
    observed = helium.observed_series(jax.random.key(10_000 + seed), preset)
    if algorithm == "apmcabc":
        options = {"alpha": 0.1, "acceptance_cutoff": 0.03, **options}
    result = jaxabc.run(
        algorithm,
        simulate,
        prior,
        observed,
        num_particles=num_particles,
        num_steps=num_steps,
        distance="kl",
        seed=seed,
        # The host driver, not jaxabc.run's fused default: with the MD engine inside the fused
        # program's scan, XLA compiles the engine twice and each generation runs slower
        # (engine_throughput_small_system's main-job rows measure this job).
        executor="vmap",
        progress=progress,
        # An example starts over unless asked to resume (its folder is its own).
        checkpoint_dir=output,
        resume=resume,
        overwrite=not resume,
        metadata={"model": "helium", "preset": preset, "true_theta": list(helium.TRUE_THETA)},
        **options,
    )
    if output is not None:
        write_outputs(result, Path(output), truth=np.asarray(helium.TRUE_THETA))
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--output", default="runs/helium")
    parser.add_argument("--algorithm", default="apmcabc", choices=["apmcabc", "abcsubsim"])
    parser.add_argument("--preset", default="cpu", choices=sorted(helium.PRESETS))
    parser.add_argument("--num-particles", type=int, default=500)
    parser.add_argument("--num-steps", type=int, default=6)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--resume", action="store_true")
    parser.add_argument("--quick", action="store_true", help="100 particles, 3 steps (a minute)")
    args = parser.parse_args(argv)
    n, steps = (100, 3) if args.quick else (args.num_particles, args.num_steps)
    # The job (not calibrate(), a library call) keeps its compiled programs between runs:
    # seconds of every later start (JAXABC_COMPILATION_CACHE=off turns it off).
    default_compilation_cache()
    t0 = time.perf_counter()
    result = calibrate(args.algorithm, args.preset, n, steps, args.seed, args.output, args.resume)
    est = result.bayes_estimate()
    truth = np.asarray(helium.TRUE_THETA)
    rel = np.linalg.norm((est - truth) / (np.asarray(helium.PRIOR_HIGH) - np.asarray(helium.PRIOR_LOW)))
    print(result.summary())
    print(
        f"truth sigma={truth[0]} nm, epsilon={truth[1]} zJ; distance of the Bayes estimate from "
        f"the truth in prior-range units: {rel:.4f}"
    )
    print(f"wrote {args.output}/result.npz, posterior.png, summary.txt ({time.perf_counter() - t0:.0f} s)")
    return 0


def example(folder: str | Path, quick: bool = False, resume: bool = False) -> None:
    """The ``jaxabc example helium`` entry point: :func:`main` writing into ``folder``."""
    main(["--output", str(folder), *(["--quick"] if quick else []), *(["--resume"] if resume else [])])


if __name__ == "__main__":
    raise SystemExit(main())
