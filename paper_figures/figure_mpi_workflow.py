"""Figure ``fig:MPI_workflow_comparison`` of Dutta et al. (2018): static chunks vs dynamic allocation.

The paper draws a cartoon of the two MPI backends.  Here the same comparison is a Gantt chart
(worker on y, time on x) of ONE batch of tasks, scheduled twice by the discrete-event model of
``benchmarks/speedup.py`` (no simulation, no MPI run):

* static: the batch is cut into equal contiguous chunks, one per worker, fixed up front
  (``jaxabc.executors.mpi.chunk_indices``, ``jaxabc.executors.scheduling.static_makespan``);
* dynamic: a free worker pulls the next task in order (greedy list scheduling,
  ``jaxabc.MPIExecutor(allocation="dynamic")``, ``jaxabc.executors.scheduling.dynamic_makespan``).

Task durations are drawn with a fixed seed from the measured durations of a water APMCABC run
stored in ``benchmarks/results/speedup.json`` (``distribution``: every GROMACS simulation's time,
failures included, from the run named by ``--records`` when it was written; the figure prints
that source), or, if that file is missing, from
``jaxabc.load("benchmarks/results/water_simulated_robust.npz").records["wall_time"]``.  The batch
is 90 tasks (one APMCABC step, N - ceil(alpha N) for N = 100, alpha = 0.1) on 8 workers.
Makespans and the lower bound max(total / n, longest task) are in the titles; the model's mean
over many batches (``speedup.json``, ``single_batch``) is printed.

Writes ``paper_figures/out/figure_mpi_workflow.png``.

Usage::

    python -m paper_figures.figure_mpi_workflow
"""

from __future__ import annotations

import heapq
import importlib
import json
from pathlib import Path
from types import ModuleType

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
OUT = Path(__file__).resolve().parent / "out"
SPEEDUP_JSON = RESULTS / "speedup.json"
RECORDS_NPZ = RESULTS / "water_simulated_robust.npz"
NUM_WORKERS = 8
NUM_TASKS = 90
SEED = 2018


def _speedup_module() -> ModuleType:
    """``benchmarks.speedup``, imported only when the records are replayed (it imports jax)."""
    return importlib.import_module("benchmarks.speedup")


def static_schedule(durations: np.ndarray, n: int) -> list[tuple[int, int, float, float]]:
    """Equal contiguous chunks, one per worker.

    Parameters
    ----------
    durations : np.ndarray, shape (num_tasks,)
    n : int
        Workers.

    Returns
    -------
    list of (task, worker, start, duration)
    """
    out = []
    for worker, chunk in enumerate(np.array_split(np.arange(durations.size), min(n, durations.size))):
        start = 0.0
        for task in chunk:
            out.append((int(task), worker, start, float(durations[task])))
            start += float(durations[task])
    return out


def dynamic_schedule(durations: np.ndarray, n: int) -> list[tuple[int, int, float, float]]:
    """Greedy list scheduling in task order: the earliest-free worker takes the next task.

    Ties go to the lowest worker index; the makespan equals ``speedup.dynamic_makespan``.

    Returns
    -------
    list of (task, worker, start, duration)
    """
    free = [(0.0, worker) for worker in range(n)]
    out = []
    for task, d in enumerate(durations):
        start, worker = heapq.heappop(free)
        out.append((task, worker, start, float(d)))
        heapq.heappush(free, (start + float(d), worker))
    return out


def _durations(speedup: ModuleType) -> tuple[np.ndarray, str]:
    """Draw the batch: from speedup.json's measured distribution, else from the npz records."""
    rng = np.random.default_rng(SEED)
    if SPEEDUP_JSON.exists():
        dist = json.loads(SPEEDUP_JSON.read_text())["distribution"]
        if dist.get("times"):
            dist = {**dist, "kind": "empirical"}
            return speedup.draw_durations(dist, rng, NUM_TASKS)[:, 0], str(dist["source"])
    import jaxabc

    times = np.asarray(jaxabc.load(RECORDS_NPZ).records["wall_time"], dtype=np.float64)
    times = times[np.isfinite(times) & (times > 0)]
    dist = {"kind": "empirical", "times": times.tolist(), "predicted": None}
    return speedup.draw_durations(dist, rng, NUM_TASKS)[:, 0], f"{RECORDS_NPZ.name}: {times.size} wall times"


def _model_summary() -> str:
    """The model's makespan / lower bound over many batches of this size, from speedup.json."""
    if not SPEEDUP_JSON.exists():
        return ""
    single = json.loads(SPEEDUP_JSON.read_text()).get("model", {}).get("single_batch", {}).get(str(NUM_TASKS))
    if not single or NUM_WORKERS not in single["n"]:
        return ""
    i = single["n"].index(NUM_WORKERS)
    return (
        f"model over many {NUM_TASKS}-task batches at n = {NUM_WORKERS}: makespan / lower bound mean (worst) "
        f"static {single['static']['mean'][i]:.2f} ({single['static']['max'][i]:.2f}), "
        f"dynamic {single['dynamic']['mean'][i]:.2f} ({single['dynamic']['max'][i]:.2f})"
    )


