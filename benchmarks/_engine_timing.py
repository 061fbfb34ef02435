"""The jax-md helium engine's throughput, shared by ``engine_throughput`` and ``gpu_throughput``."""

from __future__ import annotations

import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from md import helium


def time_jax_md(preset: helium.HeliumPreset, batch: int, num_blocks: int, single_core: bool = False) -> dict:
    """Seconds for ``num_blocks * rebuild_every`` NPT steps of ``batch`` systems (compiled).

    ``single_core``: the process runs on one core (its caller pinned it before importing JAX);
    rates are then per CPU second, else per wall second over every core.
    """
    engine = helium.make_engine(preset)
    thetas = jnp.tile(jnp.asarray(helium.TRUE_THETA, jnp.float32), (batch, 1))
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    width = preset.vmap_width  # the preset's batching: one vmap, or a map over vmapped groups
    init = jax.jit(helium.batched(lambda k, t: engine.init(k, helium._params(t)), width))

    @jax.jit
    def segment(carry, thetas):
        return helium.batched(lambda c, t: engine.run(c, helium._params(t), num_blocks, 1)[0], width)(carry, thetas)

    carry = init(keys, thetas)
    t0 = time.perf_counter()
    carry = segment(carry, thetas)
    jax.block_until_ready(carry)
    compile_s = time.perf_counter() - t0
    rebuilds0 = np.asarray(carry.diagnostics.rebuilds)
    t0, c0 = time.perf_counter(), time.process_time()
    carry = segment(carry, thetas)
    jax.block_until_ready(carry)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    seconds = cpu if single_core else wall
    d = carry.diagnostics
    steps = num_blocks * preset.rebuild_every
    cores = 1 if single_core else os.cpu_count() or 1
    return {
        "engine": "jax-md",
        "batch": batch,
        "steps": steps,
        "seconds": seconds,
        "measure": "cpu" if single_core else "wall",
        "wall_seconds": wall,
        "cpu_seconds": cpu,
        "steps_per_rebuild": float(steps / max(np.mean(np.asarray(d.rebuilds) - rebuilds0), 1e-9)),
        "compile_and_first_run_seconds": compile_s,
        "system_steps_per_second": batch * steps / seconds,
        "atom_steps_per_second": batch * steps * preset.num_atoms / seconds,
        "atom_steps_per_second_per_core": batch * steps * preset.num_atoms / seconds / cores,
        "cores": cores,
        "vmap_width": width,
        # The all-pairs kernel (md.lj.native or XLA's); trees before it had only XLA's.
        "force_kernel": getattr(engine, "force_kernel", "xla"),
        "any_overflow_or_failure": bool(np.any(np.asarray(d.overflow | d.failed()))),
    }
