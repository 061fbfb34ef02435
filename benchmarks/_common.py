"""Shared helpers for benchmark scripts: machine record, provenance and JSON output.

Every saved result goes through :func:`write_result`, which adds a ``provenance`` block: the
commit, whether the tree was clean (and the dirty files), the date, the machine, the exact
command, the seconds the run took, and a fingerprint of what the result depends on -- the project
modules the process imported (files under ``jaxabc/``, ``md/`` and ``benchmarks/`` found in
``sys.modules``) and the data files declared with :func:`declare_input` or ``inputs=``.

Code is fingerprinted by :func:`code_hash`: a hash of the AST with docstrings removed, so a
reformatting, a comment or a docstring edit does not mark a result stale, while any change to
what the code does does.  Per-file hashes are kept so that ``benchmarks/status.py`` can name the
files that changed.
"""

from __future__ import annotations

import ast
import hashlib
import importlib
import json
import os
import platform
import shlex
import subprocess
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
QUICK_RESULTS = RESULTS / "quick"
#: Untracked run caches and checkpoints (``runs/``, gitignored).  ``JAXABC_RUNS_DIR`` moves them:
#: ``benchmarks.verify`` gives each quick check an empty folder, so a check never replays
#: simulations or results that earlier code cached.
RUNS = Path(os.environ.get("JAXABC_RUNS_DIR") or ROOT / "runs")
#: Top-level folders whose imported modules count as code a result depends on.
CODE_DIRS = ("jaxabc", "md", "benchmarks")
PROVENANCE_VERSION = 1

_declared_inputs: set[Path] = set()


def resolve_recorded(rel: str, runs: Path | None = None, root: Path | None = None) -> Path:
    """The inverse of :func:`relative`: a recorded ``runs/...`` path under ``runs`` (default
    :data:`RUNS`), any other under ``root`` (default the repository root)."""
    parts = Path(rel).parts
    if parts and parts[0] == "runs":
        return (RUNS if runs is None else runs).joinpath(*parts[1:])
    return (ROOT if root is None else root) / rel


def _process_start_time() -> float:
    """Epoch seconds at which this process started (Linux), else this module's import time."""
    try:
        with open("/proc/self/stat") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        start_ticks = int(fields[19])  # field 22 of proc(5), counted after the ")" of the name
        with open("/proc/stat") as fh:
            boot = next(int(line.split()[1]) for line in fh if line.startswith("btime"))
        return boot + start_ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, StopIteration):
        return time.time()


_PROCESS_START = _process_start_time()


def process_seconds() -> float:
    """Wall seconds since this process started (the default ``cost_s`` of a result)."""
    return time.time() - _PROCESS_START


def machine() -> dict[str, Any]:
    """What ran the benchmark: enough to compare numbers across machines."""
    from jaxabc.results import versions

    cpu = platform.processor() or ""
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        load = list(os.getloadavg())
    except OSError:
        load = None
    from md.lj.native import instruction_set

    return {
        "platform": platform.platform(),
        "cpu": cpu,
        "cpu_count": os.cpu_count(),
        "load_average": load,  # 1, 5, 15 min, at the time of writing
        "versions": versions(),
        # The compiled LJ kernel is built with -march=native by default: results that use it
        # reproduce bitwise only on the same instruction set (md.lj.native).
        "native_kernel_instruction_set": instruction_set(),
    }


def cpu_signature(machine: dict[str, Any]) -> str | None:
    """A provenance ``machine`` record's CPU and, where recorded, its vector instruction sets
    (``"AMD EPYC (avx, avx2, fma)"``); None when it names no CPU.

    Hosts that report the same CPU name may differ in their instruction sets (AVX-512 or not),
    and XLA compiles reductions for the host's: float sums then differ in the last bits, and
    chaotic runs after them.  Such numbers say nothing about the code."""
    cpu = machine.get("cpu")
    if not cpu:
        return None
    simd = (machine.get("native_kernel_instruction_set") or {}).get("simd")
    return f"{cpu} ({', '.join(simd)})" if simd else str(cpu)


# ----------------------------------------------------------------------------- fingerprints


def _strip_docstrings(tree: ast.AST) -> ast.AST:
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if (
                body
                and isinstance(body[0], ast.Expr)
                and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)
            ):
                # Keep a placeholder so that a body made only of a docstring stays valid.
                node.body = body[1:] or [ast.Pass()]
    return tree


