"""Speedup of APMCABC and ABCsubsim under dynamic and static MPI allocation (paper Figure 4).

Dutta, Brotzakis & Mira (2018) show that APMCABC scales better than ABCsubsim with the number of
cores ``n``, because each APMCABC step is ``N - ceil(alpha N)`` independent simulations, while each
ABCsubsim level is ``1 / P0 - 1`` *sequential* rounds of ``N P0`` Markov-chain moves, and that
dynamic allocation copes with simulation times that vary with the parameters.  This machine has
two cores, so the study has three parts, each labelled in the JSON and the figure:

(a) ``model``: a discrete-event model of both algorithms for ``n`` up to 1024.  Every step (or
    chain round) is a batch of independent tasks followed by a barrier.  Dynamic allocation is
    greedy list scheduling in task order (a free worker takes the next task, as
    ``jaxabc.executors.mpi.MPIExecutor(allocation="dynamic")`` does); static allocation gives each worker
    one contiguous chunk of equal size (``jaxabc.executors.mpi.chunk_indices``).  Task durations are drawn
    (with replacement, common random numbers across ``n``) from the measured water imbalance
    distribution in ``benchmarks/results/imbalance.json``; with ``--distribution lognormal``
    (or when that file is missing) from the lognormal fitted there (or, without a file, the
    documented fallback ``LOGNORMAL_FALLBACK``).
(b) ``ranks``: real Open MPI ranks (oversubscribed on this machine) running the real
    ``MPIExecutor`` with tasks that ``time.sleep`` for durations drawn from the same
    distribution, scaled to a ``--sleep-mean`` of tens of milliseconds, so the real scheduler is
    timed without the CPU limit; the model, given the same durations plus a per-task overhead
    fitted at ``n = 1``, predicts those makespans (validation).
(c) ``real``: actual simulations at ``n = 1`` and ``2`` ranks: GROMACS TIP4P quick preset
    (``md.water.make_simulator("quick")``) at prior draws, through ``MPIExecutor`` (so each rank
    runs one single-threaded ``gmx mdrun``).

Reported: speedup ``S(n) = T(1) / T(n)``, parallel efficiency ``S(n) / n`` and the makespan
relative to the lower bound ``max(total work / n, longest task)`` (summed over the barriers of a
run), and relative to the pigeonhole bound of :func:`tight_lower_bound`, which every schedule of
indivisible tasks obeys.  ``n`` runs over powers of two and, for each algorithm, over the range of
one to four tasks per worker (:func:`n_grid_for`), where balancing is hardest.  Targets from
issue 4: dynamic makespan within 1.1x of the lower bound for the water time distribution at every
``n``; APMCABC efficiency >= 0.8 up to ``n = N - ceil(alpha N)``; ABCsubsim lower.  They are
evaluated, not tuned for; the JSON lists the ``n`` where no schedule can meet the first.

Usage::

    nice -n 5 python -m benchmarks.speedup                    # all parts, about 5-8 minutes
    python -m benchmarks.speedup --parts model                # seconds
    python -m benchmarks.speedup --ranks 1 2 4 8 16 32 64 --sleep-mean 0.05
    python -m benchmarks.speedup --parts real --real-num 16

Writes ``benchmarks/results/speedup.json`` and ``benchmarks/results/speedup.png`` (drawn by
``paper_figures/figure4_speedup.py``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import runpy
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from jaxabc.executors.scheduling import (  # noqa: E402  (after the path set-up: run as a script)
    dynamic_makespan,
    longest_predicted_first,
    lower_bound,
    static_makespan,
    tight_lower_bound,
)

RESULTS = ROOT / "benchmarks" / "results"
N_GRID = [1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024]
#: Besides N_GRID, every study also evaluates n = m / q for each batch size m: a few tasks per
#: worker is where a batch is hardest to balance (between one and three tasks per worker, the
#: longest tasks pile up), and powers of two alone skip most of that range for large m.
TASKS_PER_WORKER = (1.1, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5, 3.0, 4.0)


def n_grid_for(sizes: list[int], base: list[int] = N_GRID) -> list[int]:
    """``base`` plus ``m`` and ``round(m / q)`` for the largest batch size ``m`` of a run."""
    m = max(sizes[1:] or sizes)
    return sorted(set(base) | {m} | {max(1, round(m / q)) for q in TASKS_PER_WORKER})


#: Used only when imbalance.json is missing: log t ~ N(mu, sigma^2) in seconds, a guess of the
#: order of the water quick preset (median ~10 s, CV ~0.5); the JSON records which was used.
LOGNORMAL_FALLBACK = {"mu": math.log(10.0), "sigma": 0.5}
#: The paper's water prior (sigma_OW nm, epsilon_OW kJ/mol), as in benchmarks/imbalance.py.
WATER_PRIOR = ((0.281, 0.2), (0.53, 0.9))
MPI_ENV = {
    "OMPI_ALLOW_RUN_AS_ROOT": "1",
    "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
    "OMPI_MCA_rmaps_base_oversubscribe": "1",
    "JAX_PLATFORMS": "cpu",
}


# ---------------------------------------------------------------------------------------------
# Task durations


def load_distribution(path: Path, system: str, kind: str) -> dict:
    """The duration distribution: empirical times (seconds) or a lognormal, with its source."""
    if path.exists():
        data = json.loads(path.read_text())
        rec = data.get("systems", {}).get(system)
        if rec is not None:
            times = np.asarray(rec["wall_time_s"], np.float64)
            st = rec["stats_all"]
            out = {
                "system": system,
                "source": f"{path.relative_to(ROOT)} [{system}], {times.size} measured times "
                f"(failures included), {rec['how']}",
                "times": times.tolist(),
                "lognormal": {"mu": st["lognormal_mu"], "sigma": st["lognormal_sigma"]},
                "stats": st,
            }
            if rec.get("theta") is not None:
                out["predicted"] = loo_predictions(np.asarray(rec["theta"]), times).tolist()
                out["prediction_quality"] = prediction_quality(times, np.asarray(out["predicted"]))
            out["kind"] = kind
            return out
    return {
        "system": system,
        "kind": "lognormal",
        "times": None,
        "lognormal": LOGNORMAL_FALLBACK,
        "source": f"{path} has no {system!r} entry: documented fallback LOGNORMAL_FALLBACK",
    }


def loo_predictions(theta: np.ndarray, times: np.ndarray, k: int = 5) -> np.ndarray:
    """Leave-one-out prediction of each task's duration from the others' (theta, time).

    The same k-nearest-neighbour regression that ``ProcessPoolExecutor(order="longest_first")``
    and ``MPIExecutor(order="longest_first")`` use (:class:`jaxabc.executors.scheduling.NearestNeighbourCost`),
    so the model's "longest predicted first" is as good as the executors' and no better.
    """
    from jaxabc.executors.scheduling import NearestNeighbourCost

    theta = np.asarray(theta, np.float64).reshape(len(times), -1)
    out = np.empty(len(times))
    for i in range(len(times)):
        keep = np.arange(len(times)) != i
        model = NearestNeighbourCost(k=k, min_history=1)
        model.observe(theta[keep], times[keep])
        out[i] = model.predict(theta[i : i + 1])[0]
    return out


def prediction_quality(times: np.ndarray, predicted: np.ndarray) -> dict:
    """How well the leave-one-out predictions order the tasks."""
    from scipy.stats import spearmanr

    err = np.log(predicted) - np.log(np.maximum(times, 1e-3))
    return {
        "spearman": float(spearmanr(times, predicted).statistic),
        "log_error_sd": float(err.std()),
        "count": int(times.size),
    }


def records_distribution(path: Path, kind: str) -> dict:
    """Durations from a saved ABC run's records (every simulation's theta and time): a result
    (``.npz``) or a run's checkpoint folder (``checkpoint.npz``, for a run still going).

    A task's duration is :func:`jaxabc.executors.task_durations`: its CPU time where the run
    recorded one (what the task costs on a core of its own, whatever else shared the machine
    while it was measured), its wall time otherwise (runs recorded before CPU times were).
    """
    import jaxabc
    from jaxabc.checkpoint import CHECKPOINT_NAME, load_records

    if path.is_dir() or path.name == CHECKPOINT_NAME:
        rec = load_records(path / CHECKPOINT_NAME if path.is_dir() else path)
        executor = "see the run's log (checkpoint)"
    else:
        res = jaxabc.load(path)
        rec, executor = res.records, res.metadata.get("executor")
    from jaxabc.executors import task_durations

    cpu = rec.get("cpu_time")
    measure = "wall time" if cpu is None or not np.any(np.isfinite(cpu)) else "CPU time (wall where it was idle)"
    times = task_durations(rec["wall_time"], None if measure == "wall time" else cpu)
    theta = np.asarray(rec["theta"], np.float64)
    keep = np.isfinite(times) & (times > 0)
    times, theta = times[keep], theta[keep]
    pred = loo_predictions(theta, times)
    ln = np.log(times)
    failed = float(np.mean(np.asarray(rec["status"])[keep] != 0))
    return {
        "system": "records",
        "kind": kind,
        "times": times.tolist(),
        "predicted": pred.tolist(),
        "prediction_quality": prediction_quality(times, pred),
        "lognormal": {"mu": float(ln.mean()), "sigma": float(ln.std())},
        "measure": measure,
        "source": f"{path.name}: {times.size} simulations of an ABC run (failures included: {failed:.0%}), "
        f"executor {executor}, durations = {measure}",
    }


def draw_durations(dist: dict, rng: np.random.Generator, size: int) -> np.ndarray:
    """``size`` tasks as rows ``(duration s, predicted duration s)`` drawn from ``dist``.

    Empirical distributions resample measured ``(time, leave-one-out prediction)`` pairs; without
    predictions (lognormal), the prediction is the duration itself (an oracle, labelled so).
    """
    if dist["kind"] == "empirical":
        idx = rng.integers(0, len(dist["times"]), size=size)
        times = np.asarray(dist["times"])[idx]
        pred = np.asarray(dist["predicted"])[idx] if dist.get("predicted") is not None else times
        return np.stack([times, pred], axis=1)
    ln = dist["lognormal"]
    times = rng.lognormal(ln["mu"], ln["sigma"], size=size)
    return np.stack([times, times], axis=1)


# ---------------------------------------------------------------------------------------------
# Algorithms as sequences of barrier-separated batches of independent simulations


def apmcabc_batches(num_particles: int, alpha: float, steps: int) -> list[int]:
    """Batch sizes of an APMCABC run: ``N`` prior draws, then ``N - ceil(alpha N)`` per step."""
    return [num_particles] + [num_particles - math.ceil(alpha * num_particles)] * (steps - 1)


def abcsubsim_batches(num_particles: int, p0: float, levels: int) -> list[int]:
    """Batch sizes of an ABCsubsim run: ``N`` prior draws, then per level ``1/P0 - 1`` rounds of
    ``N P0`` chain moves, one after the other (a chain's next state needs its previous one)."""
    chains = round(num_particles * p0)
    rounds = round(1.0 / p0) - 1
    return [num_particles] + [chains] * (rounds * (levels - 1))


# ---------------------------------------------------------------------------------------------
# Schedulers (makespan of one batch on n identical workers): the maths lives in jaxabc.executors.scheduling.

#: Timed on real ranks (the oracle order is a bound, not something an executor can do).
RANK_ALLOCATIONS = ("dynamic", "dynamic_longest_first", "static")
#: Allocations over batches of rows (duration, predicted duration).
MAKESPAN = {
    "dynamic": lambda b, n, c=0.0: dynamic_makespan(b[:, 0], n, c),
    "dynamic_longest_first": lambda b, n, c=0.0: dynamic_makespan(longest_predicted_first(b[:, 0], b[:, 1]), n, c),
    "dynamic_lpt_oracle": lambda b, n, c=0.0: dynamic_makespan(np.sort(b[:, 0])[::-1], n, c),
    "static": lambda b, n, c=0.0: static_makespan(b[:, 0], n, c),
}
ALLOCATION_HOW = {
    "dynamic": "a free worker takes the next task, tasks in the order the algorithm produced them",
    "dynamic_longest_first": "the same, tasks queued longest *predicted* first (k-NN on the parameters, "
    "leave-one-out on measured records: what order='longest_first' does)",
    "dynamic_lpt_oracle": "the same, tasks queued by their true duration (LPT with perfect foresight: a bound)",
    "static": "equal contiguous chunks, one per worker, fixed up front",
}


def run_time(
    batches: list[np.ndarray], n: int, allocation: str, overhead: float = 0.0, barrier_seconds: float = 0.0
) -> float:
    """Wall time of a run: its batches (rows: duration, prediction) one after another, each ended
    by a barrier."""
    return sum(MAKESPAN[allocation](np.asarray(b).reshape(-1, 2), n, overhead) + barrier_seconds for b in batches)


# ---------------------------------------------------------------------------------------------
# (a) the model


def model_study(
    dist: dict, algorithms: dict[str, list[int]], n_grid: list[int], reps: int, seed: int, barrier_seconds: float
) -> dict:
    """Speedup, efficiency and makespan / lower bound of each algorithm, allocation and n."""
    rng = np.random.default_rng(seed)
    out = {}
    for name, sizes in algorithms.items():
        grid = n_grid_for(sizes, n_grid)
        res = {
            alloc: {
                "T": np.zeros((reps, len(grid))),
                "LB": np.zeros((reps, len(grid))),
                "LB_tight": np.zeros((reps, len(grid))),
                "batch_ratio_max": np.zeros((reps, len(grid))),
                "batch_ratio_tight_max": np.zeros((reps, len(grid))),
            }
            for alloc in MAKESPAN
        }
        t1 = np.zeros(reps)
        for r in range(reps):
            batches = [draw_durations(dist, rng, m) for m in sizes]
            t1[r] = sum(float(b[:, 0].sum()) for b in batches) + barrier_seconds * len(batches)
            for j, n in enumerate(grid):
                lbs = [lower_bound(b[:, 0], n) for b in batches]
                tight = [tight_lower_bound(b[:, 0], n) for b in batches]
                for alloc, fn in MAKESPAN.items():
                    spans = [fn(b, n) for b in batches]
                    res[alloc]["T"][r, j] = sum(spans) + barrier_seconds * len(batches)
                    res[alloc]["LB"][r, j] = sum(lbs) + barrier_seconds * len(batches)
                    res[alloc]["LB_tight"][r, j] = sum(tight) + barrier_seconds * len(batches)
                    res[alloc]["batch_ratio_max"][r, j] = max(s / lb for s, lb in zip(spans, lbs, strict=True))
                    res[alloc]["batch_ratio_tight_max"][r, j] = max(s / lb for s, lb in zip(spans, tight, strict=True))
        entry = {
            "batch_sizes": sizes,
            "n": grid,
            "total_simulations": int(sum(sizes)),
            "max_parallel_tasks": int(max(sizes[1:] or sizes)),
            "barriers": len(sizes),
            "T1_mean_s": float(t1.mean()),
        }
        for alloc, r in res.items():
            speedup = t1[:, None] / r["T"]
            ratio = r["T"] / r["LB"]
            entry[alloc] = {
                "speedup_mean": speedup.mean(0).tolist(),
                "speedup_min": speedup.min(0).tolist(),
                "speedup_max": speedup.max(0).tolist(),
                "efficiency_mean": (speedup.mean(0) / np.asarray(grid)).tolist(),
                "efficiency_min": (speedup.min(0) / np.asarray(grid)).tolist(),
                "makespan_over_lower_bound_mean": ratio.mean(0).tolist(),
                "makespan_over_lower_bound_max": ratio.max(0).tolist(),
                "makespan_over_tight_lower_bound_max": (r["T"] / r["LB_tight"]).max(0).tolist(),
                "worst_batch_over_lower_bound_max": r["batch_ratio_max"].max(0).tolist(),
                "worst_batch_over_tight_lower_bound_max": r["batch_ratio_tight_max"].max(0).tolist(),
                "upper_bound_speedup_from_lower_bound": (t1[:, None] / r["LB"]).mean(0).tolist(),
                "upper_bound_speedup_from_tight_lower_bound": (t1[:, None] / r["LB_tight"]).mean(0).tolist(),
            }
        out[name] = entry
    return out


def single_batch_study(dist: dict, sizes: list[int], n_grid: list[int], reps: int, seed: int) -> dict:
    """Makespan / lower bound of one batch of ``m`` tasks, dynamic vs static, for each m and n."""
    rng = np.random.default_rng(seed + 1)
    out = {}
    for m in sizes:
        grid = [n for n in n_grid_for([m], n_grid) if n <= m]
        ratios = {alloc: np.zeros((reps, len(grid))) for alloc in MAKESPAN}
        tight = {alloc: np.zeros((reps, len(grid))) for alloc in MAKESPAN}
        for r in range(reps):
            d = draw_durations(dist, rng, m)
            for j, n in enumerate(grid):
                lb, lb2 = lower_bound(d[:, 0], n), tight_lower_bound(d[:, 0], n)
                for alloc, fn in MAKESPAN.items():
                    span = fn(d, n)
                    ratios[alloc][r, j], tight[alloc][r, j] = span / lb, span / lb2
        out[str(m)] = {
            "n": grid,
            **{
                alloc: {
                    "mean": v.mean(0).tolist(),
                    "max": v.max(0).tolist(),
                    "q90": np.quantile(v, 0.9, axis=0).tolist(),
                    "over_tight_max": tight[alloc].max(0).tolist(),
                }
                for alloc, v in ratios.items()
            },
        }
    return out


def prediction_noise_study(
    dist: dict, algorithms: dict[str, list[int]], noise: tuple[float, ...], reps: int, seed: int
) -> dict:
    """How good must duration predictions be?  Longest-predicted-first with predictions equal to
    the true duration times ``exp(s Z)``, Z standard normal, for each log-error ``s``; worst whole
    run makespan over the pigeonhole bound (:func:`tight_lower_bound`) and over the plain one,
    over the range of one to four tasks per worker (:func:`n_grid_for` above 1024) and ``reps``
    repetitions.  The learnt predictor's row uses the records' leave-one-out predictions."""
    rng = np.random.default_rng(seed + 2)
    out = {}
    for name, sizes in algorithms.items():
        grid = [n for n in n_grid_for(sizes) if max(sizes[1:] or sizes) / 4 <= n < max(sizes[1:] or sizes)]
        rows = {}
        for s in (*noise, "learnt"):
            tight = plain = 0.0
            for _ in range(reps):
                batches = [draw_durations(dist, rng, m) for m in sizes]
                if s != "learnt":
                    batches = [
                        np.column_stack([b[:, 0], b[:, 0] * np.exp(s * rng.standard_normal(len(b)))]) for b in batches
                    ]
                for n in grid:
                    span = sum(MAKESPAN["dynamic_longest_first"](b, n) for b in batches)
                    tight = max(tight, span / sum(tight_lower_bound(b[:, 0], n) for b in batches))
                    plain = max(plain, span / sum(lower_bound(b[:, 0], n) for b in batches))
            rows[str(s)] = {"worst_over_tight_bound": tight, "worst_over_plain_bound": plain}
        out[name] = {"n": grid, "by_log_error_sd": rows}
    return out


# ---------------------------------------------------------------------------------------------
# (b) real ranks with sleeping tasks


def sleep_task(key: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """A task that only waits ``theta[0]`` seconds: the scheduler is timed without CPU limits."""
    time.sleep(float(theta[0]))
    return np.asarray(theta, np.float64)


class PredictedColumn:
    """Cost model for the rank study: a sleeping task's predicted duration is its ``theta[1]``
    (the leave-one-out k-NN prediction drawn with it), so the real executor queues the tasks in
    the order ``order="longest_first"`` would have chosen."""

    def predict(self, thetas: np.ndarray) -> np.ndarray:
        return np.asarray(thetas)[:, 1]

    def observe(self, thetas: np.ndarray, wall_times: np.ndarray) -> None:
        pass


def rank_job(spec_path: Path, out_path: Path) -> None:
    """Rank 0 of ``mpiexec -n K python -m mpi4py.futures benchmarks/speedup.py --rank-job``."""
    from jaxabc.executors.mpi import MPIExecutor

    spec = json.loads(spec_path.read_text())
    result = {}
    for alloc in spec["allocations"]:
        # isolate=False: a sleeping task cannot crash, and a child process per rank would only add
        # start-up time and memory at 64 oversubscribed ranks.
        if alloc == "dynamic_longest_first":
            ex = MPIExecutor("dynamic", isolate=False, order=PredictedColumn())
        else:
            ex = MPIExecutor(alloc, isolate=False)
        n = ex.num_workers
        warm = np.zeros((4 * n, 2))
        ex.map(sleep_task, np.zeros((warm.shape[0], 2), np.uint32), warm)  # every rank loads the task
        result[alloc] = {}
        for name, batches in spec["batches"].items():
            spans, workers, times = [], [], []
            t0 = time.perf_counter()
            for durations in batches:
                d = np.asarray(durations).reshape(-1, 2)  # rows (duration, predicted duration)
                batch = ex.map(sleep_task, np.zeros((d.shape[0], 2), np.uint32), d)
                spans.append(ex.last_makespan)
                workers.append(batch.worker.tolist())
                times.append(batch.wall_time.tolist())
            result[alloc][name] = {
                "total_s": time.perf_counter() - t0,
                "batch_makespans_s": spans,
                "worker": workers,
                "task_wall_s": times,
            }
        ex.close()
        result["num_workers"] = n
    out_path.write_text(json.dumps(result))


def _mpiexec(num_ranks: int, args: list[str], timeout: float) -> subprocess.CompletedProcess:
    cmd = [
        "mpiexec",
        "--allow-run-as-root",
        "--oversubscribe",
        "-n",
        str(num_ranks),
        sys.executable,
        "-m",
        "mpi4py.futures",
        str(Path(__file__).resolve()),
        *args,
    ]
    return subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, **MPI_ENV}, timeout=timeout, cwd=ROOT)


