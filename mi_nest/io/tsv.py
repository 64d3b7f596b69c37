"""3D-TSV stress files on unstructured meshes: today's ``.TSV`` and the early ``.stress``.

Both hold the same sections, each a header ``Name: count`` followed by ``count``
rows: ``Vertices`` (x y z), ``Elements`` (4 or 8 one-based node ids per row:
tetrahedra or hexahedra in VTK order), ``Node Forces`` (node fx fy fz, in N),
``Fixed Nodes`` (node), ``Cartesian Stress`` (xx yy zz yz zx xy). Loads and
fixtures are optional; vertices, elements and stress are required. Today's
3D-TSV starts its files with three header lines, which early files lack::

    Version 2.0
    Stress Data Type: NODE        (or ELEMENT: one stress row per element)
    Solid Hex 1                   (or Solid Tet 1: first-order hexahedra or tetrahedra)

Element-wise stress is averaged to the nodes, each element weighted by its
volume (:func:`mi_nest.io.cells.nodal_average`), so ``TsvModel.stress`` is
always one tensor per vertex.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from .cells import MeshError, nodal_average

_SECTIONS = {"vertices": ("Vertices", 3), "elements": ("Elements", None), "node_forces": ("Node Forces", 4),
             "fixed_nodes": ("Fixed Nodes", 1), "stress": ("Cartesian Stress", 6)}
# Header lines of today's files: the solid's element kind gives the node count per element.
_ELEMENT_NODES = {"tet": 4, "hex": 8}
_HEADER_HELP = "3D-TSV header lines are 'Version 2.0', 'Stress Data Type: NODE|ELEMENT' and 'Solid Tet|Hex 1'"


class TsvFileError(ValueError):
    """A 3D-TSV file is missing, truncated or malformed."""


def element_stress_line(path: str | Path, row: int, line: str, node: str, element: str) -> bool:
    """Whether a ``Stress Data Type: NODE|ELEMENT`` header line gives one stress per ``element`` (else per
    ``node``); any other type is refused naming the line."""
    kind = line.partition(":")[2].strip().upper()
    if kind not in ("NODE", "ELEMENT"):
        raise TsvFileError(f"{path}:{row}: unknown stress data type {kind!r}; 3D-TSV writes NODE "
                           f"(one stress per {node}) or ELEMENT (one per {element})")
    return kind == "ELEMENT"


def stress_data_type_line(element_stress: bool) -> str:
    """The header line 3D-TSV writes for nodal or element-wise stress."""
    return f"Stress Data Type: {'ELEMENT' if element_stress else 'NODE'}\n"


@dataclass(frozen=True)
class BoundaryConditions:
    """The loads and supports of the FEM run behind a 3D-TSV file.

    ``forces[k]`` (N) acts on node ``force_nodes[k]``; every displacement
    component of the ``fixed_nodes`` is held. Node indices are 0-based.
    """
    force_nodes: np.ndarray     # (K,) int64
    forces: np.ndarray          # (K, 3) float64
    fixed_nodes: np.ndarray     # (L,) int64

    def __post_init__(self):
        object.__setattr__(self, "force_nodes", np.asarray(self.force_nodes, dtype=np.int64).reshape(-1))
        object.__setattr__(self, "forces", np.asarray(self.forces, dtype=np.float64).reshape(-1, 3))
        object.__setattr__(self, "fixed_nodes", np.asarray(self.fixed_nodes, dtype=np.int64).reshape(-1))
        if len(self.forces) != len(self.force_nodes):
            raise ValueError(f"{len(self.force_nodes)} loaded nodes but {len(self.forces)} force vectors")
        if not np.all(np.isfinite(self.forces)):
            raise ValueError("node forces hold NaN or inf")

    def check_nodes(self, node_count: int) -> None:
        """Raise ``ValueError`` unless every node index lies in ``0..node_count - 1``."""
        for name, nodes in (("node forces", self.force_nodes), ("fixed nodes", self.fixed_nodes)):
            if len(nodes) and (nodes.min() < 0 or nodes.max() >= node_count):
                raise ValueError(f"{name} refer to nodes outside 0..{node_count - 1} "
                                 f"(got {nodes.min()}..{nodes.max()})")

    @property
    def total_force(self) -> np.ndarray:
        return self.forces.sum(axis=0)

    def describe(self) -> str:
        total = ", ".join(f"{v:.4g}" for v in self.total_force)
        return f"{len(self.forces)} node forces (total ({total}) N), {len(self.fixed_nodes)} fixed nodes"


@dataclass(frozen=True)
class TsvModel:
    vertices: np.ndarray        # (N, 3)
    elements: np.ndarray        # (M, 4 | 8), 0-based
    stress: np.ndarray          # (N, 6), per vertex (averaged from the elements when ``element_stress``)
    node_forces: np.ndarray     # (K, 4): 0-based node, fx, fy, fz
    fixed_nodes: np.ndarray     # (L,), 0-based
    element_stress: bool = False    # the file gave one stress per element

    def boundary_conditions(self) -> BoundaryConditions:
        return BoundaryConditions(self.node_forces[:, 0], self.node_forces[:, 1:], self.fixed_nodes)


def read_stress_file(path: str | Path) -> TsvModel:
    """Parse (and cache, keyed by path and modification time) a 3D-TSV ``.TSV`` or ``.stress`` file."""
    path = Path(path)
    if not path.is_file():
        raise TsvFileError(f"3D-TSV file not found: {path}")
    stat = os.stat(path)
    return _read_cached(str(path.resolve()), stat.st_mtime_ns, stat.st_size)


@dataclass
class _Header:
    """What today's header lines say, and on which line (for errors that point at them)."""
    element_stress: bool = False
    element_nodes: int | None = None
    lines: dict = field(default_factory=dict)      # header name -> line number

    def read(self, path: str, row: int, line: str) -> bool:
        """Take one header line; False when ``line`` is no header line."""
        words = line.replace(":", " : ").split()
        key = words[0].lower()
        if key == "version":
            self._once(path, row, "Version")
        elif line.lower().startswith("stress data type"):
            self._once(path, row, "Stress Data Type")
            self.element_stress = element_stress_line(path, row, line, "vertex", "element")
        elif key in ("solid", "plane"):
            self._once(path, row, "Solid")
            if key == "plane":
                raise TsvFileError(f"{path}:{row}: a 2D ('Plane') stress field; mi_nest renders solids "
                                   "('Solid Tet 1' or 'Solid Hex 1')")
            if len(words) != 3 or words[1].lower() not in _ELEMENT_NODES or words[2] != "1":
                raise TsvFileError(f"{path}:{row}: unsupported mesh {line!r}; mi_nest reads first-order "
                                   "solids: 'Solid Tet 1' or 'Solid Hex 1'")
            self.element_nodes = _ELEMENT_NODES[words[1].lower()]
        else:
            return False
        return True

    def _once(self, path, row, name):
        if name in self.lines:
            raise TsvFileError(f"{path}:{row}: header line '{name}' appears twice (first on line {self.lines[name]})")
        self.lines[name] = row


