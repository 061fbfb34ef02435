"""Numerical currency: rerun the quick mode of each result whose code changed, compare its numbers.

A result is current when the code it depends on is unchanged, or when its quick mode, rerun on the
code as it is now, gives the numbers saved in its quick JSON (exactly, or within the registry's
``compare_tolerance``; timing-like keys are left out).  This command makes those checks, cheapest
first within a time budget, and records each in ``benchmarks/results/verifications.json`` with the
fingerprint of the code it ran on; ``benchmarks/status.py`` reads it.  A refactor that changes no
number then needs no long rerun, and a change that does is caught in minutes (``changed``).

A check vouches for the full result only when the saved quick JSON was made from the same code as
the full result (on the files both imported); otherwise it is recorded as ``not applicable`` and
the result stays stale until it is rerun.  The saved quick JSON is restored after each check, so
the tree stays as it was; only the ledger is written.

Quick modes run with an empty ``runs/`` folder of their own (``JAXABC_RUNS_DIR``, shared by the
checks of one invocation and removed after it), never the checkout's: a run cache or a finished
checkpoint there may hold simulations of earlier code, and a check that replays them cannot fail.
``--runs-dir`` keeps that folder for later invocations on the same code.
The untracked inputs a quick mode reads (``quick_inputs``, such as the tiny model choice) are made
afresh, by the quick modes of the entries it runs after, with the code being checked.

When the saved quick JSON cannot serve (made on another CPU family, whose rounding changes chaotic
runs, or from other code than the full result), ``--rebaseline`` first remakes it here: the quick
mode runs in a temporary git worktree at the full result's own commit, and its output replaces the
saved quick JSON.  The check then compares the result's code with today's on one machine, so a
number that moves is the code's doing, not the CPU's.

Usage::

    python -m benchmarks.verify --budget 30m             # the stale results that fit
    python -m benchmarks.verify --only coverage --budget 10m
    python -m benchmarks.verify --budget 1h --dry-run    # the plan only
    python -m benchmarks.verify --only surrogate_peers --budget 20m --rebaseline
    python -m benchmarks.verify --only water_model_choice --budget 1h --rebaseline always
    python -m benchmarks.verify --only water_model_choice --budget 1h --vouch-for water_model_choice_seed1

Every check that gives the saved quick numbers is also kept as a link between two versions of the
code (``equivalences`` in the ledger): status chains links, so a result made at a commit whose
files differ from the saved quick JSON's is current when a chain of equal quick runs joins its
versions to today's.  ``--vouch-for`` adds the link such a result lacks with one quick run at its
commit, instead of a rerun of the result.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks import _common
from benchmarks._common import ROOT, cpu_signature, git_state
from benchmarks.regenerate import command_argv, parse_budget
from benchmarks.registry import REGISTRY, VERIFICATIONS, Entry, by_name
from benchmarks.status import (
    check_provenance,
    compare_numbers,
    deterministic_view,
    differing_versions,
    format_cost,
    load_verifications,
    standing_edge,
    status_of,
)

__all__ = ["baseline_mismatch", "check", "cpu_signature", "main", "plan", "rebaseline"]

#: Seconds assumed for a quick mode whose saved JSON records no cost.
DEFAULT_QUICK_COST_S = 300.0


def _provenance(data: dict[str, Any], part: str | None) -> dict[str, Any] | None:
    if part is not None and part in data.get("provenance_parts", {}):
        return data["provenance_parts"][part]
    return data.get("provenance")


def baseline_mismatch(entry: Entry, root: Path = ROOT) -> list[str]:
    """Code files the full result and its saved quick JSON both depend on but hashed differently.

    Empty when the quick JSON was made from the same code as the full result, so that a quick
    check on today's code speaks for the full result too; empty also when the full result is no
    longer saved (a retired entry kept as a checker: its quick JSON stands for itself).
    """
    assert entry.quick_output is not None, "only entries with a quick mode"
    if not (root / entry.output).is_file():
        return []
    full = json.loads((root / entry.output).read_text())
    quick = json.loads((root / entry.quick_output).read_text())
    full_code = (_provenance(full, entry.part) or {}).get("fingerprint", {}).get("code", {})
    quick_code = (_provenance(quick, entry.part) or {}).get("fingerprint", {}).get("code", {})
    return sorted(f for f in set(full_code) & set(quick_code) if full_code[f] != quick_code[f])


def _quick_cost(entry: Entry, root: Path = ROOT) -> float:
    path = root / (entry.quick_output or "")
    if path.is_file():
        prov = _provenance(json.loads(path.read_text()), entry.part) or {}
        if isinstance(prov.get("cost_s"), int | float):
            return float(prov["cost_s"])
    return DEFAULT_QUICK_COST_S


def dependency_order(rows: list[tuple[Entry, float]]) -> list[tuple[Entry, float]]:
    """``rows`` (cheapest first) with every entry moved after those it names in ``after``.

    A quick check that reads what another writes (the criticism's tiny run reads the tiny model
    choice, whose saved file records its wall time) must run after it, or the other's rewrite
    makes the first check's input new again.  ``after`` names match an entry's name or its name
    before the part (``water_simulated_surrogate_abc`` matches ``...:paper``).
    """

    def base(name: str) -> str:
        return name.split(":", 1)[0]

    out: list[tuple[Entry, float]] = []
    pending = list(rows)
    while pending:
        for i, (e, _) in enumerate(pending):
            waits = set(e.after)
            if not any(o.name in waits or base(o.name) in waits for o, _ in pending if o is not e):
                out.append(pending.pop(i))
                break
        else:  # a cycle: keep the cost order for the rest
            out += pending
            break
    return out


def plan(entries: list[Entry], budget_s: float, include_current: bool = False) -> list[tuple[Entry, float, str]]:
    """``(entry, quick cost, why)`` for every candidate, cheapest first; why is "" for those to run."""
    rows = []
    ledger = load_verifications()
    # A quick check also vouches for the stale results that name it in ``checked_by``.
    wanted = {n for r in REGISTRY if r.checked_by and status_of(r).state == "stale" for n in r.checked_by}
    for e in entries:
        st = status_of(e)
        if not e.quick or not e.quick_output:
            continue
        if st.state in ("unknown", "missing", "retired") and e.name not in wanted:
            continue  # nothing to vouch for: a result without provenance needs a rerun
        record = ledger.get(e.name)
        checked = record is not None and not check_provenance({"fingerprint": record.get("fingerprint", {})})
        if checked and record is not None and "fingerprint" in record:
            if not include_current:
                continue  # already checked on this very code (whatever the outcome)
        elif st.state == "current" and e.name not in wanted and not include_current:
            continue
        rows.append((e, _quick_cost(e)))
    rows = dependency_order(sorted(rows, key=lambda r: r[1]))
    out, left = [], budget_s
    for e, cost in rows:
        missing = [p for p in e.requires if shutil.which(p) is None]
        if missing:
            out.append((e, cost, f"needs {', '.join(missing)}"))
        elif cost > left:
            out.append((e, cost, f"over the budget left ({format_cost(left)})"))
        else:
            out.append((e, cost, ""))
            left -= cost
    return out


def _run_command(argv: list[str], root: Path, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run(argv, cwd=root, env=env, capture_output=True, text=True)


def _quick_env(root: Path, runs: Path) -> dict[str, str]:
    """The environment of a quick command: this checkout first on the path, ``runs`` as its runs folder."""
    path = os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")]))
    return {**os.environ, "PYTHONPATH": path, "JAXABC_RUNS_DIR": str(runs)}


def make_quick_inputs(entry: Entry, root: Path, env: dict[str, str]) -> subprocess.CompletedProcess | None:
    """Make the untracked caches ``entry``'s quick mode reads (``quick_inputs``) where they are
    missing from the runs folder ``env["JAXABC_RUNS_DIR"]`` (empty for each verify invocation), by
    the quick modes of the entries it runs ``after``.  None when every input is there afterwards,
    else the failed run (or a made-up one saying which input is missing)."""
    runs = Path(env.get("JAXABC_RUNS_DIR") or root / "runs")
    missing = [rel for rel in entry.quick_inputs if not _common.resolve_recorded(rel, runs, root).exists()]
    if not missing:
        return None
    for name in entry.after:
        producer = by_name(name)
        if producer.quick:
            run = _run_command(command_argv(producer.quick), root, env)
            if run.returncode != 0:
                return run
    still = [rel for rel in missing if not _common.resolve_recorded(rel, runs, root).exists()]
    if still:
        return subprocess.CompletedProcess(
            [], 1, "", f"quick inputs missing and not made by the quick modes of {list(entry.after)}: {still}"
        )
    return None


def check(entry: Entry, root: Path = ROOT, runs: Path | None = None) -> dict[str, Any]:
    """Rerun ``entry``'s quick mode on the code as it is now; the ledger record of the outcome.

    ``runs``: the quick mode's runs folder (what it caches, and the quick inputs made for it);
    default an empty temporary folder, removed afterwards.
    """
    assert entry.quick and entry.quick_output, "only entries with a quick mode"
    if runs is None:
        with tempfile.TemporaryDirectory(prefix="jaxabc-verify-runs-") as tmp:
            return check(entry, root, Path(tmp))
    record: dict[str, Any] = {"quick": entry.quick, **git_state(), "date_utc": time.strftime("%Y-%m-%d %H:%M:%S")}
    if _missing_part(entry, root):
        return {
            **record,
            "outcome": "not applicable",
            "detail": f"the saved quick JSON has no {entry.part!r} part: make one with --rebaseline",
        }
    mismatch = baseline_mismatch(entry, root)
    saved_path = root / entry.quick_output
    saved_text = saved_path.read_text()
    # Which saved numbers the check compared against: status uses a check only while they stand.
    record["baseline_date_utc"] = (_provenance(json.loads(saved_text), entry.part) or {}).get("date_utc")
    # A quick command may write other quick results too (criticism_water_joint's writes
    # water_model_choice's): every saved quick JSON is put back as it was.
    snapshot = {p: p.read_text() for p in saved_path.parent.glob("*.json")}
    env = _quick_env(root, runs)
    t0 = time.perf_counter()
    try:
        made = make_quick_inputs(entry, root, env)
        run = made if made is not None else _run_command(command_argv(entry.quick), root, env)
        new_text = saved_path.read_text()
    finally:
        for path, text in snapshot.items():
            if not path.is_file() or path.read_text() != text:
                path.write_text(text)
    record["seconds"] = round(time.perf_counter() - t0, 1)
    if run.returncode != 0:
        return {**record, "outcome": "failed", "detail": run.stderr.strip()[-1500:]}
    new = json.loads(new_text)
    record["fingerprint"] = (_provenance(new, entry.part) or {}).get("fingerprint", {})
    diffs = compare_numbers(
        deterministic_view(json.loads(saved_text), entry.ignore_keys),
        deterministic_view(new, entry.ignore_keys),
        entry.compare_tolerance,
    )
    here_cpu = cpu_signature(_common.machine())
    base_cpu = cpu_signature((_provenance(json.loads(saved_text), entry.part) or {}).get("machine") or {})
    record["cpu"], record["baseline_cpu"] = here_cpu, base_cpu
    if not diffs:
        # Equal numbers from two versions of the code: a link the ledger keeps after this record
        # and the saved quick JSON are replaced (benchmarks.status chains them).
        record["equivalence"] = _differing_files(_provenance(json.loads(saved_text), entry.part), new, entry.part)
    if diffs and _other_cpu(json.loads(saved_text), entry.part):
        # Chaotic MD (GROMACS) diverges with the CPU's rounding: other numbers on another CPU say
        # nothing about the code.  The check must run on the CPU family that made the baseline.
        return {
            **record,
            "outcome": "other machine",
            "detail": f"{len(diffs)} quick numbers differ on {here_cpu}; the saved ones were made on {base_cpu}",
            "differences": diffs[:20],
            "num_differences": len(diffs),
        }
    if mismatch:
        # The numbers still say whether today's code reproduces the quick JSON, but that JSON was
        # made from other code than the full result, so it cannot vouch for it.
        return {
            **record,
            "outcome": "not applicable",
            "detail": "the saved quick JSON was made from other code than the result: " + ", ".join(mismatch[:5]),
            "quick_reproduces": not diffs,
        }
    if diffs:
        return {**record, "outcome": "numbers changed", "differences": diffs[:20], "num_differences": len(diffs)}
    return {**record, "outcome": "reproduces"}


def quick_json_at(entry: Entry, commit: str, root: Path = ROOT) -> dict[str, Any]:
    """``entry``'s quick JSON as the code of ``commit`` makes it, here.

    The quick command runs in a temporary git worktree at ``commit`` beside ``root`` (so relative
    data paths such as ``../shared`` resolve as they do for ``root``), removed afterwards.

    Raises
    ------
    RuntimeError
        The worktree cannot be made or the quick command fails.
    """
    assert entry.quick and entry.quick_output, "only entries with a quick mode"
    tree = root.parent / f".verify-at-{entry.name.replace(':', '-')}"
    if tree.exists():
        subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=root, capture_output=True)
    made = subprocess.run(
        ["git", "worktree", "add", "--detach", "--force", str(tree), commit], cwd=root, capture_output=True, text=True
    )
    if made.returncode != 0:
        raise RuntimeError(f"{entry.name}: cannot check out {commit[:10]}: {made.stderr.strip()[-300:]}")
    try:
        # The quick inputs (untracked caches) are made afresh by that commit's code, in the
        # worktree's empty runs folder: never copied from this checkout, whose caches may hold
        # simulations of other code.
        env = {**os.environ, "PYTHONPATH": str(tree), "JAXABC_RUNS_DIR": str(tree / "runs")}
        made = make_quick_inputs(entry, tree, env)
        run = made if made is not None else _run_command(command_argv(entry.quick), tree, env)
        if run.returncode != 0:
            raise RuntimeError(f"{entry.name}: the quick mode at {commit[:10]} failed: {run.stderr.strip()[-600:]}")
        return _stamp_host(json.loads((tree / entry.quick_output).read_text()))
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=root, capture_output=True)


def _stamp_host(made: dict[str, Any]) -> dict[str, Any]:
    """``made``, a quick JSON that older code wrote here, with this host's instruction sets
    added to each provenance's machine where that code recorded none: without them a later
    check on another host of the same CPU name (AVX-512 or not) would compare its numbers as if
    both hosts were one."""
    here = _common.machine().get("native_kernel_instruction_set")
    provenances = [made.get("provenance"), *(made.get("provenance_parts") or {}).values()]
    for prov in provenances:
        machine = (prov or {}).get("machine")
        if isinstance(machine, dict) and not (machine.get("native_kernel_instruction_set") or {}).get("simd"):
            machine["native_kernel_instruction_set"] = {**(here or {}), "stamped_by": "benchmarks.verify"}
    return made


def vouch_for(check_entry: Entry, result: Entry, root: Path = ROOT) -> dict[str, Any]:
    """Link ``result``'s own code to the saved quick numbers of ``check_entry``: run its quick mode
    at the result's commit and compare with its saved quick JSON.  Equal numbers are kept in the
    ledger as an equivalence (status then chains the result's files, through the saved quick
    JSON's versions, to today's code when today's check reproduced that JSON too).

    For a result that its sibling's check cannot vouch for because the saved quick JSON was made
    with other versions of the files than the result (one baseline, several results made at
    different commits): one quick run instead of a rerun of the result.

    Returns ``{"commit", "seconds", "outcome", "differences"?, "linked"?}``, outcome
    ``"reproduces"``, ``"numbers changed"`` or ``"other machine"``.

    Raises
    ------
    RuntimeError
        No saved quick JSON or result commit, or the quick mode fails at that commit.
    """
    assert check_entry.quick and check_entry.quick_output, "only entries with a quick mode"
    saved_path = root / check_entry.quick_output
    if not saved_path.is_file() or not (root / result.output).is_file():
        raise RuntimeError(f"{check_entry.name}: no saved quick JSON, or {result.name} has no result")
    prov = _provenance(json.loads((root / result.output).read_text()), result.part) or {}
    commit = prov.get("commit")
    if not commit:
        raise RuntimeError(f"{result.name}: the result records no commit")
    saved = json.loads(saved_path.read_text())
    t0 = time.perf_counter()
    made = quick_json_at(check_entry, commit, root)
    out: dict[str, Any] = {"commit": commit, "seconds": round(time.perf_counter() - t0, 1)}
    diffs = compare_numbers(
        deterministic_view(saved, check_entry.ignore_keys),
        deterministic_view(made, check_entry.ignore_keys),
        check_entry.compare_tolerance,
    )
    if diffs:
        other = _other_cpu(saved, check_entry.part)
        return {**out, "outcome": "other machine" if other else "numbers changed", "differences": diffs[:20]}
    files = _differing_files(_provenance(saved, check_entry.part), made, check_entry.part)
    _write_ledger(
        check_entry.name,
        {"equivalence": files},
        root,
        how=f"quick mode at {commit[:10]} ({result.name}'s commit) against its saved quick JSON",
        cpu=cpu_signature(_common.machine()),
    )
    return {**out, "outcome": "reproduces", "linked": sorted(files)}


def rebaseline(entry: Entry, root: Path = ROOT) -> dict[str, Any]:
    """Remake ``entry``'s saved quick JSON here, with the code of the full result's own commit.

    The quick command runs in a temporary worktree at that commit (beside ``root``, so relative
    data paths such as ``../shared`` resolve as they do for ``root``); its quick JSON replaces the
    saved one.  Returns what was done: ``{"commit", "seconds", "mismatch"}``, where ``mismatch``
    lists the files whose hash still differs from the full result's (it was written from a tree
    with uncommitted changes): those stay unvouched.

    Raises
    ------
    RuntimeError
        The full result is missing or records no commit, the worktree cannot be made, or the
        quick command fails.
    """
    assert entry.quick and entry.quick_output, "only entries with a quick mode"
    if not (root / entry.output).is_file():
        raise RuntimeError(f"{entry.name}: no full result ({entry.output}) to rebaseline from")
    full = _provenance(json.loads((root / entry.output).read_text()), entry.part) or {}
    commit = full.get("commit")
    if not commit:
        raise RuntimeError(f"{entry.name}: the full result records no commit to rebaseline from")
    t0 = time.perf_counter()
    made_json = quick_json_at(entry, commit, root)
    saved_path = root / entry.quick_output
    if entry.part is not None and entry.part in made_json and saved_path.is_file():
        # A file several commands fill in: only this entry's part is remade (a file whose
        # parts share one body, as helium_lammps_agreement's records, is remade whole).
        merged = json.loads(saved_path.read_text())
        merged[entry.part] = made_json[entry.part]
        merged["provenance"] = made_json["provenance"]
        merged.setdefault("provenance_parts", {})[entry.part] = made_json["provenance_parts"][entry.part]
        made_json = merged
    saved_path.parent.mkdir(parents=True, exist_ok=True)
    saved_path.write_text(json.dumps(made_json, indent=1) + "\n")
    return {"commit": commit, "seconds": round(time.perf_counter() - t0, 1), "mismatch": baseline_mismatch(entry, root)}


def _write_ledger(
    name: str, record: dict[str, Any], root: Path = ROOT, how: str | None = None, cpu: str | None = None
) -> None:
    """Write ``record`` as ``name``'s last check (unless it carries only an ``equivalence``) and
    its ``equivalence``, if any, as a link (``how`` it was made)."""
    path = root / VERIFICATIONS
    ledger = json.loads(path.read_text()) if path.is_file() else {}
    ledger.setdefault(
        "description",
        "Quick-mode checks of results whose code changed (benchmarks/verify.py): outcome 'reproduces' "
        "makes a result current for the code in 'fingerprint'.",
    )
    record = dict(record)
    files = record.pop("equivalence", None)
    if record:
        ledger.setdefault("entries", {})[name] = record
        ledger["entries"] = dict(sorted(ledger["entries"].items()))
    if files:
        _add_equivalence(
            ledger,
            name,
            files,
            how or f"quick mode against its saved quick JSON ({record.get('date_utc')})",
            cpu or record.get("cpu"),
        )
    path.write_text(json.dumps(ledger, indent=1) + "\n")


def _add_equivalence(ledger: dict[str, Any], name: str, files: dict[str, list[str]], how: str, cpu: str | None) -> None:
    """Append a link to ``ledger["equivalences"]`` unless the same check already links the same
    versions."""
    links = ledger.setdefault("equivalences", [])
    if any(eq.get("check") == name and eq.get("files") == files for eq in links):
        return
    links.append(
        {"check": name, "date_utc": time.strftime("%Y-%m-%d %H:%M:%S"), "cpu": cpu, "how": how, "files": files}
    )


def _differing_files(a: dict[str, Any] | None, b_json: dict[str, Any], part: str | None) -> dict[str, list[str]]:
    """``{path: [version in a, version in b]}`` over the code files both provenances record and
    that differ: ``a`` a provenance record, ``b_json`` a quick JSON."""
    return differing_versions(
        ((a or {}).get("fingerprint") or {}).get("code", {}),
        ((_provenance(b_json, part) or {}).get("fingerprint") or {}).get("code", {}),
    )


def preserve_standing_edge(name: str, root: Path = ROOT) -> None:
    """Keep the link that ``name``'s last check made (saved quick numbers reproduced) before a new
    check replaces its record, or a rebaseline the saved quick JSON it refers to."""
    files = standing_edge(name, root)
    if files:
        record = load_verifications(root).get(name, {})
        _write_ledger(
            name,
            {"equivalence": files},
            root,
            how=f"quick mode against its saved quick JSON ({record.get('date_utc')})",
            cpu=record.get("cpu"),
        )


def _missing_part(entry: Entry, root: Path = ROOT) -> bool:
    """Whether the saved quick JSON lacks ``entry``'s part (another part of the file was saved)."""
    saved = json.loads((root / entry.quick_output).read_text())  # type: ignore[operator]
    return entry.part is not None and entry.part not in saved.get("provenance_parts", {})


