"""Per-pixel Jones recovery: the unit quaternion behind the 16 polariscope intensities (NumPy).

Every intensity is a quadratic form in ``q`` (polariscope.py), and on unit
quaternions the quadratic forms are spanned by the constant and the nine
entries of the rotation ``R(q)`` that ``q`` induces on the Poincare sphere:
each measurement is affine in ``R``. The rig has two input states (circular
and linear), so the 16 measurements fix ``R`` on the plane those two Stokes
vectors span; the rotation closest to that partial map (Procrustes) is ``R``,
and ``R`` gives ``q`` up to its sign, which no intensity can see.
This is the first step of the Two-step baseline (then per-view unwrapping and
linear tomography, ``mi_nest.reconstruct.two_step``).
"""
from __future__ import annotations

from functools import lru_cache
from typing import Iterable

import numpy as np

from .polariscope import MEASUREMENTS, Polariscope


def rotation_matrix(q: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` rotation of the unit quaternion ``q = (a, b, c, d)`` (last axis of size 4)."""
    a, b, c, d = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (c * c + d * d), 2 * (b * c - d * a), 2 * (b * d + c * a)], axis=-1),
        np.stack([2 * (b * c + d * a), 1 - 2 * (b * b + d * d), 2 * (c * d - b * a)], axis=-1),
        np.stack([2 * (b * d - c * a), 2 * (c * d + b * a), 1 - 2 * (b * b + c * c)], axis=-1),
    ], axis=-2)


def quaternion_from_rotation(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rotation_matrix` with ``a >= 0`` (Shepperd's method: the largest pivot)."""
    R = np.asarray(R, dtype=np.float64)
    trace = R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2]
    pivots = np.stack([trace, R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]], axis=-1)
    pivot = np.argmax(pivots, axis=-1)
    q = np.empty(R.shape[:-2] + (4,))
    rows = [
        (1 + trace, R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]),
        (R[..., 2, 1] - R[..., 1, 2], 1 + 2 * R[..., 0, 0] - trace, R[..., 0, 1] + R[..., 1, 0],
         R[..., 0, 2] + R[..., 2, 0]),
        (R[..., 0, 2] - R[..., 2, 0], R[..., 0, 1] + R[..., 1, 0], 1 + 2 * R[..., 1, 1] - trace,
         R[..., 1, 2] + R[..., 2, 1]),
        (R[..., 1, 0] - R[..., 0, 1], R[..., 0, 2] + R[..., 2, 0], R[..., 1, 2] + R[..., 2, 1],
         1 + 2 * R[..., 2, 2] - trace),
    ]
    for k, row in enumerate(rows):
        chosen = pivot == k
        q[chosen] = np.stack([x[chosen] for x in row], axis=-1)
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return q * np.where(q[..., :1] < 0, -1.0, 1.0)


