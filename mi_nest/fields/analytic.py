"""Closed-form stress fields, each a model of the ``stress`` medium.

Every model is a frozen dataclass: its fields are the XML parameters of
``<medium type="stress"><string name="model" value="..."/> ...``
(floats as ``<float>``, 3-vectors as ``<vector>``/``<point>``), angles in
degrees, lengths in mm, stresses in MPa, loads in N. ``eval`` runs on Dr.Jit
points and on tuples of NumPy arrays alike.
"""
from __future__ import annotations

import math

import numpy as np
from dataclasses import dataclass, field

from ..physics.backend import Array, ops
from ..physics.tensors import Tensor, Vector, add, symmetric_outer
from .base import (FieldParameterError, StressField, orthonormal_frame, require_finite,
                   require_positive, unit_vector)


def _local(p, origin, axis):
    return (p[0] - origin[0]) * axis[0] + (p[1] - origin[1]) * axis[1] + (p[2] - origin[2]) * axis[2]


def _require_nonnegative(name, value):
    require_finite(name, value)
    if value < 0:
        raise FieldParameterError(f"parameter '{name}' must not be negative, got {value!r}")


def _axis_frame(name, axis):
    """Right-handed ``(e1, e2, axis)`` for an axisymmetric model (``e1`` is arbitrary)."""
    axis = unit_vector(name, axis)
    # The world axis least aligned with ``axis`` is never parallel to it.
    reference = [0.0, 0.0, 0.0]
    reference[min(range(3), key=lambda i: abs(axis[i]))] = 1.0
    return orthonormal_frame(name, axis, "reference", tuple(reference))


def _plane_tensor(s_11, s_22, s_12, e1, e2):
    """6-tuple of the in-plane tensor ``s_11 e1 e1 + s_22 e2 e2 + s_12 (e1 e2 + e2 e1)``."""
    return add(symmetric_outer(s_11, e1, e1), symmetric_outer(s_22, e2, e2),
               symmetric_outer(2.0 * s_12, e1, e2))


def _masked(xp, inside, tensor):
    """``tensor`` where ``inside`` holds, zero stress elsewhere (outside the material)."""
    return tuple(xp.select(inside, s, 0.0) for s in tensor)


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

    def eval(self, p: Vector) -> Tensor:
        zero = p[0] * 0.0
        return tuple(zero + s for s in (self.xx, self.yy, self.zz, self.yz, self.zx, self.xy))


