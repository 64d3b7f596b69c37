"""A prior from the free surfaces: a body's free surface carries no traction, so the deviator's shear there is zero.

On a free surface ``sigma n = 0``; with ``sigma = s + p I`` that is ``s n = -p n``: the deviator's traction is
normal to the surface, whatever the mean stress. Its tangential part, ``s n - (n.s.n) n``, is therefore zero for
the true deviator and asks nothing of the invisible mean stress. The surface and where the part is loaded (no
such condition there) are found as ``mi-nest separate`` finds them (mi_nest.separation).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..arrays import device_array
from ..scene import specimen_shapes
from ..separation import scene_loads
from ..separation.surface import specimen_surface
from . import metrics

# Free-surface points each iteration's penalty draws (fixed, so that one kernel serves every iteration).
POINTS_PER_ITERATION = 2048


class FreeSurfacePrior:
    """The free surface of a scene's specimens, sampled about every ``spacing`` mm, each point a little inside
    along its inward normal (where a field is defined)."""

    def __init__(self, scene: mi.Scene, spacing: float, seed: int = 0):
        shapes = specimen_shapes(scene)
        surface = specimen_surface(scene, shapes, spacing)
        loaded = scene_loads(scene, shapes, surface, metrics.evaluation_points(scene, shapes), spacing)
        free = surface.subset(~loaded)
        self.points = (free.points - 0.25 * spacing * free.normals).astype(np.float32)
        self.normals = free.normals.astype(np.float32)
        # Its own draws: the prior leaves the batches' sequence as it is without it.
        self.rng = np.random.default_rng(seed)

    def penalty(self, field, weight: float, rng: np.random.Generator | None = None) -> mi.Float:
        """``weight`` times the mean squared shear traction of ``field``'s deviator (stress scales) at
        :data:`POINTS_PER_ITERATION` free-surface points drawn with ``rng`` (default: the prior's own)."""
        chosen = (self.rng if rng is None else rng).integers(0, len(self.points), POINTS_PER_ITERATION)
        point = mi.Point3f(*(device_array(mi.Float, c) for c in self.points[chosen].T))
        n = [device_array(mi.Float, c) for c in self.normals[chosen].T]
        xx, yy, yz, zx, xy = field.deviatoric(point)
        zz = -(xx + yy)
        traction = (xx * n[0] + xy * n[1] + zx * n[2], xy * n[0] + yy * n[1] + yz * n[2],
                    zx * n[0] + yz * n[1] + zz * n[2])
        normal = traction[0] * n[0] + traction[1] * n[1] + traction[2] * n[2]
        shear = sum(dr.square(t - normal * c) for t, c in zip(traction, n))
        return weight * dr.mean(shear)