@lru_cache(maxsize=8)
def _read_cached(path, mtime_ns, size):
    with open(path, "r", encoding="ascii", errors="replace") as handle:
        lines = handle.read().splitlines()
    header, sections, starts, row = _Header(), {}, {}, 0
    while row < len(lines):
        line = lines[row].strip()
        row += 1
        if not line:
            continue
        if not sections and header.read(path, row, line):
            continue
        name, sep, count = line.partition(":")
        key = next((k for k, (title, _) in _SECTIONS.items() if title.lower() == name.strip().lower()), None)
        if not sep or key is None:
            raise TsvFileError(f"{path}:{row}: {_unexpected(line, sections, starts)}")
        try:
            count = int(count.split()[0])
        except (IndexError, ValueError):
            raise TsvFileError(f"{path}:{row}: section '{name.strip()}' has no row count") from None
        if key in sections:
            raise TsvFileError(f"{path}:{row}: section '{name.strip()}' appears twice")
        body = lines[row:row + count]
        if len(body) < count or (count and not body[-1].strip()):
            raise TsvFileError(f"{path}:{row}: section '{name.strip()}' announces {count} rows but the file "
                               f"ends after {len([b for b in body if b.strip()])}: truncated file?")
        sections[key] = _parse_rows(path, row, name.strip(), body, _SECTIONS[key][1])
        starts[key] = row
        row += count
    for key in ("vertices", "elements", "stress"):
        if key not in sections:
            raise TsvFileError(f"{path}: missing section '{_SECTIONS[key][0]}'")
    vertices, elements, stress = sections["vertices"], sections["elements"], sections["stress"]
    nodes_per_element = elements.shape[1]
    if nodes_per_element not in (4, 8):
        raise TsvFileError(f"{path}:{starts['elements']}: elements must have 4 (tetrahedra) or 8 (hexahedra) "
                           f"nodes, got {nodes_per_element}")
    if header.element_nodes not in (None, nodes_per_element):
        announced = "hexahedra" if header.element_nodes == 8 else "tetrahedra"
        raise TsvFileError(f"{path}:{starts['elements']}: elements have {nodes_per_element} nodes but line "
                           f"{header.lines['Solid']} announces {announced}")
    elements = _node_ids(path, starts["elements"], "Elements", elements, len(vertices))
    expected, owners = (len(elements), "elements") if header.element_stress else (len(vertices), "vertices")
    if len(stress) != expected:
        hint = (" (one per element? then the file needs the header line 'Stress Data Type: ELEMENT')"
                if not header.element_stress and len(stress) == len(elements) else "")
        raise TsvFileError(f"{path}:{starts['stress']}: {len(stress)} stress rows for {expected} {owners}{hint}")
    if header.element_stress:
        try:
            stress = nodal_average(vertices, elements, stress)
        except MeshError as error:
            raise TsvFileError(f"{path}: {error}") from None
    forces = sections.get("node_forces", np.zeros((0, 4)))
    if len(forces):
        forces = np.concatenate([_node_ids(path, starts["node_forces"], "Node Forces", forces[:, :1],
                                           len(vertices)), forces[:, 1:]], axis=1)
    fixed = sections.get("fixed_nodes", np.zeros((0, 1)))
    fixed = (_node_ids(path, starts["fixed_nodes"], "Fixed Nodes", fixed, len(vertices))[:, 0] if len(fixed)
             else np.zeros(0, np.int64))
    return TsvModel(vertices, elements, stress, forces, fixed, header.element_stress)


