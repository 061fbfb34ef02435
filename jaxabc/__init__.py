"""jaxabc: Approximate Bayesian Computation on JAX for calibrating simulators.

The public API::

    prior = jaxabc.Uniform(low, high, names=("sigma", "epsilon"))
    result = jaxabc.run("apmcabc", simulate, prior, observed, num_particles=1000, num_steps=6)
    result.bayes_estimate(); result.correlation(); result.save("run.npz")
"""

__version__ = "0.1.0"

from jaxabc import distances, kernels, scheduling
from jaxabc.algorithms import BUILDERS as ALGORITHMS
from jaxabc.coverage import CoverageStudy, coverage_study
from jaxabc.errors import SimulationFailure, TooManyFailures
from jaxabc.executors import (
    DaskExecutor,
    MPIExecutor,
    ProcessPoolExecutor,
    SerialExecutor,
    SimulationBatch,
    VmapExecutor,
    get_executor,
    mark_nonfinite,
    task_durations,
)
from jaxabc.priors import Uniform
from jaxabc.priors_numpyro import Independent
from jaxabc.results import ABCResult, load
from jaxabc.run import run
from jaxabc.seeding import seed_from_key

__all__ = [
    "ALGORITHMS",
    "ABCResult",
    "CoverageStudy",
    "DaskExecutor",
    "Independent",
    "MPIExecutor",
    "ProcessPoolExecutor",
    "SerialExecutor",
    "SimulationBatch",
    "SimulationFailure",
    "TooManyFailures",
    "Uniform",
    "VmapExecutor",
    "__version__",
    "coverage_study",
    "distances",
    "get_executor",
    "kernels",
    "load",
    "mark_nonfinite",
    "run",
    "scheduling",
    "seed_from_key",
    "task_durations",
]
