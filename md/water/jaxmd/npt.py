"""NPT for rigid TIP4P on jax-md: Nose-Hoover NVT steps and a Monte Carlo barostat.

jax-md's MTTK barostat (``simulate.npt_nose_hoover``) works on point particles only; rigid
bodies carry a quaternion it cannot rescale.  Here the volume is sampled by Monte Carlo moves
between stretches of the engine's Nose-Hoover-chain NVT dynamics (Chow & Ferguson, Comput. Phys.
Commun. 91, 283 (1995); OpenMM's ``MonteCarloBarostat``), on the molecules' centres of mass:

- every ``interval_steps`` NVT steps propose ``ln V' = ln V + delta``, delta uniform in
  ``[-w, w]``; scale every centre of mass (wrapped into the box first) and the box edges by
  ``s = (V'/V)^(1/3)``; orientations and momenta are kept, so each molecule keeps its geometry
  exactly;
- accept with ``min(1, exp(-beta [U(V') - U(V) + P (V' - V)] + (N + 1) ln(V'/V)))``, N the
  number of molecules.  ``N`` counts the scaled centres; the ``+ 1`` is the Jacobian of a walk in
  ``ln V`` rather than in ``V`` (Frenkel & Smit, *Understanding Molecular Simulation*, section
  5.4; OpenMM proposes in V and uses N).  The stationary volume density is then
  ``V^N exp(-beta (P V + U))``, the isothermal-isobaric ensemble of molecules, whose ideal-gas
  mean is ``<V> = (N + 1) kT / P``;
- a rejected move returns the old state unchanged, bit for bit (a ``jnp.where`` over the whole
  state, so it works under ``vmap``); an accepted one also stores the forces at the new positions
  and box, which the next velocity-Verlet half kick uses;
- the proposal width ``w`` adapts during equilibration only (OpenMM's rule, without its cap:
  after at least 10 attempts, divided by 1.1 below 25 % acceptance, times 1.1 above 75 %, and
  the count restarts); in production it is frozen, so the production moves form a fixed,
  reversible Markov kernel.

Why this and not a barostat in the equations of motion: an MTTK or Langevin piston acting on
the centres of mass would need its own rigid-body integrator (the box momentum couples to the
NO_SQUISH translation step), to be written and verified here; the Monte Carlo move reuses
jax-md's NVT step untouched, needs only the energy, and its correctness reduces to the
acceptance rule above, which the ideal-gas test checks against the analytic answer.  The price:
no dynamical meaning of the volume's motion (fine for densities and structure), and one energy
plus one energy-and-force evaluation per move.

The thermostat stays valid across a volume move: momenta are not touched, so the Nose-Hoover
chain's variables describe the same kinetic energy.  The reaction field and LJ cut-off act on
site pairs by the minimum image of the *current* box, which every energy call receives as an
argument (``box=``, passed by jax-md to the energy and the shift function).  A box edge must
stay above twice the cut-off: proposals below that are rejected, which truncates the sampled
volumes there; the run reports it as :data:`STATUS_BOX_AT_CUTOFF_LIMIT`.

Pairs: all pairs, always.  A neighbour list would have to be rebuilt (and its capacity fixed on
the host) whenever the box changes; at the sizes this engine targets (a few hundred molecules at
r_c ~ 0.85 nm) a list saves nothing (see :class:`~md.water.jaxmd.engine.RigidWater`).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax_md import rigid_body, simulate

from md.units import AMU_IN_KG, BAR_IN_KJ_MOL_NM3, BOLTZMANN_KJ_MOL_K
from md.water.jaxmd.engine import STATUS_NONFINITE_ENERGY, Frames, RigidWater
from md.water.jaxmd.forcefield import HYDROGEN_MASS_AMU, OXYGEN_MASS_AMU, WaterModel, energy_terms

__all__ = [
    "STATUS_BOX_AT_CUTOFF_LIMIT",
    "STATUS_NONFINITE_ENERGY",
    "MonteCarloBarostat",
    "MoveInfo",
    "NPTRun",
    "NPTState",
    "density_kg_m3",
]

Array = jax.Array

#: Status bit: a proposed box edge fell to twice the cut-off or below (the move was rejected, so
#: the volumes sampled are truncated there).  Bit 1 is the engine's ``STATUS_NONFINITE_ENERGY``.
STATUS_BOX_AT_CUTOFF_LIMIT = 8

#: Mass of one water molecule (amu), from the topology's O and H masses (M is massless).
WATER_MASS_AMU = OXYGEN_MASS_AMU + 2 * HYDROGEN_MASS_AMU
_ADAPT_EVERY = 10


def density_kg_m3(volume_nm3: Array | np.ndarray | float, num_molecules: int) -> Any:
    """Mass density (kg/m^3) of ``num_molecules`` waters in ``volume_nm3`` (nm^3); any shape."""
    return num_molecules * WATER_MASS_AMU * AMU_IN_KG / (volume_nm3 * 1e-27)


class NPTState(NamedTuple):
    """State of an NPT run (a pytree: ``jit``, ``vmap`` and ``lax.scan`` carry it).

    Attributes
    ----------
    nvt : jax-md ``NVTNoseHooverState``
        Rigid bodies (centres wrapped into the box), momenta, forces at the current box, masses
        and the Nose-Hoover chain.
    box_nm : jax.Array, shape (3,)
        Orthorhombic box edges (nm), scaled isotropically by the moves.
    log_volume_step : jax.Array, shape ()
        Half-width w of the uniform proposal of ``ln(V'/V)``.
    attempts, accepted : jax.Array, int32 shape ()
        Moves tried and accepted since the last adaptation of ``w``.
    """

    nvt: Any
    box_nm: Array
    log_volume_step: Array
    attempts: Array
    accepted: Array


class MoveInfo(NamedTuple):
    """What one volume move did (scalars; stacked along moves by ``lax.scan``).

    Attributes
    ----------
    accepted : jax.Array, bool
    fits : jax.Array, bool
        False when the proposed box edge was not above twice the cut-off (then rejected).
    volume_nm3 : jax.Array
        Volume after the move (nm^3).
    potential_kj_mol : jax.Array
        Potential energy after the move (kJ/mol, whole box, without GROMACS's constant
        intramolecular reaction-field terms).
    """

    accepted: Array
    fits: Array
    volume_nm3: Array
    potential_kj_mol: Array


class NPTRun(NamedTuple):
    """Series of an NPT run's production, one entry per volume move.

    Attributes
    ----------
    density_kg_m3 : jax.Array, shape (production_moves,)
    volume_nm3 : jax.Array, shape (production_moves,)
    potential_kj_mol_per_molecule : jax.Array, shape (production_moves,)
        Intermolecular potential energy per molecule (kJ/mol).
    acceptance_rate : jax.Array, shape ()
        Fraction of production volume moves accepted.
    log_volume_step : jax.Array, shape ()
        The frozen proposal half-width used in production.
    status : jax.Array, int32 shape ()
        Bitwise OR of ``STATUS_NONFINITE_ENERGY`` and ``STATUS_BOX_AT_CUTOFF_LIMIT``; 0 if fine.
    final_state : NPTState
    """

    density_kg_m3: Array
    volume_nm3: Array
    potential_kj_mol_per_molecule: Array
    acceptance_rate: Array
    log_volume_step: Array
    status: Array
    final_state: NPTState


def _rigid_body(center: Array, orientation: Any) -> rigid_body.RigidBody:
    # jax-md's dataclass decorator hides the constructor's fields from static type checkers.
    return rigid_body.RigidBody(center, orientation)  # pyright: ignore[reportCallIssue]


def _wrap_shift(position: Array, displacement: Array, box: Array | None = None, **unused) -> Array:
    # jax-md hands the step's keyword arguments to the shift function: the box is the current one.
    if box is None:
        raise ValueError("the NPT integrator needs the box: call apply_fn(state, box=box_nm)")
    return jnp.mod(position + displacement, box)


class MonteCarloBarostat:
    """Isotropic Monte Carlo barostat around the engine's Nose-Hoover NVT, for rigid water.

    Parameters
    ----------
    engine : RigidWater
        Supplies the geometry, masses, reaction-field settings, time step and precision.  Its
        own box is only the default start; it must be built with ``neighbor_list=False``.
    pressure_bar : float
        Target pressure (bar).
    temperature_k : float
        Thermostat and Monte Carlo temperature (K).
    interval_steps : int
        NVT steps between volume moves (OpenMM's default is 25).
    log_volume_step : float
        Initial half-width of the ``ln V`` proposal (adapted during equilibration).
    tau_t_ps : float
        Nose-Hoover time constant (ps).
    chain_length : int
        Nose-Hoover chain length.

    Raises
    ------
    ValueError
        If the engine uses a neighbour list, or a setting is not positive.
    """

    def __init__(
        self,
        engine: RigidWater,
        pressure_bar: float = 1.0,
        temperature_k: float = 298.0,
        interval_steps: int = 25,
        log_volume_step: float = 0.01,
        tau_t_ps: float = 0.1,
        chain_length: int = 3,
    ) -> None:
        if engine.use_neighbor_list:
            raise ValueError(
                "MonteCarloBarostat uses all pairs (the box changes): build RigidWater(..., neighbor_list=False)"
            )
        if not (temperature_k > 0 and interval_steps >= 1 and log_volume_step > 0 and tau_t_ps > 0):
            raise ValueError(
                "need temperature_k > 0, interval_steps >= 1, log_volume_step > 0 and tau_t_ps > 0; got "
                f"{temperature_k}, {interval_steps}, {log_volume_step}, {tau_t_ps}"
            )
        if not math.isfinite(pressure_bar):
            raise ValueError(f"pressure_bar must be finite, got {pressure_bar}")
        self.engine = engine
        self.pressure_bar = float(pressure_bar)
        self.temperature_k = float(temperature_k)
        self.interval_steps = int(interval_steps)
        self.initial_log_volume_step = float(log_volume_step)
        self.tau_t_ps = float(tau_t_ps)
        self.chain_length = int(chain_length)
        self.min_edge_nm = 2.0 * engine.settings.cutoff_nm

    # -- energy and NVT -----------------------------------------------------------------------

    def energy_fn(self, model: WaterModel):
        """``energy(body, box=box_nm, **unused) -> kJ/mol``: all pairs, minimum image of ``box``."""
        engine = self.engine

        def energy(body, box: Array | None = None, **unused) -> Array:
            if box is None:
                raise ValueError("the NPT energy needs the box: energy(body, box=box_nm)")
            return energy_terms(engine.sites(body, model), box, model, engine.settings).total

        return energy

    def nvt(self, model: WaterModel):
        """jax-md Nose-Hoover chain ``(init_fn, apply_fn)`` whose calls take ``box=``."""
        # As RigidWater.nvt: the chain aims at 6N - 3 degrees of freedom (zero total momentum).
        n = self.engine.num_molecules
        kt = BOLTZMANN_KJ_MOL_K * self.temperature_k * (6 * n - 3) / (6 * n)
        return simulate.nvt_nose_hoover(
            self.energy_fn(model),
            _wrap_shift,
            self.engine.dt_ps,
            kt,
            chain_length=self.chain_length,
            tau=self.tau_t_ps,
        )

    # -- the kernel ---------------------------------------------------------------------------

    def init(self, key: Array, model: WaterModel, body: rigid_body.RigidBody, box_nm: Array | None = None) -> NPTState:
        """Velocities drawn at the temperature from ``key``; centres wrapped into ``box_nm``.

        ``box_nm`` (shape (3,), nm) defaults to the engine's box; it may be traced.
        """
        engine = self.engine
        box = jnp.asarray(engine.box_nm if box_nm is None else box_nm, engine.dtype)
        body = _rigid_body(jnp.mod(body.center, box), body.orientation)
        init_fn, _ = self.nvt(model)
        nvt = init_fn(key, body, mass=engine.mass, box=box)
        zero = jnp.zeros((), jnp.int32)
        return NPTState(nvt, box, jnp.asarray(self.initial_log_volume_step, engine.dtype), zero, zero)

    def volume_move(self, key: Array, state: NPTState, model: WaterModel, adapt: bool = False):
        """One Monte Carlo volume move.

        Parameters
        ----------
        key : PRNG key
            Both draws (the proposal and the acceptance) come from it.
        state : NPTState
        model : WaterModel
        adapt : bool
            Static.  True during equilibration: the proposal width follows the acceptance.

        Returns
        -------
        state : NPTState
            The old state exactly when rejected (the adaptation counters aside).
        info : MoveInfo
        """
        energy = self.energy_fn(model)
        dtype = self.engine.dtype
        key_proposal, key_accept = jax.random.split(key)
        log_ratio = state.log_volume_step * jax.random.uniform(key_proposal, (), dtype, -1.0, 1.0)
        scale = jnp.exp(log_ratio / 3.0)
        old_body = state.nvt.position
        box = state.box_nm
        new_box = box * scale
        new_body = _rigid_body(jnp.mod(old_body.center, box) * scale, old_body.orientation)
        old_energy = energy(old_body, box=box)
        new_energy, gradient = jax.value_and_grad(energy)(new_body, box=new_box)
        old_volume, new_volume = jnp.prod(box), jnp.prod(new_box)
        beta = 1.0 / (BOLTZMANN_KJ_MOL_K * self.temperature_k)
        pressure = self.pressure_bar * BAR_IN_KJ_MOL_NM3
        num_molecules = self.engine.num_molecules
        log_acceptance = (
            -beta * (new_energy - old_energy + pressure * (new_volume - old_volume)) + (num_molecules + 1) * log_ratio
        )
        fits = jnp.min(new_box) > self.min_edge_nm
        # A NaN energy compares False: rejected.
        accept = fits & (jnp.log(jax.random.uniform(key_accept, (), dtype)) < log_acceptance)
        force = jax.tree_util.tree_map(jnp.negative, gradient)
        proposed_nvt = state.nvt.set(position=new_body, force=force)
        nvt = jax.tree_util.tree_map(lambda new, old: jnp.where(accept, new, old), proposed_nvt, state.nvt)
        box = jnp.where(accept, new_box, box)
        attempts = state.attempts + 1
        accepted = state.accepted + accept.astype(jnp.int32)
        step = state.log_volume_step
        if adapt:
            # OpenMM's rule; its counters restart only when the width changes.
            low = (attempts >= _ADAPT_EVERY) & (accepted < 0.25 * attempts)
            high = (attempts >= _ADAPT_EVERY) & (accepted > 0.75 * attempts)
            step = jnp.where(low, step / 1.1, jnp.where(high, step * 1.1, step)).astype(dtype)
            attempts = jnp.where(low | high, 0, attempts)
            accepted = jnp.where(low | high, 0, accepted)
        info = MoveInfo(
            accept,
            fits,
            jnp.where(accept, new_volume, old_volume),
            jnp.where(accept, new_energy, old_energy),
        )
        return NPTState(nvt, box, step, attempts, accepted), info

    def move(self, key: Array, state: NPTState, model: WaterModel, adapt: bool = False):
        """``interval_steps`` NVT steps at the current box, then one volume move (same returns)."""
        _, apply_fn = self.nvt(model)

        def one_step(nvt, _):
            return apply_fn(nvt, box=state.box_nm), None  # pyright: ignore[reportCallIssue]

        nvt, _ = jax.lax.scan(one_step, state.nvt, None, length=self.interval_steps)
        return self.volume_move(key, state._replace(nvt=nvt), model, adapt)

    # -- runs ---------------------------------------------------------------------------------

    def run(
        self,
        key: Array,
        model: WaterModel,
        body: rigid_body.RigidBody,
        equilibration_moves: int,
        production_moves: int,
        box_nm: Array | None = None,
    ) -> NPTRun:
        """NPT equilibration (adapting the proposal), then production with it frozen.

        Pure JAX: ``jit`` and ``vmap`` over ``key``, the traced fields of ``model``, ``body`` and
        ``box_nm``; the move counts are static.  Each move is ``interval_steps`` NVT steps and
        one volume move, so the run is ``(equilibration_moves + production_moves) *
        interval_steps`` MD steps.

        Parameters
        ----------
        key : PRNG key
            Velocities and every Monte Carlo draw come from it.
        model : WaterModel
        body : RigidBody
            Start (e.g. ``engine.bodies(atoms, box)``).
        equilibration_moves, production_moves : int
            ``production_moves >= 1``.
        box_nm : array, shape (3,), optional
            Start box (nm); the engine's by default.

        Returns
        -------
        NPTRun
            Production series (density in kg/m^3, volume in nm^3, potential energy per molecule
            in kJ/mol), the production acceptance rate and a status bitmask.
        """
        if production_moves < 1 or equilibration_moves < 0:
            raise ValueError(
                f"need production_moves >= 1 and equilibration_moves >= 0, got {production_moves}, "
                f"{equilibration_moves}"
            )
        key_produce, state, fits_equilibration = self._equilibrate(key, model, body, equilibration_moves, box_nm)
        state, info = self._moves(state, model, key_produce, production_moves, False)
        num_molecules = self.engine.num_molecules
        status = self._status(info.potential_kj_mol, state, fits_equilibration & jnp.all(info.fits))
        return NPTRun(
            density_kg_m3(info.volume_nm3, num_molecules),
            info.volume_nm3,
            info.potential_kj_mol / num_molecules,
            jnp.mean(info.accepted.astype(self.engine.dtype)),
            state.log_volume_step,
            status.astype(jnp.int32),
            state,
        )

    def run_frames(
        self,
        key: Array,
        model: WaterModel,
        body: rigid_body.RigidBody,
        equilibration_moves: int,
        num_frames: int,
        moves_per_frame: int,
        box_nm: Array | None = None,
    ) -> tuple[Frames, Array]:
        """NPT equilibration as :meth:`run`, then ``num_frames`` frames ``moves_per_frame`` moves apart.

        The counterpart of :meth:`RigidWater.run_nvt` for the simulator: same key use as
        :meth:`run` (velocities, equilibration, production), pure JAX, static counts.

        Returns
        -------
        frames : Frames
            Wrapped O and H positions, potential and kinetic energy and the box of each frame;
            frame k is taken after ``equilibration_moves + (k + 1) moves_per_frame`` moves.
        status : jax.Array, int32 scalar
            Bitwise OR of ``STATUS_NONFINITE_ENERGY`` and ``STATUS_BOX_AT_CUTOFF_LIMIT``; 0 if fine.
        """
        if num_frames < 1 or moves_per_frame < 1 or equilibration_moves < 0:
            raise ValueError(
                f"need num_frames >= 1, moves_per_frame >= 1 and equilibration_moves >= 0, got {num_frames}, "
                f"{moves_per_frame}, {equilibration_moves}"
            )
        key_produce, state, fits_equilibration = self._equilibrate(key, model, body, equilibration_moves, box_nm)
        engine = self.engine

        def frame(carry, frame_key):
            state, fits = carry
            state, info = self._moves(state, model, frame_key, moves_per_frame, False)
            wrapped = jnp.mod(engine.sites(state.nvt.position, model), state.box_nm)
            record = Frames(
                wrapped[:, 0],
                wrapped[:, 1:3].reshape(-1, 3),
                info.potential_kj_mol[-1],
                engine.kinetic_energy(state.nvt),
                state.box_nm,
            )
            return (state, fits & jnp.all(info.fits)), record

        (state, fits), frames = jax.lax.scan(
            frame, (state, fits_equilibration), jax.random.split(key_produce, num_frames)
        )
        finite = jnp.all(jnp.isfinite(frames.oxygen_nm))
        return frames, self._status(frames.potential_kj_mol, state, fits) | jnp.where(
            finite, 0, STATUS_NONFINITE_ENERGY
        ).astype(jnp.int32)

    # -- shared pieces ------------------------------------------------------------------------

    def _moves(self, state: NPTState, model: WaterModel, key: Array, count: int, adapt: bool):
        def one(state, move_key):
            return self.move(move_key, state, model, adapt)

        return jax.lax.scan(one, state, jax.random.split(key, count))

    def _equilibrate(self, key, model, body, equilibration_moves, box_nm):
        """``(production key, state after equilibration, whether every proposal fitted)``."""
        key_init, key_equilibrate, key_produce = jax.random.split(key, 3)
        state = self.init(key_init, model, body, box_nm)
        fits = jnp.asarray(True)
        if equilibration_moves:
            state, info = self._moves(state, model, key_equilibrate, equilibration_moves, True)
            fits = jnp.all(info.fits)
        return key_produce, state, fits

    @staticmethod
    def _status(potential: Array, state: NPTState, fits: Array) -> Array:
        finite = jnp.all(jnp.isfinite(potential)) & jnp.all(jnp.isfinite(state.nvt.position.center))
        status = jnp.where(finite, 0, STATUS_NONFINITE_ENERGY) | jnp.where(fits, 0, STATUS_BOX_AT_CUTOFF_LIMIT)
        return status.astype(jnp.int32)
