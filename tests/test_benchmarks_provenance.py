"""Provenance of saved benchmark results: fingerprints, the stale check, the regeneration plan.

Fast: everything runs on small files in a temporary directory; no benchmark runs.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import math
import re
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import pytest

from benchmarks import _common, regenerate, registry, status, verify

ROOT = Path(__file__).resolve().parents[1]

SOURCE = textwrap.dedent('''
    """Module docstring."""

    import math

    SCALE = 2.0


    def f(x):
        """Twice x."""
        return SCALE * math.sqrt(x)  # a comment
''')


def test_code_hash_ignores_docstrings_comments_and_layout(tmp_path: Path) -> None:
    a, b = tmp_path / "a.py", tmp_path / "b.py"
    a.write_text(SOURCE)
    b.write_text(
        'import math\nSCALE = 2.0\ndef f(x):\n    """Another docstring,\n    two lines."""\n'
        "    # new comment\n    return SCALE * math.sqrt(\n        x\n    )\n"
    )
    assert _common.code_hash(a) == _common.code_hash(b)


@pytest.mark.parametrize(
    "edit",
    [
        ("SCALE = 2.0", "SCALE = 2.5"),
        ("math.sqrt(x)", "math.sqrt(x + 0)"),
        ('"""Twice x."""\n', '"""Twice x."""\n    x = abs(x)\n'),
    ],
)
def test_code_hash_sees_changes_of_meaning(tmp_path: Path, edit: tuple[str, str]) -> None:
    a, b = tmp_path / "a.py", tmp_path / "b.py"
    a.write_text(SOURCE)
    b.write_text(SOURCE.replace(*edit))
    assert b.read_text() != a.read_text()
    assert _common.code_hash(a) != _common.code_hash(b)


def test_function_made_only_of_a_docstring_still_hashes(tmp_path: Path) -> None:
    a = tmp_path / "a.py"
    a.write_text('def f():\n    """Nothing."""\n')
    b = tmp_path / "b.py"
    b.write_text("def f():\n    pass\n")
    assert _common.code_hash(a) == _common.code_hash(b)


@pytest.fixture
def fake_repo(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """A repository root with one imported project module and one data file."""
    (tmp_path / "jaxabc").mkdir()
    module_file = tmp_path / "jaxabc" / "fake_dependency.py"
    module_file.write_text(SOURCE)
    data = tmp_path / "data.txt"
    data.write_text("1 2 3\n")
    spec = importlib.util.spec_from_file_location("fake_dependency_for_provenance", module_file)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setitem(sys.modules, "fake_dependency_for_provenance", module)
    monkeypatch.setattr(_common, "ROOT", tmp_path)
    monkeypatch.setattr(_common, "_declared_inputs", set())
    # The machine record imports jax for its versions: not what these tests are about.
    monkeypatch.setattr(_common, "machine", lambda: {"cpu": "test"})
    return tmp_path


def write_fake(root: Path, name: str = "res", **kwargs) -> Path:
    return _common.write_result(
        root / "benchmarks" / "results" / f"{name}.json",
        {"value": 1.5},
        inputs=[root / "data.txt"],
        command="python -m benchmarks.fake",
        **kwargs,
    )


def test_write_result_records_provenance(fake_repo: Path) -> None:
    data = json.loads(write_fake(fake_repo).read_text())
    prov = data["provenance"]
    assert data["value"] == 1.5 and data["benchmark"] == "res"
    assert prov["command"] == "python -m benchmarks.fake"
    assert prov["fingerprint"]["code"] == {
        "jaxabc/fake_dependency.py": _common.code_hash(fake_repo / "jaxabc/fake_dependency.py")
    }
    assert list(prov["fingerprint"]["data"]) == ["data.txt"]
    assert prov["cost_s"] >= 0 and prov["date_utc"].endswith("Z")
    assert {"commit", "tree_clean", "dirty_files", "machine"} <= set(prov)
    assert status.check_provenance(prov, fake_repo) == []


def test_stale_check_names_what_changed(fake_repo: Path) -> None:
    prov = json.loads(write_fake(fake_repo).read_text())["provenance"]
    module_file = fake_repo / "jaxabc/fake_dependency.py"
    module_file.write_text(SOURCE.replace('"""Twice x."""', '"""Twice x, reworded."""') + "# trailing\n")
    assert status.check_provenance(prov, fake_repo) == []
    module_file.write_text(SOURCE.replace("SCALE = 2.0", "SCALE = 3.0"))
    assert status.check_provenance(prov, fake_repo) == ["jaxabc/fake_dependency.py"]
    (fake_repo / "data.txt").write_text("1 2 4\n")
    assert status.check_provenance(prov, fake_repo) == ["jaxabc/fake_dependency.py", "data.txt"]
    module_file.unlink()
    assert status.check_provenance(prov, fake_repo)[0] == "jaxabc/fake_dependency.py (removed)"


def test_code_hash_is_the_same_across_python_versions(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Python 3.12 gives every FunctionDef an empty ``type_params`` and 3.13's ast.dump hides empty
    # fields: a parse that differs only by such empty fields must hash alike, while ast.dump does not.
    a = tmp_path / "a.py"
    a.write_text(SOURCE)
    before, legacy = _common.code_hash(a), _common.legacy_code_hash(a)
    real_parse = _common.ast.parse

    def parse_with_empty_fields(source: bytes, *args: object, **kwargs: object) -> object:
        tree = real_parse(source, *args, **kwargs)  # type: ignore[arg-type]
        for node in _common.ast.walk(tree):
            if isinstance(node, _common.ast.FunctionDef):
                node._fields = (*node._fields, "type_params")
                node.type_params = []  # type: ignore[attr-defined]
        return tree

    monkeypatch.setattr(_common.ast, "parse", parse_with_empty_fields)
    # As in a new interpreter: nothing hashed yet.
    monkeypatch.setattr(_common, "_TREE_HASHES", {})
    assert _common.code_hash(a) == before
    assert _common.legacy_code_hash(a) != legacy


def test_status_accepts_the_legacy_hash(fake_repo: Path) -> None:
    prov = json.loads(write_fake(fake_repo).read_text())["provenance"]
    module_file = fake_repo / "jaxabc/fake_dependency.py"
    prov["fingerprint"]["code"]["jaxabc/fake_dependency.py"] = _common.legacy_code_hash(module_file)
    assert status.check_provenance(prov, fake_repo) == []
    module_file.write_text(SOURCE.replace("SCALE = 2.0", "SCALE = 3.0"))
    assert status.check_provenance(prov, fake_repo) == ["jaxabc/fake_dependency.py"]


def test_missing_declared_input_is_an_error(fake_repo: Path) -> None:
    with pytest.raises(FileNotFoundError, match="declared input"):
        _common.write_result(fake_repo / "r.json", {}, inputs=[fake_repo / "absent.txt"])


def test_parts_keep_each_commands_provenance(fake_repo: Path) -> None:
    path = write_fake(fake_repo, part="cpu")
    _common.write_result(path, json.loads(path.read_text()), part=["paper", "gpu"], command="python other.py")
    data = json.loads(path.read_text())
    assert set(data["provenance_parts"]) == {"cpu", "paper", "gpu"}
    assert data["provenance_parts"]["cpu"]["command"] == "python -m benchmarks.fake"
    assert data["provenance_parts"]["paper"]["command"] == "python other.py"


def test_a_run_over_several_sittings_costs_its_whole_wall_time(fake_repo: Path) -> None:
    """A resumed run's JSON is written by its last sitting's process: status must not plan a
    rerun at that process's cost (a 64-minute water run showed as 48 s)."""
    path = fake_repo / "benchmarks/results/res.json"
    for part, body in (
        ("one", {"wall_time_s": 5000.0, "sittings": 1}),
        ("two", {"wall_time_s": 5000.0, "sittings": 2}),
        ("three", {"wall_time_s": 5000.0, "wall_time_sittings": 3}),
    ):
        payload = json.loads(path.read_text()) if path.exists() else {}
        _common.write_result(path, {**payload, part: body}, inputs=[fake_repo / "data.txt"], part=part)
    one = status.status_of(registry.Entry("res:one", "benchmarks/results/res.json", "x", part="one"), root=fake_repo)
    two = status.status_of(registry.Entry("res:two", "benchmarks/results/res.json", "x", part="two"), root=fake_repo)
    assert one.cost_source == "recorded" and one.cost_s is not None and one.cost_s < 5000.0
    assert (two.cost_s, two.cost_source) == (5000.0, "recorded over 2 sittings")
    three = status.status_of(
        registry.Entry("res:three", "benchmarks/results/res.json", "x", part="three"), root=fake_repo
    )
    assert (three.cost_s, three.cost_source) == (5000.0, "recorded over 3 sittings")


def test_a_run_that_reused_work_costs_its_stated_rerun(fake_repo: Path) -> None:
    """A run that imported or replayed most of its cells states what rerunning its code costs:
    status must plan that, not the import's few minutes (surrogate_peers showed 3.1 min for 5 h)."""
    path = fake_repo / "benchmarks/results/res.json"
    _common.write_result(path, {"rerun_cost_s": 18000.0}, inputs=[fake_repo / "data.txt"])
    st = status.status_of(registry.Entry("res", "benchmarks/results/res.json", "x"), root=fake_repo)
    assert (st.cost_s, st.cost_source) == (18000.0, "recorded (rerun of its code)")
    _common.write_result(path, {"rerun_cost_s": 0.0}, inputs=[fake_repo / "data.txt"])
    st = status.status_of(registry.Entry("res", "benchmarks/results/res.json", "x"), root=fake_repo)
    assert st.cost_source == "recorded"


def test_a_file_split_into_parts_keeps_the_provenance_of_its_whole_run(fake_repo: Path) -> None:
    """The parts not yet rewritten still hold the numbers of the run that wrote the file whole."""
    path = fake_repo / "benchmarks/results/res.json"
    _common.write_result(path, {"x": 1}, inputs=[fake_repo / "data.txt"], command="python whole.py")
    _common.write_result(path, {"x": 2}, inputs=[fake_repo / "data.txt"], command="python a.py", part="a")
    _common.write_result(path, {"x": 3}, inputs=[fake_repo / "data.txt"], command="python b.py", part="b")
    data = json.loads(path.read_text())
    assert data["provenance_before_parts"]["command"] == "python whole.py"
    assert {k: v["command"] for k, v in data["provenance_parts"].items()} == {"a": "python a.py", "b": "python b.py"}
    fresh = fake_repo / "benchmarks/results/fresh.json"
    _common.write_result(fresh, {"x": 1}, inputs=[fake_repo / "data.txt"], part="a")
    _common.write_result(fresh, {"x": 1}, inputs=[fake_repo / "data.txt"], part="b")
    assert "provenance_before_parts" not in json.loads(fresh.read_text())  # written a part at a time from the start


