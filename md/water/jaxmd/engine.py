"""Rigid-body dynamics of TIP4P water on jax-md: NVE and NVT (Nose-Hoover chain).

Each molecule is one jax-md ``RigidBody``: its centre of mass and a unit quaternion, with the
total mass and the principal moments of inertia of O, H, H (the M site is massless).  jax-md's
integrator for rigid bodies is the NO_SQUISH splitting of Miller et al., J. Chem. Phys. 116,
8649 (2002): symplectic and time-reversible, so a fixed-box run conserves energy with no drift
beyond the round-off of the precision used, and the same splitting carries jax-md's
Nose-Hoover chain (Martyna et al. 1992).

Why rigid bodies and not SETTLE-like constraints: the molecule is rigid by definition, and
jax-md ships a tested integrator for exactly that; constraints would need a hand-written
SETTLE/RATTLE inside the step whose iteration and tolerance are one more thing to check, and
would carry nine coordinates per molecule instead of six degrees of freedom.  What rigid
bodies do not give: jax-md's NPT (MTTK) barostat works on point particles only (its
``rigid_body`` module says so), so this engine runs NVT at a fixed box; the box of GROMACS's
equilibrated ``tip4p.gro`` (216 molecules at 1.86824 nm) is the state point.

Site positions are ``centre + R(q) s_k`` with R the rotation matrix of the *normalised*
quaternion: its gradient with respect to q is then orthogonal to q, which is the projection
jax-md applies to its own rotation (``rigid_body._quaternion_rotate``), and unlike that custom
VJP it can be differentiated in forward mode as well (for d(summary)/d(theta) with ``jax.jvp``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax_md import partition, rigid_body, simulate, space

from md.units import BOLTZMANN_KJ_MOL_K
from md.water.jaxmd.forcefield import (
    HYDROGEN_MASS_AMU,
    OXYGEN_MASS_AMU,
    ReactionField,
    WaterModel,
    body_frame,
    energy_terms,
)

__all__ = [
    "STATUS_NEIGHBOR_OVERFLOW",
    "STATUS_NONFINITE_ENERGY",
    "Frames",
    "RigidWater",
    "quaternion_from_rotation",
    "rigid_bodies_from_atoms",
    "rotation_matrix",
]

Array = jax.Array

#: Status bits of a run (inside JAX, failures are data).
STATUS_NONFINITE_ENERGY = 1
STATUS_NEIGHBOR_OVERFLOW = 2


def _rigid_body(center: Array, orientation) -> rigid_body.RigidBody:
    # jax-md's dataclass decorator hides the constructor's fields from static type checkers.
    return rigid_body.RigidBody(center, orientation)  # pyright: ignore[reportCallIssue]


def rotation_matrix(quaternion: Array) -> Array:
    """Rotation matrices of unit quaternions (w, x, y, z), normalised first.

    Parameters
    ----------
    quaternion : array, shape (..., 4)

    Returns
    -------
    jax.Array, shape (..., 3, 3)
        The matrix of jax-md's ``quaternion_rotate`` (``v -> q v q*``, Hamilton product).
    """
    q = quaternion / jnp.linalg.norm(quaternion, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return jnp.stack([jnp.stack(row, axis=-1) for row in rows], axis=-2)


def quaternion_from_rotation(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z), w >= 0, of proper rotation matrices; shape (..., 3, 3) -> (..., 4)."""
    rotation = np.asarray(rotation, dtype=np.float64)
    flat = rotation.reshape(-1, 3, 3)
    out = np.empty((flat.shape[0], 4))
    for n, m in enumerate(flat):
        # The eigenvector of the symmetric 4x4 matrix of Bar-Itzhack (2000): stable for any angle.
        k = (
            np.array(
                [
                    [m[0, 0] - m[1, 1] - m[2, 2], m[1, 0] + m[0, 1], m[2, 0] + m[0, 2], m[2, 1] - m[1, 2]],
                    [m[1, 0] + m[0, 1], m[1, 1] - m[0, 0] - m[2, 2], m[2, 1] + m[1, 2], m[0, 2] - m[2, 0]],
                    [m[2, 0] + m[0, 2], m[2, 1] + m[1, 2], m[2, 2] - m[0, 0] - m[1, 1], m[1, 0] - m[0, 1]],
                    [m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1], m[0, 0] + m[1, 1] + m[2, 2]],
                ]
            )
            / 3.0
        )
        _, vectors = np.linalg.eigh(k)
        x, y, z, w = vectors[:, -1]
        q = np.array([w, x, y, z])
        out[n] = q if w >= 0 else -q
    return out.reshape((*rotation.shape[:-2], 4))