@dataclass(frozen=True)
class TwistedField(StressField):
    """Uniaxial stress whose direction turns uniformly along ``axis`` (docs/physics.md section 5).

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

    def eval(self, p: Vector) -> Tensor:
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

    With ``contact_width`` w > 0 each load is a radial pressure over the arc of
    chord w (as platens flatten a real disk): the same solution for diametral
    pairs of radial forces spread over the arc by Gauss-Legendre quadrature
    (``CONTACT_POINTS`` pairs, scaled so the resultant along the load is P).
    The stress stays bounded at the contacts, where the point load is 1/r
    singular.
    """
    diameter: float = 40.0
    thickness: float = 6.0
    load: float = 1000.0
    center: tuple = (0.0, 0.0, 0.0)
    axis: tuple = (0.0, 0.0, 1.0)
    load_direction: tuple = (0.0, 1.0, 0.0)
    contact_width: float = 0.0
    frame: tuple = field(init=False, repr=False, compare=False)

    # Keeps r^4 finite at the two load points (relative to R^4).
    _SINGULARITY = 1e-8
    # Diametral force pairs spreading a contact over its arc.
    CONTACT_POINTS = 16

    def __post_init__(self):
        require_positive("diameter", self.diameter)
        require_positive("thickness", self.thickness)
        require_finite("load", self.load)
        require_finite("center", *self.center)
        require_finite("contact_width", self.contact_width)
        if not 0 <= self.contact_width < self.diameter:
            raise FieldParameterError(f"parameter 'contact_width' must be in [0, diameter), got {self.contact_width!r}")
        e_load, e_across, axis = orthonormal_frame("axis", self.axis, "load_direction", self.load_direction)
        # Right-handed disk frame (e_x, e_y, axis) with e_y along the load.
        e_x = tuple(-x for x in e_across)
        object.__setattr__(self, "frame", (e_x, e_load, axis))

    def plane_stress(self, x: Array, y: Array) -> tuple[Array, Array, Array]:
        """``(s_x, s_y, t_xy)`` at disk coordinates ``(x, y)`` (mm)."""
        if self.contact_width == 0:
            return self._point_pair(x, y, self.load)
        half_angle = math.asin(self.contact_width / self.diameter)
        nodes, weights = np.polynomial.legendre.leggauss(self.CONTACT_POINTS)
        angles = half_angle * nodes
        # Radial pairs at angle phi push along the load axis with cos(phi) of their force.
        loads = self.load * weights / float(np.sum(weights * np.cos(angles)))
        s_x = s_y = t_xy = 0.0
        for angle, load in zip(angles.tolist(), loads.tolist()):
            c, s = math.cos(angle), math.sin(angle)
            a, b, t = self._point_pair(c * x + s * y, c * y - s * x, load)
            s_x = s_x + a * c * c + b * s * s - 2.0 * t * c * s
            s_y = s_y + a * s * s + b * c * c + 2.0 * t * c * s
            t_xy = t_xy + (a - b) * c * s + t * (c * c - s * s)
        return s_x, s_y, t_xy

    def _point_pair(self, x, y, load):
        """Frocht's solution for two opposite point forces ``load`` along y."""
        R = 0.5 * self.diameter
        eps = self._SINGULARITY * R ** 4
        r1_4 = (x * x + (R - y) * (R - y)) ** 2 + eps
        r2_4 = (x * x + (R + y) * (R + y)) ** 2 + eps
        k = 2.0 * load / (math.pi * self.thickness)
        inv_d = 1.0 / self.diameter
        s_x = -k * ((R - y) * x * x / r1_4 + (R + y) * x * x / r2_4 - inv_d)
        s_y = -k * ((R - y) ** 3 / r1_4 + (R + y) ** 3 / r2_4 - inv_d)
        t_xy = k * ((R - y) ** 2 * x / r1_4 - (R + y) ** 2 * x / r2_4)
        return s_x, s_y, t_xy

    def eval(self, p: Vector) -> Tensor:
        e_x, e_y, _ = self.frame
        s_x, s_y, t_xy = self.plane_stress(_local(p, self.center, e_x), _local(p, self.center, e_y))
        return add(symmetric_outer(s_x, e_x, e_x), symmetric_outer(s_y, e_y, e_y),
                   symmetric_outer(2.0 * t_xy, e_x, e_y))


@dataclass(frozen=True)
class LameCylinderField(StressField):
    """Thick-walled cylinder under internal and external pressure (Lame 1852).

    Timoshenko & Goodier, *Theory of Elasticity* (3rd ed., 1970), ch. 4
    ("thick-walled cylinder"); Boresi & Schmidt, *Advanced Mechanics of
    Materials* (6th ed., 2003), ch. 11.
    Inner radius a = ``inner_radius``, outer radius b = ``outer_radius``,
    p_i = ``internal_pressure``, p_o = ``external_pressure`` (MPa, positive
    pushing on the wall), r the distance from the axis through ``center``::

        A = (p_i a^2 - p_o b^2) / (b^2 - a^2),   B = (p_i - p_o) a^2 b^2 / (b^2 - a^2)
        s_rr = A - B / r^2,   s_tt = A + B / r^2,   t_rt = 0
        s_zz = axial_factor * A

    ``axial_factor`` picks the axial state (s_zz is uniform, so any value is in
    equilibrium): 0 = open ends / generalised plane stress, the default;
    1 = closed ends (the end caps carry the pressure: s_zz = A);
    2 nu = plane strain (e_zz = 0). Outside the wall (r < a or r > b) the stress
    is zero.
    """
    inner_radius: float = 10.0
    outer_radius: float = 20.0
    internal_pressure: float = 10.0
    external_pressure: float = 0.0
    axial_factor: float = 0.0
    center: tuple = (0.0, 0.0, 0.0)
    axis: tuple = (0.0, 0.0, 1.0)
    frame: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        require_positive("inner_radius", self.inner_radius)
        require_positive("outer_radius", self.outer_radius)
        if self.inner_radius >= self.outer_radius:
            raise FieldParameterError(
                f"parameter 'inner_radius' ({self.inner_radius!r}) must be smaller than "
                f"'outer_radius' ({self.outer_radius!r})")
        require_finite("internal_pressure", self.internal_pressure)
        require_finite("external_pressure", self.external_pressure)
        require_finite("axial_factor", self.axial_factor)
        require_finite("center", *self.center)
        object.__setattr__(self, "frame", _axis_frame("axis", self.axis))

    @property
    def lame_constants(self) -> tuple[float, float]:
        """``(A, B)`` of ``s_rr = A - B/r^2``, ``s_tt = A + B/r^2`` (MPa, MPa mm^2)."""
        a2, b2 = self.inner_radius ** 2, self.outer_radius ** 2
        A = (self.internal_pressure * a2 - self.external_pressure * b2) / (b2 - a2)
        B = (self.internal_pressure - self.external_pressure) * a2 * b2 / (b2 - a2)
        return A, B

    def eval(self, p: Vector) -> Tensor:
        e1, e2, axis = self.frame
        x, y = _local(p, self.center, e1), _local(p, self.center, e2)
        xp = ops(x)
        A, B = self.lame_constants
        r2 = x * x + y * y
        inside = (r2 >= self.inner_radius ** 2) & (r2 <= self.outer_radius ** 2)
        r2 = xp.maximum(r2, self.inner_radius ** 2)      # finite in the bore (masked anyway)
        k = B / (r2 * r2)
        # s_rr e_r e_r + s_tt e_t e_t = A I - (B / r^2) [[cos 2t, sin 2t], [sin 2t, -cos 2t]]
        s_11 = A - k * (x * x - y * y)
        s_22 = A + k * (x * x - y * y)
        s_12 = -2.0 * k * x * y
        tensor = add(_plane_tensor(s_11, s_22, s_12, e1, e2),
                     symmetric_outer(self.axial_factor * A + 0.0 * x, axis, axis))
        return _masked(xp, inside, tensor)


