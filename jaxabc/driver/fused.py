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

import os
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc import checkpoint
from jaxabc.algorithms.base import ABCAlgorithm
from jaxabc.distances import get_distance
from jaxabc.driver.checks import (
    cast_prior,
    check_first_distances,
    check_first_iteration_budget,
    check_traced_shape,
    precision,
    validate_model,
    validate_num_particles,
    validate_observed,
)
from jaxabc.driver.context import Problem, build_by_name, posterior_distances, with_run_values
from jaxabc.driver.fused_records import (
    RUNNING,
    STOP_ALGORITHM,
    STOP_BUDGET,
    STOP_STEPS,
    STOP_THRESHOLD,
    absorb,
    from_checkpoint,
    record_arrays,
    stop_reason,
    to_checkpoint,
)
from jaxabc.driver.options import Checkpointing, RunOptions
from jaxabc.errors import NoPosterior, TooManyFailures
from jaxabc.priors import Uniform
from jaxabc.results import ABCResult, versions

__all__ = ["DRIVER", "Programs", "default_compilation_cache", "enable_compilation_cache", "run_compiled", "run_fused"]

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


def _simulate_distances(
    simulate: Callable, distance: Callable, key: jax.Array, thetas: jax.Array, active: jax.Array, observed: jax.Array
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """Summaries, finite and bad-distance flags and distances (``+inf`` where inactive or failed)."""
    # The host driver's keys: one per proposal slot, split from the simulation key.
    keys = jax.random.split(key, thetas.shape[0])
    summaries = jax.vmap(simulate)(keys, thetas)
    finite = jnp.all(jnp.isfinite(summaries.reshape(summaries.shape[0], -1)), axis=1)
    raw = jax.vmap(distance, in_axes=(None, 0))(observed, summaries)
    # As the host driver: a NaN or -inf distance of finite summaries is a failure of its own.
    bad = finite & active & (jnp.isnan(raw) | (raw == -jnp.inf))
    dist = jnp.where(finite & ~bad & active, raw, jnp.inf)
    return summaries, finite, bad, dist.astype(thetas.dtype)


def _after_update(
    algo: ABCAlgorithm, carry: _Carry, state: Any, info: Any, n_active: jax.Array, limits: _Limits
) -> tuple[_Carry, dict]:
    """The carry after an update, and the iteration's record of its generation."""
    gen_sims = carry.generation_sims + n_active
    done = info.generation_done
    particles, log_w = algo.posterior(state)
    generations = carry.generations + done.astype(jnp.int32)
    code = jnp.where(
        info.stop,
        STOP_ALGORITHM,
        jnp.where(
            generations >= limits.num_steps,
            STOP_STEPS,
            jnp.where(info.threshold <= limits.final_threshold, STOP_THRESHOLD, RUNNING),
        ),
    )
    level = jnp.asarray(getattr(state, "level", 0), jnp.int32)
    new = _Carry(
        state=state,
        iteration=carry.iteration + 1,
        num_sims=carry.num_sims + n_active,
        generations=generations,
        generation_sims=jnp.where(done, 0, gen_sims),
        stop_code=jnp.where(done, code, RUNNING).astype(jnp.int32),
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


def _compile(
    algo: ABCAlgorithm, simulate: Callable, distance: Callable, chunk_size: int, keep_summaries: bool
) -> tuple[Callable, Callable]:
    """Jitted ``start(root, observed, limits)`` and ``chunk(root, observed, limits, carry)``."""

    def simulate_distances(key, thetas, active, observed):
        return _simulate_distances(simulate, distance, key, thetas, active, observed)

    def after_update(carry, state, info, n_active, limits):
        return _after_update(algo, carry, state, info, n_active, limits)

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
            return carry._replace(stop_code=jnp.int32(STOP_BUDGET)), record

        new, record = jax.lax.cond(over_budget, stop, run, None)
        record.update(thetas=proposal.thetas, active=proposal.active & ~over_budget, ok=proposal.ok | over_budget)
        return new, record

    def chunk(root, observed, limits, carry):
        def body(c, _):
            def skip(c):
                _, record = jax.eval_shape(lambda c: one_iteration(root, observed, limits, c), c)
                record = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), record)
                return c, record

            return jax.lax.cond(c.stop_code != RUNNING, skip, lambda c: one_iteration(root, observed, limits, c), c)

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