def test_a_part_costs_its_own_stated_rerun(fake_repo: Path) -> None:
    """A file written a part at a time states each part's rerun cost (surrogate_peers' problems)."""
    path = fake_repo / "benchmarks/results/res.json"
    body = {"rerun_cost_s": 9000.0, "rerun_cost_s_parts": {"a": 3000.0, "b": 0.0}}
    _common.write_result(path, body, inputs=[fake_repo / "data.txt"], part=["a", "b"])
    a = status.status_of(registry.Entry("res:a", "benchmarks/results/res.json", "x", part="a"), root=fake_repo)
    b = status.status_of(registry.Entry("res:b", "benchmarks/results/res.json", "x", part="b"), root=fake_repo)
    assert (a.cost_s, a.cost_source) == (3000.0, "recorded (rerun of its code)")
    assert b.cost_source == "recorded" and b.cost_s is not None and b.cost_s < 3000.0


def test_status_of_entries(fake_repo: Path) -> None:
    write_fake(fake_repo, part="a")
    legacy = fake_repo / "benchmarks/results/legacy.json"
    legacy.write_text(json.dumps({"runs": [{"seconds": 2.0}, {"seconds": 3.0}]}))
    entry = registry.Entry("res:a", "benchmarks/results/res.json", "python x.py", part="a")
    assert status.status_of(entry, root=fake_repo).state == "current"
    other_part = registry.Entry("res:b", "benchmarks/results/res.json", "python x.py", part="b", estimated_cost_s=7.0)
    st = status.status_of(other_part, root=fake_repo)
    assert (st.state, st.cost_s, st.cost_source) == ("unknown", 7.0, "registry estimate")
    old = registry.Entry(
        "legacy", "benchmarks/results/legacy.json", "python x.py", legacy_cost_keys=("runs/*/seconds",)
    )
    st = status.status_of(old, root=fake_repo)
    assert (st.state, st.cost_s) == ("unknown", 5.0)
    absent = registry.Entry("absent", "benchmarks/results/absent.json", "python x.py")
    assert status.status_of(absent, root=fake_repo).state == "missing"
    (fake_repo / "data.txt").write_text("changed\n")
    st = status.status_of(entry, root=fake_repo)
    assert (st.state, st.changed) == ("stale", ["data.txt"])


def test_a_retired_result_is_listed_with_its_reason_and_never_rerun(fake_repo: Path) -> None:
    reason = "superseded by res_new (same data, with provenance)"
    gone = registry.Entry("old", "benchmarks/results/old.json", "python -m benchmarks.old", retired=reason)
    st = status.status_of(gone, root=fake_repo)
    assert (st.state, st.why) == ("retired", reason)
    # A retired result whose file is still there says so: the pages would otherwise show it.
    write_fake(fake_repo, name="old")
    assert "still there: delete it" in status.status_of(gone, root=fake_repo).why
    run, skipped = regenerate.plan([(gone, st)], budget_s=1e9)
    assert not run and not skipped
    assert "retired" in status.render([st]) and reason in status.render([st])


def test_no_kept_result_reads_a_retired_one() -> None:
    retired = {e.name for e in registry.REGISTRY if e.retired}
    for e in registry.REGISTRY:
        if e.retired:
            assert len(e.retired) > 20, f"{e.name}: say why it is retired and what supersedes it"
            continue
        assert not {n for d in e.after for n in retired if n == d or n.split(":")[0] == d}, e.name


def test_deterministic_view_and_comparison() -> None:
    saved = {
        "d_E": 0.0272,
        "wall_time_s": 10.0,
        "rows": [{"seconds": 1.0, "n": 3, "x": float("nan")}],
        "provenance": {"commit": "a"},
        "machine": {"cpu": "x"},
    }
    rerun = {
        "d_E": 0.0272,
        "wall_time_s": 99.0,
        "rows": [{"seconds": 2.0, "n": 3, "x": float("nan")}],
        "provenance": {"commit": "b"},
        "machine": {"cpu": "y"},
    }
    view = status.deterministic_view
    assert status.compare_numbers(view(saved), view(rerun)) == []
    rerun["d_E"] = 0.0273
    assert status.compare_numbers(view(saved), view(rerun)) == ["/d_E: 0.0272 != 0.0273"]
    assert status.compare_numbers(view(saved), view(rerun), rtol=0.01) == []
    rerun["rows"].append({})
    assert status.compare_numbers(view(saved), view(rerun))[-1] == "/rows: length 1 != 2"
    # A part-at-a-time file's earlier provenance and its parts' rerun costs are not numbers to compare.
    split = {"n": 1, "provenance_before_parts": {"commit": "a"}, "rerun_cost_s_parts": {"linear": 3.0}}
    assert view(split) == {"n": 1}


def test_budget_and_plan_run_cheapest_first_within_budget() -> None:
    assert regenerate.parse_budget("1h") == 3600
    assert regenerate.parse_budget("1h30m") == 5400
    assert regenerate.parse_budget("45") == 45
    with pytest.raises(Exception, match="budget"):
        regenerate.parse_budget("soon")

    def item(name: str, state: str, cost: float | None, long: bool = False):
        entry = registry.Entry(name, f"benchmarks/results/{name}.json", f"python {name}.py", long=long)
        return entry, status.Status(name, entry.output, state, cost_s=cost)

    statuses = [
        item("big", "stale", 3000.0),
        item("small", "unknown", 60.0),
        item("ok", "current", 1.0),
        item("mid", "stale", 600.0),
        item("water", "stale", 20000.0, long=True),
    ]
    run, skipped = regenerate.plan(statuses, budget_s=3600.0)
    assert [e.name for e, _, _ in run] == ["small", "mid"]
    assert [e.name for e, *_ in skipped] == ["big", "water"]
    assert all("budget" in why for *_, why in skipped)


def test_plan_runs_an_entry_after_the_results_it_reads() -> None:
    def item(name: str, state: str, cost: float, after: tuple[str, ...] = ()):
        entry = registry.Entry(name, f"benchmarks/results/{name}.json", f"python {name}.py", after=after)
        return entry, status.Status(name, entry.output, state, cost_s=cost)

    statuses = [
        item("criticism", "stale", 60.0, after=("choice",)),
        item("choice", "stale", 600.0),
        item("other", "stale", 100.0),
    ]
    run, _ = regenerate.plan(statuses, budget_s=3600.0)
    assert [e.name for e, _, _ in run] == ["other", "choice", "criticism"]
    # Its input over the budget, or not selected and stale: held back, not run on old inputs.
    run, skipped = regenerate.plan(statuses, budget_s=300.0)
    assert [e.name for e, _, _ in run] == ["other"]
    assert any(e.name == "criticism" and "reads choice" in why for e, *_, why in skipped)
    run, skipped = regenerate.plan(statuses[:1], budget_s=3600.0, states={"choice": "stale"})
    assert not run and "reads choice" in skipped[0][3]
    run, _ = regenerate.plan(statuses[:1], budget_s=3600.0, states={"choice": "current"})
    assert [e.name for e, _, _ in run] == ["criticism"]


def test_registry_is_consistent() -> None:
    names = [e.name for e in registry.REGISTRY]
    assert len(names) == len(set(names))
    for e in registry.REGISTRY:
        module = e.full.split()[2]
        assert (ROOT / (module.replace(".", "/") + ".py")).is_file(), e.name
        assert e.output.startswith("benchmarks/results/") and e.output.endswith(".json")
        assert (e.quick is None) == (e.quick_output is None), e.name
        if e.quick_output:
            assert e.quick_output.startswith("benchmarks/results/quick/"), e.name
        if ":" in e.name:
            assert e.part == e.name.split(":", 1)[1], e.name
        for dep in e.after:
            assert any(n == dep or n.split(":")[0] == dep for n in names), (e.name, dep)


def test_every_benchmark_script_saves_through_write_result() -> None:
    # Tools, and private helper modules (leading underscore), are not benchmarks.
    tools = {"status.py", "regenerate.py", "registry.py", "make_docs.py", "verify.py", "park.py"}
    scripts = [p for p in (ROOT / "benchmarks").glob("*.py") if p.name not in tools and not p.name.startswith("_")]
    assert scripts
    registered = {e.full.split()[2] for e in registry.REGISTRY if e.full.split()[1] == "-m"}
    for script in scripts:
        assert "write_result(" in script.read_text(), f"{script.name} must save its JSON through write_result"
        assert f"benchmarks.{script.stem}" in registered, f"{script.name} has no entry in registry.py"


def test_no_benchmark_script_imports_another() -> None:
    """What scripts share lives in private modules (``benchmarks/_*.py``): a script importing
    another would make every result of one depend on the other's code."""
    scripts = {p.stem for p in (ROOT / "benchmarks").glob("*.py") if not p.name.startswith("_")}
    tools = {"status", "regenerate", "registry", "make_docs", "verify", "park"}
    # Left until their results are rerun, since moving the import changes code no quick check
    # covers: gpu_throughput's GPU rows need a GPU (none lent here).
    waived = {
        ("gpu_throughput", "engine_throughput"),
    }
    for path in (ROOT / "benchmarks").glob("*.py"):
        if path.stem in tools:
            continue
        imported = set(re.findall(r"^\s*(?:from|import) benchmarks\.(\w+)", path.read_text(), re.MULTILINE))
        imported = {name for name in imported & (scripts - tools) if (path.stem, name) not in waived}
        assert not imported, f"{path.name} imports {sorted(imported)}"


def test_benchmarks_are_a_package_run_with_python_m() -> None:
    """``python -m benchmarks.<name>``: no script edits sys.path, every command is a module run."""
    for path in [*(ROOT / "benchmarks").glob("*.py"), *(ROOT / "benchmarks" / "docpages").glob("*.py")]:
        assert "sys.path.insert" not in path.read_text(), path.name
    for e in registry.REGISTRY:
        for command in (e.full, e.quick):
            if command:
                assert command.startswith("python -m benchmarks."), (e.name, command)
    script = str(ROOT / "benchmarks" / "coverage.py")
    assert _common.command_line([script, "--quick"]) == "python -m benchmarks.coverage --quick"


def test_results_pages_render_and_name_their_sources() -> None:
    from benchmarks import make_docs

    for name, render in make_docs.PAGES.items():
        text = render()
        assert text.startswith("# "), name
        if name != "index.md":
            assert "Source: `benchmarks/results/" in text, f"{name} does not name its JSON"
            assert "commit `" in text, f"{name} does not name the commit of its JSON"


def test_generated_blocks_have_markers_and_name_their_source() -> None:
    from benchmarks import make_docs

    for name, (rel, render) in make_docs.BLOCKS.items():
        text = (ROOT / rel).read_text()
        filled = make_docs.fill_blocks(text, rel)
        assert f"<!-- generated: {name} -->" in filled, name
        body = render()
        assert "Source: `benchmarks/results/" in body or body.startswith("Not run yet"), name
    with pytest.raises(ValueError, match="lacks the markers"):
        make_docs.fill_blocks("no markers here", "md/water/README.md")


