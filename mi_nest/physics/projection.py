"""Projection of the 3D stress tensor onto a ray's transverse plane (PHYSICS.md 1-2).

Stress tensors travel as 6-tuples in 3D-TSV order ``(xx, yy, zz, yz, zx, xy)``;
vectors as 3-sequences of components (a Dr.Jit ``Vector3f`` or a tuple of arrays).
"""
from __future__ import annotations

from .backend import ops

COMPONENTS = ("xx", "yy", "zz", "yz", "zx", "xy")


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0])


def normalize(a):
    xp = ops(*a)
    inv = 1.0 / xp.sqrt(dot(a, a))
    return tuple(x * inv for x in a)


def transverse_basis(k, right):
    """Orthonormal ``(u, v)`` with ``u x v = k``: ``u`` is ``right`` made perpendicular to ``k``.

    ``k`` is the unit direction of light propagation (towards the camera) and
    ``right`` the camera's image-right direction.
    """
    along = dot(right, k)
    u = normalize(tuple(r - along * kk for r, kk in zip(right, k)))
    v = cross(k, u)
    return u, v


def bilinear(s6, a, b):
    """``a^T S b`` for a symmetric tensor ``S`` given as a 6-tuple."""
    xx, yy, zz, yz, zx, xy = s6
    return (a[0] * (xx * b[0] + xy * b[1] + zx * b[2])
            + a[1] * (xy * b[0] + yy * b[1] + yz * b[2])
            + a[2] * (zx * b[0] + yz * b[1] + zz * b[2]))


def project(s6, u, v):
    """Transverse stress difference ``(s_uu - s_vv, 2 s_uv)``: all the optics sees."""
    return bilinear(s6, u, u) - bilinear(s6, v, v), 2.0 * bilinear(s6, u, v)


def symmetric_outer(scale, a, b):
    """6-tuple of ``scale * (a b^T + b a^T) / 2``."""
    return (scale * a[0] * b[0], scale * a[1] * b[1], scale * a[2] * b[2],
            0.5 * scale * (a[1] * b[2] + a[2] * b[1]),
            0.5 * scale * (a[2] * b[0] + a[0] * b[2]),
            0.5 * scale * (a[0] * b[1] + a[1] * b[0]))


def add(*tensors):
    return tuple(sum(parts) for parts in zip(*tensors))
