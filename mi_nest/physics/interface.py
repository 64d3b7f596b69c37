"""A ray at a dielectric interface: Snell's law, Fresnel amplitudes, the transported frame (docs/physics.md 8).

At an interface of unit normal ``n`` (either side) a ray of unit direction ``d``
has ``s = unit(d x n)``, perpendicular to the plane of incidence, and
``p = d x s``, so that ``(s, p, d)`` is right-handed for the incident, the
transmitted and the reflected ray alike (at normal incidence any ``s`` will
do). In these frames the interface's Jones matrix is ``diag(t_s, t_p)`` or
``diag(r_s, r_p)``: with ``p = d x s`` the reflected ``p`` turns with the ray,
so ``r_p = -r_s`` at normal incidence (Born and Wolf's signs).

The transported frame: a ray's transverse basis ``(u, v)`` keeps its
components on ``s`` and ``p`` across the interface (the rotation about ``s``
that takes ``d`` to the new direction), so it is carried along a bent path
without twist, and the Jones matrix in it is the diagonal one turned by the
angle of ``s`` from ``u``.

Amplitudes are flux-normalised: ``tau = t sqrt(n2 Re(cos_t) / (n1 cos_i))``,
so that ``|r|^2 + |tau|^2 = 1`` per polarisation and the squared amplitude is
the share of the power carried on. A ray that leaves to the medium it started
in (a camera and a light in air) carries its radiance times the product of
these shares, the ``n^2`` of each crossing cancelling.

Fields vary as ``exp(+i omega t)``: beyond the critical angle the transmitted
wave must decay as ``exp(-kappa z)``, so ``cos_t = -i sqrt((n1/n2)^2 sin_i^2 - 1)``
and the reflection coefficients are unit complex numbers.

The coefficient functions are NumPy (complex); the geometry works on NumPy and
Dr.Jit alike.
"""
from __future__ import annotations

import numpy as np

from .backend import Array, ops
from .tensors import Vector, cross, dot, normalize


def cos_transmitted(cos_i: np.ndarray, n1: float, n2: float) -> np.ndarray:
    """Complex cosine of the refraction angle for incidence ``cos_i`` (>= 0) from index ``n1`` into ``n2``."""
    cos_i = np.asarray(cos_i, dtype=np.float64)
    sin_t2 = (n1 / n2) ** 2 * (1.0 - cos_i ** 2)
    return np.where(sin_t2 <= 1.0, np.sqrt(np.maximum(1.0 - sin_t2, 0.0)) + 0j,
                    -1j * np.sqrt(np.maximum(sin_t2 - 1.0, 0.0)))


def amplitude_coefficients(cos_i: np.ndarray, n1: float, n2: float) -> tuple[np.ndarray, ...]:
    """``(r_s, r_p, t_s, t_p)``: the Fresnel amplitude coefficients (field ratios, complex)."""
    _require_indices(n1, n2)
    cos_i = np.asarray(cos_i, dtype=np.float64)
    cos_t = cos_transmitted(cos_i, n1, n2)
    s_den = n1 * cos_i + n2 * cos_t
    p_den = n2 * cos_i + n1 * cos_t
    return ((n1 * cos_i - n2 * cos_t) / s_den, (n2 * cos_i - n1 * cos_t) / p_den,
            2.0 * n1 * cos_i / s_den, 2.0 * n1 * cos_i / p_den)


def flux_coefficients(cos_i: np.ndarray, n1: float, n2: float) -> tuple[np.ndarray, ...]:
    """``(r_s, r_p, tau_s, tau_p)``: reflection as :func:`amplitude_coefficients`, transmission scaled so that
    its squared magnitude is the transmitted share of the power (zero beyond the critical angle)."""
    r_s, r_p, t_s, t_p = amplitude_coefficients(cos_i, n1, n2)
    cos_i = np.asarray(cos_i, dtype=np.float64)
    ratio = n2 * np.real(cos_transmitted(cos_i, n1, n2)) / (n1 * np.maximum(cos_i, 1e-300))
    scale = np.sqrt(np.where(cos_i > 0, ratio, 0.0))
    return r_s, r_p, t_s * scale, t_p * scale


def transmitted_flux_amplitudes(cos_i: Array, ratio: Array) -> tuple[Array, Array]:
    """``(tau_s, tau_p)`` of :func:`flux_coefficients` (real) for incidence ``cos_i`` and ``ratio = n2 / n1``, on
    NumPy or Dr.Jit; zero beyond the critical angle."""
    xp = ops(cos_i, ratio)
    sin_t2 = (1.0 - cos_i * cos_i) / (ratio * ratio)
    cos_t = xp.sqrt(xp.maximum(1.0 - sin_t2, 0.0))
    s_den = cos_i + ratio * cos_t
    p_den = ratio * cos_i + cos_t
    # t_s = 2 cos_i / s_den and t_p = 2 cos_i / p_den (n1 = 1), times sqrt(ratio cos_t / cos_i).
    flux = 2.0 * xp.sqrt(xp.maximum(ratio * cos_t * cos_i, 0.0))
    return flux / s_den, flux / p_den