def _canonical(node: Any) -> str:
    # ast.dump's text differs between Python versions for the same code (3.12 adds empty
    # type_params, 3.13 hides empty fields), so spell the tree out without empty fields.
    if isinstance(node, ast.AST):
        fields = [f"{k}={_canonical(v)}" for k, v in ast.iter_fields(node) if v is not None and v != []]
        return f"{type(node).__name__}({','.join(fields)})"
    if isinstance(node, list):
        return "[" + ",".join(_canonical(v) for v in node) + "]"
    return repr(node)


#: Tree hashes by (source digest, dump): ``status`` and the results pages hash the same few
#: hundred files thousands of times, and parsing them is most of their time.  Keyed on the bytes,
#: so an edited file is hashed afresh.
_TREE_HASHES: dict[tuple[bytes, Callable[[ast.AST], str]], str] = {}


def _hash_tree(path: str | Path, dump: Callable[[ast.AST], str]) -> str:
    source = Path(path).read_bytes()
    key = (hashlib.sha256(source).digest(), dump)
    if key in _TREE_HASHES:
        return _TREE_HASHES[key]
    try:
        tree = _strip_docstrings(ast.parse(source))
    except SyntaxError:
        digest = "raw:" + hashlib.sha256(source).hexdigest()[:16]
    else:
        digest = hashlib.sha256(dump(tree).encode()).hexdigest()[:16]
    _TREE_HASHES[key] = digest
    return digest


def code_hash(path: str | Path) -> str:
    """Hash of a Python file's meaning: its AST without docstrings, comments or layout.

    The same on every Python version that parses the file alike, so a result made on another
    machine (a lent GPU's Python 3.12, say) can be checked here.

    Parameters
    ----------
    path
        A ``.py`` file.

    Returns
    -------
    str
        16 hex digits.  A file that does not parse is hashed by its bytes (prefixed ``raw:``).
    """
    return _hash_tree(path, _canonical)


def legacy_code_hash(path: str | Path) -> str:
    """The hash that results written before the version-independent one carry (``ast.dump``).

    It depends on the Python version that computed it; status accepts it beside ``code_hash``.
    """
    return _hash_tree(path, _legacy_dump)


def _legacy_dump(tree: ast.AST) -> str:
    return ast.dump(tree, include_attributes=False)


def data_hash(path: str | Path) -> str:
    """Hash of a data file's bytes (16 hex digits)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()[:16]


def relative(path: str | Path) -> str:
    """``path`` as a result records it: ``runs/...`` under :data:`RUNS` (wherever
    ``JAXABC_RUNS_DIR`` put it), else relative to the repository root (POSIX), or absolute when
    it lies outside both."""
    p = Path(path).resolve()
    if p.is_relative_to(RUNS.resolve()):
        return (Path("runs") / p.relative_to(RUNS.resolve())).as_posix()
    try:
        return p.relative_to(ROOT).as_posix()
    except ValueError:
        return p.as_posix()


def imported_project_files() -> list[str]:
    """Repository-relative paths of the project modules loaded in this process (``.py`` only)."""
    files = set()
    for module in list(sys.modules.values()):
        file = getattr(module, "__file__", None)
        if not file or not file.endswith(".py"):
            continue
        rel = relative(file)
        # This helper decides how results are recorded, not what they are: editing it must not
        # mark every saved result stale.
        if rel.split("/", 1)[0] in CODE_DIRS and rel != "benchmarks/_common.py" and (ROOT / rel).is_file():
            files.add(rel)
    return sorted(files)


CODE_STAMP = "code_stamp.json"


def guard_resume(folder: str | Path, resuming: bool, modules: Iterable[str] = ()) -> None:
    """Refuse to resume checkpoints in ``folder`` that other code made; stamp this code there.

    A run continued on changed code would mix two versions of the method while its result records
    only the last, and a finished checkpoint would be "rerun" without computing anything.  The
    stamp holds the AST hash of every project module loaded so far, after importing ``modules``
    (those the run imports lazily, e.g. ``jaxabc.surrogate``).

    Raises
    ------
    SystemExit
        ``resuming``, ``folder`` holds a ``checkpoint.npz`` (at any depth), and the stamp is missing
        or names other code: the message lists the files.
    """
    for module in modules:
        importlib.import_module(module)
    folder = Path(folder)
    stamp = folder / CODE_STAMP
    now = {f: code_hash(ROOT / f) for f in imported_project_files()}
    # Nothing to resume (a first sitting with --resume): jaxabc.run says so itself.
    if resuming and any(folder.rglob("checkpoint.npz")):
        if not stamp.exists():
            raise SystemExit(
                f"{folder} holds checkpoints without a code stamp ({CODE_STAMP}): which code made them is "
                "unknown. Start over (delete the checkpoints; cached simulations are kept), or, if you "
                "know the code is the same, write the stamp with benchmarks/_common.py's stamp_code"
            )
        before = json.loads(stamp.read_text())["files"]
        changed = sorted(f for f in set(before) | set(now) if before.get(f) != now.get(f) and f in now)
        if changed:
            raise SystemExit(
                f"the checkpoints in {folder} were made by other code; changed since: {', '.join(changed)}. "
                "Start over (delete the checkpoints; cached simulations are kept), or restore that code"
            )
    stamp_code(folder, now)


def stamp_code(folder: str | Path, files: dict[str, str] | None = None) -> None:
    """Write ``folder/code_stamp.json``: the AST hashes of the loaded project modules (or ``files``)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    files = files if files is not None else {f: code_hash(ROOT / f) for f in imported_project_files()}
    (folder / CODE_STAMP).write_text(json.dumps({"files": files}, indent=1, sort_keys=True) + "\n")


