"""Figures ``fig:md_apmcabc_sim``, ``fig:neutron_data``, ``fig:xray_data`` of Dutta et al. (2018).

The water posteriors of TIP4P's oxygen Lennard-Jones parameters (sigma_OW, epsilon_OW), redrawn
from saved results only (written by ``benchmarks/water_calibration.py --algorithm surrogate``; the
earlier APMCABC runs, 5-10 particles each, are retired in ``benchmarks/registry.py``):

* ``benchmarks/results/water_{simulated,neutron,xray}_surrogate.json``: per statistics variant
  (``robust``, ``paper``) the Bayes estimate, posterior correlation, truth (simulated data) and
  the paper's numbers;
* for the ``paper`` statistics, ``water_{data}_surrogate_abc.json`` and its ``.npz`` when saved:
  the surrogate's ABC mode on the paper's unscaled distance, the paper's own target;
* ``benchmarks/results/water_{data}_{variant}_surrogate.npz``: the posterior draws (``jaxabc.load``), whose
  weighted Gaussian-KDE contours (red, as the paper; the same KDE as ``ABCResult.plot_posterior``),
  particles, Bayes estimate (star) and truth (green cross) are drawn.

One row per dataset: simulated (the paper's Figure 6), neutron (Figure 7: measured g_OH, g_OO,
posterior) and X-ray (Figure 8: measured g_OO, posterior); one posterior panel per statistics
variant found.  Each posterior panel also marks the paper's Bayes estimate (blue diamond), the
paper's published final APMCABC generation (orange dots, ``md.water.datasets.published_posterior``)
and, for measured data, TIP4P's own parameters (grey plus).  A dataset whose files are missing is
skipped with a printed message.  Writes ``paper_figures/out/figure_water_posteriors.png`` and
prints the estimates next to the paper's.

Usage::

    python -m paper_figures.figure_water_posteriors
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import jaxabc
from md.water import datasets

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
OUT = Path(__file__).resolve().parent / "out"
DATASETS = ("simulated", "neutron", "xray")
VARIANTS = ("robust", "paper")
TITLES = {
    "simulated": "simulated data (TIP4P, quick preset)",
    "neutron": "neutron data (Soper 2013 g_OH, g_OO; D 2.30e-5 cm^2/s)",
    "xray": "X-ray data (Skinner 2013 g_OO; D 2.30e-5 cm^2/s)",
}
PAPER_FIGURE = {"simulated": "fig:md_apmcabc_sim", "neutron": "fig:neutron_data", "xray": "fig:xray_data"}
#: TIP4P's own (sigma_OW nm, epsilon_OW kJ/mol), GROMACS oplsaa.ff/tip4p.itp.
TIP4P_THETA = (0.315365, 0.64852)
#: File-name suffix of the calibrations drawn: the GP surrogate's (the APMCABC ones are retired).
SUFFIX = "_surrogate"


def available(data: str) -> tuple[dict, list[str]]:
    """The posteriors of a dataset by statistics variant, and the variants found.

    A variant's entry is the calibration's JSON entry plus ``"npz"`` (its posterior file) and
    ``"mode"``.  For the ``paper`` statistics the surrogate's ABC mode on the paper's distance (the
    paper's own target) is preferred when saved, else the synthetic likelihood.

    Parameters
    ----------
    data : {"simulated", "neutron", "xray"}

    Returns
    -------
    (dict, list of str)
        Empty when nothing is saved; a message is printed for everything skipped.
    """
    table: dict = {}
    for variant in VARIANTS:
        modes = (("_abc", "ABC on the paper's distance"), ("", "synthetic likelihood"))
        for extra, mode in modes if variant == "paper" else modes[1:]:
            path = RESULTS / f"water_{data}{SUFFIX}{extra}.json"
            npz = RESULTS / f"water_{data}_{variant}{SUFFIX}{extra}.npz"
            entry = json.loads(path.read_text()).get(variant) if path.exists() else None
            if entry and npz.exists():
                table[variant] = {**entry, "npz": npz, "mode": mode}
                break
    if not table:
        print(
            f"skipping {data}: no water_{data}{SUFFIX}*.json with a posterior in {RESULTS.relative_to(ROOT)} (run: "
            f"python -m benchmarks.water_calibration --data {data} --statistics robust --algorithm surrogate)"
        )
    return table, list(table)


def _curve_panel(ax: plt.Axes, pair: str, data: str) -> None:
    if pair == "OO" and data == "xray":
        curve, label = datasets.xray_goo(), "X-ray, Skinner et al. 2013 (295 K)"
    else:
        curve, label = datasets.neutron_curves()[pair], "neutron/EPSR, Soper 2013 (298 K)"
    ax.plot(curve.r_nm, curve.g, color="k", lw=1.2, label=label)
    ax.fill_between(
        curve.r_nm, curve.g - curve.error, curve.g + curve.error, color="tab:gray", alpha=0.4, label="quoted error"
    )
    ax.set_xlim(0.0, 1.0)
    ax.set_ylim(-0.1, 1.1 * float(np.max(curve.g)))
    ax.set_xlabel("r (nm)")
    ax.set_ylabel(f"g_{pair}(r)")
    ax.set_title(f"measured g_{pair}", fontsize=9)
    ax.legend(fontsize=7, loc="upper right")


def _kde_contours(ax: plt.Axes, particles: np.ndarray, weights: np.ndarray, xlim: tuple, ylim: tuple) -> None:
    """Weighted Gaussian-KDE contours (as ``ABCResult.plot_posterior``) on the panel's whole range."""
    from scipy.stats import gaussian_kde

    try:
        kde = gaussian_kde(particles.T, weights=weights)
    except (np.linalg.LinAlgError, ValueError):
        return  # a degenerate sample has no KDE; the scatter still shows it
    gx, gy = np.meshgrid(np.linspace(*xlim, 200), np.linspace(*ylim, 200))
    z = kde(np.vstack([gx.ravel(), gy.ravel()])).reshape(gx.shape)
    levels = np.linspace(0.0, z.max(), 9)[1:]
    ax.contourf(gx, gy, z, levels=[*levels, z.max() * 1.001], cmap="Reds", alpha=0.8)
    ax.contour(gx, gy, z, levels=levels, colors="darkred", linewidths=0.5)


def _posterior_panel(ax: plt.Axes, data: str, variant: str, entry: dict) -> None:
    result = jaxabc.load(entry["npz"])
    particles, weights = np.asarray(result.particles)[:, :2], np.asarray(result.weights, dtype=np.float64)
    published = datasets.published_posterior(data)
    paper = entry["paper"]["bayes_estimate"]
    est = entry["bayes_estimate"]
    points = np.vstack([particles, published[:, :2], [paper], [TIP4P_THETA]])
    lo, hi = points.min(axis=0), points.max(axis=0)
    pad = 0.08 * (hi - lo)
    xlim, ylim = (lo[0] - pad[0], hi[0] + pad[0]), (lo[1] - pad[1], hi[1] + pad[1])
    _kde_contours(ax, particles, weights, xlim, ylim)
    ax.scatter(
        particles[:, 0],
        particles[:, 1],
        s=6 + 60 * weights / weights.max(),
        c="k",
        alpha=0.5,
        lw=0,
        label=f"posterior particles ({particles.shape[0]}, size ~ weight)",
    )
    ax.scatter(
        published[:, 0],
        published[:, 1],
        s=5,
        color="tab:orange",
        alpha=0.6,
        label=f"paper's final generation ({published.shape[0]}, published)",
    )
    ax.plot(est[0], est[1], "*", color="k", mfc="yellow", ms=15, label="Bayes estimate (here)")
    ax.plot(
        paper[0],
        paper[1],
        "D",
        color="tab:blue",
        ms=7,
        mfc="none",
        mew=1.5,
        label=f"paper's estimate ({paper[0]}, {paper[1]})",
    )
    if entry.get("truth") is not None:
        ax.plot(*entry["truth"], "X", color="tab:green", ms=10, label="true value")
    else:
        ax.plot(*TIP4P_THETA, "+", color="tab:gray", ms=12, mew=2, label="TIP4P (0.3154, 0.649)")
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.set_xlabel("sigma_OW (nm)")
    ax.set_ylabel("epsilon_OW (kJ/mol)")
    ax.set_title(
        f"{variant} statistics, {entry['mode']}\nestimate ({est[0]:.4f}, {est[1]:.3f}), "
        f"corr {entry['correlation']:+.3f} (paper {entry['paper']['correlation']:+.3f}), "
        f"{entry['num_simulations']} simulations ({entry['num_failures']} failed), "
        f"final threshold {entry['final_threshold']:.3g}",
        fontsize=8,
    )
    ax.legend(fontsize=6, loc="upper right")


def main(out_dir: str | Path | None = None) -> Path:
    """Draw every available water posterior and print the comparison with the paper.

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
        If no dataset has results.
    """
    rows = [(data, *available(data)) for data in DATASETS]
    rows = [row for row in rows if row[2]]
    if not rows:
        raise FileNotFoundError(f"no water calibration results in {RESULTS}")
    curve_pairs = {"simulated": (), "neutron": ("OH", "OO"), "xray": ("OO",)}
    num_cols = max(len(curve_pairs[data]) + len(variants) for data, _, variants in rows)
    fig = plt.figure(figsize=(5.4 * num_cols, 4.9 * len(rows)), layout="constrained")
    subfigs = np.atleast_1d(fig.subfigures(len(rows), 1))
    lines = []
    for subfig, (data, table, variants) in zip(subfigs, rows, strict=True):
        row_axes = subfig.subplots(1, num_cols, squeeze=False)[0]
        col = 0
        for pair in curve_pairs[data]:
            _curve_panel(row_axes[col], pair, data)
            col += 1
        for variant in variants:
            _posterior_panel(row_axes[col], data, variant, table[variant])
            col += 1
            entry = table[variant]
            lines.append(
                f"{data:<9} {variant:<6} {entry['bayes_estimate'][0]:8.4f} {entry['bayes_estimate'][1]:8.3f} "
                f"{entry['correlation']:+7.3f}   {entry['paper']['bayes_estimate'][0]:8.4f} "
                f"{entry['paper']['bayes_estimate'][1]:8.3f} {entry['paper']['correlation']:+7.3f}"
            )
        for ax in row_axes[col:]:
            ax.axis("off")
        subfig.suptitle(f"{TITLES[data]}   [{PAPER_FIGURE[data]}]", fontsize=10, fontweight="bold")
    out = Path(out_dir) if out_dir is not None else OUT
    out.mkdir(parents=True, exist_ok=True)
    path = out / "figure_water_posteriors.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"{'data':<9} {'stats':<6} {'sigma':>8} {'epsilon':>8} {'corr':>7}   {'paper:':>8} {'':>8} {'':>7}")
    print("\n".join(lines))
    return path


if __name__ == "__main__":
    print(main())
