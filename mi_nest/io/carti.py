"""3D-TSV ``.carti`` files: stress on the solid voxels of a Cartesian grid.

Layout (as read by the 3D-TSV importer; keywords are not checked, only positions):
three header lines; a line ending in ``CARTESIAN_GRID``; then keyword-prefixed
values: the voxel counts ``nelx nely nelz``, the lower and upper bounds of the
box, the number of solid voxels followed (after one more keyword) by their
0-based ids; a keyword line ending in a field count; then the sections
``Node Forces``, ``Fixed Nodes`` and ``Cartesian Stress`` as in ``.stress``
files, with 0-based node ids.

Ids are column-major over (y, x, z) and y runs from the upper bound down:
voxel ``(ix, iy, iz)`` has id ``iy + nely (ix + nelx iz)``, grid node
``(ix, iy, iz)`` has id ``iy + (nely + 1) (ix + (nelx + 1) iz)`` and sits at
``y = y_max - iy * dy``. Stress rows belong to the nodes of solid voxels, in
increasing node id.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .tsv import TsvFileError, TsvModel


@dataclass(frozen=True)
class CartesianGrid:
    cells: tuple           # (nelx, nely, nelz)
    lower: np.ndarray      # (3,)
    upper: np.ndarray      # (3,)
    voxels: np.ndarray     # (V,) 0-based voxel ids
    node_ids: np.ndarray   # (N,) grid node ids of the solid voxels' nodes, increasing
    stress: np.ndarray     # (N, 6)
    node_forces: np.ndarray
    fixed_nodes: np.ndarray

    def node_coordinates(self, ids):
        nelx, nely, _ = self.cells
        iy = ids % (nely + 1)
        ix = (ids // (nely + 1)) % (nelx + 1)
        iz = ids // ((nely + 1) * (nelx + 1))
        step = (self.upper - self.lower) / np.array(self.cells)
        return np.stack([self.lower[0] + ix * step[0], self.upper[1] - iy * step[1],
                         self.lower[2] + iz * step[2]], axis=1)

    def hexahedra(self):
        """Grid node ids of each solid voxel's corners in VTK order (y up: from the larger iy)."""
        nelx, nely, _ = self.cells
        iy = self.voxels % nely
        ix = (self.voxels // nely) % nelx
        iz = self.voxels // (nely * nelx)

        def node(dx, dy, dz):
            return (iy + dy) + (nely + 1) * ((ix + dx) + (nelx + 1) * (iz + dz))
        # Corner y0 (the lower y) is the node row below: iy + 1.
        return np.stack([node(0, 1, 0), node(1, 1, 0), node(1, 0, 0), node(0, 0, 0),
                         node(0, 1, 1), node(1, 1, 1), node(1, 0, 1), node(0, 0, 1)], axis=1)

    def model(self) -> TsvModel:
        """The same data as an unstructured hexahedral model (0-based, compact node numbering)."""
        compact = np.full((self.cells[0] + 1) * (self.cells[1] + 1) * (self.cells[2] + 1), -1, np.int64)
        compact[self.node_ids] = np.arange(len(self.node_ids))
        forces = self.node_forces.copy()
        if len(forces):
            forces[:, 0] = compact[forces[:, 0].astype(np.int64)]
        return TsvModel(self.node_coordinates(self.node_ids), compact[self.hexahedra()], self.stress,
                        forces, compact[self.fixed_nodes] if len(self.fixed_nodes) else self.fixed_nodes)

    def grid_stress(self):
        """Nodal stress on the full grid as (Z, Y, X, 6), y ascending; empty nodes take the nearest node."""
        from ..fields.mesh import fill_from_nearest
        nelx, nely, nelz = self.cells
        count = (nelx + 1) * (nely + 1) * (nelz + 1)
        values = np.zeros((count, 6), np.float32)
        values[self.node_ids] = self.stress
        known = np.zeros(count, bool)
        known[self.node_ids] = True

        def on_grid(array):
            # Node id order is (y fastest, then x, then z) with y descending.
            return array.reshape(nelz + 1, nelx + 1, nely + 1, -1).transpose(0, 2, 1, 3)[:, ::-1]
        return fill_from_nearest(on_grid(values), on_grid(known[:, None])[..., 0])


def read_carti_file(path) -> CartesianGrid:
    path = Path(path)
    if not path.is_file():
        raise TsvFileError(f"3D-TSV file not found: {path}")
    lines = path.read_text(encoding="ascii", errors="replace").splitlines()
    tokens = " ".join(lines[3:]).split()
    reader = _Tokens(path, tokens)
    if reader.take(2)[-1].upper() != "CARTESIAN_GRID":
        raise TsvFileError(f"{path}: not a Cartesian-grid (.carti) file: 'CARTESIAN_GRID' expected on line 4")
    cells = tuple(int(v) for v in reader.keyword_numbers(3, int))
    if min(cells) < 1:
        raise TsvFileError(f"{path}: voxel counts must be positive, got {cells}")
    lower, upper = reader.keyword_numbers(3, float), reader.keyword_numbers(3, float)
    if not np.all(upper > lower):
        raise TsvFileError(f"{path}: upper bound {upper} must exceed lower bound {lower}")
    count = int(reader.keyword_numbers(1, int)[0])
    reader.take(1)
    voxels = np.unique(reader.numbers(count, int))
    if len(voxels) != count or voxels.min() < 0 or voxels.max() >= np.prod(cells):
        raise TsvFileError(f"{path}: solid voxel ids must be {count} distinct values in 0..{np.prod(cells) - 1}")
    reader.take(4)
    reader.numbers(1, int)
    forces = reader.section(4, float)
    fixed = reader.section(1, int)[:, 0]
    stress = reader.section(6, float)
    grid = CartesianGrid(cells, lower, upper, voxels, np.zeros(0, np.int64), stress, forces,
                         fixed.astype(np.int64))
    node_ids = np.unique(grid.hexahedra())
    if len(stress) != len(node_ids):
        raise TsvFileError(f"{path}: {len(stress)} stress rows for the {len(node_ids)} nodes of the solid voxels")
    return CartesianGrid(cells, lower, upper, voxels, node_ids, stress.astype(np.float32), forces,
                         fixed.astype(np.int64))


class _Tokens:
    def __init__(self, path, tokens):
        self.path, self.tokens, self.at = path, tokens, 0

    def take(self, count):
        if self.at + count > len(self.tokens):
            raise TsvFileError(f"{self.path}: file ends early (truncated file?)")
        taken = self.tokens[self.at:self.at + count]
        self.at += count
        return taken

    def numbers(self, count, kind):
        values = self.take(count)
        try:
            return np.array([kind(float(v)) if kind is int else float(v) for v in values])
        except ValueError:
            raise TsvFileError(f"{self.path}: expected {count} numbers, got {' '.join(values[:6])}...") from None

    def keyword_numbers(self, count, kind):
        self.take(1)
        return self.numbers(count, kind)

    def section(self, width, kind):
        self.take(2)
        rows = int(self.numbers(1, int)[0])
        return self.numbers(rows * width, kind).reshape(rows, width)


def write_carti_file(path, cells, lower, upper, voxels, stress_of_node, node_forces=(), fixed_nodes=()):
    """Write a ``.carti`` file; ``stress_of_node(points)`` gives (K, 6) stress at node positions."""
    grid = CartesianGrid(tuple(cells), np.asarray(lower, float), np.asarray(upper, float),
                         np.unique(voxels), np.zeros(0, np.int64), np.zeros((0, 6)), np.zeros((0, 4)),
                         np.zeros(0, np.int64))
    node_ids = np.unique(grid.hexahedra())
    stress = np.asarray(stress_of_node(grid.node_coordinates(node_ids)))
    with open(path, "w", encoding="ascii") as out:
        out.write("# vtk DataFile Version 3.0\nmi_nest\nASCII\nDATASET CARTESIAN_GRID\n")
        out.write("Resolution: {} {} {}\n".format(*cells))
        out.write("LowerBound: {:.9e} {:.9e} {:.9e}\n".format(*lower))
        out.write("UpperBound: {:.9e} {:.9e} {:.9e}\n".format(*upper))
        out.write(f"SolidVoxels: {len(grid.voxels)}\nVoxelIds:\n")
        np.savetxt(out, grid.voxels[None, :], fmt="%d")
        out.write("Number of Stress Fields: 1\n")
        out.write(f"Node Forces: {len(node_forces)}\n")
        for node, fx, fy, fz in node_forces:
            out.write(f"{int(node)} {fx:.9e} {fy:.9e} {fz:.9e}\n")
        out.write(f"Fixed Nodes: {len(fixed_nodes)}\n")
        for node in fixed_nodes:
            out.write(f"{int(node)}\n")
        out.write(f"Cartesian Stress: {len(node_ids)}\n")
        np.savetxt(out, stress, fmt="%.9e")
