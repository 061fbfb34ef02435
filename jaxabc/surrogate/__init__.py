"""Surrogate-accelerated calibration: a GP emulator of the simulator, a synthetic-likelihood
posterior sampled with NUTS (or ABC on emulated summaries, ``mode="abc"``), sequential design,
and held-out validation before reporting.

``build(prior, num_particles, observed=..., max_simulations=...)`` returns an
:class:`~jaxabc.algorithms.base.ABCAlgorithm` (host code) for the driver :func:`jaxabc.run`.
See ``docs/guide/surrogate.md``.
"""

from jaxabc.surrogate import abc_mode, design, diagnostics, emulator, sampling
from jaxabc.surrogate.algorithm import (
    MODES,
    EmulatorFailure,
    SurrogateAlgorithm,
    SurrogateInfo,
    SurrogateState,
    build,
)

__all__ = [
    "MODES",
    "EmulatorFailure",
    "SurrogateAlgorithm",
    "SurrogateInfo",
    "SurrogateState",
    "abc_mode",
    "build",
    "design",
    "diagnostics",
    "emulator",
    "sampling",
]
