"""The package layout: inference never imports simulators, and no import cycles among jaxabc's modules.

Imports are read from the source (``ast``), inside functions too: an import deferred into a
function body is still a dependency, and two modules that defer imports of each other still form
a loop that a reader has to untangle.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).parents[1]


def _modules(package: str) -> dict[str, Path]:
    out = {}
    for path in sorted((ROOT / package).rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _imports(name: str, path: Path) -> set[str]:
    """Every module name an import statement in ``path`` names (``from a import b``: ``a.b``)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                package = name if path.name == "__init__.py" else name.rpartition(".")[0]
                for _ in range(node.level - 1):
                    package = package.rpartition(".")[0]
                base = f"{package}.{base}".rstrip(".")
            # The package's version string is metadata, not code: reading it is no dependency.
            found.update(f"{base}.{alias.name}" for alias in node.names if alias.name != "__version__")
    return found


def _graph(package: str) -> dict[str, set[str]]:
    modules = _modules(package)

    def resolve(target: str) -> str | None:
        while target and target not in modules:
            target = target.rpartition(".")[0]
        return target or None

    graph = {}
    for name, path in modules.items():
        edges = {resolve(t) for t in _imports(name, path) if t.split(".")[0] == package}
        graph[name] = {e for e in edges if e is not None and e != name}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    cycles, state = [], {}

    def visit(node: str, stack: list[str]) -> None:
        state[node] = "open"
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == "open":
                cycles.append([*stack[stack.index(nxt) :], nxt])
            elif nxt not in state:
                visit(nxt, stack)
        stack.pop()
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [])
    return cycles


def test_jaxabc_never_imports_md() -> None:
    offenders = {
        name: sorted(t for t in _imports(name, path) if t.split(".")[0] == "md")
        for name, path in _modules("jaxabc").items()
    }
    assert not {k: v for k, v in offenders.items() if v}, "jaxabc (inference) must not import md (simulators)"


def test_md_never_imports_the_command_line() -> None:
    offenders = [
        name for name, path in _modules("md").items() if any(t.startswith("jaxabc.cli") for t in _imports(name, path))
    ]
    assert not offenders


def test_no_import_cycle_among_jaxabc_modules() -> None:
    graph = _graph("jaxabc")
    assert "jaxabc.executors.mpi" in graph and "jaxabc.executors.workers" in graph
    assert _cycles(graph) == []


def test_the_cycle_finder_finds_the_loops_it_is_meant_to_catch() -> None:
    # The two loops the layout removed: executors <-> mpi (one import deferred into a function)
    # and a three-module ring.
    assert _cycles({"a": {"b"}, "b": {"a"}}) == [["a", "b", "a"]]
    assert _cycles({"x": {"y"}, "y": {"z"}, "z": {"x"}, "w": {"x"}}) == [["x", "y", "z", "x"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_executors_and_mpi_share_one_worker_module() -> None:
    graph = _graph("jaxabc")
    assert "jaxabc.executors.workers" in graph["jaxabc.executors.local"]
    assert "jaxabc.executors.workers" in graph["jaxabc.executors.mpi"]
    # MPI reaches the rest of the executors only through the base and worker modules, and the
    # scheduling cost models (a leaf that imports no executor).
    assert graph["jaxabc.executors.mpi"] & {m for m in graph if m.startswith("jaxabc.executors")} <= {
        "jaxabc.executors.base",
        "jaxabc.executors.scheduling",
        "jaxabc.executors.workers",
    }
    assert not {m for m in graph["jaxabc.executors.scheduling"] if m.startswith("jaxabc.executors")}


def test_jaxabc_imports_nothing_by_a_string_it_wrote() -> None:
    # importlib.import_module("literal") hides a dependency from readers and from the cycle check.
    offenders = []
    for name, path in _modules("jaxabc").items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if (
                isinstance(node, ast.Call)
                and getattr(node.func, "attr", getattr(node.func, "id", "")) in ("import_module", "__import__")
                and node.args
                and isinstance(node.args[0], ast.Constant)
            ):
                offenders.append(f"{name}:{node.lineno}")
    assert offenders == []


def test_top_level_of_jaxabc_is_small() -> None:
    modules = sorted(p.stem for p in (ROOT / "jaxabc").glob("*.py") if p.name != "__init__.py")
    assert len(modules) <= 12, modules


def test_no_private_name_is_imported_from_another_module() -> None:
    # A leading underscore means "this module only"; private *modules* inside a package are fine.
    offenders = []
    modules = _modules("jaxabc")
    for name, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "jaxabc":
                offenders += [
                    f"{name}: {node.module}.{a.name}"
                    for a in node.names
                    if a.name.startswith("_")
                    and not a.name.startswith("__")
                    and f"{node.module}.{a.name}" not in modules
                ]
    assert offenders == []


def test_no_function_in_jaxabc_is_longer_than_150_lines() -> None:
    # A function a reader cannot hold in view is split at its seams (design, fit, sampling, ...).
    long = []
    for name, path in _modules("jaxabc").items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = (node.end_lineno or node.lineno) - node.lineno + 1
                if lines > 150:
                    long.append(f"{name}.{node.name}: {lines} lines")
    assert long == []


def test_moved_public_modules_import_from_their_old_names_with_a_warning() -> None:
    import importlib
    import sys
    import warnings

    import jaxabc

    for old, new in jaxabc._MOVED.items():
        sys.modules.pop(old, None)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            module = importlib.import_module(old)
        assert module is importlib.import_module(new)
        assert any(issubclass(w.category, DeprecationWarning) and new in str(w.message) for w in caught), old
