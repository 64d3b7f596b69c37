"""Plugin properties read and checked the same way by every plugin that takes them."""
from __future__ import annotations

import math

import mitsuba as mi


def angle_property(props: mi.Properties, name: str, default: float | None) -> float | None:
    """The angle ``name`` in degrees, ``default`` when the scene leaves it out; it must be finite."""
    if name not in props:
        return default
    value = float(props[name])
    if not math.isfinite(value):
        raise ValueError(f"polariscope: angle '{name}' must be finite, got {value}")
    return value