def declare_input(*paths: str | Path) -> None:
    """Declare data files this run reads; their hashes go into the result's fingerprint."""
    for path in paths:
        p = Path(path)
        if p.is_dir():
            _declared_inputs.update(q.resolve() for q in sorted(p.rglob("*")) if q.is_file())
        else:
            _declared_inputs.add(p.resolve())


def fingerprint(code_files: Iterable[str], data_files: Iterable[str | Path]) -> dict[str, Any]:
    """Per-file hashes of code (AST) and data (bytes), and one digest over all of them."""
    code = {f: code_hash(ROOT / f) for f in sorted(set(code_files))}
    data = {}
    for f in data_files:
        p = Path(f) if Path(f).is_absolute() else ROOT / f
        if not p.is_file():
            raise FileNotFoundError(f"declared input {f} does not exist: declare only files the run read")
        data[relative(p)] = data_hash(p)
    data = dict(sorted(data.items()))
    digest = hashlib.sha256(json.dumps([code, data], sort_keys=True).encode()).hexdigest()[:16]
    return {"digest": digest, "code": code, "data": data}


# ----------------------------------------------------------------------------- git and command


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout if out.returncode == 0 else None


def git_state() -> dict[str, Any]:
    """Commit, and the files that differ from it (results folders excluded: runs write there)."""
    commit = _git("rev-parse", "HEAD")
    status = _git("status", "--porcelain", "--untracked-files=normal") or ""
    dirty = sorted(line[3:].strip() for line in status.splitlines() if line.strip())
    dirty = [f for f in dirty if not f.startswith(("benchmarks/results/", "docs/results/"))]
    if commit is None and os.environ.get("JAXABC_SOURCE_COMMIT"):
        # A copy of the tree without .git (e.g. on a lent GPU machine): the caller names the commit.
        return {
            "commit": os.environ["JAXABC_SOURCE_COMMIT"],
            "tree_clean": None,
            "dirty_files": [],
            "copied_tree": True,
        }
    return {
        "commit": commit.strip() if commit else None,
        "tree_clean": not dirty if commit else None,
        "dirty_files": dirty,
    }


def command_line(argv: list[str] | None = None) -> str:
    """The command that ran this process, as one would type it from the repository root."""
    argv = list(sys.argv if argv is None else argv)
    if argv and argv[0].endswith(".py"):
        argv[0] = relative(argv[0])
        # Benchmarks run as modules of the ``benchmarks`` package (``python -m benchmarks.<name>``).
        if argv[0].startswith("benchmarks/") and "/" not in argv[0].removeprefix("benchmarks/"):
            return shlex.join(["python", "-m", argv[0].removesuffix(".py").replace("/", "."), *argv[1:]])
    return shlex.join(["python", *argv])


