"""The benchmarks and the results pipeline: ``python -m benchmarks.<name>`` from the repository root.

Each module writes a result JSON under ``benchmarks/results/`` with its provenance
(:mod:`benchmarks._common`); :mod:`benchmarks.registry` lists them, :mod:`benchmarks.status` says
which are current, :mod:`benchmarks.verify` re-checks them by their quick modes and
:mod:`benchmarks.make_docs` writes the results pages.
"""
