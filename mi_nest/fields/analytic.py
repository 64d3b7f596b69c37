"""Closed-form stress fields, each a model of the ``stress`` medium.

Every model is a frozen dataclass: its fields are the XML parameters of
``<medium type="stress"><string name="model" value="..."/> ...``
(floats as ``<float>``, 3-vectors as ``<vector>``/``<point>``), angles in
degrees, lengths in mm, stresses in MPa, loads in N. ``eval`` runs on Dr.Jit
points and on tuples of NumPy arrays alike.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..physics.backend import ops
from ..physics.projection import add, symmetric_outer
from .base import StressField, orthonormal_frame, require_finite, require_positive


def _local(p, origin, axis):
    return (p[0] - origin[0]) * axis[0] + (p[1] - origin[1]) * axis[1] + (p[2] - origin[2]) * axis[2]


@dataclass(frozen=True)
class UniformField(StressField):
    """Constant stress tensor (MPa): a single retarder along any straight path."""
    xx: float = 0.0
    yy: float = 0.0
    zz: float = 0.0
    yz: float = 0.0
    zx: float = 0.0
    xy: float = 0.0

    def __post_init__(self):
        for name in ("xx", "yy", "zz", "yz", "zx", "xy"):
            require_finite(name, getattr(self, name))

    def eval(self, p):
        zero = p[0] * 0.0
        return tuple(zero + s for s in (self.xx, self.yy, self.zz, self.yz, self.zx, self.xy))


@dataclass(frozen=True)
class TwistedField(StressField):
    """Uniaxial stress whose direction turns uniformly along ``axis`` (PHYSICS.md section 5).

    ``S(p) = amplitude * n n^T`` with ``n = cos(phi) e1 + sin(phi) e2`` and
    ``phi = angle + rate * ((p - origin) . axis)``; ``e1`` is ``reference`` made
    perpendicular to ``axis`` and ``e2 = axis x e1``. Seen along ``axis`` the
    transverse axes rotate by ``rate`` degrees per mm: the twisted retarder, whose
    Jones matrix is known in closed form (Yariv & Yeh, *Optical Waves in Crystals*).
    """
    amplitude: float = 1.0
    rate: float = 10.0
    angle: float = 0.0
    axis: tuple = (0.0, 0.0, 1.0)
    reference: tuple = (1.0, 0.0, 0.0)
    origin: tuple = (0.0, 0.0, 0.0)
    frame: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        require_finite("amplitude", self.amplitude)
        require_finite("rate", self.rate)
        require_finite("angle", self.angle)
        require_finite("origin", *self.origin)
        object.__setattr__(self, "frame", orthonormal_frame("axis", self.axis, "reference", self.reference))

    def eval(self, p):
        e1, e2, axis = self.frame
        xp = ops(p[0])
        phi = math.radians(self.angle) + math.radians(self.rate) * _local(p, self.origin, axis)
        s, c = xp.sincos(phi)
        n = tuple(c * a + s * b for a, b in zip(e1, e2))
        return symmetric_outer(self.amplitude, n, n)


@dataclass(frozen=True)
class DiskCompressionField(StressField):
    """Disk under diametral compression, plane stress (Frocht, *Photoelasticity* vol. 2, 1948).

    A disk of ``diameter`` D and ``thickness`` t, centred at ``center`` with its
    faces normal to ``axis``, squeezed by two opposite forces ``load`` P (N) along
    ``load_direction``. In the disk frame (x across, y along the load, R = D/2,
    r1^2 = x^2 + (R - y)^2, r2^2 = x^2 + (R + y)^2)::

        s_x  = -2P/(pi t) [ (R - y) x^2 / r1^4 + (R + y) x^2 / r2^4 - 1/D ]
        s_y  = -2P/(pi t) [ (R - y)^3 / r1^4 + (R + y)^3 / r2^4 - 1/D ]
        t_xy =  2P/(pi t) [ (R - y)^2 x / r1^4 - (R + y)^2 x / r2^4 ]

    At the centre ``s_x - s_y = 8 P / (pi D t)``: fringe order ``8 P / (pi D f_sigma)``.
    """
    diameter: float = 40.0
    thickness: float = 6.0
    load: float = 1000.0
    center: tuple = (0.0, 0.0, 0.0)
    axis: tuple = (0.0, 0.0, 1.0)
    load_direction: tuple = (0.0, 1.0, 0.0)
    frame: tuple = field(init=False, repr=False, compare=False)

    # Keeps r^4 finite at the two load points (relative to R^4).
    _SINGULARITY = 1e-8

    def __post_init__(self):
        require_positive("diameter", self.diameter)
        require_positive("thickness", self.thickness)
        require_finite("load", self.load)
        require_finite("center", *self.center)
        e_load, e_across, axis = orthonormal_frame("axis", self.axis, "load_direction", self.load_direction)
        # Right-handed disk frame (e_x, e_y, axis) with e_y along the load.
        e_x = tuple(-x for x in e_across)
        object.__setattr__(self, "frame", (e_x, e_load, axis))

    def plane_stress(self, x, y):
        """``(s_x, s_y, t_xy)`` at disk coordinates ``(x, y)`` (mm)."""
        R = 0.5 * self.diameter
        eps = self._SINGULARITY * R ** 4
        r1_4 = (x * x + (R - y) * (R - y)) ** 2 + eps
        r2_4 = (x * x + (R + y) * (R + y)) ** 2 + eps
        k = 2.0 * self.load / (math.pi * self.thickness)
        inv_d = 1.0 / self.diameter
        s_x = -k * ((R - y) * x * x / r1_4 + (R + y) * x * x / r2_4 - inv_d)
        s_y = -k * ((R - y) ** 3 / r1_4 + (R + y) ** 3 / r2_4 - inv_d)
        t_xy = k * ((R - y) ** 2 * x / r1_4 - (R + y) ** 2 * x / r2_4)
        return s_x, s_y, t_xy

    def eval(self, p):
        e_x, e_y, _ = self.frame
        s_x, s_y, t_xy = self.plane_stress(_local(p, self.center, e_x), _local(p, self.center, e_y))
        return add(symmetric_outer(s_x, e_x, e_x), symmetric_outer(s_y, e_y, e_y),
                   symmetric_outer(2.0 * t_xy, e_x, e_y))


MODELS = {
    "uniform": UniformField,
    "twisted": TwistedField,
    "disk_compression": DiskCompressionField,
}
