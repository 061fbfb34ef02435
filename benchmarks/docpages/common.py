"""Shared helpers of the results pages: load a result, name its source, format numbers and tables."""

from __future__ import annotations

import functools
import json
import subprocess
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks._common import RESULTS, ROOT
from benchmarks.registry import REGISTRY
from benchmarks.status import format_cost

DOCS = ROOT / "docs" / "results"

#: Code whose later commits the pages list under a result without provenance.
#: The code a result depends on: Python files only, so that a commit of generated docs under md/
#: (md/water/README.md) does not count as a code change and re-stale its own generated blocks.
CODE_PATHS = (":(glob)jaxabc/**/*.py", ":(glob)md/**/*.py")


def load(name: str) -> dict[str, Any] | None:
    """``benchmarks/results/<name>.json``, or None when it is not saved."""
    path = RESULTS / f"{name}.json"
    return json.loads(path.read_text()) if path.is_file() else None


def git(*args: str) -> str:
    """Stdout of ``git args`` in the repository ("" when git fails)."""
    out = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)
    return out.stdout.strip() if out.returncode == 0 else ""


def source(name: str, part: str | None = None, data: dict[str, Any] | None = None) -> str:
    """One Markdown line: the JSON, the commit that made it, its date and its status now."""
    rel = f"benchmarks/results/{name}.json"
    data = data if data is not None else load(name) or {}
    prov = data.get("provenance_parts", {}).get(part) if part else data.get("provenance")
    label = f"`{rel}`" + (f" (part `{part}`)" if part else "")
    if prov:
        commit = (prov.get("commit") or "?")[:10]
        dirty = "" if prov.get("tree_clean", True) else " plus uncommitted changes"
        return (
            f"Source: {label}, made at commit `{commit}`{dirty} on {prov.get('date_utc', '?')} "
            f"in {format_cost(prov.get('cost_s'))} by `{prov.get('command', '?')}`."
        )
    saved = git("log", "-1", "--format=%h %ad", "--date=short", "--", rel)
    if not saved:
        return f"Source: {label} (not committed yet; no provenance recorded)."
    commit, date = saved.split(" ", 1)
    later = git("rev-list", "--count", f"{commit}..HEAD", "--", *CODE_PATHS) or "?"
    return (
        f"Source: {label}, saved at commit `{commit}` ({date}; no provenance recorded: the code "
        f"version is that of the commit that saved it); {later} later commits changed Python files under "
        "`jaxabc/` or `md/`."
    )


def sources_by_part(name: str, parts: Sequence[str], data: dict[str, Any]) -> str:
    """The source lines of a result written a part at a time: one per part in ``parts`` that has
    its own provenance, then one for the rest (a file saved whole before it was split: the
    provenance of that whole run, ``provenance_before_parts`` once a part was rewritten)."""
    own = data.get("provenance_parts") or {}
    lines = [source(name, part, data) for part in parts if part in own]
    rest = [part for part in parts if part not in own]
    if rest:
        before = data.get("provenance_before_parts")
        whole = source(name, None, {**data, "provenance": before} if before else data).removesuffix(".")
        lines.append(f"{whole} (parts {', '.join(f'`{r}`' for r in rest)}).")
    return "\n\n".join(lines)


def retired(prefixes: Sequence[str]) -> str:
    """A Markdown list of the retired registry entries whose names start with one of ``prefixes``
    (why each was retired and what supersedes it), or "" when there are none."""
    rows = [e for e in REGISTRY if e.retired and e.name.startswith(tuple(prefixes))]
    return "\n".join(f"- `{e.name}`: {e.retired}." for e in rows)


def figure(rel: str, caption: str) -> str:
    """A Markdown image of ``benchmarks/results/<rel>`` (published by ``mkdocs_figures.py``).

    Raises FileNotFoundError when the figure is not saved, so that a page never links to nothing.
    """
    path = RESULTS / rel
    if not path.is_file() or path.suffix != ".png" or rel.startswith("quick/"):
        raise FileNotFoundError(f"no published figure benchmarks/results/{rel}")
    return f"![{caption}](figures/{rel})\n\n*{caption}* (`benchmarks/results/{rel}`)"


def table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A Markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def f(x: float | None, digits: int = 3) -> str:
    """Fixed-point with ``digits`` decimals; '-' for None."""
    return "-" if x is None else f"{x:.{digits}f}"


def g(x: float | None, digits: int = 3) -> str:
    """``digits`` significant figures; '-' for None."""
    return "-" if x is None else f"{x:.{digits}g}"


def span(values: Sequence[float], digits: int = 2) -> str:
    """'a' or 'a-b' for the min and max of ``values``."""
    lo, hi = f(min(values), digits), f(max(values), digits)
    return lo if lo == hi else f"{lo}-{hi}"


#: What the misfit table's band and z each measure (they answer different questions).
MISFIT_NOTE = (
    "The band is the posterior predictive's central 90 % over posterior draws (it includes the "
    "parameters' uncertainty); z is the residual left after the best linearised refit of the base "
    "parameters to the fitted summaries, in units of the simulator's noise (and the prior's spread) "
    "at the posterior point (`jaxabc.criticism`): an observed value can lie inside the band and still "
    "have a large |z| when no single parameter value fits it together with the fitted summaries."
)


def misfit_rows(d: dict[str, Any], limit: int) -> list[list[str]]:
    """Rows of a criticism report's first ``limit`` misfits."""
    return [
        [
            m["name"],
            f(m["observed"], 3),
            f"{f(m['band'][0], 3)}-{f(m['band'][1], 3)}",
            f(m["residual"], 1),
            g(m["adjusted_p_value"], 2),
            "held out" if m["held_out"] else "fitted",
        ]
        for m in d["misfits"][:limit]
    ]


def cause_rows(d: dict[str, Any]) -> list[list[str]]:
    """Rows of a criticism report's ranked causes."""
    return [
        [
            c["name"],
            f(c["score"], 1),
            f"{100 * c['fraction_explained']:.0f} %",
            g(c["adjusted_p_value"], 2),
            "yes" if c["ambiguous"] else "no",
            c.get("note", ""),
        ]
        for c in d["causes"]
    ]


def sourced_table(names: Sequence[str], header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A generated block: the source line of each result, then the table."""
    return "\n\n".join([*(source(n) for n in names), table(header, rows)])


@functools.cache
def saved_extension(path: Path) -> Any:
    """A criticism's saved extension refit (a :class:`jaxabc.ABCResult`), or None when not saved;
    read once per page build (a criticism's section and its comparison both ask)."""
    if not path.is_file():
        return None
    import warnings

    import jaxabc

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return jaxabc.load(path)


def extension_edges(result: Any) -> list[str]:
    """The prior-edge warnings of an extension refit ([] when none or not saved)."""
    if result is None:
        return []
    return list((result.diagnostics.get("prior_edge") or {}).get("messages", []))