def _other_cpu(saved: dict[str, Any], part: str | None) -> str | None:
    """The CPU that made a saved quick JSON when it is not this machine's (None when the same or
    unknown); compared by :func:`cpu_signature`, or by name alone where the saved record has no
    instruction sets."""
    base_machine = (_provenance(saved, part) or {}).get("machine") or {}
    base = cpu_signature(base_machine)
    if not base:
        return None
    here = _common.machine()
    if (base_machine.get("native_kernel_instruction_set") or {}).get("simd"):
        return base if base != cpu_signature(here) else None
    return base if base_machine.get("cpu") != here.get("cpu") else None


def _needs_rebaseline(entry: Entry, root: Path = ROOT) -> bool:
    """Whether the saved quick JSON is missing, or was made on another CPU or from other code."""
    assert entry.quick_output is not None
    if not (root / entry.quick_output).is_file() or _missing_part(entry, root):
        return True
    saved = json.loads((root / entry.quick_output).read_text())
    return bool(baseline_mismatch(entry, root)) or _other_cpu(saved, entry.part) is not None


def main(argv: list[str] | None = None) -> int:
    """Check what fits the budget; exit 1 when any check found changed numbers or failed."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--budget", type=parse_budget, required=True, help="e.g. 30m, 1h, 900")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="registry names")
    parser.add_argument("--include-current", action="store_true", help="check current results too")
    parser.add_argument("--dry-run", action="store_true", help="list the plan, run nothing")
    parser.add_argument(
        "--runs-dir",
        type=Path,
        help="the quick modes' runs folder, kept afterwards (default: an empty temporary one): pass the same "
        "folder to later invocations on the same code to reuse the quick inputs made for earlier checks",
    )
    parser.add_argument(
        "--rebaseline",
        nargs="?",
        const="auto",
        choices=("auto", "always"),
        help="where the saved quick JSON was made on another CPU or from other code, remake it here at the "
        "full result's commit first (doubles the cost); 'always': remake every checked baseline (one made "
        "before checks ran in their own runs folder may have replayed cached simulations)",
    )
    parser.add_argument(
        "--vouch-for",
        metavar="RESULT",
        help="run the quick mode of each --only entry at RESULT's commit and compare it with its saved quick "
        "JSON: equal numbers link RESULT's code to the saved quick numbers (one quick run instead of rerunning "
        "RESULT, when the saved quick JSON was made with other versions of its files)",
    )
    args = parser.parse_args(argv)
    if args.vouch_for is not None:
        return _vouch_all(args.only or [], args.vouch_for, args.dry_run)
    entries = [e for e in REGISTRY if args.only is None or e.name in args.only or e.name.split(":")[0] in args.only]
    rows = plan(entries, args.budget, args.include_current or bool(args.only))
    for e, cost, why in rows:
        print(f"  {'check' if not why else 'skip ':5s} {e.name:40s} {format_cost(cost):>9s}  {why or e.quick}")
    if args.dry_run:
        return 0
    bad = []
    if args.runs_dir is not None:
        args.runs_dir.mkdir(parents=True, exist_ok=True)
        _check_all(rows, args.rebaseline, args.runs_dir.resolve(), bad)
        return 1 if bad else 0
    runs = Path(tempfile.mkdtemp(prefix="jaxabc-verify-runs-"))
    try:
        _check_all(rows, args.rebaseline, runs, bad)
    finally:
        shutil.rmtree(runs, ignore_errors=True)
    return 1 if bad else 0


def _vouch_all(checks: list[str], result_name: str, dry_run: bool) -> int:
    """``--vouch-for``: link ``result_name``'s code through each of ``checks``; 1 on any failure."""
    if not checks:
        print("--vouch-for needs --only with the quick checks to run at the result's commit")
        return 2
    try:
        result, entries = by_name(result_name), [by_name(n) for n in checks]
    except KeyError as err:
        print(f"unknown registry name: {err}")
        return 2
    bad = 0
    for e in entries:
        if not (e.quick and e.quick_output):
            print(f"  {e.name}: has no quick mode")
            bad += 1
            continue
        print(f"  vouch {e.name:40s} {format_cost(_quick_cost(e)):>9s}  at {result.name}'s commit: {e.quick}")
        if dry_run:
            continue
        try:
            out = vouch_for(e, result)
        except RuntimeError as err:
            print(f"    failed: {err}")
            bad += 1
            continue
        print(f"[{time.strftime('%H:%M:%S')}] {e.name}: {out['outcome']} ({out['seconds']} s) {out.get('linked', '')}")
        if out["outcome"] != "reproduces":
            bad += 1
            for line in out.get("differences", [])[:5]:
                print(f"    {line}")
    return 1 if bad else 0