@dataclass(frozen=True)
class Programs:
    """How the fused loop is compiled.

    Attributes
    ----------
    chunk_size : int
        Iterations per compiled program between two visits to the host.
    fast_compile : bool
        Compile without LLVM's optimisation passes (CPU backend only).
    builder_options : dict
        The builder's keywords, part of the programs' cache key (empty for an algorithm object).
    """

    chunk_size: int = _DEFAULT_CHUNK
    fast_compile: bool = False
    builder_options: dict = field(default_factory=dict)

    @classmethod
    def create(
        cls,
        chunk_size: int | None,
        fast_compile: bool,
        checkpointing: Checkpointing,
        builder_options: dict | None = None,
    ) -> Programs:
        """The programs of a run; ``chunk_size`` defaults to 1 when checkpointing (a checkpoint
        after every iteration, as the host driver writes), else 16.

        Raises
        ------
        ValueError
            ``chunk_size`` is not a positive integer.
        """
        if chunk_size is None:
            chunk_size = 1 if checkpointing.folder is not None else _DEFAULT_CHUNK
        if not isinstance(chunk_size, int | np.integer) or chunk_size < 1:
            raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
        return cls(int(chunk_size), fast_compile, dict(builder_options or {}))


def run_fused(
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
        As in :func:`jaxabc.run` (``num_particles`` required); ``simulate(key, theta) ->
        summaries`` must be traceable by JAX (it runs under ``vmap`` inside ``lax.scan``).
    final_threshold, max_simulations, max_wall_time, max_failure_fraction, keep_summaries
        As in :func:`jaxabc.run`.  The wall-time limit and the failure check are applied
        between chunks, so a run may go up to ``chunk_size - 1`` iterations past them.
    chunk_size : int, optional
        Iterations per compiled program between two visits to the host.  Default: 1 with a
        ``checkpoint_dir`` (a checkpoint after every iteration, as the host driver writes), else 16.
    fast_compile : bool
        Compile with LLVM's optimisation passes off: a cold run compiles faster; the compiled
        loop may run slower, which matters for expensive simulators (CPU backend only).
    checkpoint_dir, resume, overwrite, simulator_id
        As in :func:`jaxabc.run`, a checkpoint after every chunk.  A checkpoint of the host
        driver is refused (the fingerprint's ``driver`` field differs).
    stop_after_iterations : int, optional
        Stop, resumably, at the first chunk boundary at or after this many iterations.
    progress, dtype, metadata, **algorithm_options
        As in :func:`jaxabc.run`.

    Returns
    -------
    ABCResult
        As :func:`jaxabc.run`'s.  For a seed the iterations use the host driver's keys; the
        posterior agrees with the ``"vmap"`` executor's up to floating-point rounding (XLA may
        fuse the simulator and the distance differently).  Records have no per-simulation
        wall or CPU time (NaN) and worker 0.

    Raises
    ------
    TypeError
        ``simulate`` cannot be traced by JAX: use :func:`jaxabc.run` with a process executor.
    ValueError
        Bad arguments, as in :func:`jaxabc.run`, or a host algorithm.
    TooManyFailures
        More than ``max_failure_fraction`` of the simulations returned non-finite summaries or
        distances, or all of them.
    NoPosterior
        The run stopped before accepting any particle.
    RuntimeError
        The truncated kernel could not reach the prior's support.
    jaxabc.checkpoint.CheckpointError, FileExistsError
        As in :func:`jaxabc.run`.
    """
    options = RunOptions.from_keywords(
        seed=seed,
        num_steps=num_steps,
        final_threshold=final_threshold,
        max_simulations=max_simulations,
        max_wall_time=max_wall_time,
        max_failure_fraction=max_failure_fraction,
        checkpoint_dir=checkpoint_dir,
        resume=resume,
        overwrite=overwrite,
        simulator_id=simulator_id,
        stop_after=stop_after_iterations,
        keep_summaries=keep_summaries,
        progress=progress,
        dtype=dtype,
        metadata=metadata,
    )
    n = validate_num_particles(num_particles, required=True)
    validate_model(simulate, prior)
    # Double precision for this run only (see jaxabc.run): the process-wide flag is restored.
    with precision(dtype):
        obs = validate_observed(observed, dtype, distance)
        prior = cast_prior(prior, options.execution.jdtype)
        if isinstance(algorithm, ABCAlgorithm):
            algo, builder_options = algorithm, algorithm_options
        else:
            builder_options = with_run_values(algorithm, algorithm_options, options.stopping, obs)
            algo = build_by_name(algorithm, prior, n, builder_options)
        if algo.host or algo.uses_summaries:
            raise ValueError(f"{algo.name} is host code: run it with jaxabc.run, not run_fused")
        options.stopping.check_algorithm(algo)
        programs = Programs.create(chunk_size, fast_compile, options.checkpointing, builder_options)
        return run_compiled(algo, Problem(simulate, prior, obs, distance, n), options, programs)


def run_compiled(
    algo: ABCAlgorithm, problem: Problem, options: RunOptions, programs: Programs | None = None
) -> ABCResult:
    """Run the JAX algorithm ``algo`` on ``problem`` as compiled chunks (see :func:`run_fused`).

    Call it in the run's precision, with ``problem`` and ``options`` checked and ``algo`` a JAX
    algorithm whose stopping rules ``options`` satisfy; ``programs`` defaults to
    :meth:`Programs.create`'s defaults.

    Raises
    ------
    TypeError, ValueError
        ``problem.simulate`` cannot be traced, returns the wrong shape, or the first iteration
        exceeds ``max_simulations``.
    TooManyFailures, NoPosterior, RuntimeError, jaxabc.checkpoint.CheckpointError
        As :func:`run_fused`.
    """
    t_start = time.perf_counter()
    default_compilation_cache()
    programs = programs or Programs.create(None, False, options.checkpointing)
    check_traced_shape(
        problem.simulate, problem.prior, problem.observed, problem.distance, options.execution.jdtype, "The fused path"
    )
    first = jax.eval_shape(algo.initial_proposal, jax.random.key(0)).thetas.shape[0]
    check_first_iteration_budget(first, options.stopping.max_simulations, algo.name)  # every initial slot is active
    options.checkpointing.require_fingerprintable(problem.simulate, problem.distance)
    # One run per checkpoint folder, held until the last checkpoint is written.
    with options.checkpointing.locked():
        # Only now, with every input checked, may overwrite=True delete an old checkpoint.
        ckpt_path = options.checkpointing.prepare()
        run = _setup(algo, problem, options, programs, ckpt_path, t_start)
        if options.checkpointing.resume:
            _resume(run)
        _drive(run)
    return _result(run)


# ----------------------------------------------------------------------------- a run under way


@dataclass
class _Fused:
    """A fused run: its compiled programs and their inputs, and what the host has seen so far."""

    algo: ABCAlgorithm
    problem: Problem
    options: RunOptions
    chunk_size: int
    root: jax.Array
    observed: jax.Array
    limits: _Limits
    start: Callable
    chunk: Callable
    template: Any  # the carry's shapes
    fingerprint: dict
    ckpt_path: Path | None
    t_start: float
    carry: Any = None
    records: list[dict[str, np.ndarray]] = field(default_factory=list)
    history: dict[str, list] = field(
        default_factory=lambda: {"threshold": [], "sims": [], "acceptance": [], "ess": [], "wall": []}
    )
    iteration: int = 0  # iterations the host has absorbed
    stop_reason: str = ""
    bar: Any = None


def _setup(
    algo: ABCAlgorithm,
    problem: Problem,
    options: RunOptions,
    programs: Programs,
    ckpt_path: Path | None,
    t_start: float,
) -> _Fused:
    """The compiled programs (from the cache, or compiled now) and their traced inputs."""
    jdtype = options.execution.jdtype
    stopping = options.stopping
    root = jax.random.key(options.seed)
    observed = jnp.asarray(problem.observed, jdtype)
    budget = stopping.max_simulations
    limits = _Limits(
        num_steps=jnp.int32(_INT_MAX if stopping.num_steps is None else stopping.num_steps),
        final_threshold=jnp.asarray(-jnp.inf if stopping.final_threshold is None else stopping.final_threshold, jdtype),
        max_simulations=jnp.int32(_INT_MAX if budget is None else min(budget, _INT_MAX)),
    )
    dist_fn = get_distance(problem.distance)
    keep = options.execution.keep_summaries
    key = _cache_key(
        algo,
        programs.builder_options,
        problem.prior,
        problem.simulate,
        dist_fn,
        problem.observed.shape,
        jdtype,
        programs.chunk_size,
        keep,
        programs.fast_compile,
    )
    if key not in _COMPILED:
        if len(_COMPILED) >= _MAX_COMPILED:
            _COMPILED.pop(next(iter(_COMPILED)))
        start, chunk = _compile(algo, problem.simulate, dist_fn, programs.chunk_size, keep)
        fast = programs.fast_compile and jax.default_backend() == "cpu"
        _COMPILED[key] = _compile_both(start, chunk, root, observed, limits, fast)
    start, chunk, template = _COMPILED[key]
    return _Fused(
        algo=algo,
        problem=problem,
        options=options,
        chunk_size=programs.chunk_size,
        root=root,
        observed=observed,
        limits=limits,
        start=start,
        chunk=chunk,
        template=template,
        fingerprint={**problem.fingerprint(algo, options), "driver": DRIVER},
        ckpt_path=ckpt_path,
        t_start=t_start,
    )


def _resume(run: _Fused) -> None:
    assert run.ckpt_path is not None, "prepare_folder refuses resume without a folder"
    ck = checkpoint.load(run.ckpt_path)
    checkpoint.check_fingerprint(ck.fingerprint, run.fingerprint, run.ckpt_path)
    carry = checkpoint.restore_state(ck.state_leaves, run.template, run.ckpt_path)
    run.records, run.history = from_checkpoint(ck.records), ck.history
    run.iteration = int(ck.counters["iteration"])
    run.stop_reason = run.options.stopping.reopen(ck.counters["stop_reason"], run.history, run.ckpt_path)
    if not run.stop_reason:  # an ended run that goes on under this run's rules
        carry = carry._replace(stop_code=jnp.asarray(RUNNING, jnp.int32))
    run.carry = carry


def _drive(run: _Fused) -> None:
    """Run chunks until a rule stops the run; the host checks and checkpoints between them."""
    if run.options.execution.progress:
        from tqdm.auto import tqdm

        stopping = run.options.stopping
        run.bar = tqdm(total=stopping.num_steps, desc=run.algo.name, unit="step", initial=len(run.history["threshold"]))
    try:
        pending = [] if run.carry is not None else [_start(run)]
        while not _between_chunks(run, pending):
            run.carry, block = run.chunk(run.root, run.observed, run.limits, run.carry)
            pending = [jax.tree.map(np.asarray, block)]
    finally:
        if run.bar is not None:
            run.bar.close()


def _start(run: _Fused) -> dict:
    """The first iteration (the prior sample), as a block of one."""
    run.carry, first = run.start(run.root, run.observed, run.limits)
    # The distances are computed inside the program; the host checks the first population's
    # (prior draws) as the host driver does, before any further chunk.
    check_first_distances(np.asarray(first["distances"]))
    return jax.tree.map(lambda x: np.asarray(x)[None], first)


def _between_chunks(run: _Fused, pending: list[dict]) -> bool:
    """Take in the chunks just run, check failures, set the stop reason, checkpoint; whether to stop."""
    for block in pending:
        absorb(block, run.iteration, run.records, run.history, run.t_start, run.algo.name, run.bar)
        run.iteration += int(block["ran"].sum())
    _check_failures(run.records, run.options.execution.max_failure_fraction)
    stopping = run.options.stopping
    code = int(run.carry.stop_code)
    if not run.stop_reason and code != RUNNING:
        run.stop_reason = stop_reason(code, run.algo, run.history, stopping)
    wall = stopping.max_wall_time
    if not run.stop_reason and wall is not None and time.perf_counter() - run.t_start > wall:
        run.stop_reason = f"wall time {wall} s reached"
    if run.ckpt_path is not None and pending:
        _save(run)
    if run.stop_reason:
        return True
    if stopping.stop_after is not None and run.iteration >= stopping.stop_after:
        run.stop_reason = f"stopped after {run.iteration} iterations (resumable)"
        return True
    return False


def _check_failures(records: list[dict], max_failure_fraction: float) -> None:
    total = sum(int(r["active"].sum()) for r in records)
    failed = sum(int(np.sum(r["active"] & (~r["finite"] | r["bad"]))) for r in records)
    if total and failed == total:
        # As the host driver: nothing was learnt, whatever the limit.
        raise TooManyFailures(
            f"all {total} simulations failed (non-finite summaries or distances), so there is no posterior to return"
        )
    if total >= _MIN_FOR_FAILURE_CHECK and failed > max_failure_fraction * total:
        raise TooManyFailures(
            f"{failed} of {total} simulations failed: non-finite summaries or distances "
            f"(limit {max_failure_fraction:.0%})"
        )


def _save(run: _Fused) -> None:
    assert run.ckpt_path is not None, "only called when checkpointing"
    carry = run.carry
    done = int(carry.generations) > 0
    checkpoint.save(
        run.ckpt_path,
        checkpoint.Checkpoint(
            fingerprint=run.fingerprint,
            state_leaves=checkpoint.flatten_state(carry),
            counters={
                "iteration": run.iteration,
                "num_sims": int(carry.num_sims),
                "sims_this_generation": int(carry.generation_sims),
                "stop_reason": run.stop_reason,
            },
            history=run.history,
            records=to_checkpoint(run.records),
            last_posterior=(
                (np.asarray(carry.post_particles), np.asarray(carry.post_log_weights), np.asarray(carry.post_distances))
                if done
                else None
            ),
        ),
    )


# ----------------------------------------------------------------------------- the result


def _final_posterior(run: _Fused) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """The last completed generation's posterior and the stop reason; before the first
    generation completed (as the host driver), the particles accepted so far, flagged."""
    carry = run.carry
    if int(carry.generations) > 0:
        particles = np.asarray(carry.post_particles)
        return particles, np.asarray(carry.post_log_weights), np.asarray(carry.post_distances), run.stop_reason
    particles, log_w = (np.asarray(a) for a in run.algo.posterior(carry.state))
    dist = posterior_distances(carry.state, len(log_w))
    if not np.any(np.isfinite(log_w)):
        raise NoPosterior(
            f"the run stopped ({run.stop_reason}) after {int(carry.num_sims)} simulations without "
            "accepting any particle: raise max_simulations / max_wall_time or loosen the threshold"
        )
    reason = run.stop_reason + (
        f"; incomplete: the first generation was not completed, the posterior "
        f"holds the {int(np.isfinite(log_w).sum())} particles accepted so far"
    )
    return particles, log_w, dist, reason


def _result(run: _Fused) -> ABCResult:
    particles, log_w, dist, reason = _final_posterior(run)
    problem, options, algo, history = run.problem, run.options, run.algo, run.history
    keep = np.isfinite(log_w)
    w = np.exp(log_w[keep] - np.max(log_w[keep]))
    distance, obs = problem.distance, problem.observed
    meta = {
        "versions": versions(),
        "executor": "fused",
        "distance": distance if isinstance(distance, str) else getattr(distance, "__name__", "custom"),
        "dtype": options.execution.dtype,
        "observed": obs.tolist() if obs.size <= 10_000 else None,
        # Seconds since the run started, at the end of the chunk that completed each
        # generation (the host does not see generations inside a chunk; after a resume,
        # counted from the resume).
        "generation_wall_times": history["wall"],
        "simulator": checkpoint.display_name(run.fingerprint["simulator"]),
        "incomplete": int(run.carry.generations) == 0,
        "chunk_size": run.chunk_size,
    }
    meta.update(options.metadata or {})
    extras = dict(algo.finalize(run.carry.state))
    reason = extras.pop("stop_reason_prefix", "") + reason
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
        num_simulations=int(run.carry.num_sims),
        algorithm=algo.name,
        settings=algo.settings,
        prior=problem.prior,
        seed=options.seed,
        stop_reason=reason,
        wall_time=time.perf_counter() - run.t_start,
        log_evidence=log_ev,
        records=record_arrays(run.records, options.execution.keep_summaries),
        metadata=meta,
        diagnostics=diagnostics,
    )
