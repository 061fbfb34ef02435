"""Surrogate-accelerated calibration: a GP emulator of the simulator, a synthetic-likelihood
posterior sampled with NUTS, sequential design, and held-out validation before reporting.

``build(prior, num_particles, observed=..., max_simulations=...)`` returns an
:class:`~jaxabc.algorithms.base.ABCAlgorithm` (host code) for the driver :func:`jaxabc.run`.
See ``docs/guide/surrogate.md``.
"""

from jaxabc.surrogate import design, diagnostics, emulator, sampling
from jaxabc.surrogate.algorithm import EmulatorFailure, SurrogateState, build

__all__ = ["EmulatorFailure", "SurrogateState", "build", "design", "diagnostics", "emulator", "sampling"]
