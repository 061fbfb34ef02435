"""Model criticism of Lennard-Jones argon on measured data: :mod:`criticism_neon` with ``--fluid argon``.

The expected cause is the Axilrod-Teller triple-dipole term (C9 = 521 hartree bohr^9); see
``criticism_neon.py`` for the protocol, the data's provenance and the options; its ``main``
saves ``benchmarks/results/criticism_argon.json`` through ``_common.write_result(...)``.

Usage::

    python -m benchmarks.criticism_argon
"""

from __future__ import annotations

import sys

from benchmarks.criticism_neon import main

if __name__ == "__main__":
    # Through argv, so that the result records a command that reruns argon.
    main(["--fluid", "argon", *sys.argv[1:]])
