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

import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc import checkpoint
from jaxabc.driver.assemble import assemble
from jaxabc.driver.checks import check_first_distances, check_first_iteration_budget, check_shape, shapes_compatible
from jaxabc.driver.context import (
    Compiled,
    Context,
    Problem,
    Progress,
    Recorder,
    mark_bad_distances,
    open_executor,
    posterior_distances,
)
from jaxabc.driver.options import RunOptions
from jaxabc.errors import STATUS_OK, TooManyFailures
from jaxabc.results import ABCResult

__all__ = ["run_host"]

_MIN_FOR_FAILURE_CHECK = 20


def run_host(compiled: Compiled, problem: Problem, options: RunOptions, t_start: float) -> ABCResult:
    """Run ``compiled`` on ``problem`` with an executor, checkpointing as ``options`` ask.

    Call it in the run's precision (:func:`~jaxabc.driver.checks.precision`), with ``problem``
    and ``options`` checked; ``t_start`` is when the run started (``perf_counter``).

    Raises
    ------
    TooManyFailures, NoPosterior, jaxabc.checkpoint.CheckpointError, FileExistsError
    ValueError, TypeError
        A simulator whose output does not fit the observed data, or a bad distance.
    """
    checkpointing = options.checkpointing
    with open_executor(options.execution.executor, problem.observed, problem.distance) as executor:
        check_shape(executor, problem.simulate, problem.prior, problem.observed, problem.distance)
        checkpointing.require_fingerprintable(problem.simulate, problem.distance)
        # One run per folder; and only now, with every input checked, may overwrite=True
        # delete an old checkpoint.
        with checkpointing.locked():
            ckpt_path = checkpointing.prepare()
            ctx = Context.create(compiled, problem, options, executor, ckpt_path, t_start)
            prog = Progress(Recorder(options.execution.keep_summaries))
            if checkpointing.resume:
                _restore(ctx, prog)
            _loop_with_progress_bar(ctx, prog)
    # A surrogate with a discrepancy samples theta and the discrepancy sds: its result's prior
    # is the augmented box (the simulator, the design and the fingerprint keep theta's).
    return assemble(ctx, prog, getattr(compiled.algorithm, "augmented_prior", None) or problem.prior)


# ----------------------------------------------------------------------------- the loop


def _loop_with_progress_bar(ctx: Context, prog: Progress) -> None:
    if ctx.options.execution.progress:
        from tqdm.auto import tqdm

        ctx.bar = tqdm(
            total=ctx.options.stopping.num_steps,
            desc=ctx.compiled.algorithm.name,
            unit="step",
            initial=len(prog.history["threshold"]),
        )
    try:
        _loop(ctx, prog)
    finally:
        if ctx.bar is not None:
            ctx.bar.close()


def _loop(ctx: Context, prog: Progress) -> None:
    stopping = ctx.options.stopping
    while not prog.stop_reason:
        info = _step(ctx, prog)
        if info is None:
            break
        if bool(info.generation_done):
            _end_generation(ctx, prog, info)
        if (
            not prog.stop_reason
            and stopping.max_wall_time is not None
            and time.perf_counter() - ctx.t_start > stopping.max_wall_time
        ):
            prog.stop_reason = f"wall time {stopping.max_wall_time} s reached"
        if ctx.ckpt_path is not None:
            _save(ctx, prog)
        if stopping.stop_after is not None and prog.iteration >= stopping.stop_after and not prog.stop_reason:
            prog.stop_reason = f"stopped after {prog.iteration} iterations (resumable)"