@lru_cache(maxsize=8)
def _affine_model(polariscopes):
    """``(offset (N,), A (N, 9))`` with ``I_k(q) = offset_k + A_k . vec(R(q))`` for unit ``q``.

    Fitted exactly on random unit quaternions: the constant and R's entries
    span the quadratic forms there, so the residual is round-off.
    """
    rng = np.random.default_rng(0)
    q = rng.normal(size=(64, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    design = np.concatenate([np.ones((len(q), 1)), rotation_matrix(q).reshape(-1, 9)], axis=-1)
    values = np.stack([scope.intensity(tuple(q.T)) for scope in polariscopes], axis=-1)
    solution, *_ = np.linalg.lstsq(design, values, rcond=None)
    residual = np.abs(design @ solution - values).max()
    if residual > 1e-9:
        raise RuntimeError(f"polariscope intensities are not affine in R(q) (residual {residual:.2e})")
    return solution[0], solution[1:].T


def quaternion_from_intensities(values: np.ndarray,
                                polariscopes: Iterable[Polariscope] = tuple(MEASUREMENTS.values())) -> np.ndarray:
    """The Jones quaternion (``a >= 0``) behind intensities ``(..., N)`` measured with ``polariscopes``.

    Least squares: exact for noiseless data, the closest rotation otherwise.
    The settings must fix the rotation on a plane of input states (rank 6 of
    the affine model), as the rig's 16 do, calibrated or nominal.
    """
    return jones_and_polarisation(values, polariscopes)[0]


@lru_cache(maxsize=8)
def _input_plane(polariscopes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(pinv(A), a, b)``: the affine model's pseudo-inverse and an orthonormal basis of the plane of input
    Stokes vectors on which the measurements fix ``R``.

    The measurements see ``R`` only through ``R a`` and ``R b``: the least-norm ``vec(R)`` they give is ``R P``,
    with ``P`` the plane's projector, which the model's own projector ``pinv(A) A`` holds on each row's block.
    """
    offset, A = _affine_model(polariscopes)
    rank = np.linalg.matrix_rank(A, tol=1e-9)
    if rank < 6:
        raise ValueError(f"these {len(polariscopes)} polariscope settings do not determine the Jones matrix (rank "
                         f"{rank} of the 6 needed: two input states, each analysed in three independent ways)")
    inverse = np.linalg.pinv(A, rcond=1e-9)
    plane = (inverse @ A)[:3, :3]
    _, vectors = np.linalg.eigh((plane + plane.T) / 2)     # eigenvalues 0, 1, 1
    return inverse, vectors[:, 2], vectors[:, 1]


def jones_and_polarisation(values: np.ndarray,
                           polariscopes: Iterable[Polariscope] = tuple(MEASUREMENTS.values())
                           ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`quaternion_from_intensities` and how much of the light the pixel kept polarised, ``(...)``: the
    smaller singular value of the map the measurements fix on the plane of input states, 1 for one Jones matrix
    and less where the rays a pixel averages saw different ones (fringes denser than the pixels) or noise.

    The rotation closest to that map (orthogonal Procrustes) in closed form: the images ``u, v`` of the plane's
    basis ``a, b`` are made orthonormal by the inverse square root of their 2 x 2 Gram matrix (the polar factor of
    ``[u v]``), and ``a x b`` goes to their cross product; no SVD per pixel (80 to 130 times faster than one, side by side on
    an AMD EPYC Zen 4, the same rotations to 1e-13: ``tests/test_two_step.py``).
    """
    polariscopes = tuple(polariscopes)
    values = np.asarray(values, dtype=np.float64)
    if values.shape[-1] != len(polariscopes):
        raise ValueError(f"the last axis holds {values.shape[-1]} intensities for {len(polariscopes)} polariscopes")
    offset, _ = _affine_model(polariscopes)
    inverse, a, b = _input_plane(polariscopes)
    partial = ((values - offset) @ inverse.T).reshape(values.shape[:-1] + (3, 3))
    u, v = partial @ a, partial @ b
    uu, uv, vv = (u * u).sum(-1), (u * v).sum(-1), (v * v).sum(-1)
    trace, determinant = uu + vv, np.maximum(uu * vv - uv * uv, 1e-30)
    # sqrt(G) = (G + r I) / sqrt(tr G + 2 r), r = sqrt(det G), for a symmetric positive 2 x 2 G; its inverse is
    # sqrt(tr G + 2 r) adj(G + r I) / (r (tr G + 2 r)).
    root = np.sqrt(determinant)
    factor = np.sqrt(trace + 2 * root) / (root * (trace + 2 * root))
    g11, g12, g22 = (vv + root) * factor, -uv * factor, (uu + root) * factor
    first = u * g11[..., None] + v * g12[..., None]
    second = u * g12[..., None] + v * g22[..., None]
    third = np.cross(first, second)
    rotation = (first[..., :, None] * a + second[..., :, None] * b + third[..., :, None] * np.cross(a, b))
    # tr^2 / 4 - det as a sum of squares: the difference cancels to rounding where G is isotropic (one Jones
    # matrix), and the root of that rounding would be ~1e-8 off.
    spread = np.sqrt(((uu - vv) / 2) ** 2 + uv * uv)
    smaller = trace / 2 - spread
    return quaternion_from_rotation(rotation), np.sqrt(np.maximum(smaller, 0.0))
