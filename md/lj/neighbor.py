"""Neighbour lists for the LJ engine: a cell list hashed by atom, no dense cell grid.

Positions are fractional (unit cube) in an orthorhombic box.  A list is built with the skin
folded into its reach (``reach_nm`` = cutoff + skin) and rebuilt from scratch by the engine at
block starts; a conditional update would become a select under ``jax.vmap`` and rebuild every
member every step.  Atoms are hashed to cells, a (cells, cell_capacity) table is filled by
rounds of scatter-min, and each atom's stencil cells are expanded into candidate slots by
running sums, so the cost follows atoms and real candidates rather than cells (argsort,
searchsorted and long cumulative sums are slow under ``vmap`` on CPU).  Boxes narrower than
three reaches per side get no grid: every atom is a candidate.

Three capacities are static (pair slots, candidate slots, atoms per cell) and checked at every
build: exceeding one sets ``did_buffer_overflow`` instead of raising (errors are data inside
jit).  :func:`allocate_neighbor_list` sizes them on the host; re-allocation after an overflow
is the engine's job (:meth:`md.lj.LJEngine.allocate_neighbors`).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax_md import space

from md.lj.config import NEIGHBOR_FORMATS, Array

__all__ = [
    "HalfPairs",
    "NeighborList",
    "NeighborSpec",
    "allocate_neighbor_list",
    "build_neighbor_list",
]


class HalfPairs(NamedTuple):
    """A sparse half neighbour list: each pair (i < j) once, ``num_atoms`` marks an empty slot.

    Attributes
    ----------
    i, j : Array, shape (P,), int32
    """

    i: Array
    j: Array


def _box_diagonal(box: float | Array) -> Array:
    """Side lengths (3,) of an orthorhombic box given as (3, 3), (3,) or a scalar."""
    box = jnp.asarray(box)
    if box.ndim == 2:
        return jnp.diagonal(box)
    return jnp.broadcast_to(box, (3,))


def _neighbor_vectors(
    position: Array, idx: Any, box: Array, perturbation: Array | None, autodiff: bool = True
) -> tuple[Array, Array]:
    """Real-space minimum-image vectors from each atom to its listed partners.

    ``idx`` is None (all pairs), a dense (N, M) array of partners (N marks an empty slot) or a
    :class:`HalfPairs`.  Returns ``(vectors, valid)``: shapes (N, N or M, 3) and (N, N or M),
    or (P, 3) and (P,) for half lists (vector from ``i`` to ``j``).  ``space.transform`` has a
    custom JVP so that gradients with respect to fractional positions come out as real-space
    forces, as jax-md's own ``periodic_general`` does; ``autodiff=False`` (analytic forces)
    multiplies by the sides directly, which XLA's CPU backend runs several times faster than
    the einsum inside ``space.transform`` under ``vmap``.
    """
    n = position.shape[0]
    if idx is None:
        # All pairs by broadcasting (N, N): no gather, which is slow on CPU.
        valid = ~jnp.eye(n, dtype=bool)
        d = position[None, :, :] - position[:, None, :]
    elif isinstance(idx, HalfPairs):
        valid = idx.i < n
        d = position[jnp.where(valid, idx.j, 0)] - position[jnp.where(valid, idx.i, 0)]
    else:
        valid = idx < n
        partner = position[jnp.where(valid, idx, 0)]
        d = partner - position[:, None, :]
    d = d - jnp.round(d)
    # Orthorhombic boxes only (all boxes here are cubic, NPT scales isotropically): scaling by
    # the diagonal is 3 multiplications per pair instead of a 3x3 matrix product.
    if autodiff:
        vectors = space.transform(_box_diagonal(box), d)
    else:
        vectors = d * _box_diagonal(box)
    if perturbation is not None:
        vectors = vectors * perturbation
    return vectors, valid


_HALF = [(0, 0, 0)] + [
    (dx, dy, dz) for dz in (-1, 0, 1) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dz, dy, dx) > (0, 0, 0)
]
_STENCIL = np.array(_HALF + [(-dx, -dy, -dz) for dx, dy, dz in _HALF[1:]], np.int32)
#: ``rebuild="when_needed"`` projects the displacement over the coming block with this multiple
#: of the fastest atom's current speed.  In an elastic collision of equal masses no atom leaves
#: faster than sqrt(v1^2 + v2^2) <= sqrt(2) v_max (helium's well, 0.03 k_B T, adds little), so
#: 1.5 covers a gas; in a liquid the force changes a velocity by F dt / m per step, small over a
#: block of a few steps.  The skin check at the end of every block stays as the safety net.
_SPEED_MARGIN = 1.5


@dataclasses.dataclass(frozen=True)
class NeighborSpec:
    """Static shape of a neighbour list (a new one recompiles).

    Attributes
    ----------
    format : str
        ``"sparse"``: :class:`HalfPairs`, each pair once (P slots); ``"dense"``: (N, M) partners,
        each pair twice.
    num_atoms : int
    reach_nm : float
        Cutoff plus skin, nm.
    cells_per_side : int
        Cell grid of the fractional unit cube (cells at least ``reach_nm`` wide); 0: no grid,
        every atom is a candidate partner of every other (small boxes).
    candidate_capacity : int
        Slots for (atom, candidate partner in a stencil cell) pairs.
    capacity : int
        P (sparse) or M (dense).
    cell_capacity : int
        Atoms per cell (more sets the overflow flag).
    """

    format: str
    num_atoms: int
    reach_nm: float
    cells_per_side: int
    candidate_capacity: int
    capacity: int
    cell_capacity: int = 1


@functools.partial(
    jax.tree_util.register_dataclass,
    data_fields=["idx", "did_buffer_overflow", "cell_size_too_small", "required"],
    meta_fields=["spec"],
)
@dataclasses.dataclass(frozen=True)
class NeighborList:
    """A neighbour list built by :func:`build_neighbor_list` (a pytree; ``spec`` is static).

    Attributes
    ----------
    idx : HalfPairs or Array (N, M)
    did_buffer_overflow : Array, bool
        Candidate or pair slots ran out: pairs were dropped, re-allocate.
    cell_size_too_small : Array, bool
        The box shrank so that a cell is narrower than the reach: re-allocate.
    required : Array, shape (3,), int32
        Candidates, pairs (sparse) or largest row (dense), and largest cell occupancy this
        build needed.
    spec : NeighborSpec
    """

    idx: Any
    did_buffer_overflow: Array
    cell_size_too_small: Array
    required: Array
    spec: NeighborSpec

    @property
    def max_occupancy(self) -> int:
        """Pair slots P (sparse) or partners per atom M (dense)."""
        return self.spec.capacity

    def update(self, position: Array, box: Array) -> NeighborList:
        """Rebuild from scratch at ``position`` (fractional) in ``box`` with the same spec."""
        return build_neighbor_list(self.spec, position, box)


def _cell_id(cell3: Array, nc: int) -> Array:
    return (cell3[..., 2] * nc + cell3[..., 1]) * nc + cell3[..., 0]


def _candidates(spec: NeighborSpec, position: Array, side: Array) -> tuple:
    """Candidate pairs (i, j, ok) in ``candidate_capacity`` slots, plus the number needed, the
    largest cell occupancy and the cell-too-small flag.

    No sort and no (cells x 27 x capacity) scan: atoms are hashed to cells, a (cells,
    cell_capacity) table is filled by ``cell_capacity`` rounds of scatter-min (the lowest
    unplaced index per cell: deterministic), and each atom's stencil cells are expanded into
    candidate slots from per-atom offsets (running sums over a 14- or 27-long axis and one
    over atoms, then a running max over the candidate slots), so the cost scales with atoms
    and real candidates, not with cells.
    """
    n = spec.num_atoms
    nc = spec.cells_per_side
    cap = spec.candidate_capacity
    if nc < 3:
        t = jnp.arange(n * n, dtype=jnp.int32)
        ok = (t // n) != (t % n)
        if spec.format == "sparse":
            ok = ok & ((t % n) > (t // n))
        return (t // n, t % n, ok, jnp.int32(n * n), jnp.int32(0), jnp.asarray(False))
    ccap = spec.cell_capacity
    atoms = jnp.arange(n, dtype=jnp.int32)
    cell3 = jnp.clip(jnp.floor(position * nc).astype(jnp.int32), 0, nc - 1)
    cid = _cell_id(cell3, nc)
    counts = jnp.zeros(nc**3, jnp.int32).at[cid].add(1)
    occupancy = jnp.max(counts)
    placed = jnp.zeros(n, bool)
    rows = []
    for _ in range(ccap):
        first = jnp.full(nc**3, n, jnp.int32).at[cid].min(jnp.where(placed, n, atoms))
        rows.append(first)
        placed = placed | (first[cid] == atoms)
    table = jnp.stack(rows, axis=1)  # (cells, ccap), n marks empty
    stencil = _STENCIL[:14] if spec.format == "sparse" else _STENCIL
    s = stencil.shape[0]
    nb = _cell_id((cell3[:, None, :] + stencil) % nc, nc)  # (N, s)
    count = jnp.minimum(counts[nb], ccap)
    # Offsets of each (atom, cell) entry: running sum along the short stencil axis, plus a
    # running sum over atoms.
    within = [jnp.zeros(n, jnp.int32)]
    for k in range(s - 1):
        within.append(within[-1] + count[:, k])
    per_atom = within[-1] + count[:, s - 1]
    base = jnp.cumsum(per_atom) - per_atom
    start = base[:, None] + jnp.stack(within, axis=1)  # (N, s)
    total = base[-1] + per_atom[-1]
    # Mark each non-empty entry at its first slot and fill forward (a running max): slot t
    # belongs to the last entry starting at or before it.
    start = start.reshape(-1)
    entry = jnp.arange(n * s, dtype=jnp.int32)
    target = jnp.where(count.reshape(-1) > 0, start, cap)  # empty entries: dropped
    first = jnp.full(cap, -1, jnp.int32).at[target].max(entry, mode="drop")
    e = jnp.maximum(jax.lax.cummax(first), 0)
    t = jnp.arange(cap, dtype=jnp.int32)
    k = t - start[e]
    ok = t < total
    i = e // s
    own = (e % s) == 0
    j = table[nb.reshape(-1)[e], k]
    ok = ok & jnp.where(own, j > i if spec.format == "sparse" else j != i, True)
    too_small = jnp.any(side / nc < spec.reach_nm)
    return i, j, ok, total, occupancy, too_small


def build_neighbor_list(spec: NeighborSpec, position: Array, box: Array) -> NeighborList:
    """Build a neighbour list of fractional ``position`` (N, 3) in an orthorhombic ``box``.

    Every pair closer than ``spec.reach_nm`` (minimum image) is listed unless a capacity is
    exceeded, which sets ``did_buffer_overflow`` (and ``required`` says how much was needed).
    Pure JAX with static shapes: jit- and vmap-able.
    """
    n = spec.num_atoms
    side = _box_diagonal(box)
    i, j, ok, total, occupancy, too_small = _candidates(spec, position, side)
    d = position[j] - position[i]
    d = (d - jnp.round(d)) * side
    keep = ok & (jnp.sum(d * d, axis=-1) < spec.reach_nm**2)
    kept = jnp.cumsum(keep.astype(jnp.int32))
    overflow = (total > i.shape[0]) | (occupancy > spec.cell_capacity)
    if spec.format == "sparse":
        slot = jnp.where(keep, kept - 1, spec.capacity)
        pi = jnp.full(spec.capacity, n, jnp.int32).at[slot].set(i, mode="drop")
        pj = jnp.full(spec.capacity, n, jnp.int32).at[slot].set(j, mode="drop")
        idx = HalfPairs(pi, pj)
        needed = kept[-1]
    else:
        row = jnp.zeros(n, jnp.int32).at[i].add(keep.astype(jnp.int32))
        before = jnp.cumsum(row) - row
        col = jnp.where(keep, kept - 1 - before[i], spec.capacity)
        idx = jnp.full((n, spec.capacity), n, jnp.int32).at[i, col].set(j, mode="drop")
        needed = jnp.max(row)
    overflow = overflow | (needed > spec.capacity)
    return NeighborList(
        idx=idx,
        did_buffer_overflow=overflow,
        cell_size_too_small=too_small,
        required=jnp.stack([total, needed, occupancy]).astype(jnp.int32),
        spec=spec,
    )


def allocate_neighbor_list(
    format: str,
    position: Array,
    box: Array,
    reach_nm: float,
    cells_box_nm: float,
    capacity_multiplier: float = 1.5,
    extra_capacity: int = 4,
    previous: NeighborSpec | None = None,
) -> NeighborList:
    """Size a list on one configuration (host side) and build it.

    Capacities are ``capacity_multiplier`` x what ``position`` needs plus ``extra_capacity``
    (candidates and sparse pairs: ``extra_capacity`` per 64 atoms), plus the capacities of
    ``previous`` (re-allocation after an overflow grows the list at least twofold).  The cell
    grid is sized for a box of side ``cells_box_nm`` (the smallest box expected).
    """
    if format not in NEIGHBOR_FORMATS:
        raise ValueError(f"neighbor format must be one of {NEIGHBOR_FORMATS}, got {format!r}")
    position = jnp.asarray(position, jnp.float32)
    n = position.shape[0]
    nc = int(np.floor(cells_box_nm / reach_nm))
    nc = nc if nc >= 3 else 0
    max_candidates = n * n
    pairs_cap = n * (n - 1) // 2 if format == "sparse" else n - 1
    probe = NeighborSpec(format, n, float(reach_nm), nc, max_candidates, max(pairs_cap, 1), n)
    if nc:
        # Cell occupancy and the number of candidates are known from the cell counts alone.
        _, _, occupancy = (
            int(v)
            for v in build_neighbor_list(
                dataclasses.replace(probe, candidate_capacity=1, capacity=1, cell_capacity=1), position, box
            ).required
        )
        probe = dataclasses.replace(probe, cell_capacity=max(occupancy, 1))
        total = int(
            build_neighbor_list(dataclasses.replace(probe, candidate_capacity=1, capacity=1), position, box).required[0]
        )
        probe = dataclasses.replace(probe, candidate_capacity=max(total, 1))
    total, needed, occupancy = (int(v) for v in build_neighbor_list(probe, position, box).required)
    extra_sparse = extra_capacity * max(1, n // 64)
    cand = int(np.ceil(capacity_multiplier * total)) + extra_sparse
    if format == "sparse":
        cap = int(np.ceil(capacity_multiplier * needed)) + extra_sparse
    else:
        cap = int(np.ceil(capacity_multiplier * needed)) + extra_capacity
    cell_cap = int(np.ceil(capacity_multiplier * occupancy)) + 1
    if previous is not None:
        cand += previous.candidate_capacity
        cap += previous.capacity
        cell_cap += previous.cell_capacity
    spec = dataclasses.replace(
        probe,
        candidate_capacity=max_candidates if nc == 0 else min(cand, max_candidates),
        capacity=min(cap, max(pairs_cap, 1)),
        cell_capacity=min(cell_cap, n),
    )
    return build_neighbor_list(spec, position, box)
