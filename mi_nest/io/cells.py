"""Cells of volume meshes as index arrays: tetrahedra, their volumes, values moved from cells to nodes.

Below both the file readers (3D-TSV files give stress per element, made nodal
here) and the mesh stress field (``mi_nest.fields.mesh``).
"""
from __future__ import annotations

import numpy as np


class MeshError(ValueError):
    """A mesh or its stress data is inconsistent."""


# A positively oriented hexahedron (VTK / 3D-TSV order: bottom quad 0-3, top quad
# 4-7) cut into six tetrahedra around its diagonal 0-6.
HEX_TO_TETS = np.array([[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]])


def as_tets(cells: np.ndarray) -> np.ndarray:
    """Cells as tetrahedra: hexahedra (M, 8) cut into six each, tetrahedra (M, 4) as they are."""
    return cells[:, HEX_TO_TETS].reshape(-1, 4) if cells.shape[1] == 8 else cells


def signed_volumes(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Six times the signed volume of each tetrahedron."""
    corners = nodes[tets]
    return np.einsum("ij,ij->i", np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]),
                     corners[:, 3] - corners[:, 0])


def nodal_average(nodes: np.ndarray, cells: np.ndarray, cell_values: np.ndarray) -> np.ndarray:
    """Values given per cell (M, C) averaged at the nodes, each cell weighted by its volume.

    What element-wise FEM stress becomes on a mesh that interpolates nodal
    values: a field that is uniform over the cells stays exactly uniform, and
    per-cell samples of a linear field give it back exactly at nodes whose cells
    sit symmetrically around them. Nodes of no cell get zeros (no cell uses them).
    """
    nodes = np.asarray(nodes, dtype=np.float64)
    cells = np.asarray(cells, dtype=np.int64)
    tets = as_tets(cells)
    volume = np.abs(signed_volumes(nodes, tets)).reshape(len(cells), -1).sum(axis=1)
    degenerate = volume <= 1e-12 * np.ptp(nodes, axis=0).max() ** 3
    if np.any(degenerate):
        raise MeshError(f"{int(np.sum(degenerate))} degenerate (zero-volume) cells, first cell "
                        f"{int(np.argmax(degenerate))}: their stress cannot be weighted")
    weighted = np.zeros((len(nodes), cell_values.shape[1]))
    weight = np.zeros(len(nodes))
    for corner in cells.T:
        np.add.at(weighted, corner, volume[:, None] * cell_values)
        np.add.at(weight, corner, volume)
    return weighted / np.maximum(weight, np.finfo(float).tiny)[:, None]


def fill_from_nearest(values: np.ndarray, known: np.ndarray) -> np.ndarray:
    """``values`` (Z, Y, X, C) with every node outside ``known`` copied from the nearest known node.

    A Euclidean distance transform on the grid itself: iterative C code, so it
    also runs on the small stacks of Mitsuba's scene-loading worker threads
    (a k-d tree query there has crashed the process).
    """
    if known.all():
        return values
    if not known.any():
        raise MeshError("no grid node lies inside the mesh: the grid is too coarse for it")
    from scipy.ndimage import distance_transform_edt
    nearest = distance_transform_edt(~known, return_distances=False, return_indices=True)
    return values[tuple(nearest)]
