"""General Jones matrices, with loss and diattenuation, as complex quaternions (docs/physics.md section 8).

A stressed medium's Jones matrix is unitary (a unit quaternion, su2.py). A
dielectric interface is not: its s and p components are transmitted by
different real amounts, and at total internal reflection shifted by different
phases. Any complex 2 x 2 matrix is ``M = A + i B`` in the same basis, with two
real quaternions ``A`` and ``B`` (a biquaternion): products keep the quaternion
rule with complex coefficients, so a march multiplies unitary steps into it as
into a unit quaternion, twice.

Every function works element-wise on NumPy or Dr.Jit arrays; ``to_matrix`` and
``from_matrix`` are NumPy-only helpers for tests and tools.
"""
from __future__ import annotations

from typing import NewType, Sequence

import numpy as np

from . import su2
from .backend import Array, ops

# ``(A, B)``: the Jones matrix ``M = A + i B`` with real quaternions ``A`` and ``B``.
Biquaternion = NewType("Biquaternion", tuple)


class Incoherent(tuple):
    """The Jones matrices of paths whose intensities add (light is incoherent over their path differences): a
    refracted ray's transmitted path and its ghost."""


def from_quaternion(q: su2.Quaternion) -> Biquaternion:
    """The unitary ``q`` as a general Jones matrix."""
    return Biquaternion((tuple(q), tuple(x * 0.0 for x in q)))


def multiply(m1: Biquaternion, m2: Biquaternion) -> Biquaternion:
    """``m1 m2`` (``m2`` acts first)."""
    (a1, b1), (a2, b2) = m1, m2
    real = tuple(x - y for x, y in zip(su2.multiply(a1, a2), su2.multiply(b1, b2)))
    imaginary = tuple(x + y for x, y in zip(su2.multiply(a1, b2), su2.multiply(b1, a2)))
    return Biquaternion((real, imaginary))


def multiply_unitary(q: su2.Quaternion, m: Biquaternion) -> Biquaternion:
    """``q m`` for a unit quaternion ``q``: a stress step after ``m``."""
    return Biquaternion((su2.multiply(q, m[0]), su2.multiply(q, m[1])))


def diattenuator(x: complex | Array, y: complex | Array, angle: Array) -> Biquaternion:
    """``R(angle) diag(x, y) R(-angle)``: amplitude ``x`` along the axis at ``angle`` (radians, from u towards
    v), ``y`` across it. ``x`` and ``y`` are ``(real, imaginary)`` pairs (or real arrays)."""
    (xr, xi), (yr, yi) = _pair(x), _pair(y)
    xp = ops(xr, xi, yr, yi, angle)
    sin2, cos2 = xp.sin(2.0 * angle), xp.cos(2.0 * angle)
    # diag(x, y) = (x + y)/2 I - i (x - y)/2 (cos 2a B_c + sin 2a B_b) once turned by the angle.
    half_sum_r, half_sum_i = 0.5 * (xr + yr), 0.5 * (xi + yi)
    half_diff_r, half_diff_i = 0.5 * (xr - yr), 0.5 * (xi - yi)
    zero = angle * 0.0
    # -i (dr + i di) = di - i dr
    real = (half_sum_r + zero, half_diff_i * sin2, half_diff_i * cos2, zero)
    imaginary = (half_sum_i + zero, -half_diff_r * sin2, -half_diff_r * cos2, zero)
    return Biquaternion((real, imaginary))


def _pair(value):
    if isinstance(value, tuple):
        return value
    if isinstance(value, complex) or (isinstance(value, np.ndarray) and np.iscomplexobj(value)):
        return np.real(value), np.imag(value)
    return value, value * 0.0


def amplitudes(coefficients: Sequence[tuple[tuple[float, ...], tuple[float, ...]]],
               m: Biquaternion) -> list[tuple[Array, Array]]:
    """``(real, imaginary)`` of each output row's amplitude ``kappa . (A + i B)`` (polariscope.py's forms)."""
    a, b = m
    rows = []
    for re, im in coefficients:
        ka_re, ka_im = _dot(re, a), _dot(im, a)
        kb_re, kb_im = _dot(re, b), _dot(im, b)
        rows.append((ka_re - kb_im, ka_im + kb_re))
    return rows


def intensity(coefficients: Sequence[tuple[tuple[float, ...], tuple[float, ...]]], m: Biquaternion) -> Array:
    """The detected intensity through a polariscope of these forms (``Polariscope.coefficients()``)."""
    total = 0.0
    for re, im in amplitudes(coefficients, m):
        total = total + re * re + im * im
    return total


def _dot(k, q):
    terms = [c * x for c, x in zip(k, q) if not (isinstance(c, float) and c == 0.0)]
    return sum(terms) if terms else q[0] * 0.0


def to_matrix(m: Biquaternion) -> np.ndarray:
    """The complex 2 x 2 matrix (NumPy)."""
    return su2.to_matrix(m[0]) + 1j * su2.to_matrix(m[1])


def from_matrix(matrix: np.ndarray) -> Biquaternion:
    """The biquaternion of any complex 2 x 2 matrix (NumPy)."""
    matrix = np.asarray(matrix, dtype=np.complex128)
    # The basis matrices are orthogonal, each of squared norm 2: coefficients are their projections.
    basis = [su2.to_matrix(tuple(float(i == k) for i in range(4))) for k in range(4)]
    coefficients = [np.trace(b.conj().T @ matrix) / 2.0 for b in basis]
    return Biquaternion((tuple(float(c.real) for c in coefficients), tuple(float(c.imag) for c in coefficients)))


def inverse(m: Biquaternion) -> Biquaternion:
    """``m^-1``: the conjugate quaternion over the determinant ``sum c_k^2`` (complex, a polynomial identity of the
    basis). Finite wherever ``m`` is invertible: every interface below grazing incidence, every stress step."""
    a, b = m
    det_re = sum(x * x for x in a) - sum(y * y for y in b)
    det_im = 2.0 * sum(x * y for x, y in zip(a, b))
    norm = det_re * det_re + det_im * det_im
    conj_a, conj_b = su2.conjugate(a), su2.conjugate(b)
    # (conj_a + i conj_b) (det_re - i det_im) / |det|^2
    real = tuple((x * det_re + y * det_im) / norm for x, y in zip(conj_a, conj_b))
    imaginary = tuple((y * det_re - x * det_im) / norm for x, y in zip(conj_a, conj_b))
    return Biquaternion((real, imaginary))


def unitary_adjoint(before: Biquaternion, after: Biquaternion, grad: Biquaternion) -> su2.Quaternion:
    """The adjoint of ``q`` in ``M = before q after`` (``q`` a real quaternion) from the adjoint ``grad`` of ``M``'s
    real and imaginary quaternion coordinates: ``d/dq_k (grad . M)``, linear in ``q``'s coordinates."""
    like = before[0][0] * 0.0
    adjoint = []
    for k in range(4):
        basis = tuple(like + float(i == k) for i in range(4))
        moved = multiply(multiply(before, from_quaternion(basis)), after)
        adjoint.append(sum(g * x for g, x in zip(grad[0], moved[0])) + sum(g * x for g, x in zip(grad[1], moved[1])))
    return su2.Quaternion(tuple(adjoint))
