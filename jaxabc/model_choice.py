"""ABC model choice: which of several simulators explains the observed data best.

Work in progress: the driver hook (``jaxabc.run`` with a list of models) dispatches here.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

__all__ = ["Model", "ModelChoiceResult", "run_from_driver"]


class Model(NamedTuple):
    """One candidate model: a name, a simulator ``simulate(key, theta) -> summaries`` and its prior."""

    name: str
    simulate: Callable
    prior: Any


class ModelChoiceResult(NamedTuple):
    """Placeholder: the model-choice record."""

    names: tuple[str, ...]


def run_from_driver(arguments: dict[str, Any]) -> Any:
    """Entry point for :func:`jaxabc.run` when it receives a list of models."""
    raise NotImplementedError("ABC model choice is not implemented yet")
