"""Virtual environments for the peers a benchmark compares against (ELFI, pyABC, ABCpy, sbi), kept
out of the project's own dependencies."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path


def make_venv(cache: Path, name: str, requirement: str, module: str, install: list | None = None) -> dict:
    """A virtual environment with ``requirement`` installed (made once, then reused); ``install``,
    when given, lists the ``pip install`` argument lists to run instead."""
    venv = cache / f"venv-{name}"
    python = venv / "bin" / "python"
    check = [str(python), "-c", f"import {module}, numpy, importlib.metadata as m; print(m.version({module!r}))"]
    if python.exists() and subprocess.run(check, capture_output=True).returncode == 0:
        return {"python": str(python), "created": False}
    shutil.rmtree(venv, ignore_errors=True)
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    # The host's pip installs into the venv: the venv's own bundled pip may be too old for
    # some packages' metadata.
    for arguments in install or [[requirement]]:
        pip = subprocess.run(
            [sys.executable, "-m", "pip", "--python", str(python), "install", "-q", *arguments],
            capture_output=True,
            text=True,
        )
        if pip.returncode != 0:
            return {"error": f"pip install {' '.join(arguments)} failed: {pip.stderr.strip()[-500:]}"}
    # The first import byte-compiles the package; do it here so that timed runs are cold
    # processes, not first-ever imports.
    done = subprocess.run(check, capture_output=True, text=True)
    if done.returncode != 0:
        return {"error": f"import {module} failed: {done.stderr.strip()[-500:]}"}
    return {"python": str(python), "created": True}
