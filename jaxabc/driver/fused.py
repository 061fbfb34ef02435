"""A whole calibration of a JAX simulator as compiled programs.

:func:`run_fused` runs the same iterations as the host driver :func:`jaxabc.run` -- the same
keys (``fold_in(key(seed), iteration)`` split into proposal, simulation and update keys), the
same ``propose`` / ``update`` functions, the same stopping rules -- but a chunk of iterations
is one compiled program: a ``lax.scan`` over ``chunk_size`` steps in which the vmapped
simulator, the distances and the algorithm's update never leave the device.  The host sees the
run only between chunks, for the progress bar, the wall-time limit, the failure check and the
record of simulations.

Compiled chunks are cached in the process, keyed on the algorithm's configuration, the
simulator and distance functions, the prior, the shapes and the precision; the observed data
and the stopping limits are traced arguments, so a second run with new data or a new budget
reuses the compiled program.  Across processes, :func:`run_fused` turns on JAX's persistent
compilation cache in ``~/.cache/jaxabc/xla`` (see :func:`enable_compilation_cache`), so only the
first run of a configuration on a machine pays XLA's compile time; set
``JAXABC_COMPILATION_CACHE`` to another folder, or to ``off`` to keep it off.
"""

from __future__ import annotations

import functools
import os
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc import checkpoint as _ckpt
from jaxabc.algorithms.base import ABCAlgorithm
from jaxabc.distances import get_distance
from jaxabc.driver.checks import (
    cast_prior,
    check_first_distances,
    check_first_iteration_budget,
    check_stopping_rule,
    check_traced_shape,
    precision,
    validate_observed,
    validate_seed,
)
from jaxabc.driver.context import build_by_name, builder_accepts, posterior_distances
from jaxabc.driver.fused_records import (
    _NONE,
    _STOP_ALGORITHM,
    _STOP_BUDGET,
    _STOP_STEPS,
    _STOP_THRESHOLD,
    _absorb,
    _record_arrays,
    _stop_reason,
    from_checkpoint,
    to_checkpoint,
)
from jaxabc.errors import NoPosterior, TooManyFailures
from jaxabc.priors import Uniform
from jaxabc.results import ABCResult, versions

__all__ = ["DRIVER", "default_compilation_cache", "enable_compilation_cache", "run_fused"]

#: The ``driver`` field of a fused run's checkpoint fingerprint (the host driver's has none).
DRIVER = "fused"

#: Environment variable naming a folder for JAX's persistent compilation cache; ``off``
#: (or ``0``, ``false``, ``no``) keeps :func:`run_fused` from turning the cache on.
CACHE_ENV = "JAXABC_COMPILATION_CACHE"
_CACHE_OFF = ("off", "0", "false", "no")

_INT_MAX = np.iinfo(np.int32).max
_DEFAULT_CHUNK = 16
_MIN_FOR_FAILURE_CHECK = 20
_COMPILED: dict[Any, tuple[Callable, Callable, Any]] = {}
_MAX_COMPILED = 32
# LLVM's optimisation passes are most of XLA:CPU's compile time; the ABC loop's cost is
# dominated by sorts, gathers and the simulator's own arithmetic, which lose little without them.
_FAST_COMPILE = {"xla_backend_optimization_level": 0, "xla_llvm_disable_expensive_passes": True}


