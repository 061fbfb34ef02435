"""jaxabc: Approximate Bayesian Computation on JAX for calibrating simulators.

The public API::

    prior = jaxabc.Uniform(low, high, names=("sigma", "epsilon"))
    result = jaxabc.run("apmcabc", simulate, prior, observed, num_particles=1000, num_steps=6)
    result.bayes_estimate(); result.correlation(); result.save("run.npz")
"""

__version__ = "0.1.0"

import importlib
import importlib.abc
import importlib.util
from importlib.machinery import ModuleSpec
from types import ModuleType

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
    module = importlib.import_module(module_name)
    value = module if attr is None else getattr(module, attr)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


# Public modules that moved into subpackages: ``import jaxabc.fused`` (and ``from jaxabc.fused
# import run_fused``) keep working, with a DeprecationWarning naming the new place.
_MOVED = {
    "jaxabc.cache": "jaxabc.executors.cache",
    "jaxabc.fused": "jaxabc.driver.fused",
    "jaxabc.priors_numpyro": "jaxabc.priors.independent",
    "jaxabc.progress": "jaxabc.executors.progress",
    "jaxabc.scheduling": "jaxabc.executors.scheduling",
}


class _MovedModuleFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Resolves an old module name in :data:`_MOVED` to the module at its new place."""

    def find_spec(self, fullname: str, path: object = None, target: object = None) -> ModuleSpec | None:
        return importlib.util.spec_from_loader(fullname, self) if fullname in _MOVED else None

    def create_module(self, spec: ModuleSpec) -> ModuleType:
        import warnings

        new = _MOVED[spec.name]
        warnings.warn(f"{spec.name} moved to {new}; import it from there", DeprecationWarning, stacklevel=2)
        return importlib.import_module(new)

    def exec_module(self, module: ModuleType) -> None:
        """Nothing to run: the module at the new place is already executed."""


def _install_moved_module_finder() -> None:
    import sys

    if not any(isinstance(f, _MovedModuleFinder) for f in sys.meta_path):
        sys.meta_path.append(_MovedModuleFinder())


_install_moved_module_finder()


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