def _gantt(ax: plt.Axes, schedule: list, cmap, norm, makespan: float, bound: float, title: str) -> None:
    for task, worker, start, d in schedule:
        ax.barh(worker, d, left=start, height=0.8, color=cmap(norm(d)), edgecolor="k", lw=0.4)
        if d > 0.04 * makespan:
            ax.text(start + d / 2, worker, str(task), ha="center", va="center", fontsize=5)
    ax.axvline(makespan, color="tab:red", lw=1.5, label=f"makespan {makespan:.1f} s")
    ax.axvline(bound, color="k", ls="--", lw=1.2, label=f"lower bound max(total/n, longest) {bound:.1f} s")
    ax.set_yticks(range(NUM_WORKERS))
    ax.set_yticklabels([f"worker {w}" for w in range(NUM_WORKERS)], fontsize=8)
    ax.invert_yaxis()
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc="center right")


def main(out_dir: str | Path | None = None) -> Path:
    """Draw the Gantt charts and print the makespans.

    Parameters
    ----------
    out_dir : path-like, optional
        Where to write the PNG; default ``paper_figures/out``.

    Returns
    -------
    pathlib.Path
        The PNG written.
    """
    speedup = _speedup_module()
    durations, source = _durations(speedup)
    schedules = {"static": static_schedule(durations, NUM_WORKERS), "dynamic": dynamic_schedule(durations, NUM_WORKERS)}
    spans = {name: max(start + d for _, _, start, d in s) for name, s in schedules.items()}
    check = {
        "static": speedup.static_makespan(durations, NUM_WORKERS),
        "dynamic": speedup.dynamic_makespan(durations, NUM_WORKERS),
    }
    for name in spans:
        if not np.isclose(spans[name], check[name]):
            raise RuntimeError(f"{name} schedule makespan {spans[name]} != speedup.py's {check[name]}")
    bound = speedup.lower_bound(durations, NUM_WORKERS)
    tight = speedup.tight_lower_bound(durations, NUM_WORKERS)

    many = _model_summary()
    cmap = plt.get_cmap("viridis")
    norm = matplotlib.colors.LogNorm(vmin=max(durations.min(), 0.05), vmax=durations.max())
    fig, axes = plt.subplots(2, 1, figsize=(12, 7.5), sharex=True)
    how = {
        "static": "static: equal contiguous chunks of tasks, fixed up front (MPI backend)",
        "dynamic": "dynamic: a free worker pulls the next task (dynamic-MPI backend)",
    }
    for ax, name in zip(axes, ("static", "dynamic"), strict=True):
        _gantt(
            ax,
            schedules[name],
            cmap,
            norm,
            spans[name],
            bound,
            f"({'ab'[name == 'dynamic']}) {how[name]}: makespan {spans[name]:.1f} s = "
            f"{spans[name] / bound:.2f} x lower bound",
        )
    axes[1].set_xlim(0.0, 1.3 * max(spans.values()))  # room on the right for the legends
    axes[1].set_xlabel("time (s)")
    fig.colorbar(
        matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap), ax=axes, label="task duration (s)", fraction=0.03, pad=0.01
    )
    fig.suptitle(
        f"Discrete-event model (benchmarks/speedup.py) over measured water task durations: {NUM_TASKS} tasks "
        f"on {NUM_WORKERS} workers\nstatic {spans['static']:.1f} s, dynamic {spans['dynamic']:.1f} s, "
        f"lower bound {bound:.1f} s (total {durations.sum():.0f} s, longest {durations.max():.1f} s); "
        f"durations: {source}" + (f"\nthis is one draw; {many}" if many else ""),
        fontsize=8,
    )
    out = Path(out_dir) if out_dir is not None else OUT
    out.mkdir(parents=True, exist_ok=True)
    path = out / "figure_mpi_workflow.png"
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)

    print(
        f"{NUM_TASKS} tasks on {NUM_WORKERS} workers (seed {SEED}): static {spans['static']:.1f} s, "
        f"dynamic {spans['dynamic']:.1f} s, lower bound {bound:.1f} s (pigeonhole bound {tight:.1f} s); "
        f"ratio to the bound: static {spans['static'] / bound:.2f}, dynamic {spans['dynamic'] / bound:.2f}"
    )
    if many:
        print(f"speedup.json, {many}")
    print("The paper shows this comparison as a cartoon (no numbers).")
    return path


if __name__ == "__main__":
    print(main())
