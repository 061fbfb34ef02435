"""Write the results pages ``docs/results/*.md`` from the saved JSON, never from typed numbers.

Each table names its source JSON and the commit that made it: the ``provenance`` the benchmark
helper recorded, or, for results saved before provenance existed, the last commit that changed
the file (``git log``), marked as such, with the later commits that touched the code under it.

Usage::

    python -m benchmarks.make_docs            # rewrite docs/results/
    python -m benchmarks.make_docs --check    # exit 1 if a page differs from what the JSON gives
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from benchmarks._common import RESULTS, ROOT
from benchmarks.docpages.common import DOCS, table
from benchmarks.docpages.criticism import page_criticism_fluids
from benchmarks.docpages.engine import page_abc_overhead, page_engine, page_speedup
from benchmarks.docpages.helium import page_coverage, page_helium_table1, page_identifiability, page_lammps
from benchmarks.docpages.model_choice import (
    block_water_model_choice,
    block_water_model_outcome,
    page_water_model_choice,
)
from benchmarks.docpages.reliability import page_reliability
from benchmarks.docpages.surrogate import (
    page_surrogate_classifier,
    page_surrogate_coverage,
    page_surrogate_helium,
    page_surrogate_honesty,
    page_surrogate_peers,
)
from benchmarks.docpages.water import (
    block_water_calibrations,
    block_water_prior_range,
    block_water_validation,
    page_water,
)
from benchmarks.docpages.water_jaxmd import page_density_relaxation, page_water_jaxmd
from benchmarks.registry import REGISTRY
from benchmarks.status import format_cost, status_of

_HONESTY_LINK = "- [Does the surrogate say when it is wrong?](surrogate_honesty.md)\n"


def page_index() -> str:
    rows, states = [], []
    for e in REGISTRY:
        st = status_of(e)
        states.append(st)
        rows.append(
            [
                f"`{e.name}`",
                f"{st.state} ({st.why})" if st.why else st.state,
                format_cost(st.cost_s) + ("" if st.cost_source.startswith("recorded") else " (est.)"),
                ", ".join(st.changed[:3]) + (" ..." if len(st.changed) > 3 else ""),
            ]
        )
    current = sum(st.state == "current" for st in states)
    retired = sum(st.state == "retired" for st in states)
    behind = [st for st in states if st.state not in ("current", "retired")]
    rerun_s = sum(st.cost_s or 0.0 for st in behind)
    return f"""# Results

Every number on these pages is read from `benchmarks/results/*.json` by `benchmarks/make_docs.py`;
each table names its JSON and the commit that made it, and the table at the end says whether
today's code still gives it.

