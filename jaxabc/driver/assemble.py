"""Result assembly: the driver's final state becomes an :class:`~jaxabc.results.ABCResult`."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from jaxabc.checkpoint import display_name
from jaxabc.driver.context import Context, Progress, posterior_distances
from jaxabc.errors import NoPosterior
from jaxabc.results import ABCResult, versions

__all__ = ["assemble", "final_posterior"]


def final_posterior(ctx: Context, prog: Progress) -> tuple[tuple, bool]:
    """The last completed generation's posterior, or (flagged incomplete) the accepted
    particles of the generation under way when the run stopped before completing one."""
    if prog.last_posterior is not None:
        return prog.last_posterior, False
    if prog.state is not None:
        particles, log_w = ctx.compiled.posterior(prog.state)
        log_w = np.asarray(log_w)
        if np.any(np.isfinite(log_w)):
            return (np.asarray(particles), log_w, posterior_distances(prog.state, len(log_w))), True
    raise NoPosterior(
        f"the run stopped ({prog.stop_reason}) after {prog.num_sims} simulations without "
        "accepting any particle: raise max_simulations / max_wall_time or loosen the threshold"
    )


def assemble(ctx: Context, prog: Progress, prior: Any) -> ABCResult:
    """The result of a finished host run; ``prior`` is the one to report (the problem's, or a
    surrogate's augmented box)."""
    (particles, log_w, dist), incomplete = final_posterior(ctx, prog)
    algo = ctx.compiled.algorithm
    stop_reason = prog.stop_reason
    keep = np.isfinite(log_w)
    if incomplete:
        stop_reason += (
            f"; incomplete: the first generation was not completed, the posterior "
            f"holds the {int(keep.sum())} particles accepted so far"
        )
    w = np.exp(log_w[keep] - np.max(log_w[keep]))
    distance, observed = ctx.problem.distance, ctx.problem.observed
    meta: dict[str, Any] = {
        "versions": versions(),
        "executor": ctx.executor.name,
        "distance": distance if isinstance(distance, str) else getattr(distance, "__name__", "custom"),
        "dtype": ctx.options.execution.dtype,
        "observed": observed.tolist() if observed.size <= 10_000 else None,
        # Seconds since this process started the run, at the end of each generation (after a
        # resume, counted from the resume).
        "generation_wall_times": prog.history["wall"],
        "simulator": display_name(ctx.fingerprint["simulator"]),
        "incomplete": incomplete,
    }
    extras = dict(algo.finalize(prog.state)) if prog.state is not None else {}
    # An algorithm may put a verdict in front of the stop reason (the surrogate's misfit).
    stop_reason = extras.pop("stop_reason_prefix", "") + stop_reason
    log_ev = extras.pop("log_evidence", None)
    diagnostics = extras.pop("diagnostics", None) or {}
    if "distance_weights" in prog.history:
        diagnostics = {**diagnostics, "distance_weights": prog.history["distance_weights"]}
    final_ess = extras.pop("ess", None)
    meta.update(extras)
    meta.update(ctx.options.metadata or {})
    h = prog.history
    ess = np.asarray(h["ess"], np.float64)
    if final_ess is not None and ess.size:
        # The algorithm's own end-of-run estimate (e.g. ABCsubsim's chain ESS) bounds the last.
        ess[-1] = min(ess[-1], float(final_ess))
    return ABCResult(
        particles=particles[keep].astype(np.float64),
        weights=w / w.sum(),
        distances=dist[keep] if dist is not None else np.full(int(keep.sum()), np.nan),
        thresholds=np.asarray(h["threshold"]),
        simulations_per_step=np.asarray(h["sims"]),
        acceptance_rates=np.asarray(h["acceptance"]),
        ess=ess,
        num_simulations=prog.num_sims,
        algorithm=algo.name,
        settings=algo.settings,
        prior=prior,
        seed=ctx.options.seed,
        stop_reason=stop_reason,
        wall_time=time.perf_counter() - ctx.t_start,
        log_evidence=None if log_ev is None else float(log_ev),
        records=prog.recorder.arrays(),
        metadata=meta,
        diagnostics=diagnostics,
    )
