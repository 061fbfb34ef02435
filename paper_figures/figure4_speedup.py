"""Figure 4 of Dutta et al. (2018): speedup of APMCABC vs ABCsubsim with dynamic MPI allocation.

Redraws from ``benchmarks/results/speedup.json`` only (written by ``benchmarks/speedup.py``).
Four panels, every curve labelled with how it was obtained:

(a) speedup S(n) = T(1)/T(n) of both algorithms, discrete-event model (N of the paper's helium
    run), dynamic and static allocation;
(b) the same for the small runs timed on real MPI ranks with sleeping tasks (markers), the model's
    prediction for the same durations (lines) and the real GROMACS runs at n = 1, 2;
(c) parallel efficiency S(n)/n (model), with the 0.8 target up to n = N - ceil(alpha N);
(d) makespan / lower bound max(total/n, longest task) of one batch, dynamic vs static.

Usage::

    python -m paper_figures.figure4_speedup [speedup.json] [figure4_speedup.png]
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
COLORS = {"apmcabc": "tab:blue", "abcsubsim": "tab:orange"}
NAMES = {"apmcabc": "APMCABC", "abcsubsim": "ABCsubsim"}
#: dynamic_longest_first: queued longest predicted first; dynamic_lpt_oracle: by true duration (a bound).
ALLOC_COLORS = {
    "dynamic": "tab:blue",
    "dynamic_longest_first": "tab:green",
    "dynamic_lpt_oracle": "tab:gray",
    "static": "tab:red",
}


def _panel_model(ax: plt.Axes, model: dict) -> None:
    for name, rec in model["algorithms"].items():
        n = np.asarray(rec["n"])
        for alloc, style in (("dynamic", "-"), ("static", "--")):
            ax.plot(
                n,
                rec[alloc]["speedup_mean"],
                style,
                color=COLORS[name],
                marker="o" if alloc == "dynamic" else None,
                ms=3,
                label=f"{NAMES[name]}, {alloc} (model)",
            )
    n = np.asarray(model["algorithms"]["apmcabc"]["n"])
    ax.plot(n, n, ":", color="gray", label="ideal S(n) = n")
    s = model["settings"]
    ax.set_title(
        f"(a) model: N = {s['num_particles']}, alpha = {s['alpha']}, P0 = {s['p0']}, "
        f"{s['steps']} steps, {s['reps']} reps",
        fontsize=9,
    )
    ax.set_xscale("log", base=2)
    ax.set_yscale("log", base=2)
    ax.set_xlabel("workers n")
    ax.set_ylabel("speedup S(n) = T(1)/T(n)")
    ax.legend(fontsize=7)


def _panel_ranks(ax: plt.Axes, data: dict) -> None:
    ranks = data.get("ranks")
    if ranks and ranks.get("validation"):
        val = ranks["validation"]
        for name in ("apmcabc", "abcsubsim"):
            if name not in val:
                continue
            n = np.asarray(val[name]["n"])
            for alloc, marker, style in (("dynamic", "o", "-"), ("static", "s", "--")):
                row = val[name][alloc]
                if row["measured_speedup"] is not None:
                    ax.plot(
                        n,
                        row["measured_speedup"],
                        marker,
                        color=COLORS[name],
                        mfc="none" if alloc == "static" else COLORS[name],
                        label=f"{NAMES[name]}, {alloc}: measured, real MPI ranks, sleep tasks",
                    )
                ax.plot(
                    n,
                    row["model_speedup"],
                    style,
                    color=COLORS[name],
                    lw=1,
                    label=f"{NAMES[name]}, {alloc}: model, same durations",
                )
        s = ranks["settings"]
        ax.set_title(
            f"(b) real ranks (oversubscribed), N = {s['num_particles']}, {s['steps']} steps, mean sleep "
            f"{ranks['sleep_mean_s'] * 1e3:.0f} ms; overhead {val['overhead_per_task_s'] * 1e3:.2f} ms/task",
            fontsize=9,
        )
        top = max(n)
    else:
        top = 2
        ax.set_title("(b) real ranks: not run", fontsize=9)
    real = data.get("real")
    if real and "speedup" in real:
        for alloc, marker in (("dynamic", "*"), ("static", "P")):
            ax.plot(
                [1, 2],
                [1.0, real["speedup"][alloc]],
                marker,
                color="tab:green",
                ms=11,
                label=f"water GROMACS, {alloc}: measured, real simulations ({real['num_tasks']} tasks)",
            )
    ax.plot([1, top], [1, top], ":", color="gray", label="ideal")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log", base=2)
    ax.set_xlabel("workers n")
    ax.set_ylabel("speedup S(n)")
    ax.legend(fontsize=6)


def _panel_efficiency(ax: plt.Axes, model: dict) -> None:
    s = model["settings"]
    for name, rec in model["algorithms"].items():
        n = np.asarray(rec["n"])
        ax.plot(
            n,
            rec["dynamic"]["efficiency_mean"],
            "-o",
            ms=3,
            color=COLORS[name],
            label=f"{NAMES[name]}, dynamic (model)",
        )
        ax.plot(n, rec["static"]["efficiency_mean"], "--", color=COLORS[name], label=f"{NAMES[name]}, static (model)")
        if "dynamic_longest_first" in rec:
            ax.plot(
                n,
                rec["dynamic_longest_first"]["efficiency_mean"],
                "-.",
                color=COLORS[name],
                label=f"{NAMES[name]}, dynamic longest-predicted-first (model)",
            )
        ax.axvline(
            rec["max_parallel_tasks"],
            color=COLORS[name],
            lw=0.8,
            ls=":",
            label=f"{NAMES[name]}: {rec['max_parallel_tasks']} parallel tasks per barrier",
        )
    ax.axhline(0.8, color="k", lw=0.8, label="target 0.8")
    m = s["num_particles"] - math.ceil(s["alpha"] * s["num_particles"])
    ax.set_title(f"(c) parallel efficiency S(n)/n; APMCABC target up to n = N - ceil(alpha N) = {m}", fontsize=9)
    ax.set_xscale("log", base=2)
    ax.set_ylim(0, 1.05)
    ax.set_xlabel("workers n")
    ax.set_ylabel("efficiency")
    ax.legend(fontsize=7)


def _panel_makespan(ax: plt.Axes, model: dict, data: dict) -> None:
    styles = ["-", "-.", ":"]
    for k, (m, rec) in enumerate(sorted(model["single_batch"].items(), key=lambda kv: int(kv[0]))):
        n = np.asarray(rec["n"])
        for alloc, color in ALLOC_COLORS.items():
            if alloc in rec:
                ax.plot(n, rec[alloc]["max"], styles[k % 3], color=color, label=f"{alloc}, m = {m} (model, worst)")
    ranks = data.get("ranks")
    if ranks and ranks.get("validation"):
        val = ranks["validation"]["apmcabc"]
        for alloc, color in ALLOC_COLORS.items():
            if alloc in val:
                ax.plot(
                    val["n"],
                    val[alloc]["measured_over_lower_bound"],
                    "o",
                    color=color,
                    mfc="none",
                    label=f"{alloc}, APMCABC run (measured, real ranks, sleep)",
                )
    ax.axhline(1.1, color="k", lw=0.8, label="target 1.1")
    ax.set_xscale("log", base=2)
    ax.set_xlabel("workers n")
    ax.set_ylabel("makespan / max(total/n, longest)")
    ax.set_title(
        "(d) makespan relative to the lower bound, " + data["distribution"]["system"] + " time distribution", fontsize=9
    )
    ax.legend(fontsize=6)


def draw(json_path: str | Path, png_path: str | Path) -> None:
    """Draw the figure from the saved JSON."""
    data = json.loads(Path(json_path).read_text())
    fig, axes = plt.subplots(2, 2, figsize=(13, 10))
    if "model" in data:
        _panel_model(axes[0, 0], data["model"])
        _panel_efficiency(axes[1, 0], data["model"])
        _panel_makespan(axes[1, 1], data["model"], data)
    _panel_ranks(axes[0, 1], data)
    dist = data["distribution"]
    fig.suptitle(
        f"Speedup with dynamic MPI allocation; task durations: {dist['kind']} from {dist['source']}", fontsize=9
    )
    fig.tight_layout()
    fig.savefig(png_path, dpi=110)
    plt.close(fig)


def main(out_dir: str | Path | None = None) -> Path:
    """Draw from ``benchmarks/results/speedup.json`` into ``out_dir`` (default ``paper_figures/out``).

    Used by ``paper_figures/make_all.py`` and the tests; the command line below keeps its own
    defaults.

    Returns
    -------
    pathlib.Path
        The PNG written.
    """
    out = Path(out_dir) if out_dir is not None else Path(__file__).resolve().parent / "out"
    out.mkdir(parents=True, exist_ok=True)
    path = out / "figure4_speedup.png"
    draw(RESULTS / "speedup.json", path)
    return path


if __name__ == "__main__":
    src = Path(sys.argv[1]) if len(sys.argv) > 1 else RESULTS / "speedup.json"
    dst = Path(sys.argv[2]) if len(sys.argv) > 2 else ROOT / "paper_figures" / "figure4_speedup.png"
    draw(src, dst)
    print(f"wrote {dst}")
