"""Redraw every figure of Dutta, Brotzakis & Mira (2018) from the saved results.

Runs each script's ``main(out_dir)`` in the order of the paper (see ``paper_figures/README.md``
for which results each reads and which command writes them).  No simulation runs.  A figure
whose input files are missing is reported and skipped; the others are still drawn.

Usage::

    python -m paper_figures.make_all [out_dir]        # default paper_figures/out
"""

from __future__ import annotations

import importlib.util
import sys
import time
import traceback
from pathlib import Path
from types import ModuleType

#: The scripts import ``jaxabc``, ``md`` and ``benchmarks``: run with ``python -m`` from the repository root.
HERE = Path(__file__).resolve().parent

#: Script (in paper_figures/) for each figure, in the paper's order, with the paper's LaTeX labels.
SCRIPTS: dict[str, str] = {
    "figure_summary_statistics": "fig:summ_stat",
    "figure3_imbalance": "fig:imbalance",
    "figure_mpi_workflow": "fig:MPI_workflow_comparison",
    "figure4_speedup": "fig:comp_abcsubsim_apmcabc",
    "figure5_helium_posterior": "fig:helium_sim (and table:compare_algo)",
    "figure_water_posteriors": "fig:md_apmcabc_sim, fig:neutron_data, fig:xray_data",
    "figure_water_predictive": "fig:pred_neutron_data, fig:pred_xray_data",
    "figure_water_model_choice": "beyond the paper: the water model choice's predictive g_OO and g_OH",
}


def load_script(name: str) -> ModuleType:
    """Import ``paper_figures/<name>.py`` by path, under a name of its own.

    Parameters
    ----------
    name : str
        Script name without ``.py``.

    Returns
    -------
    module
    """
    spec = importlib.util.spec_from_file_location(f"paper_figures_{name}", HERE / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def main(out_dir: str | Path | None = None) -> dict[str, Path | None]:
    """Run every figure script.

    Parameters
    ----------
    out_dir : path-like, optional
        Where the PNGs go; default ``paper_figures/out``.

    Returns
    -------
    dict
        Script name -> PNG written, or None where its inputs were missing or it failed.
    """
    written: dict[str, Path | None] = {}
    for name, labels in SCRIPTS.items():
        print(f"=== {name} ({labels})")
        t0 = time.perf_counter()
        try:
            written[name] = load_script(name).main(out_dir)
        except FileNotFoundError as error:
            print(f"skipped: {error}")
            written[name] = None
        except Exception:  # keep drawing the others; the traceback says what broke
            traceback.print_exc()
            written[name] = None
        else:
            print(f"wrote {written[name]} ({time.perf_counter() - t0:.1f} s)")
    missing = [name for name, path in written.items() if path is None]
    summary = f"{len(written) - len(missing)} of {len(written)} figures drawn"
    print(summary + (f"; not drawn: {missing}" if missing else ""))
    return written


if __name__ == "__main__":
    result = main(sys.argv[1] if len(sys.argv) > 1 else None)
    sys.exit(0 if all(result.values()) else 1)
