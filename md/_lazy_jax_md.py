"""Import jax-md without running its ``rigid_body`` module until something uses it.

``jax_md/__init__.py`` imports every submodule, and ``jax_md.rigid_body`` computes its shape
tables at import: about a hundred small XLA compilations, the largest single cost of a cold
``import jax_md`` (``python -X importtime``).  The helium and LJ engines never touch it.
:func:`defer_rigid_body` puts a lazy module (:class:`importlib.util.LazyLoader`) for it in
jax-md's package before its ``__init__`` runs, so the package's own ``from jax_md import
rigid_body`` binds it without running it; the first attribute access (the rigid-water
engine's ``rigid_body.RigidBody``) loads it in full.  Nothing changes once jax-md has been
imported, or when it is not installed.  Importing this module does it (the packages that
import jax-md import this module first).
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import sys

__all__ = ["defer_rigid_body"]

_NAME = "jax_md.rigid_body"


def defer_rigid_body() -> bool:
    """Import jax-md with ``rigid_body`` lazy, unless jax-md is imported already; True if it did.

    The package is loaded here by the documented recipe (``module_from_spec`` and
    ``exec_module``) so that ``jax_md.rigid_body`` can be set on it first: its ``__init__``'s
    ``from jax_md import rigid_body`` then finds the attribute and binds the lazy module (a
    plain import of a lazy module in ``sys.modules`` would read its ``__spec__`` and load it).
    """
    if "jax_md" in sys.modules or _NAME in sys.modules:
        return False
    spec = importlib.util.find_spec("jax_md")  # locates it without running its __init__
    if spec is None or spec.loader is None or spec.submodule_search_locations is None:
        return False
    child = importlib.machinery.PathFinder.find_spec(_NAME, list(spec.submodule_search_locations))
    if child is None or child.loader is None:
        return False
    child.loader = importlib.util.LazyLoader(child.loader)
    lazy = importlib.util.module_from_spec(child)
    child.loader.exec_module(lazy)
    package = importlib.util.module_from_spec(spec)
    package.rigid_body = lazy  # type: ignore[attr-defined]
    sys.modules["jax_md"], sys.modules[_NAME] = package, lazy
    try:
        spec.loader.exec_module(package)
    except BaseException:
        sys.modules.pop("jax_md", None)
        sys.modules.pop(_NAME, None)
        raise
    return True


defer_rigid_body()
