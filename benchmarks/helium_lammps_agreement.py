"""jax-md against LAMMPS on the same helium system: T, P, V, f_B and the KL of f_B series.

Runs ``--seeds`` independent trajectories in each engine at the truth (and optionally at a
second parameter point) with the CPU preset, and writes the comparison of
:func:`md.lammps_reference.compare_with_jax_md` to
``benchmarks/results/helium_lammps_agreement.json``: for each mean quantity, the engines'
difference in units of its standard error (z), and the jax-md-vs-LAMMPS KL next to the jax-md
seed-to-seed KL.

Run: ``nice -n 5 python benchmarks/helium_lammps_agreement.py`` (about 1 minute).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import numpy as np

from md import helium, lammps_reference

RESULTS = Path(__file__).resolve().parent / "results" / "helium_lammps_agreement.json"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=48)
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args()
    records = []
    for i, theta in enumerate([helium.TRUE_THETA, (0.4, 0.5)]):
        r = lammps_reference.compare_with_jax_md(
            jax.random.PRNGKey(20 + i), theta, "cpu", num_seeds=args.seeds
        )
        records.append(r)
        zs = {k: round(v["z"], 2) for k, v in r["quantities"].items()}
        print(f"theta={theta}: z = {zs}; KL cross median {np.median(r['kl_cross']):.3f}, "
              f"seed-to-seed median {np.median(r['kl_jax_md_seed_to_seed']):.3f} "
              f"max {np.max(r['kl_jax_md_seed_to_seed']):.3f}", flush=True)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps({"description": __doc__, "records": records}, indent=1))


if __name__ == "__main__":
    main()