@dataclass(frozen=True)
class ShaftTorsionField(StressField):
    """Circular shaft of ``radius`` R twisted by a ``torque`` T (N mm) about ``axis``.

    Coulomb / Saint-Venant torsion of a circular section (Timoshenko & Goodier,
    *Theory of Elasticity*, 3rd ed., ch. 10 "Torsion"; Gere & Goodno, *Mechanics
    of Materials*, ch. 3): pure shear in cylindrical coordinates (r, theta,
    z = ``axis``)::

        t_tz = T r / J,   J = pi R^4 / 2,   all other components zero

    i.e. ``S = (T / J) (w axis^T + axis w^T)`` with ``w = axis x (p - center)``.
    T > 0 is right-handed about ``axis``: the traction on a cross-section facing
    +``axis`` has moment +T about it. Zero stress outside the shaft (r > R).
    """
    radius: float = 10.0
    torque: float = 10000.0
    center: tuple = (0.0, 0.0, 0.0)
    axis: tuple = (0.0, 0.0, 1.0)
    frame: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        require_positive("radius", self.radius)
        require_finite("torque", self.torque)
        require_finite("center", *self.center)
        object.__setattr__(self, "frame", _axis_frame("axis", self.axis))

    def eval(self, p: Vector) -> Tensor:
        e1, e2, axis = self.frame
        x, y = _local(p, self.center, e1), _local(p, self.center, e2)
        xp = ops(x)
        polar_moment = 0.5 * math.pi * self.radius ** 4
        w = tuple(x * b - y * a for a, b in zip(e1, e2))        # r e_theta
        tensor = symmetric_outer(2.0 * self.torque / polar_moment, w, axis)
        return _masked(xp, x * x + y * y <= self.radius ** 2, tensor)


@dataclass(frozen=True)
class BeamBendingField(StressField):
    """Pure bending of a prismatic beam with a ``width`` x ``height`` rectangular section.

    Navier's flexure formula, exact in linear elasticity for pure bending
    (Timoshenko & Goodier, *Theory of Elasticity*, 3rd ed., "pure bending of
    prismatic bars"; Gere & Goodno, *Mechanics of Materials*, ch. 5). Beam
    frame: x along ``axis`` (the beam axis), y along ``height_direction`` (made
    perpendicular to x: the bending plane), z = x cross y (the neutral axis of
    the section, along the width); coordinates from ``center``, a point of the
    centroidal axis::

        s_xx = -M y / I,   I = b h^3 / 12,   all other components zero

    M = ``moment`` (N mm) is the bending moment about +z acting on a section
    facing +x: M > 0 compresses the +y side. Zero stress outside the section
    (|y| > h/2 or |z| > b/2); the beam is infinitely long.
    """
    width: float = 10.0
    height: float = 20.0
    moment: float = 100000.0
    center: tuple = (0.0, 0.0, 0.0)
    axis: tuple = (1.0, 0.0, 0.0)
    height_direction: tuple = (0.0, 1.0, 0.0)
    frame: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        require_positive("width", self.width)
        require_positive("height", self.height)
        require_finite("moment", self.moment)
        require_finite("center", *self.center)
        e_y, e_z, e_x = orthonormal_frame("axis", self.axis, "height_direction", self.height_direction)
        object.__setattr__(self, "frame", (e_x, e_y, e_z))

    @property
    def second_moment(self) -> float:
        return self.width * self.height ** 3 / 12.0

    def eval(self, p: Vector) -> Tensor:
        e_x, e_y, e_z = self.frame
        y, z = _local(p, self.center, e_y), _local(p, self.center, e_z)
        xp = ops(y)
        tensor = symmetric_outer(-self.moment / self.second_moment * y, e_x, e_x)
        inside = (xp.abs(y) <= 0.5 * self.height) & (xp.abs(z) <= 0.5 * self.width)
        return _masked(xp, inside, tensor)


