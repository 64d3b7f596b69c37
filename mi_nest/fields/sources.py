"""Stress files of every supported kind, turned into the grid a ``stress`` medium renders."""
from __future__ import annotations

import os
import zipfile
from functools import lru_cache
from importlib import resources
from pathlib import Path

import numpy as np

from ..io.carti import read_carti_file
from ..io.grid import GridFileError, StressGrid, grid_cells, load_stress_grid
from ..io.mesh import is_mesh_npz, load_mesh_arrays, load_mesh_boundary
from ..io.tsv import TsvModel, read_stress_file
from .mesh import TetMeshStress

# 3D-TSV names its files by extension, today's first; any case is accepted.
TSV_MESH_SUFFIXES = (".tsv", ".stress")
TSV_GRID_SUFFIXES = (".tsvcarti", ".carti")
SUFFIXES = (".npz",) + TSV_MESH_SUFFIXES + TSV_GRID_SUFFIXES
SUPPORTED = "grid or mesh .npz, 3D-TSV .TSV/.stress or .TSVcarti/.carti"


def is_stress_file(path: str | Path) -> bool:
    """Whether ``path`` names a stress file by its extension (any case)."""
    return Path(path).suffix.lower() in SUFFIXES


def is_tsv_file(path: str | Path) -> bool:
    return Path(path).suffix.lower() in TSV_MESH_SUFFIXES + TSV_GRID_SUFFIXES


def read_tsv_model(path: str | Path) -> TsvModel:
    """A 3D-TSV file of any kind as its unstructured model (grid files as hexahedra)."""
    if Path(path).suffix.lower() in TSV_MESH_SUFFIXES:
        return read_stress_file(path)
    return read_carti_file(path).model()


def stress_file(path: str | Path) -> Path:
    """The stress file ``path`` stands for: itself, or a bare file name of the shipped data
    (``kitten.stress``), as ``mi-nest render kitten`` finds a shipped scene from anywhere."""
    path = Path(path)
    if not path.exists() and len(path.parts) == 1:
        shipped = Path(resources.files("mi_nest.scenes") / "data" / path.name)
        if shipped.is_file():
            return shipped
    return path


def is_mesh_file(path: str | Path) -> bool:
    """Whether ``path`` holds stress on a mesh (3D-TSV files, mesh ``.npz``) rather than a grid."""
    path = Path(path)
    if is_tsv_file(path):
        return True
    try:
        with np.load(path) as data:
            return is_mesh_npz(data.files)
    except (OSError, ValueError, zipfile.BadZipFile) as error:
        raise GridFileError(f"{path}: not a readable .npz stress file ({error})") from error


def mesh_arrays(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(nodes, cells, stress)`` of a mesh file, cells as stored (tetrahedra or hexahedra)."""
    if is_tsv_file(path):
        model = read_tsv_model(path)
        return model.vertices, model.elements, model.stress
    return load_mesh_arrays(path)


def load_mesh(path: str | Path) -> TetMeshStress:
    """The mesh of a 3D-TSV file (with its boundary conditions) or of a mesh ``.npz`` (FEM result).

    Cached by path and modification time: a ``specimen`` shape and its medium build it once.
    """
    path = Path(path)
    stat = os.stat(path)
    return _mesh_cached(str(path.resolve()), stat.st_mtime_ns, stat.st_size)


@lru_cache(maxsize=8)
def _mesh_cached(path, mtime_ns, size):
    if is_tsv_file(path):
        return TetMeshStress.from_model(read_tsv_model(path))
    return TetMeshStress.from_cells(*mesh_arrays(path))


def export_file(path: str | Path, output: str | Path, resolution: int = 64) -> str:
    """Write any stress file as ``.vtu`` or 3D-TSV ``.TSV`` (by ``output``'s suffix): meshes with their own
    cells (and the boundary conditions a 3D-TSV file or a ``mi-nest fem`` result holds), grids as hexahedra."""
    from ..io import export_format
    from ..io.tsv import write_stress_file
    from ..io.vtk import write_mesh_vtu
    kind = export_format(output)
    boundary = {}
    if Path(path).is_file() and is_mesh_file(path):
        nodes, cells, stress = mesh_arrays(path)
        TetMeshStress.from_cells(nodes, cells, stress)   # validates the mesh before writing it out
        conditions = read_tsv_model(path).boundary_conditions() if is_tsv_file(path) else (
            load_mesh_boundary(path) if Path(path).suffix.lower() == ".npz" else None)
        if conditions is not None:
            boundary = {"node_forces": np.column_stack([conditions.force_nodes, conditions.forces]),
                        "fixed_nodes": conditions.fixed_nodes}
        summary = f"{len(nodes)} nodes, {len(cells)} cells"
    else:
        grid = grid_from_file(path, resolution)
        nodes, cells, stress = grid_cells(grid)
        summary = "grid " + "x".join(str(n) for n in grid.stress.shape[2::-1])
    if kind == ".vtu":
        write_mesh_vtu(output, nodes, cells, stress)
    else:
        write_stress_file(output, nodes, cells, stress, **boundary)
    return summary


def grid_from_file(path: str | Path, resolution: int = 64) -> StressGrid:
    """A :class:`~mi_nest.io.grid.StressGrid` from any supported stress file.

    Grids and ``.TSVcarti``/``.carti`` files load at their own nodes; meshes
    (``.TSV``/``.stress``, mesh ``.npz``) are resampled with
    ``resolution`` nodes along their longest axis. Results are cached by path,
    modification time and resolution, so a specimen and its medium parse once.
    """
    path = Path(path)
    if not path.is_file():
        raise GridFileError(f"stress file not found: {path}")
    if not is_stress_file(path):
        raise GridFileError(f"{path}: unsupported stress file type '{path.suffix}'; supported: {SUPPORTED}")
    stat = os.stat(path)
    return _grid_cached(str(path.resolve()), stat.st_mtime_ns, int(resolution))


@lru_cache(maxsize=8)
def _grid_cached(path, mtime_ns, resolution):
    if Path(path).suffix.lower() in TSV_GRID_SUFFIXES:
        # Nodal values on a regular grid: trilinear lookup is the hexahedral interpolation itself.
        carti = read_carti_file(path)
        return StressGrid(carti.grid_stress(), carti.lower, carti.upper)
    if not is_mesh_file(path):
        return load_stress_grid(path)
    return load_mesh(path).to_grid(resolution)
