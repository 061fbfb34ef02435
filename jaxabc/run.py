"""The host driver: one loop for every algorithm and executor.

Each iteration derives its key from the seed and the iteration number alone
(``fold_in(key, iteration)``), asks the algorithm where to simulate, runs the simulations on the
executor, turns failures into ``+inf`` distances, updates the algorithm's state and writes a
checkpoint.  Because nothing else feeds the random stream, a run killed at any point and resumed
from its checkpoint gives exactly the result of the uninterrupted run, and the result does not
depend on the executor or the number of workers.
"""

from __future__ import annotations

import os
import pickle
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxabc import algorithms as _algorithms
from jaxabc.distances import get_distance
from jaxabc.errors import STATUS_NAMES, STATUS_OK, TooManyFailures
from jaxabc.executors import Executor, get_executor
from jaxabc.priors import Uniform
from jaxabc.results import ABCResult, versions

__all__ = ["CHECKPOINT_NAME", "run"]

CHECKPOINT_NAME = "checkpoint.pkl"
_MIN_FOR_FAILURE_CHECK = 20


def _validate_observed(observed: Any) -> np.ndarray:
    try:
        obs = np.asarray(observed, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"observed data must be a numeric array: {exc}") from None
    if obs.ndim == 0:
        obs = obs[None]
    if obs.size == 0:
        raise ValueError("observed data is empty: pass the measured summary vector or series")
    bad = ~np.isfinite(obs)
    if np.any(bad):
        raise ValueError(
            f"observed data contains {int(bad.sum())} NaN or infinite values (first at flat "
            f"index {int(np.flatnonzero(bad.ravel())[0])}): clean or drop them before calibrating"
        )
    return obs


def _cast_prior(prior: Uniform, dtype: Any) -> Uniform:
    if not isinstance(prior, Uniform):
        return prior
    out = Uniform.__new__(Uniform)
    out.__dict__.update(prior.__dict__)
    out.low, out.high = jnp.asarray(prior.low, dtype), jnp.asarray(prior.high, dtype)
    return out


def _shapes_compatible(simulated: tuple, observed: tuple, distance: Any) -> bool:
    if getattr(get_distance(distance), "compares_samples", False):
        return len(simulated) == len(observed) == 1
    return tuple(simulated) == tuple(observed)


def _check_shape(executor: Executor, simulate: Callable, prior: Uniform,
                 observed: np.ndarray, distance: Any) -> None:
    """Fail early, with a clear message, when a JAX simulator's output shape is wrong."""
    if executor.name != "vmap" or hasattr(simulate, "simulate_batch"):
        return
    try:
        out = jax.eval_shape(simulate, jax.random.key(0), jnp.zeros((prior.dim,), prior.low.dtype))
    except Exception as exc:
        raise TypeError(
            f"could not trace simulate(key, theta) with theta of shape ({prior.dim},): {exc}. "
            "A vmap executor needs a JAX-traceable simulator; use executor='serial' or "
            "'process_pool' for other code"
        ) from exc
    if not _shapes_compatible(tuple(out.shape), observed.shape, distance):
        raise ValueError(
            f"the simulator returns summaries of shape {tuple(out.shape)} but the observed data "
            f"has shape {observed.shape}: they must match"
        )


def _make_distance_fn(distance: Any, observed: np.ndarray, dtype: Any) -> Callable:
    dist = get_distance(distance)
    obs = jnp.asarray(observed, dtype)
    batched = jax.jit(jax.vmap(lambda s: dist(obs, s)))

    def compute(summaries: np.ndarray, ok: np.ndarray) -> np.ndarray:
        out = np.full(summaries.shape[0], np.inf)
        good = summaries[ok]
        if good.shape[0]:
            # Pad to a power of two so that varying batch sizes reuse a few compiled shapes.
            size = max(64, 1 << (good.shape[0] - 1).bit_length())
            padded = np.concatenate([good, np.repeat(good[:1], size - good.shape[0], axis=0)])
            d = np.asarray(batched(jnp.asarray(padded, dtype)), dtype=np.float64)[: good.shape[0]]
            out[ok] = np.where(np.isfinite(d), d, np.inf)
        return out

    return compute


