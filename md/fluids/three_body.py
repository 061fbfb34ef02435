"""Axilrod-Teller triple-dipole energy in LJ reduced units, over neighbour triples.

::

    E_AT = nu sum_{i<j<k} (1 + 3 cos g_i cos g_j cos g_k) / (r_ij r_ik r_jk)^3

with ``nu = C9 / (epsilon sigma^9)`` and ``g_i`` the triangle's angle at atom i.  A triple counts
when all three sides are shorter than ``cutoff`` (in sigma).  The energy is homogeneous of
degree -9 in the lengths (the angles do not change under a uniform scaling), so its virial is
exactly ``W = -dE/d(ln L) = 9 E`` and its pressure ``3 E / V``; no gradient is needed for the
thermodynamics.  Forces come from ``jax.grad`` when the term is composed into the dynamics.

:func:`c9_reduced` converts C9 from atomic units (hartree bohr^9) to ``nu``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["BOHR_M", "HARTREE_J", "axilrod_teller_energy", "c9_reduced", "nearest_neighbors"]

HARTREE_J = 4.3597447222071e-18
BOHR_M = 5.29177210903e-11
_K_B = 1.380649e-23


def c9_reduced(c9_atomic: float, epsilon_k: float, sigma_m: float) -> float:
    """``nu = C9 / (epsilon sigma^9)`` for C9 in hartree bohr^9, epsilon / k_B in K, sigma in m."""
    if c9_atomic < 0 or epsilon_k <= 0 or sigma_m <= 0:
        raise ValueError("C9 must be >= 0 and epsilon, sigma positive (hartree bohr^9, K, m)")
    return c9_atomic * HARTREE_J * BOHR_M**9 / (epsilon_k * _K_B * sigma_m**9)


def nearest_neighbors(position: jax.Array, side: jax.Array, num_neighbors: int) -> tuple[jax.Array, jax.Array]:
    """Minimum-image vectors to each atom's ``num_neighbors`` nearest atoms.

    Parameters
    ----------
    position : Array, shape (N, 3)
        Positions in a cubic box, reduced units (any origin).
    side : Array, shape ()
        Box side (reduced).
    num_neighbors : int
        M, static; at most N - 1.

    Returns
    -------
    (vectors (N, M, 3), r2 (N, M))
        From atom i to its neighbours, nearest first.
    """
    n = position.shape[0]
    if not 0 < num_neighbors < n:
        raise ValueError(f"num_neighbors must be in 1..{n - 1}, got {num_neighbors}")
    d = position[None, :, :] - position[:, None, :]
    d = d - side * jnp.round(d / side)
    r2 = jnp.sum(d * d, axis=-1) + jnp.where(jnp.eye(n, dtype=bool), jnp.inf, 0.0)
    # Sorting keys are not differentiated: the selection is piecewise constant in positions.
    _, idx = jax.lax.top_k(-jax.lax.stop_gradient(r2), num_neighbors)
    vectors = jnp.take_along_axis(d, idx[:, :, None], axis=1)
    return vectors, jnp.sum(vectors * vectors, axis=-1)


def axilrod_teller_energy(vectors: jax.Array, nu: float | jax.Array, cutoff: float | jax.Array) -> jax.Array:
    """Axilrod-Teller energy of every triple with all sides below ``cutoff``, reduced units.

    Parameters
    ----------
    vectors : Array, shape (N, M, 3)
        Vectors from each atom to neighbours (:func:`nearest_neighbors`); M must hold every
        neighbour within ``cutoff`` or triples are missed (a caller's check: ``r2[:, -1]``).
    nu : Array, shape ()
        ``C9 / (epsilon sigma^9)``; positive for the physical (repulsive on average) term.
    cutoff : float
        Triple cutoff in sigma.

    Returns
    -------
    Array, shape ()
        Each triple is seen from its three vertices, so the sum over (i, j < k) is divided by 3.
    """
    a = vectors[:, :, None, :]  # i -> j
    b = vectors[:, None, :, :]  # i -> k
    c = b - a  # j -> k
    ra2 = jnp.sum(a * a, axis=-1)
    rb2 = jnp.sum(b * b, axis=-1)
    rc2 = jnp.sum(c * c, axis=-1)
    m = vectors.shape[1]
    cut2 = cutoff * cutoff
    upper = jnp.triu(jnp.ones((m, m), dtype=bool), k=1)
    valid = upper[None] & (ra2 < cut2) & (rb2 < cut2) & (rc2 < cut2)
    # Harmless lengths outside the valid set keep NaN out of the gradient.
    ra2, rb2, rc2 = (jnp.where(valid, x, 1.0) for x in (ra2, rb2, rc2))
    ab = jnp.sum(a * b, axis=-1)  # r_ij r_ik cos g_i
    ac = jnp.sum(a * c, axis=-1)  # -r_ij r_jk cos g_j
    bc = jnp.sum(b * c, axis=-1)  # r_ik r_jk cos g_k
    r2_product = ra2 * rb2 * rc2
    cos_product = ab * (-ac) * bc / r2_product
    e = (1.0 + 3.0 * cos_product) / (r2_product * jnp.sqrt(r2_product))
    return nu * jnp.sum(jnp.where(valid, e, 0.0)) / 3.0