- [Helium Table 1](helium_table1.md) and [the choice of the CPU preset](helium_identifiability.md)
- [Engine throughput](engine_throughput.md) and [agreement with LAMMPS](lammps_agreement.md)
- [Coverage of credible regions](coverage.md) and [of the surrogate posterior](surrogate_coverage.md)
- [Surrogate against APMCABC on helium](surrogate_helium.md) and [against sbi, BOLFI and pyABC](surrogate_peers.md)
{_HONESTY_LINK if "surrogate_honesty.md" in PAGES else ""}\
- [The surrogate's success classifier on the water runs](surrogate_classifier.md)
- [Speedup and scheduling](speedup.md)
- [Cost of an ABC step](abc_overhead.md)
- [Water calibrations](water_calibrations.md) and [the quick preset's density relaxation](water_density_relaxation.md)
- [Which water model the data prefer, and the criticism of it](water_model_choice.md)
- [Model criticism of neon and argon](criticism_fluids.md)
- [Reliability probes: what a hostile user sees](reliability.md)

## Does today's code still give each result?

When these pages were generated: {current} current, {len(behind)} not current ({format_cost(rerun_s)} to rerun
them by their recorded costs, on the machines that made them), {retired} retired.
`python -m benchmarks.status` says it now.

- **Current** means the result's code is unchanged, or it changed and the result's quick mode
  reruns on today's code to its saved quick numbers ("code changed, quick mode reproduces";
  `python -m benchmarks.verify --budget 30m`).  Where the numbers differ the result is `changed`;
  `python -m benchmarks.regenerate --budget 1h` reruns what fits, each after the results it reads.
- **Long runs** without a quick mode of their own (the hours-long water and criticism runs) name
  in the registry (`checked_by`) the quick modes that run their code path.  Such a result is
  current when, for every file that changed, one of those quick modes ran the file on today's
  code and reproduced numbers made with the result's own version of it ("quick mode of ...
  reproduces").  So the saved quick numbers are made on the same code as the long run
  (`python -m benchmarks.regenerate --quick --only NAME` right after it).
- **Baselines** made on another CPU family or from other code are remade here at the result's
  own commit, in a temporary git worktree (`python -m benchmarks.verify --rebaseline`), so that a
  check compares two code versions on one machine.  Every check runs its quick mode in an empty
  runs folder, never replaying the run caches of earlier code.
- **Links**: every check that reproduces is kept in a ledger as a link between two versions of
  the code, and status chains the links, so several long runs made at different commits can rest
  on one saved quick JSON.  A result whose files the saved quick numbers were not made with needs
  one quick run at its commit (`python -m benchmarks.verify --only CHECK --vouch-for RESULT
  --budget 1h`), not a rerun.  Data changes always call for a rerun.
- **Retired** results are no longer kept: the table gives why, what supersedes each and the
  commit of its last version; no page shows them.
- **Caches** and checkpoints live under `runs/` (not tracked).  A run longer than one sitting, on a
  machine that keeps only the git tree, parks its checkpoint (`python -m benchmarks.park save
  NAME`, committed under `benchmarks/parked/`); `regenerate` restores it on the next machine and
  drops it when the run has finished.

{table(["result", "state", "cost", "changed since"], rows)}
"""


PAGES: dict[str, Callable[[], str]] = {
    "index.md": page_index,
    "helium_table1.md": page_helium_table1,
    "helium_identifiability.md": page_identifiability,
    "engine_throughput.md": page_engine,
    "lammps_agreement.md": page_lammps,
    "coverage.md": page_coverage,
    "surrogate_coverage.md": page_surrogate_coverage,
    "surrogate_helium.md": page_surrogate_helium,
    "surrogate_peers.md": page_surrogate_peers,
    "surrogate_classifier.md": page_surrogate_classifier,
    "speedup.md": page_speedup,
    "abc_overhead.md": page_abc_overhead,
    "water_calibrations.md": page_water,
    "water_density_relaxation.md": page_density_relaxation,
    "water_jaxmd.md": page_water_jaxmd,
    "criticism_fluids.md": page_criticism_fluids,
}
if (RESULTS / "water_model_choice.json").is_file():
    # Hours of GROMACS: a page once there is a result to show (every page names its JSON).
    PAGES["water_model_choice.md"] = page_water_model_choice
if (RESULTS / "surrogate_honesty.json").is_file():
    PAGES["surrogate_honesty.md"] = page_surrogate_honesty
if (RESULTS / "reliability_probes.json").is_file():
    PAGES["reliability.md"] = page_reliability


#: Generated blocks inside hand-written Markdown: ``<!-- generated: NAME -->`` ... ``<!-- /generated -->``.
BLOCKS: dict[str, tuple[str, Callable[[], str]]] = {
    "water_model_choice": ("md/water/README.md", block_water_model_choice),
    "water_model_outcome": ("md/water/README.md", block_water_model_outcome),
    "water_calibrations": ("md/water/README.md", block_water_calibrations),
    "water_validation": ("md/water/README.md", block_water_validation),
    "water_prior_range": ("md/water/README.md", block_water_prior_range),
}


def fill_blocks(text: str, path: str) -> str:
    """``text`` with every generated block of ``path`` re-rendered (ValueError: a marker is missing)."""
    for name, (where, render) in BLOCKS.items():
        if where != path:
            continue
        start, end = f"<!-- generated: {name} -->", "<!-- /generated -->"
        i = text.find(start)
        j = text.find(end, i + 1)
        if i < 0 or j < 0:
            raise ValueError(f"{path} lacks the markers of the generated block {name!r}")
        text = text[: i + len(start)] + "\n" + render().rstrip() + "\n" + text[j:]
    return text


def main(argv: list[str] | None = None) -> int:
    """Write (or with ``--check`` compare) every page and generated block; exit 1 when one differs."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="compare instead of writing")
    parser.add_argument("--out", type=Path, default=DOCS)
    args = parser.parse_args(argv)
    differ = []
    for name, render in PAGES.items():
        text = render().rstrip() + "\n"
        path = args.out / name
        if args.check:
            if not path.is_file() or path.read_text() != text:
                differ.append(name)
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    for rel in sorted({where for where, _ in BLOCKS.values()}) if args.out == DOCS else []:
        path = ROOT / rel
        old = path.read_text()
        new = fill_blocks(old, rel)
        if args.check:
            if new != old:
                differ.append(rel)
        elif new != old:
            path.write_text(new)
    if differ:
        print(f"out of date: {', '.join(differ)} (run python -m benchmarks.make_docs)")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
