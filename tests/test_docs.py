"""The README and the guide say what the code does: their marked examples run, their links resolve.

A ```python block preceded by the line ``<!-- runnable -->`` is executed here; the blocks of one
page run in order in one namespace, in a temporary working directory, so a page reads like a
session.  Unmarked blocks are fragments (placeholders such as ``my_module.simulate``).
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs" / "guide").glob("*.md"))]
MARKER = "<!-- runnable -->"
FENCE = re.compile(r"^```(\w*)\n(.*?)^```$", re.S | re.M)
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


def runnable_blocks(text: str) -> list[tuple[int, str]]:
    """``(line number, source)`` of each python block preceded by the marker line.

    Raises ``ValueError`` for a marker that is not followed by a ```python block, which would
    otherwise silently test nothing.
    """
    blocks = []
    for match in re.finditer(re.escape(MARKER) + r"[ \t]*\n", text):
        fence = FENCE.match(text, match.end())
        line = text.count("\n", 0, match.start()) + 1
        if fence is None or fence.group(1) != "python":
            raise ValueError(f"line {line}: {MARKER} must be followed directly by a ```python block")
        blocks.append((line + 2, fence.group(2)))
    return blocks


def _page_id(path: Path) -> str:
    return str(path.relative_to(ROOT))


def test_marker_parser_finds_marked_blocks_only() -> None:
    text = f"intro\n```python\nskipped = 1\n```\n{MARKER}\n```python\nx = 1\n```\n{MARKER}\n```python\ny = 2\n```\n"
    assert runnable_blocks(text) == [(7, "x = 1\n"), (11, "y = 2\n")]
    with pytest.raises(ValueError, match="line 1"):
        runnable_blocks(f"{MARKER}\n```bash\nls\n```\n")


@pytest.mark.parametrize("page", [p for p in PAGES if MARKER in p.read_text()], ids=_page_id)
def test_runnable_examples_run(page: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # examples may save results or figures
    namespace: dict = {"__name__": "__docs__"}
    for line, source in runnable_blocks(page.read_text()):
        code = compile("\n" * (line - 1) + source, str(page), "exec")  # tracebacks point at the page
        exec(code, namespace)


def test_readme_has_a_runnable_example() -> None:
    assert runnable_blocks((ROOT / "README.md").read_text()), "the README's example must be marked runnable"


def test_readme_stays_short() -> None:
    # The README says what the package is and where to read on; the rest belongs in docs/.
    num_lines = len((ROOT / "README.md").read_text().splitlines())
    assert num_lines <= 150, f"README.md has {num_lines} lines: move detail to docs/"


def test_ci_runs_the_readme_test_command_verbatim() -> None:
    blocks = [body for lang, body in FENCE.findall((ROOT / "README.md").read_text()) if lang == "bash"]
    commands = [line for body in blocks for line in body.splitlines() if "pytest" in line]
    assert len(commands) == 1, commands
    ci_lines = [line.strip() for line in (ROOT / ".ci" / "run").read_text().splitlines()]
    assert commands[0].strip() in ci_lines
    assert shlex.split(commands[0])[-2:] == ["-m", "not slow"]


@pytest.mark.parametrize("page", PAGES, ids=_page_id)
def test_relative_links_resolve(page: Path) -> None:
    missing = [
        target
        for target in LINK.findall(page.read_text())
        if "://" not in target and not (page.parent / target).exists()
    ]
    assert not missing, f"{_page_id(page)} links to missing files: {missing}"


def test_the_fluids_page_shows_each_extension_refits_prior_edges() -> None:
    """A refit piled on its prior box says so on the page, not only in its saved diagnostics."""
    from benchmarks._common import RESULTS
    from benchmarks.docpages.common import extension_edges, saved_extension
    from benchmarks.docpages.criticism import page_criticism_fluids

    edges = [
        m
        for name in ("criticism_neon", "criticism_argon")
        for m in extension_edges(saved_extension(RESULTS / name / "extension.npz"))
    ]
    if not edges:
        pytest.skip("no saved fluid extension refit reports a prior edge")
    page = page_criticism_fluids()
    for message in edges:
        assert message in page
