"""A calibration run used by test_faults.py: killed part-way, then resumed.

argv: folder, mode (plain | ckpt | resume), optionally the method (apmcabc, the default, or
surrogate).
"""

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
    method = sys.argv[3] if len(sys.argv) > 3 else "apmcabc"
    common = dict(
        executor="serial",
        seed=7,
        checkpoint_dir=None if mode == "plain" else folder,
        resume=mode == "resume",
    )
    if method == "surrogate":
        # A host (NumPy) simulator through the surrogate's sequential design.
        prior = jaxabc.Uniform([-10.0, -10.0], [10.0, 10.0], names=("a", "b"))
        result = jaxabc.run("surrogate", slow_simulate, prior, np.array([0.5, -1.0]), max_simulations=60, **common)
    else:
        prior = jaxabc.Uniform([-10.0], [10.0], names=("mu",))
        result = jaxabc.run(
            "apmcabc",
            slow_simulate,
            prior,
            np.array([0.0]),
            num_particles=300,
            num_steps=7,
            acceptance_cutoff=0.0,
            **common,
        )
    result.save(f"{folder}/result-{mode}-{method}.npz")


if __name__ == "__main__":
    main()