@dataclass(frozen=True)
class KirschPlateField(StressField):
    """Infinite plate with a circular hole under remote uniaxial tension (Kirsch 1898).

    G. Kirsch, *Zeitschrift des Vereines deutscher Ingenieure* 42 (1898) 797-807;
    Timoshenko & Goodier, *Theory of Elasticity*, 3rd ed., section 35. Plane
    stress, plate normal ``axis``, hole of ``radius`` a centred at ``center``,
    remote stress S = ``tension`` (MPa) along ``load_direction`` (made
    perpendicular to ``axis``); theta measured from the load direction::

        s_rr = S/2 (1 - a^2/r^2) + S/2 (1 - 4 a^2/r^2 + 3 a^4/r^4) cos 2theta
        s_tt = S/2 (1 + a^2/r^2) - S/2 (1 + 3 a^4/r^4) cos 2theta
        t_rt = -S/2 (1 + 2 a^2/r^2 - 3 a^4/r^4) sin 2theta

    (s_tt = 3S at the hole edge across the load: stress concentration 3).
    Inside the hole (r < a, no material) the stress is zero.
    """
    radius: float = 5.0
    tension: float = 10.0
    center: tuple = (0.0, 0.0, 0.0)
    axis: tuple = (0.0, 0.0, 1.0)
    load_direction: tuple = (1.0, 0.0, 0.0)
    frame: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        require_positive("radius", self.radius)
        require_finite("tension", self.tension)
        require_finite("center", *self.center)
        object.__setattr__(self, "frame", orthonormal_frame("axis", self.axis, "load_direction",
                                                            self.load_direction))

    def polar_stress(self, r: Array, theta: Array) -> tuple[Array, Array, Array]:
        """``(s_rr, s_tt, t_rt)`` at polar coordinates ``r`` (mm), ``theta`` (rad, from the load)."""
        xp = ops(r)
        return self._polar((self.radius / r) ** 2, xp.cos(2.0 * theta), xp.sin(2.0 * theta))

    def _polar(self, q, c2, s2):
        # q = a^2 / r^2, (c2, s2) = (cos 2theta, sin 2theta)
        S = self.tension
        s_rr = 0.5 * S * (1 - q) + 0.5 * S * (1 - 4 * q + 3 * q * q) * c2
        s_tt = 0.5 * S * (1 + q) - 0.5 * S * (1 + 3 * q * q) * c2
        t_rt = -0.5 * S * (1 + 2 * q - 3 * q * q) * s2
        return s_rr, s_tt, t_rt

    def eval(self, p: Vector) -> Tensor:
        e1, e2, _ = self.frame
        x, y = _local(p, self.center, e1), _local(p, self.center, e2)
        xp = ops(x)
        a2 = self.radius ** 2
        r2 = x * x + y * y
        inside = r2 >= a2
        r2 = xp.maximum(r2, a2)
        c2, s2 = (x * x - y * y) / r2, 2.0 * x * y / r2
        s_rr, s_tt, t_rt = self._polar(a2 / r2, c2, s2)
        # Polar to Cartesian: rotate by theta (cos 2theta = c2, sin 2theta = s2).
        mean, half = 0.5 * (s_rr + s_tt), 0.5 * (s_rr - s_tt)
        tensor = _plane_tensor(mean + half * c2 - t_rt * s2, mean - half * c2 + t_rt * s2,
                               half * s2 + t_rt * c2, e1, e2)
        return _masked(xp, inside, tensor)


