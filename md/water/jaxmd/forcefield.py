"""Rigid four-site TIP4P water models and their reaction-field energy, in JAX.

A molecule is four sites in the order O, H1, H2, M (the order GROMACS writes them): LJ 12-6 on
the oxygens only, point charges ``q_H`` on the hydrogens and ``q_M = -2 q_H`` on the massless M
site, which sits on the HOH bisector at ``d_OM`` from the oxygen.  It is placed from the atoms
exactly as GROMACS's ``virtual_sites3`` does, ``M = O + a (H1 - O) + a (H2 - O)`` with
``a = d_OM / (2 d_OH cos(theta_HOH / 2))``, so its force is spread onto O, H1 and H2 by the
chain rule.

Electrostatics: reaction field (Tironi et al., J. Chem. Phys. 102, 5451 (1995)), as GROMACS's
``coulombtype = reaction-field`` with the Verlet scheme computes it.  For a site pair closer than
the cut-off r_c

    V(r) = f q_i q_j (1/r + k_rf r^2 - c_rf),   k_rf = (eps_rf - 1) / ((2 eps_rf + 1) r_c^3),
    c_rf = 1/r_c + k_rf r_c^2,   f = 1 / (4 pi eps_0) = 138.935458 kJ mol^-1 nm e^-2,

with ``eps_rf = inf`` giving ``k_rf = 1 / (2 r_c^3)`` (a conducting continuum).  The potential
and its force both vanish at r_c, so energy is conserved without a switching function.  GROMACS
also adds ``f q_i q_j (k_rf r^2 - c_rf)`` for every excluded (same-molecule) pair and
``-f q_i^2 c_rf / 2`` for every site; for rigid molecules those are constants whose central
forces have no net force or torque on a molecule; :func:`intramolecular_rf_energy` gives them so
energies and per-atom forces can be compared with GROMACS term by term.
LJ is cut at r_c and shifted to zero there (GROMACS ``vdw-modifier = Potential-shift``, its
default), without dispersion correction.

Why reaction field and not Ewald/PME: it is pairwise and short-ranged, so energy and forces are
one masked pair sum that ``jax.vmap`` batches over parameters and that JAX differentiates
through without a reciprocal-space grid; jax-md has no maintained PME, and a hand-written one
would need its own check.  What it costs: the field beyond r_c is that of a uniform dielectric,
which shifts the energy per molecule by a few percent relative to PME and changes dielectric
and long-range orientational properties most; site-site g(r) within r_c changes little.  The
GROMACS check compares like with like (both reaction field).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "COULOMB_CONSTANT_KJ_MOL_NM",
    "MODELS",
    "SITES_PER_MOLECULE",
    "EnergyTerms",
    "ReactionField",
    "WaterModel",
    "body_frame",
    "energy_terms",
    "get_model",
    "intramolecular_rf_energy",
    "place_m_site",
]

#: 1 / (4 pi eps_0) in kJ mol^-1 nm e^-2, from the exact 2019 SI e and N_A and CODATA 2018 eps_0
#: (GROMACS 2022 uses the same constants).
COULOMB_CONSTANT_KJ_MOL_NM = 1.602176634e-19**2 * 6.02214076e23 / (4 * math.pi * 8.8541878128e-12) / 1e-9 / 1e3
#: Sites per molecule: O, H1, H2, M.
SITES_PER_MOLECULE = 4
#: Atomic masses (amu) of O and H as in GROMACS's TIP4P topology; M is massless.
OXYGEN_MASS_AMU = 15.9994
HYDROGEN_MASS_AMU = 1.008


class WaterModel(NamedTuple):
    """Parameters of a rigid four-site water model (a pytree: fields may be traced).

    Attributes
    ----------
    sigma_nm : float
        O-O Lennard-Jones sigma (nm).
    epsilon_kj_mol : float
        O-O Lennard-Jones epsilon (kJ/mol).
    charge_h_e : float
        Hydrogen charge (e); M carries ``-2 charge_h_e``, O none.
    om_distance_nm : float
        O-M distance along the HOH bisector (nm).
    oh_distance_nm, hh_distance_nm : float
        Rigid geometry (nm).  They fix the masses' frame, so they must be concrete numbers
        when a rigid body is built (:func:`body_frame`); sigma, epsilon, charge and d_OM may
        be traced.
    """

    sigma_nm: float | jax.Array
    epsilon_kj_mol: float | jax.Array
    charge_h_e: float | jax.Array
    om_distance_nm: float | jax.Array
    oh_distance_nm: float | jax.Array = 0.09572
    hh_distance_nm: float | jax.Array = 0.15139

    @property
    def vsite_coefficient(self):
        """GROMACS ``virtual_sites3`` coefficient ``a = b`` that places M at ``om_distance_nm``."""
        half_angle_cos = jnp.sqrt(1.0 - (self.hh_distance_nm / (2.0 * self.oh_distance_nm)) ** 2)
        return self.om_distance_nm / (2.0 * self.oh_distance_nm * half_angle_cos)

    def charges(self) -> jax.Array:
        """Charges of H1, H2 and M (e), shape (3,)."""
        q = jnp.asarray(self.charge_h_e)
        return jnp.stack([q, q, -2.0 * q])

    def with_theta(self, theta: jax.Array) -> WaterModel:
        """This model with ``theta = (sigma_nm, epsilon_kj_mol[, charge_h_e[, om_distance_nm]])``.

        ``theta`` is an array whose length is static (2 to 4); its entries may be traced.
        """
        theta = jnp.asarray(theta)
        size = theta.shape[-1]
        if theta.ndim != 1 or not 2 <= size <= 4:
            raise ValueError(
                f"theta must have shape (2,) to (4,): (sigma nm, epsilon kJ/mol[, q_H e[, d_OM nm]]), got {theta.shape}"
            )
        fields = ("sigma_nm", "epsilon_kj_mol", "charge_h_e", "om_distance_nm")
        return self._replace(**{name: theta[i] for i, name in enumerate(fields[:size])})

    def to_gromacs(self):
        """The same model as :class:`md.water.topology.TIP4PParameters` (concrete values only)."""
        from md.water.topology import TIP4PParameters

        return TIP4PParameters(
            sigma_ow_nm=float(self.sigma_nm),
            epsilon_ow_kj_mol=float(self.epsilon_kj_mol),
            charge_h_e=float(self.charge_h_e),
            om_distance_nm=float(self.om_distance_nm),
            oh_distance_nm=float(self.oh_distance_nm),
            hh_distance_nm=float(self.hh_distance_nm),
        )


#: H-H distance (nm) of r_OH 0.09572 nm and 104.52 degrees, as GROMACS's TIP4P SETTLE entry
#: writes it (2 r_OH sin(52.26 deg) = 0.1513901).
_HH_NM = 0.15139

#: Published models; every one has r_OH 0.09572 nm and HOH angle 104.52 degrees (H-H 0.15139 nm).
#:
#: - ``tip4p``: Jorgensen, Chandrasekhar, Madura, Impey & Klein, J. Chem. Phys. 79, 926 (1983):
#:   A = 600e3 kcal A^12/mol, C = 610 kcal A^6/mol (sigma 0.315365 nm, epsilon 0.1550 kcal/mol),
#:   q_H 0.52 e, d_OM 0.15 A; the values of GROMACS's ``oplsaa.ff/tip4p.itp`` and of
#:   :data:`md.water.topology.TIP4P_PARAMETERS`.
#: - ``tip4p-2005``: Abascal & Vega, J. Chem. Phys. 123, 234505 (2005): sigma 3.1589 A,
#:   epsilon/k_B 93.2 K, q_H 0.5564 e, d_OM 0.1546 A.
#: - ``tip4p-ew``: Horn et al., J. Chem. Phys. 120, 9665 (2004): sigma 3.16435 A,
#:   epsilon 0.16275 kcal/mol, q_H 0.52422 e, d_OM 0.125 A.
MODELS: dict[str, WaterModel] = {
    "tip4p": WaterModel(0.315365, 0.648520, 0.52, 0.015, 0.09572, _HH_NM),
    "tip4p-2005": WaterModel(0.31589, 93.2 * 1.380649e-23 * 6.02214076e23 / 1e3, 0.5564, 0.01546, 0.09572, _HH_NM),
    "tip4p-ew": WaterModel(0.316435, 0.16275 * 4.184, 0.52422, 0.0125, 0.09572, _HH_NM),
}


def get_model(name: str | WaterModel) -> WaterModel:
    """A model by name (``"tip4p"``, ``"tip4p-2005"``, ``"tip4p-ew"``) or the model itself."""
    if isinstance(name, WaterModel):
        return name
    try:
        return MODELS[name]
    except KeyError:
        raise ValueError(f"unknown water model {name!r}; choose one of {sorted(MODELS)} or pass a WaterModel") from None


class ReactionField(NamedTuple):
    """Static settings of the cut-off interactions (changing them recompiles).

    Attributes
    ----------
    cutoff_nm : float
        LJ and Coulomb cut-off r_c (nm), on every site pair.
    epsilon_rf : float
        Dielectric constant beyond r_c; ``math.inf`` (GROMACS ``epsilon-rf = 0``) is a conductor.
    """

    cutoff_nm: float = 0.85
    epsilon_rf: float = math.inf

    @property
    def k_rf(self) -> float:
        """k_rf (nm^-3)."""
        rc3 = self.cutoff_nm**3
        if math.isinf(self.epsilon_rf):
            return 0.5 / rc3
        return (self.epsilon_rf - 1.0) / ((2.0 * self.epsilon_rf + 1.0) * rc3)

    @property
    def c_rf(self) -> float:
        """c_rf (nm^-1), which makes the pair potential zero at r_c."""
        return 1.0 / self.cutoff_nm + self.k_rf * self.cutoff_nm**2

    def validate(self, box_nm) -> None:
        """Raise ValueError unless every box edge exceeds twice the cut-off (minimum image)."""
        if not (self.cutoff_nm > 0 and (math.isinf(self.epsilon_rf) or self.epsilon_rf >= 1)):
            raise ValueError(f"need cutoff_nm > 0 and epsilon_rf >= 1 (or inf), got {self}")
        smallest = float(np.min(np.asarray(box_nm)))
        if smallest <= 2.0 * self.cutoff_nm:
            raise ValueError(
                f"box edge {smallest:.4g} nm must exceed twice the cut-off ({2 * self.cutoff_nm:g} nm): "
                "use a larger box or a shorter cut-off"
            )


class EnergyTerms(NamedTuple):
    """Intermolecular potential energy by term (kJ/mol), scalars.

    Attributes
    ----------
    lj : jax.Array
        O-O LJ, shifted to zero at r_c (GROMACS ``LJ (SR)``).
    coulomb : jax.Array
        Reaction-field Coulomb between sites of different molecules.  GROMACS's
        ``Coulomb (SR)`` is this plus :func:`intramolecular_rf_energy`.
    """

    lj: jax.Array
    coulomb: jax.Array

    @property
    def total(self) -> jax.Array:
        return self.lj + self.coulomb


def place_m_site(atoms_nm: jax.Array, model: WaterModel) -> jax.Array:
    """Add the M site to O, H1, H2 positions.

    Parameters
    ----------
    atoms_nm : array, shape (num_molecules, 3, 3)
        O, H1, H2 of each molecule (nm), each molecule whole (not split by the box).

    Returns
    -------
    jax.Array, shape (num_molecules, 4, 3)
        O, H1, H2, M.
    """
    oxygen, h1, h2 = atoms_nm[:, 0], atoms_nm[:, 1], atoms_nm[:, 2]
    a = model.vsite_coefficient
    m = oxygen + a * (h1 - oxygen) + a * (h2 - oxygen)
    return jnp.concatenate([atoms_nm, m[:, None, :]], axis=1)


def _minimum_image(delta: jax.Array, box_nm: jax.Array) -> jax.Array:
    return delta - box_nm * jnp.round(delta / box_nm)


def _masked_distance(delta: jax.Array, mask: jax.Array) -> tuple[jax.Array, jax.Array]:
    """r and r^2 with masked pairs at r = 1: their gradients stay finite (no sqrt(0))."""
    r2 = jnp.where(mask, jnp.sum(delta * delta, axis=-1), 1.0)
    return jnp.sqrt(r2), r2


def _lj(r2, mask, model: WaterModel, settings: ReactionField):
    sigma2 = jnp.asarray(model.sigma_nm) ** 2
    s6 = (sigma2 / r2) ** 3
    s6_cut = (sigma2 / settings.cutoff_nm**2) ** 3
    shift = s6_cut * s6_cut - s6_cut
    inside = mask & (r2 < settings.cutoff_nm**2)
    return jnp.where(inside, 4.0 * model.epsilon_kj_mol * (s6 * s6 - s6 - shift), 0.0)


def _coulomb(r, qq, mask, settings: ReactionField):
    inside = mask & (r < settings.cutoff_nm)
    value = COULOMB_CONSTANT_KJ_MOL_NM * qq * (1.0 / r + settings.k_rf * r * r - settings.c_rf)
    return jnp.where(inside, value, 0.0)


def energy_terms(
    sites_nm: jax.Array,
    box_nm: jax.Array,
    model: WaterModel,
    settings: ReactionField = ReactionField(),  # noqa: B008  (an immutable NamedTuple)
    neighbors: jax.Array | None = None,
) -> EnergyTerms:
    """Intermolecular LJ and reaction-field energies of a configuration.

    Parameters
    ----------
    sites_nm : array, shape (num_molecules, 4, 3)
        O, H1, H2, M positions (nm); any periodic image of each site will do.
    box_nm : array, shape (3,)
        Orthorhombic box edges (nm); each must exceed ``2 settings.cutoff_nm``
        (not checked here, see :meth:`ReactionField.validate`).
    model : WaterModel
    settings : ReactionField
    neighbors : array of int, shape (num_molecules, max_neighbors), optional
        Molecule neighbour list (jax-md ``Dense`` format: padded with ``num_molecules``), which
        must hold every molecule with a site within r_c of a site of the row's molecule, each
        pair in both rows.  ``None``: all pairs (no list, cost O(N^2), for small boxes).

    Returns
    -------
    EnergyTerms
        Each pair counted once, by the minimum image of each *site* pair (as GROMACS does).
    """
    sites_nm = jnp.asarray(sites_nm)
    num_molecules = sites_nm.shape[0]
    box_nm = jnp.asarray(box_nm, dtype=sites_nm.dtype)
    charges = model.charges().astype(sites_nm.dtype)
    if neighbors is None:
        oxygen = sites_nm[:, 0]
        other = ~jnp.eye(num_molecules, dtype=bool)
        _, r2 = _masked_distance(_minimum_image(oxygen[:, None] - oxygen[None], box_nm), other)
        lj = 0.5 * jnp.sum(_lj(r2, other, model, settings))
        charged = sites_nm[:, 1:].reshape(-1, 3)
        q = jnp.tile(charges, num_molecules)
        molecule = jnp.repeat(jnp.arange(num_molecules), 3)
        other = molecule[:, None] != molecule[None, :]
        r, _ = _masked_distance(_minimum_image(charged[:, None] - charged[None], box_nm), other)
        coulomb = 0.5 * jnp.sum(_coulomb(r, q[:, None] * q[None, :], other, settings))
        return EnergyTerms(lj, coulomb)
    # Padded entries point past the last molecule; jnp indexing clamps them, the mask drops them.
    valid = neighbors < num_molecules
    partner = sites_nm[jnp.minimum(neighbors, num_molecules - 1)]  # (N, K, 4, 3)
    delta = _minimum_image(sites_nm[:, None, :, None, :] - partner[:, :, None, :, :], box_nm)  # (N, K, 4, 4, 3)
    _, r2 = _masked_distance(delta[:, :, 0, 0], valid)
    lj = 0.5 * jnp.sum(_lj(r2, valid, model, settings))
    pair_mask = jnp.broadcast_to(valid[:, :, None, None], (*delta.shape[:2], 3, 3))
    r, _ = _masked_distance(delta[:, :, 1:, 1:], pair_mask)
    coulomb = 0.5 * jnp.sum(_coulomb(r, charges[:, None] * charges[None, :], pair_mask, settings))
    return EnergyTerms(lj, coulomb)


def intramolecular_rf_energy(
    sites_nm: jax.Array,
    model: WaterModel,
    settings: ReactionField = ReactionField(),  # noqa: B008
) -> jax.Array:
    """The reaction-field terms GROMACS adds for excluded and self pairs (kJ/mol).

    ``sum_molecules [sum_{i<j} f q_i q_j (k_rf r_ij^2 - c_rf) - sum_i f q_i^2 c_rf / 2]``.
    For rigid molecules it is a constant and its forces (central, within each molecule) have
    no net force or torque, so the dynamics never needs it; GROMACS's ``Coulomb (SR)`` and its
    per-atom forces include it.

    Parameters
    ----------
    sites_nm : array, shape (num_molecules, 4, 3)
        O, H1, H2, M, each molecule whole.
    """
    charges = jnp.concatenate([jnp.zeros(1), model.charges()]).astype(sites_nm.dtype)
    delta = sites_nm[:, :, None, :] - sites_nm[:, None, :, :]
    r2 = jnp.sum(delta * delta, axis=-1)  # (N, 4, 4)
    upper = jnp.triu(jnp.ones((4, 4), dtype=bool), k=1)
    qq = charges[:, None] * charges[None, :]
    pairs = jnp.sum(jnp.where(upper, qq * (settings.k_rf * r2 - settings.c_rf), 0.0))
    self_terms = -0.5 * settings.c_rf * jnp.sum(charges**2) * sites_nm.shape[0]
    return COULOMB_CONSTANT_KJ_MOL_NM * (pairs + self_terms)


def body_frame(model: WaterModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A molecule in its principal-axes frame, centre of mass at the origin.

    Parameters
    ----------
    model : WaterModel
        ``oh_distance_nm`` and ``hh_distance_nm`` must be concrete.

    Returns
    -------
    atoms_nm : np.ndarray, shape (3, 3)
        O, H1, H2 (float64); M is ``atoms_nm[0] + d_OM * bisector``.
    bisector : np.ndarray, shape (3,)
        Unit vector from O towards the hydrogens' midpoint, in the same frame (M = O + d_OM u).
    inertia_amu_nm2 : np.ndarray, shape (3,)
        Principal moments of inertia (ascending).
    """
    oh, hh = float(model.oh_distance_nm), float(model.hh_distance_nm)
    if not 0 < hh < 2 * oh:
        raise ValueError(f"impossible geometry: hh_distance_nm={hh} must lie in (0, 2 oh_distance_nm={2 * oh})")
    height = math.sqrt(oh**2 - (hh / 2) ** 2)
    atoms = np.array([[0.0, 0.0, 0.0], [hh / 2, 0.0, height], [-hh / 2, 0.0, height]])
    masses = np.array([OXYGEN_MASS_AMU, HYDROGEN_MASS_AMU, HYDROGEN_MASS_AMU])
    atoms = atoms - masses @ atoms / masses.sum()
    inertia = sum(m * (np.dot(p, p) * np.eye(3) - np.outer(p, p)) for m, p in zip(masses, atoms, strict=True))
    moments, axes = np.linalg.eigh(inertia)
    if np.linalg.det(axes) < 0:  # keep a proper rotation
        axes[:, 0] = -axes[:, 0]
    atoms = atoms @ axes
    bisector = np.array([0.0, 0.0, 1.0]) @ axes
    return atoms, bisector, moments
