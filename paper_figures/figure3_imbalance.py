"""Figure 3 of Dutta et al. (2018): imbalance of single-simulation wall time over prior draws.

Redraws from ``benchmarks/results/imbalance.json`` only (written by ``benchmarks/imbalance.py``):
one row per system (helium, water), with the histogram of wall times (failed runs stacked in a
second colour) and the prior draws coloured by their wall time.

Usage::

    python -m paper_figures.figure3_imbalance [imbalance.json] [figure3_imbalance.png]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
TITLES = {"helium": "Lennard-Jones helium (jax-md)", "water": "TIP4P water (GROMACS quick preset)"}


def draw(json_path: str | Path, png_path: str | Path) -> None:
    """Draw the figure from the saved JSON."""
    data = json.loads(Path(json_path).read_text())
    systems = [s for s in ("helium", "water") if s in data["systems"]]
    fig, axes = plt.subplots(len(systems), 2, figsize=(10, 3.8 * len(systems)), squeeze=False)
    for row, name in zip(axes, systems, strict=True):
        rec = data["systems"][name]
        t = np.asarray(rec["wall_time_s"])
        ok = np.asarray(rec["status"]) == 0
        theta = np.asarray(rec["theta"])
        st = rec["stats_all"]
        bins = np.linspace(t.min(), t.max(), 16) if t.max() > t.min() else 8
        row[0].hist(
            [t[ok], t[~ok]],
            bins=bins,
            stacked=True,
            color=["tab:blue", "tab:red"],
            label=[f"finished ({ok.sum()})", f"failed ({(~ok).sum()})"],
        )
        row[0].axvline(st["mean"], color="k", ls="--", lw=1, label=f"mean {st['mean']:.3g} s")
        row[0].set_xlabel("wall time of one simulation (s)")
        row[0].set_ylabel("prior draws")
        row[0].set_title(
            f"{TITLES[name]}\nCV {st['cv']:.2f}, max/mean {st['max_over_mean']:.2f}, {rec['how']}", fontsize=9
        )
        row[0].legend(fontsize=8)
        sc = row[1].scatter(
            theta[ok, 0],
            theta[ok, 1],
            c=t[ok],
            cmap="viridis",
            marker="o",
            vmin=t.min(),
            vmax=t.max(),
            label="finished",
        )
        row[1].scatter(
            theta[~ok, 0],
            theta[~ok, 1],
            c=t[~ok],
            cmap="viridis",
            marker="x",
            vmin=t.min(),
            vmax=t.max(),
            label="failed",
        )
        fig.colorbar(sc, ax=row[1], label="wall time (s)")
        names = rec["theta_names"]
        row[1].set_xlabel(names[0])
        row[1].set_ylabel(names[1])
        row[1].set_xlim(rec["prior_low"][0], rec["prior_high"][0])
        row[1].set_ylim(rec["prior_low"][1], rec["prior_high"][1])
        row[1].legend(fontsize=8)
        row[1].set_title("prior draws coloured by wall time", fontsize=9)
    machine = data["machine"]
    fig.suptitle(
        f"Imbalance of simulation time (measured; {machine['cpu_count']} cores, load {machine['load_average'][0]:.1f})",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(png_path, dpi=120)
    plt.close(fig)


def main(out_dir: str | Path | None = None) -> Path:
    """Draw from ``benchmarks/results/imbalance.json`` into ``out_dir`` (default ``paper_figures/out``).

    Used by ``paper_figures/make_all.py`` and the tests; the command line below keeps its own
    defaults.

    Returns
    -------
    pathlib.Path
        The PNG written.
    """
    out = Path(out_dir) if out_dir is not None else Path(__file__).resolve().parent / "out"
    out.mkdir(parents=True, exist_ok=True)
    path = out / "figure3_imbalance.png"
    draw(RESULTS / "imbalance.json", path)
    return path


if __name__ == "__main__":
    src = Path(sys.argv[1]) if len(sys.argv) > 1 else RESULTS / "imbalance.json"
    dst = Path(sys.argv[2]) if len(sys.argv) > 2 else ROOT / "paper_figures" / "figure3_imbalance.png"
    draw(src, dst)
    print(f"wrote {dst}")