# ----------------------------------------------------------------------------- numerical currency


#: A result with a quick mode, as the numerical-currency tests use it.
QUICK_ENTRY = registry.Entry(
    "res",
    "benchmarks/results/res.json",
    "python x.py",
    quick="python x.py --quick",
    quick_output="benchmarks/results/quick/res.json",
)


def _fake_quick_run(root: Path, value: float, entry: registry.Entry):
    """Stands for the quick command: writes the quick JSON with this process's provenance."""

    def run(argv, cwd, env):
        _common.write_result(
            root / entry.quick_output, {"value": value}, inputs=[root / "data.txt"], command=entry.quick
        )
        return subprocess.CompletedProcess(argv, 0, "", "")

    return run


def test_a_missing_quick_input_is_made_by_the_quick_mode_it_runs_after(
    fake_repo: Path, monkeypatch, tmp_path_factory
) -> None:
    """A check never reads the checkout's untracked caches (they may hold earlier code's runs): it
    makes its quick inputs in its own runs folder with the quick mode of the entry it runs after,
    restores that entry's quick JSON, then checks; an input nothing makes is a clear failure."""
    from benchmarks import verify

    producer = registry.Entry(
        "maker",
        "benchmarks/results/maker.json",
        "python m.py",
        quick="python m.py --tiny",
        quick_output="benchmarks/results/quick/maker.json",
    )
    entry = registry.Entry(
        "res",
        "benchmarks/results/res.json",
        "python x.py",
        quick="python x.py --quick",
        quick_output="benchmarks/results/quick/res.json",
        quick_inputs=("runs/cache/tiny",),
        after=("maker",),
    )
    write_fake(fake_repo)
    _common.write_result(fake_repo / entry.quick_output, {"value": 1.5}, inputs=[fake_repo / "data.txt"])
    maker_quick = fake_repo / producer.quick_output
    maker_quick.write_text('{"saved": true}')
    (fake_repo / "runs/cache/tiny").mkdir(parents=True)  # the checkout's cache: earlier code's, never read
    calls, folders = [], set()

    def run(argv, cwd, env):
        calls.append(" ".join(argv))
        runs = Path(env["JAXABC_RUNS_DIR"])
        folders.add(runs)
        if "m.py" in argv:
            (runs / "cache/tiny").mkdir(parents=True, exist_ok=True)
            maker_quick.write_text('{"overwritten": true}')
            return subprocess.CompletedProcess(argv, 0, "", "")
        if not (runs / "cache/tiny").is_dir():
            return subprocess.CompletedProcess(argv, 1, "", "FileNotFoundError: runs/cache/tiny")
        return _fake_quick_run(fake_repo, 1.5, entry)(argv, cwd, env)

    monkeypatch.setattr(verify, "by_name", lambda name: {"maker": producer}[name])
    monkeypatch.setattr(verify, "_run_command", run)
    record = verify.check(entry, fake_repo)
    assert record["outcome"] == "reproduces", record
    assert [c.split()[-1] for c in calls] == ["--tiny", "--quick"]
    assert maker_quick.read_text() == '{"saved": true}'  # the producer's saved quick JSON is put back
    (folder,) = folders
    assert fake_repo not in folder.parents and not folder.exists()  # its own folder, removed afterwards
    # A second check in its own folder makes the input again; in a folder it shares (one verify
    # invocation), the input made by today's code is not made again.
    calls.clear()
    assert verify.check(entry, fake_repo)["outcome"] == "reproduces" and len(calls) == 2
    shared = tmp_path_factory.mktemp("runs")
    assert verify.check(entry, fake_repo, shared)["outcome"] == "reproduces"
    calls.clear()
    assert verify.check(entry, fake_repo, shared)["outcome"] == "reproduces" and len(calls) == 1
    # An input no quick mode makes.
    lonely = dataclasses.replace(entry, quick_inputs=("runs/cache/other",))
    failed = verify.check(lonely, fake_repo)
    assert failed["outcome"] == "failed" and "runs/cache/other" in failed["detail"]


def test_a_code_change_is_current_when_the_quick_mode_reproduces(fake_repo: Path, monkeypatch) -> None:
    from benchmarks import verify

    entry = QUICK_ENTRY
    write_fake(fake_repo)
    _common.write_result(fake_repo / entry.quick_output, {"value": 1.5}, inputs=[fake_repo / "data.txt"])
    assert (status.status_of(entry, root=fake_repo).why) == "code unchanged"
    module_file = fake_repo / "jaxabc/fake_dependency.py"
    module_file.write_text(SOURCE.replace("return SCALE", "y = SCALE\n    return y"))  # a refactor
    st = status.status_of(entry, root=fake_repo)
    assert (st.state, st.why) == ("stale", "code changed, not checked")

    saved = (fake_repo / entry.quick_output).read_text()
    monkeypatch.setattr(verify, "_run_command", _fake_quick_run(fake_repo, 1.5, entry))
    record = verify.check(entry, fake_repo)
    assert record["outcome"] == "reproduces"
    assert (fake_repo / entry.quick_output).read_text() == saved  # the saved quick JSON is restored
    verify._write_ledger(entry.name, record, fake_repo)
    st = status.status_of(entry, root=fake_repo)
    assert (st.state, st.why) == ("current", "code changed, quick mode reproduces")

    module_file.write_text(SOURCE.replace("SCALE = 2.0", "SCALE = 3.0"))  # a change of meaning
    st = status.status_of(entry, root=fake_repo)
    assert st.state == "stale" and st.why.startswith("code changed since the last check")
    monkeypatch.setattr(verify, "_run_command", _fake_quick_run(fake_repo, 2.25, entry))
    record = verify.check(entry, fake_repo)
    assert record["outcome"] == "numbers changed" and record["differences"] == ["/value: 1.5 != 2.25"]
    verify._write_ledger(entry.name, record, fake_repo)
    st = status.status_of(entry, root=fake_repo)
    assert (st.state, st.why) == ("changed", "numbers changed")


def test_a_quick_json_from_other_code_cannot_vouch_for_the_result(fake_repo: Path, monkeypatch) -> None:
    from benchmarks import verify

    entry = QUICK_ENTRY
    write_fake(fake_repo)
    module_file = fake_repo / "jaxabc/fake_dependency.py"
    module_file.write_text(SOURCE.replace("SCALE = 2.0", "SCALE = 3.0"))
    _common.write_result(fake_repo / entry.quick_output, {"value": 1.5}, inputs=[fake_repo / "data.txt"])
    assert verify.baseline_mismatch(entry, fake_repo) == ["jaxabc/fake_dependency.py"]
    monkeypatch.setattr(verify, "_run_command", _fake_quick_run(fake_repo, 1.5, entry))
    record = verify.check(entry, fake_repo)
    assert record["outcome"] == "not applicable" and record["quick_reproduces"]
    verify._write_ledger(entry.name, record, fake_repo)
    st = status.status_of(entry, root=fake_repo)
    assert st.state == "stale" and "other code than the result" in st.why


