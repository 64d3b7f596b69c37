"""A walk's inside segment, as the straight and the refracted walks hand it to a method."""
from __future__ import annotations

from typing import NamedTuple

import drjit as dr
import mitsuba as mi


class Segment(NamedTuple):
    """One inside chord of each ray in a walk: ``steps`` steps of length ``h`` from ``origin`` along ``d``
    through medium ``medium`` (0: outside, i + 1: the set-up's medium i)."""
    steps: mi.UInt32
    h: mi.Float
    medium: mi.UInt32
    origin: mi.Point3f
    d: mi.Vector3f
    coefficients: tuple     # the ray's projection coefficients (SceneSetup.projection_coefficients)
    seed: mi.UInt32         # what jittered steps hash with their index


def equal_steps(chord: mi.Float, marched: mi.Bool, step_size: float) -> tuple[mi.UInt32, mi.Float]:
    """``(steps, h)``: a marched chord split into ``ceil(chord / step_size)`` equal steps (at least one) of
    length ``h``; none where it is not marched."""
    steps = mi.UInt32(dr.select(marched, dr.maximum(dr.ceil(chord / step_size), 1), 0))
    return steps, chord / mi.Float(dr.maximum(steps, 1))
