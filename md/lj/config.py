"""Static configuration, parameters and state records of the LJ engine.

Units: nm, ps, amu, kJ/mol (see :mod:`md.units`).
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax

from md.units import BOLTZMANN_KJ_MOL_K

__all__ = [
    "ENSEMBLES",
    "NEIGHBOR_FORMATS",
    "REBUILD_POLICIES",
    "Array",
    "Carry",
    "Diagnostics",
    "EngineConfig",
    "LJParams",
    "Thermo",
]

Array = jax.Array

ENSEMBLES = ("npt", "nvt_nose_hoover", "nvt_langevin", "nve")
NEIGHBOR_FORMATS = ("sparse", "dense")
FORCE_KERNELS = ("auto", "native", "xla")
REBUILD_POLICIES = ("every_block", "when_needed")


class LJParams(NamedTuple):
    """Force-field parameters, traced (one set per batch member under ``vmap``).

    Attributes
    ----------
    sigma_nm : Array, shape ()
        LJ diameter, nm.
    epsilon_kj_mol : Array, shape ()
        LJ well depth, kJ/mol.
    c9_kj_mol_nm9 : Array, shape ()
        Axilrod-Teller coefficient C9, kJ/mol nm^9; ignored unless the engine was built with
        ``three_body=True``.
    fh_scale : Array, shape ()
        Multiplies the Feynman-Hibbs correction (engines built with ``feynman_hibbs=True``):
        1 is its physical strength for the configured mass and temperature, 0 switches it off.
        Traced, so a batch can vary the quantum correction without recompiling.
    """

    sigma_nm: Array
    epsilon_kj_mol: Array
    c9_kj_mol_nm9: float | Array = 0.0
    fh_scale: float | Array = 1.0


@dataclasses.dataclass(frozen=True)
class EngineConfig:
    """Static settings of an LJ engine (changing any of them recompiles).

    Parameters
    ----------
    num_atoms : int
        Number of atoms N.
    box_nm : float
        Initial side of the cubic box, nm.
    mass_amu : float
        Atomic mass, amu.
    cutoff_nm : float
        Interaction cutoff r_c, nm (fixed in physical units, not in units of sigma).
    dt_ps : float
        Time step, ps.
    temperature_k : float
        Thermostat target, K (NVE: the temperature of the initial velocities).
    ensemble : str
        One of :data:`ENSEMBLES`.
    pressure_kj_mol_nm3 : float
        Barostat target (NPT only), kJ/mol/nm^3.
    tau_t_ps, tau_p_ps : float
        Nose-Hoover thermostat / barostat damping times, ps (LAMMPS ``Tdamp`` / ``Pdamp``).
    gamma_per_ps : float
        Langevin friction, 1/ps.
    chain_length, chain_steps, sy_steps : int
        Nose-Hoover chain settings.  The defaults 3 / 1 / 1 are LAMMPS's ``fix npt``
        (``tchain 3 pchain 3 tloop 1 ploop 1``); jax-md's own 5 / 2 / 3 costs many tiny
        operations per step, which dominate small vmapped systems on CPU.
    truncation : str
        ``"plain"``: LJ up to r_c and zero beyond (LAMMPS ``lj/cut``, the paper's helium model);
        ``"shifted"``: LJ minus its value at r_c (same forces, continuous energy).
    three_body : bool
        Add the Axilrod-Teller triple-dipole term (cost N M^2 for M neighbours per atom).
    feynman_hibbs : bool
        Add the quadratic Feynman-Hibbs correction at the thermostat temperature.
    use_neighbor_list : bool
        Use a neighbour list (:func:`build_neighbor_list`: sort-based cells when the box holds
        at least three cells per side); False uses all pairs (best for small systems).
    skin_nm : float
        Neighbour-list skin, nm.
    rebuild_every : int
        Steps per block.  The skin check, and the rebuild decision, happen at block starts.
    rebuild : str
        ``"every_block"`` (default): rebuild the list at the start of every block, whatever
        happened (the only sensible choice under ``vmap``, where a conditional rebuild becomes
        a select that computes the rebuild anyway).  ``"when_needed"``: rebuild at a block
        start only if the block could otherwise outrun the skin, projecting the displacement
        since the last rebuild by twice the fastest atom's speed over the block (a real
        ``lax.cond``: worth it when members run one at a time, ``vmap_width=1``).  Both give
        the same pairs within r_c at every step, so the same physics; sums run in a different
        pair order, so trajectories agree to rounding, not bitwise.
    capacity_multiplier : float
        Capacity head-room at allocation (x what the allocation configuration needs).
    extra_capacity : int
        Extra slots at allocation (per atom for dense lists, per 64 atoms for sparse ones).
    allocation_box_fraction : float
        The list is allocated in a box this fraction of ``box_nm`` (room for NPT shrinkage:
        the cell size stays valid and capacity is ample).
    neighbor_format : str
        ``"sparse"`` (default): a half list of pairs, forces scattered once per pair; the
        cheapest for dilute systems.  ``"dense"``: (N, M) partners per atom (each pair twice);
        needed by the three-body term, which is given one automatically.
    force_kernel : str
        All-pairs forces (``use_neighbor_list=False``) from ``"native"``: the compiled CPU
        kernel of :mod:`md.lj.native` (plain LJ, float32; an error where it cannot run),
        ``"xla"``: the pure-JAX kernel of :mod:`md.lj.dense`, or ``"auto"`` (default): native
        where it can run, else xla.  Both compute the same forces to float32 rounding;
        ``LJEngine.force_kernel`` says which one an engine uses.
    """

    num_atoms: int
    box_nm: float
    mass_amu: float
    cutoff_nm: float
    dt_ps: float
    temperature_k: float
    ensemble: str = "npt"
    pressure_kj_mol_nm3: float = 0.0
    tau_t_ps: float = 2.0
    tau_p_ps: float = 20.0
    gamma_per_ps: float = 1.0
    chain_length: int = 3
    chain_steps: int = 1
    sy_steps: int = 1
    truncation: str = "plain"
    three_body: bool = False
    feynman_hibbs: bool = False
    use_neighbor_list: bool = True
    skin_nm: float = 0.3
    rebuild_every: int = 10
    rebuild: str = "every_block"
    capacity_multiplier: float = 1.5
    extra_capacity: int = 4
    allocation_box_fraction: float = 0.9
    neighbor_format: str = "sparse"
    force_kernel: str = "auto"

    def __post_init__(self) -> None:
        if self.ensemble not in ENSEMBLES:
            raise ValueError(f"unknown ensemble {self.ensemble!r}: use one of {ENSEMBLES}")
        if self.truncation not in ("plain", "shifted"):
            raise ValueError(f"truncation must be 'plain' or 'shifted', got {self.truncation!r}")
        if self.num_atoms < 2:
            raise ValueError(f"need at least 2 atoms, got num_atoms={self.num_atoms}")
        reach = self.cutoff_nm + (self.skin_nm if self.use_neighbor_list else 0.0)
        if reach > 0.5 * self.box_nm * self.allocation_box_fraction:
            # Minimum image only: a cutoff beyond half the box would miss or double-count pairs.
            raise ValueError(
                f"cutoff (+ skin) = {reach:.3f} nm exceeds half the "
                f"(shrunk) box {0.5 * self.box_nm * self.allocation_box_fraction:.3f} nm: "
                "use more atoms, a lower density, or a smaller skin"
            )
        if self.neighbor_format not in NEIGHBOR_FORMATS:
            raise ValueError(f"neighbor_format must be one of {NEIGHBOR_FORMATS}, got {self.neighbor_format!r}")
        if self.rebuild_every < 1 or self.dt_ps <= 0.0:
            raise ValueError("rebuild_every must be >= 1 and dt_ps > 0")
        if self.force_kernel not in FORCE_KERNELS:
            raise ValueError(f"force_kernel must be one of {FORCE_KERNELS}, got {self.force_kernel!r}")
        if self.rebuild not in REBUILD_POLICIES:
            raise ValueError(f"rebuild must be one of {REBUILD_POLICIES}, got {self.rebuild!r}")

    @property
    def kt_kj_mol(self) -> float:
        """k_B T at the target temperature, kJ/mol."""
        return self.temperature_k * BOLTZMANN_KJ_MOL_K

    @property
    def degrees_of_freedom(self) -> int:
        """3N - 3 when the integrator conserves zero total momentum (all but Langevin), else 3N.

        This is LAMMPS's default ``temp`` compute, so temperatures and pressures are comparable.
        """
        return 3 * self.num_atoms - (0 if self.ensemble == "nvt_langevin" else 3)


class Diagnostics(NamedTuple):
    """Sticky health flags of one trajectory (all shape ()).

    Attributes
    ----------
    overflow : Array, bool
        The neighbour (or cell) list overflowed, or the cell size became too small, at some
        rebuild: pairs may have been missed, the segment must be redone with a larger list.
    max_skin_ratio : Array, float
        Largest ``(2 max|dr| + (r_c + skin)|L/L_ref - 1|) / skin`` over blocks; above 1 a pair
        may have entered the cutoff unseen (rebuild more often or use a larger skin).
    nonfinite : Array, bool
        A non-finite position or momentum appeared.
    box_too_small : Array, bool
        The box side fell below 2 (r_c + skin): the minimum-image convention no longer holds.
    rebuilds : Array, int32
        Neighbour-list builds since :meth:`LJEngine.init` (0 without a list).
    """

    overflow: Array
    max_skin_ratio: Array
    nonfinite: Array
    box_too_small: Array
    rebuilds: int | Array = 0

    def failed(self) -> Array:
        """True when the trajectory cannot be trusted (for any reason but a fixable overflow)."""
        return self.nonfinite | self.box_too_small | (self.max_skin_ratio >= 1.0)


class Carry(NamedTuple):
    """The state carried through a simulation (one batch member).

    Attributes
    ----------
    md : jax-md state
        Integrator state; ``md.position`` is (N, 3) fractional, ``md.momentum`` (N, 3) in
        amu nm/ps.
    neighbors : NeighborList or None
        ``idx`` a :class:`HalfPairs` or shape (N, M); None when all pairs are used.
    unwrapped : Array, shape (N, 3)
        Fractional positions without periodic wrapping (for mean-squared displacements).
    diagnostics : Diagnostics
    strain_derivative : Array, shape ()
        dU/d(strain) at the current positions and box (NPT only), kJ/mol: cached so that each
        NPT step evaluates forces and virial once instead of twice.
    list_reference : Array, shape (N, 3)
        ``unwrapped`` when the neighbour list was last built (the skin check's origin).
    list_side : Array, shape ()
        The box side, nm, when the neighbour list was last built.
    """

    md: Any
    neighbors: Any
    unwrapped: Array
    diagnostics: Diagnostics
    strain_derivative: float | Array = 0.0
    list_reference: Array | None = None
    list_side: float | Array = 0.0


class Thermo(NamedTuple):
    """Instantaneous thermodynamics of one configuration (all shape ()).

    Attributes
    ----------
    kinetic : kJ/mol
    potential : kJ/mol, U
    virial : kJ/mol, W = -dU/d(ln scale) = sum over pairs of r . F (plus three-body part)
    volume : nm^3
    temperature : K, 2 KE / (dof k_B)
    pressure : kJ/mol/nm^3, (2 KE + W) / (3 V)
    """

    kinetic: Array
    potential: Array
    virial: Array
    volume: Array
    temperature: Array
    pressure: Array
