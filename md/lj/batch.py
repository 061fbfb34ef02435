"""Batched, compiled pieces of the engine's host loop (see :meth:`md.lj.LJEngine.run_checked`)."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import jax

from md.lj.config import Array, Carry, LJParams

if TYPE_CHECKING:
    from md.lj.engine import LJEngine

__all__ = ["batched"]


def batched(fn: Callable[..., Any], width: int | None) -> Callable[..., Any]:
    """``fn`` mapped over the leading axis of its arguments.

    ``jax.vmap`` when ``width`` is None, else a sequential ``jax.lax.map`` over groups of
    ``width`` members (vmapped within a group; no vmap at all for 1).  Members are independent,
    so both give the same results up to rounding.
    """
    if width is None:
        return jax.vmap(fn)

    def mapped(*args: Any) -> Any:
        if width == 1:
            return jax.lax.map(lambda a: fn(*a), args)
        return jax.lax.map(lambda a: fn(*a), args, batch_size=width)

    return mapped


# The engine (hashed by identity) and the shapes are static; the template travels as an
# argument, so its spec (static pytree metadata) is part of the cache key and a re-allocation
# retraces instead of reusing a list size captured at trace time.
@functools.partial(jax.jit, static_argnums=(0, 1))
def _init_batch(engine: LJEngine, width: int | None, keys: Array, params: LJParams, template: Any) -> Carry:
    return batched(lambda k, p: engine.init(k, p, neighbors=template), width)(keys, params)


@functools.partial(jax.jit, static_argnums=(0, 1))
def _rebuild_batch(engine: LJEngine, width: int | None, carry: Carry, template: Any) -> Carry:
    return batched(lambda c: engine.rebuild_neighbors(c, template), width)(carry)


@functools.partial(jax.jit, static_argnums=(0, 1, 2, 3, 4))
def _advance_batch(
    engine: LJEngine,
    width: int | None,
    num_samples: int,
    blocks_per_sample: int,
    observe: Callable[[Carry, LJParams], Any] | None,
    carry: Carry,
    params: LJParams,
) -> tuple[Carry, Any]:
    def one(c: Carry, p: LJParams) -> tuple[Carry, Any]:
        return engine.run(c, p, num_samples, blocks_per_sample, observe)

    return batched(one, width)(carry, params)