def rank_study(
    dist: dict,
    algorithms: dict[str, list[int]],
    ranks: list[int],
    sleep_mean: float,
    seed: int,
    timeout: float,
    previous: dict | None = None,
) -> dict:
    """Time the real MPIExecutor on oversubscribed ranks with sleeping tasks; validate the model.

    ``previous``: measurements of an earlier call with the same durations (same distribution,
    settings and seed), kept for the worker counts not measured again, so that a long series of
    launches can be split into several calls.
    """
    rng = np.random.default_rng(seed + 2)
    base = np.asarray(dist["times"]) if dist["kind"] == "empirical" else None
    scale_mean = (
        float(np.mean(base))
        if base is not None
        else math.exp(dist["lognormal"]["mu"] + dist["lognormal"]["sigma"] ** 2 / 2)
    )
    scale = sleep_mean / scale_mean
    batches = {
        name: [(draw_durations(dist, rng, m) * scale).tolist() for m in sizes] for name, sizes in algorithms.items()
    }
    measured = {}
    if previous and previous.get("batches_s") == batches:
        measured = {k: v for k, v in previous["measured"].items() if "error" not in v}
    with tempfile.TemporaryDirectory(prefix="jaxabc-speedup-") as tmp:
        spec = Path(tmp) / "spec.json"
        spec.write_text(json.dumps({"batches": batches, "allocations": list(RANK_ALLOCATIONS)}))
        for n in ranks:
            if str(n) in measured:
                continue
            out = Path(tmp) / f"ranks{n}.json"
            t0 = time.perf_counter()
            proc = _mpiexec(n + 1, ["--rank-job", str(spec), str(out)], timeout)
            if proc.returncode != 0 or not out.exists():
                measured[str(n)] = {
                    "error": f"mpiexec -n {n + 1} failed ({proc.returncode}): {(proc.stdout + proc.stderr)[-1500:]}"
                }
                print(f"ranks n={n}: FAILED", file=sys.stderr)
                continue
            measured[str(n)] = json.loads(out.read_text())
            measured[str(n)]["launch_wall_s"] = time.perf_counter() - t0
            print(
                f"ranks n={n}: "
                + ", ".join(
                    f"{a}/{k} {measured[str(n)][a][k]['total_s']:.2f} s" for a in RANK_ALLOCATIONS for k in batches
                ),
                flush=True,
            )
    # Model prediction with the same durations: the executor's round trip c per future (one per
    # task under dynamic allocation, one per chunk under static) fitted from the dynamic run at
    # the smallest n (one worker, where scheduling cannot matter), T = sum(d) + m c; everything
    # else, static allocation included, is predicted.
    ranks = sorted({*ranks, *map(int, measured)})
    ok = [n for n in ranks if "error" not in measured[str(n)]]
    validation = {}
    if ok:
        n0 = min(ok)
        per_task = {}
        for name, bs in batches.items():
            count = sum(len(b) for b in bs)
            per_task[name] = (
                measured[str(n0)]["dynamic"][name]["total_s"]
                - run_time([np.asarray(b).reshape(-1, 2) for b in bs], n0, "dynamic")
            ) / count
        overhead = float(np.median(list(per_task.values())))
        for name, bs in batches.items():
            arrays = [np.asarray(b).reshape(-1, 2) for b in bs]
            t1_meas = measured[str(n0)]["dynamic"][name]["total_s"] if n0 == 1 else None
            rows = {"n": ok}
            for alloc in RANK_ALLOCATIONS:
                if any(alloc not in measured[str(n)] for n in ok):
                    continue  # measured by an older version of this script
                meas = [measured[str(n)][alloc][name]["total_s"] for n in ok]
                pred = [run_time(arrays, n, alloc, overhead) for n in ok]
                lb = [sum(lower_bound(b[:, 0], n) for b in arrays) for n in ok]
                rows[alloc] = {
                    "measured_s": meas,
                    "model_s": pred,
                    "model_no_overhead_s": [run_time(arrays, n, alloc) for n in ok],
                    "lower_bound_s": lb,
                    "relative_error": [(p - m) / m for p, m in zip(pred, meas, strict=True)],
                    "measured_over_lower_bound": [m / b for m, b in zip(meas, lb, strict=True)],
                    "measured_speedup": [t1_meas / m for m in meas] if t1_meas else None,
                    "model_speedup": [run_time(arrays, 1, "dynamic", overhead) / p for p in pred],
                }
            validation[name] = rows
        validation["overhead_per_task_s"] = overhead
        validation["overhead_fitted_at_n"] = n0
        validation["overhead_per_algorithm_s"] = per_task
    return {
        "sleep_mean_s": sleep_mean,
        "scale": scale,
        "ranks": ranks,
        "batches_s": batches,
        "measured": measured,
        "validation": validation,
    }


