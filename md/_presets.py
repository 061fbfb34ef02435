"""Preset lookup shared by the in-process simulators (helium, LJ fluids)."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

P = TypeVar("P", bound="DataclassInstance")


def resolve_preset(preset: str | P, presets: dict[str, P], kind: str, **overrides: Any) -> P:
    """Return ``presets[preset]`` (or the preset object itself) with dataclass field overrides.

    Raises a ``ValueError`` naming the known presets when ``preset`` is an unknown name.
    """
    if isinstance(preset, str):
        try:
            chosen = presets[preset]
        except KeyError:
            raise ValueError(f"unknown {kind} preset {preset!r}: use one of {sorted(presets)}") from None
    else:
        chosen = preset
    return dataclasses.replace(chosen, **overrides) if overrides else chosen
