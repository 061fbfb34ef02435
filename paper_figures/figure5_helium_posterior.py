"""Figure 5 of the paper (helium posterior contours) and Table 1, redrawn from saved results.

Reads ``benchmarks/results/helium_table1_{apmcabc,abcsubsim}.npz`` and ``helium_table1.json``
(written by ``benchmarks/helium_table1.py``); runs no simulation.  Writes
``paper_figures/out/figure5_helium_posterior.png`` and prints Table 1 next to the paper's.
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import jaxabc

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
OUT = Path(__file__).resolve().parent / "out"


def main(out_dir: str | Path | None = None) -> Path:
    """Draw the figure into ``out_dir`` (default ``paper_figures/out``) and print Table 1; return the PNG."""
    table = json.loads((RESULTS / "helium_table1.json").read_text())
    truth = np.asarray(table["setup"]["truth"])
    names = ("apmcabc", "abcsubsim")
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, name in zip(axes, names, strict=True):
        result = jaxabc.load(RESULTS / f"helium_table1_{name}.npz")
        result.plot_posterior(ax=ax, truth=truth)
        row = table["algorithms"][name]
        ax.set_title(f"{name}: d_E {row['d_E']:.4f}, gamma_final {row['gamma_final']:.3g}")
    fig.tight_layout()
    out = Path(out_dir) if out_dir is not None else OUT
    out.mkdir(parents=True, exist_ok=True)
    path = out / "figure5_helium_posterior.png"
    fig.savefig(path, dpi=120)
    print(f"{'algorithm':<10} {'d_E':>9} {'(paper)':>9} {'gamma_final':>12} {'(paper)':>9} {'sims':>7}")
    for name in names:
        row = table["algorithms"][name]
        print(
            f"{name:<10} {row['d_E']:9.5f} {row['paper']['d_E']:9.5f} {row['gamma_final']:12.4g} "
            f"{row['paper']['gamma_final']:9.4g} {row['simulations']:7d}"
        )
    return path


if __name__ == "__main__":
    print(main())
