"""jax_md.rigid_body stays unloaded until used (cold-start cost), and works when used."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_importing_the_engines_defers_rigid_body_until_use() -> None:
    code = textwrap.dedent(
        """
        import sys, types
        import md.lj
        import jax_md
        lazy = sys.modules["jax_md.rigid_body"]
        # Before use its body has not run: its class is still the lazy loader's.
        assert type(lazy) is not types.ModuleType, type(lazy)
        assert "jax_md" in sys.modules and md.lj.LJEngine is not None
        from jax_md import rigid_body
        body = rigid_body.RigidBody  # first use loads it in full
        assert type(sys.modules["jax_md.rigid_body"]) is types.ModuleType
        assert body.__name__ == "RigidBody" and rigid_body.tetrahedron is not None
        print("ok")
        """
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300, env=None, check=False
    )
    assert out.returncode == 0 and out.stdout.strip().endswith("ok"), out.stderr[-2000:]


def test_nothing_changes_once_jax_md_is_imported() -> None:
    import jax_md  # noqa: F401

    from md import _lazy_jax_md

    assert _lazy_jax_md.defer_rigid_body() is False
