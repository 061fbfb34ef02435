"""jax-md against LAMMPS on the same helium system: T, P, V, f_B and the KL of f_B series.

Runs ``--seeds`` independent trajectories in each engine at the truth (and, for the CPU preset,
at a second parameter point) with ``--preset`` (``cpu`` or the published ``paper`` settings:
1000 atoms, 1 atm, 0.2 ns + 2 ns), and writes the comparison of
:func:`md.lammps_reference.compare_with_jax_md` to
``benchmarks/results/helium_lammps_agreement.json``: for each mean quantity, the engines'
difference in units of its standard error (z), and the jax-md-vs-LAMMPS KL next to the jax-md
seed-to-seed KL.

Run: ``nice -n 5 python -m benchmarks.helium_lammps_agreement`` (about 1 minute), or
``--preset paper --seeds 4`` (about 15 minutes on 2 cores).  Entries of other presets already in
the JSON are kept.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import jax
import numpy as np

from benchmarks._common import write_result
from md import helium, lammps_reference

RESULTS = Path(__file__).resolve().parent / "results" / "helium_lammps_agreement.json"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=48)
    parser.add_argument("--preset", choices=("cpu", "paper"), default="cpu")
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args()
    old = json.loads(args.output.read_text()) if args.output.exists() else {}
    records = [r for r in old.get("records", []) if r["preset"]["name"] != args.preset]
    thetas = [helium.TRUE_THETA, (0.4, 0.5)] if args.preset == "cpu" else [helium.TRUE_THETA]
    for i, theta in enumerate(thetas):
        r = lammps_reference.compare_with_jax_md(jax.random.PRNGKey(20 + i), theta, args.preset, num_seeds=args.seeds)
        r["command"] = " ".join(["python", *sys.argv])
        records.append(r)
        zs = {k: round(v["z"], 2) for k, v in r["quantities"].items()}
        print(
            f"theta={theta}: z = {zs}; KL cross median {np.median(r['kl_cross']):.3f}, "
            f"seed-to-seed median {np.median(r['kl_jax_md_seed_to_seed']):.3f} "
            f"max {np.max(r['kl_jax_md_seed_to_seed']):.3f}",
            flush=True,
        )
    write_result(args.output, {"description": __doc__, "records": records}, part=args.preset)


if __name__ == "__main__":
    main()
