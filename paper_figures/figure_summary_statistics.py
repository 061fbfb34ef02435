"""Figure ``fig:summ_stat`` of Dutta et al. (2018): the summary statistics S1..S9 of water.

Redraws from ``benchmarks/results/water_example_curves.json`` (written by
``benchmarks/water_example_curves.py``: one GROMACS TIP4P run, ``quick`` preset, at TIP4P's own
parameters) and the measured curves in ``md.water.datasets``; runs no simulation.  Three panels,
as the paper's (a) g_OH(r), (b) g_OO(r), (c) MSD, each marking where the ``robust`` statistics
(``md.water.statistics``) are read off:

(a) S1 = mean of g_OH over [0.12, 0.80] nm (shaded window, horizontal line), S2 = r of the first
    minimum after the hydrogen-bond peak (vertical line), S3 = integral of g_OH from 0.12 nm to S2
    (hatched area);
(b) S4 = mean of g_OO over [0.20, 0.80] nm, S5 = r of the first minimum, S6 = integral from
    0.20 nm to S5, S7 / S8 = height / position of the first maximum;
(c) S9 = D = slope / 6 of the oxygen MSD, fitted over 10-50 % of the longest lag (shaded).

The measured Soper 2013 neutron g_OH / g_OO (and the Skinner 2013 X-ray g_OO) are drawn
alongside, and in (c) the slope 6 D of water's measured D = 2.30e-5 cm^2/s at 298 K.  Writes
``paper_figures/out/figure_summary_statistics.png`` and prints S1..S9 of this run (both
variants) next to the paper's published "simulated observed" vector.

Usage::

    python -m paper_figures.figure_summary_statistics
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
INPUT = RESULTS / "water_example_curves.json"
#: Windows of the robust variant (md.water.statistics): g_OH and g_OO means and area starts.
OH_WINDOW_NM = (0.12, 0.80)
OO_WINDOW_NM = (0.20, 0.80)
#: 1 nm^2/ps = 1e3 x 1e-5 cm^2/s.
NM2_PER_PS_IN_1E5_CM2_PER_S = 1e3


def _area(ax: plt.Axes, r: np.ndarray, g: np.ndarray, lo: float, hi: float, color: str, label: str) -> None:
    """Hatch the area under the piecewise-linear curve from ``lo`` to ``hi``."""
    fine = np.linspace(lo, hi, 200)
    ax.fill_between(fine, 0.0, np.interp(fine, r, g), color=color, alpha=0.25, hatch="//", lw=0, label=label)


def _panel_oh(ax: plt.Axes, curves: dict, s: np.ndarray) -> None:
    r, g = np.asarray(curves["r_oh_nm"]), np.asarray(curves["g_oh"])
    measured = datasets.neutron_curves()["OH"]
    ax.plot(measured.r_nm, measured.g, "--", color="tab:gray", lw=1.2, label="neutron (Soper 2013)")
    ax.plot(r, g, color="tab:blue", lw=1.4, label="TIP4P simulation (quick preset)")
    ax.axvspan(*OH_WINDOW_NM, color="tab:green", alpha=0.06)
    ax.hlines(
        s[0],
        *OH_WINDOW_NM,
        color="tab:green",
        lw=1.5,
        label=f"S1 = {s[0]:.4f}: mean over [{OH_WINDOW_NM[0]}, {OH_WINDOW_NM[1]}] nm",
    )
    ax.axvline(s[1], color="tab:red", ls=":", lw=1.3, label=f"S2 = {s[1]:.4f} nm: first minimum")
    _area(ax, r, g, OH_WINDOW_NM[0], s[1], "tab:orange", f"S3 = {s[2]:.4f} nm: integral {OH_WINDOW_NM[0]} nm..S2")
    ax.set_xlim(0.0, 0.85)
    ax.set_ylim(0.0, max(1.6, 1.15 * float(np.max(g[r > OH_WINDOW_NM[0]]))))
    ax.set_xlabel("r (nm)")
    ax.set_ylabel("g_OH(r), intermolecular")
    ax.set_title("(a) O-H radial distribution: S1, S2, S3", fontsize=9)
    ax.legend(fontsize=7, loc="upper right")


def _panel_oo(ax: plt.Axes, curves: dict, s: np.ndarray) -> None:
    r, g = np.asarray(curves["r_oo_nm"]), np.asarray(curves["g_oo"])
    neutron = datasets.neutron_curves()["OO"]
    xray = datasets.xray_goo()
    ax.plot(neutron.r_nm, neutron.g, "--", color="tab:gray", lw=1.2, label="neutron (Soper 2013)")
    ax.plot(xray.r_nm, xray.g, ":", color="k", lw=1.0, label="X-ray (Skinner 2013)")
    ax.plot(r, g, color="tab:blue", lw=1.4, label="TIP4P simulation (quick preset)")
    ax.axvspan(*OO_WINDOW_NM, color="tab:green", alpha=0.06)
    ax.hlines(
        s[3],
        *OO_WINDOW_NM,
        color="tab:green",
        lw=1.5,
        label=f"S4 = {s[3]:.4f}: mean over [{OO_WINDOW_NM[0]}, {OO_WINDOW_NM[1]}] nm",
    )
    ax.axvline(s[4], color="tab:red", ls=":", lw=1.3, label=f"S5 = {s[4]:.4f} nm: first minimum")
    _area(ax, r, g, OO_WINDOW_NM[0], s[4], "tab:orange", f"S6 = {s[5]:.4f} nm: integral {OO_WINDOW_NM[0]} nm..S5")
    ax.plot([s[7]], [s[6]], "o", color="tab:purple", ms=6, zorder=5)
    ax.hlines(s[6], 0.0, s[7], color="tab:purple", ls="--", lw=1.0, label=f"S7 = {s[6]:.3f}: height of first maximum")
    ax.vlines(s[7], 0.0, s[6], color="tab:purple", ls="-.", lw=1.0, label=f"S8 = {s[7]:.4f} nm: its position")
    ax.set_xlim(0.0, 0.85)
    ax.set_ylim(0.0, 1.12 * max(float(np.max(g)), float(np.max(neutron.g))))
    ax.set_xlabel("r (nm)")
    ax.set_ylabel("g_OO(r)")
    ax.set_title("(b) O-O radial distribution: S4 ... S8", fontsize=9)
    ax.legend(fontsize=7, loc="upper right")


def _panel_msd(ax: plt.Axes, curves: dict, s: np.ndarray, window_ps: list[float]) -> float:
    lag, msd = np.asarray(curves["lag_ps"]), np.asarray(curves["msd_nm2"])
    mask = (lag >= window_ps[0] - 1e-9) & (lag <= window_ps[1] + 1e-9)
    slope, intercept = np.polyfit(lag[mask], msd[mask], 1)
    d_refit = slope / 6.0 * NM2_PER_PS_IN_1E5_CM2_PER_S
    ax.plot(lag, msd, "o-", color="tab:blue", ms=2.5, lw=1.0, label="TIP4P simulation: oxygen MSD")
    ax.axvspan(
        *window_ps,
        color="tab:green",
        alpha=0.08,
        label=f"fit window {window_ps[0]:.1f}-{window_ps[1]:.1f} ps (10-50 % of the longest lag)",
    )
    ax.plot(
        lag,
        intercept + slope * lag,
        color="tab:red",
        lw=1.3,
        label=f"slope {slope:.4f} nm^2/ps: S9 = D = slope/6 = {s[8]:.3f}e-5 cm^2/s",
    )
    slope_exp = 6.0 * datasets.DIFFUSION_298K_CM2_S * 1e2
    mid = 0.5 * (window_ps[0] + window_ps[1])
    ax.plot(
        lag,
        intercept + slope * mid + slope_exp * (lag - mid),
        ":",
        color="k",
        lw=1.0,
        label=f"measured D = {datasets.DIFFUSION_298K_CM2_S * 1e5:.2f}e-5 cm^2/s (298 K): slope {slope_exp:.4f}",
    )
    ax.set_xlabel("lag (ps)")
    ax.set_ylabel("MSD (nm^2)")
    ax.set_xlim(0.0, float(lag[-1]))
    ax.set_ylim(0.0, 1.1 * float(np.max(msd)))
    ax.set_title("(c) mean squared displacement of O: S9", fontsize=9)
    ax.legend(fontsize=7, loc="upper left")
    return float(d_refit)


def main(out_dir: str | Path | None = None) -> Path:
    """Draw the figure and print the statistics.

    Parameters
    ----------
    out_dir : path-like, optional
        Where to write the PNG; default ``paper_figures/out``.

    Returns
    -------
    pathlib.Path
        The PNG written.
    """
    data = json.loads(INPUT.read_text())
    curves = data["curves"]["robust"]
    robust = np.asarray(data["statistics"]["robust"]["values"], dtype=np.float64)
    window = data["statistics"]["robust"]["msd_fit_window_ps"]
    setup = data["setup"]
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8))
    _panel_oh(axes[0], curves, robust)
    _panel_oo(axes[1], curves, robust)
    d_refit = _panel_msd(axes[2], curves, robust, window)
    fig.suptitle(
        f"Summary statistics S1..S9 (robust variant) of one TIP4P run: GROMACS {setup['preset']} preset, "
        f"{setup['num_molecules']} molecules, sigma {setup['theta'][0]} nm, epsilon {setup['theta'][1]} "
        f"kJ/mol, analysed from {setup['protocol']['analysis_start_ps']} ps, density "
        f"{curves['density_kg_m3']:.1f} kg/m3",
        fontsize=9,
    )
    fig.tight_layout()
    out = Path(out_dir) if out_dir is not None else OUT
    out.mkdir(parents=True, exist_ok=True)
    path = out / "figure_summary_statistics.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)

    paper_variant = np.asarray(data["statistics"]["paper"]["values"], dtype=np.float64)
    published = datasets.published_statistics("simulated")
    units_r = data["statistics"]["robust"]["units"]
    units_p = data["statistics"]["paper"]["units"]
    print("S1..S9 of this run (robust and paper variants) and the paper's published 'simulated observed' vector")
    print("(paper variant, 515 molecules, 100 ps; GROMACS of 2018):")
    print(f"{'statistic':<40} {'robust':>9} {'paper':>9} {'published':>10}  units (robust | paper)")
    for i, name in enumerate(data["statistic_names"]):
        print(f"{name:<40} {robust[i]:9.4f} {paper_variant[i]:9.4f} {published[i]:10.4f}  {units_r[i]} | {units_p[i]}")
    print(f"S9 refitted from the saved MSD: {d_refit:.4f} (saved {robust[8]:.4f}) x 1e-5 cm^2/s")
    return path


if __name__ == "__main__":
    print(main())