def rigid_bodies_from_atoms(
    atoms_nm: np.ndarray, box_nm: np.ndarray, model: WaterModel
) -> tuple[np.ndarray, np.ndarray]:
    """Best-fitting rigid molecules (Kabsch) for O, H1, H2 positions.

    Parameters
    ----------
    atoms_nm : np.ndarray, shape (num_molecules, 3, 3)
        O, H1, H2; a molecule split by the box is made whole first (minimum image from O).
    box_nm : np.ndarray, shape (3,)
    model : WaterModel

    Returns
    -------
    centers_nm : np.ndarray, shape (num_molecules, 3)
        Centres of mass wrapped into the box.
    quaternions : np.ndarray, shape (num_molecules, 4)
    """
    atoms = np.asarray(atoms_nm, dtype=np.float64)
    box = np.asarray(box_nm, dtype=np.float64)
    bonds = atoms[:, 1:] - atoms[:, :1]
    atoms = np.concatenate([atoms[:, :1], atoms[:, :1] + bonds - box * np.round(bonds / box)], axis=1)
    reference, _, _ = body_frame(model)
    masses = np.array([OXYGEN_MASS_AMU, HYDROGEN_MASS_AMU, HYDROGEN_MASS_AMU])
    centers = np.einsum("k,nkd->nd", masses, atoms) / masses.sum()
    relative = atoms - centers[:, None]
    covariance = np.einsum("k,nki,kj->nij", masses, relative, reference)
    u, _, vt = np.linalg.svd(covariance)
    sign = np.sign(np.linalg.det(u @ vt))
    correction = np.ones((atoms.shape[0], 3))
    correction[:, -1] = sign
    rotations = (u * correction[:, None, :]) @ vt
    return np.mod(centers, box), quaternion_from_rotation(rotations)


class Frames(NamedTuple):
    """Positions recorded along a run.

    Attributes
    ----------
    oxygen_nm : jax.Array, shape (num_frames, num_molecules, 3)
    hydrogen_nm : jax.Array, shape (num_frames, 2 num_molecules, 3)
        Hydrogens of molecule i at rows 2i and 2i + 1.
    potential_kj_mol : jax.Array, shape (num_frames,)
    kinetic_kj_mol : jax.Array, shape (num_frames,)
    box_nm : jax.Array, shape (num_frames, 3)
        The box of each frame (constant in NVT, the barostat's in NPT).
    """

    oxygen_nm: Array
    hydrogen_nm: Array
    potential_kj_mol: Array
    kinetic_kj_mol: Array
    box_nm: Array


