"""MkDocs hook: the results figures (``benchmarks/results/**/*.png``) become site files.

The results pages show each figure where its numbers are (:func:`docpages.common.figure` writes
``![...](figures/<path under benchmarks/results>)``); the PNGs stay where the benchmarks write
them, tracked once, and this hook adds them to the build under ``results/figures/`` so that
``mkdocs build --strict`` checks every link.  Quick-mode figures are not published.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

RESULTS = Path(__file__).resolve().parents[1] / "results"


def published() -> dict[str, Path]:
    """Site path (``results/figures/<rel>``) of every published figure, to its file."""
    out = {}
    for path in sorted(RESULTS.rglob("*.png")):
        rel = path.relative_to(RESULTS)
        if rel.parts[0] != "quick":
            out[f"results/figures/{rel.as_posix()}"] = path
    return out


def on_files(files: Files, config: Any) -> Files:
    for uri, path in published().items():
        files.append(File.generated(config, uri, abs_src_path=str(path)))
    return files
