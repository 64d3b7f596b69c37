"""Checks of public API arguments: a wrong type or value is named where it is passed, not deep inside."""
from __future__ import annotations

import numbers


def whole_number(name: str, value: object, minimum: int = 1, maximum: int | None = None) -> int:
    """``value`` as an ``int``: an integer (not a bool, not 2.5) of at least ``minimum`` (and at most ``maximum``).

    ``TypeError`` for another type, ``ValueError`` out of range; both name ``name``.
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"'{name}' must be an integer, got {value!r} ({type(value).__name__})")
    if value < minimum:
        expected = "a positive integer" if minimum == 1 else f"an integer >= {minimum}"
        raise ValueError(f"'{name}' must be {expected}, got {value}")
    if maximum is not None and value > maximum:
        raise ValueError(f"'{name}' must be an integer from {minimum} to {maximum}, got {value}")
    return int(value)
