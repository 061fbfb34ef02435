"""The host driver: one loop for every algorithm and executor.

Each iteration derives its key from the seed and the iteration number alone
(``fold_in(key, iteration)``), asks the algorithm where to simulate, runs the simulations on the
executor, turns failures into ``+inf`` distances, updates the algorithm's state and writes a
checkpoint.  Because nothing else feeds the random stream, a run killed at any point and resumed
from its checkpoint gives exactly the result of the uninterrupted run, and the result does not
depend on the executor or the number of workers.

The driver knows no algorithm by name: stop reasons, result extras and whether a stopping rule
is required come from the :class:`~jaxabc.algorithms.base.ABCAlgorithm` fields.
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast, overload

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc import algorithms as _algorithms
from jaxabc import checkpoint as _ckpt
from jaxabc.algorithms.base import ABCAlgorithm
from jaxabc.checkpoint import CHECKPOINT_NAME
from jaxabc.distances import AdaptivePNorm, as_adaptive, get_distance, is_adaptive
from jaxabc.driver.assemble import assemble
from jaxabc.driver.checks import (
    cast_prior,
    check_first_distances,
    check_first_iteration_budget,
    check_shape,
    check_stopping_rule,
    precision,
    shapes_compatible,
    validate_arguments,
    validate_observed,
    validate_seed,
)
from jaxabc.driver.context import (
    Context,
    Progress,
    Recorder,
    SharedVmapExecutor,
    builder_accepts,
    compile_algorithm,
    make_distance_fn,
    mark_bad_distances,
    posterior_distances,
)
from jaxabc.driver.fused import DRIVER as FUSED_DRIVER
from jaxabc.driver.fused import _run_fused_body
from jaxabc.errors import STATUS_OK, TooManyFailures
from jaxabc.executors import Executor, get_executor
from jaxabc.noise import Discrepancy, ResolvedDiscrepancy, observation_covariance, wrap_for_abc
from jaxabc.priors import Uniform
from jaxabc.results import ABCResult

if TYPE_CHECKING:  # model choice is imported only when a list of models is run
    from jaxabc.model_choice import ModelChoiceResult

__all__ = ["CHECKPOINT_NAME", "run"]

_MIN_FOR_FAILURE_CHECK = 20


# ----------------------------------------------------------------------------- the loop


def _simulate_batch(
    ctx: Context, prog: Progress, k_sim: jax.Array, thetas: np.ndarray, active: np.ndarray
) -> tuple[np.ndarray, np.ndarray | None]:
    """Simulate the active slots; distances (m,) and, if the algorithm wants them, summaries."""
    m = thetas.shape[0]
    distances = np.full(m, np.inf)
    summaries = None
    if ctx.compiled.algorithm.uses_summaries:
        summaries = np.full((m, *ctx.observed.shape), np.nan)
    if not active.any():
        return distances, summaries
    sim_keys = np.asarray(jax.random.key_data(jax.random.split(k_sim, m)))
    batch = ctx.executor.map(ctx.simulate, sim_keys[active], thetas[active])
    ok = np.asarray(batch.status) == STATUS_OK
    if ok.any() and not shapes_compatible(batch.summaries.shape[1:], ctx.observed.shape, ctx.distance):
        raise ValueError(
            f"the simulator returned summaries of shape {batch.summaries.shape[1:]} "
            f"but the observed data has shape {ctx.observed.shape}: they must match"
        )
    dist, bad = ctx.distances_of(batch.summaries, ok)
    status, reasons = mark_bad_distances(batch.status, batch.reasons, bad, dist)
    distances[active] = dist
    if summaries is not None:
        if summaries.shape[1:] != batch.summaries.shape[1:]:
            summaries = np.full((m, *batch.summaries.shape[1:]), np.nan)
        summaries[np.flatnonzero(active)[ok & ~bad]] = batch.summaries[ok & ~bad]
    prog.recorder.add(prog.iteration, thetas[active], batch, dist, status, reasons)
    prog.num_sims += int(active.sum())
    prog.sims_this_generation += int(active.sum())
    _check_failures(prog.recorder, ctx.max_failure_fraction)
    return distances, summaries


def _check_failures(recorder: Recorder, max_failure_fraction: float) -> None:
    total, failed, examples = recorder.failures()
    if total and failed == total:
        # Nothing was learnt: whatever the limit, a posterior now would be prior draws.
        raise TooManyFailures(
            f"all {total} simulations failed, so there is no posterior to return; first "
            "failures:\n  " + "\n  ".join(examples)
        )
    if total >= _MIN_FOR_FAILURE_CHECK and failed > max_failure_fraction * total:
        raise TooManyFailures(
            f"{failed} of {total} simulations failed (limit {max_failure_fraction:.0%}); first "
            "failures:\n  " + "\n  ".join(examples)
        )


def _step(ctx: Context, prog: Progress) -> Any:
    """One iteration: propose, simulate, update.  Returns the algorithm's Info, or None when the
    simulation budget stopped the run before simulating."""
    c = ctx.compiled
    key = jax.random.fold_in(ctx.root, prog.iteration)
    k_prop, k_sim, k_upd = jax.random.split(key, 3)
    proposal = c.initial_proposal(k_prop) if prog.state is None else c.propose(k_prop, prog.state)
    if not bool(proposal.ok):
        raise RuntimeError(
            f"{c.algorithm.name}: the truncated perturbation kernel could not reach the prior's "
            "support from some particles (no draw inside the box in 10,000 tries). The "
            "posterior is piled against a prior bound: widen the prior there"
        )
    active = np.asarray(proposal.active, bool)
    thetas = np.asarray(proposal.thetas)
    if prog.state is None and prog.num_sims == 0:
        check_first_iteration_budget(int(active.sum()), ctx.max_simulations, c.algorithm.name)
    if (
        ctx.max_simulations is not None
        and prog.state is not None
        and prog.num_sims + int(active.sum()) > ctx.max_simulations
    ):
        prog.stop_reason = f"simulation budget {ctx.max_simulations} reached"
        return None
    distances, summaries = _simulate_batch(ctx, prog, k_sim, thetas, active)
    if prog.state is None:
        # Prior draws: a distance that goes negative or cannot rank them shows it here.
        check_first_distances(distances)
    d = np.asarray(distances) if c.algorithm.host else jnp.asarray(distances, ctx.jdtype)
    extra = () if summaries is None else (summaries if c.algorithm.host else jnp.asarray(summaries),)
    if prog.state is None:
        prog.state, info = c.init(k_upd, proposal, d, *extra)
    else:
        prog.state, info = c.update(k_upd, prog.state, proposal, d, *extra)
    prog.iteration += 1
    return info


def _end_generation(ctx: Context, prog: Progress, info: Any) -> None:
    particles, log_w = ctx.compiled.posterior(prog.state)
    prog.last_posterior = (np.asarray(particles), np.asarray(log_w), posterior_distances(prog.state, len(log_w)))
    h = prog.history
    h["threshold"].append(float(info.threshold))
    h["sims"].append(prog.sims_this_generation)
    h["acceptance"].append(float(info.acceptance_rate))
    h["ess"].append(float(info.ess))
    h["wall"].append(time.perf_counter() - ctx.t_start)
    weights = getattr(prog.state, "distance_weights", None)
    if weights is not None:
        # An adaptive distance's weights change each generation; the history is checkpointed.
        h.setdefault("distance_weights", []).append(np.asarray(weights, np.float64).tolist())
    prog.sims_this_generation = 0
    if ctx.bar is not None:
        ctx.bar.update(1)
        ctx.bar.set_postfix(
            threshold=f"{float(info.threshold):.4g}",
            acceptance=f"{float(info.acceptance_rate):.3f}",
            sims=prog.num_sims,
        )
    algo = ctx.compiled.algorithm
    if bool(info.stop):
        prog.stop_reason = algo.stop_reason(algo.settings, info)
    elif ctx.num_steps is not None and len(h["threshold"]) >= ctx.num_steps:
        prog.stop_reason = f"{ctx.num_steps} steps done"
    elif ctx.final_threshold is not None and float(info.threshold) <= ctx.final_threshold:
        prog.stop_reason = f"final threshold {ctx.final_threshold} reached"


def _loop(ctx: Context, prog: Progress) -> None:
    while not prog.stop_reason:
        info = _step(ctx, prog)
        if info is None:
            break
        if bool(info.generation_done):
            _end_generation(ctx, prog, info)
        if (
            not prog.stop_reason
            and ctx.max_wall_time is not None
            and time.perf_counter() - ctx.t_start > ctx.max_wall_time
        ):
            prog.stop_reason = f"wall time {ctx.max_wall_time} s reached"
        if ctx.ckpt_path is not None:
            _save(ctx, prog)
        if (
            ctx.stop_after_iterations is not None
            and prog.iteration >= ctx.stop_after_iterations
            and not prog.stop_reason
        ):
            prog.stop_reason = f"stopped after {prog.iteration} iterations (resumable)"


# ----------------------------------------------------------------------------- checkpoints


def _save(ctx: Context, prog: Progress) -> None:
    assert ctx.ckpt_path is not None, "only called when checkpointing"
    _ckpt.save(
        ctx.ckpt_path,
        _ckpt.Checkpoint(
            fingerprint=ctx.fingerprint,
            state_leaves=_ckpt.flatten_state(prog.state),
            counters={
                "iteration": prog.iteration,
                "num_sims": prog.num_sims,
                "sims_this_generation": prog.sims_this_generation,
                "stop_reason": prog.stop_reason,
            },
            history=prog.history,
            records=prog.recorder.chunks,
            last_posterior=prog.last_posterior,
        ),
    )


def _state_template(ctx: Context) -> Any:
    algo = ctx.compiled.algorithm
    key = jax.random.key(0)
    proposal = jax.eval_shape(algo.initial_proposal, key)
    m = proposal.thetas.shape[0]
    args = [key, proposal, jax.ShapeDtypeStruct((m,), ctx.jdtype)]
    if algo.uses_summaries:
        args.append(jax.ShapeDtypeStruct((m, *ctx.observed.shape), jnp.result_type(float)))
    return jax.eval_shape(algo.init, *args)[0]


def _restore(ctx: Context, prog: Progress) -> None:
    assert ctx.ckpt_path is not None, "only called when resuming from a checkpoint"
    ck = _ckpt.load(ctx.ckpt_path)
    _ckpt.check_fingerprint(ck.fingerprint, ctx.fingerprint, ctx.ckpt_path)
    algo = ctx.compiled.algorithm
    if algo.restore_state is not None:
        prog.state = algo.restore_state(ck.state_leaves)
    else:
        prog.state = _ckpt.restore_state(ck.state_leaves, _state_template(ctx), ctx.ckpt_path)
    c = ck.counters
    prog.iteration, prog.num_sims = int(c["iteration"]), int(c["num_sims"])
    prog.sims_this_generation = int(c["sims_this_generation"])
    prog.history = ck.history
    prog.stop_reason = _ckpt.reopen(
        c["stop_reason"],
        ck.history,
        num_steps=ctx.num_steps,
        final_threshold=ctx.final_threshold,
        max_simulations=ctx.max_simulations,
        max_wall_time=ctx.max_wall_time,
        path=ctx.ckpt_path,
    )
    prog.recorder.chunks = ck.records
    prog.last_posterior = ck.last_posterior


# ----------------------------------------------------------------------------- entry point


def _fused_applies(
    algo: ABCAlgorithm,
    num_particles: int | None,
    simulate: Callable,
    prior: Uniform,
    obs: np.ndarray,
    distance: Any,
    jdtype: Any,
    checkpoint_dir: str | Path | None,
    resume: bool,
) -> bool:
    """Whether ``run(executor=None)`` can run the whole calibration as compiled programs
    (:func:`jaxabc.driver.fused.run_fused`): a JAX algorithm, and a simulator and distance JAX can trace.
    A resumed run stays on the driver that wrote its checkpoint."""
    if algo.host or algo.uses_summaries or num_particles is None:
        return False
    if resume and checkpoint_dir is not None and (Path(checkpoint_dir) / CHECKPOINT_NAME).exists():
        try:
            stored = _ckpt.load(Path(checkpoint_dir) / CHECKPOINT_NAME).fingerprint
        except _ckpt.CheckpointError:
            return False  # the host driver reports it
        return stored.get("driver") == FUSED_DRIVER
    try:
        out = jax.eval_shape(simulate, jax.random.key(0), jnp.zeros((prior.dim,), jdtype))
        jax.eval_shape(get_distance(distance), jnp.zeros(obs.shape, jdtype), out)
    except Exception:
        # Not traceable (NumPy, an external program, Python control flow on values): this is a
        # probe, and the host driver gives such simulators their own clear errors.
        return False
    return shapes_compatible(tuple(out.shape), obs.shape, distance)


def _adaptive_setup(distance: Any, algorithm: Any, obs: np.ndarray, options: dict) -> Callable:
    """Hand the bound adaptive norm to the algorithm; return the distance the driver records."""
    spec = as_adaptive(distance, obs)
    if isinstance(algorithm, ABCAlgorithm):
        if "adaptive_distance" not in algorithm.settings:
            raise ValueError(
                f"distance='adaptive' is computed by the algorithm, but this {algorithm.name} "
                "object was built without adaptive_distance=: build it with "
                "adaptive_distance=AdaptivePNorm().bind(observed), or pass its name"
            )
    elif builder_accepts(algorithm, "adaptive_distance"):
        options["adaptive_distance"] = spec
    else:
        raise ValueError(
            f"distance='adaptive' works with the SMC algorithms 'apmcabc' and 'pmcabc', not "
            f"{algorithm!r}: choose one of them or a fixed distance"
        )
    return spec.record_distance()


#: The ABC algorithms: measurement error and discrepancy enter them through the simulator and
#: the prior (noisy ABC).  Other builders (the surrogate) take them as builder options.
_ABC_ALGORITHMS = ("apmcabc", "pmcabc", "abcsubsim", "rejection")


def _builder_takes(name: str, option: str) -> bool:
    """Whether the builder ``name`` takes ``option``, following the surrogate's lazy wrapper
    (``**options`` passed on to :func:`jaxabc.surrogate.build`)."""
    if builder_accepts(name, option):
        return True
    if name == "surrogate":
        from jaxabc.surrogate import build

        return option in inspect.signature(build).parameters
    return False


def _measured_data(
    algorithm: str | ABCAlgorithm,
    simulate: Callable,
    prior: Any,
    obs: np.ndarray,
    observation_error: Any,
    discrepancy: Any,
    options: dict,
) -> tuple[Callable, Any, dict]:
    """Apply ``observation_error`` and ``discrepancy`` to a calibration.

    Returns the simulator and prior the algorithm runs with (wrapped and augmented for the ABC
    algorithms, unchanged for builders that take the options themselves, into whose
    ``options`` they are then put) and the settings to record, JSON-normal, for the result and
    the checkpoint fingerprint.
    """
    if observation_error is None and discrepancy is None:
        return simulate, prior, {}
    cov = None if observation_error is None else observation_covariance(observation_error, obs.shape)
    if discrepancy is not None and not isinstance(discrepancy, Discrepancy):
        raise TypeError(f"discrepancy must be a jaxabc.Discrepancy(max_sd, groups), got {type(discrepancy).__name__}")
    resolved: ResolvedDiscrepancy | None = None if discrepancy is None else discrepancy.resolve(obs.shape)
    settings: dict[str, Any] = {}
    if cov is not None:
        settings["observation_error"] = cov.tolist()
    if discrepancy is not None:
        settings["discrepancy"] = discrepancy.describe()
    name = algorithm if isinstance(algorithm, str) else algorithm.name
    if isinstance(algorithm, str) and name not in _ABC_ALGORITHMS and name in _algorithms.BUILDERS:
        # Not an ABC algorithm (the surrogate): it models the error in its likelihood.
        for option, value in (("observation_error", cov), ("discrepancy", resolved)):
            if value is None:
                continue
            if not _builder_takes(name, option):
                raise ValueError(
                    f"the {name} in this version does not take {option}: run an ABC algorithm "
                    f"({', '.join(_ABC_ALGORITHMS)}) with it, or leave it out"
                )
            options[option] = value
        return simulate, prior, settings
    if isinstance(algorithm, ABCAlgorithm) and name not in _ABC_ALGORITHMS:
        raise ValueError(
            f"observation_error and discrepancy reach an algorithm object {name!r} only through its "
            "builder: pass the algorithm by name, or give them to the function that built it"
        )
    simulate, augmented = wrap_for_abc(simulate, prior, obs.shape, cov, resolved)
    if isinstance(algorithm, ABCAlgorithm) and resolved is not None:
        dim = jax.eval_shape(algorithm.initial_proposal, jax.random.key(0)).thetas.shape[-1]
        if dim != augmented.dim:
            raise ValueError(
                f"with a discrepancy the run has {augmented.dim} parameters ({prior.dim} of the model, "
                f"{len(resolved.names)} discrepancy sds), but this {name} object was built for {dim}: "
                "pass the algorithm by name, or build it with the prior of jaxabc.noise.wrap_for_abc"
            )
    return simulate, augmented, settings


@overload
def run(
    algorithm: list[Any] | tuple[Any, ...],
    simulate: None = None,
    prior: None = None,
    observed: Any = None,
    **options: Any,
) -> ModelChoiceResult: ...


@overload
def run(
    algorithm: str | ABCAlgorithm,
    simulate: Callable,
    prior: Uniform,
    observed: Any,
    **options: Any,
) -> ABCResult: ...


def run(
    algorithm: str | ABCAlgorithm | Sequence[Any],
    simulate: Callable | None = None,
    prior: Uniform | None = None,
    observed: Any = None,
    num_particles: int | None = None,
    num_steps: int | None = None,
    distance: str | Callable | AdaptivePNorm = "mean_abs",
    seed: int = 0,
    *,
    executor: str | Executor | None = None,
    final_threshold: float | None = None,
    max_simulations: int | None = None,
    max_wall_time: float | None = None,
    max_failure_fraction: float = 0.5,
    checkpoint_dir: str | Path | None = None,
    resume: bool = False,
    overwrite: bool = False,
    simulator_id: str | None = None,
    stop_after_iterations: int | None = None,
    keep_summaries: bool = True,
    progress: bool = False,
    dtype: str = "float32",
    metadata: dict | None = None,
    observation_error: Any = None,
    discrepancy: Discrepancy | None = None,
    **algorithm_options: Any,
) -> ABCResult | ModelChoiceResult:
    """Calibrate ``simulate`` against ``observed`` with an ABC algorithm.

    Parameters
    ----------
    algorithm : {"apmcabc", "abcsubsim", "pmcabc", "rejection"} or ABCAlgorithm
        A name is built from :data:`jaxabc.algorithms.BUILDERS` with ``prior``,
        ``num_particles`` and ``**algorithm_options``; an algorithm object is used as it is.
        A list of models, ``jaxabc.run([(simulate_a, prior_a), (simulate_b, prior_b)],
        observed=...)``, runs ABC model choice instead and returns a
        :class:`jaxabc.model_choice.ModelChoiceResult` (see :func:`jaxabc.model_choice.run_model_choice`).
    simulate : callable ``(key, theta) -> summaries``
        One parameter vector in, a fixed-shape summary array (or a scalar) out.  A JAX function
        for the ``"vmap"`` executor; any picklable callable for ``"process_pool"`` / ``"mpi"``
        (it then gets the key as raw ``uint32[2]`` data; see
        :func:`jaxabc.seeding.seed_from_key`).  Failures: raise
        :class:`jaxabc.SimulationFailure` or return NaN.
    prior : Uniform
    observed : array_like
        The measured summaries, same shape as ``simulate``'s output.
    num_particles : int, optional
        Population size ``N`` (for ``"surrogate"``: posterior draws, default 2000).  Required by
        the population algorithms.
        Population size ``N``.
    num_steps : int, optional
        Maximum number of ABC steps (generations / levels), the initial prior sample included.
    distance : str, callable or AdaptivePNorm
        ``"mean_abs"``, ``"euclidean"``, ``"kl"`` or ``distance(observed, simulated) -> scalar``.
        A NaN distance of a successful simulation is recorded as a failure.  ``"adaptive"``
        (or :class:`jaxabc.distances.AdaptivePNorm` for another ``p``), for ``"apmcabc"`` and
        ``"pmcabc"`` with flat summary vectors: Prangle's adaptive weighted p-norm, re-weighted
        each generation by the algorithm; the weights of every generation are in
        ``result.diagnostics["distance_weights"]`` (shape (generations, s)), the records hold
        the unit-weight p-norm, and the thresholds are on each generation's own scale.
    seed : int
        The run's only source of randomness: an integer with ``0 <= seed < 2**32`` (a NumPy
        integer is taken as its value; anything else is refused with ``TypeError`` or
        ``ValueError``).
    executor : str or Executor, optional
        ``"vmap"``, ``"serial"``, ``"process_pool"``, ``"mpi"``, ``"mpi_static"``, or an executor
        object.  Default: the whole run as compiled programs (:func:`jaxabc.run_fused`, result
        ``metadata["executor"] == "fused"``) when the algorithm is a JAX one and JAX can trace
        ``simulate`` and the distance, else ``"vmap"`` on this host driver.  Both give the same
        iterations for a seed, up to floating-point rounding.
    final_threshold : float, optional
        Stop once a generation's threshold is at or below this.
    max_simulations : int, optional
        Simulation budget: stop before an iteration that would exceed it.  A budget below the
        first iteration's simulations (the initial prior sample) is refused.  A run stopped before
        its first generation completed returns the particles accepted so far, flagged
        ``incomplete`` in ``stop_reason`` and ``metadata``.
    max_wall_time : float, optional
        Seconds; checked after each iteration.
    max_failure_fraction : float
        Stop with :class:`jaxabc.TooManyFailures` when more than this fraction of simulations
        (after the first 20) failed, or when every simulation so far failed.
    checkpoint_dir : path, optional
        Write ``checkpoint.npz`` there after every iteration (atomically).  A fresh run into a
        folder holding a checkpoint is refused unless ``resume`` or ``overwrite`` is given.
    resume : bool
        Continue from the checkpoint in ``checkpoint_dir``; the result equals that of the
        uninterrupted run.  Refused when the problem differs (prior, observed values, distance,
        simulator, algorithm and settings, ``observation_error``, ``discrepancy``, seed,
        ``num_particles``, dtype; a partial's or closure's bound values count, see
        :func:`jaxabc.checkpoint.describe_callable`) or when another run holds the folder
        (:class:`jaxabc.checkpoint.FolderInUse`).  A run that had
        ended on ``num_steps``, ``final_threshold``, ``max_simulations`` or ``max_wall_time``
        goes on when this call's rule allows more.
    overwrite : bool
        Delete an existing checkpoint in ``checkpoint_dir`` and start over.
    simulator_id : str, optional
        The simulator's identity in checkpoints (default: :func:`jaxabc.checkpoint.describe_callable`
        of ``simulate``): required with ``checkpoint_dir`` when ``simulate`` captures an object
        that cannot be fingerprinted; useful for external programs.
    stop_after_iterations : int, optional
        Stop after this many iterations (for tests and for splitting long runs).
    keep_summaries : bool
        Keep every simulation's summaries in the record.
    progress : bool
        Show a progress bar with threshold, acceptance and ETA.
    dtype : {"float32", "float64"}
        Working precision of the inference kernels; ``"float64"`` enables ``jax_enable_x64``
        for the duration of the run only.
    metadata : dict, optional
        Stored in the result.
    observation_error : float, array_like or (n, n) array, optional
        The measurement error of ``observed``, in the summaries' units: one standard deviation
        for all summaries, one per summary (``observed``'s shape, or flattened ``(n,)``; 0 where
        the data state none), or a covariance ``(n, n)`` over the flattened summaries (squared
        units, symmetric positive semi-definite).  Read by
        :func:`jaxabc.noise.observation_covariance`; negative, non-finite, misshapen or
        non-PSD values are refused with ``ValueError``.  The ABC algorithms run *noisy ABC*:
        every simulated summary vector gets its own draw of the error, from the simulation's key
        (so a seed fixes it on every executor), and ABC then targets the posterior of the model
        plus that error rather than treating the data as exact (Wilkinson 2013, "Approximate
        Bayesian computation (ABC) gives exact results under the assumption of model error",
        Stat. Appl. Genet. Mol. Biol. 12, 129).  ``"surrogate"`` takes it as a builder option
        (its synthetic likelihood adds the covariance).  Recorded as the covariance list in
        ``result.settings["observation_error"]`` and in the checkpoint fingerprint.
    discrepancy : jaxabc.Discrepancy, optional
        Model discrepancy (Kennedy & O'Hagan 2001, "Bayesian calibration of computer models",
        J. R. Stat. Soc. B 63, 425), a variance per group of summaries: the model reproduces the
        data up to independent Gaussian errors of unknown standard deviation ``delta_g`` per
        group.  For the ABC algorithms the prior gains ``G`` uniform parameters
        ``[0, max_sd_g]`` (summary units), named ``discrepancy_sd[<group>]``, and each
        simulation adds ``N(0, delta_g^2)`` to the summaries of group ``g``: the result's
        particles have ``d + G`` columns and ``result.prior`` is the augmented prior.
        ``"surrogate"`` takes the resolved groups as a builder option.  Recorded as
        ``result.settings["discrepancy"]`` (:meth:`jaxabc.Discrepancy.describe`) and in the
        checkpoint fingerprint; groups naming summaries that do not exist are refused with
        ``ValueError``.

        For a list of models (model choice) both options are passed on to it unchanged.
    **algorithm_options
        Passed to the algorithm's builder (see :mod:`jaxabc.algorithms`).

    Returns
    -------
    ABCResult

    Raises
    ------
    TooManyFailures, NoPosterior, jaxabc.checkpoint.CheckpointError, FileExistsError
    ValueError
        Besides bad arguments: observed data beyond ``dtype``'s range or that the distance
        cannot use (``"kl"`` with fewer than two distinct values), or a distance that returned
        negative values for the first population.  Every distance of the first population
        being equal only warns (``UserWarning``): the posterior is then the prior.
    TypeError
        Besides bad argument types: a simulator that returns complex summaries.
    """
    seed = validate_seed(seed)  # before model choice takes the arguments, so it is checked too
    if type(algorithm) in (list, tuple) or type(simulate) in (list, tuple):
        # Model choice, imported here so that a calibration never loads it.
        if algorithm_options.get("method") == "surrogate":
            # One surrogate calibration per model, each through this function (passed, not
            # imported, so that model choice does not import the driver back).
            from jaxabc.model_choice.surrogate import run_from_driver as surrogate_choice

            return surrogate_choice(dict(locals()), run)
        from jaxabc.model_choice import run_from_driver

        return run_from_driver(dict(locals()))
    if simulate is None or prior is None:
        raise TypeError("run() needs simulate and prior (for model choice: a list of models first)")
    algorithm = cast(str | ABCAlgorithm, algorithm)
    t_start = time.perf_counter()
    validate_arguments(dtype, num_particles, num_steps, max_failure_fraction, simulate, prior)
    obs = validate_observed(observed, dtype, distance)
    # Noisy ABC and discrepancy: a wrapped simulator and an augmented prior (or builder options).
    simulate, prior, measured = _measured_data(
        algorithm, simulate, prior, obs, observation_error, discrepancy, algorithm_options
    )
    if isinstance(distance, AdaptivePNorm) or is_adaptive(distance):
        # The algorithm computes the adaptive distances; the driver records a fixed one.
        distance = _adaptive_setup(distance, algorithm, obs, algorithm_options)
    with precision(dtype):
        jdtype = jnp.float64 if dtype == "float64" else jnp.float32
        prior = cast_prior(cast(Uniform, prior), jdtype)
        if isinstance(algorithm, str):
            # Run-level settings that some builders need to see (the surrogate's budget and data).
            for option, value in (
                ("final_threshold", final_threshold),
                ("observed", obs),
                ("max_simulations", max_simulations),
            ):
                if value is not None and builder_accepts(algorithm, option):
                    algorithm_options.setdefault(option, value)
        compiled = compile_algorithm(algorithm, prior, num_particles, algorithm_options, dtype)
        if measured:
            # In the settings, so that results record them and a resume with others is refused
            # (the checkpoint fingerprint holds the settings), on the fused and the host driver.
            extra = {k: v for k, v in measured.items() if k not in compiled.algorithm.settings}
            settings = {**compiled.algorithm.settings, **extra}
            compiled = compiled._replace(algorithm=compiled.algorithm._replace(settings=settings))
        algo = compiled.algorithm
        check_stopping_rule(algo, num_steps, final_threshold, max_simulations, max_wall_time)
        fused = executor is None and _fused_applies(
            algo, num_particles, simulate, prior, obs, distance, jdtype, checkpoint_dir, resume
        )
        if fused:
            return _run_fused_body(
                algo,
                simulate,
                prior,
                obs,
                int(cast(int, num_particles)),
                num_steps,
                distance,
                seed,
                final_threshold=final_threshold,
                max_simulations=max_simulations,
                max_wall_time=max_wall_time,
                max_failure_fraction=max_failure_fraction,
                checkpoint_dir=checkpoint_dir,
                resume=resume,
                overwrite=overwrite,
                simulator_id=simulator_id,
                stop_after_iterations=stop_after_iterations,
                keep_summaries=keep_summaries,
                progress=progress,
                dtype=dtype,
                metadata=metadata,
            )
        own_executor = not hasattr(executor, "map")
        ex = SharedVmapExecutor() if executor in (None, "vmap") else get_executor(executor)
        lock = None
        try:
            check_shape(ex, simulate, prior, obs, distance)
            if hasattr(ex, "summary_shape") and not getattr(get_distance(distance), "compares_samples", False):
                # A batch where every task fails keeps it (not on the Executor protocol).
                cast(Any, ex).summary_shape = tuple(obs.shape)
            if checkpoint_dir is not None:
                _ckpt.require_fingerprintable(simulate, simulator_id, distance)
            # One run per folder; and only now, with every input checked, may overwrite=True
            # delete an old checkpoint.
            lock = _ckpt.FolderLock.acquire(checkpoint_dir)
            ckpt_path = _ckpt.prepare_folder(checkpoint_dir, resume, overwrite)
            fp = _ckpt.fingerprint(
                algorithm=algo.name,
                settings=algo.settings,
                prior=prior,
                observed=obs,
                distance=distance,
                simulator_id=_ckpt.simulator_identity(simulate, simulator_id),
                seed=seed,
                num_particles=None if num_particles is None else int(num_particles),
                dtype=dtype,
            )
            ctx = Context(
                compiled,
                simulate,
                ex,
                obs,
                distance,
                make_distance_fn(distance, obs, jdtype),
                jdtype,
                jax.random.key(seed),
                t_start,
                num_steps,
                final_threshold,
                max_simulations,
                max_wall_time,
                max_failure_fraction,
                stop_after_iterations,
                ckpt_path,
                fp,
            )
            prog = Progress(Recorder(keep_summaries))
            if resume:
                _restore(ctx, prog)
            if progress:
                from tqdm.auto import tqdm

                ctx.bar = tqdm(total=num_steps, desc=algo.name, unit="step", initial=len(prog.history["threshold"]))
            try:
                _loop(ctx, prog)
            finally:
                if ctx.bar is not None:
                    ctx.bar.close()
        finally:
            if lock is not None:
                lock.release()
            if own_executor:
                ex.close()
        # A surrogate with a discrepancy samples theta and the discrepancy sds: its result's prior
        # is the augmented box (the simulator, the design and the fingerprint keep theta's).
        return assemble(ctx, prog, dtype, metadata, seed, getattr(algo, "augmented_prior", None) or prior)