# ---------------------------------------------------------------------------------------------
# (c) real simulations at n = 1 and 2


def real_job(spec_path: Path, out_path: Path) -> None:
    """Rank 0 of the real-simulation launch: GROMACS quick preset through MPIExecutor."""
    from jaxabc.executors.mpi import MPIExecutor
    from md.water import make_simulator

    spec = json.loads(spec_path.read_text())
    simulate = make_simulator("quick")
    keys = np.asarray(spec["keys"], np.uint32)
    thetas = np.asarray(spec["thetas"])
    result = {}
    for alloc in spec["allocations"]:
        ex = MPIExecutor(alloc)
        n = ex.num_workers
        batch = ex.map(simulate, keys, thetas)
        result[alloc] = {
            "makespan_s": ex.last_makespan,
            "task_wall_s": batch.wall_time.tolist(),
            "status": batch.status.tolist(),
            "worker": batch.worker.tolist(),
            "reasons": list(batch.reasons),
        }
        ex.close()
        result["num_workers"] = n
    result["load_average_after"] = list(os.getloadavg())
    out_path.write_text(json.dumps(result))


def real_study(num: int, seed: int, timeout: float, posterior: Path | None = None) -> dict:
    """Time ``num`` GROMACS runs at n = 1 and 2 workers.

    Parameters are drawn from a saved calibration's posterior (by weight, with replacement), so
    that the timed runs are liquid ones as a calibration's later steps are; from the prior (where
    most of the box vaporises or freezes within a second) when ``posterior`` is None.
    """
    import jax

    import jaxabc

    key_theta, key_sim = jax.random.split(jax.random.key(seed + 3))
    if posterior is None:
        thetas = np.asarray(jaxabc.Uniform(*map(list, WATER_PRIOR)).sample(key_theta, num), np.float64)
    else:
        saved = jaxabc.load(posterior)
        rows = np.asarray(jax.random.choice(key_theta, len(saved.weights), (num,), p=jax.numpy.asarray(saved.weights)))
        thetas = np.asarray(saved.particles, np.float64)[rows]
    keys = np.asarray(jax.random.key_data(jax.random.split(key_sim, num)))
    out = {
        "simulator": "md.water.make_simulator('quick') (GROMACS TIP4P, 216 molecules, 20 ps), one "
        "single-threaded gmx mdrun per rank, MPIExecutor with isolate=True",
        "num_tasks": num,
        "theta_source": "prior" if posterior is None else f"posterior of {Path(posterior).name}",
        "theta": thetas.tolist(),
        "runs": {},
    }
    with tempfile.TemporaryDirectory(prefix="jaxabc-speedup-real-") as tmp:
        spec = Path(tmp) / "spec.json"
        for n, allocs in ((1, ["dynamic"]), (2, ["dynamic", "static"])):
            spec.write_text(json.dumps({"keys": keys.tolist(), "thetas": thetas.tolist(), "allocations": allocs}))
            dst = Path(tmp) / f"real{n}.json"
            load = list(os.getloadavg())
            proc = _mpiexec(n + 1, ["--real-job", str(spec), str(dst)], timeout)
            if proc.returncode != 0 or not dst.exists():
                out["runs"][str(n)] = {"error": (proc.stdout + proc.stderr)[-1500:]}
                continue
            out["runs"][str(n)] = {**json.loads(dst.read_text()), "load_average_before": load}
            statuses = [s for a in allocs for s in out["runs"][str(n)][a]["status"]]
            out["runs"][str(n)]["num_succeeded"] = int(sum(s == 0 for s in statuses))
            out["runs"][str(n)]["num_timed"] = len(statuses)
            print(
                f"real n={n}: " + ", ".join(f"{a} {out['runs'][str(n)][a]['makespan_s']:.1f} s" for a in allocs),
                flush=True,
            )
    runs = out["runs"]
    if "error" not in runs.get("1", {"error": 1}) and "error" not in runs.get("2", {"error": 1}):
        t1 = runs["1"]["dynamic"]["makespan_s"]
        out["speedup"] = {a: t1 / runs["2"][a]["makespan_s"] for a in ("dynamic", "static")}
        out["efficiency"] = {a: s / 2 for a, s in out["speedup"].items()}
        # On a shared machine two concurrent simulations may not get two cores: the summed task
        # time at n = 2 over that at n = 1 says how much slower each simulation ran.
        out["task_time_inflation_n2"] = {
            a: float(np.sum(runs["2"][a]["task_wall_s"]) / np.sum(runs["1"]["dynamic"]["task_wall_s"]))
            for a in ("dynamic", "static")
        }
        d2 = np.asarray(runs["2"]["dynamic"]["task_wall_s"])
        out["lower_bound_n2_s"] = lower_bound(d2, 2)
        out["makespan_over_lower_bound_n2"] = {
            a: runs["2"][a]["makespan_s"] / lower_bound(np.asarray(runs["2"][a]["task_wall_s"]), 2)
            for a in ("dynamic", "static")
        }
    return out


