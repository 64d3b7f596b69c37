"""Jones matrices of lossless media as unit quaternions (docs/physics.md section 3).

A quaternion is the tuple ``(a, b, c, d)`` of real arrays standing for the SU(2)
matrix ``J = a I + i (b sigma_x + c sigma_z) + d (i sigma_y)``::

    J = [[a + i c,  d + i b],
         [-d + i b, a - i c]]

acting on Jones vectors expressed in the transverse basis (u, v) of a ray.
Every function works element-wise on NumPy or Dr.Jit arrays (see backend.py);
``to_matrix``/``from_matrix`` are NumPy-only helpers for tests and tools.

Quaternions travel as plain tuples, which Dr.Jit traces and carries through its
loops as they are; :data:`Quaternion` and :data:`Generator` only name them.
"""
from __future__ import annotations

from typing import NewType

import numpy as np

from .backend import Array, ops
from .tensors import cross

# ``(a, b, c, d)``: a Jones matrix (a unit quaternion for a lossless medium).
Quaternion = NewType("Quaternion", tuple)
# ``(0, b, c, d)``: a pure quaternion, element of su(2), the exponent of a step (its generator).
Generator = NewType("Generator", Quaternion)

# Smallest squared phase carried through the square root (AD-safe at zero stress).
_TINY = 1e-30
# Largest squared phase for the series of cos and sinc (their first omitted terms,
# x^12 / 12! and x^12 / 13!, are below 3e-9 there).
_SERIES_LIMIT = 1.0


def identity(like: Array = 0.0) -> Quaternion:
    """The identity quaternion, broadcast to the type of ``like``."""
    zero = like * 0.0
    return Quaternion((zero + 1.0, zero, zero, zero))


def multiply(q1: Quaternion, q2: Quaternion) -> Quaternion:
    """Quaternion product matching the matrix product ``J(q1) @ J(q2)``."""
    a1, b1, c1, d1 = q1
    a2, b2, c2, d2 = q2
    return Quaternion((a1 * a2 - b1 * b2 - c1 * c2 - d1 * d2,
            a1 * b2 + b1 * a2 - d1 * c2 + c1 * d2,
            a1 * c2 + c1 * a2 - b1 * d2 + d1 * b2,
            a1 * d2 + d1 * a2 + b1 * c2 - c1 * b2))


def conjugate(q: Quaternion) -> Quaternion:
    """Inverse of a unit quaternion: the conjugate transpose of its Jones matrix."""
    a, b, c, d = q
    return Quaternion((a, -b, -c, -d))


def norm_squared(q: Quaternion) -> Array:
    a, b, c, d = q
    return a * a + b * b + c * c + d * d


def newton_factor(q: Quaternion) -> Array:
    """``(3 - |q|^2) / 2``: scaling by it is one Newton step of ``q`` towards unit norm."""
    return (3.0 - norm_squared(q)) * 0.5


def scale(q: Quaternion, factor: Array) -> Quaternion:
    return Quaternion(tuple(x * factor for x in q))


def renormalize(q: Quaternion) -> Quaternion:
    """One Newton step towards unit norm, ``q (3 - |q|^2) / 2``.

    Cheap enough to apply after every step; it removes the float32 drift of
    long products to first order without a square root.
    """
    return scale(q, newton_factor(q))


def multiply_renormalized(q: Quaternion, unit_step: Quaternion) -> Quaternion:
    """``renormalize(q * unit_step)`` with the factor taken from ``q``.

    A unit quaternion does not change the norm, so the Newton factor of ``q``
    is that of the product; computing it from ``q`` lets it run alongside the
    product instead of after it, which shortens the dependency chain of a march.
    """
    return scale(multiply(q, unit_step), newton_factor(q))


def step(p: Array, q: Array, phase: Array) -> Quaternion:
    """Exact exponential of one constant-stress step.

    Solves ``dE/ds = -i k [[p, q], [q, -p]] E`` over one step where ``phase = k h``
    (``k = pi C / lambda``, ``h`` the step length), ``p = s_uu - s_vv`` and
    ``q = 2 s_uv``. The result is a retarder of retardance
    ``Delta = 2 phase sqrt(p^2 + q^2)`` whose slow axis is ``0.5 atan2(q, p)``,
    the direction of the larger principal stress: under ``exp(+i omega t)`` the
    component along it gets the phase ``-Delta / 2``, the lag that a positive
    stress-optic coefficient gives it (docs/physics.md section 2).
    """
    return exponential(generator(p, q, phase))


def generator(p: Array, q: Array, phase: Array = 1.0) -> Generator:
    """The step generator ``-i phase (p sigma_z + q sigma_x)`` as a pure quaternion ``(0, b, c, d)``."""
    zero = p * 0.0
    return Generator((zero, -phase * q, -phase * p, zero))


def exponential(omega: Generator) -> Quaternion:
    """``exp`` of a pure quaternion ``(0, b, c, d)`` (an element of su(2)): a unit quaternion."""
    _, b, c, d = omega
    cos_x, sinc_x = cos_sinc(b * b + c * c + d * d)
    return Quaternion((cos_x, b * sinc_x, c * sinc_x, d * sinc_x))