def provenance(
    inputs: Iterable[str | Path] = (), command: str | None = None, cost_s: float | None = None
) -> dict[str, Any]:
    """The provenance block of a result written now by this process.

    Parameters
    ----------
    inputs
        Data files read, in addition to those given to :func:`declare_input`.
    command
        The command to record; default: this process's command line.
    cost_s
        Seconds the result took; default: wall seconds since this process started.
    """
    return {
        "version": PROVENANCE_VERSION,
        **git_state(),
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "command": command or command_line(),
        "cost_s": round(time.time() - _PROCESS_START, 1) if cost_s is None else cost_s,
        "machine": machine(),
        "fingerprint": fingerprint(imported_project_files(), [*_declared_inputs, *inputs]),
    }


def model_selection_record(choice: Any, name: str, given: bool, choice_folder: Path) -> dict[str, Any]:
    """The header saying which model of a model choice a result is about, and why.

    Parameters
    ----------
    choice
        The :class:`jaxabc.ModelChoiceResult` the model came from.
    name
        The model the result is about.
    given
        Whether the user named the model (``--model``) rather than taking the most probable one.
    choice_folder
        The folder the model choice was loaded from.
    """
    return {
        "model": name,
        "model_selected_as": "given (--model)" if given else "the most probable model of the model choice",
        "model_choice_misspecified": bool(choice.metadata.get("misspecified", False)),
        "model_choice_stop_reason": choice.stop_reason,
        "model_probability": choice.probability(name),
        "model_choice": relative(choice_folder),
    }


# ----------------------------------------------------------------------------- writing


def result_path(name: str, quick: bool = False) -> Path:
    """``benchmarks/results/<name>.json``, or ``benchmarks/results/quick/<name>.json``."""
    return (QUICK_RESULTS if quick else RESULTS) / f"{name}.json"


def write_result(
    name: str | Path,
    payload: dict[str, Any],
    *,
    quick: bool = False,
    part: str | Iterable[str] | None = None,
    inputs: Iterable[str | Path] = (),
    command: str | None = None,
    cost_s: float | None = None,
) -> Path:
    """Write a result JSON with its provenance; the one way benchmark scripts save results.

    Parameters
    ----------
    name
        Result name (``benchmarks/results/<name>.json``, or under ``quick/`` with ``quick``), or
        an explicit ``.json`` path (a script's ``--output``).
    payload
        The result.  Its ``provenance``/``provenance_parts`` keys, if any (a payload read back
        from the file it updates), are replaced.
    part
        For files that several commands fill in (one entry per preset, data set, ...): the
        part(s) this run wrote.  Their provenance goes to ``provenance_parts[part]``, the parts
        already in the file keep theirs; the caller merges the payload itself.  A file first
        written whole keeps that provenance as ``provenance_before_parts``.
    inputs
        Data files read (added to those declared with :func:`declare_input`).
    command
        Command to record (default: this process's command line).
    cost_s
        Seconds the result cost (default: this process's wall time so far); a process that
        writes several parts one after another gives each its own.

    Returns
    -------
    pathlib.Path
        The file written.
    """
    path = Path(name) if str(name).endswith(".json") else result_path(str(name), quick)
    prov = provenance(inputs, command, cost_s)
    own = ("provenance", "provenance_parts", "provenance_before_parts")
    body = {k: v for k, v in payload.items() if k not in own}
    out: dict[str, Any] = {"benchmark": path.stem, **body, "provenance": prov}
    if part is not None:
        old: dict[str, Any] = {}
        if path.exists():
            try:
                old = json.loads(path.read_text())
            except json.JSONDecodeError:
                old = {}
        old = old if isinstance(old, dict) else {}
        parts = old.get("provenance_parts", {})
        # A file written whole before it was written a part at a time: its provenance stays the
        # record of the parts not yet rewritten (their numbers are still that run's).
        before = old.get("provenance_before_parts") or (None if parts else old.get("provenance"))
        if before:
            out["provenance_before_parts"] = before
        names = [part] if isinstance(part, str) else list(part)
        out["provenance_parts"] = {**parts, **{p: prov for p in names}}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1, default=_json_default) + "\n")
    return path


def _json_default(value: Any) -> Any:
    try:
        import numpy as np

        if isinstance(value, np.ndarray):
            return value.tolist()
        if isinstance(value, np.generic):
            return value.item()
    except ImportError:  # pragma: no cover
        pass
    if isinstance(value, Path):
        return value.as_posix()
    return float(value)
