"""One TIP4P water simulation's curves and S1..S9, for the paper's summary-statistics figure.

Runs ONE GROMACS simulation with the ``quick`` preset (216 molecules, 20 ps NPT, analysed
5-20 ps) at TIP4P's own oxygen parameters (sigma_OW 0.315365 nm, epsilon_OW 0.64852 kJ/mol)
through the plugin (``md.water.make_simulator("quick", "robust")``), keeps the trajectory in a
temporary directory long enough to analyse it twice, and saves:

* ``curves.robust``: what the ``robust`` statistics are computed from (intermolecular g_OH,
  normalisation over non-excluded pairs, MSD with origins at every frame, drift removed);
* ``curves.paper``: the same trajectory analysed as the published pipeline did (g_OH with each
  molecule's own O-H pair, ``N_A N_B`` normalisation, MSD origins every 10 ps);
* ``statistics.robust`` / ``statistics.paper``: S1..S9 of each (:mod:`md.water.statistics`),
  with names and units; the robust MSD fitting window (10-50 % of the longest lag).

Writes ``benchmarks/results/water_example_curves.json`` (drawn by
``paper_figures/figure_summary_statistics.py``).  About 10-20 s on one core.

Usage::

    nice -n 15 python -m benchmarks.water_example_curves [--seed 0]
    python -m benchmarks.water_example_curves --quick   # same run, written to results/quick/
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks._common import command_line, write_result
from md.water import make_simulator
from md.water.analysis import WaterCurves, compute_curves, load_trajectory
from md.water.gromacs import TIP4P_PARAMETERS
from md.water.statistics import STATISTIC_NAMES, STATISTIC_UNITS, summary_statistics

TIP4P_THETA = np.array([TIP4P_PARAMETERS.sigma_ow_nm, TIP4P_PARAMETERS.epsilon_ow_kj_mol])
#: Fractions of the longest lag between which the robust S9 fits the MSD slope
#: (default of :func:`md.water.analysis.fit_msd_slope`).
MSD_WINDOW_FRACTION = (0.1, 0.5)


def curves_to_json(curves: WaterCurves) -> dict[str, Any]:
    """Plain-JSON form of :class:`md.water.analysis.WaterCurves`.

    Parameters
    ----------
    curves : WaterCurves

    Returns
    -------
    dict
        Every array field as a list of floats, plus density and ``intermolecular_oh``.
    """
    out: dict[str, Any] = {}
    for field in ("r_oo_nm", "g_oo", "r_oh_nm", "g_oh", "lag_ps", "msd_nm2"):
        out[field] = np.asarray(getattr(curves, field), dtype=np.float64).round(7).tolist()
    out["density_kg_m3"] = float(curves.density_kg_m3)
    out["intermolecular_oh"] = bool(curves.intermolecular_oh)
    return out


def parse_arguments(argv: list[str] | None = None) -> argparse.Namespace:
    """Command-line options."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=0, help="second word of the raw JAX key [0, seed]")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="write benchmarks/results/quick/water_example_curves.json (the run is already quick)",
    )
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> Path:
    """Run the simulation, analyse it both ways and write the JSON.

    Returns
    -------
    pathlib.Path
        The JSON written.
    """
    args = parse_arguments(argv)
    key = np.array([0, args.seed], np.uint32)
    simulator = make_simulator("quick", "robust")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="water_example_") as workdir:
        output = simulator.run(key, TIP4P_THETA, keep_directory=workdir)
        t_sim = time.perf_counter() - t0
        trajectory = load_trajectory(output.run.trajectory, start_ps=simulator.protocol.analysis_start_ps)
        paper_curves = compute_curves(trajectory, "paper", density_kg_m3=output.curves.density_kg_m3)
    paper_statistics = summary_statistics(paper_curves, "paper")
    robust_statistics = np.asarray(output.statistics, dtype=np.float64)
    lag = np.asarray(output.curves.lag_ps)
    window = [MSD_WINDOW_FRACTION[0] * float(lag[-1]), MSD_WINDOW_FRACTION[1] * float(lag[-1])]
    protocol = simulator.protocol
    path = write_result(
        "water_example_curves",
        {
            "description": __doc__.split("\n\n")[0],
            "setup": {
                "preset": protocol.name,
                "protocol": {k: v for k, v in protocol.__dict__.items() if isinstance(v, int | float | str | None)},
                "theta": TIP4P_THETA.tolist(),
                "theta_names": ["sigma_ow_nm", "epsilon_ow_kj_mol"],
                "key": key.tolist(),
                "gen_seed": int(output.run.gen_seed),
                "ld_seed": int(output.run.ld_seed),
                "num_molecules": int(output.run.num_molecules),
                "gromacs_wall_time_s": float(output.run.wall_time_s),
                "total_wall_time_s": t_sim,
            },
            "statistic_names": list(STATISTIC_NAMES),
            "statistics": {
                "robust": {
                    "values": robust_statistics.tolist(),
                    "units": list(STATISTIC_UNITS["robust"]),
                    "msd_fit_window_ps": window,
                },
                "paper": {
                    "values": paper_statistics.tolist(),
                    "units": list(STATISTIC_UNITS["paper"]),
                    "msd_fit_window_ps": [float(lag[2]), float(lag[-1])] if lag.size > 2 else None,
                },
            },
            "curves": {"robust": curves_to_json(output.curves), "paper": curves_to_json(paper_curves)},
        },
        quick=args.quick,
        command=None if argv is None else command_line([__file__, *argv]),
    )
    for variant, values in (("robust", robust_statistics), ("paper", paper_statistics)):
        print(f"{variant:>6}: " + ", ".join(f"S{i + 1} {v:.4g}" for i, v in enumerate(values)))
    print(f"GROMACS {output.run.wall_time_s:.1f} s, density {output.curves.density_kg_m3:.1f} kg/m3")
    return path


if __name__ == "__main__":
    print(f"wrote {main()}")
