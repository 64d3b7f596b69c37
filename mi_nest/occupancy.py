"""Where specimens are: crossings of lines with specimen surfaces, and points inside them.

Occupancy is the specimen shape itself (ray-traced), never a learned function.
"""
from __future__ import annotations

from typing import Sequence

import drjit as dr
import mitsuba as mi
import numpy as np

# Crossings followed per line: a guard against broken meshes.
MAX_CROSSINGS = 64


def shape_id(shape: mi.Shape) -> int:
    """The registry id a ray's ``si.shape`` carries for ``shape`` (what lookup tables are indexed by)."""
    return int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shape))[0])


def crossings_along_lines(scene: mi.Scene, shape: mi.Shape, starts: np.ndarray, k: np.ndarray) -> np.ndarray:
    """``(crossings, lines)`` distances along ``k`` from ``starts`` where each line crosses ``shape``.

    Traces each line through the scene from just before its start (other shapes
    are passed through); ``inf`` pads lines with fewer crossings. A point is
    inside after an odd number of them.
    """
    target = shape_id(shape)
    back = 1e-3
    origin = mi.Point3f(*(starts - back * k).T)
    direction = mi.Vector3f(*np.broadcast_to(k, starts.shape).T)
    ray = mi.Ray3f(origin, direction)
    active = mi.Bool(True)
    crossings = []
    for _ in range(MAX_CROSSINGS):
        si = scene.ray_intersect(ray, active=active)
        active &= si.is_valid()
        on_shape = active & (dr.reinterpret_array(mi.UInt32, si.shape) == target)
        distance = dr.select(on_shape, dr.dot(si.p - origin, direction) - back, dr.inf)
        # The next start too: left lazy, each query's kernel would trace every query before it again.
        onward = past_surface(si, direction)
        dr.eval(distance, active, onward)
        crossings.append(np.array(distance))
        if not np.array(active).any():
            break
        ray = mi.Ray3f(onward, direction)
    return np.stack(crossings).astype(np.float64)



# Lines for the parity test run nearly along +z, tilted off every axis: regular lattices of
# points along +z pass exactly through the edges of triangle fans (a disk's caps), where a
# line is counted on both triangles or neither.
_PARITY_DIRECTION = np.array([0.0173, 0.0311, 1.0]) / np.linalg.norm([0.0173, 0.0311, 1.0])


def inside(scene: mi.Scene, shapes: Sequence[mi.Shape], points: np.ndarray) -> np.ndarray:
    """Which of ``points`` (N, 3) lie inside any of ``shapes``: parity of crossings along a line to each."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    k = _PARITY_DIRECTION
    low = min(float(s.bbox().min.z) for s in shapes) - 1.0
    distance = (points[:, 2] - low) / k[2]
    starts = points - distance[:, None] * k
    result = np.zeros(len(points), dtype=bool)
    for shape in shapes:
        crossings = crossings_along_lines(scene, shape, starts, k)
        result |= (crossings < distance[None, :]).sum(axis=0) % 2 == 1
    return result


def nudged(p: mi.Point3f, d: mi.Vector3f, look: mi.UInt32) -> mi.Point3f:
    """``p`` moved by a surface clearance along ``d`` and across it (one way for even ``look``, another for odd).

    A query from there rounds Embree's edge tests differently; moving along
    ``d`` alone changes nothing for a ray along a coordinate axis. The ray
    stays within about a micrometre of its line.
    """
    s, t = mi.coordinate_system(d)
    across = dr.select(look % 2 == 0, s, t)
    return dr.fma(d + across, (1.0 + dr.max(dr.abs(p))) * mi.math.RayEpsilon, p)


def past_surface(si: mi.SurfaceInteraction3f, d: mi.Vector3f) -> mi.Point3f:
    """Continue on the camera line, just past the surface.

    ``si.spawn_ray`` offsets along the normal, which moves the continued ray off
    the line by ~(1 + |p|) 1e-4 mm: on curved surfaces the exit point, and the
    chord, would be wrong by about that much. Moving along ``d`` instead by the
    same normal clearance (capped for grazing rays) keeps every hit on the line.
    """
    clearance = (1.0 + dr.max(dr.abs(si.p))) * mi.math.RayEpsilon
    return dr.fma(d, clearance / dr.maximum(dr.abs(dr.dot(si.n, d)), 1e-2), si.p)
