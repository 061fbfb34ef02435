"""Beyond the paper: posterior-predictive g_OO and g_OH of every model of the water model choice.

Redrawn from the ``predictive`` entry of ``benchmarks/results/water_model_choice.json`` (written
by ``benchmarks/water_model_choice.py``: GROMACS runs at posterior draws of each model, with the
5, 25, 50, 75 and 95 % points of g_OO and the intermolecular g_OH on a common r grid); runs no
simulation.  Left: g_OO against the curve the models were fitted to.  Right: g_OH against
Soper's (2013) neutron g_OH, which the X-ray fit never saw (a held-out check of the structure
around the hydrogens; for a neutron model choice it is fitted data).  Bands: 5-95 %, line: median.

Writes ``figure_water_model_choice.png`` and prints, per model, the height of the median's first
g_OO and g_OH peaks beside the measured ones.

Usage::

    python -m paper_figures.figure_water_model_choice [out_dir]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from md.water import datasets

ROOT = Path(__file__).resolve().parent.parent
RESULT = ROOT / "benchmarks" / "results" / "water_model_choice.json"
OUT = Path(__file__).resolve().parent / "out"
#: Where each panel's first peak is looked for (nm): g_OO's first shell, g_OH's hydrogen bond.
PEAK_WINDOWS = {"g_oo": (0.24, 0.33), "g_oh": (0.15, 0.22)}


def first_peak(r: np.ndarray, g: np.ndarray, window: tuple[float, float]) -> float:
    """Height of the largest value of ``g`` inside ``window``."""
    inside = (r >= window[0]) & (r <= window[1])
    return float(np.max(g[inside])) if inside.any() else float("nan")


def main(out_dir: str | Path | None = None) -> Path:
    """Draw the figure; FileNotFoundError when the model choice has not been run."""
    if not RESULT.exists():
        raise FileNotFoundError(f"{RESULT.relative_to(ROOT)} (run benchmarks/water_model_choice.py)")
    d = json.loads(RESULT.read_text())
    bands = d.get("predictive")
    if not bands:
        raise FileNotFoundError(f"no predictive entry in {RESULT.relative_to(ROOT)}")
    out = Path(out_dir) if out_dir is not None else OUT
    out.mkdir(parents=True, exist_ok=True)
    r = np.asarray(bands["r_nm"])
    fitted = datasets.xray_goo() if d["data"] == "xray" else datasets.neutron_curves()["OO"]
    soper_oh = datasets.neutron_curves()["OH"]
    measured = {
        "g_oo": (fitted, f"measured ({d['data']}, fitted)"),
        "g_oh": (soper_oh, "neutron, Soper 2013" + (" (not fitted)" if d["data"] == "xray" else " (fitted)")),
    }
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    rows = []
    for ax, key, label, xlim in zip(
        axes, ("g_oo", "g_oh"), ("g_OO(r)", "g_OH(r), intermolecular"), ((0.22, 0.8), (0.14, 0.8)), strict=True
    ):
        for i, (name, entry) in enumerate(bands["models"].items()):
            if key not in entry:
                continue
            q = np.asarray(entry[key])
            ax.fill_between(r, q[0], q[-1], color=f"C{i}", alpha=0.2)
            ax.plot(r, q[len(q) // 2], color=f"C{i}", lw=1, label=f"{name} ({entry['num_runs']} runs)")
            rows.append((name, key, first_peak(r, q[len(q) // 2], PEAK_WINDOWS[key])))
        curve, curve_label = measured[key]
        ax.plot(curve.r_nm, curve.g, "k-", lw=1.5, label=curve_label)
        rows.append(("measured", key, first_peak(np.asarray(curve.r_nm), np.asarray(curve.g), PEAK_WINDOWS[key])))
        ax.set_xlim(*xlim)
        ax.set_xlabel("r [nm]")
        ax.set_ylabel(label)
        ax.legend(fontsize=7)
    fig.suptitle(f"Water model choice ({d['data']} joint data): posterior-predictive 5-95 % bands and medians")
    fig.tight_layout()
    path = out / "figure_water_model_choice.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    for name, key, height in rows:
        print(f"{name:12s} {key}: first peak {height:.3f}")
    return path


if __name__ == "__main__":
    print(main(sys.argv[1] if len(sys.argv) > 1 else None))