def _build_algorithm(name: str, prior: Uniform, num_particles: int, options: dict):
    try:
        builder = _algorithms.BUILDERS[name]
    except KeyError:
        raise ValueError(
            f"unknown algorithm {name!r}: use one of {sorted(_algorithms.BUILDERS)}"
        ) from None
    try:
        return builder(prior, num_particles, **options)
    except TypeError as exc:
        raise TypeError(f"bad option for {name!r}: {exc}") from None


class _Recorder:
    """Accumulates the record of every simulation."""

    def __init__(self, keep_summaries: bool):
        self.keep_summaries = keep_summaries
        self.chunks: list[dict[str, Any]] = []

    def restore(self, chunks: list[dict[str, Any]]) -> None:
        self.chunks = chunks

    def add(self, iteration: int, thetas, batch, distances) -> None:
        self.chunks.append({
            "theta": np.asarray(thetas, np.float64),
            "summaries": np.asarray(batch.summaries) if self.keep_summaries else None,
            "distance": distances,
            "status": np.asarray(batch.status, np.int32),
            "wall_time": np.asarray(batch.wall_time),
            "cpu_time": (np.full(len(distances), np.nan) if batch.cpu_time is None
                         else np.asarray(batch.cpu_time, np.float64)),
            "worker": np.asarray(batch.worker, np.int32),
            "iteration": np.full(len(distances), iteration, np.int32),
            "reasons": list(batch.reasons),
        })

    def arrays(self) -> dict[str, Any]:
        if not self.chunks:
            return {}
        out: dict[str, Any] = {}
        for key in ("theta", "distance", "status", "wall_time", "worker", "iteration"):
            out[key] = np.concatenate([c[key] for c in self.chunks])
        # Checkpoints written before CPU times were recorded lack them: NaN there.
        out["cpu_time"] = np.concatenate([c.get("cpu_time", np.full(len(c["distance"]), np.nan))
                                          for c in self.chunks])
        if self.keep_summaries:
            shapes = {c["summaries"].shape[1:] for c in self.chunks}
            if len(shapes) == 1:
                out["summaries"] = np.concatenate([c["summaries"] for c in self.chunks])
        out["reasons"] = [r for c in self.chunks for r in c["reasons"]]
        return out

    def failures(self) -> tuple[int, int, list[str]]:
        total = sum(len(c["distance"]) for c in self.chunks)
        failed = sum(int(np.sum(c["status"] != STATUS_OK)) for c in self.chunks)
        examples: list[str] = []
        for c in self.chunks:
            for i in np.flatnonzero(c["status"] != STATUS_OK)[: 5 - len(examples)]:
                status = STATUS_NAMES.get(int(c["status"][i]), int(c["status"][i]))
                examples.append(f"theta={np.array2string(c['theta'][i], precision=4)}: {status}: "
                                f"{c['reasons'][i]}")
            if len(examples) >= 5:
                break
        return total, failed, examples


