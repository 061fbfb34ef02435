"""Griffe extension for the API reference: Sphinx roles in docstrings as inline code.

The docstrings cross-reference with Sphinx roles (``:class:`jaxabc.Uniform```, ``:func:`~x.y```),
which mkdocstrings shows verbatim; this renders each as the target in backticks (``~`` keeps the
last component, as Sphinx does).  Loaded by ``mkdocs.yml``'s mkdocstrings handler options.
"""

from __future__ import annotations

import re
from typing import Any

import griffe

_ROLE = re.compile(r":(?:py:)?(?:class|func|meth|attr|data|mod|exc|obj|const|ref|doc):`(~?)([^`<]+?)(?:\s*<[^>]*>)?`")


def _code(match: re.Match) -> str:
    target = match.group(2).strip()
    return f"`{target.rsplit('.', 1)[-1] if match.group(1) else target}`"


def roles_to_code(text: str) -> str:
    """``text`` with each Sphinx role replaced by its target as inline code."""
    return _ROLE.sub(_code, text)


class SphinxRoles(griffe.Extension):
    """Rewrite the roles in every docstring once its object is loaded."""

    def on_instance(self, *, obj: griffe.Object, **kwargs: Any) -> None:
        if obj.docstring is not None:
            obj.docstring.value = roles_to_code(obj.docstring.value)