def magnus4(first: Generator, second: Generator, length: Array) -> Quaternion:
    """Fourth-order Magnus step from the generators per unit length at the two Gauss points.

    ``Omega = h/2 (A1 + A2) + sqrt(3)/12 h^2 [A2, A1]``, with ``A1`` sampled before
    ``A2`` along the light; the commutator of two pure quaternions is a cross
    product. Unitary for any step (Blanes, Casas, Oteo & Ros 2009).
    """
    _, b1, c1, d1 = first
    _, b2, c2, d2 = second
    # In (b, d, c) = (i sigma_x, i sigma_y, i sigma_z) coordinates e_x e_y = -e_z (cyclic),
    # so [A2, A1] = -2 (v2 x v1).
    cb, cd, cc = cross((b2, d2, c2), (b1, d1, c1))
    k = -2.0 * 3.0 ** 0.5 / 12.0 * length * length
    half = 0.5 * length
    return exponential(Generator((b1 * 0.0, half * (b1 + b2) + k * cb, half * (c1 + c2) + k * cc,
                                  half * (d1 + d2) + k * cd)))


def cos_sinc(x2: Array) -> tuple[Array, Array]:
    """``(cos x, sin(x) / x)`` from ``x^2``, exact to float32 rounding for any x.

    Both are even in x: for ``x^2 <= 1`` (a retardance of at most 2 rad per step,
    the usual case) their Taylor series in x^2 up to x^10 are exact in float32 and
    need neither a square root nor a range reduction; larger phases take
    ``sincos``, which Dr.Jit only runs for the vector packets that need it.
    """
    xp = ops(x2)
    cos_x = _horner(xp, x2, (1.0, -1 / 2, 1 / 24, -1 / 720, 1 / 40320, -1 / 3628800))
    sinc_x = _horner(xp, x2, (1.0, -1 / 6, 1 / 120, -1 / 5040, 1 / 362880, -1 / 39916800))
    return xp.replace_where(x2 > _SERIES_LIMIT, lambda x2: _cos_sinc_trigonometric(x2, xp),
                            (cos_x, sinc_x), (x2,))


def _horner(xp, x: Array, coefficients: tuple[float, ...]) -> Array:
    """``sum(c_k x^k)``, one fused multiply-add per term: half the instructions and half the dependent latency
    of a multiply and an add."""
    value = coefficients[-1]
    for c in reversed(coefficients[:-1]):
        value = xp.fma(x, value, c)
    return value


def _cos_sinc_trigonometric(x2, xp):
    # The floor keeps the reciprocal (and AD) finite at x = 0.
    inv_x = xp.rsqrt(xp.maximum(x2, _TINY))
    sin_x, cos_x = xp.sincos(x2 * inv_x)
    return cos_x, sin_x * inv_x


def retarder(delta: Array, theta: Array) -> Quaternion:
    """Linear retarder of retardance ``delta`` with its slow axis at ``theta`` (radians)."""
    xp = ops(delta, theta)
    s, c = xp.sincos(0.5 * delta)
    s2, c2 = xp.sincos(2.0 * theta)
    return Quaternion((c, -s * s2, -s * c2, delta * 0.0))


def rotator(gamma: Array) -> Quaternion:
    """Rotator by ``gamma`` (radians): the rotation R(gamma) of docs/physics.md section 1."""
    xp = ops(gamma)
    s, c = xp.sincos(gamma)
    zero = gamma * 0.0
    return Quaternion((c, zero, zero, -s))


def characteristic_parameters(q: Quaternion) -> tuple[Array, Array, Array]:
    """Poincare equivalence: ``J = rotator(gamma) @ retarder(delta, theta)``.

    Returns ``(delta, theta, gamma)`` in radians with ``delta`` in [0, 2 pi],
    ``theta`` in [0, pi) and ``gamma`` in (-pi/2, pi/2]; the representative with
    ``cos(gamma) >= 0`` keeps a single retarder's retardance unwrapped up to 2 pi.
    """
    a, b, c, d = q
    xp = ops(a, b, c, d)
    gamma0 = xp.atan2(-d, a)
    flip = xp.abs(gamma0) > 0.5 * np.pi
    gamma = xp.select(flip, gamma0 - np.pi * xp.sign(gamma0), gamma0)
    cos_half = xp.sqrt(a * a + d * d)
    cos_half = xp.select(flip, -cos_half, cos_half)
    sin_half = xp.sqrt(b * b + c * c)
    delta = 2.0 * xp.atan2(sin_half, cos_half)
    sg, cg = xp.sincos(gamma)
    b_ret = cg * b - sg * c
    c_ret = sg * b + cg * c
    theta = 0.5 * xp.atan2(-b_ret, -c_ret)
    theta = xp.select(theta < 0.0, theta + np.pi, theta)
    return delta, theta, gamma


def to_matrix(q: Quaternion) -> np.ndarray:
    """Complex Jones matrices, shape ``(..., 2, 2)`` (NumPy)."""
    a, b, c, d = (np.asarray(x, dtype=np.float64) for x in q)
    J = np.empty(np.broadcast(a, b, c, d).shape + (2, 2), dtype=np.complex128)
    J[..., 0, 0] = a + 1j * c
    J[..., 0, 1] = d + 1j * b
    J[..., 1, 0] = -d + 1j * b
    J[..., 1, 1] = a - 1j * c
    return J


def from_matrix(J: np.ndarray) -> Quaternion:
    """Quaternion of SU(2) matrices ``(..., 2, 2)`` (NumPy); inverse of :func:`to_matrix`."""
    J = np.asarray(J)
    a = 0.5 * (J[..., 0, 0] + J[..., 1, 1]).real
    c = 0.5 * (J[..., 0, 0] - J[..., 1, 1]).imag
    b = 0.5 * (J[..., 0, 1] + J[..., 1, 0]).imag
    d = 0.5 * (J[..., 0, 1] - J[..., 1, 0]).real
    return Quaternion((a, b, c, d))