def _step(ctx: Context, prog: Progress) -> Any:
    """One iteration: propose, simulate, update.  Returns the algorithm's Info, or None when the
    simulation budget stopped the run before simulating."""
    c = ctx.compiled
    budget = ctx.options.stopping.max_simulations
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
        check_first_iteration_budget(int(active.sum()), budget, c.algorithm.name)
    if budget is not None and prog.state is not None and prog.num_sims + int(active.sum()) > budget:
        prog.stop_reason = f"simulation budget {budget} reached"
        return None
    distances, summaries = _simulate_batch(ctx, prog, k_sim, thetas, active)
    if prog.state is None:
        # Prior draws: a distance that goes negative or cannot rank them shows it here.
        check_first_distances(distances)
    jdtype = ctx.options.execution.jdtype
    d = np.asarray(distances) if c.algorithm.host else jnp.asarray(distances, jdtype)
    extra = () if summaries is None else (summaries if c.algorithm.host else jnp.asarray(summaries),)
    if prog.state is None:
        prog.state, info = c.init(k_upd, proposal, d, *extra)
    else:
        prog.state, info = c.update(k_upd, prog.state, proposal, d, *extra)
    prog.iteration += 1
    return info


def _simulate_batch(
    ctx: Context, prog: Progress, k_sim: jax.Array, thetas: np.ndarray, active: np.ndarray
) -> tuple[np.ndarray, np.ndarray | None]:
    """Simulate the active slots; distances (m,) and, if the algorithm wants them, summaries."""
    observed = ctx.problem.observed
    m = thetas.shape[0]
    distances = np.full(m, np.inf)
    summaries = None
    if ctx.compiled.algorithm.uses_summaries:
        summaries = np.full((m, *observed.shape), np.nan)
    if not active.any():
        return distances, summaries
    sim_keys = np.asarray(jax.random.key_data(jax.random.split(k_sim, m)))
    batch = ctx.executor.map(ctx.problem.simulate, sim_keys[active], thetas[active])
    ok = np.asarray(batch.status) == STATUS_OK
    if ok.any() and not shapes_compatible(batch.summaries.shape[1:], observed.shape, ctx.problem.distance):
        raise ValueError(
            f"the simulator returned summaries of shape {batch.summaries.shape[1:]} "
            f"but the observed data has shape {observed.shape}: they must match"
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
    _check_failures(prog.recorder, ctx.options.execution.max_failure_fraction)
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
    stopping = ctx.options.stopping
    if bool(info.stop):
        prog.stop_reason = algo.stop_reason(algo.settings, info)
    elif stopping.num_steps is not None and len(h["threshold"]) >= stopping.num_steps:
        prog.stop_reason = f"{stopping.num_steps} steps done"
    elif stopping.final_threshold is not None and float(info.threshold) <= stopping.final_threshold:
        prog.stop_reason = f"final threshold {stopping.final_threshold} reached"


# ----------------------------------------------------------------------------- checkpoints


def _save(ctx: Context, prog: Progress) -> None:
    assert ctx.ckpt_path is not None, "only called when checkpointing"
    checkpoint.save(
        ctx.ckpt_path,
        checkpoint.Checkpoint(
            fingerprint=ctx.fingerprint,
            state_leaves=checkpoint.flatten_state(prog.state),
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
    args = [key, proposal, jax.ShapeDtypeStruct((m,), ctx.options.execution.jdtype)]
    if algo.uses_summaries:
        args.append(jax.ShapeDtypeStruct((m, *ctx.problem.observed.shape), jnp.result_type(float)))
    return jax.eval_shape(algo.init, *args)[0]


def _restore(ctx: Context, prog: Progress) -> None:
    assert ctx.ckpt_path is not None, "only called when resuming from a checkpoint"
    ck = checkpoint.load(ctx.ckpt_path)
    checkpoint.check_fingerprint(ck.fingerprint, ctx.fingerprint, ctx.ckpt_path)
    algo = ctx.compiled.algorithm
    if algo.restore_state is not None:
        prog.state = algo.restore_state(ck.state_leaves)
    else:
        prog.state = checkpoint.restore_state(ck.state_leaves, _state_template(ctx), ctx.ckpt_path)
    c = ck.counters
    prog.iteration, prog.num_sims = int(c["iteration"]), int(c["num_sims"])
    prog.sims_this_generation = int(c["sims_this_generation"])
    prog.history = ck.history
    prog.stop_reason = ctx.options.stopping.reopen(c["stop_reason"], ck.history, ctx.ckpt_path)
    prog.recorder.chunks = ck.records
    prog.last_posterior = ck.last_posterior
