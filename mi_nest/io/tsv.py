"""3D-TSV ``.stress`` files (the 3D Tensor Stress Visualization project, BSD-2).

Sections, each a header ``Name: count`` followed by ``count`` rows:
``Vertices`` (x y z), ``Elements`` (4 or 8 one-based node ids per row: tetrahedra
or hexahedra in VTK order), ``Node Forces`` (node fx fy fz), ``Fixed Nodes``
(node), ``Cartesian Stress`` (xx yy zz yz zx xy per vertex). Loads and fixtures
are optional; vertices, elements and stress are required.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

_SECTIONS = {"vertices": ("Vertices", 3), "elements": ("Elements", None), "node_forces": ("Node Forces", 4),
             "fixed_nodes": ("Fixed Nodes", 1), "stress": ("Cartesian Stress", 6)}


class TsvFileError(ValueError):
    """A ``.stress`` file is missing, truncated or malformed."""


@dataclass(frozen=True)
class TsvModel:
    vertices: np.ndarray        # (N, 3)
    elements: np.ndarray        # (M, 4 | 8), 0-based
    stress: np.ndarray          # (N, 6)
    node_forces: np.ndarray     # (K, 4): 0-based node, fx, fy, fz
    fixed_nodes: np.ndarray     # (L,), 0-based

    def mesh(self):
        from ..fields.mesh import TetMeshStress
        return TetMeshStress.from_cells(self.vertices, self.elements, self.stress)


def read_stress_file(path) -> TsvModel:
    """Parse (and cache, keyed by path and modification time) a 3D-TSV ``.stress`` file."""
    path = Path(path)
    if not path.is_file():
        raise TsvFileError(f"3D-TSV file not found: {path}")
    stat = os.stat(path)
    return _read_cached(str(path.resolve()), stat.st_mtime_ns, stat.st_size)


@lru_cache(maxsize=8)
def _read_cached(path, mtime_ns, size):
    with open(path, "r", encoding="ascii", errors="replace") as handle:
        lines = handle.read().splitlines()
    sections, row = {}, 0
    while row < len(lines):
        line = lines[row].strip()
        row += 1
        if not line:
            continue
        name, sep, count = line.partition(":")
        key = next((k for k, (title, _) in _SECTIONS.items() if title.lower() == name.strip().lower()), None)
        if not sep or key is None:
            raise TsvFileError(f"{path}:{row}: expected a section header like 'Vertices: N', got {line[:60]!r}")
        try:
            count = int(count.split()[0])
        except (IndexError, ValueError):
            raise TsvFileError(f"{path}:{row}: section '{name.strip()}' has no row count") from None
        if key in sections:
            raise TsvFileError(f"{path}:{row}: section '{name.strip()}' appears twice")
        body = lines[row:row + count]
        if len(body) < count or (count and not body[-1].strip()):
            raise TsvFileError(f"{path}: section '{name.strip()}' announces {count} rows but the file "
                               f"ends after {len([b for b in body if b.strip()])}: truncated file?")
        sections[key] = _parse_rows(path, row, name.strip(), body, _SECTIONS[key][1])
        row += count
    for key in ("vertices", "elements", "stress"):
        if key not in sections:
            raise TsvFileError(f"{path}: missing section '{_SECTIONS[key][0]}'")
    vertices, elements, stress = sections["vertices"], sections["elements"], sections["stress"]
    if elements.shape[1] not in (4, 8):
        raise TsvFileError(f"{path}: elements must have 4 (tetrahedra) or 8 (hexahedra) nodes, "
                           f"got {elements.shape[1]}")
    if len(stress) != len(vertices):
        raise TsvFileError(f"{path}: {len(stress)} stress rows for {len(vertices)} vertices")
    elements = _node_ids(path, "Elements", elements, len(vertices))
    forces = sections.get("node_forces", np.zeros((0, 4)))
    if len(forces):
        forces = np.concatenate([_node_ids(path, "Node Forces", forces[:, :1], len(vertices)), forces[:, 1:]],
                                axis=1)
    fixed = sections.get("fixed_nodes", np.zeros((0, 1)))
    fixed = _node_ids(path, "Fixed Nodes", fixed, len(vertices))[:, 0] if len(fixed) else np.zeros(0, np.int64)
    return TsvModel(vertices, elements, stress, forces, fixed)


def _parse_rows(path, first_row, name, body, width):
    try:
        table = np.array([line.split() for line in body], dtype=np.float64)
    except ValueError:
        widths = {len(line.split()) for line in body}
        bad = next((i for i, line in enumerate(body) if _not_numbers(line)), None)
        where = f" (line {first_row + bad + 1})" if bad is not None else f" (row widths {sorted(widths)})"
        raise TsvFileError(f"{path}: section '{name}' has malformed rows{where}") from None
    if table.ndim != 2 or (width is not None and table.shape[1] != width):
        raise TsvFileError(f"{path}: section '{name}' rows must have {width or 'a fixed number of'} "
                           f"values, got shape {table.shape}")
    if not np.all(np.isfinite(table)):
        raise TsvFileError(f"{path}: section '{name}' holds NaN or inf values")
    return table


def _not_numbers(line):
    try:
        [float(x) for x in line.split()]
        return False
    except ValueError:
        return True


def _node_ids(path, name, table, vertex_count):
    ids = table.astype(np.int64)
    if np.any(ids != table) or ids.min() < 1 or ids.max() > vertex_count:
        raise TsvFileError(f"{path}: section '{name}' refers to node ids outside 1..{vertex_count} "
                           "(ids are one-based)")
    return ids - 1


def write_stress_file(path, vertices, elements, stress, node_forces=None, fixed_nodes=None):
    """Write a 3D-TSV ``.stress`` file (element and node ids one-based)."""
    elements = np.asarray(elements, dtype=np.int64) + 1
    with open(path, "w", encoding="ascii") as out:
        out.write(f"Vertices: {len(vertices)}\n")
        np.savetxt(out, np.asarray(vertices), fmt="%.9e")
        out.write(f"Elements: {len(elements)}\n")
        np.savetxt(out, elements, fmt="%d")
        if node_forces is not None and len(node_forces):
            forces = np.asarray(node_forces, dtype=np.float64)
            out.write(f"Node Forces: {len(forces)}\n")
            for node, fx, fy, fz in forces:
                out.write(f"{int(node) + 1} {fx:.9e} {fy:.9e} {fz:.9e}\n")
        if fixed_nodes is not None and len(fixed_nodes):
            out.write(f"Fixed Nodes: {len(fixed_nodes)}\n")
            np.savetxt(out, np.asarray(fixed_nodes, dtype=np.int64) + 1, fmt="%d")
        out.write(f"Cartesian Stress: {len(stress)}\n")
        np.savetxt(out, np.asarray(stress), fmt="%.9e")
