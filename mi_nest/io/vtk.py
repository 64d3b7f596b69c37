"""Stress fields as VTK unstructured grids (``.vtu`` via meshio) for ParaView.

Point data: ``stress`` (the full tensor, 9 components, row-major), the principal
stresses ``sigma_1 >= sigma_2 >= sigma_3``, their difference ``sigma_1 - sigma_3``
and the von Mises stress.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .grid import grid_nodes


def stress_matrices(stress6):
    """(N, 6) in 3D-TSV order (xx yy zz yz zx xy) -> (N, 3, 3) symmetric tensors."""
    xx, yy, zz, yz, zx, xy = np.asarray(stress6, dtype=np.float64).T
    return np.stack([np.stack([xx, xy, zx], -1), np.stack([xy, yy, yz], -1), np.stack([zx, yz, zz], -1)], -2)


def principal_stresses(stress6):
    """(N, 3) principal stresses, largest first."""
    return np.linalg.eigvalsh(stress_matrices(stress6))[:, ::-1]


def von_mises(stress6):
    xx, yy, zz, yz, zx, xy = np.asarray(stress6, dtype=np.float64).T
    return np.sqrt(0.5 * ((xx - yy) ** 2 + (yy - zz) ** 2 + (zz - xx) ** 2) + 3.0 * (xy ** 2 + yz ** 2 + zx ** 2))


def point_data(stress6):
    principal = principal_stresses(stress6)
    return {"stress": stress_matrices(stress6).reshape(-1, 9), "sigma_1": principal[:, 0],
            "sigma_2": principal[:, 1], "sigma_3": principal[:, 2],
            "sigma_1_minus_sigma_3": principal[:, 0] - principal[:, 2], "von_mises": von_mises(stress6)}


def write_mesh_vtu(path, nodes, cells, stress6):
    """Tetrahedra (M, 4) or hexahedra (M, 8), VTK node order."""
    import meshio
    cells = np.asarray(cells)
    kind = {4: "tetra", 8: "hexahedron"}[cells.shape[1]]
    meshio.Mesh(np.asarray(nodes, np.float64), [(kind, cells)], point_data=point_data(stress6)).write(
        str(Path(path)))


def write_grid_vtu(path, grid):
    """A :class:`~mi_nest.io.grid.StressGrid` as hexahedral cells between its nodes."""
    nz, ny, nx = grid.stress.shape[:3]
    nodes = grid_nodes(grid.bbox_min, grid.bbox_max, (nx, ny, nz))
    index = np.arange(nx * ny * nz).reshape(nz, ny, nx)
    corner = index[:-1, :-1, :-1].ravel()
    dx, dy, dz = 1, nx, nx * ny
    cells = np.stack([corner, corner + dx, corner + dx + dy, corner + dy,
                      corner + dz, corner + dz + dx, corner + dz + dx + dy, corner + dz + dy], axis=1)
    write_mesh_vtu(path, nodes, cells, grid.stress.reshape(-1, 6))
