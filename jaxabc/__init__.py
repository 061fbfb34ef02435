"""jaxabc: Approximate Bayesian Computation on JAX for calibrating simulators.

The public API::

    prior = jaxabc.Uniform(low, high, names=("sigma", "epsilon"))
    result = jaxabc.run("apmcabc", simulate, prior, observed, num_particles=1000, num_steps=6)
    result.bayes_estimate(); result.correlation(); result.save("run.npz")
"""

__version__ = "0.1.0"

from jaxabc import distances, kernels
from jaxabc.algorithms import BUILDERS as ALGORITHMS
from jaxabc.distances import AdaptivePNorm
from jaxabc.errors import NoPosterior, PriorEdgeWarning, SimulationFailure, TooManyFailures
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
from jaxabc.noise import Discrepancy
from jaxabc.priors import Independent, Uniform
from jaxabc.results import ABCResult, load
from jaxabc.run import run  # eager: the function shadows the submodule ``jaxabc.run``
from jaxabc.seeding import seed_from_key

# Imported on first use (PEP 562), so that ``import jaxabc`` and a plain ``run`` do not pay
# for modules they do not touch.
_LAZY = {
    "CoverageStudy": ("jaxabc.coverage", "CoverageStudy"),
    "RunCache": ("jaxabc.executors.cache", "RunCache"),
    "SittingClock": ("jaxabc.executors.progress", "SittingClock"),
    "coverage_study": ("jaxabc.coverage", "coverage_study"),
    "enable_compilation_cache": ("jaxabc.driver.fused", "enable_compilation_cache"),
    "Model": ("jaxabc.model_choice", "Model"),
    "ModelChoiceResult": ("jaxabc.model_choice", "ModelChoiceResult"),
    "model_choice": ("jaxabc.model_choice", None),
    "run_fused": ("jaxabc.driver.fused", "run_fused"),
    "scheduling": ("jaxabc.executors.scheduling", None),
}


def __getattr__(name: str):
    try:
        module_name, attr = _LAZY[name]
    except KeyError:
        raise AttributeError(f"module 'jaxabc' has no attribute {name!r}") from None
    import importlib

    module = importlib.import_module(module_name)
    value = module if attr is None else getattr(module, attr)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


def _cache_from_environment() -> None:
    import os

    if os.environ.get("JAXABC_COMPILATION_CACHE"):
        from jaxabc.driver.fused import enable_compilation_cache

        enable_compilation_cache()


_cache_from_environment()


__all__ = [
    "ALGORITHMS",
    "ABCResult",
    "AdaptivePNorm",
    "CoverageStudy",
    "DaskExecutor",
    "Discrepancy",
    "Independent",
    "MPIExecutor",
    "Model",
    "ModelChoiceResult",
    "NoPosterior",
    "PriorEdgeWarning",
    "ProcessPoolExecutor",
    "RunCache",
    "SerialExecutor",
    "SimulationBatch",
    "SimulationFailure",
    "SittingClock",
    "TooManyFailures",
    "Uniform",
    "VmapExecutor",
    "__version__",
    "coverage_study",
    "distances",
    "enable_compilation_cache",
    "get_executor",
    "kernels",
    "load",
    "mark_nonfinite",
    "model_choice",
    "run",
    "run_fused",
    "scheduling",
    "seed_from_key",
    "task_durations",
]
