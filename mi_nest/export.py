"""Stress fields of a loaded scene, sampled on grids and written for ParaView (``.vtu``) or 3D-TSV (``.TSV``)."""
from __future__ import annotations

from pathlib import Path

import mitsuba as mi
import numpy as np

from . import occupancy
from .arguments import whole_number
from .fields import StressField
from .fields.base import sample
from .io import export_format
from .io.grid import StressGrid, grid_cells, grid_nodes
from .io.tsv import write_stress_file
from .io.vtk import write_grid_vtu
from .scene import specimen_shapes


def specimen_grids(scene: mi.Scene, resolution: int = 64, field: StressField | None = None) -> list[StressGrid]:
    """One :class:`StressGrid` per specimen (a shape with a ``stress`` medium), over its bounding box.

    Samples the medium's field (or ``field``, a reconstruction's, in every
    specimen) at the grid nodes exactly as the renderer evaluates it (analytic
    models included); nodes outside the shape carry the field's value there,
    which the renderer never uses.
    """
    # Two nodes per axis at least: one would be a grid of zero spacing, written as a single cell.
    resolution = whole_number("resolution", resolution, minimum=2)
    grids = []
    for shape in specimen_shapes(scene):
        medium = shape.interior_medium()
        box = shape.bbox()
        lo, hi = np.array(box.min, dtype=np.float64).ravel(), np.array(box.max, dtype=np.float64).ravel()
        spacing = (hi - lo).max() / (resolution - 1)
        counts = np.maximum(np.ceil((hi - lo) / spacing).astype(int) + 1, 2)
        nodes = grid_nodes(lo, hi, counts)
        values = medium.sample(nodes) if field is None else sample(field, nodes)
        grids.append(StressGrid(values.reshape(counts[2], counts[1], counts[0], 6), lo, hi))
    return grids


def export_scene(scene: mi.Scene, output: str | Path, resolution: int = 64,
                 field: StressField | None = None) -> list[Path]:
    """Write each specimen's field (or ``field`` in each) as ``output`` (``output-<i>.<suffix>`` when there
    are several): ``.vtu`` over its bounding box, ``.TSV`` as the hexahedra of that grid whose centres lie
    inside the specimen (what 3D-TSV traces stress lines through)."""
    output = Path(output)
    kind = export_format(output)
    grids = specimen_grids(scene, resolution, field)
    paths = [output] if len(grids) == 1 else [output.with_name(f"{output.stem}-{i}{output.suffix}")
                                              for i in range(len(grids))]
    for shape, grid, path in zip(specimen_shapes(scene), grids, paths):
        if kind == ".vtu":
            write_grid_vtu(path, grid)
        else:
            write_stress_file(path, *_inside_hexahedra(scene, shape, grid))
    return paths


def _inside_hexahedra(scene, shape, grid):
    """``(nodes, hexahedra, stress)``: the grid's cells whose centres lie inside ``shape``, and their nodes."""
    nodes, cells, stress = grid_cells(grid)
    keep = occupancy.inside(scene, [shape], nodes[cells].mean(axis=1))
    if not keep.any():
        nz, ny, nx = grid.stress.shape[:3]
        raise ValueError(f"no cell of a {nx}x{ny}x{nz} grid lies inside specimen '{shape.id()}': raise the "
                         "resolution")
    cells = cells[keep]
    used, renumbered = np.unique(cells, return_inverse=True)
    return nodes[used], renumbered.reshape(cells.shape), stress[used]
