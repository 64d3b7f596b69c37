"""Stress on a mesh as ``.npz``: ``nodes`` (N, 3) mm, ``cells`` (M, 4 | 8) 0-based, ``stress`` (N, 6) MPa."""
from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from .atomic import atomic_path
from .grid import GridFileError


def save_mesh_stress(path: str | Path, nodes: np.ndarray, cells: np.ndarray, stress: np.ndarray) -> None:
    """Write atomically (temp file + rename)."""
    with atomic_path(path, ".npz") as tmp:
        np.savez_compressed(tmp, nodes=np.asarray(nodes, np.float64), cells=np.asarray(cells, np.int64),
                            stress=np.asarray(stress, np.float32))


def is_mesh_npz(files: Iterable[str]) -> bool:
    return {"nodes", "cells", "stress"} <= set(files)


def load_mesh_arrays(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    with np.load(path) as data:
        missing = {"nodes", "cells", "stress"} - set(data.files)
        if missing:
            raise GridFileError(f"{path}: missing array(s) {sorted(missing)} of a mesh stress file")
        return data["nodes"], data["cells"], data["stress"]
