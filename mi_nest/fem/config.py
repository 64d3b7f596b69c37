"""Errors and the dict -> dataclass parsing shared by the FEM specs (TOML/JSON friendly).

Every spec is a frozen dataclass whose fields are the keys of its dict form; a
``type`` key picks the class where several share a slot (regions, loads,
geometries). Unknown or missing keys raise :class:`FemError` naming where they
occurred, with a suggestion for near misses.
"""
from __future__ import annotations

import dataclasses
import difflib
import math
from collections.abc import Iterable, Mapping
from typing import Any, TypeVar

import numpy as np


class FemError(ValueError):
    """An FEM model that cannot be built or solved as specified."""


Spec = TypeVar("Spec")


def parse_fields(cls: type[Spec], data: Any, where: str, *, skip: Iterable[str] = ("type",),
                 prefix_nested: bool = True) -> Spec:
    """``cls(**data)`` after checking ``data`` is a mapping with only ``cls``'s init fields.

    Errors raised while building ``cls`` get ``where`` as a prefix unless
    ``prefix_nested`` is false (a top-level spec whose parts name themselves).
    """
    if not isinstance(data, Mapping):
        raise FemError(f"{where}: expected a table of keys, got {type(data).__name__} {data!r}")
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    unknown = [key for key in data if key not in names and key not in skip]
    if unknown:
        key = unknown[0]
        close = difflib.get_close_matches(str(key), names, n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        raise FemError(f"{where}: unknown key '{key}'{hint}; expected keys: {', '.join(names)}")
    required = [f.name for f in dataclasses.fields(cls)
                if f.init and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    missing = [name for name in required if name not in data]
    if missing:
        raise FemError(f"{where}: missing key(s) {', '.join(repr(m) for m in missing)}")
    try:
        return cls(**{key: value for key, value in data.items() if key not in skip})
    except FemError as error:
        if not prefix_nested:
            raise
        raise FemError(f"{where}: {error}") from None
    except (TypeError, ValueError) as error:
        raise FemError(f"{where}: {error}") from None


def parse_typed(registry: Mapping[str, type], data: Any, where: str, default: str | None = None) -> Any:
    """Pick the class named by ``data['type']`` in ``registry`` and parse ``data`` into it."""
    if not isinstance(data, Mapping):
        raise FemError(f"{where}: expected a table with a 'type' key, got {type(data).__name__} {data!r}")
    kind = data.get("type", default)
    if kind is None:
        raise FemError(f"{where}: missing key 'type' (one of: {', '.join(registry)})")
    if kind not in registry:
        close = difflib.get_close_matches(str(kind), list(registry), n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        raise FemError(f"{where}: unknown type '{kind}'{hint}; expected one of: {', '.join(registry)}")
    return parse_fields(registry[kind], data, where)


def vector(name: str, value: Any, length: int = 3) -> tuple[float, ...]:
    """``value`` as a tuple of ``length`` finite floats (raises FemError otherwise)."""
    try:
        values = tuple(float(v) for v in np.asarray(value, dtype=np.float64).ravel())
    except (TypeError, ValueError):
        raise FemError(f"'{name}' must be a list of {length} numbers, got {value!r}") from None
    if len(values) != length or np.ndim(value) != 1:
        raise FemError(f"'{name}' must be a list of {length} numbers, got {value!r}")
    if not all(math.isfinite(v) for v in values):
        raise FemError(f"'{name}' must be finite, got {value!r}")
    return values


def vectors(name: str, value: Any) -> np.ndarray:
    """``value`` as a (K >= 1, 3) array of finite floats (raises FemError otherwise)."""
    try:
        values = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise FemError(f"'{name}' must be a list of [x, y, z] triples, got {value!r}") from None
    if values.ndim != 2 or values.shape[1] != 3 or len(values) == 0:
        raise FemError(f"'{name}' must be a non-empty list of [x, y, z] triples, got shape {values.shape}")
    if not np.all(np.isfinite(values)):
        raise FemError(f"'{name}' must be finite (row {int(np.argmin(np.isfinite(values).all(axis=1)))} is not)")
    return values


def number(name: str, value: Any, *, positive: bool = False, nonnegative: bool = False) -> float:
    """``value`` as a finite float with an optional sign requirement."""
    if isinstance(value, bool):
        raise FemError(f"'{name}' must be a number, got {value!r}")
    try:
        result = float(value)
    except (TypeError, ValueError):
        raise FemError(f"'{name}' must be a number, got {value!r}") from None
    if not math.isfinite(result):
        raise FemError(f"'{name}' must be finite, got {value!r}")
    if positive and result <= 0:
        raise FemError(f"'{name}' must be positive, got {value!r}")
    if nonnegative and result < 0:
        raise FemError(f"'{name}' must not be negative, got {value!r}")
    return result


def format_point(point: Iterable[float]) -> str:
    return "(" + ", ".join(f"{v:g}" for v in point) + ")"
