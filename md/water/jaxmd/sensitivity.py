"""Derivatives of trajectory observables with respect to force-field parameters.

S1..S8 are read off histograms, which are piecewise constant in the positions: their derivative
with respect to theta is zero almost everywhere, and the one that matters (how the *expected*
curve moves) is not a pathwise derivative.  What differentiates pathwise are smooth functionals
of the trajectory; :func:`smooth_observables` gives two that carry the same information as the
g_OO statistics and the energy:

- the mean potential energy per molecule (kJ/mol);
- the first-shell O-O coordination number, counting neighbours with a logistic weight
  ``1 / (1 + exp((r - r_shell) / width))`` instead of the step ``r < r_shell``.

:func:`observable_derivatives` returns d(observable)/d(theta) by forward mode (``jax.jvp``, one
pass per parameter) through the whole run: velocities drawn from the same key, the Nose-Hoover
chain and the rigid-body integrator.  Molecular dynamics is chaotic, so the pathwise derivative
of a single trajectory grows with its length (Lyapunov time of water ~0.1-1 ps): it is the
derivative of *this* trajectory, and matches finite differences with common random numbers
only over short runs; for long runs average over many keys or use ensemble estimators.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from md.water.jaxmd.engine import Frames

__all__ = ["observable_derivatives", "smooth_observables"]


def smooth_observables(
    frames: Frames, box_nm: jax.Array, shell_nm: float = 0.336, width_nm: float = 0.005
) -> jax.Array:
    """Mean potential energy per molecule and smooth first-shell coordination number.

    Parameters
    ----------
    frames : Frames
    box_nm : array, shape (3,)
    shell_nm, width_nm : float
        Shell radius (near the first minimum of g_OO) and the logistic edge width (nm).

    Returns
    -------
    jax.Array, shape (2,)
        ``[<U>/N (kJ/mol), <n_OO>]`` averaged over frames.
    """
    oxygen = frames.oxygen_nm
    num_molecules = oxygen.shape[1]
    box = jnp.asarray(box_nm, oxygen.dtype)

    def coordination(positions):
        delta = positions[:, None] - positions[None]
        delta = delta - box * jnp.round(delta / box)
        other = ~jnp.eye(num_molecules, dtype=bool)
        r = jnp.sqrt(jnp.where(other, jnp.sum(delta * delta, axis=-1), 1.0))
        weight = jax.nn.sigmoid((shell_nm - r) / width_nm)
        return jnp.sum(jnp.where(other, weight, 0.0)) / num_molecules

    shell = jnp.mean(jax.vmap(coordination)(oxygen))
    return jnp.stack([jnp.mean(frames.potential_kj_mol) / num_molecules, shell])


def observable_derivatives(simulator, key: jax.Array, theta: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Observables and their Jacobian with respect to theta, by forward mode.

    Parameters
    ----------
    simulator : md.water.jaxmd.simulator.JaxWaterSimulator
    key : PRNG key
    theta : array, shape (d,)

    Returns
    -------
    values : jax.Array, shape (2,)
        :func:`smooth_observables` of the run.
    jacobian : jax.Array, shape (2, d)
        ``d values / d theta`` along this trajectory (see the module notes on chaos).
    """
    theta = jnp.asarray(theta, simulator.dtype)

    def observe(theta):
        frames, _ = simulator.frames(key, theta)
        return smooth_observables(frames, simulator.engine.box_nm)

    return observe(theta), jax.jacfwd(observe)(theta)
