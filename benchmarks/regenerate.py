"""Rerun the saved results that are stale or of unknown provenance, within a time budget.

Candidates are the entries of ``benchmarks/registry.py`` that ``status.py`` does not call
current.  They run **cheapest first** (the most results for the budget, and cheap inputs such as
``imbalance`` before what reads them), each only if its cost -- recorded by the helper in its last
JSON, else estimated -- fits in what is left of the budget.  After every run the status is checked
again, so a result that became stale because an input it reads was just regenerated is picked
up in the same call.  The long runs (water calibrations, criticism) are listed with their cost;
they run only when the budget holds them.  A run that spans sittings on machines that keep
nothing but the git tree continues from its parked checkpoint (``benchmarks/park.py``).

Usage::

    python -m benchmarks.regenerate --budget 1h --dry-run
    python -m benchmarks.regenerate --budget 1h
    python -m benchmarks.regenerate --quick --budget 15m      # the quick-mode JSONs
    python -m benchmarks.regenerate --only coverage helium_table1 --budget 2h
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import shutil
import subprocess
import sys
import time

from benchmarks import park
from benchmarks._common import ROOT
from benchmarks.registry import REGISTRY, Entry
from benchmarks.status import Status, format_cost, status_of

__all__ = ["command_argv", "main", "parse_budget", "plan"]

#: Cost assumed for a result with no recorded or estimated cost (it is run last).
UNKNOWN_COST_S = 3600.0
#: Cost assumed for a quick mode never run (quick modes are meant to take a few minutes).
QUICK_COST_S = 300.0


def parse_budget(text: str) -> float:
    """``'1h'``, ``'90m'``, ``'45s'``, ``'1h30m'`` or plain seconds -> seconds."""
    text = text.strip().lower()
    if re.fullmatch(r"\d+(\.\d+)?", text):
        return float(text)
    parts = re.findall(r"(\d+(?:\.\d+)?)\s*([hms])", text)
    if not parts or "".join(n + u for n, u in parts) != text.replace(" ", ""):
        raise argparse.ArgumentTypeError(f"budget {text!r}: write e.g. 1h, 90m, 1h30m or 3600 (seconds)")
    return sum(float(n) * {"h": 3600, "m": 60, "s": 1}[u] for n, u in parts)


def command_argv(command: str) -> list[str]:
    """A registry command as argv, with ``python`` replaced by this interpreter."""
    argv = shlex.split(command)
    if argv and argv[0] in ("python", "python3"):
        argv[0] = sys.executable
    return argv


def _missing_programs(entry: Entry) -> list[str]:
    return [p for p in entry.requires if shutil.which(p) is None]


def _waiting_for(entry: Entry, states: dict[str, str], pending: set[str]) -> list[str]:
    """Entries of ``entry.after`` that are not current and will not run before it."""
    names = [n for d in entry.after for n in states if n == d or n.split(":")[0] == d]
    return [n for n in names if states[n] != "current" and n not in pending]


def plan(
    statuses: list[tuple[Entry, Status]],
    budget_s: float,
    quick: bool = False,
    states: dict[str, str] | None = None,
) -> tuple[list[tuple[Entry, Status, float]], list[tuple[Entry, Status, float, str]]]:
    """Split the non-current entries into (run, skipped-with-reason), cheapest first, each after
    the entries it reads (``Entry.after``; full mode only).

    ``states`` maps registry names to their state, for entries named in ``after`` that
    ``statuses`` does not hold (default: only those in ``statuses`` are known).  Returns lists of
    ``(entry, status, cost_s)`` to run in order, and of ``(entry, status, cost_s, reason)`` left
    out; an entry whose inputs are not current and not planned before it is left out.
    """

    def cost_of(entry: Entry, st: Status) -> float:
        if st.cost_s is not None:
            return st.cost_s
        if quick:
            return QUICK_COST_S
        return entry.estimated_cost_s if entry.estimated_cost_s is not None else UNKNOWN_COST_S

    todo = sorted(
        ((e, s, cost_of(e, s)) for e, s in statuses if s.state not in ("current", "retired")), key=lambda t: t[2]
    )
    known = {**(states or {}), **{e.name: s.state for e, s in statuses}}
    if not quick:
        # Cheapest first among those whose inputs are already planned (a stable topological order).
        ordered, rest = [], list(todo)
        while rest:
            planned = {e.name for e, _, _ in rest}
            ready = next((t for t in rest if not set(_waiting_for(t[0], known, set())) & planned), rest[0])
            ordered.append(ready)
            rest.remove(ready)
        todo = ordered
    run, skipped, left = [], [], budget_s
    for entry, st, cost in todo:
        missing = _missing_programs(entry)
        command = entry.quick if quick else entry.full
        waiting = [] if quick else _waiting_for(entry, known, {e.name for e, _, _ in run})
        if command is None:
            skipped.append((entry, st, cost, "no quick mode"))
        elif missing:
            skipped.append((entry, st, cost, f"needs {', '.join(missing)}"))
        elif waiting:
            skipped.append((entry, st, cost, f"reads {', '.join(waiting)}, not current"))
        elif cost > left:
            skipped.append((entry, st, cost, f"over the budget left ({format_cost(left)})"))
        else:
            run.append((entry, st, cost))
            left -= cost
    return run, skipped


def _select(names: list[str] | None) -> list[Entry]:
    if not names:
        return list(REGISTRY)
    known = {e.name: e for e in REGISTRY}
    unknown = [n for n in names if n not in known and not any(e.name.startswith(n + ":") for e in REGISTRY)]
    if unknown:
        raise SystemExit(f"unknown results {unknown}; known: {', '.join(known)}")
    return [e for e in REGISTRY if e.name in names or e.name.split(":")[0] in names]


def dependency_states(entries: list[Entry], quick: bool) -> dict[str, str]:
    """States of the registry entries that ``entries`` read (``Entry.after``)."""
    wanted = {d for e in entries for d in e.after}
    return {e.name: status_of(e, quick).state for e in REGISTRY if e.name in wanted or e.name.split(":")[0] in wanted}


def main(argv: list[str] | None = None) -> int:
    """Run (or, with ``--dry-run``, list) what fits the budget; exit 1 if a command failed."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--budget", type=parse_budget, required=True, help="e.g. 1h, 90m, 3600")
    parser.add_argument("--dry-run", action="store_true", help="list the plan, run nothing")
    parser.add_argument("--quick", action="store_true", help="regenerate the quick-mode JSONs instead")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="registry names (a file stem selects its parts)")
    parser.add_argument("--include-current", action="store_true", help="rerun current results too")
    args = parser.parse_args(argv)
    entries = [e for e in _select(args.only) if not args.quick or e.quick]

    def statuses() -> list[tuple[Entry, Status]]:
        out = [(e, status_of(e, args.quick)) for e in entries]
        if args.include_current:
            for _, s in out:
                s.state = "stale" if s.state == "current" else s.state
        return out

    done: set[str] = set()
    failed: list[str] = []
    left = args.budget
    first = True
    while True:
        current = [(e, s) for e, s in statuses() if e.name not in done]
        run, skipped = plan(current, left, args.quick, dependency_states(entries, args.quick))
        if first:
            print(
                f"budget {format_cost(args.budget)}, cheapest first; "
                f"{sum(s.state == 'current' for _, s in current)} current"
            )
            for e, s, cost in run:
                print(f"  run   {e.name:34s} {s.state:8s} {format_cost(cost):>9s}  {e.quick if args.quick else e.full}")
            for e, s, cost, why in skipped:
                print(f"  skip  {e.name:34s} {s.state:8s} {format_cost(cost):>9s}  {why}")
            long = [(e, s) for e, s in current if e.long and s.state not in ("current", "retired")]
            if long and not args.quick:
                total = sum(s.cost_s or UNKNOWN_COST_S for _, s in long)
                print(f"long runs not current ({format_cost(total)} together on the machine that made them):")
                for e, s in long:
                    print(f"  {e.name:34s} {format_cost(s.cost_s):>9s}  {e.full}")
            first = False
            if args.dry_run:
                return 0
        if not run:
            break
        entry, _, cost = run[0]
        command = entry.quick if args.quick else entry.full
        print(f"[{time.strftime('%H:%M:%S')}] {entry.name}: {command}", flush=True)
        if not args.quick and (restored := park.restore(entry, ROOT)):
            print(f"  restored its parked checkpoint: {', '.join(restored)}", flush=True)
        t0 = time.perf_counter()
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
        code = subprocess.run(command_argv(command), cwd=ROOT, env=env).returncode
        took = time.perf_counter() - t0
        left -= max(took, 0.0)
        done.add(entry.name)
        print(
            f"[{time.strftime('%H:%M:%S')}] {entry.name}: exit {code} after {format_cost(took)} "
            f"(expected {format_cost(cost)}), {format_cost(max(left, 0))} left",
            flush=True,
        )
        if code != 0:
            failed.append(entry.name)
        elif not args.quick and park.drop(entry, ROOT):
            print(f"  dropped its parked checkpoint, {park.parked_folder(entry, ROOT).relative_to(ROOT)}", flush=True)
    if failed:
        print(f"failed: {', '.join(failed)}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