@dataclass(frozen=True)
class BoussinesqField(StressField):
    """Point load normal to the surface of an elastic half-space (Boussinesq 1885).

    J. Boussinesq, *Application des potentiels...* (Gauthier-Villars, 1885); in
    this form K. L. Johnson, *Contact Mechanics* (1985), section 3.2
    ("concentrated normal force"), also Timoshenko & Goodier, *Theory of
    Elasticity*, 3rd ed., ch. 13. A force P = ``load`` (N,
    positive pushing into the solid) acts at ``origin``; ``axis`` is the inward
    normal, z >= 0 the depth, r the distance from the load line,
    rho^2 = r^2 + z^2, nu = ``poisson_ratio``::

        s_r  =  P/(2 pi) [ (1 - 2nu) (1 - z/rho) / r^2 - 3 z r^2 / rho^5 ]
        s_t  = -P/(2 pi) (1 - 2nu) [ (1 - z/rho) / r^2 - z / rho^3 ]
        s_z  = -3P/(2 pi) z^3 / rho^5
        t_rz = -3P/(2 pi) r z^2 / rho^5

    Evaluated in Cartesian form, free of the r = 0 axis singularity, with
    (1 - z/rho)/r^2 = 1/(rho (rho + z)) and
    (s_r - s_t)/r^2 = P/(2 pi) [(1 - 2nu)(2 rho + z)/(rho^3 (rho + z)^2) - 3 z/rho^5].
    The load point itself is regularised like the disk's load points: rho^2 is
    replaced by r^2 + z^2 + c^2 with c = ``core_radius`` (mm, default 1e-4 mm),
    so stresses stay finite there (about 3P/(2 pi c^2) at the load point, well
    inside float32); at a distance d from the load the relative change is of
    order (c/d)^2 (1e-8 at d = 1 mm). Zero stress above the surface
    (z < 0, no material). The default ``axis`` (0, 0, -1) puts the solid in
    z < 0 under a surface z = 0, loaded downwards.
    """
    load: float = 1000.0
    poisson_ratio: float = 0.3
    core_radius: float = 1e-4
    origin: tuple = (0.0, 0.0, 0.0)
    axis: tuple = (0.0, 0.0, -1.0)
    frame: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        require_finite("load", self.load)
        require_finite("poisson_ratio", self.poisson_ratio)
        if not -1.0 < self.poisson_ratio <= 0.5:
            raise FieldParameterError(
                f"parameter 'poisson_ratio' must be in (-1, 0.5], got {self.poisson_ratio!r}")
        require_positive("core_radius", self.core_radius)
        require_finite("origin", *self.origin)
        object.__setattr__(self, "frame", _axis_frame("axis", self.axis))

    def eval(self, p: Vector) -> Tensor:
        e1, e2, axis = self.frame
        x, y, depth = (_local(p, self.origin, e) for e in (e1, e2, axis))
        xp = ops(x)
        z = xp.maximum(depth, 0.0)
        rho2 = x * x + y * y + z * z + self.core_radius ** 2
        rho = xp.sqrt(rho2)
        inv_rho3 = 1.0 / (rho2 * rho)
        inv_rho5 = inv_rho3 / rho2
        k = self.load / (2.0 * math.pi)
        m = 1.0 - 2.0 * self.poisson_ratio
        rz = rho + z
        s_t = -k * m * (1.0 / (rho * rz) - z * inv_rho3)
        q = k * (m * (2.0 * rho + z) * inv_rho3 / (rz * rz) - 3.0 * z * inv_rho5)
        shear = -3.0 * k * z * z * inv_rho5                     # t_rz / r
        tensor = add(_plane_tensor(s_t + q * x * x, s_t + q * y * y, q * x * y, e1, e2),
                     symmetric_outer(-3.0 * k * z * z * z * inv_rho5, axis, axis),
                     symmetric_outer(2.0 * shear * x, e1, axis),
                     symmetric_outer(2.0 * shear * y, e2, axis))
        return _masked(xp, depth >= 0.0, tensor)


