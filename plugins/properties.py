"""Plugin properties read and checked the same way by every plugin that takes them."""
from __future__ import annotations

import math

import mitsuba as mi

from mi_nest.physics.polariscope import Element, parse_optics


def angle_property(props: mi.Properties, name: str, default: float | None) -> float | None:
    """The angle ``name`` in degrees, ``default`` when the scene leaves it out; it must be finite."""
    if name not in props:
        return default
    value = float(props[name])
    if not math.isfinite(value):
        raise ValueError(f"polariscope: angle '{name}' must be finite, got {value}")
    return value


def optics_property(props: mi.Properties, name: str, plugin: str,
                    instead_of: tuple[str, ...]) -> tuple[Element, ...] | None:
    """The optical elements the string ``name`` lists (``physics.polariscope.parse_optics``), None when the scene
    leaves it out; it replaces the properties ``instead_of``, which may not be given beside it."""
    if name not in props:
        return None
    both = [other for other in instead_of if other in props]
    if both:
        raise ValueError(f"{plugin}: '{name}' lists every element, so leave out {', '.join(map(repr, both))} "
                         f"(or give them without '{name}')")
    try:
        return parse_optics(str(props[name]))
    except ValueError as error:
        raise ValueError(f"{plugin}: {error}") from None