class RigidWater:
    """TIP4P water as jax-md rigid bodies in a fixed orthorhombic box.

    Parameters
    ----------
    num_molecules : int
    box_nm : array_like, shape (3,)
        Box edges (nm); each must exceed twice the cut-off.
    geometry : WaterModel
        Supplies the rigid geometry (O-H, H-H); sigma, epsilon, charge and d_OM are passed to
        each call, so they may be traced.
    settings : ReactionField
        Cut-off and reaction field (static).
    dt_ps : float
        Time step (ps).
    neighbor_list : bool or None
        Molecule neighbour list (jax-md ``partition``, Dense format) or all pairs.  ``None``
        chooses the list when its sphere holds under a third of the box (large boxes); all
        pairs cost O(N^2) but cannot overflow.
    skin_nm : float
        Neighbour-list skin (nm).
    capacity_multiplier : float
        jax-md's headroom of a list over the occupancy it is allocated at (default 1.25).
    dtype : numpy dtype
        ``float32`` (default) or ``float64`` (needs ``jax.config.update("jax_enable_x64", True)``
        or the ``jax.enable_x64`` context around tracing and running).

    Notes
    -----
    The thermostat targets 6N - 3 degrees of freedom (jax-md counts 6N; the initial velocities
    have zero total momentum, which the dynamics keeps), by handing it ``kT (6N - 3) / 6N``.
    """

    def __init__(
        self,
        num_molecules: int,
        box_nm,
        geometry: WaterModel,
        settings: ReactionField = ReactionField(),  # noqa: B008
        dt_ps: float = 0.002,
        neighbor_list: bool | None = None,
        skin_nm: float = 0.1,
        dtype=jnp.float32,
        capacity_multiplier: float = 1.25,
    ) -> None:
        box = np.broadcast_to(np.asarray(box_nm, dtype=np.float64), (3,)).copy()
        settings.validate(box)
        if num_molecules < 2:
            raise ValueError(f"num_molecules must be at least 2, got {num_molecules}")
        if dtype == jnp.float64 and not jax.config.read("jax_enable_x64"):
            raise ValueError("dtype=float64 needs x64: jax.config.update('jax_enable_x64', True)")
        self.num_molecules = int(num_molecules)
        self.geometry = geometry
        self.settings = settings
        self.dt_ps = float(dt_ps)
        self.dtype = dtype
        self.box_nm = jnp.asarray(box, dtype=dtype)
        atoms, bisector, moments = body_frame(geometry)
        self._atoms_body = jnp.asarray(atoms, dtype=dtype)
        self._oxygen_body = np.asarray(atoms[0])
        self._bisector_body = np.asarray(bisector)
        total_mass = OXYGEN_MASS_AMU + 2 * HYDROGEN_MASS_AMU
        self.mass = _rigid_body(
            jnp.full((num_molecules,), total_mass, dtype=dtype),
            jnp.tile(jnp.asarray(moments, dtype=dtype), (num_molecules, 1)),
        )
        radius = float(np.max(np.linalg.norm(np.vstack([atoms, atoms[0] + 0.05 * bisector]), axis=1)))
        self.list_cutoff_nm = settings.cutoff_nm + 2 * radius
        self.skin_nm = float(skin_nm)
        list_volume = 4.0 / 3.0 * math.pi * (self.list_cutoff_nm + skin_nm) ** 3
        if neighbor_list is None:
            neighbor_list = list_volume < float(np.prod(box)) / 3.0
        self.use_neighbor_list = bool(neighbor_list)
        self.displacement, self.shift = space.periodic(self.box_nm)
        self.neighbor_fn = None
        if self.use_neighbor_list:
            if 2 * (self.list_cutoff_nm + skin_nm) >= float(box.min()):
                raise ValueError("the neighbour-list radius exceeds half the box: use neighbor_list=False")
            self.neighbor_fn = partition.neighbor_list(
                self.displacement,
                self.box_nm,
                self.list_cutoff_nm,
                dr_threshold=skin_nm,
                format=partition.NeighborListFormat.Dense,
                capacity_multiplier=capacity_multiplier,
                # jax-md's cell list needs at least three cells per edge.
                disable_cell_list=float(box.min()) < 3 * (self.list_cutoff_nm + skin_nm),
            )

    # -- geometry -----------------------------------------------------------------------------

    def sites(self, body: rigid_body.RigidBody, model: WaterModel) -> Array:
        """O, H1, H2, M positions (nm) of rigid bodies; shape (num_molecules, 4, 3).

        The M site is ``O + d_OM u`` in the body frame, with ``model.om_distance_nm`` (traced).
        """
        orientation = body.orientation
        q = orientation.vec if isinstance(orientation, rigid_body.Quaternion) else orientation
        m_body = jnp.asarray(self._oxygen_body, self.dtype) + model.om_distance_nm * jnp.asarray(
            self._bisector_body, self.dtype
        )
        local = jnp.concatenate([self._atoms_body, m_body[None].astype(self.dtype)], axis=0)
        return body.center[:, None, :] + jnp.einsum("nij,kj->nki", rotation_matrix(q), local)

    def bodies(self, atoms_nm: np.ndarray, box_nm: np.ndarray | None = None) -> rigid_body.RigidBody:
        """Rigid bodies fitted to O, H1, H2 positions (see :func:`rigid_bodies_from_atoms`)."""
        box = np.asarray(self.box_nm if box_nm is None else box_nm)
        centers, quaternions = rigid_bodies_from_atoms(atoms_nm, box, self.geometry)
        quaternion = rigid_body.Quaternion(jnp.asarray(quaternions, self.dtype))  # pyright: ignore[reportCallIssue]
        return _rigid_body(jnp.asarray(centers, self.dtype), quaternion)

    # -- energy -------------------------------------------------------------------------------

    def energy_fn(self, model: WaterModel):
        """``energy(body, neighbor=None, **unused) -> kJ/mol`` for jax-md's integrators."""

        def energy(body, neighbor=None, **unused):
            idx = None if neighbor is None else neighbor.idx
            return energy_terms(self.sites(body, model), self.box_nm, model, self.settings, idx).total

        return energy

    def allocate_neighbors(self, body: rigid_body.RigidBody, extra_capacity: int = 6):
        """A neighbour list for ``body``, or None without a list.

        Host code: the capacity is fixed here, ``capacity_multiplier`` times the largest
        occupancy in ``body`` plus ``extra_capacity`` slots; a run that outgrows it reports
        ``STATUS_NEIGHBOR_OVERFLOW`` (the simulator then reallocates and reruns).
        """
        if self.neighbor_fn is None:
            return None
        if extra_capacity < 0:
            raise ValueError(f"extra_capacity must be >= 0, got {extra_capacity}")
        return self.neighbor_fn.allocate(body.center, extra_capacity=int(extra_capacity))

    # -- integrators --------------------------------------------------------------------------

    def _kt(self, temperature_k: float) -> float:
        dof_fraction = (6 * self.num_molecules - 3) / (6 * self.num_molecules)
        return BOLTZMANN_KJ_MOL_K * temperature_k * dof_fraction

    def nve(self, model: WaterModel):
        """jax-md ``(init_fn, apply_fn)`` at constant energy; ``init_fn(key, body, kT, mass=...)``."""
        return simulate.nve(self.energy_fn(model), self.shift, self.dt_ps)

    def nvt(self, model: WaterModel, temperature_k: float, tau_t_ps: float = 0.1, chain_length: int = 3):
        """jax-md Nose-Hoover chain ``(init_fn, apply_fn)`` at ``temperature_k``."""
        return simulate.nvt_nose_hoover(
            self.energy_fn(model),
            self.shift,
            self.dt_ps,
            self._kt(temperature_k),
            chain_length=chain_length,
            tau=tau_t_ps,
        )

    def nvt_invariant(self, model: WaterModel, state, temperature_k: float, neighbor=None) -> Array:
        """The Nose-Hoover extended energy (kJ/mol), conserved by exact NVT dynamics."""
        invariant = simulate.nvt_nose_hoover_invariant(
            self.energy_fn(model), state, self._kt(temperature_k), neighbor=neighbor
        )
        return jnp.asarray(invariant)

    def kinetic_energy(self, state) -> Array:
        """Translational plus rotational kinetic energy (kJ/mol)."""
        return simulate.kinetic_energy(state)

    # -- runs ---------------------------------------------------------------------------------

    def run_nvt(
        self,
        key: Array,
        model: WaterModel,
        body: rigid_body.RigidBody,
        temperature_k: float,
        num_frames: int,
        steps_per_frame: int,
        equilibration_steps: int = 0,
        tau_t_ps: float = 0.1,
        neighbor=None,
        ensemble: str = "nvt",
    ) -> tuple[Frames, Array]:
        """Equilibrate, then record ``num_frames`` frames ``steps_per_frame`` steps apart.

        Pure JAX (``jit``/``vmap`` over ``key`` and the traced fields of ``model``); the step
        counts are static.  ``ensemble="nve"`` runs plain velocity Verlet from velocities drawn
        at ``temperature_k`` (for conservation checks).

        Parameters
        ----------
        key : PRNG key
            Draws the initial velocities.
        model : WaterModel
        body : RigidBody
            Start (e.g. :meth:`bodies` of GROMACS's ``tip4p.gro``).
        neighbor : jax-md NeighborList, optional
            From :meth:`allocate_neighbors`; required when the engine uses a list.

        Returns
        -------
        frames : Frames
            Frame k is taken after ``equilibration_steps + (k + 1) steps_per_frame`` steps.
        status : jax.Array, int32 scalar
            Bitwise OR of ``STATUS_NONFINITE_ENERGY`` and ``STATUS_NEIGHBOR_OVERFLOW``; 0 if fine.
        """
        if self.use_neighbor_list and neighbor is None:
            raise ValueError("this engine uses a neighbour list: pass neighbor=engine.allocate_neighbors(body)")
        kt = self._kt(temperature_k)
        energy = self.energy_fn(model)
        if ensemble == "nvt":
            init_fn, apply_fn = self.nvt(model, temperature_k, tau_t_ps)
            state = init_fn(key, body, mass=self.mass, neighbor=neighbor)
        elif ensemble == "nve":
            init_fn, apply_fn = self.nve(model)
            state = init_fn(key, body, kt, mass=self.mass, neighbor=neighbor)
        else:
            raise ValueError(f"ensemble must be 'nvt' or 'nve', got {ensemble!r}")

        def one_step(carry, _):
            state, nbrs, overflow = carry
            if nbrs is not None:
                nbrs = nbrs.update(state.position.center)
                overflow = overflow | (jnp.asarray(nbrs.did_buffer_overflow) != 0)
            state = apply_fn(state, neighbor=nbrs)  # pyright: ignore[reportCallIssue]
            return (state, nbrs, overflow), None

        def advance(carry, num_steps):
            return jax.lax.scan(one_step, carry, None, length=num_steps)[0] if num_steps else carry

        carry = advance((state, neighbor, jnp.asarray(False)), equilibration_steps)

        def frame(carry, _):
            carry = advance(carry, steps_per_frame)
            state, nbrs, _ = carry
            sites = self.sites(state.position, model)
            wrapped = jnp.mod(sites, self.box_nm)
            record = Frames(
                wrapped[:, 0],
                wrapped[:, 1:3].reshape(-1, 3),
                energy(state.position, neighbor=nbrs),
                self.kinetic_energy(state),
                self.box_nm,
            )
            return carry, record

        (_, _, overflow), frames = jax.lax.scan(frame, carry, None, length=num_frames)
        finite = jnp.all(jnp.isfinite(frames.potential_kj_mol)) & jnp.all(jnp.isfinite(frames.oxygen_nm))
        status = jnp.where(finite, 0, STATUS_NONFINITE_ENERGY) | jnp.where(overflow, STATUS_NEIGHBOR_OVERFLOW, 0)
        return frames, status.astype(jnp.int32)