@dataclass(frozen=True)
class StackedDisksField(StressField):
    """A stack of ``count`` disks under diametral compression, each loaded at its own angle.

    Disk k (k = 0 .. count-1) is a :class:`DiskCompressionField` (Frocht's plane
    stress solution) of the given ``diameter``, ``thickness`` and ``load``,
    centred at ``center + k (thickness + gap) axis``, loaded along
    ``load_direction`` rotated by ``k * angle_step`` degrees (right-handed) about
    ``axis``. Seen along ``axis`` the principal directions turn by ``angle_step``
    from one disk to the next: the NeST paper's "two stacked disks loaded at
    different angles", where the linear (commuting) model of the integral fails.
    A point belongs to the disk whose slab (|(p - c_k) . axis| <= thickness/2)
    contains it; in the gaps between slabs and beyond the ends of the stack the
    stress is zero (where two slabs touch, gap = 0, disk k + 1 wins). Radially the
    formula is not cut off, as for ``disk_compression``: the enclosing shape is
    the occupancy. ``count`` is a float for the XML interface but must be a whole
    number >= 1 (a Python loop of ``count`` selects per evaluation).
    """
    diameter: float = 40.0
    thickness: float = 6.0
    load: float = 1000.0
    count: float = 2.0
    gap: float = 0.0
    angle_step: float = 45.0
    center: tuple = (0.0, 0.0, 0.0)
    axis: tuple = (0.0, 0.0, 1.0)
    load_direction: tuple = (0.0, 1.0, 0.0)
    contact_width: float = 0.0       # mm; each disk's loads spread as in ``disk_compression``
    frame: tuple = field(init=False, repr=False, compare=False)
    disk: DiskCompressionField = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        require_positive("diameter", self.diameter)
        require_positive("thickness", self.thickness)
        require_finite("load", self.load)
        require_finite("count", self.count)
        if self.count < 1 or self.count != int(self.count):
            raise FieldParameterError(f"parameter 'count' must be a whole number >= 1, got {self.count!r}")
        _require_nonnegative("gap", self.gap)
        require_finite("angle_step", self.angle_step)
        require_finite("center", *self.center)
        object.__setattr__(self, "frame", orthonormal_frame("axis", self.axis, "load_direction",
                                                            self.load_direction))
        object.__setattr__(self, "disk", DiskCompressionField(self.diameter, self.thickness, self.load,
                                                              contact_width=self.contact_width))

    def disk_center(self, k: int) -> tuple[float, float, float]:
        offset = k * (self.thickness + self.gap)
        return tuple(c + offset * a for c, a in zip(self.center, self.frame[2]))

    def disk_field(self, k: int) -> DiskCompressionField:
        """Disk ``k`` alone, as a :class:`DiskCompressionField`."""
        e1, e2, axis = self.frame
        angle = math.radians(k * self.angle_step)
        direction = tuple(math.cos(angle) * a + math.sin(angle) * b for a, b in zip(e1, e2))
        return DiskCompressionField(self.diameter, self.thickness, self.load, self.disk_center(k),
                                    axis, direction, self.contact_width)

    def eval(self, p: Vector) -> Tensor:
        e1, e2, axis = self.frame
        u, v, w = (_local(p, self.center, e) for e in (e1, e2, axis))
        xp = ops(u)
        # Which slab holds the point, and the (cos, sin) of that disk's load angle.
        pitch, half = self.thickness + self.gap, 0.5 * self.thickness
        inside = xp.abs(w) <= half
        c, s = 1.0 + 0.0 * u, 0.0 * u
        for k in range(1, int(self.count)):
            in_k = xp.abs(w - k * pitch) <= half
            angle = math.radians(k * self.angle_step)
            c = xp.select(in_k, math.cos(angle), c)
            s = xp.select(in_k, math.sin(angle), s)
            inside = inside | in_k
        # Disk frame: e_y = load direction = c e1 + s e2, e_x = e_y x axis = s e1 - c e2.
        e_x = tuple(s * a - c * b for a, b in zip(e1, e2))
        e_y = tuple(c * a + s * b for a, b in zip(e1, e2))
        s_x, s_y, t_xy = self.disk.plane_stress(s * u - c * v, c * u + s * v)
        return _masked(xp, inside, _plane_tensor(s_x, s_y, t_xy, e_x, e_y))


MODELS = {
    "uniform": UniformField,
    "twisted": TwistedField,
    "disk_compression": DiskCompressionField,
    "lame_cylinder": LameCylinderField,
    "shaft_torsion": ShaftTorsionField,
    "beam_bending": BeamBendingField,
    "kirsch_plate": KirschPlateField,
    "boussinesq": BoussinesqField,
    "stacked_disks": StackedDisksField,
}
