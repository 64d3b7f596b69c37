"""Stress tensors and 3-vectors: the one home of their algebra.

Stress tensors travel as 6-tuples in 3D-TSV order ``(xx, yy, zz, yz, zx, xy)``,
vectors as 3-sequences of components; the tuple forms run on NumPy and Dr.Jit
arrays alike. Batches of tensors on NumPy are ``(..., 6)`` arrays in the same
order.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .backend import Array, ops

COMPONENTS = ("xx", "yy", "zz", "yz", "zx", "xy")

# A 3-vector (a Dr.Jit ``Vector3f`` or 3 arrays) and a stress tensor as its 6 components.
Vector = Sequence[Array]
Tensor = tuple[Array, Array, Array, Array, Array, Array]


def dot(a: Vector, b: Vector) -> Array:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a: Vector, b: Vector) -> tuple[Array, Array, Array]:
    return (a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0])


def normalize(a: Vector) -> tuple[Array, ...]:
    xp = ops(*a)
    inv = 1.0 / xp.sqrt(dot(a, a))
    return tuple(x * inv for x in a)


def symmetric_outer(scale: Array, a: Vector, b: Vector) -> Tensor:
    """6-tuple of ``scale * (a b^T + b a^T) / 2``."""
    return (scale * a[0] * b[0], scale * a[1] * b[1], scale * a[2] * b[2],
            0.5 * scale * (a[1] * b[2] + a[2] * b[1]),
            0.5 * scale * (a[2] * b[0] + a[0] * b[2]),
            0.5 * scale * (a[0] * b[1] + a[1] * b[0]))


def add(*tensors: Tensor) -> Tensor:
    return tuple(sum(parts) for parts in zip(*tensors))


def stress_matrices(stress6: np.ndarray) -> np.ndarray:
    """``(..., 6)`` tensors -> ``(..., 3, 3)`` symmetric matrices."""
    xx, yy, zz, yz, zx, xy = np.moveaxis(np.asarray(stress6, dtype=np.float64), -1, 0)
    return np.stack([np.stack([xx, xy, zx], -1), np.stack([xy, yy, yz], -1), np.stack([zx, yz, zz], -1)], -2)


def principal_stresses(stress6: np.ndarray) -> np.ndarray:
    """``(..., 3)`` principal stresses of ``(..., 6)`` tensors, largest first."""
    return np.linalg.eigvalsh(stress_matrices(stress6))[..., ::-1]


def principal_axes(stress6: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(values, directions)`` of ``(..., 6)`` tensors: the principal stresses ``(..., 3)``, largest first, and
    their unit directions ``(..., 3, 3)``, ``directions[..., k, :]`` along ``values[..., k]``.

    A direction is a line, not an arrow: each is signed so that its largest
    component is positive, which is the same choice wherever the axes turn
    little (a stream tracer still meets flips where they turn past 45 degrees).
    Where two principal stresses are equal their directions are any orthonormal
    pair of that plane.
    """
    values, vectors = np.linalg.eigh(stress_matrices(stress6))
    values, directions = values[..., ::-1], np.swapaxes(vectors[..., ::-1], -1, -2)
    largest = np.take_along_axis(directions, np.abs(directions).argmax(axis=-1)[..., None], axis=-1)
    return values, directions * np.where(largest < 0, -1.0, 1.0)


def principal_difference(stress6: np.ndarray) -> np.ndarray:
    """``sigma_max - sigma_min`` of ``(..., 6)`` tensors: the 3D principal stress difference."""
    principal = principal_stresses(stress6)
    return principal[..., 0] - principal[..., 2]


def von_mises(stress6: np.ndarray) -> np.ndarray:
    """The von Mises stress of ``(..., 6)`` tensors."""
    xx, yy, zz, yz, zx, xy = np.moveaxis(np.asarray(stress6, dtype=np.float64), -1, 0)
    return np.sqrt(0.5 * ((xx - yy) ** 2 + (yy - zz) ** 2 + (zz - xx) ** 2) + 3.0 * (xy ** 2 + yz ** 2 + zx ** 2))


def deviatoric_part(stress: np.ndarray) -> np.ndarray:
    """Deviatoric part of ``(..., 6)`` stress arrays in 3D-TSV order (NumPy)."""
    stress = np.asarray(stress, dtype=np.float64)
    mean = stress[..., :3].sum(axis=-1, keepdims=True) / 3.0
    return np.concatenate([stress[..., :3] - mean, stress[..., 3:]], axis=-1)


def tensor_norm(s6: np.ndarray) -> np.ndarray:
    """Frobenius norm of symmetric tensors in 6-vector form (shear components count twice)."""
    return np.sqrt((s6[..., :3] ** 2).sum(-1) + 2.0 * (s6[..., 3:] ** 2).sum(-1))
