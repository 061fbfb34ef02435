"""A generic Lennard-Jones molecular-dynamics engine on jax-md, batched with ``jax.vmap``.

Units: nm, ps, amu, kJ/mol (see :mod:`md.units`).  Positions are stored as *fractional*
coordinates in the unit cube, so one code path serves fixed boxes (NVE, NVT) and the isotropic
NPT box of jax-md's Nose-Hoover-chain barostat.

- :mod:`md.lj.config`: :class:`EngineConfig` (static, recompiles), :class:`LJParams` (traced),
  and the state records :class:`Carry`, :class:`Diagnostics`, :class:`Thermo`.
- :mod:`md.lj.energy`: composable energy terms (:func:`make_energy_fn`): the plain-truncated or
  shifted LJ pair term, Axilrod-Teller three-body and Feynman-Hibbs corrections.
- :mod:`md.lj.neighbor`: the cell-hashed neighbour list and its static capacities.
- :mod:`md.lj.dense`: the all-pairs kernel for small boxes (no list), vmap-friendly layout.
- :mod:`md.lj.native`: the same kernel compiled for CPU (an XLA FFI call, one system per SIMD
  lane), used by default where it can run (``EngineConfig.force_kernel``).
- :mod:`md.lj.engine`: :class:`LJEngine`, whose ``init``/``run`` are pure JAX and which owns
  its neighbour lists (allocation and re-allocation after an overflow on the host).
"""

from md import _lazy_jax_md  # noqa: F401  (first: defers jax_md.rigid_body before jax_md loads)
from md.lj.config import (
    ENSEMBLES,
    FORCE_KERNELS,
    NEIGHBOR_FORMATS,
    REBUILD_POLICIES,
    Carry,
    Diagnostics,
    EngineConfig,
    LJParams,
    Thermo,
)
from md.lj.energy import (
    axilrod_teller_energy,
    feynman_hibbs_correction,
    lattice_positions,
    lj_pair_energy,
    make_energy_fn,
)
from md.lj.engine import LJEngine
from md.lj.neighbor import (
    HalfPairs,
    NeighborList,
    NeighborSpec,
    allocate_neighbor_list,
    build_neighbor_list,
)

__all__ = [
    "ENSEMBLES",
    "FORCE_KERNELS",
    "NEIGHBOR_FORMATS",
    "REBUILD_POLICIES",
    "Carry",
    "Diagnostics",
    "EngineConfig",
    "HalfPairs",
    "LJEngine",
    "LJParams",
    "NeighborList",
    "NeighborSpec",
    "Thermo",
    "allocate_neighbor_list",
    "axilrod_teller_energy",
    "build_neighbor_list",
    "feynman_hibbs_correction",
    "lattice_positions",
    "lj_pair_energy",
    "make_energy_fn",
]
