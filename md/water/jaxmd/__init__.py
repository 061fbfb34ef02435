"""Rigid TIP4P water in process on jax-md, checked against GROMACS.

Modules
-------
forcefield  TIP4P / TIP4P/2005 / TIP4P-Ew parameters, M-site placement, LJ and reaction-field
            energies per term (all pairs or a molecule neighbour list)
engine      rigid-body dynamics (jax-md ``rigid_body``): NVE and Nose-Hoover NVT, recorded frames
simulator   ``make_simulator(...) -> simulate(key, theta) -> S1..S9``, ``.pure`` (jit/vmap),
            ``.batch`` (vmapped over parameters)
reference   GROMACS ``grompp`` + ``mdrun -rerun`` on one configuration, for the checks

Nothing in :mod:`md.water` imports this package, so the GROMACS plugin does not depend on it.
"""

from md import _lazy_jax_md  # noqa: F401  (first: defers jax_md.rigid_body before jax_md loads)
from md.water.jaxmd.forcefield import MODELS, ReactionField, WaterModel, get_model
from md.water.jaxmd.simulator import PRESETS, JaxWaterPreset, JaxWaterSimulator, make_simulator

__all__ = [
    "MODELS",
    "PRESETS",
    "JaxWaterPreset",
    "JaxWaterSimulator",
    "ReactionField",
    "WaterModel",
    "get_model",
    "make_simulator",
]
