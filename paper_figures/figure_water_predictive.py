"""Figures ``fig:pred_neutron_data`` and ``fig:pred_xray_data`` of Dutta et al. (2018).

Posterior-predictive g_OO(r) against the measured curve, redrawn from the ``predictive_goo``
entry of ``benchmarks/results/water_{neutron,xray}_surrogate.json`` (the APMCABC runs are retired),
written by ``benchmarks/water_calibration.py --algorithm surrogate --predictive N`` (g_OO of N
simulations at posterior draws, resampled onto r = 0.001..0.801 nm, with keys ``r_nm, min, q25,
median, q75, max, num_curves``); runs no simulation.  One panel per dataset and statistics
variant found: the band between minimum and maximum, the band between the 1/4 and 3/4
quantiles, the median (solid; the paper shows the mean, which was not saved) and the measured
g_OO (dashed: Soper 2013 for neutron, Skinner 2013 for X-ray).  A dataset whose JSON is missing
is skipped with a printed message.

Writes ``paper_figures/out/figure_water_predictive.png`` and prints, over r in [0.2, 0.8] nm,
the fraction of the measured curve inside each band (the paper: "mostly within the prediction
band ... except near the second maximum of g_OO").

Usage::

    python -m paper_figures.figure_water_predictive
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from md.water import datasets

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
OUT = Path(__file__).resolve().parent / "out"
DATASETS = ("neutron", "xray")
VARIANTS = ("robust", "paper")
PAPER_FIGURE = {"neutron": "fig:pred_neutron_data", "xray": "fig:pred_xray_data"}
#: r-window (nm) over which the band coverage is reported: the robust statistics' g_OO window.
WINDOW_NM = (0.2, 0.8)
#: File-name suffix of the calibrations drawn: the GP surrogate's (the APMCABC ones are retired).
SUFFIX = "_surrogate"


def measured_goo(data: str) -> datasets.ExperimentalCurve:
    """The measured g_OO of a dataset: Soper 2013 (neutron) or Skinner 2013 (X-ray)."""
    return datasets.xray_goo() if data == "xray" else datasets.neutron_curves()["OO"]


def entries() -> list[tuple[str, str, dict, dict]]:
    """``(data, variant, predictive_goo, variant entry)`` for everything saved, skipping the rest.

    Returns
    -------
    list of tuple
        Empty if nothing is saved; a message is printed for each dataset or variant skipped.
    """
    out = []
    for data in DATASETS:
        path = RESULTS / f"water_{data}{SUFFIX}.json"
        if not path.exists():
            print(
                f"skipping {data}: {path.relative_to(ROOT)} not found (run: python -m benchmarks.water_calibration "
                f"--data {data} --statistics robust --algorithm surrogate --predictive 20)"
            )
            continue
        table = json.loads(path.read_text())
        for variant in VARIANTS:
            if variant not in table:
                continue
            predictive = table[variant].get("predictive_goo")
            if not predictive:
                print(
                    f"skipping {data} / {variant}: no predictive_goo in {path.relative_to(ROOT)} "
                    "(run with --predictive N)"
                )
                continue
            out.append((data, variant, predictive, table[variant]))
    return out


def coverage(predictive: dict, curve: datasets.ExperimentalCurve) -> dict[str, float]:
    """Fraction of the measured g_OO inside the min-max and quartile bands over ``WINDOW_NM``.

    Parameters
    ----------
    predictive : dict
        ``predictive_goo`` entry.
    curve : ExperimentalCurve

    Returns
    -------
    dict
        ``{"min-max": fraction, "quartiles": fraction}``.
    """
    r = np.asarray(predictive["r_nm"], dtype=np.float64)
    keep = (r >= WINDOW_NM[0]) & (r <= WINDOW_NM[1])
    g = np.interp(r[keep], curve.r_nm, curve.g)

    def inside(lo: str, hi: str) -> float:
        return float(np.mean((g >= np.asarray(predictive[lo])[keep]) & (g <= np.asarray(predictive[hi])[keep])))

    return {"min-max": inside("min", "max"), "quartiles": inside("q25", "q75")}


def main(out_dir: str | Path | None = None) -> Path:
    """Draw the predictive bands and print their coverage of the measured curves.

    Parameters
    ----------
    out_dir : path-like, optional
        Where to write the PNG; default ``paper_figures/out``.

    Returns
    -------
    pathlib.Path
        The PNG written.

    Raises
    ------
    FileNotFoundError
        If no dataset has a saved ``predictive_goo``.
    """
    rows = entries()
    if not rows:
        raise FileNotFoundError(f"no predictive_goo in water_{{neutron,xray}}{SUFFIX}.json under {RESULTS}")
    fig, axes = plt.subplots(1, len(rows), figsize=(6.4 * len(rows), 5.0), squeeze=False)
    lines = []
    for ax, (data, variant, p, entry) in zip(axes[0], rows, strict=True):
        r = np.asarray(p["r_nm"])
        curve = measured_goo(data)
        ax.fill_between(r, p["min"], p["max"], color="tab:blue", alpha=0.2, lw=0, label="posterior predictive: min-max")
        ax.fill_between(r, p["q25"], p["q75"], color="tab:blue", alpha=0.45, lw=0, label="1/4 to 3/4 quantile")
        ax.plot(r, p["median"], color="tab:blue", lw=1.4, label="median")
        ax.plot(
            curve.r_nm,
            curve.g,
            "--",
            color="k",
            lw=1.2,
            label="measured: " + ("X-ray, Skinner 2013" if data == "xray" else "neutron/EPSR, Soper 2013"),
        )
        cov = coverage(p, curve)
        est = entry["bayes_estimate"]
        ax.set_xlim(0.2, float(r[-1]))
        ax.set_ylim(-0.05, 1.1 * max(float(np.max(p["max"])), float(np.max(curve.g))))
        ax.set_xlabel("r (nm)")
        ax.set_ylabel("g_OO(r)")
        ax.set_title(
            f"{data}, {variant} statistics [{PAPER_FIGURE[data]}]: {p['num_curves']} simulations at posterior "
            f"draws\nBayes estimate ({est[0]:.4f} nm, {est[1]:.3f} kJ/mol)\nmeasured curve inside min-max "
            f"{cov['min-max']:.0%}, inside quartiles {cov['quartiles']:.0%} of r in "
            f"[{WINDOW_NM[0]}, {WINDOW_NM[1]}] nm",
            fontsize=8,
        )
        ax.legend(fontsize=7, loc="upper right")
        lines.append(f"{data:<8} {variant:<7} {p['num_curves']:>6} {cov['min-max']:>8.0%} {cov['quartiles']:>10.0%}")
    fig.tight_layout()
    out = Path(out_dir) if out_dir is not None else OUT
    out.mkdir(parents=True, exist_ok=True)
    path = out / "figure_water_predictive.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    print(
        f"measured g_OO inside the posterior-predictive bands over r in [{WINDOW_NM[0]}, {WINDOW_NM[1]}] nm "
        "(paper: mostly inside, except near the second maximum):"
    )
    print(f"{'data':<8} {'stats':<7} {'curves':>6} {'min-max':>8} {'quartiles':>10}")
    print("\n".join(lines))
    return path


if __name__ == "__main__":
    print(main())
