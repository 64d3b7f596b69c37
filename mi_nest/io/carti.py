"""3D-TSV Cartesian-grid files (today's ``.TSVcarti``, the early ``.carti``): stress on solid voxels.

Layout (as read by the 3D-TSV importer; keywords are not checked, only positions):
a line ending in ``CARTESIAN_GRID`` (early files put three lines before it,
today's none), optionally ``Stress Data Type: NODE|ELEMENT``; then
keyword-prefixed values: the voxel counts ``nelx nely nelz``, the lower and
upper bounds of the box, the number of solid voxels followed (after one more
keyword) by their ids; a keyword line ending in a field count; then the
sections ``Node Forces``, ``Fixed Nodes`` and ``Cartesian Stress`` as in
``.TSV`` files. Ids are 0-based in ``.carti`` files and one-based in
``.TSVcarti`` files (today's importer uses them as MATLAB indices). ``ELEMENT``
stress has one row per solid voxel and is averaged to the voxels' nodes.

Ids are column-major over (y, x, z) and y runs from the upper bound down:
voxel ``(ix, iy, iz)`` has id ``iy + nely (ix + nelx iz)``, grid node
``(ix, iy, iz)`` has id ``iy + (nely + 1) (ix + (nelx + 1) iz)`` and sits at
``y = y_max - iy * dy``. Stress rows belong to the nodes of solid voxels, in
increasing node id.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .cells import fill_from_nearest, nodal_average
from .tsv import TsvFileError, TsvModel, element_stress_line, stress_data_type_line


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

    def node_coordinates(self, ids: np.ndarray) -> np.ndarray:
        nelx, nely, _ = self.cells
        iy = ids % (nely + 1)
        ix = (ids // (nely + 1)) % (nelx + 1)
        iz = ids // ((nely + 1) * (nelx + 1))
        step = (self.upper - self.lower) / np.array(self.cells)
        return np.stack([self.lower[0] + ix * step[0], self.upper[1] - iy * step[1],
                         self.lower[2] + iz * step[2]], axis=1)

    def hexahedra(self) -> np.ndarray:
        """Grid node ids of each solid voxel's corners in VTK order (y up: from the larger iy)."""
        nelx, nely, _ = self.cells
        iy = self.voxels % nely
        ix = (self.voxels // nely) % nelx
        iz = self.voxels // (nely * nelx)

        def node(dx: int, dy: int, dz: int) -> np.ndarray:
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

    def grid_stress(self) -> np.ndarray:
        """Nodal stress on the full grid as (Z, Y, X, 6), y ascending; empty nodes take the nearest node."""
        nelx, nely, nelz = self.cells
        count = (nelx + 1) * (nely + 1) * (nelz + 1)
        values = np.zeros((count, 6), np.float32)
        values[self.node_ids] = self.stress
        known = np.zeros(count, bool)
        known[self.node_ids] = True

        def on_grid(array: np.ndarray) -> np.ndarray:
            # Node id order is (y fastest, then x, then z) with y descending.
            return array.reshape(nelz + 1, nelx + 1, nely + 1, -1).transpose(0, 2, 1, 3)[:, ::-1]
        return fill_from_nearest(on_grid(values), on_grid(known[:, None])[..., 0])


# Early files put the CARTESIAN_GRID line fourth, today's first.
_GRID_LINE_WITHIN = 4


def read_carti_file(path: str | Path, one_based: bool | None = None) -> CartesianGrid:
    """Parse a ``.TSVcarti`` or ``.carti`` file; ``one_based`` defaults to what the extension says."""
    path = Path(path)
    if not path.is_file():
        raise TsvFileError(f"3D-TSV file not found: {path}")
    if one_based is None:
        one_based = path.suffix.lower() == ".tsvcarti"
    lines = path.read_text(encoding="ascii", errors="replace").splitlines()
    grid_line = next((i for i, line in enumerate(lines[:_GRID_LINE_WITHIN])
                      if line.split()[-1:] == ["CARTESIAN_GRID"]), None)
    if grid_line is None:
        raise TsvFileError(f"{path}: not a Cartesian-grid (.TSVcarti/.carti) file: no line ending in "
                           f"'CARTESIAN_GRID' among its first {_GRID_LINE_WITHIN}")
    element_stress, body = False, grid_line + 1
    if body < len(lines) and lines[body].lower().startswith("stress data type"):
        element_stress, body = element_stress_line(path, body + 1, lines[body], "grid node", "solid voxel"), body + 1
    reader = _Tokens(path, " ".join(lines[body:]).split())
    cells = tuple(int(v) for v in reader.keyword_numbers(3, int))
    if min(cells) < 1:
        raise TsvFileError(f"{path}: voxel counts must be positive, got {cells}")
    lower, upper = reader.keyword_numbers(3, float), reader.keyword_numbers(3, float)
    if not np.all(upper > lower):
        raise TsvFileError(f"{path}: upper bound {upper} must exceed lower bound {lower}")
    count = int(reader.keyword_numbers(1, int)[0])
    reader.take(1)
    first = int(one_based)
    voxels = np.unique(reader.numbers(count, int)) - first
    if len(voxels) != count or voxels.min() < 0 or voxels.max() >= np.prod(cells):
        raise TsvFileError(f"{path}: solid voxel ids must be {count} distinct values in {first}.."
                           f"{np.prod(cells) - 1 + first}{_BASE_HINT[one_based]}")
    reader.take(4)
    reader.numbers(1, int)
    forces = reader.section(4, float)
    fixed = reader.section(1, int)[:, 0].astype(np.int64) - first
    stress = reader.section(6, float)
    grid = CartesianGrid(cells, lower, upper, voxels, np.zeros(0, np.int64), stress, forces, fixed)
    hexahedra = grid.hexahedra()
    node_ids = np.unique(hexahedra)
    if element_stress:
        if len(stress) != len(voxels):
            raise TsvFileError(f"{path}: {len(stress)} stress rows for {len(voxels)} solid voxels "
                               "('Stress Data Type: ELEMENT': one per voxel)")
        stress = nodal_average(grid.node_coordinates(node_ids), np.searchsorted(node_ids, hexahedra), stress)
    elif len(stress) != len(node_ids):
        raise TsvFileError(f"{path}: {len(stress)} stress rows for the {len(node_ids)} nodes of the solid voxels")
    if len(forces):
        forces[:, 0] -= first
    for name, nodes in (("Node Forces", forces[:, 0]), ("Fixed Nodes", fixed)):
        if len(nodes) and not np.all(np.isin(nodes, node_ids)):
            raise TsvFileError(f"{path}: section '{name}' refers to grid nodes of no solid voxel "
                               f"(first {int(nodes[~np.isin(nodes, node_ids)][0]) + first}){_BASE_HINT[one_based]}")
    return CartesianGrid(cells, lower, upper, voxels, node_ids, stress.astype(np.float32), forces, fixed)


_BASE_HINT = {True: " (ids are one-based in .TSVcarti files; a file with 0-based ids is an early .carti)",
              False: " (ids are 0-based in .carti files; a file with one-based ids is a .TSVcarti)"}


class _Tokens:
    def __init__(self, path, tokens):
        self.path, self.tokens, self.at = path, tokens, 0

    def take(self, count: int) -> list[str]:
        if self.at + count > len(self.tokens):
            raise TsvFileError(f"{self.path}: file ends early (truncated file?)")
        taken = self.tokens[self.at:self.at + count]
        self.at += count
        return taken

    def numbers(self, count: int, kind: type[int] | type[float]) -> np.ndarray:
        values = self.take(count)
        try:
            return np.array([kind(float(v)) if kind is int else float(v) for v in values])
        except ValueError:
            raise TsvFileError(f"{self.path}: expected {count} numbers, got {' '.join(values[:6])}...") from None

    def keyword_numbers(self, count: int, kind: type[int] | type[float]) -> np.ndarray:
        self.take(1)
        return self.numbers(count, kind)

    def section(self, width: int, kind: type[int] | type[float]) -> np.ndarray:
        name = " ".join(self.take(2))
        rows = int(self.numbers(1, int)[0])
        table = self.numbers(rows * width, kind).reshape(rows, width)
        if not np.all(np.isfinite(table)):
            raise TsvFileError(f"{self.path}: section {name!r} holds NaN or inf values")
        return table


def write_carti_file(path: str | Path, cells: Sequence[int], lower: Sequence[float], upper: Sequence[float],
                     voxels: np.ndarray, stress_at: Callable[[np.ndarray], np.ndarray],
                     node_forces: Sequence[Sequence[float]] | np.ndarray = (),
                     fixed_nodes: Sequence[int] | np.ndarray = (), element_stress: bool = False) -> None:
    """Write a Cartesian-grid file: today's ``.TSVcarti`` under that name (any case), else an early ``.carti``.

    ``stress_at(points)`` gives (K, 6) stress at the nodes of the solid voxels,
    or at their centres with ``element_stress`` (written as ``Stress Data Type:
    ELEMENT``, ``.TSVcarti`` only). Voxel and node ids are given 0-based.
    """
    today = Path(path).suffix.lower() == ".tsvcarti"
    if element_stress and not today:
        raise ValueError("element-wise stress needs today's format: name the file .TSVcarti")
    first = int(today)
    grid = CartesianGrid(tuple(cells), np.asarray(lower, float), np.asarray(upper, float),
                         np.unique(voxels), np.zeros(0, np.int64), np.zeros((0, 6)), np.zeros((0, 4)),
                         np.zeros(0, np.int64))
    hexahedra = grid.hexahedra()
    node_ids = np.unique(hexahedra)
    points = (grid.node_coordinates(hexahedra.ravel()).reshape(-1, 8, 3).mean(axis=1) if element_stress
              else grid.node_coordinates(node_ids))
    stress = np.asarray(stress_at(points))
    with open(path, "w", encoding="ascii") as out:
        if today:
            out.write(f"DATASET CARTESIAN_GRID\n{stress_data_type_line(element_stress)}")
        else:
            out.write("# vtk DataFile Version 3.0\nmi_nest\nASCII\nDATASET CARTESIAN_GRID\n")
        out.write("Resolution: {} {} {}\n".format(*cells))
        out.write("LowerBound: {:.9e} {:.9e} {:.9e}\n".format(*lower))
        out.write("UpperBound: {:.9e} {:.9e} {:.9e}\n".format(*upper))
        out.write(f"SolidVoxels: {len(grid.voxels)}\nVoxelIds:\n")
        np.savetxt(out, grid.voxels[None, :] + first, fmt="%d")
        out.write("Number of Stress Fields: 1\n")
        out.write(f"Node Forces: {len(node_forces)}\n")
        for node, fx, fy, fz in node_forces:
            out.write(f"{int(node) + first} {fx:.9e} {fy:.9e} {fz:.9e}\n")
        out.write(f"Fixed Nodes: {len(fixed_nodes)}\n")
        for node in fixed_nodes:
            out.write(f"{int(node) + first}\n")
        out.write(f"Cartesian Stress: {len(stress)}\n")
        np.savetxt(out, stress, fmt="%.9e")