def enable_compilation_cache(path: str | os.PathLike | None = None, min_compile_time_s: float = 0.0) -> Path | None:
    """Turn on JAX's persistent compilation cache, so a new process reuses compiled kernels.

    Parameters
    ----------
    path : path, optional
        Cache folder (created if missing).  Default: ``$JAXABC_COMPILATION_CACHE``, else
        ``~/.cache/jaxabc/xla``.
    min_compile_time_s : float
        Programs that compiled faster than this are not stored (JAX's own default is 1 s).

    Returns
    -------
    pathlib.Path or None
        The folder in use; ``None`` (cache left off) when no ``path`` is given and
        ``JAXABC_COMPILATION_CACHE`` is ``off``.  Entries are keyed by JAX on the program, the JAX version and the
        device, so a stale entry is never used; delete the folder to reclaim space.
    """
    env = os.environ.get(CACHE_ENV, "")
    if path is None and env.lower() in _CACHE_OFF:
        return None
    folder = Path(path or env or Path.home() / ".cache" / "jaxabc" / "xla")
    folder.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(folder))
    # ABC kernels compile in well under JAX's default one-second floor, and those are the
    # ones a cold run pays for many times over: by default cache everything.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_time_s))
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    # JAX decides once per process, at its first compilation, whether the cache is in use;
    # a program compiled before this call (the user's own data set-up) would lock it off.
    from jax.experimental.compilation_cache import compilation_cache

    compilation_cache.reset_cache()
    return folder


def default_compilation_cache() -> None:
    """Turn the persistent cache on (for :func:`run_fused` and the examples' jobs) unless the
    user chose otherwise.

    Left alone when ``JAXABC_COMPILATION_CACHE`` says ``off`` or when JAX already has a cache
    folder (the user's own, or one set earlier); a folder that cannot be created leaves the
    cache off rather than failing the run.
    """
    if os.environ.get(CACHE_ENV, "x").lower() in _CACHE_OFF or getattr(jax.config, "jax_compilation_cache_dir", None):
        return
    try:
        # The floor keeps the rest of the user's process (small jitted helpers) out of the
        # cache and lets the fused programs, which take seconds to compile, in.
        enable_compilation_cache(min_compile_time_s=0.25)
    except OSError:
        pass


class _Carry(NamedTuple):
    state: Any
    iteration: jax.Array  # ()
    num_sims: jax.Array  # ()
    generations: jax.Array  # () completed generations
    generation_sims: jax.Array  # () simulations since the last completed generation
    stop_code: jax.Array  # ()
    post_particles: jax.Array  # (n, d) last completed generation
    post_log_weights: jax.Array  # (n,)
    post_distances: jax.Array  # (n,)
    level: jax.Array  # () ABCsubsim's level at the last completed generation


class _Limits(NamedTuple):
    num_steps: jax.Array  # () int
    final_threshold: jax.Array  # () float, -inf for none
    max_simulations: jax.Array  # () int


