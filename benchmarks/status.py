"""Which saved results does the current code still produce?  Currency is numerical.

For every entry of :data:`registry.REGISTRY` (and every other JSON in ``benchmarks/results/``)
this compares the fingerprint recorded at write time (per-file AST hashes of the project modules
the run imported, byte hashes of the data it declared) with the files as they are now.  The
fingerprint only decides whether a check must run; the numbers decide the state:

- ``current`` (code unchanged): nothing the result depends on changed (a reformatting or a
  docstring edit does not count: code is hashed without docstrings, comments or layout);
- ``current`` (code changed, quick mode reproduces): files changed, but ``benchmarks/verify.py``
  reran the result's quick mode on the code as it is now and got the saved quick numbers;
- ``changed`` (numbers changed): that check gave other numbers (the first differences are kept
  in ``benchmarks/results/verifications.json``): rerun the result;
- ``stale``: files changed and no check of the code as it is now exists (they are named);
- ``unknown`` (no provenance): the result records none (written before it existed, or by hand);
- ``retired``: the registry retired it (``Entry.retired`` says why and what supersedes it); its
  files are gone from ``benchmarks/results`` and no page shows it.

Modules that the current code would import but the recorded run did not (a new file after a
split) are seen through the files that import them, which changed.

Usage::

    python -m benchmarks.status            # or: python -m benchmarks.status
    python -m benchmarks.status --quick    # the quick-mode results under benchmarks/results/quick/
    python -m benchmarks.status --json
    python -m benchmarks.verify --budget 30m   # quick-mode checks of the stale results
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import math
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from benchmarks._common import ROOT, code_hash, data_hash, legacy_code_hash
from benchmarks.registry import CACHES, REGISTRY, TIMING_KEYS, VERIFICATIONS, Entry

__all__ = [
    "Status",
    "check_provenance",
    "compare_numbers",
    "deterministic_view",
    "differing_versions",
    "legacy_cost",
    "load_equivalences",
    "main",
    "standing_edge",
    "status_all",
    "status_of",
]


@dataclass
class Status:
    """The state of one saved result.

    ``cost_s`` is the recorded cost (``provenance.cost_s``, raised to the result's own
    ``rerun_cost_s`` where it states one: what rerunning its code costs when the run reused cached
    or imported work; a part's from ``rerun_cost_s_parts``), else the legacy wall-time fields'
    sum, else the registry's estimate; ``cost_source`` says which.
    """

    name: str
    output: str
    state: str  # "current", "changed", "stale", "unknown", "missing" or "retired"
    changed: list[str] = field(default_factory=list)
    why: str = ""  # "code unchanged", "code changed, quick mode reproduces", "numbers changed", ...
    cost_s: float | None = None
    cost_source: str = "none"
    commit: str | None = None
    date_utc: str | None = None
    tree_clean: bool | None = None
    long: bool = False
    note: str = ""


def check_provenance(prov: dict[str, Any], root: Path = ROOT) -> list[str]:
    """Files recorded in ``prov['fingerprint']`` whose content differs now (empty: current).

    Each entry is a repository-relative path, followed by `` (removed)`` when it no longer exists.
    """
    changed = []
    fp = prov.get("fingerprint", {})
    for kind, hasher in (("code", code_hash), ("data", data_hash)):
        for rel, recorded in fp.get(kind, {}).items():
            path = Path(rel) if Path(rel).is_absolute() else root / rel
            if not path.is_file():
                changed.append(f"{rel} (removed)")
            elif hasher(path) != recorded and not (kind == "code" and legacy_code_hash(path) == recorded):
                changed.append(rel)
    return changed


def _walk(data: Any, keys: list[str]) -> list[Any]:
    if not keys:
        return [data]
    head, rest = keys[0], keys[1:]
    if head == "*":
        values = data.values() if isinstance(data, dict) else data if isinstance(data, list) else []
        return [v for item in values for v in _walk(item, rest)]
    if isinstance(data, dict) and head in data:
        return _walk(data[head], rest)
    return []


def legacy_cost(data: dict[str, Any], keys: tuple[str, ...]) -> float | None:
    """Sum of the wall-time fields at ``/``-separated paths (``*`` for every item), or None."""
    values = [v for k in keys for v in _walk(data, k.split("/")) if isinstance(v, int | float)]
    return float(sum(values)) if values else None


def _provenance_of(data: dict[str, Any], part: str | None) -> dict[str, Any] | None:
    if part is None:
        return data.get("provenance")
    return data.get("provenance_parts", {}).get(part)


def status_of(entry: Entry, quick: bool = False, root: Path = ROOT) -> Status:
    """Check one registry entry (its quick output with ``quick``)."""
    output = entry.quick_output if quick else entry.output
    st = Status(entry.name, output or "", "missing", long=entry.long and not quick, note=entry.note)
    if entry.retired and not quick:
        st.state, st.why = "retired", entry.retired
        siblings = [e for e in REGISTRY if e.output == entry.output and e.name != entry.name]
        if all(e.retired for e in siblings) and (root / entry.output).is_file():
            st.why += f"; its file {entry.output} is still there: delete it"
        return st
    if output is None:
        st.state, st.note = "missing", "no quick mode"
        return st
    path = root / output
    if not path.is_file():
        return st
    data = json.loads(path.read_text())
    prov = _provenance_of(data, None if quick else entry.part)
    if prov is None and quick:
        prov = _provenance_of(data, entry.part)
    if prov is None:
        st.state, st.why = "unknown", "no provenance"
        cost = legacy_cost(data, entry.legacy_cost_keys)
        if cost is not None:
            st.cost_s, st.cost_source = cost, "legacy wall-time fields"
        elif entry.estimated_cost_s is not None:
            st.cost_s, st.cost_source = entry.estimated_cost_s, "registry estimate"
        return st
    st.changed = check_provenance(prov, root)
    _numerical_state(st, entry, quick, root, prov)
    st.cost_s, st.cost_source = prov.get("cost_s"), "recorded"
    body = data.get(entry.part, {}) if entry.part and not quick else data
    # The model choice records the count as "wall_time_sittings".
    sittings = body.get("sittings", body.get("wall_time_sittings")) if isinstance(body, dict) else None
    if isinstance(sittings, int) and sittings > 1 and isinstance(body.get("wall_time_s"), (int, float)):
        # A run resumed over several sittings: the process that wrote the JSON paid only the
        # last one; its own wall time over every sitting is the cost of a rerun.
        st.cost_s = max(st.cost_s or 0.0, float(body["wall_time_s"]))
        st.cost_source = f"recorded over {sittings} sittings"
    rerun = body.get("rerun_cost_s") if isinstance(body, dict) else None
    if entry.part and not quick and isinstance(data.get("rerun_cost_s_parts"), dict):
        rerun = data["rerun_cost_s_parts"].get(entry.part, rerun)  # a file whose parts state their own
    if isinstance(rerun, (int, float)) and rerun > (st.cost_s or 0.0):
        # A run that reused cached or imported work states what a rerun of its code would cost.
        st.cost_s, st.cost_source = float(rerun), "recorded (rerun of its code)"
    st.commit, st.date_utc, st.tree_clean = prov.get("commit"), prov.get("date_utc"), prov.get("tree_clean")
    return st


def load_verifications(root: Path = ROOT) -> dict[str, Any]:
    """The ledger of quick-mode checks, ``{entry name: record}`` (empty when none was made)."""
    path = root / VERIFICATIONS
    if not path.is_file():
        return {}
    return json.loads(path.read_text()).get("entries", {})


def load_equivalences(root: Path = ROOT) -> list[dict[str, Any]]:
    """The ledger's code equivalences: ``{"check", "date_utc", "cpu", "how", "files": {path:
    [version a, version b]}}``, each a quick check that gave the same numbers with the files at
    version a as at version b (:func:`benchmarks.verify.check`, ``verify --vouch-for``)."""
    path = root / VERIFICATIONS
    if not path.is_file():
        return []
    return json.loads(path.read_text()).get("equivalences", [])


def standing_edge(name: str, root: Path = ROOT) -> dict[str, list[str]] | None:
    """The files whose version differs between registry entry ``name``'s saved quick JSON and its
    last check, ``{path: [saved version, checked version]}``, when that check reproduced the saved
    numbers and they still stand (None otherwise: no check, other numbers, or a remade baseline)."""
    record = load_verifications(root).get(name)
    if record is None or not (record.get("outcome") == "reproduces" or record.get("quick_reproduces")):
        return None
    baseline = _quick_baseline(name, root)
    if baseline is None or record.get("baseline_date_utc", baseline.get("date_utc")) != baseline.get("date_utc"):
        return None
    return differing_versions(
        baseline.get("fingerprint", {}).get("code", {}), record.get("fingerprint", {}).get("code", {})
    )


def differing_versions(base: dict[str, str], ran: dict[str, str]) -> dict[str, list[str]]:
    """``{path: [version in base, version in ran]}`` over the code files both fingerprints record
    whose versions differ: the link that equal quick numbers of the two make."""
    return {rel: [base[rel], ran[rel]] for rel in ran if rel in base and base[rel] != ran[rel]}


def _chain_vouch(names: list[str], prov: dict[str, Any], items: list[str], root: Path) -> dict[str, set[str]]:
    """The changed files (of ``items``) whose version in the result is linked to today's by a chain
    of quick checks of ``names`` that gave equal numbers (each link one check: the saved quick
    numbers against a rerun, or ``verify --vouch-for``'s run at another commit), each with the
    checks whose links it took.

    Like :func:`_vouch`, this judges file by file: a link says that the two versions of a file,
    with the other files as they were in that check, give the same quick numbers.
    """
    links: dict[str, dict[str, dict[str, str]]] = {}  # file -> version -> linked version -> check

    def add(name: str, files: dict[str, list[str]]) -> None:
        for rel, (a, b) in files.items():
            graph = links.setdefault(rel, {})
            graph.setdefault(a, {})[b] = name
            graph.setdefault(b, {})[a] = name

    for eq in load_equivalences(root):
        if eq.get("check") in names:
            add(eq["check"], eq.get("files", {}))
    for name in names:
        add(name, standing_edge(name, root) or {})
    mine = prov.get("fingerprint", {}).get("code", {})
    out: dict[str, set[str]] = {}
    for item in items:
        path = root / item
        if item.endswith(" (removed)") or item not in mine or item not in links or not path.is_file():
            continue
        today = {code_hash(path), legacy_code_hash(path)}
        came: dict[str, tuple[str, str] | None] = {mine[item]: None}  # version -> (previous, check)
        todo = [mine[item]]
        while todo:
            here = todo.pop()
            for nxt, name in links[item].get(here, {}).items():
                if nxt not in came:
                    came[nxt] = (here, name)
                    todo.append(nxt)
        reached = next((v for v in today if v in came), None)
        if reached is not None:
            used, step = set(), came[reached]
            while step is not None:
                used.add(step[1])
                step = came[step[0]]
            out[item] = used
    return out


def _quick_baseline(name: str, root: Path) -> dict[str, Any] | None:
    """The provenance of registry entry ``name``'s saved quick JSON (None: no quick mode or file)."""
    entry = next((e for e in REGISTRY if e.name == name), None)
    if entry is None or entry.quick_output is None or not (root / entry.quick_output).is_file():
        return None
    data = json.loads((root / entry.quick_output).read_text())
    return (_provenance_of(data, entry.part) if entry.part else None) or _provenance_of(data, None)


def _check_problem(record: dict[str, Any], root: Path) -> str:
    """Why a ledger check says nothing about today's code ("" when it ran on it)."""
    # The check holds for the code it ran on: the files its quick run imported, as they are now.
    # Its inputs under runs/ (the tiny model choice) were made afresh in the check's own runs
    # folder by today's code (benchmarks.verify), and are gone with it: not compared.
    fingerprint = dict(record.get("fingerprint", {}))
    fingerprint["data"] = {k: v for k, v in fingerprint.get("data", {}).items() if not k.startswith("runs/")}
    since = check_provenance({"fingerprint": fingerprint}, root)
    return "code changed since the last check (" + ", ".join(since[:3]) + ")" if since else ""


def _check_failure(record: dict[str, Any]) -> str:
    """A ledger check's outcome and the last line of its detail."""
    last = (record.get("detail", "").strip().splitlines() or [""])[-1]
    return f"check {record.get('outcome', '?')}: {last[:160]}".strip()


def _vouch(name: str, prov: dict[str, Any], changed: list[str], root: Path) -> set[str]:
    """The changed files that registry entry ``name``'s quick check vouches for.

    A file is vouched for when the last check of ``name`` ran on today's code, reproduced the
    saved quick numbers, ran the file (or the file is gone and was not run), and those saved
    numbers were made with the result's own version of the file: then that version and today's
    give the same quick numbers.  Data files are never vouched for.
    """
    record = load_verifications(root).get(name)
    if record is None or _check_problem(record, root):
        return set()
    if not (record.get("outcome") == "reproduces" or record.get("quick_reproduces")):
        return set()
    baseline = _quick_baseline(name, root)
    if baseline is None or record.get("baseline_date_utc", baseline.get("date_utc")) != baseline.get("date_utc"):
        return set()  # no saved quick JSON, or rewritten after the check
    mine = prov.get("fingerprint", {}).get("code", {})
    base = baseline.get("fingerprint", {}).get("code", {})
    ran = record.get("fingerprint", {}).get("code", {})
    return {
        item
        for item in changed
        if (rel := item.removesuffix(" (removed)")) in mine
        and base.get(rel) == mine[rel]
        and (item.endswith(" (removed)") or rel in ran)
    }


def _numerical_state(st: Status, entry: Entry, quick: bool, root: Path, prov: dict[str, Any] | None = None) -> None:
    """Set ``st.state``/``st.why`` from the fingerprint and, when code changed, the ledger.

    The result's own quick check decides first; then the quick checks of ``entry.checked_by``
    may vouch, file by file, for what changed (:func:`_vouch`).
    """
    if not st.changed:
        st.state, st.why = "current", "code unchanged"
        return
    st.state = "stale"
    if quick:
        st.why = "code changed, not checked"
        return
    inputs = ((prov or {}).get("fingerprint") or {}).get("data", {})
    if data_changed := [c for c in st.changed if c.removesuffix(" (removed)") in inputs]:
        # A quick check reruns the code on the quick mode's own inputs: it cannot vouch for
        # other data.  Data changes always call for a rerun.
        st.why = "inputs changed, rerun it: " + ", ".join(data_changed[:3])
        return
    record = load_verifications(root).get(entry.name)
    if record is None:
        st.why = "code changed, not checked" if entry.quick else "code changed; no quick mode to check it"
    elif problem := _check_problem(record, root):
        st.why = problem
    elif record.get("outcome") == "reproduces":
        st.state, st.why = "current", "code changed, quick mode reproduces"
        return
    elif record.get("outcome") == "numbers changed":
        st.state, st.why = "changed", "numbers changed"
        return
    else:
        st.why = _check_failure(record)
    if prov is None:
        return
    # File by file: the own check (when it could not vouch for the whole result) and the siblings'.
    names = ([entry.name] if entry.quick_output and record is not None else []) + list(entry.checked_by)
    vouched: set[str] = set()
    by = []
    for name in names:
        got = _vouch(name, prov, st.changed, root)
        if got - vouched:
            by.append(name)
        vouched |= got
    chained = _chain_vouch(names, prov, [c for c in st.changed if c not in vouched], root)
    by += sorted({name for used in chained.values() for name in used} - set(by))
    if vouched | set(chained) >= set(st.changed):
        st.state = "current"
        st.why = (
            "code changed, quick mode of "
            + ", ".join(by)
            + " reproduces"
            + (f" (through earlier checks: {', '.join(sorted(chained)[:3])})" if chained else "")
        )
    elif entry.checked_by:
        rest = [c for c in st.changed if c not in vouched | set(chained)]
        st.why += "; not vouched for by " + ", ".join(entry.checked_by) + ": " + ", ".join(rest[:3])


def status_all(quick: bool = False, root: Path = ROOT) -> list[Status]:
    """Every registry entry (with a quick mode, for ``quick``) plus unregistered result JSONs."""
    out = [status_of(e, quick, root) for e in REGISTRY if not quick or e.quick_output]
    if not quick:
        known = {e.output for e in REGISTRY}
        for path in sorted((root / "benchmarks" / "results").glob("*.json")):
            rel = path.relative_to(root).as_posix()
            if rel not in known and rel not in CACHES and rel != VERIFICATIONS:
                data = json.loads(path.read_text())
                prov = data.get("provenance") if isinstance(data, dict) else None
                st = Status(path.stem, rel, "unknown", why="no provenance", note="not in benchmarks/registry.py")
                if prov is not None:
                    st.changed = check_provenance(prov, root)
                    st.state, st.why = (
                        ("stale", "code changed, not in the registry")
                        if st.changed
                        else (
                            "current",
                            "code unchanged",
                        )
                    )
                out.append(st)
    return out


# ----------------------------------------------------------------------------- reproduction


def deterministic_view(data: Any, ignore: tuple[str, ...] = ()) -> Any:
    """``data`` without provenance, machine records, commands, dates and timing keys."""
    skip = (
        *TIMING_KEYS,
        *ignore,
        "provenance",
        "provenance_parts",
        "provenance_before_parts",
        "machine",
        "command",
        "commands",
        "date_utc",
        "versions",
        "description",
    )
    if isinstance(data, dict):
        return {
            k: deterministic_view(v, ignore)
            for k, v in data.items()
            if not any(fnmatch.fnmatchcase(k, p) for p in skip)
        }
    if isinstance(data, list):
        return [deterministic_view(v, ignore) for v in data]
    return data


def compare_numbers(saved: Any, new: Any, rtol: float = 0.0, path: str = "") -> list[str]:
    """Differences between two JSON trees: structure exactly, numbers within ``rtol`` (0: equal).

    NaN equals NaN; each difference is reported as ``path: saved != new``.
    """
    if isinstance(saved, dict) and isinstance(new, dict):
        diffs = [f"{path}/{k}: only in one" for k in sorted(set(saved) ^ set(new))]
        for k in sorted(set(saved) & set(new)):
            diffs += compare_numbers(saved[k], new[k], rtol, f"{path}/{k}")
        return diffs
    if isinstance(saved, list) and isinstance(new, list):
        if len(saved) != len(new):
            return [f"{path}: length {len(saved)} != {len(new)}"]
        return [
            d
            for i, (a, b) in enumerate(zip(saved, new, strict=True))
            for d in compare_numbers(a, b, rtol, f"{path}[{i}]")
        ]
    numeric = (int, float)
    if (
        isinstance(saved, numeric)
        and isinstance(new, numeric)
        and not isinstance(saved, bool)
        and not isinstance(new, bool)
    ):
        if math.isnan(saved) and math.isnan(new):
            return []
        if saved == new or (rtol and math.isclose(saved, new, rel_tol=rtol, abs_tol=rtol * 1e-6)):
            return []
        return [f"{path}: {saved!r} != {new!r}"]
    return [] if saved == new else [f"{path}: {saved!r} != {new!r}"]


# ----------------------------------------------------------------------------- command line


def format_cost(seconds: float | None) -> str:
    """``'12 s'``, ``'3.4 min'``, ``'1.6 h'`` or ``'?'``."""
    if seconds is None:
        return "?"
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def render(rows: list[Status]) -> str:
    """Plain-text table of the statuses."""
    lines = [f"{'result':34s} {'state':8s} {'cost':>9s}  {'commit':8s} {'date (UTC)':20s} why / what changed / note"]
    for s in rows:
        estimated = s.cost_source not in ("recorded", "none") and not s.cost_source.startswith("recorded ")
        cost = format_cost(s.cost_s) + ("*" if estimated else "")
        commit = (s.commit or "-")[:8] + ("+" if s.tree_clean is False else "")
        detail = ", ".join(s.changed[:6]) + (f" (+{len(s.changed) - 6} more)" if len(s.changed) > 6 else "")
        if s.why and s.state != "stale":
            detail = s.why
        elif s.why:
            detail = f"{s.why}: {detail}"
        if not detail:
            detail = {"unknown": "no provenance recorded", "missing": "not written yet"}.get(s.state, "")
        tag = " [long]" if s.long else ""
        lines.append(f"{s.name + tag:34s} {s.state:8s} {cost:>9s}  {commit:8s} {s.date_utc or '-':20s} {detail}")
    lines.append(
        "cost*: estimated (legacy wall-time fields or the registry), not recorded; commit+: uncommitted "
        "changes at write time"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Print the status table; exit status 1 when any result is neither current nor retired."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="the quick-mode results instead")
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    args = parser.parse_args(argv)
    rows = status_all(args.quick)
    if args.json:
        print(json.dumps([asdict(r) for r in rows], indent=1))
    else:
        print(render(rows))
    return 0 if all(r.state in ("current", "retired") for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
