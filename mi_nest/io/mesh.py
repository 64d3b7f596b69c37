"""Stress on a mesh as ``.npz``: ``nodes`` (N, 3) mm, ``cells`` (M, 4 | 8) 0-based, ``stress`` (N, 6) MPa, and
optionally the boundary conditions it was solved with: ``force_nodes`` (K,) 0-based with ``forces`` (K, 3) N, and
``fixed_nodes`` (L,) 0-based (what a 3D-TSV file holds as node forces and fixed nodes)."""
from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from .atomic import atomic_path
from .grid import GridFileError
from .tsv import BoundaryConditions


def save_mesh_stress(path: str | Path, nodes: np.ndarray, cells: np.ndarray, stress: np.ndarray,
                     boundary: BoundaryConditions | None = None) -> None:
    """Write atomically (temp file + rename)."""
    extra = {} if boundary is None else {"force_nodes": boundary.force_nodes, "forces": boundary.forces,
                                         "fixed_nodes": boundary.fixed_nodes}
    with atomic_path(path, ".npz") as tmp:
        np.savez_compressed(tmp, nodes=np.asarray(nodes, np.float64), cells=np.asarray(cells, np.int64),
                            stress=np.asarray(stress, np.float32), **extra)


def load_mesh_boundary(path: str | Path) -> BoundaryConditions | None:
    """The boundary conditions a mesh ``.npz`` records (None when it records none)."""
    with np.load(path) as data:
        if not {"force_nodes", "forces", "fixed_nodes"} <= set(data.files):
            return None
        boundary = BoundaryConditions(data["force_nodes"], data["forces"], data["fixed_nodes"])
        boundary.check_nodes(len(data["nodes"]))
        return boundary


def is_mesh_npz(files: Iterable[str]) -> bool:
    return {"nodes", "cells", "stress"} <= set(files)


def load_mesh_arrays(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    with np.load(path) as data:
        missing = {"nodes", "cells", "stress"} - set(data.files)
        if missing:
            raise GridFileError(f"{path}: missing array(s) {sorted(missing)} of a mesh stress file")
        return data["nodes"], data["cells"], data["stress"]