def _check_all(
    rows: list[tuple[Entry, float, str]], rebase: str | None, runs: Path, bad: list[str], root: Path | None = None
) -> None:
    """The checks of one invocation, in order, sharing the runs folder ``runs``; failures to ``bad``."""
    root = ROOT if root is None else root
    for e, _, why in rows:
        if why:
            continue
        print(f"[{time.strftime('%H:%M:%S')}] {e.name}: {e.quick}", flush=True)
        # This check's record, or a rebaseline, replaces the link the last check made: keep it.
        preserve_standing_edge(e.name, root)
        rebased = None
        if rebase == "always" or (rebase == "auto" and _needs_rebaseline(e, root)):
            try:
                rebased = rebaseline(e, root)
            except (RuntimeError, KeyError, ValueError) as err:  # one bad baseline does not end the pass
                print(f"    rebaseline failed: {err!r}")
                bad.append(e.name)
                continue
            print(f"    rebaselined at {rebased['commit'][:10]} in {rebased['seconds']} s", flush=True)
        record = check(e, root, runs=runs)
        if rebased is not None:
            record["rebaselined"] = rebased
        _write_ledger(e.name, record, root)
        print(f"[{time.strftime('%H:%M:%S')}] {e.name}: {record['outcome']} ({record['seconds']} s)", flush=True)
        if record["outcome"] in ("numbers changed", "failed"):
            bad.append(e.name)
            for line in record.get("differences", [])[:5] or [record.get("detail", "")[-300:]]:
                print(f"    {line}")


if __name__ == "__main__":
    sys.exit(main())
