"""The peers' table (docs/peers.md) names a test for each jaxabc feature: that test must exist."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_test_named_in_the_peers_table_exists() -> None:
    text = (ROOT / "docs" / "peers.md").read_text()
    missing, current = [], None
    # `file.py::test_name` sets the file; a following `::test_name` refers to the same file.
    for file, name in re.findall(r"`(?:(test_\w+\.py))?::(test_\w+)`", text):
        current = file or current
        assert current is not None, f"::{name} is named before any test file"
        source = (ROOT / "tests" / current).read_text()
        if not re.search(rf"^def {name}\(", source, re.M):
            missing.append(f"{current}::{name}")
    assert not missing, f"docs/peers.md names tests that do not exist: {missing}"
