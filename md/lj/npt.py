"""The NPT (MTTK) step of the LJ engine with a cached strain derivative, and float32 helpers
for jax-md's integrators."""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Iterator
from typing import Any

import jax.numpy as jnp
from jax_md import simulate as jmd_simulate

from md.lj.config import Array
from md.lj.neighbor import _box_diagonal

__all__ = ["jax_md_float32", "kinetic_energy", "npt_step"]


def kinetic_energy(momentum: Array, mass: Array) -> Array:
    """sum p^2 / (2 m), kJ/mol, in the arrays' precision.

    jax-md's ``quantity.kinetic_energy`` asks for a float64 sum, which JAX truncates to float32
    with a warning when x64 is off; this is the same float32 sum without the request.
    """
    return 0.5 * jnp.sum(momentum**2 / mass)


@contextlib.contextmanager
def jax_md_float32() -> Iterator[None]:
    """Trace jax-md's integrators without their float64-truncation warnings.

    jax-md sums kinetic energies with ``dtype=float64`` (``util.high_precision_sum``); with x64
    off JAX truncates that to float32 and warns at every traced call site, a screen of warnings
    a user cannot act on.  The engine runs in float32 by design, so exactly that warning is
    silenced, only while jax-md code is being traced; every other warning still shows.
    """
    with warnings.catch_warnings():
        warnings.filterwarnings(
            "ignore",
            message=r"Explicitly requested dtype float64 requested in .* is not available",
            category=UserWarning,
        )
        yield


def npt_step(engine: Any, state: Any, strain: Array, **kwargs: Any) -> tuple[Any, Array]:
    """One step of jax-md's ``npt_nose_hoover`` (MTTK, Tuckerman et al. 2006), re-written
    so the strain derivative dU/d(eps) of the previous step is reused.

    jax-md evaluates ``value_and_grad`` with respect to the strain at the start of every
    step, at exactly the positions and box where the previous step ended (the chain
    half-steps change momenta only): that second energy-and-gradient evaluation is about a
    third of the cost of a small system.  The arithmetic below is otherwise jax-md 0.2.29's
    ``inner_step`` / ``apply_fn`` line by line, with three exact rewrites for orthorhombic
    boxes and speed (see the module notes): the position shift divides by the box sides,
    the first ``sum p^2 / m`` is twice the thermostat's tracked kinetic energy, and the
    second is computed once and also gives the new kinetic energy.
    """
    c = engine.config
    dt = c.dt_ps
    dt_2 = 0.5 * dt
    kt = engine._kt_integrator
    pressure = c.pressure_kj_mol_nm3
    n, dim = state.position.shape

    def sinhx_x(x: Array) -> Array:
        return 1 + x**2 / 6 + x**4 / 120 + x**6 / 5040 + x**8 / 362_880 + x**10 / 39_916_800

    def box_force(alpha: float, vol: float | Array, dudv: Array, ke2: Array):
        # ke2 = sum p^2 / m = 2 KE, passed in: the thermostat already tracks it.
        return alpha * ke2 - dudv - pressure * vol * dim

    def exp_il1(box: float | Array, r: Array, v: Array, v_b: Array) -> Array:
        x = v_b * dt
        x_2 = x / 2
        # jax-md's shift_fn: dR in real units, transformed by the inverse box and wrapped
        # into the unit cube; for orthorhombic boxes a division by the sides (no 3 x 3
        # product per atom) and x - floor(x) (the same value as mod(x, 1)).
        dr = (r * (jnp.exp(x) - 1) + dt * v * jnp.exp(x_2) * sinhx_x(x_2)) / _box_diagonal(box)
        r = r + dr
        return r - jnp.floor(r)

    def exp_il2(alpha: float, p: Array, f: Array, v_b: Array) -> Array:
        x = alpha * v_b * dt_2
        x_2 = x / 2
        return p * jnp.exp(-x) + dt_2 * f * sinhx_x(x_2) * jnp.exp(-x_2)

    bc = engine._barostat.update_mass(state.barostat, kt)
    tc = engine._thermostat.update_mass(state.thermostat, kt)
    box_mass = jnp.asarray(dim * (n + 1) * kt * state.barostat.tau**2, state.position.dtype)
    s = state.set(box_mass=box_mass)
    p_b, bc = engine._barostat.half_step(s.box_momentum, bc, kt)
    p, tc = engine._thermostat.half_step(s.momentum, tc, kt)

    r, m, f = s.position, s.mass, s.force
    alpha = 1 + 1 / n
    vol, box_fn = jmd_simulate._npt_box_info(s)
    # The thermostat half step scaled p and its tracked kinetic energy together.
    p_b = p_b + dt_2 * box_force(alpha, vol, strain, 2.0 * tc.kinetic_energy)
    p = exp_il2(alpha, p, f, p_b / box_mass)
    r_b = s.box_position + p_b / box_mass * dt
    s = s.set(box_position=r_b)
    vol, box_fn = jmd_simulate._npt_box_info(s)
    box = box_fn(vol)
    r = exp_il1(box, r, p / m, p_b / box_mass)
    f, strain = engine._force_and_strain(r, box, **kwargs)
    p = exp_il2(alpha, p, f, p_b / box_mass)
    ke2 = jnp.sum(p * p / m)  # the one reduction over momenta per step
    p_b = p_b + dt_2 * box_force(alpha, vol, strain, ke2)

    tc = tc.set(kinetic_energy=0.5 * ke2)
    bc = bc.set(kinetic_energy=kinetic_energy(p_b, box_mass))
    p, tc = engine._thermostat.half_step(p, tc, kt)
    p_b, bc = engine._barostat.half_step(p_b, bc, kt)
    s = s.set(
        position=r,
        momentum=p,
        force=f,
        box_position=r_b,
        box_momentum=p_b,
        thermostat=tc,
        barostat=bc,
    )
    return s, strain