def _compile(
    algo: ABCAlgorithm, simulate: Callable, distance: Callable, chunk_size: int, keep_summaries: bool
) -> tuple[Callable, Callable]:
    """Jitted ``start(root, observed, limits)`` and ``chunk(root, observed, limits, carry)``."""

    def simulate_distances(key, thetas, active, observed):
        # The host driver's keys: one per proposal slot, split from the simulation key.
        keys = jax.random.split(key, thetas.shape[0])
        summaries = jax.vmap(simulate)(keys, thetas)
        finite = jnp.all(jnp.isfinite(summaries.reshape(summaries.shape[0], -1)), axis=1)
        raw = jax.vmap(distance, in_axes=(None, 0))(observed, summaries)
        # As the host driver: a NaN or -inf distance of finite summaries is a failure of its own.
        bad = finite & active & (jnp.isnan(raw) | (raw == -jnp.inf))
        dist = jnp.where(finite & ~bad & active, raw, jnp.inf)
        return summaries, finite, bad, dist.astype(thetas.dtype)

    def after_update(carry, state, info, n_active, limits):
        gen_sims = carry.generation_sims + n_active
        done = info.generation_done
        particles, log_w = algo.posterior(state)
        generations = carry.generations + done.astype(jnp.int32)
        code = jnp.where(
            info.stop,
            _STOP_ALGORITHM,
            jnp.where(
                generations >= limits.num_steps,
                _STOP_STEPS,
                jnp.where(info.threshold <= limits.final_threshold, _STOP_THRESHOLD, _NONE),
            ),
        )
        level = jnp.asarray(getattr(state, "level", 0), jnp.int32)
        new = _Carry(
            state=state,
            iteration=carry.iteration + 1,
            num_sims=carry.num_sims + n_active,
            generations=generations,
            generation_sims=jnp.where(done, 0, gen_sims),
            stop_code=jnp.where(done, code, _NONE).astype(jnp.int32),
            post_particles=jnp.where(done, particles, carry.post_particles),
            post_log_weights=jnp.where(done, log_w, carry.post_log_weights),
            post_distances=jnp.where(done, state.distances, carry.post_distances),
            level=jnp.where(done, level, carry.level),
        )
        record = {
            "done": done,
            "threshold": info.threshold,
            "acceptance": info.acceptance_rate,
            "ess": info.ess,
            "generation_sims": gen_sims,
        }
        return new, record

    def start(root, observed, limits):
        key = jax.random.fold_in(root, 0)
        k_prop, k_sim, k_upd = jax.random.split(key, 3)
        proposal = algo.initial_proposal(k_prop)
        summaries, finite, bad, dist = simulate_distances(k_sim, proposal.thetas, proposal.active, observed)
        state, info = algo.init(k_upd, proposal, dist)
        particles, log_w = algo.posterior(state)
        zero = jnp.int32(0)
        empty = _Carry(
            state,
            zero,
            zero,
            zero,
            zero,
            zero,
            jnp.zeros_like(particles),
            jnp.full_like(log_w, -jnp.inf),
            jnp.full_like(state.distances, jnp.inf),
            zero,
        )
        n_active = jnp.sum(proposal.active).astype(jnp.int32)
        carry, record = after_update(empty, state, info, n_active, limits)
        record.update(
            thetas=proposal.thetas,
            active=proposal.active,
            distances=dist,
            finite=finite,
            bad=bad,
            ok=proposal.ok,
            ran=jnp.bool_(True),
        )
        if keep_summaries:
            record["summaries"] = summaries
        return carry, record

    def one_iteration(root, observed, limits, carry):
        key = jax.random.fold_in(root, carry.iteration)
        k_prop, k_sim, k_upd = jax.random.split(key, 3)
        proposal = algo.propose(k_prop, carry.state)
        n_active = jnp.sum(proposal.active).astype(jnp.int32)
        over_budget = carry.num_sims + n_active > limits.max_simulations

        def run(_):
            summaries, finite, bad, dist = simulate_distances(k_sim, proposal.thetas, proposal.active, observed)
            state, info = algo.update(k_upd, carry.state, proposal, dist)
            new, record = after_update(carry, state, info, n_active, limits)
            record.update(distances=dist, finite=finite, bad=bad, ran=jnp.bool_(True))
            if keep_summaries:
                record["summaries"] = summaries
            return new, record

        def stop(_):
            # The host driver's rule: stop before an iteration that would exceed the budget.
            _, record = jax.eval_shape(run, None)
            record = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), record)
            return carry._replace(stop_code=jnp.int32(_STOP_BUDGET)), record

        new, record = jax.lax.cond(over_budget, stop, run, None)
        record.update(thetas=proposal.thetas, active=proposal.active & ~over_budget, ok=proposal.ok | over_budget)
        return new, record

    def chunk(root, observed, limits, carry):
        def body(c, _):
            def skip(c):
                _, record = jax.eval_shape(lambda c: one_iteration(root, observed, limits, c), c)
                record = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), record)
                return c, record

            return jax.lax.cond(c.stop_code != _NONE, skip, lambda c: one_iteration(root, observed, limits, c), c)

        return jax.lax.scan(body, carry, None, length=chunk_size)

    return jax.jit(start), jax.jit(chunk)


