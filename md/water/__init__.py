"""TIP4P water with GROMACS: simulator plugin, trajectory analysis, S1..S9, measured data.

Modules
-------
gromacs     topology, protocol presets (``paper``, ``quick``), one ``gmx mdrun`` per call
analysis    XTC/TRR reading (mdtraj), g_OO / g_OH and oxygen MSD in JAX
statistics  S1..S9, variants ``paper`` and ``robust``
datasets    X-ray and neutron curves, the published vectors (in the right order), diffusion
simulator   ``make_simulator(...) -> simulate(key, theta) -> np.ndarray (9,)``
"""

from md.water.simulator import OBSERVED_KINDS, SimulationOutput, TIP4PSimulator, make_simulator

__all__ = ["OBSERVED_KINDS", "SimulationOutput", "TIP4PSimulator", "make_simulator"]
