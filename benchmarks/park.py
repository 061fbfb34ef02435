"""Carry a long run's checkpoint between machines that keep nothing but the git tree.

A run longer than one sitting resumes from its checkpoint under ``runs/`` (untracked).  Where
machines are lent for one sitting and ``runs/`` does not outlive them, ``save`` copies the
checkpoint folders the registry declares for the run (``Entry.resumable``: small files, not the
per-simulation run caches) into ``benchmarks/parked/<name>/`` to be committed; on the next
machine ``regenerate.py`` (or ``restore``) copies them back before the same command continues
the run, and ``regenerate.py`` drops the parked copy once the run has finished.  The
checkpoint's own code stamp still refuses a resume on changed code.  A run resumed on another
CPU family is not bitwise the run one machine would make (XLA's float sums follow the host's
vector instructions): the parked copy records the CPU it was saved on (``parked.json``) and a
restore on another says so.

Usage::

    python -m benchmarks.park list
    python -m benchmarks.park save water_xray_surrogate_paper_preset:paper
    python -m benchmarks.park restore water_xray_surrogate_paper_preset:paper
    python -m benchmarks.park drop water_xray_surrogate_paper_preset:paper
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

from benchmarks._common import ROOT, cpu_signature, machine
from benchmarks.registry import REGISTRY, Entry

__all__ = ["drop", "parked_folder", "restore", "save"]

#: Where parked checkpoints live, tracked, one folder per registry entry.
PARKED = "benchmarks/parked"
#: The stamp beside a parked copy: what was saved, when and on which CPU.
STAMP = "parked.json"
#: Largest parked copy (bytes): a checkpoint, not a run cache.
MAX_BYTES = 5_000_000


def parked_folder(entry: Entry, root: Path = ROOT) -> Path:
    """The tracked folder that holds ``entry``'s parked checkpoint (``:`` becomes ``__``)."""
    return root / PARKED / entry.name.replace(":", "__")


def _size(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file()) if path.is_dir() else path.stat().st_size


def _copy(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    shutil.copytree(src, dst) if src.is_dir() else shutil.copy2(src, dst)


def save(entry: Entry, root: Path = ROOT) -> list[str]:
    """Copy ``entry``'s resumable paths into its parked folder (replacing an older copy).

    Returns the paths copied.  Raises ``SystemExit`` when the entry declares none, when none
    exists, or when they exceed :data:`MAX_BYTES`.
    """
    if not entry.resumable:
        raise SystemExit(f"{entry.name}: the registry declares no resumable checkpoint (Entry.resumable)")
    present = [p for p in entry.resumable if (root / p).exists()]
    if not present:
        raise SystemExit(f"{entry.name}: nothing to park, none of {list(entry.resumable)} exists")
    size = sum(_size(root / p) for p in present)
    if size > MAX_BYTES:
        raise SystemExit(f"{entry.name}: {size} bytes to park, more than {MAX_BYTES}: a run cache, not a checkpoint?")
    target = parked_folder(entry, root)
    shutil.rmtree(target, ignore_errors=True)
    for p in present:
        src, dst = root / p, target / p
        _copy(src, dst)
    stamp = {"paths": present, "bytes": size, "cpu": cpu_signature(machine()), "saved_unix": time.time()}
    (target / STAMP).write_text(json.dumps(stamp, indent=1) + "\n")
    return present


def restore(entry: Entry, root: Path = ROOT, force: bool = False) -> list[str]:
    """Copy ``entry``'s parked checkpoint back under ``runs/``; returns the paths restored.

    Paths that already exist are kept (the local checkpoint is at least as recent) unless
    ``force``; nothing parked restores nothing.
    """
    source = parked_folder(entry, root)
    done: list[str] = []
    for p in entry.resumable:
        src, dst = source / p, root / p
        local = dst.exists() and not (dst.is_dir() and not any(dst.iterdir()))  # an empty folder is none
        if not src.exists() or (local and not force):
            continue
        if dst.exists():
            shutil.rmtree(dst) if dst.is_dir() else dst.unlink()
        _copy(src, dst)
        done.append(p)
    if done:
        saved_on = json.loads((source / STAMP).read_text()).get("cpu") if (source / STAMP).is_file() else None
        here = cpu_signature(machine())
        if saved_on != here:
            print(f"{entry.name}: parked on {saved_on}, resumed on {here}: not bitwise one machine's run", flush=True)
    return done


def drop(entry: Entry, root: Path = ROOT) -> bool:
    """Remove ``entry``'s parked copy; True when there was one."""
    target = parked_folder(entry, root)
    if not target.exists():
        return False
    shutil.rmtree(target)
    return True


def main(argv: list[str] | None = None) -> int:
    """Command line: ``list``, or ``save``/``restore``/``drop`` NAME."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("action", choices=("list", "save", "restore", "drop"))
    parser.add_argument("names", nargs="*", metavar="NAME", help="registry names")
    parser.add_argument("--force", action="store_true", help="restore over an existing checkpoint")
    args = parser.parse_args(argv)
    known = {e.name: e for e in REGISTRY}
    unknown = [n for n in args.names if n not in known]
    if unknown:
        raise SystemExit(f"unknown results {unknown}; resumable: {[e.name for e in REGISTRY if e.resumable]}")
    if args.action == "list":
        for e in REGISTRY:
            if e.resumable:
                state = "parked" if parked_folder(e).exists() else "-"
                print(f"{e.name:45s} {state:7s} {' '.join(e.resumable)}")
        return 0
    if not args.names:
        raise SystemExit(f"{args.action}: name at least one result")
    for name in args.names:
        entry = known[name]
        if args.action == "save":
            print(f"{name}: parked {save(entry)} in {parked_folder(entry).relative_to(ROOT)}")
        elif args.action == "restore":
            print(f"{name}: restored {restore(entry, force=args.force) or 'nothing'}")
        else:
            print(f"{name}: {'dropped' if drop(entry) else 'nothing parked'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