def run(
    algorithm: str,
    simulate: Callable,
    prior: Uniform,
    observed: Any,
    num_particles: int,
    num_steps: int | None = None,
    distance: str | Callable = "mean_abs",
    seed: int = 0,
    *,
    executor: str | Executor | None = None,
    final_threshold: float | None = None,
    max_simulations: int | None = None,
    max_wall_time: float | None = None,
    max_failure_fraction: float = 0.5,
    checkpoint_dir: str | Path | None = None,
    resume: bool = False,
    stop_after_iterations: int | None = None,
    keep_summaries: bool = True,
    progress: bool = False,
    dtype: str = "float32",
    metadata: dict | None = None,
    **algorithm_options: Any,
) -> ABCResult:
    """Calibrate ``simulate`` against ``observed`` with an ABC algorithm.

    Parameters
    ----------
    algorithm : {"apmcabc", "abcsubsim", "pmcabc", "rejection"}
    simulate : callable ``(key, theta) -> summaries``
        One parameter vector in, a fixed-shape summary array out.  A JAX function for the
        ``"vmap"`` executor; any picklable callable for ``"process_pool"`` / ``"mpi"`` (it then
        gets the key as raw ``uint32[2]`` data; see :func:`jaxabc.seeding.seed_from_key`).
        Failures: raise :class:`jaxabc.SimulationFailure` or return NaN.
    prior : Uniform
    observed : array_like
        The measured summaries, same shape as ``simulate``'s output.
    num_particles : int
        Population size ``N``.
    num_steps : int, optional
        Maximum number of ABC steps (generations / levels), the initial prior sample included
        (ABCpy's ``steps``).  Default: no limit (another rule must stop the run).
    distance : str or callable
        ``"mean_abs"`` (the paper's water distance), ``"euclidean"``, ``"kl"`` (the helium
        distance) or ``distance(observed, simulated) -> scalar``.
    seed : int
        The run's only source of randomness.
    executor : str or Executor
        ``"vmap"`` (default), ``"serial"``, ``"process_pool"``, ``"mpi"``, ``"mpi_static"``, or
        an executor object.
    final_threshold : float, optional
        Stop once a generation's threshold is at or below this.
    max_simulations : int, optional
        Simulation budget: stop before an iteration that would exceed it.
    max_wall_time : float, optional
        Seconds; checked after each iteration.
    max_failure_fraction : float
        Stop with :class:`jaxabc.TooManyFailures` when more than this fraction of simulations
        (after the first 20) failed.
    checkpoint_dir : path, optional
        Write ``checkpoint.pkl`` there after every iteration (atomically).
    resume : bool
        Continue from the checkpoint in ``checkpoint_dir``; the result equals that of the
        uninterrupted run.
    stop_after_iterations : int, optional
        Stop after this many iterations (for tests and for splitting long runs).
    keep_summaries : bool
        Keep every simulation's summaries in the record.
    progress : bool
        Show a progress bar with threshold, acceptance and ETA.
    dtype : {"float32", "float64"}
        Working precision of the inference kernels; ``"float64"`` turns on ``jax_enable_x64``.
    metadata : dict, optional
        Stored in the result.
    **algorithm_options
        Passed to the algorithm: APMCABC ``alpha``, ``acceptance_cutoff``,
        ``covariance_factor``, ``weights``; ABCsubsim ``p0``, ``acceptance_floor``; PMC-ABC
        ``thresholds``, ``quantile``; rejection ``threshold`` or ``quantile``.

    Returns
    -------
    ABCResult
    """
    t_start = time.perf_counter()
    if dtype not in ("float32", "float64"):
        raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype!r}")
    if dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    jdtype = jnp.float64 if dtype == "float64" else jnp.float32
    if not isinstance(num_particles, int | np.integer) or num_particles < 1:
        raise ValueError(f"num_particles must be a positive integer, got {num_particles!r}")
    if num_steps is not None and num_steps < 1:
        raise ValueError(f"num_steps must be at least 1, got {num_steps}")
    if not 0.0 < max_failure_fraction <= 1.0:
        raise ValueError(f"max_failure_fraction must lie in (0, 1], got {max_failure_fraction}")
    if not callable(simulate):
        raise TypeError("simulate must be a callable simulate(key, theta) -> summaries")
    if not hasattr(prior, "sample") or not hasattr(prior, "low"):
        raise TypeError("prior must be a jaxabc prior such as jaxabc.Uniform(low, high, names)")
    obs = _validate_observed(observed)
    prior = _cast_prior(prior, jdtype)
    if algorithm == "abcsubsim" and final_threshold is not None:
        algorithm_options.setdefault("final_threshold", final_threshold)
    algo = _build_algorithm(algorithm, prior, int(num_particles), algorithm_options)
    if num_steps is None and final_threshold is None and max_simulations is None \
            and max_wall_time is None and algorithm in ("pmcabc", "abcsubsim") \
            and not algorithm_options.get("acceptance_floor"):
        raise ValueError(
            f"{algorithm} needs a stopping rule: give num_steps, final_threshold, "
            "max_simulations or max_wall_time"
        )
    own_executor = not hasattr(executor, "map")
    ex = get_executor(executor)
    _check_shape(ex, simulate, prior, obs, distance)
    distances_of = _make_distance_fn(distance, obs, jdtype)

    jit_initial = jax.jit(algo.initial_proposal)
    jit_init = jax.jit(algo.init)
    jit_propose = jax.jit(algo.propose)
    jit_update = jax.jit(algo.update)
    jit_posterior = jax.jit(algo.posterior)

    root = jax.random.key(seed)
    ckpt_path = Path(checkpoint_dir) / CHECKPOINT_NAME if checkpoint_dir is not None else None
    recorder = _Recorder(keep_summaries)
    history: dict[str, list] = {"threshold": [], "sims": [], "acceptance": [], "ess": [], "wall": []}
    state = None
    iteration = 0
    num_sims = 0
    sims_this_generation = 0
    last_posterior = None
    last_level = 0
    stop_reason = ""
    run_id = {"algorithm": algorithm, "settings": algo.settings, "seed": seed,
              "num_particles": int(num_particles), "observed_shape": obs.shape}

    if resume:
        if ckpt_path is None:
            raise ValueError("resume=True needs checkpoint_dir= (the folder of the checkpoint)")
        if not ckpt_path.exists():
            raise FileNotFoundError(
                f"no checkpoint at {ckpt_path}: run without resume=True to start afresh"
            )
        with open(ckpt_path, "rb") as fh:
            ck = pickle.load(fh)
        if ck["run_id"] != run_id:
            raise ValueError(
                f"the checkpoint in {checkpoint_dir} belongs to a different run "
                f"({ck['run_id']}); use another folder or the same settings"
            )
        state = jax.tree.map(jnp.asarray, ck["state"])
        iteration, num_sims = ck["iteration"], ck["num_sims"]
        sims_this_generation = ck["sims_this_generation"]
        history = ck["history"]
        recorder.restore(ck["records"])
        last_posterior, last_level = ck["last_posterior"], ck.get("last_level", 0)
        stop_reason = ck.get("stop_reason", "")

    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=num_steps, desc=algorithm, unit="step", initial=len(history["threshold"]))

    try:
        while not stop_reason:
            key = jax.random.fold_in(root, iteration)
            k_prop, k_sim, k_upd = jax.random.split(key, 3)
            proposal = jit_initial(k_prop) if state is None else jit_propose(k_prop, state)
            if not bool(proposal.ok):
                raise RuntimeError(
                    f"{algorithm}: the truncated perturbation kernel could not reach the prior's "
                    "support from some particles (no draw inside the box in 10,000 tries). The "
                    "posterior is piled against a prior bound: widen the prior there"
                )
            active = np.asarray(proposal.active)
            thetas = np.asarray(proposal.thetas)
            n_active = int(active.sum())
            if max_simulations is not None and state is not None \
                    and num_sims + n_active > max_simulations:
                stop_reason = f"simulation budget {max_simulations} reached"
                break
            sim_keys = np.asarray(jax.random.key_data(jax.random.split(k_sim, thetas.shape[0])))
            distances = np.full(thetas.shape[0], np.inf)
            if n_active:
                batch = ex.map(simulate, sim_keys[active], thetas[active])
                if np.any(batch.status == STATUS_OK) and not _shapes_compatible(
                        batch.summaries.shape[1:], obs.shape, distance):
                    raise ValueError(
                        f"the simulator returned summaries of shape {batch.summaries.shape[1:]} "
                        f"but the observed data has shape {obs.shape}: they must match"
                    )
                ok = batch.status == STATUS_OK
                distances[active] = distances_of(batch.summaries, ok)
                recorder.add(iteration, thetas[active], batch, distances[active])
                num_sims += n_active
                sims_this_generation += n_active
                total, failed, examples = recorder.failures()
                if total >= _MIN_FOR_FAILURE_CHECK and failed > max_failure_fraction * total:
                    raise TooManyFailures(
                        f"{failed} of {total} simulations failed (limit "
                        f"{max_failure_fraction:.0%}); first failures:\n  " + "\n  ".join(examples)
                    )
            d = jnp.asarray(distances, jdtype)
            if state is None:
                state, info = jit_init(k_upd, proposal, d)
            else:
                state, info = jit_update(k_upd, state, proposal, d)
            iteration += 1
            if bool(info.generation_done):
                particles, log_w = jit_posterior(state)
                last_posterior = (np.asarray(particles), np.asarray(log_w),
                                  _posterior_distances(state))
                last_level = int(getattr(state, "level", 0))
                history["threshold"].append(float(info.threshold))
                history["sims"].append(sims_this_generation)
                history["acceptance"].append(float(info.acceptance_rate))
                history["ess"].append(float(info.ess))
                history["wall"].append(time.perf_counter() - t_start)
                sims_this_generation = 0
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix(threshold=f"{float(info.threshold):.4g}",
                                    acceptance=f"{float(info.acceptance_rate):.3f}", sims=num_sims)
                if bool(info.stop):
                    stop_reason = _algorithm_stop_reason(algorithm, algo.settings, info)
                elif num_steps is not None and len(history["threshold"]) >= num_steps:
                    stop_reason = f"{num_steps} steps done"
                elif final_threshold is not None and float(info.threshold) <= final_threshold:
                    stop_reason = f"final threshold {final_threshold} reached"
            if not stop_reason and max_wall_time is not None \
                    and time.perf_counter() - t_start > max_wall_time and last_posterior is not None:
                stop_reason = f"wall time {max_wall_time} s reached"
            if ckpt_path is not None:
                _write_checkpoint(ckpt_path, {
                    "run_id": run_id, "state": jax.tree.map(np.asarray, state),
                    "iteration": iteration, "num_sims": num_sims,
                    "sims_this_generation": sims_this_generation, "history": history,
                    "records": recorder.chunks, "last_posterior": last_posterior,
                    "last_level": last_level, "stop_reason": stop_reason,
                })
            if stop_after_iterations is not None and iteration >= stop_after_iterations \
                    and not stop_reason:
                stop_reason = f"stopped after {iteration} iterations (resumable)"
    finally:
        if bar is not None:
            bar.close()
        if own_executor:
            ex.close()

    particles, log_w, dist = last_posterior
    keep = np.isfinite(log_w)
    w = np.exp(log_w[keep] - np.max(log_w[keep]))
    meta = {"versions": versions(), "executor": ex.name,
            "distance": distance if isinstance(distance, str) else getattr(distance, "__name__", "custom"),
            "dtype": dtype, "observed": obs.tolist() if obs.size <= 10_000 else None,
            # Seconds since this process started the run, at the end of each generation (after
            # a resume, counted from the resume).
            "generation_wall_times": history["wall"]}
    meta.update(metadata or {})
    log_ev = None
    if algorithm == "abcsubsim":
        from jaxabc.algorithms.subsim import log_evidence

        log_ev = log_evidence(last_level, algo.settings["p0"])
    return ABCResult(
        particles=particles[keep].astype(np.float64), weights=w / w.sum(),
        distances=dist[keep] if dist is not None else np.full(int(keep.sum()), np.nan),
        thresholds=np.asarray(history["threshold"]), simulations_per_step=np.asarray(history["sims"]),
        acceptance_rates=np.asarray(history["acceptance"]), ess=np.asarray(history["ess"]),
        num_simulations=num_sims, algorithm=algorithm, settings=algo.settings, prior=prior,
        seed=seed, stop_reason=stop_reason, wall_time=time.perf_counter() - t_start,
        log_evidence=log_ev, records=recorder.arrays(), metadata=meta,
    )


def _posterior_distances(state: Any) -> np.ndarray:
    # Each algorithm's state keeps its distances aligned with its posterior particles.
    return np.asarray(state.distances)


def _algorithm_stop_reason(algorithm: str, settings: dict, info: Any) -> str:
    if algorithm == "apmcabc":
        return (f"acceptance {float(info.acceptance_rate):.4f} < cutoff "
                f"{settings['acceptance_cutoff']}")
    if algorithm == "abcsubsim":
        from jaxabc.algorithms.subsim import stop_reason

        return stop_reason(settings, info)
    return "done"


def _write_checkpoint(path: Path, payload: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        pickle.dump(payload, fh, protocol=pickle.HIGHEST_PROTOCOL)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