def reflected_amplitudes(cos_i: Array, ratio: Array) -> tuple[Array, Array]:
    """``(r_s, r_p)`` of :func:`amplitude_coefficients` (real) for incidence ``cos_i`` and ``ratio = n2 / n1``
    below the critical angle, on NumPy or Dr.Jit (beyond it: :func:`reflection_phases`)."""
    xp = ops(cos_i, ratio)
    cos_t = xp.sqrt(xp.maximum(1.0 - (1.0 - cos_i * cos_i) / (ratio * ratio), 0.0))
    return ((cos_i - ratio * cos_t) / (cos_i + ratio * cos_t),
            (ratio * cos_i - cos_t) / (ratio * cos_i + cos_t))


def reflection_phases(cos_i: Array, ratio: Array) -> tuple[Array, Array]:
    """Phases ``(phi_s, phi_p)`` of ``r_s``, ``r_p`` beyond the critical angle (``ratio = n2 / n1 < 1``), on
    NumPy or Dr.Jit: :func:`total_reflection_phases`."""
    xp = ops(cos_i, ratio)
    root = xp.sqrt(xp.maximum(1.0 - cos_i * cos_i - ratio * ratio, 0.0))
    return 2.0 * xp.atan2(root, cos_i), 2.0 * xp.atan2(root, ratio * ratio * cos_i)


def brewster_angle(n1: float, n2: float) -> float:
    """Incidence angle (radians) at which p light is transmitted whole."""
    _require_indices(n1, n2)
    return float(np.arctan2(n2, n1))


def critical_angle(n1: float, n2: float) -> float | None:
    """Incidence angle (radians) beyond which light is totally reflected (None where ``n1 <= n2``)."""
    _require_indices(n1, n2)
    return float(np.arcsin(n2 / n1)) if n1 > n2 else None


def total_reflection_phases(cos_i: np.ndarray, n1: float, n2: float) -> tuple[np.ndarray, np.ndarray]:
    """Phases ``(phi_s, phi_p)`` (radians) of ``r_s`` and ``r_p`` beyond the critical angle, in closed form."""
    cos_i = np.asarray(cos_i, dtype=np.float64)
    n = n2 / n1
    root = np.sqrt(np.maximum(1.0 - cos_i ** 2 - n ** 2, 0.0))
    # r_s = (cos_i + i root) / (cos_i - i root) and r_p = (n^2 cos_i + i root) / (n^2 cos_i - i root) under
    # exp(+i omega t): each twice the argument of its numerator.
    return 2.0 * np.arctan2(root, cos_i), 2.0 * np.arctan2(root, n ** 2 * cos_i)


def refract(d: Vector, normal: Vector, n1: Array, n2: Array) -> tuple[tuple[Array, Array, Array], Array, Array]:
    """``(direction, cos_i, total)``: the refracted unit direction of ``d`` crossing a surface of ``normal``
    (either side) from index ``n1`` into ``n2``; where ``total`` (beyond the critical angle) the direction is
    the reflected one."""
    xp = ops(*d, *normal, n1, n2)
    facing = dot(d, normal)
    # The normal on the side the ray comes from, and the cosine of incidence.
    sign = xp.select(facing > 0, -1.0, 1.0)
    n = tuple(sign * x for x in normal)
    cos_i = -dot(d, n)
    eta = n1 / n2
    sin_t2 = eta * eta * (1.0 - cos_i * cos_i)
    total = sin_t2 > 1.0
    cos_t = xp.sqrt(xp.maximum(1.0 - sin_t2, 0.0))
    refracted = tuple(eta * di + (eta * cos_i - cos_t) * ni for di, ni in zip(d, n))
    reflected = reflect(d, normal)
    direction = tuple(xp.select(total, r, t) for r, t in zip(reflected, refracted))
    return normalize(direction), cos_i, total


def reflect(d: Vector, normal: Vector) -> tuple[Array, Array, Array]:
    """The mirror direction of ``d`` at a surface of ``normal`` (either side)."""
    along = dot(d, normal)
    return tuple(di - 2.0 * along * ni for di, ni in zip(d, normal))


def s_axis(d: Vector, normal: Vector, u: Vector) -> tuple[Array, Array, Array]:
    """``unit(d x normal)``, perpendicular to the plane of incidence; at normal incidence, where the plane is
    undefined, ``u`` (any axis will do: both coefficients are then equal)."""
    xp = ops(*d, *normal, *u)
    axis = cross(d, normal)
    length2 = dot(axis, axis)
    oblique = length2 > 1e-14
    safe = xp.rsqrt(xp.maximum(length2, 1e-30))
    return tuple(xp.select(oblique, a * safe, ui) for a, ui in zip(axis, u))


def transported(vector: Vector, d_in: Vector, d_out: Vector, s: Vector) -> tuple[Array, Array, Array]:
    """A transverse ``vector`` of the incident ray carried onto the outgoing one: its components on ``s`` and
    on ``p = d x s`` kept."""
    p_in, p_out = cross(d_in, s), cross(d_out, s)
    on_s, on_p = dot(vector, s), dot(vector, p_in)
    return tuple(on_s * si + on_p * po for si, po in zip(s, p_out))


def s_angle(u: Vector, v: Vector, s: Vector) -> Array:
    """The angle (radians) of ``s`` in the transverse frame ``(u, v)``, from u towards v."""
    return ops(*u, *v, *s).atan2(dot(s, v), dot(s, u))


def _require_indices(n1, n2):
    for name, value in (("n1", n1), ("n2", n2)):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"refractive index {name} must be a positive number, got {value}")