# ---------------------------------------------------------------------------------------------


def _targets(model: dict, single: dict, alpha: float, p0: float, num_particles: int) -> dict:
    m_apmc = num_particles - math.ceil(alpha * num_particles)
    ap, sub = model["apmcabc"], model["abcsubsim"]
    n_ap = np.asarray(ap["n"])
    eff = np.asarray(ap["dynamic"]["efficiency_mean"])
    within = n_ap <= m_apmc
    dyn = ("dynamic", "dynamic_longest_first", "dynamic_lpt_oracle")
    worst_single = {a: {m: max(v[a]["max"]) for m, v in single.items()} for a in dyn}
    worst_single_tight = {a: {m: max(v[a]["over_tight_max"]) for m, v in single.items()} for a in dyn}
    run_ratio = {a: {name: max(model[name][a]["makespan_over_lower_bound_max"]) for name in model} for a in dyn}
    run_tight = {a: {name: max(model[name][a]["makespan_over_tight_lower_bound_max"]) for name in model} for a in dyn}
    n_sub = np.asarray(sub["n"])
    common = [int(n) for n in n_ap if n in set(n_sub.tolist())]
    # No schedule beats the tight bound, so T(1) / LB_tight / n caps the efficiency of any scheduler.
    ceiling = np.asarray(ap["dynamic"]["upper_bound_speedup_from_tight_lower_bound"]) / n_ap
    return {
        "dynamic_within_1.1x_lower_bound": {
            "target": "dynamic makespan <= 1.1 x max(total/n, longest) at every n (water distribution)",
            "whole_run_worst_ratio": run_ratio["dynamic"],
            "single_batch_worst_ratio_by_m": worst_single["dynamic"],
            "met_whole_run": bool(all(v <= 1.1 for v in run_ratio["dynamic"].values())),
            "met_every_single_batch": bool(all(v <= 1.1 for v in worst_single["dynamic"].values())),
            "by_allocation": {
                a: {
                    "whole_run_worst_ratio": run_ratio[a],
                    "whole_run_worst_ratio_to_tight_bound": run_tight[a],
                    "single_batch_worst_ratio_by_m": worst_single[a],
                    "single_batch_worst_ratio_to_tight_bound_by_m": worst_single_tight[a],
                    "met_whole_run": bool(all(v <= 1.1 for v in run_ratio[a].values())),
                    "met_whole_run_tight": bool(all(v <= 1.1 for v in run_tight[a].values())),
                }
                for a in dyn
            },
            # T(1)/LB over T(1)/LB_tight = LB_tight / LB: where it exceeds 1.1, no schedule is within
            # 1.1x of the plain bound (the pigeonhole bound is a bound on every schedule).
            "n_where_no_scheduler_is_within_1.1x": {
                name: [
                    int(n)
                    for n, a, b in zip(
                        model[name]["n"],
                        model[name]["dynamic"]["upper_bound_speedup_from_lower_bound"],
                        model[name]["dynamic"]["upper_bound_speedup_from_tight_lower_bound"],
                        strict=True,
                    )
                    if a / b > 1.1
                ]
                for name in model
            },
            "why_the_bound_is_not_reachable": (
                "tasks are indivisible: with m > n tasks two of the n + 1 longest share a worker, so no schedule "
                "finishes before p_n + p_(n+1), which exceeds max(total/n, longest) when m / n is small "
                "(e.g. m = n + 1 equal tasks: twice the bound); more generally some worker runs k + 1 of the k n + 1 "
                "longest; the tight bound adds these terms"
            ),
        },
        "apmcabc_efficiency_0.8": {
            "target": f"APMCABC dynamic efficiency >= 0.8 for n <= N - ceil(alpha N) = {m_apmc}",
            "n": n_ap[within].tolist(),
            "efficiency": eff[within].tolist(),
            "met": bool(np.all(eff[within] >= 0.8)),
            "largest_n_with_efficiency_0.8": int(n_ap[eff >= 0.8].max()) if np.any(eff >= 0.8) else None,
            "efficiency_by_allocation": {a: np.asarray(ap[a]["efficiency_mean"])[within].tolist() for a in dyn},
            "efficiency_ceiling_any_scheduler": ceiling[within].tolist(),
            "why": (
                "at n = N - ceil(alpha N) every task has its own worker and each step lasts its longest task, "
                "so efficiency = mean / max duration whatever the scheduler (the ceiling row)"
            ),
        },
        "abcsubsim_lower": {
            "target": "ABCsubsim efficiency below APMCABC's (sequential chain rounds)",
            "n": common,
            "apmcabc": [float(eff[list(n_ap).index(n)]) for n in common],
            "abcsubsim": [float(np.asarray(sub["dynamic"]["efficiency_mean"])[list(n_sub).index(n)]) for n in common],
            "reason": (
                f"after the prior sample, each ABCsubsim level is {round(1 / p0) - 1} barrier-separated rounds "
                f"of only {sub['max_parallel_tasks']} parallel chain moves (a chain's next state needs its "
                f"previous one; {sub['barriers']} barriers in the run), against one step of "
                f"{ap['max_parallel_tasks']} independent simulations per APMCABC step ({ap['barriers']} "
                "barriers): fewer tasks per barrier leave workers idle sooner and the longest task of "
                "each round is paid more often"
            ),
        },
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--parts", nargs="+", default=["model", "ranks", "real"], choices=["model", "ranks", "real"])
    parser.add_argument("--imbalance", type=Path, default=RESULTS / "imbalance.json")
    parser.add_argument(
        "--records",
        type=Path,
        default=None,
        help="use the simulation records of a saved ABC run (npz) as the duration distribution, "
        "e.g. benchmarks/results/water_simulated_robust.npz",
    )
    parser.add_argument("--system", default="water", help="which imbalance distribution (water or helium)")
    parser.add_argument("--distribution", default="empirical", choices=["empirical", "lognormal"])
    parser.add_argument("--num-particles", type=int, default=5000, help="N (paper helium: 5000)")
    parser.add_argument("--alpha", type=float, default=0.1, help="APMCABC alpha (ABCpy default 0.1)")
    parser.add_argument("--p0", type=float, default=0.2, help="ABCsubsim P0")
    parser.add_argument("--steps", type=int, default=6, help="APMCABC steps and ABCsubsim levels (paper: 6)")
    parser.add_argument("--reps", type=int, default=10, help="model repetitions (fresh durations)")
    parser.add_argument(
        "--barrier-seconds", type=float, default=0.0, help="serial driver time per barrier (0: pure scheduling model)"
    )
    parser.add_argument(
        "--ranks",
        type=int,
        nargs="+",
        default=[1, 2, 4, 8, 16, 32],
        help="worker counts for the real-rank part (mpiexec -n n+1)",
    )
    parser.add_argument(
        "--rank-particles", type=int, default=100, help="N of the algorithms timed on real ranks (paper water: 100)"
    )
    parser.add_argument("--rank-steps", type=int, default=3)
    parser.add_argument(
        "--reuse-ranks",
        action="store_true",
        help="keep the saved rank timings (same durations only) and launch only the worker counts they lack, "
        "to split a long series of launches over several calls",
    )
    parser.add_argument("--sleep-mean", type=float, default=0.03, help="mean sleep per task, seconds")
    parser.add_argument("--real-num", type=int, default=6, help="water simulations for the n = 1, 2 part")
    parser.add_argument(
        "--real-posterior",
        default="benchmarks/results/water_neutron_robust.npz",
        help="saved calibration whose posterior gives the real part's parameters ('prior': the prior)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds per mpiexec launch")
    parser.add_argument("--output", type=Path, default=RESULTS / "speedup.json")
    parser.add_argument("--figure", type=Path, default=RESULTS / "speedup.png")
    parser.add_argument("--rank-job", nargs=2, type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--real-job", nargs=2, type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.rank_job:
        return rank_job(*args.rank_job)
    if args.real_job:
        return real_job(*args.real_job)

    out = json.loads(args.output.read_text()) if args.output.exists() else {}
    out["command"] = " ".join([Path(sys.executable).name, *sys.argv])
    # The parts can be rerun one at a time; keep the command that produced each.
    out["commands"] = {**out.get("commands", {}), **{part: out["command"] for part in args.parts}}
    # The duration distribution of the model and rank parts; the real part runs GROMACS itself
    # and must not replace the one they were made with.
    uses_distribution = bool({"model", "ranks"} & set(args.parts))
    if uses_distribution:
        if args.records is not None:
            dist = records_distribution(args.records, args.distribution)
        else:
            dist = load_distribution(args.imbalance, args.system, args.distribution)
        out["distribution"] = dist
    settings = {"num_particles": args.num_particles, "alpha": args.alpha, "p0": args.p0, "steps": args.steps}
    algorithms = {
        "apmcabc": apmcabc_batches(args.num_particles, args.alpha, args.steps),
        "abcsubsim": abcsubsim_batches(args.num_particles, args.p0, args.steps),
    }
    if "model" in args.parts:
        t0 = time.perf_counter()
        model = model_study(dist, algorithms, N_GRID, args.reps, args.seed, args.barrier_seconds)
        sizes = sorted(
            {
                algorithms["apmcabc"][1],
                algorithms["abcsubsim"][1],
                args.rank_particles - math.ceil(args.alpha * args.rank_particles),
            }
        )
        single = single_batch_study(dist, sizes, N_GRID, args.reps * 5, args.seed)
        out["model"] = {
            "how": "discrete-event model: greedy list scheduling (dynamic) / equal contiguous chunks "
            "(static), barrier after every batch, durations resampled from the imbalance "
            "distribution",
            "settings": {**settings, "reps": args.reps, "barrier_seconds": args.barrier_seconds},
            "algorithms": model,
            "single_batch": single,
            "prediction_noise": prediction_noise_study(
                dist, algorithms, (0.0, 0.05, 0.1, 0.2), max(2, args.reps // 3), args.seed
            ),
            "seconds": time.perf_counter() - t0,
        }
        out["targets"] = _targets(model, single, args.alpha, args.p0, args.num_particles)
        print(json.dumps(out["targets"], indent=1))
    if "ranks" in args.parts:
        small = {
            "apmcabc": apmcabc_batches(args.rank_particles, args.alpha, args.rank_steps),
            "abcsubsim": abcsubsim_batches(args.rank_particles, args.p0, args.rank_steps),
        }
        out["ranks"] = {
            "how": "real Open MPI ranks (oversubscribed, mpiexec -n n+1 python -m mpi4py.futures), "
            "jaxabc.executors.MPIExecutor(isolate=False) running time.sleep tasks",
            "settings": {
                "num_particles": args.rank_particles,
                "alpha": args.alpha,
                "p0": args.p0,
                "steps": args.rank_steps,
            },
            **rank_study(
                dist,
                small,
                args.ranks,
                args.sleep_mean,
                args.seed,
                args.timeout,
                # Reused only on request: a saved result must not pass off old timings as new ones.
                previous=out.get("ranks") if args.reuse_ranks else None,
            ),
        }
    if "real" in args.parts:
        out["real"] = {
            "how": "actual GROMACS simulations on 1 and 2 MPI worker ranks (this machine: 2 shared cores)",
            **real_study(
                args.real_num,
                args.seed,
                args.timeout,
                None if args.real_posterior == "prior" else ROOT / args.real_posterior,
            ),
        }
    from benchmarks._common import write_result

    out.pop("machine", None)  # written before provenance existed; the provenance holds the machine now
    source = args.records or args.imbalance
    inputs = [source] if uses_distribution and source.exists() else []
    if "real" in args.parts and args.real_posterior != "prior":
        inputs.append(ROOT / args.real_posterior)
    write_result(args.output, out, part=args.parts, inputs=inputs)
    draw = runpy.run_path(str(ROOT / "paper_figures" / "figure4_speedup.py"))["draw"]
    draw(args.output, args.figure)
    print(f"wrote {args.output} and {args.figure}")


if __name__ == "__main__":
    main()