def _compile_both(
    start: Callable, chunk: Callable, root: jax.Array, observed: jax.Array, limits: _Limits, fast_compile: bool
) -> tuple[Callable, Callable, Any]:
    """Compile the two programs side by side: XLA releases the GIL while it compiles, and a
    cold run spends most of its time here.  Also returns the carry's shapes (a checkpoint's
    template)."""
    carry = jax.eval_shape(start, root, observed, limits)[0]
    lowered = [start.lower(root, observed, limits), chunk.lower(root, observed, limits, carry)]
    options = _FAST_COMPILE if fast_compile else None
    with ThreadPoolExecutor(max_workers=2) as pool:
        compiled = list(pool.map(lambda program: program.compile(options), lowered))
    return compiled[0], compiled[1], carry


def _cache_key(
    algo: ABCAlgorithm,
    options: dict,
    prior: Uniform,
    simulate: Callable,
    distance: Callable,
    obs_shape: tuple,
    dtype: Any,
    chunk_size: int,
    keep_summaries: bool,
    fast_compile: bool,
) -> Any:
    return (
        algo.name,
        repr(sorted(algo.settings.items())),
        repr(sorted(options.items())),
        simulate,
        distance,
        obs_shape,
        np.dtype(dtype).str,
        chunk_size,
        keep_summaries,
        fast_compile,
        np.asarray(prior.low).tobytes(),
        np.asarray(prior.high).tobytes(),
    )