def _git_commit_all(root: Path) -> None:
    for args in (["init", "-q"], ["add", "-A"], ["-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "c"]):
        subprocess.run(["git", *args], cwd=root, check=True, capture_output=True)


def _fake_quick_run_by_tree(
    root: Path, values: dict[str, float], entry: registry.Entry, monkeypatch, part: str | None = None
):
    """The quick command in ``root`` or in a worktree of it: writes with that tree's code and provenance."""

    def run(argv, cwd, env):
        cwd = Path(cwd)
        if cwd != root:  # the rebaseline worktree: import its own copy of the module
            spec = importlib.util.spec_from_file_location("fake_dependency_worktree", cwd / "jaxabc/fake_dependency.py")
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
            monkeypatch.setitem(sys.modules, "fake_dependency_worktree", module)
        with monkeypatch.context() as m:
            m.setattr(_common, "ROOT", cwd)
            value = values["worktree" if cwd != root else "root"]
            path = cwd / entry.quick_output
            payload = {"value": value}
            if part is not None:  # like water_calibration: update this part of the file in place
                payload = {**(json.loads(path.read_text()) if path.is_file() else {}), part: {"value": value}}
            _common.write_result(path, payload, part=part, inputs=[cwd / "data.txt"], command=entry.quick)
        if cwd != root:
            monkeypatch.delitem(sys.modules, "fake_dependency_worktree")
        return subprocess.CompletedProcess(argv, 0, "", "")

    return run


@pytest.mark.parametrize(("today", "outcome"), [(1.5, "reproduces"), (2.25, "numbers changed")])
def test_rebaseline_compares_the_results_code_with_todays_on_this_machine(
    fake_repo: Path, monkeypatch, today: float, outcome: str
) -> None:
    from benchmarks import verify

    entry = QUICK_ENTRY
    _git_commit_all(fake_repo)
    write_fake(fake_repo)
    # The saved quick numbers were made on another CPU: they differ whatever the code.
    with monkeypatch.context() as m:
        m.setattr(_common, "machine", lambda: {"cpu": "other"})
        _common.write_result(fake_repo / entry.quick_output, {"value": 1.7}, inputs=[fake_repo / "data.txt"])
    module_file = fake_repo / "jaxabc/fake_dependency.py"
    module_file.write_text(SOURCE.replace("return SCALE", "y = SCALE\n    return y"))  # today's code
    assert verify._needs_rebaseline(entry, fake_repo)
    monkeypatch.setattr(
        verify, "_run_command", _fake_quick_run_by_tree(fake_repo, {"worktree": 1.5, "root": 1.5}, entry, monkeypatch)
    )
    assert verify.check(entry, fake_repo)["outcome"] == "other machine"

    runs = {"worktree": 1.5, "root": today}
    monkeypatch.setattr(verify, "_run_command", _fake_quick_run_by_tree(fake_repo, runs, entry, monkeypatch))
    done = verify.rebaseline(entry, fake_repo)
    full = json.loads((fake_repo / entry.output).read_text())
    assert done["mismatch"] == [] and done["commit"] == full["provenance"]["commit"]
    assert not verify._needs_rebaseline(entry, fake_repo)
    assert not any(p.name.startswith(".verify-") for p in fake_repo.parent.iterdir())  # worktree removed
    saved = json.loads((fake_repo / entry.quick_output).read_text())
    assert saved["value"] == 1.5 and saved["provenance"]["machine"]["cpu"] == "test"
    code = "jaxabc/fake_dependency.py"  # made with the result's version of the module, not today's
    assert saved["provenance"]["fingerprint"]["code"][code] == full["provenance"]["fingerprint"]["code"][code]
    assert _common.code_hash(module_file) != full["provenance"]["fingerprint"]["code"][code]
    record = verify.check(entry, fake_repo)
    assert record["outcome"] == outcome
    verify._write_ledger(entry.name, record, fake_repo)
    st = status.status_of(entry, root=fake_repo)
    assert st.state == ("current" if outcome == "reproduces" else "changed")


def test_rebaseline_remakes_only_its_own_part_of_a_shared_quick_json(fake_repo: Path, monkeypatch) -> None:
    from benchmarks import verify

    entry = registry.Entry(
        "res:robust",
        "benchmarks/results/res.json",
        "python x.py",
        part="robust",
        quick="python x.py --quick",
        quick_output="benchmarks/results/quick/res.json",
    )
    _git_commit_all(fake_repo)
    _common.write_result(fake_repo / entry.output, {"robust": {"value": 1.5}}, part="robust")
    quick = fake_repo / entry.quick_output
    with monkeypatch.context() as m:
        m.setattr(_common, "machine", lambda: {"cpu": "other"})
        _common.write_result(quick, {"paper": {"value": 9.0}}, part="paper")
        _common.write_result(quick, {**json.loads(quick.read_text()), "robust": {"value": 1.7}}, part="robust")
    runs = {"worktree": 1.5, "root": 1.5}
    monkeypatch.setattr(verify, "_run_command", _fake_quick_run_by_tree(fake_repo, runs, entry, monkeypatch, "robust"))
    verify.rebaseline(entry, fake_repo)
    saved = json.loads(quick.read_text())
    assert saved["robust"] == {"value": 1.5} and saved["paper"] == {"value": 9.0}
    assert saved["provenance_parts"]["paper"]["machine"]["cpu"] == "other"
    assert saved["provenance_parts"]["robust"]["machine"]["cpu"] == "test"
    assert verify.check(entry, fake_repo)["outcome"] == "reproduces"
    # A part the saved quick JSON lacks has no baseline: never compared against the other parts.
    other = registry.Entry(
        "res:other", entry.output, "python x.py", part="other", quick="q", quick_output=entry.quick_output
    )
    assert verify._needs_rebaseline(other, fake_repo)
    record = verify.check(other, fake_repo)
    assert record["outcome"] == "not applicable" and "no 'other' part" in record["detail"]


def test_rebaseline_remakes_a_quick_json_whose_parts_share_one_body(fake_repo: Path, monkeypatch) -> None:
    """helium_lammps_agreement's parts share one body (``records``) and differ only in their
    provenance: there is no top-level part to merge, so the remade file replaces the saved one."""
    from benchmarks import verify

    entry = registry.Entry(
        "res:cpu",
        "benchmarks/results/res.json",
        "python x.py",
        part="cpu",
        quick="python x.py --quick",
        quick_output="benchmarks/results/quick/res.json",
    )
    _git_commit_all(fake_repo)
    _common.write_result(fake_repo / entry.output, {"value": 1.5}, part="cpu")
    with monkeypatch.context() as m:
        m.setattr(_common, "machine", lambda: {"cpu": "other"})
        _common.write_result(fake_repo / entry.quick_output, {"value": 1.7}, part="cpu")

    def run(argv, cwd, env):
        with monkeypatch.context() as m:
            m.setattr(_common, "ROOT", Path(cwd))
            _common.write_result(Path(cwd) / entry.quick_output, {"value": 1.5}, part="cpu", command=entry.quick)
        return subprocess.CompletedProcess(argv, 0, "", "")

    monkeypatch.setattr(verify, "_run_command", run)
    verify.rebaseline(entry, fake_repo)
    saved = json.loads((fake_repo / entry.quick_output).read_text())
    assert saved["value"] == 1.5 and saved["provenance_parts"]["cpu"]["machine"]["cpu"] == "test"
    assert verify.check(entry, fake_repo)["outcome"] == "reproduces"


def test_rebaseline_refuses_a_result_without_a_commit(fake_repo: Path) -> None:
    from benchmarks import verify

    write_fake(fake_repo)  # no git repository: no commit recorded
    _common.write_result(fake_repo / QUICK_ENTRY.quick_output, {"value": 1.5}, inputs=[fake_repo / "data.txt"])
    with pytest.raises(RuntimeError, match="records no commit"):
        verify.rebaseline(QUICK_ENTRY, fake_repo)


def test_rebaseline_refuses_a_retired_result_whose_file_is_gone(fake_repo: Path) -> None:
    """A retired result's quick mode may still vouch for others; with its full JSON deleted there
    is no commit to rebaseline at, and the refusal says so instead of a traceback."""
    from benchmarks import verify

    write_fake(fake_repo)
    (fake_repo / QUICK_ENTRY.output).unlink(missing_ok=True)
    with pytest.raises(RuntimeError, match="no full result"):
        verify.rebaseline(QUICK_ENTRY, fake_repo)


def test_results_pages_show_figures_that_exist_and_the_build_publishes_them() -> None:
    """Every ``![...](figures/<rel>)`` on a results page is a saved, non-quick PNG under
    benchmarks/results, and the MkDocs hook publishes exactly those under results/figures/."""
    import importlib.util
    import re

    root = Path(__file__).resolve().parents[1]
    shown = set()
    for page in (root / "docs" / "results").glob("*.md"):
        shown |= set(re.findall(r"!\[[^\]]*\]\(figures/([^)]+)\)", page.read_text()))
    assert shown, "no results page shows a figure"
    for rel in shown:
        assert (root / "benchmarks" / "results" / rel).is_file() and not rel.startswith("quick/"), rel
    spec = importlib.util.spec_from_file_location("mkdocs_figures", root / "benchmarks/docpages/mkdocs_figures.py")
    assert spec is not None and spec.loader is not None
    hook = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hook)
    published = {uri.removeprefix("results/figures/") for uri in hook.published()}
    assert shown <= published
    assert not any(p.startswith("quick/") for p in published)


def test_a_sibling_quick_check_vouches_file_by_file(fake_repo: Path, monkeypatch) -> None:
    """A result without a quick mode is current after a refactor when the quick mode it names in
    ``checked_by`` reproduces on today's code numbers made with the result's own code."""
    from benchmarks import verify

    sibling = QUICK_ENTRY
    long = registry.Entry("long", "benchmarks/results/long.json", "python x.py --long", checked_by=("res",))
    monkeypatch.setattr(status, "REGISTRY", (sibling, long))
    write_fake(fake_repo)
    write_fake(fake_repo, name="long")
    _common.write_result(fake_repo / sibling.quick_output, {"value": 1.5}, inputs=[fake_repo / "data.txt"])
    module_file = fake_repo / "jaxabc/fake_dependency.py"
    module_file.write_text(SOURCE.replace("return SCALE", "y = SCALE\n    return y"))  # a refactor
    st = status.status_of(long, root=fake_repo)
    assert st.state == "stale" and "no quick mode" in st.why and "not vouched for by res" in st.why

    monkeypatch.setattr(verify, "_run_command", _fake_quick_run(fake_repo, 1.5, sibling))
    verify._write_ledger("res", verify.check(sibling, fake_repo), fake_repo)
    st = status.status_of(long, root=fake_repo)
    assert (st.state, st.why) == ("current", "code changed, quick mode of res reproduces")

    module_file.write_text(SOURCE.replace("SCALE = 2.0", "SCALE = 3.0"))  # a change of meaning
    assert status.status_of(long, root=fake_repo).state == "stale"  # the check ran on other code
    monkeypatch.setattr(verify, "_run_command", _fake_quick_run(fake_repo, 2.25, sibling))
    record = verify.check(sibling, fake_repo)
    assert record["outcome"] == "numbers changed"
    verify._write_ledger("res", record, fake_repo)
    st = status.status_of(long, root=fake_repo)
    assert st.state == "stale" and "not vouched for by res: jaxabc/fake_dependency.py" in st.why


def test_a_sibling_cannot_vouch_with_numbers_made_from_other_code(fake_repo: Path, monkeypatch) -> None:
    from benchmarks import verify

    sibling = QUICK_ENTRY
    long = registry.Entry("long", "benchmarks/results/long.json", "python x.py --long", checked_by=("res",))
    monkeypatch.setattr(status, "REGISTRY", (sibling, long))
    write_fake(fake_repo, name="long")  # the result: SCALE 2.0
    module_file = fake_repo / "jaxabc/fake_dependency.py"
    module_file.write_text(SOURCE.replace("SCALE = 2.0", "SCALE = 3.0"))
    write_fake(fake_repo)
    _common.write_result(fake_repo / sibling.quick_output, {"value": 1.5}, inputs=[fake_repo / "data.txt"])
    monkeypatch.setattr(verify, "_run_command", _fake_quick_run(fake_repo, 1.5, sibling))
    verify._write_ledger("res", verify.check(sibling, fake_repo), fake_repo)
    # The sibling reproduces on today's code, but its numbers were made with SCALE 3.0, not 2.0.
    assert status.status_of(long, root=fake_repo).state == "stale"

    # Nor is a change of data ever vouched for.
    module_file.write_text(SOURCE)
    write_fake(fake_repo, name="long")
    (fake_repo / "data.txt").write_text("1 2 4\n")
    st = status.status_of(long, root=fake_repo)
    assert (st.state, st.changed) == ("stale", ["data.txt"])


def test_other_numbers_on_another_cpu_decide_nothing(fake_repo: Path, monkeypatch) -> None:
    """Chaotic MD differs from CPU to CPU: a check there is recorded, not read as changed numbers."""
    from benchmarks import verify

    entry = QUICK_ENTRY
    write_fake(fake_repo)
    _common.write_result(fake_repo / entry.quick_output, {"value": 1.5}, inputs=[fake_repo / "data.txt"])
    monkeypatch.setattr(_common, "machine", lambda: {"cpu": "another"})
    monkeypatch.setattr(verify, "_run_command", _fake_quick_run(fake_repo, 1.6, entry))
    record = verify.check(entry, fake_repo)
    assert record["outcome"] == "other machine" and record["baseline_cpu"] == "test"
    verify._write_ledger(entry.name, record, fake_repo)
    (fake_repo / "jaxabc/fake_dependency.py").write_text(SOURCE.replace("return SCALE", "y = SCALE\n    return y"))
    # The ledger's check ran on the code before this refactor: stale, never "changed".
    assert status.status_of(entry, root=fake_repo).state == "stale"


def test_a_cpu_of_the_same_name_with_other_instruction_sets_is_another_machine(fake_repo: Path, monkeypatch) -> None:
    """Hosts that both read "AMD EPYC" may differ in AVX-512: XLA's float sums then differ in the
    last bits (seen here: S7 2.6440566397969145 against 2.644056639796915)."""
    from benchmarks import verify

    def host(*simd: str) -> dict:
        return {"cpu": "AMD EPYC", "native_kernel_instruction_set": {"simd": list(simd)}}

    entry = QUICK_ENTRY
    write_fake(fake_repo)
    with monkeypatch.context() as m:
        m.setattr(_common, "machine", lambda: host("avx2", "avx512f"))
        _common.write_result(fake_repo / entry.quick_output, {"value": 1.5}, inputs=[fake_repo / "data.txt"])
    monkeypatch.setattr(_common, "machine", lambda: host("avx2"))
    monkeypatch.setattr(verify, "_run_command", _fake_quick_run(fake_repo, 1.5000000000000002, entry))
    record = verify.check(entry, fake_repo)
    assert record["outcome"] == "other machine", record
    assert record["baseline_cpu"] == "AMD EPYC (avx2, avx512f)" and record["cpu"] == "AMD EPYC (avx2)"
    assert verify._needs_rebaseline(entry, fake_repo)
    # The same instruction sets: the numbers decide.
    monkeypatch.setattr(_common, "machine", lambda: host("avx2", "avx512f"))
    assert verify.check(entry, fake_repo)["outcome"] == "numbers changed"
    assert not verify._needs_rebaseline(entry, fake_repo)
    assert verify.cpu_signature({}) is None and verify.cpu_signature({"cpu": "x"}) == "x"


def test_the_model_choice_readers_follow_its_saved_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The criticism and the paper check start from the folder the model choice's JSON records."""
    from benchmarks import _water_model_choice_paths as paths

    monkeypatch.setattr(paths, "RESULTS", tmp_path)
    monkeypatch.setattr(_common, "ROOT", tmp_path)
    monkeypatch.setattr(_common, "RUNS", tmp_path / "elsewhere")  # JAXABC_RUNS_DIR
    with pytest.raises(FileNotFoundError, match=r"run the registry's water_model_choice first"):
        paths.model_choice_folder("xray")
    (tmp_path / "water_model_choice.json").write_text(json.dumps({"data": "xray", "saved_result": "a/b"}))
    assert paths.model_choice_folder("xray") == tmp_path / "a" / "b"
    # A repeat of the model choice (e.g. without the discrepancy term) is read by its result name.
    with pytest.raises(FileNotFoundError, match="water_model_choice_no_discrepancy"):
        paths.model_choice_folder("xray", result="water_model_choice_no_discrepancy")
    (tmp_path / "water_model_choice_no_discrepancy.json").write_text(json.dumps({"data": "xray", "saved_result": "c"}))
    assert paths.model_choice_folder("xray", result="water_model_choice_no_discrepancy") == tmp_path / "c"
    with pytest.raises(FileNotFoundError, match="not 'neutron'"):
        paths.model_choice_folder("neutron")
    tiny = tmp_path / "elsewhere/cache/water_model_choice/xray_quick_tiny/result"
    assert paths.model_choice_folder("xray", tiny=True) == tiny
    # A folder recorded under runs/ is found where the runs folder is now.
    (tmp_path / "water_model_choice.json").write_text(json.dumps({"data": "xray", "saved_result": "runs/x/result"}))
    assert paths.model_choice_folder("xray") == tmp_path / "elsewhere/x/result"
    assert _common.relative(tmp_path / "elsewhere/x/result") == "runs/x/result"
    assert _common.relative(tmp_path / "benchmarks/results/y") == "benchmarks/results/y"


def test_the_model_choice_page_says_which_box_change_turns_the_verdict() -> None:
    from benchmarks.docpages.model_choice import _what_would_change

    names = ["A", "B", "C"]
    nan = float("nan")

    def row(label: str, p: list[float], iv: list[list[float]]) -> dict:
        return {"label": label, "probabilities": p, "intervals": iv}

    rows = [
        row("A box x0.5", [0.8, 0.1, 0.1], [[0.6, 0.9], [0.05, 0.2], [0.05, 0.2]]),  # A's interval clears
        row("B box x0.5", [0.3, 0.5, 0.2], [[0.1, 0.5], [0.3, 0.7], [0.1, 0.4]]),  # still overlapping
        row("all boxes x2", [nan, nan, nan], [[nan, nan]] * 3),
    ]
    text = _what_would_change({"verdict": {"status": "undecided", "model": None}}, names, rows)
    assert "A box x0.5 gives A preferred (0.80 [0.60, 0.90])" in text
    assert "Unchanged with B box x0.5." in text and "Narrowing one model's box alone" in text
    assert "Not computed from this run (they need simulations in the wider boxes): all boxes x2." in text
    # A preferred verdict that a narrower box leaves as it is, and one it turns to undecided.
    text = _what_would_change({"verdict": {"status": "preferred", "model": "A"}}, names, rows[:2])
    assert "B box x0.5 gives undecided (0.50 [0.30, 0.70])" in text and "Unchanged with A box x0.5." in text


def test_the_model_choice_page_computes_wider_boxes_from_a_second_run(monkeypatch) -> None:
    """One model's doubled box takes its evidence from the wider run, the others' from the first."""
    from benchmarks.docpages import model_choice as page

    def result(log_z: list[float], validated: list[bool]) -> dict:
        names = ["A", "B"]
        return {
            "model_choice": {
                "names": names,
                "log_evidence": log_z,
                "log_evidence_errors": [0.5, 0.5],
                "model_prior": [0.5, 0.5],
            },
            "per_model": {n: {"validated": v} for n, v in zip(names, validated, strict=True)},
            "models": {},
        }

    base = result([0.0, 0.0], [True, True])
    wide = result([math.log(0.5), 3.0], [True, False])
    monkeypatch.setattr(page, "load", lambda name: wide if name == "wide" else None)
    text = "".join(page._wider_boxes(base, "wide"))
    # A x2: A's evidence halves, so A 1/3 and B 2/3; their intervals (log Z +- 1) overlap.
    # B x2 from an unvalidated emulator: B's evidence e^3 decides it (1 / (1 + e^3) = 0.0474 for A).
    assert "| B sigma box x2 | B preferred (B not validated) | 0.0474 [" in text
    assert "| A sigma box x2 | undecided | 0.333 [0.0634, 0.787] | 0.667 [0.213, 0.937] |" in text
    assert "A doubled sigma box turns the verdict: B sigma box x2 (B); all sigma boxes x2 (B)." in text
    assert page._wider_boxes(base, "missing") == ["Wider sigma boxes: `missing` not run yet.\n"]
    # The sentence: the rows' verdicts and who lies below another's interval in every row.
    assert page._doubled_sentence(base, "wide") == (
        ". With the sigma boxes doubled (seed ? again, `wide`; each model's box alone, then all): A sigma box x2 "
        "undecided; B sigma box x2 B preferred (from a failed emulator); all sigma boxes x2 B preferred (from a failed "
        "emulator), below another model's interval in every doubled row: no model (the emulator of B failed in the "
        "wider run)"
    )
    base["settings"] = {"seed": 1}
    base["model_choice"]["log_evidence"] = [0.0, 5.0]
    wide["model_choice"]["log_evidence"] = [0.0, 5.0]
    wide["per_model"]["B"]["validated"] = True
    assert page._doubled_sentence(base, "wide") == (
        ". With the sigma boxes doubled (seed 1 again, `wide`; each model's box alone, then all): 3 of 3 rows say B "
        "preferred, below another model's interval in every doubled row: A"
    )
    assert page._doubled_sentence(base, "missing") == ""


def test_a_retired_checker_without_its_full_result_is_still_checked(fake_repo: Path, monkeypatch) -> None:
    """A retired entry whose full JSON was deleted can still run its quick check for others."""
    from benchmarks import verify

    entry = QUICK_ENTRY
    write_fake(fake_repo)
    _common.write_result(fake_repo / entry.quick_output, {"value": 1.5}, inputs=[fake_repo / "data.txt"])
    (fake_repo / entry.output).unlink()
    assert verify.baseline_mismatch(entry, fake_repo) == []
    monkeypatch.setattr(verify, "_run_command", _fake_quick_run(fake_repo, 1.5, entry))
    assert verify.check(entry, fake_repo)["outcome"] == "reproduces"


def test_verify_runs_a_check_after_the_checks_it_reads() -> None:
    from benchmarks import verify
    from benchmarks.registry import Entry

    model = Entry("model_choice", "m.json", "python -m x", quick="q", quick_output="mq.json")
    crit = Entry("criticism", "c.json", "python -m y", quick="q", quick_output="cq.json", after=("model_choice",))
    samples = Entry("samples", "s.json", "python -m z", quick="q", quick_output="sq.json", after=("abc",))
    abc = Entry("abc:paper", "a.json", "python -m w", quick="q", quick_output="aq.json")
    rows = [(crit, 1.0), (samples, 2.0), (model, 5.0), (abc, 9.0)]
    assert [e.name for e, _ in verify.dependency_order(rows)] == ["model_choice", "criticism", "abc:paper", "samples"]


def test_rebaseline_makes_its_quick_inputs_with_the_results_code(fake_repo: Path, monkeypatch) -> None:
    """The checkout's untracked caches may hold other code's runs: a rebaseline never copies them,
    it makes the inputs in the worktree with the quick mode the entry runs after."""
    import dataclasses

    from benchmarks import verify

    producer = registry.Entry("maker", "m.json", "python m.py", quick="python m.py --tiny", quick_output="mq.json")
    entry = dataclasses.replace(QUICK_ENTRY, quick_inputs=("runs/cache/tiny",), after=("maker",))
    _git_commit_all(fake_repo)
    write_fake(fake_repo)
    cache = fake_repo / "runs/cache/tiny"
    cache.mkdir(parents=True)
    (cache / "model_choice.json").write_text('{"old": true}')
    seen = []

    def run(argv, tree, env):
        runs = Path(env["JAXABC_RUNS_DIR"])
        assert runs.is_relative_to(tree)
        if "m.py" in argv:
            (runs / "cache/tiny").mkdir(parents=True)
            (runs / "cache/tiny/model_choice.json").write_text('{"new": true}')
            return subprocess.CompletedProcess(argv, 0, "", "")
        seen.append(json.loads((runs / "cache/tiny/model_choice.json").read_text()))
        _common.write_result(tree / entry.quick_output, {"value": 1.5}, inputs=[tree / "data.txt"])
        return subprocess.CompletedProcess(argv, 0, "", "")

    monkeypatch.setattr(verify, "by_name", lambda name: {"maker": producer}[name])
    monkeypatch.setattr(verify, "_run_command", run)
    verify.rebaseline(entry, fake_repo)
    assert seen == [{"new": True}]


def test_verify_invocations_share_a_runs_folder_only_when_asked(monkeypatch, tmp_path: Path) -> None:
    """One invocation's checks share one empty runs folder, removed afterwards; ``--runs-dir``
    keeps a folder for later invocations."""
    from benchmarks import verify

    entries = [registry.Entry(n, f"{n}.json", "python -m x", quick="q", quick_output=f"{n}q.json") for n in "ab"]
    seen: list[Path] = []

    def fake_check(entry, root=None, runs=None):
        seen.append(runs)
        (runs / f"{entry.name}.made").write_text("")
        return {"outcome": "reproduces", "seconds": 0.0}

    monkeypatch.setattr(verify, "REGISTRY", entries)
    monkeypatch.setattr(verify, "plan", lambda es, budget, include: [(e, 1.0, "") for e in es])
    monkeypatch.setattr(verify, "check", fake_check)
    monkeypatch.setattr(verify, "_write_ledger", lambda name, record, root=None: None)
    assert verify.main(["--budget", "1h"]) == 0
    assert seen[0] == seen[1] and not seen[0].exists()
    seen.clear()
    kept = tmp_path / "runs"
    assert verify.main(["--budget", "1h", "--only", "a", "--runs-dir", str(kept)]) == 0
    assert seen == [kept.resolve()] and (kept / "a.made").is_file()


def test_a_checks_quick_inputs_under_runs_do_not_stale_it(fake_repo: Path) -> None:
    """The inputs a check made in its own runs folder are gone afterwards: only its code counts."""
    module = "jaxabc/fake_dependency.py"
    record = {"fingerprint": {"code": {module: _common.code_hash(fake_repo / module)}, "data": {}}}
    record["fingerprint"]["data"]["runs/cache/tiny/model_choice.json"] = "0" * 16
    assert status._check_problem(record, fake_repo) == ""
    record["fingerprint"]["data"]["data.txt"] = "0" * 16  # a tracked input that changed still counts
    assert "data.txt" in status._check_problem(record, fake_repo)


def test_a_quick_check_cannot_vouch_for_changed_inputs(fake_repo: Path, monkeypatch) -> None:
    """A result whose data input changed (a calibration it reads was rerun) needs a rerun, even
    where its quick mode reproduces: the quick mode reads other inputs."""
    from benchmarks import verify

    entry = QUICK_ENTRY
    write_fake(fake_repo)
    _common.write_result(fake_repo / entry.quick_output, {"value": 1.5}, inputs=[fake_repo / "data.txt"])
    (fake_repo / "jaxabc/fake_dependency.py").write_text(SOURCE.replace("return SCALE", "y = SCALE\n    return y"))
    monkeypatch.setattr(verify, "_run_command", _fake_quick_run(fake_repo, 1.5, entry))
    verify._write_ledger(entry.name, verify.check(entry, fake_repo), fake_repo)
    assert status.status_of(entry, root=fake_repo).state == "current"
    (fake_repo / "data.txt").write_text("1 2 4\n")
    st = status.status_of(entry, root=fake_repo)
    assert st.state == "stale" and st.why.startswith("inputs changed, rerun it: data.txt")


def test_the_model_choice_page_trusts_only_seeds_with_every_emulator_validated(monkeypatch) -> None:
    """The held-out family's sentence counts a seed as trusted only without a flag, and says when
    the trusted seeds disagree."""
    from benchmarks.docpages import model_choice as page

    def run(seed: int, status: str, model: str | None, stop: str) -> dict:
        return {
            "settings": {"seed": seed, "budget_per_model": 120},
            "summaries": {"held_out": ["density_kg_m3", "r_oo_max2_nm"]},
            "verdict": {"status": status, "model": model},
            "per_model": {
                "A": {"validated": True, "num_simulations": 100},
                "B": {"validated": True, "num_simulations": 90},
            },
            "model_choice": {
                "names": ["A", "B"],
                "probabilities": [0.9, 0.1],
                "log_evidence": [0.0, -2.2],
                "log_evidence_errors": [0.1, 0.1],
                "model_prior": [0.5, 0.5],
                "stop_reason": stop,
                "posteriors": {},
            },
        }

    saved = {
        "s0": run(0, "preferred", "A", "every model's emulator validated"),
        "s1": run(1, "undecided", None, "every model's emulator validated"),
        "s2": run(2, "undecided", None, "UNTRUSTED: B's emulator failed validation"),
    }
    monkeypatch.setattr(page, "HOLDOUT_FAMILY", ("s0", "s1", "s2"))
    monkeypatch.setattr(page, "HOLDOUT_NO_DISCREPANCY", "nd")
    monkeypatch.setattr(page, "load", saved.get)
    text = "".join(page._holdout_family())
    assert "3 of 3 seeds run; 2 with every emulator validated and no flag (flagged: `s2`)" in text
    assert "the trusted seeds disagree (preferred A; undecided)" in text
    assert "r_oo_max2_nm" in text and "0.9 [" in text
    saved["s0"] = run(0, "undecided", None, "every model's emulator validated")
    assert "the 2 trusted seeds agree: undecided (the others: not run or flagged)." in "".join(page._holdout_family())
    del saved["s1"], saved["s2"]
    assert "the one trusted seed says undecided: one seed is not yet a verdict" in "".join(page._holdout_family())
    assert "`nd` not run yet" in "".join(page._without_discrepancy(None))
    # Without the discrepancy term: every model rejected by its misfit check, on validated emulators.
    saved["nd"] = run(0, "undecided", None, "MISSPECIFIED: no model reproduces the data")
    for name, p in (("A", 1e-4), ("B", 3e-3)):
        saved["nd"]["per_model"][name]["observed_misfit"] = {"p_value": p}
    text = "".join(page._holdout_family() + page._without_discrepancy(saved["nd"]))
    assert "`nd` (seed 0, no discrepancy term) | undecided | MISSPECIFIED |" in text
    assert "every emulator validated; the misfit check" in text and "A 0.0001, B 0.003" in text
    assert "no model reproduces the measured summaries within their stated errors" in text
    # The headline: two trusted seeds agree; a halved box of A turns it, one of B does not.
    saved.update(s1=run(1, "undecided", None, "every model's emulator validated"))
    halved = [
        {"label": "A box x0.5", "probabilities": [0.8, 0.2], "intervals": [[0.7, 0.9], [0.1, 0.3]]},
        {"label": "B box x0.5", "probabilities": [0.5, 0.5], "intervals": [[0.3, 0.7], [0.3, 0.7]]},
        {"label": "A box x2", "probabilities": [float("nan")] * 2, "intervals": [[0.0, 1.0]] * 2},
    ]
    for name in ("s0", "s1"):
        saved[name]["sensitivity"] = halved
    head = "".join(page._family_headline())
    assert head.startswith("**Verdict: undecided.** From the 2 trusted seeds of the held-out family (2 of 3 run")
    assert "seed 0 A 0.90, seed 1 A 0.90" in head and "Not counted" not in head
    assert "makes that model preferred in 2 of 4 (seed, model) cases: the differences" in head
    assert "every model's misfit check rejects it (p < 0.01) on validated emulators" in head
    # Calibrated predictive medians against the published parameters' means.
    saved["water_published_predictive"] = {
        "summary_names": ["S9", "density_kg_m3", "hvap_kj_mol"],
        "observed": [2.0, 1000.0, 44.0],
        "models": {"A": {"mean": [3.0, 990.0, 43.0]}, "B": {"mean": [2.5, 1001.0, 40.0]}},
    }
    quantiles = {"A": [4.0, 995.0, 43.5], "B": [2.2, 1010.0, 41.0]}
    for name in ("s0", "s1"):
        saved[name]["predictive"] = {
            "models": {m: {"scalars": [[0.0] * 3, [0.0] * 3, q, [0.0] * 3, [0.0] * 3]} for m, q in quantiles.items()}
        }
    assert page._worse_pairs(saved["s0"]) == (
        ["A S9 3 -> 4 (measured 2)", "B density_kg_m3 1001 -> 1010 (measured 1000)"],
        6,
    )
    assert (
        "farther from the measured values than the published parameters in 2 of 6 (model, property) pairs in "
        "seed 0 and 2 of 6 in seed 1" in "".join(page._family_headline())
    )
    saved["s1"]["verdict"] = {"status": "preferred", "model": "A"}
    assert "**Verdict: depends on the seed.**" in "".join(page._family_headline())
    saved["nd"]["per_model"]["B"].update(validated=False, observed_misfit={"p_value": 0.4})
    text = "".join(page._without_discrepancy(saved["nd"]))
    assert (
        "the emulator of B failed validation (its misfit is not trustworthy)" in text
        and "rejected at p < 0.01: A" in text
    )


def test_the_model_choice_page_reports_the_published_bounds_reruns(monkeypatch) -> None:
    """The bullet of the family rerun with the published-model bounds: its bounds, each seed's
    verdict, the force-field mass piled on a bound (TIP3P's epsilon named even when below 5 %)."""
    from benchmarks.docpages import model_choice as page

    def run(seed: int, tip3p_low: float, stop: str) -> dict:
        edge = {
            "parameters": ["sigma_OO", "epsilon_OO", "discrepancy_sd[D]"],
            "mass": [[0.01, 0.0], [tip3p_low, 0.0], [0.5, 0.0]],
        }
        return {
            "settings": {"seed": seed, "discrepancy": {"max_sd": [0.25, 3.5], "groups": {"g": [0], "D": [1]}}},
            "verdict": {"status": "undecided", "model": None},
            "per_model": {
                name: {
                    "validated": name not in stop,
                    "bayes_estimate": [1.0] * 4,
                    "credible_interval_95": [[0, 1], [0, 1], [0.0, 0.3], [0.0, 1.0]],
                }
                for name in ("TIP3P", "A")
            },
            "model_choice": {
                "names": ["TIP3P", "A"],
                "probabilities": [0.3, 0.7],
                "stop_reason": stop,
                "log_evidence": [0.0, 0.3],
                "log_evidence_errors": [0.1, 0.1],
                "model_prior": [0.5, 0.5],
            },
            "prior_edge": {"TIP3P": edge},
            "saved_result": "benchmarks/results/not_saved",
        }

    assert page.PUBLISHED_WIDER_BASE in page.PUBLISHED_BOUNDS_FAMILY  # the doubled run's base is one of its seeds
    saved = {"b0": run(0, 0.02, "every model's emulator validated")}
    monkeypatch.setattr(page, "PUBLISHED_BOUNDS_FAMILY", ("b0", "b1"))
    monkeypatch.setattr(page, "load", saved.get)
    line = page._bounded_family()
    assert line.startswith("With the published-model discrepancy bounds as the prior (g 0.25, D 3.5; rerun")
    assert "1 of 2 seeds run): seed 0 undecided (most probable A 0.70)" in line
    assert "bound above 5 %: none (TIP3P's epsilon: 2%)" in line
    assert "in every halved box: no model." in line  # log evidences 0.3 apart, +- 0.2: intervals overlap
    # The doubled sigma boxes of one seed follow, whether or not a seed failed an emulator.
    monkeypatch.setattr(page, "PUBLISHED_WIDER_BASE", "b0")
    monkeypatch.setattr(page, "PUBLISHED_BOUNDS_WIDER", ("w", 0))
    assert "in every halved box: no model. Doubled sigma boxes: `w` not run yet." in page._bounded_family()
    saved["w"] = {**saved["b0"], "model_choice": {**saved["b0"]["model_choice"], "names": ["A", "B"]}}
    assert "Doubled sigma boxes: `w` compares other models." in page._bounded_family()
    saved["w"] = saved["b0"]
    assert (
        "in every halved box: no model. With the sigma boxes doubled (seed 0 again, `w`; each model's box alone, "
        "then all): 3 of 3 rows say undecided, below another model's interval in every doubled row: no model."
        in page._bounded_family()
    )
    section = "".join(page._published_wider())
    assert section.startswith("### The published-bounds family in wider boxes\n`b0` (probabilities TIP3P 0.3, A 0.7;")
    assert "| all sigma boxes x2 | undecided |" in section and "No doubled sigma box turns the verdict." in section
    del saved["w"]
    saved["b0"]["model_choice"]["log_evidence"] = [0.0, 2.0]
    saved["b0"]["sensitivity"] = [{"label": "A box x0.5", "intervals": [[0.1, 0.2], [0.8, 0.9]]}]
    assert "in every halved box: TIP3P in seed 0." in page._bounded_family()
    saved["b0"]["sensitivity"].append({"label": "TIP3P box x0.5", "intervals": [[0.3, 0.6], [0.4, 0.7]]})
    assert "in every halved box: no model." in page._bounded_family()
    saved["b1"] = run(1, 0.09, "UNTRUSTED: TIP3P's emulator failed validation")
    line = page._bounded_family()
    assert "seed 1 undecided (most probable A 0.70; UNTRUSTED: TIP3P's emulator failed validation)" in line
    assert "above 5 %: TIP3P's epsilon_OO 9% in seed 1." in line
    # All three bounded seeds run, two trusted: the headline stands on them; the fixed-bounds
    # family becomes a bullet, and its trusted seeds say whether the round-number bounds change it.
    saved.update(b2=run(2, 0.01, "every model's emulator validated"))
    halved = [{"label": "A box x0.5", "probabilities": [0.1, 0.9], "intervals": [[0.05, 0.2], [0.8, 0.95]]}]
    for name in ("b0", "b2"):
        saved[name]["model_choice"]["log_evidence"] = [0.0, 2.0]
        saved[name].update(sensitivity=halved, summaries={"fitted": []})
    family = {"s0": 0, "s1": 1}
    for name, seed in family.items():
        saved[name] = run(seed, 0.09, "every model's emulator validated") | {"summaries": {"fitted": []}}
    monkeypatch.setattr(page, "HOLDOUT_FAMILY", tuple(family))
    monkeypatch.setattr(page, "HOLDOUT_NO_DISCREPANCY", "nd")
    monkeypatch.setattr(page, "PUBLISHED_BOUNDS_FAMILY", ("b0", "b1", "b2"))
    head = "".join(page._family_headline())
    assert head.startswith("**Verdict: undecided.** From the 2 trusted seeds of the published-bounds family (3 of 3")
    assert "Not counted: seed 1 (UNTRUSTED: TIP3P's emulator failed validation), which says undecided." in head
    assert "- Bottom: TIP3P lies below another model's probability interval in each trusted seed" in head
    assert "seed 2 TIP3P 0.00 +- 0.10 against A 2.00 +- 0.10, a Bayes factor of 7.4)." in head
    assert "- With the fixed round-number discrepancy bounds of the held-out family instead (g 0.25, D 3.5" in head
    assert "above 5 %: TIP3P's epsilon_OO 9% in seed 0; TIP3P's epsilon_OO 9% in seed 1." in head
    assert "- Prior edges: no posterior has more than 5 % of its mass within 2 % of a bound of its box (a " in head
    assert (
        "bound at 0 is a physical limit, not counted); the largest force-field share: TIP3P's epsilon_OO 2% in " in head
    )
    assert "(with the fixed round-number bounds the trusted seeds say undecided; tables below)." in head
    # The box split of the headline's own family, over its saved runs.
    moves = {"parameters": {"median": 0.5}, "discrepancy": {"median": 1.5}}
    saved["water_box_sensitivity"] = {
        "repeats": [{"result": n, "published_bounds_family": True} for n in ("b0", "b1", "b2")]
        + [{"result": n, "family": True} for n in family],
        "published_bounds_family_log_evidence_change_abs": moves,
        "family_log_evidence_change_abs": {k: {"median": 2 * v["median"]} for k, v in moves.items()},
    }
    assert (
        "Split apart over the 3 saved runs of this family, halving the discrepancy bounds moves a model's log "
        "evidence by a median 1.50, halving the force-field box by 0.50: the discrepancy priors weigh most"
        in "".join(page._family_headline())
    )
    # What no model reproduces: a discrepancy sd's 2.5 % point above 2 % of its bound.
    for name in ("b0", "b2"):
        for model, low in (("TIP3P", 0.1), ("A", 0.05)):
            saved[name]["per_model"][model]["credible_interval_95"][2][0] = low
    assert (
        "- Not reproduced within the measurement error by any model, in each trusted seed"
        in (head := "".join(page._family_headline()))
        and "of its bound): g." in head
    )
    saved["b2"]["per_model"]["A"]["credible_interval_95"][2][0] = 0.001
    assert "of its bound): no group; by some models in some seeds: g (A in seed 0; TIP3P in seeds 0, 2)." in "".join(
        page._family_headline()
    )
    saved["s1"]["verdict"] = {"status": "preferred", "model": "A"}
    head = "".join(page._family_headline())
    assert "with the fixed round-number bounds the trusted seeds say preferred A; undecided; tables below)." in head
    # One trusted bounded seed: the headline stays on the held-out family; with one trusted seed
    # there, it says one seed is not a verdict, and what the flagged ones say.
    saved["b2"]["model_choice"]["stop_reason"] = "UNTRUSTED: A's emulator failed validation"
    assert "From the 2 trusted seeds of the held-out family (2 of 2 run" in "".join(page._family_headline())
    saved["s1"]["model_choice"]["stop_reason"] = "UNTRUSTED: A's emulator failed validation"
    head = "".join(page._family_headline())
    assert "From the one trusted seed of the held-out family (2 of 2 run" in head and "it says undecided" in head
    assert "One trusted seed alone is not a verdict." in head
    saved["s1"]["verdict"] = {"status": "undecided", "model": None}
    assert "One trusted seed alone is not a verdict: every flagged seed says undecided too." in "".join(
        page._family_headline()
    )
    saved["s1"]["verdict"] = {"status": "preferred", "model": "A"}
    saved["s1"]["model_choice"]["stop_reason"] = "every model's emulator validated"
    saved["b2"]["model_choice"]["stop_reason"] = "every model's emulator validated"
    # A bounded seed missing: the headline stands on the held-out family, the bounds a bullet.
    del saved["b2"]
    for name in family:
        saved[name]["sensitivity"] = halved
    head = "".join(page._family_headline())
    assert head.startswith("**Verdict: depends on the seed.** From the 2 trusted seeds of the held-out family")
    assert "; bounds on the discrepancy sds from outside the fit (tables below)" in head
    # The held-out family agrees again: the one trusted bounded seed says the same.
    saved["s1"]["verdict"] = {"status": "undecided", "model": None}
    assert "from no fit, leave it undecided in their one trusted seed) (tables below)." in "".join(
        page._family_headline()
    )
    assert "Split apart over the 2 saved runs of this family, halving the discrepancy bounds moves a model's " in head
    assert "- With the published-model discrepancy bounds as the prior (g 0.25, D 3.5; rerun" in head
    assert (
        "- Prior edges (more than 5 % of a posterior within 2 % of a bound): TIP3P's epsilon_OO in seed 0, 9%" in head
    )
    saved.clear()
    assert page._bounded_family() is None


def test_the_model_choice_page_splits_the_published_bounds_family_apart() -> None:
    """The box split of the published-bounds family is its own sentence, not pooled with the runs
    made under the fixed bounds, and the headline's box bullet uses it when it stands on them."""
    from benchmarks.docpages import model_choice as page

    moves = {"parameters": {"median": 0.5, "max": 1.0}, "discrepancy": {"median": 1.5, "max": 2.0}}
    runs = [
        {
            "names": ["A", "B"],
            "published_bounds_family": True,
            "discrepancy_upper_half_share": {
                "A": {"discrepancy_sd[D]": 0.4, "discrepancy_sd[g]": 0.1},
                "B": {"discrepancy_sd[D]": 0.3, "discrepancy_sd[g]": 0.3 * seed},
            },
        }
        for seed in (0, 1)
    ]
    split = {"repeats": runs, "published_bounds_family_log_evidence_change_abs": moves}
    text = page._bounded_moves(split)
    assert "In the 2 runs made with the published-model bounds as the prior (not in the table)" in text
    assert "median 1.50 (at most 2.00), halving the force-field box by 0.50 (at most 1.00)" in text
    assert text.endswith("(in any run): D (2 of 2 models), g (1 of 2 models: B).")
    assert page._bounded_moves({"repeats": runs[:0], "published_bounds_family_log_evidence_change_abs": moves}) == ""


def test_the_model_choice_page_compares_every_saved_criticism(monkeypatch) -> None:
    """Three criticisms side by side: the causes each names, which gains count (beyond 2 s.e., on a
    validated extension) and what every run needs."""
    from benchmarks.docpages import model_choice as page

    def crit(top: str, gain: float, se: float, needed: list[str]) -> dict:
        causes = [{"name": top, "score": 5.0, "fraction_explained": 0.5}, {"name": "b", "score": 1.0}]
        causes += [{"name": n, "score": 0.5, "fraction_explained": 0.1} for n in needed if n not in (top, "b")]
        misfits = [{"name": "S7", "residual": -3.0}]
        return {"causes": causes, "needed": needed, "gain": {"delta_lpd": gain, "delta_lpd_se": se}, "misfits": misfits}

    crits = {"one": crit("oh", 1.4, 0.1, ["oh", "t"]), "two": crit("m", 0.4, 0.3, ["m", "oh"]), "three": None}
    failed = {"two"}
    monkeypatch.setattr(page, "_extension_failed", lambda name, c: name in failed)
    text = "\n".join(page._criticisms_compared(crits))
    assert "Both runs" not in text and "The runs name different causes (oh one; m two)" in text
    assert "beyond twice its standard error, on a validated extension: one (1 of 2)." in text
    assert "in every run: oh." in text and "failed validation in the criticism two" in text
    crits["three"] = crit("oh", 3.0, 0.5, ["oh"])
    failed.clear()
    text = "\n".join(page._criticisms_compared(crits))
    assert "(oh one, three; m two)" in text and "extension: one; three (2 of 3)." in text
    crits["two"] = crit("oh", 0.1, 0.3, ["oh"])
    text = "\n".join(page._criticisms_compared(crits))
    assert "All 3 runs name the same cause, oh." in text and "failed validation" not in text
    assert page._criticisms_compared({"one": crits["one"], "two": None}) == []


def test_the_model_choice_page_compares_the_validated_models_of_a_flagged_seed() -> None:
    """A failed emulator leaves the comparisons among the other models intact: the verdict and the
    bottom of the run restricted to the validated models, in the run and every halved box."""
    from benchmarks.docpages import model_choice as page

    def run(seed: int, log_z: list[float], failed: str | None, halved: list[float], flag: str = "") -> dict:
        names = ["A", "B", "C"]
        stop = f"UNTRUSTED: the emulator of ['{failed}'] failed validation" if failed else "every model validated"
        rows = [{"label": "A box x0.5", "status": "reused", "log_evidence": halved, "log_evidence_errors": [0.1] * 3}]
        # A wider box needs simulations: not in the verdict, whatever its numbers.
        rows.append({"label": "A box x2", "status": "needs simulations", "log_evidence": [9.0, 0.0, 0.0]})
        mc = {
            "names": names,
            "stop_reason": stop + flag,
            "log_evidence": log_z,
            "log_evidence_errors": [0.1] * 3,
            "model_prior": [1 / 3] * 3,
            "sensitivity": rows,
        }
        return {
            "settings": {"seed": seed},
            "model_choice": mc,
            "per_model": {n: {"validated": n != failed} for n in names},
        }

    # C fails: among A and B, B leads by far in the run and in the halved box.
    assert page._among_validated(run(0, [0.0, 3.0, 9.0], "C", [0.5, 3.0, 9.0])) == (["C"], "preferred B", ["A"])
    # A halved box that brings A level with B: undecided, and A is no longer below in every box.
    assert page._among_validated(run(0, [0.0, 3.0, 9.0], "C", [3.0, 3.0, 9.0])) == (["C"], "undecided", [])
    # Trusted: nobody left out; the full comparison.
    assert page._among_validated(run(0, [0.0, 0.1, 3.0], None, [0.0, 0.1, 3.0])) == ([], "preferred C", ["A", "B"])
    assert page._among_validated(run(0, [0.0, 3.0, 9.0], "C", [0.5, 3.0, 9.0], "; MISSPECIFIED: no model")) is None
    saved = [("r0", run(0, [0.0, 3.0, 9.0], "C", [0.5, 3.0, 9.0])), ("r1", run(1, [0.0, 3.0, 3.1], "B", [0, 3, 3.1]))]
    text = page._among_validated_sentence(saved)
    assert "seed 0 preferred B (without C); seed 1 preferred C (without B)" in text
    assert text.endswith("computed from it: A in every seed where its emulator validated (0, 1)")
    # A flagged seed is named, not silently dropped; a model compared in fewer seeds is counted there.
    saved.append(("r2", run(2, [0.0, 3.0, 9.0], "C", [0.5, 3.0, 9.0], "; MISSPECIFIED: no model")))
    saved.append(("r3", run(3, [5.0, 3.0, 9.0], "C", [5.0, 3.0, 9.0])))
    text = page._among_validated_sentence(saved)
    assert "A in 2 of the 3 seeds where its emulator validated (0, 1); B in 1 of the 2 seeds where its" in text
    assert text.endswith("(not counted: seed 2, flagged otherwise)")
    # A validated model without an accepted simulation (-inf) still takes part, from its upper bound.
    none = run(0, [0.0, float("-inf"), 9.0], "C", [0.0, float("-inf"), 9.0])
    assert page._among_validated(none) == (["C"], "undecided", [])
    assert page._among_validated_sentence([("r", run(0, [0.0, 0.1, 3.0], None, [0.0, 0.1, 3.0]))]) == ""


_VERSIONS = {
    "v0": ("return SCALE", "y = SCALE\n    return y"),
    "v1": ("return SCALE * math.sqrt(x)", "return math.sqrt(x) * SCALE"),
    "v2": ("SCALE = 2.0", "SCALE = 2.0 * 1"),
}


def _hash_of(source: str, version: str) -> str:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "m.py"
        path.write_text(source.replace(*_VERSIONS[version]))
        return _common.code_hash(path)


@pytest.mark.parametrize(("at_result", "outcome"), [(1.5, "reproduces"), (2.25, "numbers changed")])
def test_vouch_for_links_a_result_made_with_other_versions_than_the_saved_quick_json(
    fake_repo: Path, monkeypatch, at_result: float, outcome: str
) -> None:
    """One saved quick JSON, results made at several commits: a quick run at the result's commit
    that gives the saved numbers links the result's version to them, and through today's check
    that reproduced them, to today's code. A link survives a rebaseline of the saved quick JSON."""
    from benchmarks import verify

    sibling = QUICK_ENTRY
    long = registry.Entry("long", "benchmarks/results/long.json", "python x.py --long", checked_by=("res",))
    monkeypatch.setattr(status, "REGISTRY", (sibling, long))
    module_file = fake_repo / "jaxabc/fake_dependency.py"
    module_file.write_text(SOURCE.replace(*_VERSIONS["v1"]))
    _git_commit_all(fake_repo)
    write_fake(fake_repo, name="long")  # the result, made at this commit with v1
    write_fake(fake_repo)
    module_file.write_text(SOURCE.replace(*_VERSIONS["v0"]))  # the saved quick JSON's version
    _common.write_result(fake_repo / sibling.quick_output, {"value": 1.5}, inputs=[fake_repo / "data.txt"])
    module_file.write_text(SOURCE.replace(*_VERSIONS["v2"]))  # today's
    runs = {"root": 1.5, "worktree": at_result}
    monkeypatch.setattr(verify, "_run_command", _fake_quick_run_by_tree(fake_repo, runs, sibling, monkeypatch))
    record = verify.check(sibling, fake_repo)
    assert record.pop("equivalence") == {"jaxabc/fake_dependency.py": [_hash_of(SOURCE, "v0"), _hash_of(SOURCE, "v2")]}
    verify._write_ledger("res", record, fake_repo)  # as a check recorded before links were kept
    st = status.status_of(long, root=fake_repo)
    assert st.state == "stale" and "not vouched for by res" in st.why  # the saved numbers are v0's, not v1's

    out = verify.vouch_for(sibling, long, fake_repo)
    assert out["outcome"] == outcome
    assert not any(p.name.startswith(".verify-") for p in fake_repo.parent.iterdir())  # worktree removed
    assert json.loads((fake_repo / sibling.quick_output).read_text())["value"] == 1.5  # saved JSON untouched
    st = status.status_of(long, root=fake_repo)
    if outcome != "reproduces":
        assert st.state == "stale" and status.load_equivalences(fake_repo) == [
            eq for eq in status.load_equivalences(fake_repo) if "commit" not in eq["how"]
        ]
        return
    assert out["linked"] == ["jaxabc/fake_dependency.py"]
    assert st.state == "current" and "quick mode of res reproduces (through earlier checks" in st.why
    assert all(eq["cpu"] == "test" for eq in status.load_equivalences(fake_repo))

    # A rebaseline replaces the saved quick JSON (and so the standing v0-v2 link): the ledger kept it.
    verify.preserve_standing_edge("res", fake_repo)
    _common.write_result(fake_repo / sibling.quick_output, {"value": 1.5}, inputs=[fake_repo / "data.txt"])
    assert not status.standing_edge("res", fake_repo)  # the new saved JSON is v2's own
    assert status.status_of(long, root=fake_repo).state == "current"
    # A change of meaning today breaks the chain: no link reaches today's version.
    module_file.write_text(SOURCE.replace("SCALE = 2.0", "SCALE = 3.0"))
    assert status.status_of(long, root=fake_repo).state == "stale"


def test_a_new_check_keeps_the_link_the_last_one_made(fake_repo: Path, monkeypatch, tmp_path: Path) -> None:
    """A result made at v2 rests on the last check's link (saved v0 = v2); the next check, at v3,
    replaces that record but not the link, so the result stays current through v0."""
    from benchmarks import verify

    sibling = QUICK_ENTRY
    long = registry.Entry("long", "benchmarks/results/long.json", "python x.py --long", checked_by=("res",))
    monkeypatch.setattr(status, "REGISTRY", (sibling, long))
    monkeypatch.setattr(verify, "REGISTRY", (sibling, long))
    module_file = fake_repo / "jaxabc/fake_dependency.py"
    module_file.write_text(SOURCE.replace(*_VERSIONS["v0"]))
    write_fake(fake_repo)
    _common.write_result(fake_repo / sibling.quick_output, {"value": 1.5}, inputs=[fake_repo / "data.txt"])
    module_file.write_text(SOURCE.replace(*_VERSIONS["v2"]))
    write_fake(fake_repo, name="long")
    monkeypatch.setattr(verify, "_run_command", _fake_quick_run(fake_repo, 1.5, sibling))
    record = verify.check(sibling, fake_repo)
    record.pop("equivalence")  # as a check recorded before links were kept
    verify._write_ledger("res", record, fake_repo)
    assert status.status_of(long, root=fake_repo).state == "current"  # code unchanged

    module_file.write_text(SOURCE.replace(*_VERSIONS["v1"]))  # v3, also a refactor
    st = status.status_of(long, root=fake_repo)
    assert st.state == "stale"
    bad: list[str] = []
    probe = json.loads((fake_repo / registry.VERIFICATIONS).read_text())
    verify._check_all([(sibling, 1.0, "")], None, tmp_path, bad, fake_repo)
    assert bad == [] and status.load_verifications(fake_repo)["res"]["outcome"] == "reproduces"
    st = status.status_of(long, root=fake_repo)
    assert st.state == "current" and "through earlier checks" in st.why
    # Without the kept link, v2 would not be joined to today's v3.
    (fake_repo / registry.VERIFICATIONS).write_text(json.dumps(probe))
    monkeypatch.setattr(verify, "preserve_standing_edge", lambda name, root: None)
    verify._check_all([(sibling, 1.0, "")], None, tmp_path, bad, fake_repo)
    assert status.status_of(long, root=fake_repo).state == "stale"


def test_a_quick_json_older_code_made_here_gets_this_hosts_instruction_sets() -> None:
    """Code from before the instruction sets were recorded wrote only the CPU's name: a rebaseline
    made on an AVX-512 host then passed for this host's, and the reproduction test compared them."""
    here = _common.machine()["native_kernel_instruction_set"]
    other = {"simd": ["avx512f"]}
    made = {
        "provenance": {"machine": {"cpu": "AMD EPYC"}},
        "provenance_parts": {
            "a": {"machine": {"cpu": "AMD EPYC"}},
            "b": {"machine": {"cpu": "AMD EPYC", "native_kernel_instruction_set": other}},
        },
    }
    stamped = verify._stamp_host(made)
    assert stamped["provenance"]["machine"]["native_kernel_instruction_set"]["simd"] == here["simd"]
    assert (
        stamped["provenance_parts"]["a"]["machine"]["native_kernel_instruction_set"]["stamped_by"]
        == "benchmarks.verify"
    )
    assert stamped["provenance_parts"]["b"]["machine"]["native_kernel_instruction_set"] == other
    assert verify.cpu_signature(stamped["provenance"]["machine"]) == verify.cpu_signature(
        {**_common.machine(), "cpu": "AMD EPYC"}
    )
