"""Stress given at the nodes of a tetrahedral mesh: FEM results and 3D-TSV imports.

Within each tetrahedron the stress is the barycentric (linear) interpolation of
its four nodal tensors. For rendering, :meth:`TetMeshStress.to_grid` resamples
that interpolation onto a regular grid for :class:`~mi_nest.fields.grid.GridField`
(trilinear texture lookups are what a ray march can afford per step); grid
nodes outside the mesh take the value of the nearest grid node inside it, so
that interpolation at the boundary does not blend in zeros.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..io.cells import MeshError, as_tets, fill_from_nearest, signed_volumes
from ..io.grid import StressGrid, grid_nodes
from ..io.tsv import BoundaryConditions, TsvModel
from .base import FieldParameterError

_TET_FACES = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
_HEX_FACES = np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])


@dataclass(frozen=True)
class TetMeshStress:
    """Nodal stress (MPa, 3D-TSV order xx yy zz yz zx xy) on a tetrahedral mesh (mm).

    ``surface`` holds the boundary as outward-oriented triangles over ``nodes``;
    for meshes made of other cells it is the boundary of those cells.
    ``boundary`` holds the node forces and fixed nodes of the FEM run behind the
    stress when the file carried them (3D-TSV files do), else None.
    """
    nodes: np.ndarray      # (N, 3) float64
    tets: np.ndarray       # (M, 4) int64, 0-based
    stress: np.ndarray     # (N, 6) float32
    surface: np.ndarray    # (F, 3) int64, outward
    boundary: BoundaryConditions | None = None

    @classmethod
    def from_cells(cls, nodes: np.ndarray, cells: np.ndarray, stress: np.ndarray,
                   boundary: BoundaryConditions | None = None) -> TetMeshStress:
        """Build from tetrahedra (M, 4) or hexahedra (M, 8), validating everything."""
        nodes = np.asarray(nodes, dtype=np.float64)
        cells = _node_indices(cells)
        stress = np.asarray(stress, dtype=np.float32)
        if nodes.ndim != 2 or nodes.shape[1] != 3 or len(nodes) < 4:
            raise MeshError(f"nodes must have shape (N >= 4, 3), got {nodes.shape}")
        if cells.ndim != 2 or cells.shape[1] not in (4, 8) or len(cells) == 0:
            raise MeshError(f"cells must be tetrahedra (M, 4) or hexahedra (M, 8), got {cells.shape}")
        if stress.shape != (len(nodes), 6):
            raise MeshError(f"stress must have shape ({len(nodes)}, 6) (one tensor per node), "
                            f"got {stress.shape}")
        if cells.min() < 0 or cells.max() >= len(nodes):
            raise MeshError(f"cell node indices must lie in [0, {len(nodes) - 1}], "
                            f"got [{cells.min()}, {cells.max()}]")
        for name, values in (("nodes", nodes), ("stress", stress)):
            if not np.all(np.isfinite(values)):
                row = int(np.argwhere(~np.isfinite(values))[0][0])
                raise MeshError(f"{name} holds NaN or inf (first at node {row})")
        if boundary is not None:
            try:
                boundary.check_nodes(len(nodes))
            except ValueError as error:
                raise MeshError(f"boundary conditions: {error}") from None
        faces = _HEX_FACES if cells.shape[1] == 8 else _TET_FACES
        tets = _positively_oriented(nodes, as_tets(cells))
        return cls(nodes, tets, stress, _boundary(nodes, cells, faces), boundary)

    @classmethod
    def from_model(cls, model: TsvModel) -> TetMeshStress:
        """The mesh of a 3D-TSV model (``mi_nest.io.tsv``), with its boundary conditions."""
        return cls.from_cells(model.vertices, model.elements, model.stress, boundary=model.boundary_conditions())

    @property
    def bbox(self) -> tuple[np.ndarray, np.ndarray]:
        return self.nodes.min(axis=0), self.nodes.max(axis=0)

    def locate(self, points: np.ndarray, chunk: int = 200_000) -> tuple[np.ndarray, np.ndarray]:
        """Containing tetrahedron and barycentric weights of each point (-1 where outside)."""
        points = np.asarray(points, dtype=np.float64)
        corners = self.nodes[self.tets]                                # (M, 4, 3)
        inverse = np.linalg.inv(np.transpose(corners[:, 1:] - corners[:, :1], (0, 2, 1)))
        lo, hi = corners.min(axis=1), corners.max(axis=1)
        cell = np.full(len(points), -1, dtype=np.int64)
        weights = np.zeros((len(points), 4))
        # Bin points on a grid of a typical tetrahedron's size so each tetrahedron tests
        # only the points of the few bins its bounding box overlaps.
        size = np.percentile(hi - lo, 90, axis=0) + 1e-12
        origin = points.min(axis=0) if len(points) else np.zeros(3)
        keys = np.floor((points - origin) / size).astype(np.int64)
        shape = keys.max(axis=0) + 1 if len(points) else np.ones(3, np.int64)
        flat = np.ravel_multi_index(keys.T, shape) if len(points) else np.zeros(0, np.int64)
        order = np.argsort(flat, kind="stable")
        starts = np.searchsorted(flat[order], np.arange(np.prod(shape) + 1))
        first = np.clip(np.floor((lo - origin) / size).astype(np.int64), 0, shape - 1)
        last = np.clip(np.floor((hi - origin) / size).astype(np.int64), 0, shape - 1)
        pairs_tet, pairs_point = [], []
        for offset in np.ndindex(*(last - first + 1).max(axis=0)):
            bins = first + np.array(offset)
            valid = np.all(bins <= last, axis=1)
            tet_ids = np.nonzero(valid)[0]
            key = np.ravel_multi_index(bins[valid].T, shape)
            counts = starts[key + 1] - starts[key]
            pairs_tet.append(np.repeat(tet_ids, counts))
            base = np.repeat(starts[key] - np.cumsum(counts) + counts, counts)
            pairs_point.append(order[base + np.arange(counts.sum())])
        pair_tet, pair_point = np.concatenate(pairs_tet), np.concatenate(pairs_point)
        for begin in range(0, len(pair_tet), chunk):
            t, p = pair_tet[begin:begin + chunk], pair_point[begin:begin + chunk]
            lam = np.einsum("nij,nj->ni", inverse[t], points[p] - corners[t, 0])
            bary = np.concatenate([1.0 - lam.sum(axis=1, keepdims=True), lam], axis=1)
            inside = np.all(bary >= -1e-9, axis=1)
            cell[p[inside]] = t[inside]
            weights[p[inside]] = bary[inside]
        return cell, weights

    def sample(self, points: np.ndarray) -> np.ndarray:
        """Barycentric interpolation at ``points`` (K, 3); NaN outside the mesh."""
        cell, weights = self.locate(points)
        values = np.einsum("nk,nkc->nc", weights, self.stress[self.tets[np.maximum(cell, 0)]])
        values[cell < 0] = np.nan
        return values

    def to_grid(self, resolution: int = 64, padding: float = 0.02) -> StressGrid:
        """Resample onto a nodal grid with ``resolution`` nodes along the longest axis."""
        if int(resolution) < 2:
            raise FieldParameterError(f"grid resolution must be at least 2, got {resolution}")
        lo, hi = self.bbox
        pad = padding * (hi - lo).max()
        lo, hi = lo - pad, hi + pad
        spacing = (hi - lo).max() / (int(resolution) - 1)
        counts = np.maximum(np.ceil((hi - lo) / spacing).astype(int) + 1, 2)
        hi = lo + (counts - 1) * spacing
        values = self.sample(grid_nodes(lo, hi, counts)).reshape(counts[2], counts[1], counts[0], 6)
        stress = fill_from_nearest(values, ~np.isnan(values[..., 0])).astype(np.float32)
        return StressGrid(stress, lo, hi)


def _node_indices(cells):
    """``cells`` as int64 node indices. Floats must hold whole numbers: cast, 3.7 would become node 3."""
    cells = np.asarray(cells)
    if cells.dtype.kind in "iu":
        return cells.astype(np.int64)
    if cells.dtype.kind != "f":
        raise MeshError(f"cell node indices must be integers, got {cells.dtype} values")
    fractional = ~(np.isfinite(cells) & (cells == np.round(cells)))
    if np.any(fractional):
        cell = int(np.argwhere(fractional)[0][0])
        raise MeshError(f"cell node indices must be whole numbers, got {cells[cell].tolist()} in cell {cell}; "
                        "store the cells as integers")
    return cells.astype(np.int64)


def _positively_oriented(nodes, tets):
    volume = signed_volumes(nodes, tets)
    extent = np.ptp(nodes, axis=0).max()
    degenerate = np.abs(volume) <= 1e-12 * extent ** 3
    if np.any(degenerate):
        raise MeshError(f"{int(np.sum(degenerate))} degenerate (zero-volume) tetrahedra")
    flipped = tets.copy()
    flipped[volume < 0] = flipped[volume < 0][:, [0, 2, 1, 3]]
    return flipped


def _boundary(nodes, cells, faces):
    """Faces used by exactly one cell, as triangles oriented away from their cell."""
    all_faces = cells[:, faces].reshape(-1, faces.shape[1])
    owner = np.repeat(np.arange(len(cells)), len(faces))
    key = np.sort(all_faces, axis=1)
    _, index, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    single = index[counts == 1]
    boundary, owner = all_faces[single], owner[single]
    if boundary.shape[1] == 4:
        boundary = np.concatenate([boundary[:, [0, 1, 2]], boundary[:, [0, 2, 3]]])
        owner = np.concatenate([owner, owner])
    corners = nodes[boundary]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    outward = corners.mean(axis=1) - nodes[cells[owner]].mean(axis=1)
    inward = np.einsum("ij,ij->i", normal, outward) < 0
    boundary[inward] = boundary[inward][:, [0, 2, 1]]
    return boundary