def _fused_run(
    algorithm: str | ABCAlgorithm,
    simulate: Callable,
    prior: Uniform,
    observed: Any,
    num_particles: int,
    num_steps: int | None = None,
    distance: str | Callable = "mean_abs",
    seed: int = 0,
    *,
    final_threshold: float | None = None,
    max_simulations: int | None = None,
    max_wall_time: float | None = None,
    max_failure_fraction: float = 0.5,
    chunk_size: int | None = None,
    fast_compile: bool = False,
    checkpoint_dir: str | Path | None = None,
    resume: bool = False,
    overwrite: bool = False,
    simulator_id: str | None = None,
    stop_after_iterations: int | None = None,
    keep_summaries: bool = True,
    progress: bool = False,
    dtype: str = "float32",
    metadata: dict | None = None,
    **algorithm_options: Any,
) -> ABCResult:
    """Calibrate a JAX simulator with the whole loop compiled; the arguments of :func:`jaxabc.run`.

    Parameters
    ----------
    algorithm, simulate, prior, observed, num_particles, num_steps, distance, seed
        As in :func:`jaxabc.run`; ``simulate(key, theta) -> summaries`` must be traceable by
        JAX (it runs under ``vmap`` inside ``lax.scan``).
    final_threshold, max_simulations, max_wall_time, max_failure_fraction, keep_summaries
        As in :func:`jaxabc.run`.  The wall-time limit and the failure check are applied
        between chunks, so a run may go up to ``chunk_size - 1`` iterations past them.
    chunk_size : int, optional
        Iterations per compiled program between two visits to the host.  Default: 1 with a
        ``checkpoint_dir`` (a checkpoint after every iteration, as the host driver writes), else 16.
    checkpoint_dir, resume, overwrite, simulator_id
        As in :func:`jaxabc.run`: a checkpoint after every chunk, and a resumed run gives the
        uninterrupted run's result.  A checkpoint of the host driver is refused (the
        fingerprint's ``driver`` field differs); :func:`jaxabc.run` resumes it on the host.
    stop_after_iterations : int, optional
        Stop, resumably, at the first chunk boundary at or after this many iterations.
    fast_compile : bool
        Compile with LLVM's optimisation passes off: a cold run compiles faster; the compiled
        loop may run slower, which matters for expensive simulators (CPU backend only).
    progress, dtype, metadata, **algorithm_options
        As in :func:`jaxabc.run`.

    Returns
    -------
    ABCResult
        The fields of :func:`jaxabc.run`'s result (a run stopped before its first generation
        completed returns the particles accepted so far, flagged ``incomplete``).  For the
        same seed the iterations use the same keys as the host driver with the ``"vmap"``
        executor; the posterior agrees with it up to floating-point rounding (XLA may fuse the
        simulator and the distance differently inside one program, which can move a distance
        across a threshold by one ulp).  Records have no per-simulation wall or CPU time (NaN)
        and worker 0.

    Raises
    ------
    TypeError
        ``simulate`` cannot be traced by JAX: use :func:`jaxabc.run` with a process executor.
    ValueError
        Bad arguments, as in :func:`jaxabc.run`.
    TooManyFailures
        More than ``max_failure_fraction`` of the simulations returned non-finite summaries, or
        all of them.
    NoPosterior
        The run stopped before accepting any particle.
    RuntimeError
        The truncated kernel could not reach the prior's support.
    jaxabc.checkpoint.CheckpointError, FileExistsError
        As in :func:`jaxabc.run`.
    """
    t_start = time.perf_counter()
    if dtype not in ("float32", "float64"):
        raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype!r}")
    jdtype = jnp.float64 if dtype == "float64" else jnp.float32
    if not isinstance(num_particles, int | np.integer) or num_particles < 1:
        raise ValueError(f"num_particles must be a positive integer, got {num_particles!r}")
    if num_steps is not None and num_steps < 1:
        raise ValueError(f"num_steps must be at least 1, got {num_steps}")
    if chunk_size is None:
        chunk_size = 1 if checkpoint_dir is not None else _DEFAULT_CHUNK
    if not isinstance(chunk_size, int | np.integer) or chunk_size < 1:
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    if not 0.0 < max_failure_fraction <= 1.0:
        raise ValueError(f"max_failure_fraction must lie in (0, 1], got {max_failure_fraction}")
    if not callable(simulate):
        raise TypeError("simulate must be a callable simulate(key, theta) -> summaries")
    seed = validate_seed(seed)
    default_compilation_cache()
    obs = validate_observed(observed, dtype, distance)
    prior = cast_prior(prior, jdtype)
    if isinstance(algorithm, ABCAlgorithm):
        algo = algorithm
    else:
        if final_threshold is not None and builder_accepts(algorithm, "final_threshold"):
            algorithm_options.setdefault("final_threshold", final_threshold)
        algo = build_by_name(algorithm, prior, int(num_particles), algorithm_options)
    if algo.host or algo.uses_summaries:
        raise ValueError(f"{algo.name} is host code: run it with jaxabc.run, not run_fused")
    name = algo.name
    check_stopping_rule(algo, num_steps, final_threshold, max_simulations, max_wall_time)
    check_traced_shape(simulate, prior, obs, distance, jdtype, "The fused path")
    dist_fn = get_distance(distance)
    first = jax.eval_shape(algo.initial_proposal, jax.random.key(0)).thetas.shape[0]
    check_first_iteration_budget(first, max_simulations, name)  # every initial slot is active
    if checkpoint_dir is not None:
        _ckpt.require_fingerprintable(simulate, simulator_id, distance)
    # Only now, with every input checked, may overwrite=True delete an old checkpoint (the
    # caller, _run_fused_body, holds the folder's lock).
    ckpt_path = _ckpt.prepare_folder(checkpoint_dir, resume, overwrite)
    fp = {
        **_ckpt.fingerprint(
            algorithm=name,
            settings=algo.settings,
            prior=prior,
            observed=obs,
            distance=distance,
            simulator_id=_ckpt.simulator_identity(simulate, simulator_id),
            seed=seed,
            num_particles=int(num_particles),
            dtype=dtype,
        ),
        "driver": DRIVER,
    }
    root = jax.random.key(seed)
    obs_j = jnp.asarray(obs, jdtype)
    limits = _Limits(
        num_steps=jnp.int32(_INT_MAX if num_steps is None else num_steps),
        final_threshold=jnp.asarray(-jnp.inf if final_threshold is None else final_threshold, jdtype),
        max_simulations=jnp.int32(_INT_MAX if max_simulations is None else min(max_simulations, _INT_MAX)),
    )
    key = _cache_key(
        algo,
        algorithm_options,
        prior,
        simulate,
        dist_fn,
        obs.shape,
        jdtype,
        int(chunk_size),
        keep_summaries,
        fast_compile,
    )
    if key not in _COMPILED:
        if len(_COMPILED) >= _MAX_COMPILED:
            _COMPILED.pop(next(iter(_COMPILED)))
        start, chunk = _compile(algo, simulate, dist_fn, int(chunk_size), keep_summaries)
        _COMPILED[key] = _compile_both(
            start, chunk, root, obs_j, limits, fast_compile and jax.default_backend() == "cpu"
        )
    start, chunk, template = _COMPILED[key]

    records: list[dict[str, np.ndarray]] = []
    history: dict[str, list] = {"threshold": [], "sims": [], "acceptance": [], "ess": [], "wall": []}
    stop_reason = ""
    first_iteration = 0
    if resume:
        assert ckpt_path is not None, "prepare_folder refuses resume without a folder"
        ck = _ckpt.load(ckpt_path)
        _ckpt.check_fingerprint(ck.fingerprint, fp, ckpt_path)
        carry = _ckpt.restore_state(ck.state_leaves, template, ckpt_path)
        records, history = from_checkpoint(ck.records), ck.history
        first_iteration = int(ck.counters["iteration"])
        stop_reason = _ckpt.reopen(
            ck.counters["stop_reason"],
            history,
            num_steps=num_steps,
            final_threshold=final_threshold,
            max_simulations=max_simulations,
            max_wall_time=max_wall_time,
            path=ckpt_path,
        )
        if not stop_reason:  # an ended run that goes on under this run's rules
            carry = carry._replace(stop_code=jnp.asarray(_NONE, jnp.int32))
        pending = []
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=num_steps, desc=name, unit="step", initial=len(history["threshold"]))
    try:
        if not resume:
            carry, first = start(root, obs_j, limits)
            # The distances are computed inside the program; the host checks the first
            # population's (prior draws) as the host driver does, before any further chunk.
            check_first_distances(np.asarray(first["distances"]))
            pending = [jax.tree.map(lambda x: np.asarray(x)[None], first)]
        while True:
            for block in pending:
                _absorb(block, first_iteration, records, history, t_start, name, bar)
                first_iteration += int(block["ran"].sum())
            total = sum(int(r["active"].sum()) for r in records)
            failed = sum(int(np.sum(r["active"] & (~r["finite"] | r["bad"]))) for r in records)
            if total and failed == total:
                # As the host driver: nothing was learnt, whatever the limit.
                raise TooManyFailures(
                    f"all {total} simulations failed (non-finite summaries or distances), so there is no "
                    "posterior to return"
                )
            if total >= _MIN_FOR_FAILURE_CHECK and failed > max_failure_fraction * total:
                raise TooManyFailures(
                    f"{failed} of {total} simulations failed: non-finite summaries or distances "
                    f"(limit {max_failure_fraction:.0%})"
                )
            code = int(carry.stop_code)
            if not stop_reason and code != _NONE:
                stop_reason = _stop_reason(code, name, algo, history, num_steps, final_threshold, max_simulations)
            if not stop_reason and max_wall_time is not None and time.perf_counter() - t_start > max_wall_time:
                stop_reason = f"wall time {max_wall_time} s reached"
            if ckpt_path is not None and pending:
                _save(ckpt_path, fp, carry, first_iteration, stop_reason, history, records)
            if stop_reason:
                break
            if stop_after_iterations is not None and first_iteration >= stop_after_iterations:
                stop_reason = f"stopped after {first_iteration} iterations (resumable)"
                break
            carry, block = chunk(root, obs_j, limits, carry)
            pending = [jax.tree.map(np.asarray, block)]
    finally:
        if bar is not None:
            bar.close()

    num_sims = int(carry.num_sims)
    incomplete = int(carry.generations) == 0
    if incomplete:
        # As the host driver: the particles accepted so far, flagged.
        particles, log_w = (np.asarray(a) for a in algo.posterior(carry.state))
        dist = posterior_distances(carry.state, len(log_w))
        if not np.any(np.isfinite(log_w)):
            raise NoPosterior(
                f"the run stopped ({stop_reason}) after {num_sims} simulations without "
                "accepting any particle: raise max_simulations / max_wall_time or loosen the threshold"
            )
        stop_reason += (
            f"; incomplete: the first generation was not completed, the posterior "
            f"holds the {int(np.isfinite(log_w).sum())} particles accepted so far"
        )
    else:
        particles = np.asarray(carry.post_particles)
        log_w = np.asarray(carry.post_log_weights)
        dist = np.asarray(carry.post_distances)
    keep = np.isfinite(log_w)
    w = np.exp(log_w[keep] - np.max(log_w[keep]))
    meta = {
        "versions": versions(),
        "executor": "fused",
        "distance": distance if isinstance(distance, str) else getattr(distance, "__name__", "custom"),
        "dtype": dtype,
        "observed": obs.tolist() if obs.size <= 10_000 else None,
        # Seconds since the run started, at the end of the chunk that completed each
        # generation (the host does not see generations inside a chunk; after a resume,
        # counted from the resume).
        "generation_wall_times": history["wall"],
        "simulator": _ckpt.display_name(fp["simulator"]),
        "incomplete": incomplete,
        "chunk_size": int(chunk_size),
    }
    meta.update(metadata or {})
    extras = dict(algo.finalize(carry.state))
    log_ev = extras.pop("log_evidence", None)
    diagnostics = extras.pop("diagnostics", None) or {}
    final_ess = extras.pop("ess", None)
    meta.update(extras)
    ess = np.asarray(history["ess"], np.float64)
    if final_ess is not None and ess.size:
        ess[-1] = min(ess[-1], float(final_ess))
    return ABCResult(
        particles=particles[keep].astype(np.float64),
        weights=w / w.sum(),
        distances=dist[keep].astype(np.float64),
        thresholds=np.asarray(history["threshold"]),
        simulations_per_step=np.asarray(history["sims"]),
        acceptance_rates=np.asarray(history["acceptance"]),
        ess=ess,
        num_simulations=num_sims,
        algorithm=name,
        settings=algo.settings,
        prior=prior,
        seed=seed,
        stop_reason=stop_reason,
        wall_time=time.perf_counter() - t_start,
        log_evidence=log_ev,
        records=_record_arrays(records, keep_summaries),
        metadata=meta,
        diagnostics=diagnostics,
    )


