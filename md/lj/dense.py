"""All-pairs kernels for small boxes, laid out for ``jax.vmap`` on CPU.

With a few dozen atoms every atom is within reach of every other, so a neighbour list only adds
gathers and capacity checks; all N x N pairs by broadcasting are cheaper.  The (N, N, 3)
displacement array of the general path puts the 3 Cartesian components on the fastest axis,
where XLA's CPU backend vectorises poorly (reductions over 3 and over the middle axis).  Here each
component is its own (N, N) array ("structure of arrays"), so every operation is elementwise
over (B, N, N) under ``vmap`` and the sum over partners runs along the contiguous last axis.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from md.lj.config import Array, LJParams
from md.lj.neighbor import _box_diagonal

__all__ = ["all_pairs_force_and_strain"]


def all_pairs_force_and_strain(
    pair_energy: Callable[[Array, LJParams], Array],
    cutoff_nm: float,
    position: Array,
    box: Array,
    params: LJParams,
) -> tuple[Array, Array]:
    """Real-space pair forces (N, 3) and dU/d(strain) () over all pairs, analytically.

    Parameters
    ----------
    pair_energy : callable
        ``pair_energy(r2, params)`` of pairs inside the cutoff (``energy_fn.pair_energy``).
    cutoff_nm : float
    position : Array, shape (N, 3)
        Fractional coordinates in the unit cube.
    box : Array, shape (3, 3) or (3,)
        Orthorhombic box, nm.
    params : LJParams

    Returns
    -------
    (Array (N, 3), Array ())
        The same quantities as ``energy_fn.force_and_strain(position, box, idx=None, ...)``,
        equal to rounding (sums over partners may run in a different order).
    """
    n = position.shape[0]
    side = _box_diagonal(box)
    comps = []
    for a in range(3):
        x = position[:, a]
        d = x[None, :] - x[:, None]  # from i (row) to j (column)
        comps.append((d - jnp.round(d)) * side[a])
    r2 = comps[0] * comps[0] + comps[1] * comps[1] + comps[2] * comps[2]
    rc2 = cutoff_nm**2
    inside = ~jnp.eye(n, dtype=bool) & (r2 < rc2)
    # Excluded pairs get a harmless distance so no NaN reaches the derivative.
    r2 = jnp.where(inside, r2, rc2)
    du = jax.grad(lambda x: jnp.sum(pair_energy(x, params)))(r2)
    du = jnp.where(inside, du, 0.0)
    g = 2.0 * du
    force = jnp.stack([jnp.sum(g * c, axis=1) for c in comps], axis=-1)
    strain = jnp.sum(du * r2)  # every pair twice: 1/2 x 2 r^2 u'
    return force, strain
