"""Stress grids on disk: ``.npz`` with ``stress`` (Z, Y, X, 6) in MPa, ``bbox_min``/``bbox_max`` in mm.

Components follow 3D-TSV order (xx, yy, zz, yz, zx, xy). Samples sit on the grid
nodes: node (0, 0, 0) at ``bbox_min``, the last node at ``bbox_max``.
"""
from __future__ import annotations

import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .atomic import atomic_path


class GridFileError(ValueError):
    """A stress grid file is missing, unreadable or inconsistent."""


@dataclass(frozen=True)
class StressGrid:
    stress: np.ndarray      # (Z, Y, X, 6) float32, MPa
    bbox_min: np.ndarray    # (3,) mm
    bbox_max: np.ndarray    # (3,) mm

    def __post_init__(self):
        validate_grid(self.stress, self.bbox_min, self.bbox_max, source="stress grid")


def validate_grid(stress: np.ndarray, bbox_min: np.ndarray, bbox_max: np.ndarray, source: str) -> None:
    stress = np.asarray(stress)
    if stress.ndim != 4 or stress.shape[-1] != 6:
        raise GridFileError(f"{source}: array 'stress' must have shape (Z, Y, X, 6), got {stress.shape}")
    if min(stress.shape[:3]) < 2:
        raise GridFileError(f"{source}: the grid needs at least 2 nodes per axis, got {stress.shape[:3]}")
    if not np.all(np.isfinite(stress)):
        bad = np.argwhere(~np.isfinite(stress))[0]
        raise GridFileError(f"{source}: 'stress' holds NaN or inf (first at index {tuple(int(i) for i in bad)})")
    for name, box in (("bbox_min", bbox_min), ("bbox_max", bbox_max)):
        box = np.asarray(box)
        if box.shape != (3,) or not np.all(np.isfinite(box)):
            raise GridFileError(f"{source}: '{name}' must be 3 finite numbers, got {box!r}")
    if not np.all(np.asarray(bbox_max) > np.asarray(bbox_min)):
        raise GridFileError(f"{source}: bbox_max {bbox_max} must exceed bbox_min {bbox_min} on every axis")


def load_stress_grid(path: str | Path) -> StressGrid:
    path = Path(path)
    if not path.is_file():
        raise GridFileError(f"stress grid file not found: {path}")
    try:
        with np.load(path) as data:
            missing = {"stress", "bbox_min", "bbox_max"} - set(data.files)
            if missing:
                raise GridFileError(f"{path}: missing array(s) {sorted(missing)}; "
                                    "expected 'stress' (Z, Y, X, 6), 'bbox_min', 'bbox_max'")
            stress, bbox_min, bbox_max = data["stress"], data["bbox_min"], data["bbox_max"]
    except (OSError, ValueError, zipfile.BadZipFile) as error:
        if isinstance(error, GridFileError):
            raise
        raise GridFileError(f"{path}: not a readable .npz stress grid ({error})") from error
    validate_grid(stress, bbox_min, bbox_max, source=str(path))
    return StressGrid(stress.astype(np.float32), bbox_min.astype(np.float64), bbox_max.astype(np.float64))


def save_stress_grid(path: str | Path, grid: StressGrid) -> None:
    """Write atomically (temp file + rename) so a crash never leaves half a grid."""
    with atomic_path(path, ".npz") as tmp:
        np.savez_compressed(tmp, stress=grid.stress, bbox_min=grid.bbox_min, bbox_max=grid.bbox_max)


def grid_nodes(bbox_min: np.ndarray, bbox_max: np.ndarray, counts: Sequence[int]) -> np.ndarray:
    """``(nz * ny * nx, 3)`` positions of the nodes of a grid with ``counts = (nx, ny, nz)`` nodes spanning
    the box, in the (z, y, x) order of a stress array."""
    axes = [np.linspace(bbox_min[i], bbox_max[i], int(counts[i])) for i in range(3)]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    return np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)


def grid_cells(grid: StressGrid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(nodes, hexahedra, stress)`` of a grid as a mesh: its nodes (:func:`grid_nodes`), the ``(M, 8)``
    hexahedra between them in VTK order, and the ``(N, 6)`` stress at the nodes."""
    nz, ny, nx = grid.stress.shape[:3]
    index = np.arange(nx * ny * nz).reshape(nz, ny, nx)
    corner = index[:-1, :-1, :-1].ravel()
    dx, dy, dz = 1, nx, nx * ny
    cells = np.stack([corner, corner + dx, corner + dx + dy, corner + dy,
                      corner + dz, corner + dz + dx, corner + dz + dx + dy, corner + dz + dy], axis=1)
    return grid_nodes(grid.bbox_min, grid.bbox_max, (nx, ny, nz)), cells, grid.stress.reshape(-1, 6)
