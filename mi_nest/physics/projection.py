"""Projection of the 3D stress tensor onto a ray's transverse plane (docs/physics.md 1-2).

Stress tensors travel as 6-tuples in 3D-TSV order ``(xx, yy, zz, yz, zx, xy)``;
vectors as 3-sequences of components (a Dr.Jit ``Vector3f`` or a tuple of arrays).
"""
from __future__ import annotations

from .backend import Array
from .tensors import Tensor, Vector, cross, dot, normalize

# The 6-tuples ``(alpha, beta)`` of :func:`projection_coefficients`.
Coefficients = tuple[Tensor, Tensor]


def transverse_basis(k: Vector, right: Vector) -> tuple[tuple[Array, ...], tuple[Array, Array, Array]]:
    """Orthonormal ``(u, v)`` with ``u x v = k``: ``u`` is ``right`` made perpendicular to ``k``.

    ``k`` is the unit direction of light propagation (towards the camera) and
    ``right`` the camera's image-right direction.
    """
    along = dot(right, k)
    u = normalize(tuple(r - along * kk for r, kk in zip(right, k)))
    v = cross(k, u)
    return u, v


def projection_coefficients(u: Vector, v: Vector) -> Coefficients:
    """6-tuples ``(alpha, beta)`` with ``s_uu - s_vv = alpha . s6`` and ``2 s_uv = beta . s6``.

    Constant along a ray, so a march computes them once and spends six
    multiply-adds per quantity and step instead of the full bilinear forms.
    """
    alpha = (u[0] * u[0] - v[0] * v[0], u[1] * u[1] - v[1] * v[1], u[2] * u[2] - v[2] * v[2],
             2.0 * (u[1] * u[2] - v[1] * v[2]), 2.0 * (u[2] * u[0] - v[2] * v[0]),
             2.0 * (u[0] * u[1] - v[0] * v[1]))
    beta = (2.0 * u[0] * v[0], 2.0 * u[1] * v[1], 2.0 * u[2] * v[2],
            2.0 * (u[1] * v[2] + u[2] * v[1]), 2.0 * (u[2] * v[0] + u[0] * v[2]),
            2.0 * (u[0] * v[1] + u[1] * v[0]))
    return alpha, beta


def apply_coefficients(coefficients: Coefficients, s6: Tensor) -> tuple[Array, Array]:
    """``(s_uu - s_vv, 2 s_uv)`` from :func:`projection_coefficients`."""
    alpha, beta = coefficients
    return (sum(a * s for a, s in zip(alpha, s6)), sum(b * s for b, s in zip(beta, s6)))


def project(s6: Tensor, u: Vector, v: Vector) -> tuple[Array, Array]:
    """Transverse stress difference ``(s_uu - s_vv, 2 s_uv)``: all the optics sees."""
    return apply_coefficients(projection_coefficients(u, v), s6)