def _unexpected(line, sections, starts):
    """Why ``line`` cannot start a section, and what probably went wrong."""
    if not _not_numbers(line) and sections:
        last = max(starts, key=starts.get)
        return (f"a row of numbers where a section header was expected: does section "
                f"'{_SECTIONS[last][0]}' (line {starts[last]}) announce too few rows?")
    header = "" if sections else f" ({_HEADER_HELP})"
    return f"expected a section header like 'Vertices: N'{header}, got {line[:60]!r}"


def _parse_rows(path, first_row, name, body, width):
    rows = [line.split() for line in body]
    bad = next((i for i, line in enumerate(body) if _not_numbers(line)), None)
    if bad is not None:
        raise TsvFileError(f"{path}: section '{name}' has malformed rows (line {first_row + bad + 1})")
    if width is None:           # elements: as many columns as the first row has
        width = len(rows[0]) if rows else 0
    odd = next((i for i, row in enumerate(rows) if len(row) != width), None)
    if odd is not None:
        raise TsvFileError(f"{path}:{first_row + odd + 1}: section '{name}' rows must have {width} values, "
                           f"this one has {len(rows[odd])}")
    table = np.array(rows, dtype=np.float64).reshape(len(rows), width)
    finite = np.isfinite(table).all(axis=1)
    if not finite.all():
        raise TsvFileError(f"{path}:{first_row + int(np.argmin(finite)) + 1}: section '{name}' holds NaN or inf")
    return table


def _not_numbers(line):
    try:
        [float(x) for x in line.split()]
        return False
    except ValueError:
        return True


def _node_ids(path, header_row, name, table, vertex_count):
    ids = table.astype(np.int64)
    bad = np.any((ids != table) | (ids < 1) | (ids > vertex_count), axis=1)
    if bad.any():
        row = int(np.argmax(bad))
        raise TsvFileError(f"{path}:{header_row + row + 1}: section '{name}' refers to node ids outside "
                           f"1..{vertex_count} (ids are one-based): {' '.join(f'{v:g}' for v in table[row])}")
    return ids - 1


def write_stress_file(path: str | Path, vertices: np.ndarray, elements: np.ndarray, stress: np.ndarray,
                      node_forces: np.ndarray | None = None, fixed_nodes: np.ndarray | None = None,
                      note: str | None = None) -> None:
    """Write a 3D-TSV file (element and node ids one-based).

    A ``.TSV`` name (any case) gets today's header lines and always both
    boundary-condition sections, as 3D-TSV writes them; ``stress`` with one row
    per element (and not per vertex) is written as ``Stress Data Type: ELEMENT``.
    Other names get the early ``.stress`` layout (nodal stress only). A ``note``
    (one line) follows ``Version 2.0`` on its line: 3D-TSV's reader skips that
    line whole, and so the note tells a person what the file holds.
    """
    elements = np.asarray(elements, dtype=np.int64) + 1
    today = Path(path).suffix.lower() == ".tsv"
    element_stress = len(stress) != len(vertices)
    if element_stress and not (today and len(stress) == len(elements)):
        raise ValueError(f"stress must have one row per vertex ({len(vertices)}) or, in a .TSV file, one per "
                         f"element ({len(elements)}); got {len(stress)}")
    forces = np.zeros((0, 4)) if node_forces is None else np.asarray(node_forces, dtype=np.float64).reshape(-1, 4)
    fixed = np.zeros(0, np.int64) if fixed_nodes is None else np.asarray(fixed_nodes, dtype=np.int64)
    with open(path, "w", encoding="ascii") as out:
        if today:
            out.write(f"Version 2.0{'' if note is None else '  ' + note}\n{stress_data_type_line(element_stress)}"
                      f"Solid {'Hex' if elements.shape[1] == 8 else 'Tet'} 1\n")
        out.write(f"Vertices: {len(vertices)}\n")
        np.savetxt(out, np.asarray(vertices), fmt="%.9e")
        out.write(f"Elements: {len(elements)}\n")
        np.savetxt(out, elements, fmt="%d")
        if today or len(forces):
            out.write(f"Node Forces: {len(forces)}\n")
            for node, fx, fy, fz in forces:
                out.write(f"{int(node) + 1} {fx:.9e} {fy:.9e} {fz:.9e}\n")
        if today or len(fixed):
            out.write(f"Fixed Nodes: {len(fixed)}\n")
            np.savetxt(out, fixed + 1, fmt="%d")
        out.write(f"Cartesian Stress: {len(stress)}\n")
        np.savetxt(out, np.asarray(stress), fmt="%.9e")
