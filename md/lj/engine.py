"""The LJ engine: integrators over the composed energy, with neighbour lists it owns.

Ensembles: ``"npt"`` (Nose-Hoover chains on particles and box, Martyna-Tuckerman-Tobias-Klein as
in :func:`jax_md.simulate.npt_nose_hoover`), ``"nvt_nose_hoover"``, ``"nvt_langevin"``, ``"nve"``.

Implementation notes (why the code differs from jax-md's):

- The NPT step (:func:`md.lj.npt.npt_step`) reuses the strain derivative of the previous step:
  jax-md evaluates energy and gradient twice per step, once is enough.  It divides by the box
  sides instead of multiplying by the inverse box, and reduces sum p^2/m once per step; under
  ``vmap`` on CPU, reductions and 3 x 3 products cost far more than fused elementwise work.
  Trajectories equal jax-md's to rounding, not bitwise.
- Pair forces and the virial are analytic (``energy_fn.force_and_strain``): no backward pass,
  whose gather transpose is a slow scatter on CPU.  The three-body term uses autodiff.
- Nose-Hoover chains default to LAMMPS's 3 / 1 / 1 (length / chain steps / Suzuki-Yoshida)
  rather than jax-md's 5 / 2 / 3, whose many tiny operations dominate small systems.
- Neighbour lists are rebuilt at the start of a block of ``rebuild_every`` steps, at every block
  (``rebuild="every_block"``, the choice under ``vmap``, where a ``lax.cond`` becomes a select)
  or only when the block could outrun the skin (``"when_needed"``).  A block is safe when
  ``2 max|dr| + (r_c + skin) |L/L_ref - 1| < skin``; overflow, a cell size that became too small
  and an unsafe block are sticky flags in :class:`Diagnostics`.  A traced call cannot
  re-allocate: it returns the flags; the host re-allocates a larger list and redoes the chunk.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax_md import simulate as jmd_simulate
from jax_md import space

from md.lj import native as native_kernel
from md.lj.batch import _advance_batch, _init_batch, _rebuild_batch, batched
from md.lj.config import Array, Carry, Diagnostics, EngineConfig, LJParams, Thermo
from md.lj.energy import lattice_positions, make_energy_fn
from md.lj.neighbor import (
    _SPEED_MARGIN,
    NeighborList,
    NeighborSpec,
    _box_diagonal,
    allocate_neighbor_list,
    build_neighbor_list,
)
from md.lj.npt import jax_md_float32, kinetic_energy, npt_step
from md.units import BOLTZMANN_KJ_MOL_K

__all__ = ["LJEngine", "batched"]


def _resolve_force_kernel(c: EngineConfig) -> str:
    """``"native"`` or ``"xla"`` for the all-pairs forces of ``c`` (see ``force_kernel``)."""
    if c.force_kernel == "xla":
        return "xla"
    why = None
    if c.use_neighbor_list or c.three_body or c.feynman_hibbs:
        why = "it covers all-pairs plain LJ only (no neighbour list, three-body or Feynman-Hibbs term)"
    why = why or native_kernel.unavailable_reason()
    if why is None:
        return "native"
    if c.force_kernel == "native":
        raise ValueError(f"force_kernel='native' cannot be used: {why}")
    return "xla"


class LJEngine:
    """An LJ engine for one static :class:`EngineConfig`.

    Parameters
    ----------
    config : EngineConfig

    Notes
    -----
    ``init`` and ``run`` are pure JAX functions of (key, params) and (carry, params); vmap them
    over a batch.  The engine owns its neighbour lists: ``neighbor_template`` is the allocated
    list whose static capacity every member shares, :meth:`allocate_neighbors` and
    :meth:`reallocate` size it on the host (jax-md's ``allocate``), members rebuild from it
    inside jit (``update``), and :meth:`init_batch` / :meth:`run_checked` run a batch with the
    overflow check and re-allocation loop.
    """

    def __init__(self, config: EngineConfig):
        self.config = config
        c = config
        self.box0 = jnp.eye(3, dtype=jnp.float32) * c.box_nm
        self.force_kernel = _resolve_force_kernel(c)
        self.energy_fn = make_energy_fn(
            c.cutoff_nm,
            c.truncation,
            c.three_body,
            c.feynman_hibbs,
            c.mass_amu,
            c.kt_kj_mol,
            native=self.force_kernel == "native",
        )
        self.displacement_fn, self.shift_fn = space.periodic_general(self.box0, fractional_coordinates=True)
        # jax-md's Nose-Hoover chains count 3N degrees of freedom, but the total momentum is zero
        # and conserved, so only 3N - 3 are thermal: scale the target so that the kinetic
        # temperature measured with 3N - 3 (LAMMPS's convention) equals the set point.
        kt = c.kt_kj_mol
        self._kt_integrator = kt * c.degrees_of_freedom / (3.0 * c.num_atoms)
        chain = {
            "chain_length": c.chain_length,
            "chain_steps": c.chain_steps,
            "sy_steps": c.sy_steps,
        }
        if c.ensemble == "npt":
            self._thermostat = jmd_simulate.nose_hoover_chain(c.dt_ps, tau=c.tau_t_ps, **chain)
            self._barostat = jmd_simulate.nose_hoover_chain(c.dt_ps, tau=c.tau_p_ps, **chain)
            self._init_fn, self._apply_fn = jmd_simulate.npt_nose_hoover(
                self.energy_fn,
                self.shift_fn,
                c.dt_ps,
                c.pressure_kj_mol_nm3,
                self._kt_integrator,
                barostat_kwargs={"tau": c.tau_p_ps, **chain},
                thermostat_kwargs={"tau": c.tau_t_ps, **chain},
            )
        elif c.ensemble == "nvt_nose_hoover":
            self._init_fn, self._apply_fn = jmd_simulate.nvt_nose_hoover(
                self.energy_fn, self.shift_fn, c.dt_ps, self._kt_integrator, tau=c.tau_t_ps, **chain
            )
        elif c.ensemble == "nvt_langevin":
            self._init_fn, self._apply_fn = jmd_simulate.nvt_langevin(
                self.energy_fn, self.shift_fn, c.dt_ps, kt, gamma=c.gamma_per_ps
            )
        else:
            self._init_fn, self._apply_fn = jmd_simulate.nve(self.energy_fn, self.shift_fn, c.dt_ps)
        self.neighbor_template: NeighborList | None = None
        if c.use_neighbor_list:
            # Kept for callers that test ``neighbor_fn is None``: builds a list from the template.
            self.neighbor_fn = self._build
            self.allocate_neighbors()
        else:
            self.neighbor_fn = None

    # -- neighbour lists: allocated and grown on the host, rebuilt inside jit ----------------

    @property
    def neighbor_format(self) -> str:
        """``"dense"`` when the three-body term needs it, else the configured format."""
        return "dense" if self.config.three_body else self.config.neighbor_format

    def _template(self) -> NeighborList:
        # Set by allocate_neighbors, which __init__ calls whenever the engine uses a list.
        assert self.neighbor_template is not None, "this engine has no neighbour list template"
        return self.neighbor_template

    def _build(self, position: Array, box: Array) -> NeighborList:
        return build_neighbor_list(self._template().spec, position, box)

    def allocate_neighbors(
        self, position: Array | np.ndarray | None = None, previous: NeighborSpec | None = None
    ) -> NeighborList:
        """Size a neighbour list on the host and make it the engine's template.

        Parameters
        ----------
        position : Array, shape (N, 3), optional
            Fractional configuration to size the list on (in the box shrunk by
            ``allocation_box_fraction``, which over-counts); default a uniform random one.
        previous : NeighborSpec, optional
            Capacities to add as head-room (re-allocation grows every capacity at least twofold).

        Returns
        -------
        NeighborList
            The new template.  Pass it to :meth:`init` / :meth:`rebuild_neighbors` as
            ``neighbors=``: its spec is static pytree metadata, so a jitted caller retraces when
            it changes instead of building lists at a capacity captured at trace time.
        """
        if not self.config.use_neighbor_list:
            raise ValueError("this engine uses all pairs (use_neighbor_list=False): no list")
        c = self.config
        if position is None:
            position = jax.random.uniform(jax.random.PRNGKey(0), (c.num_atoms, 3), dtype=jnp.float32)
        self.neighbor_template = allocate_neighbor_list(
            self.neighbor_format,
            jnp.asarray(position),
            self.box0 * c.allocation_box_fraction,
            c.cutoff_nm + c.skin_nm,
            c.box_nm * c.allocation_box_fraction,
            c.capacity_multiplier,
            c.extra_capacity,
            previous=previous,
        )
        return self.neighbor_template

    def reallocate(self, position: Array | np.ndarray) -> NeighborList:
        """Replace the template by a larger one sized on ``position`` (N, 3), host only.

        Every capacity at least doubles (the old ones are added as head-room).  Returns the new
        template; rebuild members' lists from it with :meth:`rebuild_neighbors`.
        """
        return self.allocate_neighbors(position, previous=self._template().spec)

    def rebuild_neighbors(self, carry: Carry, neighbors: NeighborList | None = None) -> Carry:
        """Rebuild one member's list with the spec of ``neighbors`` (traced; vmap over a batch).

        ``neighbors`` defaults to the template at trace time; jitted callers should pass it.
        """
        if self.neighbor_fn is None:
            return carry
        template = self._template() if neighbors is None else neighbors
        box = self.box(carry.md)
        nbrs = template.update(carry.md.position, box=box)
        diag = carry.diagnostics._replace(rebuilds=carry.diagnostics.rebuilds + 1)
        return carry._replace(neighbors=nbrs, list_reference=carry.unwrapped, list_side=box[0, 0], diagnostics=diag)

    # -- batches on the host: overflow checks and re-allocation --------------------------------

    def init_batch(
        self,
        keys: Array,
        params: LJParams,
        width: int | None = None,
        max_reallocations: int = 6,
    ) -> Carry:
        """Start a batch (host side), re-allocating the list until no member overflows.

        Parameters
        ----------
        keys : Array, shape (B, 2) or typed (B,)
        params : LJParams with leaves of shape (B,)
        width : int, optional
            Members advanced together by ``jax.vmap`` (see :func:`batched`).
        max_reallocations : int
            Re-allocations before giving up (the carry is returned with its overflow flags set).

        Returns
        -------
        Carry with a leading batch axis of length B.
        """
        carry = _init_batch(self, width, keys, params, self.neighbor_template)
        for _ in range(max_reallocations):
            overflow = np.asarray(carry.diagnostics.overflow)
            if self.neighbor_fn is None or not overflow.any():
                break
            self.reallocate(np.asarray(carry.md.position[int(np.argmax(overflow))]))
            carry = _init_batch(self, width, keys, params, self.neighbor_template)
        return carry

    def run_checked(
        self,
        carry: Carry,
        params: LJParams,
        num_samples: int,
        blocks_per_sample: int,
        observe: Callable[[Carry, LJParams], Any] | None = None,
        width: int | None = None,
        max_reallocations: int = 6,
    ) -> tuple[Carry, Any, bool]:
        """:meth:`run` over a batch (host side), redoing the chunk after any list overflow.

        After the chunk the overflow flags are read; if any member overflowed, the list is
        re-allocated on that member's start configuration, every member's list is rebuilt from
        the new template and the whole chunk is redone from its saved start, so no pair is ever
        dropped and results do not depend on which members shared a batch.

        Parameters
        ----------
        carry : Carry with a leading batch axis (from :meth:`init_batch`)
        params : LJParams with leaves of shape (B,)
        num_samples, blocks_per_sample, observe
            As in :meth:`run`.  ``observe`` is a static argument of the compiled chunk: pass the
            same function object each time to reuse the compilation.
        width : int, optional
            See :func:`batched`.
        max_reallocations : int
            Re-allocations of this chunk before giving up.

        Returns
        -------
        (Carry, pytree or None, bool)
            The advanced carry, the stacked observations, and False if the list still overflowed
            after ``max_reallocations`` (those members' results cannot be trusted).
        """
        for attempt in range(max_reallocations + 1):
            new, out = _advance_batch(self, width, num_samples, blocks_per_sample, observe, carry, params)
            overflow = np.asarray(new.diagnostics.overflow)
            if self.neighbor_fn is None or not overflow.any():
                return new, out, True
            if attempt == max_reallocations:
                break
            self.reallocate(np.asarray(carry.md.position[int(np.argmax(overflow))]))
            carry = _rebuild_batch(self, width, carry, self.neighbor_template)
            carry = carry._replace(
                diagnostics=carry.diagnostics._replace(overflow=jnp.zeros_like(carry.diagnostics.overflow))
            )
        return new, out, False

    # -- NPT step with a cached virial ---------------------------------------------------

    def _force_and_strain(self, position: Array, box: Array, **kwargs: Any) -> tuple:
        if not self.config.three_body:
            # Analytic pair forces and virial: no backward pass (and no scatter for dense lists).
            return self.energy_fn.force_and_strain(position, box, idx=kwargs.get("idx"), params=kwargs["params"])

        def energy(pos: Array, eps: Array) -> Array:
            return self.energy_fn(pos, box=box, perturbation=1.0 + eps, **kwargs)

        grads = jax.grad(energy, argnums=(0, 1))(position, jnp.zeros((), position.dtype))
        return -grads[0], grads[1]

    # -- pure JAX ------------------------------------------------------------------------

    def box(self, md_state: Any) -> Array:
        """The current box (3, 3), nm."""
        if self.config.ensemble == "npt":
            return jmd_simulate.npt_box(md_state)
        return self.box0

    def _idx(self, carry_neighbors: Any) -> Array | None:
        # None means all pairs (see _neighbor_vectors).
        return None if carry_neighbors is None else carry_neighbors.idx

    def _step_kwargs(self, idx: Array | None, params: LJParams) -> dict:
        kwargs = {"idx": idx, "params": params}
        if self.config.ensemble != "npt":
            # npt_nose_hoover passes its own current box; the fixed-box integrators need it.
            kwargs["box"] = self.box0
        return kwargs

    def init(
        self,
        key: Array,
        params: LJParams,
        position: Array | None = None,
        neighbors: NeighborList | None = None,
    ) -> Carry:
        """Start a trajectory: jittered lattice (or ``position``) and Maxwell-Boltzmann momenta.

        Parameters
        ----------
        key : PRNG key
        params : LJParams
        position : Array, shape (N, 3), optional
            Fractional start; default a simple-cubic lattice jittered by 5% of its spacing.
        neighbors : NeighborList, optional
            The template whose spec the member's list gets (from :meth:`allocate_neighbors`);
            default the engine's template at trace time.  Pass it under ``jax.jit``.

        Returns
        -------
        Carry
        """
        c = self.config
        k_pos, k_mom = jax.random.split(key)
        if position is None:
            lattice = jnp.asarray(lattice_positions(c.num_atoms))
            spacing = 1.0 / np.ceil(c.num_atoms ** (1.0 / 3.0) - 1e-9)
            jitter = 0.05 * spacing * jax.random.uniform(k_pos, lattice.shape, minval=-1, maxval=1)
            position = jnp.mod(lattice + jitter, 1.0)
        position = position.astype(jnp.float32)
        if self.neighbor_fn is not None:
            template = self._template() if neighbors is None else neighbors
            nbrs = template.update(position, box=self.box0)
        else:
            nbrs = None
        kw = self._step_kwargs(self._idx(nbrs), params)
        mass = jnp.float32(c.mass_amu)
        with jax_md_float32():
            if c.ensemble == "npt":
                md = self._init_fn(k_mom, position, self.box0, mass=mass, **kw)
            elif c.ensemble == "nve":
                md = self._init_fn(k_mom, position, self._kt_integrator, mass=mass, **kw)
            else:
                md = self._init_fn(k_mom, position, mass=mass, **kw)
        diag = Diagnostics(
            overflow=jnp.asarray(False),
            max_skin_ratio=jnp.asarray(0.0, jnp.float32),
            nonfinite=jnp.asarray(False),
            box_too_small=jnp.asarray(False),
            rebuilds=jnp.asarray(0, jnp.int32),
        )
        if nbrs is not None:
            diag = diag._replace(overflow=self._neighbor_error(nbrs), rebuilds=jnp.asarray(1, jnp.int32))
        strain = jnp.float32(0.0)
        if c.ensemble == "npt":
            _, strain = self._force_and_strain(position, self.box0, **kw)
        return Carry(
            md=md,
            neighbors=nbrs,
            unwrapped=position,
            diagnostics=diag,
            strain_derivative=strain,
            list_reference=position,
            list_side=self.box0[0, 0],
        )

    @staticmethod
    def _neighbor_error(nbrs: Any) -> Array:
        # MALFORMED_BOX is set spuriously with fractional coordinates: read the two real flags.
        return jnp.asarray(nbrs.did_buffer_overflow, bool) | jnp.asarray(nbrs.cell_size_too_small, bool)

    def _block(self, carry: Carry, params: LJParams) -> Carry:
        """``rebuild_every`` steps, starting with a list rebuild (every block, or when needed)."""
        c = self.config
        box_now = self.box(carry.md)
        nbrs = carry.neighbors
        overflow = carry.diagnostics.overflow
        ref, side_ref = carry.list_reference, carry.list_side
        assert ref is not None, "init sets list_reference"
        rebuilds = carry.diagnostics.rebuilds
        if nbrs is not None:

            def rebuilt(_: Any) -> tuple:
                new = nbrs.update(carry.md.position, box=box_now)
                return new, carry.unwrapped, box_now[0, 0], rebuilds + 1

            if c.rebuild == "every_block":
                nbrs, ref, side_ref, rebuilds = rebuilt(None)
            else:
                moved = (carry.unwrapped - ref) * _box_diagonal(box_now)
                disp = jnp.sqrt(jnp.max(jnp.sum(moved * moved, -1)))
                speed = jnp.sqrt(jnp.max(jnp.sum(carry.md.momentum**2, -1))) / c.mass_amu
                # The fastest atom's flight over the block, with a margin for collisions that
                # speed atoms up within it.
                ahead = disp + _SPEED_MARGIN * speed * c.dt_ps * c.rebuild_every
                drift = (c.cutoff_nm + c.skin_nm) * jnp.abs(box_now[0, 0] / side_ref - 1.0)
                need = 2.0 * ahead + drift >= c.skin_nm
                nbrs, ref, side_ref, rebuilds = jax.lax.cond(
                    need, rebuilt, lambda _: (nbrs, ref, side_ref, rebuilds), None
                )
            overflow = overflow | self._neighbor_error(nbrs)
        kw = self._step_kwargs(self._idx(nbrs), params)

        with_list = self.neighbor_fn is not None
        # The list's reference positions wrapped into the box: each step measures every atom's
        # minimum-image displacement from them, which needs no per-step unwrapping.
        ref_wrapped = ref - jnp.floor(ref)

        def step(_: Any, state: tuple) -> tuple:
            md, unwrapped, max_disp2, strain = state
            old = md.position
            if c.ensemble == "npt":
                md, strain = npt_step(self, md, strain, **kw)
            else:
                with jax_md_float32():
                    md = self._apply_fn(md, **kw)
            if not with_list:
                d = md.position - old
                return md, unwrapped + (d - jnp.round(d)), max_disp2, strain  # no skin to track
            moved = md.position - ref_wrapped
            moved = (moved - jnp.round(moved)) * _box_diagonal(self.box(md))
            return md, unwrapped, jnp.maximum(max_disp2, jnp.max(jnp.sum(moved * moved, -1))), strain

        # A rebuilt list holds the same pairs within r_c, so the cached strain derivative of
        # the NPT step stays exact across the rebuild.
        md, unwrapped, max_disp2, strain = jax.lax.fori_loop(
            0,
            c.rebuild_every,
            step,
            (carry.md, carry.unwrapped, jnp.float32(0.0), carry.strain_derivative),
        )
        if with_list:
            # Unwrapped once per block: exact while no atom crosses half a box within a block,
            # which a skin ratio below 1 guarantees (every step stays within skin / 2 of the
            # reference); the per-step unwrapping it replaces cost ~2 % of a helium step.
            d = md.position - carry.md.position
            unwrapped = unwrapped + (d - jnp.round(d))
        max_disp = jnp.sqrt(max_disp2)
        side = self.box(md)[0, 0]
        scale = jnp.abs(side / side_ref - 1.0)
        reach = c.cutoff_nm + (c.skin_nm if self.neighbor_fn is not None else 0.0)
        ratio = (2.0 * max_disp + (c.cutoff_nm + c.skin_nm) * scale) / c.skin_nm
        if self.neighbor_fn is None:
            ratio = jnp.float32(0.0)  # all pairs are always present: no skin to outrun
        finite = jnp.all(jnp.isfinite(md.position)) & jnp.all(jnp.isfinite(md.momentum))
        diag = Diagnostics(
            overflow=overflow,
            max_skin_ratio=jnp.maximum(carry.diagnostics.max_skin_ratio, ratio),
            nonfinite=carry.diagnostics.nonfinite | ~finite,
            box_too_small=carry.diagnostics.box_too_small | (side < 2.0 * reach),
            rebuilds=rebuilds,
        )
        return Carry(
            md=md,
            neighbors=nbrs,
            unwrapped=unwrapped,
            diagnostics=diag,
            strain_derivative=strain,
            list_reference=ref,
            list_side=side_ref,
        )

    def run(
        self,
        carry: Carry,
        params: LJParams,
        num_samples: int,
        blocks_per_sample: int,
        observe: Callable[[Carry, LJParams], Any] | None = None,
    ) -> tuple[Carry, Any]:
        """Advance ``num_samples * blocks_per_sample * rebuild_every`` steps.

        Parameters
        ----------
        carry : Carry
        params : LJParams
        num_samples, blocks_per_sample : int (static)
        observe : callable, optional
            ``observe(carry, params) -> pytree`` called after every ``blocks_per_sample``
            blocks; its outputs are stacked along a leading axis of length ``num_samples``.

        Returns
        -------
        (Carry, pytree or None)
        """

        def sample(carry: Carry, _: Any) -> tuple[Carry, Any]:
            def block(carry: Carry, _: Any) -> tuple[Carry, None]:
                return self._block(carry, params), None

            carry, _ = jax.lax.scan(block, carry, None, length=blocks_per_sample)
            return carry, (None if observe is None else observe(carry, params))

        return jax.lax.scan(sample, carry, None, length=num_samples)

    def thermo(self, carry: Carry, params: LJParams) -> Thermo:
        """Instantaneous :class:`Thermo` of a carry (one extra energy + virial evaluation)."""
        c = self.config
        md = carry.md
        box = self.box(md)
        idx = self._idx(carry.neighbors)

        def energy(eps: Array) -> Array:
            return self.energy_fn(md.position, box, perturbation=1.0 + eps, idx=idx, params=params)

        if self.force_kernel == "native":
            potential, d_energy = self.energy_fn.energy_and_strain(md.position, box, params)
        else:
            potential, d_energy = jax.value_and_grad(energy)(jnp.float32(0.0))
        kinetic = kinetic_energy(md.momentum, md.mass)
        volume = jnp.abs(jnp.linalg.det(box))
        virial = -d_energy
        return Thermo(
            kinetic=kinetic,
            potential=potential,
            virial=virial,
            volume=volume,
            temperature=2.0 * kinetic / (c.degrees_of_freedom * BOLTZMANN_KJ_MOL_K),
            pressure=(2.0 * kinetic + virial) / (3.0 * volume),
        )

    def conserved_energy(self, carry: Carry, params: LJParams) -> Array:
        """Total energy KE + U (NVE's conserved quantity), kJ/mol."""
        t = self.thermo(carry, params)
        return t.kinetic + t.potential
