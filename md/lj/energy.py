"""Energy terms of the LJ engine: pair term, Feynman-Hibbs and Axilrod-Teller corrections.

Units: nm, kJ/mol.  ``sigma`` and ``epsilon`` are traced call-time arguments (a new value never
recompiles, and ``jax.vmap`` runs many parameter sets at once).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from md.lj import native as native_kernel
from md.lj.config import Array, LJParams
from md.lj.dense import all_pairs_force_and_strain
from md.lj.neighbor import HalfPairs, _box_diagonal, _neighbor_vectors
from md.units import HBAR_KJ_MOL_PS

__all__ = [
    "axilrod_teller_energy",
    "feynman_hibbs_correction",
    "lattice_positions",
    "lj_pair_energy",
    "make_energy_fn",
]


def lj_pair_energy(r: Array, sigma: Array, epsilon: Array) -> Array:
    """LJ 12-6 pair energy 4 eps ((s/r)^12 - (s/r)^6), kJ/mol, for distances r (nm), any shape."""
    sr6 = (sigma / r) ** 6
    return 4.0 * epsilon * (sr6 * sr6 - sr6)


def feynman_hibbs_correction(r: Array, sigma: Array, epsilon: Array, mass_amu: float, kt_kj_mol: float) -> Array:
    """Quadratic Feynman-Hibbs correction to the LJ pair energy, kJ/mol.

    ``hbar^2 / (24 mu k_B T) (U'' + 2 U'/r)`` with reduced mass ``mu = m / 2`` (Feynman & Hibbs
    1965; Sese 1993 for LJ fluids).  For LJ, ``U'' + 2U'/r = 4 eps (132 s^12/r^14 - 30 s^6/r^8)``.

    Parameters
    ----------
    r : Array, nm, any shape
    sigma, epsilon : Array, shape (), nm and kJ/mol
    mass_amu : float
        Atomic mass (the pair's reduced mass is half of it).
    kt_kj_mol : float
        k_B T, kJ/mol.
    """
    reduced_mass = 0.5 * mass_amu
    prefactor = HBAR_KJ_MOL_PS**2 / (24.0 * reduced_mass * kt_kj_mol)
    sr6 = (sigma / r) ** 6
    return prefactor * 4.0 * epsilon * (132.0 * sr6 * sr6 - 30.0 * sr6) / r**2


def axilrod_teller_energy(vectors: Array, mask: Array, c9: float | Array, cutoff_nm: float) -> Array:
    """Axilrod-Teller triple-dipole energy summed over triples, kJ/mol.

    ``E = C9 (1 + 3 cos g1 cos g2 cos g3) / (r_ij r_ik r_jk)^3`` for every triple whose three
    sides are all shorter than the cutoff.  Each such triple is seen from each of its three
    vertices in a neighbour list, hence the factor 1/3.

    Parameters
    ----------
    vectors : Array, shape (N, M, 3)
        Real-space vectors from atom i to its neighbours j, nm.
    mask : Array, shape (N, M), bool
        True for real neighbours within the cutoff.
    c9 : Array, shape ()
        C9, kJ/mol nm^9 (helium: about 1.47 hartree bohr^9 = 1.27e-8 kJ/mol nm^9).
    cutoff_nm : float
    """
    a = vectors[:, :, None, :]  # i -> j
    b = vectors[:, None, :, :]  # i -> k
    c = b - a  # j -> k
    ra2 = jnp.sum(a * a, axis=-1)
    rb2 = jnp.sum(b * b, axis=-1)
    rc2 = jnp.sum(c * c, axis=-1)
    m = vectors.shape[1]
    upper = jnp.triu(jnp.ones((m, m), dtype=bool), k=1)
    valid = mask[:, :, None] & mask[:, None, :] & upper[None] & (rc2 < cutoff_nm**2)
    rc2_safe = jnp.where(valid, rc2, 1.0)
    ra2_safe = jnp.where(valid, ra2, 1.0)
    rb2_safe = jnp.where(valid, rb2, 1.0)
    ab = jnp.sum(a * b, axis=-1)
    ac = jnp.sum(a * c, axis=-1)
    bc = jnp.sum(b * c, axis=-1)
    cos_product = ab * (-ac) * bc / (ra2_safe * rb2_safe * rc2_safe)
    r2_product = ra2_safe * rb2_safe * rc2_safe
    e = c9 * (1.0 + 3.0 * cos_product) / (r2_product * jnp.sqrt(r2_product))
    return jnp.sum(jnp.where(valid, e, 0.0)) / 3.0


def make_energy_fn(
    cutoff_nm: float,
    truncation: str = "plain",
    three_body: bool = False,
    feynman_hibbs: bool = False,
    mass_amu: float = 1.0,
    kt_kj_mol: float = 1.0,
    native: bool = False,
) -> Callable[..., Array]:
    """Build ``energy_fn(position, box, perturbation=None, idx=..., params=...) -> U`` (kJ/mol).

    Parameters
    ----------
    cutoff_nm : float
        Fixed cutoff r_c, nm.
    truncation : str
        ``"plain"`` or ``"shifted"`` (see :class:`EngineConfig`).
    three_body, feynman_hibbs : bool
        Add the Axilrod-Teller / Feynman-Hibbs terms.
    mass_amu, kt_kj_mol : float
        Used by the Feynman-Hibbs term only.
    native : bool
        All-pairs forces (``idx=None``) from the compiled CPU kernel (:mod:`md.lj.native`);
        plain LJ only (no Feynman-Hibbs term).  The caller checks it is available.

    Returns
    -------
    Callable
        ``position`` (N, 3) fractional, ``box`` (3, 3) nm, ``perturbation`` () or None
        (jax-md's isotropic strain used for the virial), ``idx`` None (all pairs), (N, M) int
        partners (N marks an empty slot) or :class:`HalfPairs`, ``params`` :class:`LJParams`.
        Returns U, shape ().  Attributes: ``pair_energy(r2, params)`` (the pair term inside
        r_c, shared by every path) and ``force_and_strain(position, box, idx, params)``
        (analytic pair forces and dU/d(strain), no three-body term); with ``native``, also
        ``energy_and_strain(position, box, params)`` (U and dU/d(strain), all pairs).

    Notes
    -----
    The cutoff is fixed in nm as in the paper's LAMMPS input, not 2.5 sigma.  For sigma above
    r_c / 2.5 the truncation happens before the attractive tail has decayed, and for sigma above
    r_c (the prior corner up to 0.8 nm) the plain-truncated potential is a repulsive step at
    r_c.  The force is the analytic LJ force inside r_c and zero outside, exactly as in LAMMPS
    ``lj/cut``, so this engine simulates the same model as the paper there: energy is not
    conserved across the step (the thermostat absorbs it; NPT then runs a few percent hot), but
    the run stays finite.  ``truncation="shifted"`` changes the reported energy, not the forces.
    """

    def pair_energy(r2: Array, params: LJParams) -> Array:
        """Energy of pairs at squared distances ``r2`` (all inside r_c), any shape."""
        sigma, epsilon = params.sigma_nm, params.epsilon_kj_mol
        # (sigma^2 / r^2)^3 avoids a square root and a power per pair (the hot loop).
        sr2 = sigma * sigma / r2
        sr6 = sr2 * sr2 * sr2
        pair = 4.0 * epsilon * (sr6 * sr6 - sr6)
        if truncation == "shifted":
            pair = pair - lj_pair_energy(jnp.asarray(cutoff_nm, r2.dtype), sigma, epsilon)
        if feynman_hibbs:
            r = jnp.sqrt(r2)
            pair = pair + params.fh_scale * feynman_hibbs_correction(r, sigma, epsilon, mass_amu, kt_kj_mol)
        return pair

    def energy_fn(
        position: Array,
        box: Array,
        perturbation: Array | None = None,
        idx: Any = None,
        params: LJParams | None = None,
        **unused: Any,
    ) -> Array:
        # Optional only so jax-md can call with keyword arguments; the engine always passes it.
        assert params is not None, "energy_fn needs params=LJParams(...)"
        vectors, valid = _neighbor_vectors(position, idx, box, perturbation)
        r2 = jnp.sum(vectors * vectors, axis=-1)
        inside = valid & (r2 < cutoff_nm**2)
        # Padding and out-of-range pairs get a harmless distance so no NaN reaches the gradient.
        r2 = jnp.where(inside, r2, cutoff_nm**2)
        pair = pair_energy(r2, params)
        # Dense lists and all pairs hold every pair twice (i -> j and j -> i); half lists once.
        half = 1.0 if isinstance(idx, HalfPairs) else 0.5
        energy = half * jnp.sum(jnp.where(inside, pair, 0.0))
        if three_body:
            if isinstance(idx, HalfPairs):
                raise ValueError("the three-body term needs a dense (or no) neighbour list")
            c9 = params.c9_kj_mol_nm9
            energy = energy + axilrod_teller_energy(vectors, inside, c9, cutoff_nm)
        return energy

    def force_and_strain(
        position: Array, box: Array, idx: Any = None, params: LJParams | None = None
    ) -> tuple[Array, Array]:
        """Real-space forces (N, 3) and dU/d(strain) () of the pair terms, analytically.

        The pair derivative dU/d(r^2) is taken elementwise (no scatter in a backward pass):
        ``F_i = sum_j 2 u'(r_ij^2) r_ij`` and ``dU/d eps = sum_pairs 2 r^2 u'(r^2)`` for the
        isotropic strain ``r -> (1 + eps) r``.
        """
        assert params is not None, "force_and_strain needs params=LJParams(...)"
        if idx is None and native:
            force, strain, _ = _native_all_pairs(position, box, params)
            return force, strain
        if idx is None:
            # Small boxes: all pairs, one (N, N) array per component (see md.lj.dense).
            return all_pairs_force_and_strain(pair_energy, cutoff_nm, position, box, params)
        vectors, valid = _neighbor_vectors(position, idx, box, None, autodiff=False)
        r2 = jnp.sum(vectors * vectors, axis=-1)
        inside = valid & (r2 < cutoff_nm**2)
        r2 = jnp.where(inside, r2, cutoff_nm**2)
        du = jax.grad(lambda x: jnp.sum(pair_energy(x, params)))(r2)
        du = jnp.where(inside, du, 0.0)
        pair_force = (2.0 * du)[..., None] * vectors
        if isinstance(idx, HalfPairs):
            force = (
                jnp.zeros_like(position)
                .at[jnp.where(valid, idx.i, 0)]
                .add(pair_force)
                .at[jnp.where(valid, idx.j, 0)]
                .add(-pair_force)
            )
            strain = 2.0 * jnp.sum(du * r2)
        else:
            force = jnp.sum(pair_force, axis=1)
            strain = jnp.sum(du * r2)  # every pair twice: 1/2 x 2 r^2 u'
        return force, strain

    def _native_all_pairs(position: Array, box: Array, params: LJParams) -> tuple[Array, Array, Array]:
        side = _box_diagonal(box)
        return native_kernel.all_pairs(
            position, side, params.sigma_nm, params.epsilon_kj_mol, cutoff_nm, truncation == "shifted"
        )

    def energy_and_strain(position: Array, box: Array, params: LJParams) -> tuple[Array, Array]:
        """U and dU/d(strain) over all pairs from the compiled kernel (``native`` only)."""
        _, strain, energy = _native_all_pairs(position, box, params)
        return energy, strain

    if native and (feynman_hibbs or three_body):
        raise ValueError("the compiled all-pairs kernel covers the plain LJ pair term only")
    energy_fn.pair_energy = pair_energy  # type: ignore[attr-defined]
    energy_fn.force_and_strain = force_and_strain  # type: ignore[attr-defined]
    if native:
        energy_fn.energy_and_strain = energy_and_strain  # type: ignore[attr-defined]
    return energy_fn


def lattice_positions(num_atoms: int) -> np.ndarray:
    """Simple-cubic lattice sites in the unit cube, shape (num_atoms, 3), fractional.

    Uses the smallest n^3 >= num_atoms grid and keeps the first ``num_atoms`` sites.
    """
    n = int(np.ceil(num_atoms ** (1.0 / 3.0) - 1e-9))
    grid = (np.arange(n) + 0.5) / n
    sites = np.stack(np.meshgrid(grid, grid, grid, indexing="ij"), axis=-1).reshape(-1, 3)
    return sites[:num_atoms].astype(np.float32)