def _save(path: Path, fp: dict, carry: _Carry, iteration: int, stop_reason: str, history: dict, records: list) -> None:
    done = int(carry.generations) > 0
    _ckpt.save(
        path,
        _ckpt.Checkpoint(
            fingerprint=fp,
            state_leaves=_ckpt.flatten_state(carry),
            counters={
                "iteration": iteration,
                "num_sims": int(carry.num_sims),
                "sims_this_generation": int(carry.generation_sims),
                "stop_reason": stop_reason,
            },
            history=history,
            records=to_checkpoint(records),
            last_posterior=(
                (np.asarray(carry.post_particles), np.asarray(carry.post_log_weights), np.asarray(carry.post_distances))
                if done
                else None
            ),
        ),
    )


@functools.wraps(_fused_run)
def _run_fused_body(*args: Any, checkpoint_dir: str | Path | None = None, **kwargs: Any) -> ABCResult:
    # One run per checkpoint folder: the lock is held from before the folder is prepared until
    # the last checkpoint is written.
    lock = _ckpt.FolderLock.acquire(checkpoint_dir)
    try:
        return _fused_run(*args, checkpoint_dir=checkpoint_dir, **kwargs)
    finally:
        if lock is not None:
            lock.release()


@functools.wraps(_run_fused_body)
def run_fused(*args: Any, dtype: str = "float32", **kwargs: Any) -> ABCResult:
    # Double precision for this run only (see jaxabc.run): the process-wide flag is restored.
    with precision(dtype):
        return _run_fused_body(*args, dtype=dtype, **kwargs)
