"""A calibration run used by test_run.py: killed part-way, then resumed (argv: folder, mode)."""

import sys
import time

import numpy as np

import jaxabc
from jaxabc.examples import host_gaussian_simulate


def slow_simulate(key, theta):
    time.sleep(0.001)  # long enough for the test to kill the run between checkpoints
    return host_gaussian_simulate(key, theta)


def main() -> None:
    folder, mode = sys.argv[1], sys.argv[2]
    prior = jaxabc.Uniform([-10.0], [10.0], names=("mu",))
    result = jaxabc.run(
        "apmcabc",
        slow_simulate,
        prior,
        np.array([0.0]),
        num_particles=300,
        num_steps=7,
        acceptance_cutoff=0.0,
        executor="serial",
        seed=7,
        checkpoint_dir=None if mode == "plain" else folder,
        resume=mode == "resume",
    )
    result.save(f"{folder}/result-{mode}.npz")


if __name__ == "__main__":
    main()
