"""Preset lookup shared by the in-process simulators (helium, LJ fluids)."""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

P = TypeVar("P")


def resolve_preset(preset: str | P, presets: dict[str, P], kind: str, **overrides: Any) -> P:
    """Return ``presets[preset]`` (or the preset object itself) with dataclass field overrides.

    Raises a ``ValueError`` naming the known presets when ``preset`` is an unknown name.
    """
    if isinstance(preset, str):
        try:
            preset = presets[preset]
        except KeyError:
            raise ValueError(f"unknown {kind} preset {preset!r}: use one of {sorted(presets)}") from None
    return dataclasses.replace(preset, **overrides) if overrides else preset
