"""The one small interface every stress source implements."""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..physics.tensors import Tensor, Vector, cross

if TYPE_CHECKING:
    import mitsuba as mi
    import numpy as np


class StressField:
    """A 3D stress tensor field in MPa over scene coordinates in mm.

    ``eval(p)`` takes a point as a 3-sequence of arrays (a Dr.Jit ``Point3f`` or a
    tuple of NumPy arrays for analytic fields) and returns the 6-tuple
    ``(xx, yy, zz, yz, zx, xy)``. Fields with optimisable data expose it through
    ``traverse``/``parameters_changed`` like a Mitsuba object.
    """

    def eval(self, p: Vector) -> Tensor:
        raise NotImplementedError

    def projected(self, alpha: Tensor, beta: Tensor):
        """The field as one fixed transverse frame sees it (``(alpha . s, beta . s)`` by an ``eval(p)`` cheaper
        than projecting ``eval``'s six components), for a render whose rays all share that frame; None where
        the field has no such lookup."""
        return None

    def traverse(self, callback: mi.TraversalCallback) -> None:
        pass

    def parameters_changed(self, keys: list[str]) -> None:
        pass


def sample(field: StressField, points: np.ndarray) -> np.ndarray:
    """``(N, 6)`` float64 stress (MPa) of ``field`` at NumPy points ``(N, 3)`` (mm), through Dr.Jit."""
    import mitsuba as mi
    import numpy as np
    points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    values = field.eval(mi.Point3f(points.T))
    return np.stack([np.broadcast_to(np.array(v, dtype=np.float64), (len(points),)) for v in values], axis=-1)


# A unit 3-vector of a model's frame, in world coordinates.
Direction = tuple[float, float, float]


class FieldParameterError(ValueError):
    """A field or model parameter is missing, unknown or out of range."""


def require_finite(name: str, *values: float) -> None:
    for value in values:
        if not math.isfinite(value):
            raise FieldParameterError(f"parameter '{name}' must be finite, got {value!r}")


def require_positive(name: str, value: float) -> None:
    require_finite(name, value)
    if value <= 0:
        raise FieldParameterError(f"parameter '{name}' must be positive, got {value!r}")


def unit_vector(name: str, vector: Sequence[float]) -> Direction:
    if len(vector) != 3:
        raise FieldParameterError(f"parameter '{name}' must have 3 components, got {vector!r}")
    require_finite(name, *vector)
    length = math.sqrt(sum(x * x for x in vector))
    if length == 0:
        raise FieldParameterError(f"parameter '{name}' must be a non-zero vector")
    return tuple(x / length for x in vector)


def orthonormal_frame(name_axis: str, axis: Sequence[float], name_ref: str,
                      reference: Sequence[float]) -> tuple[Direction, Direction, Direction]:
    """Right-handed ``(e1, e2, axis)`` with ``e1`` = ``reference`` made perpendicular to ``axis``."""
    axis = unit_vector(name_axis, axis)
    reference = unit_vector(name_ref, reference)
    along = sum(r * a for r, a in zip(reference, axis))
    e1 = tuple(r - along * a for r, a in zip(reference, axis))
    length = math.sqrt(sum(x * x for x in e1))
    if length < 1e-6:
        raise FieldParameterError(f"parameter '{name_ref}' must not be parallel to '{name_axis}'")
    e1 = tuple(x / length for x in e1)
    return e1, cross(axis, e1), axis
