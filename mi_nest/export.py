"""Stress fields of a loaded scene, sampled on grids and written for ParaView (``.vtu``) or 3D-TSV (``.TSV``)."""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import mitsuba as mi
import numpy as np

from . import occupancy
from .arguments import whole_number
from .fields import StressField
from .fields.base import sample
from .io import export_format
from .io.grid import StressGrid, grid_cells, grid_nodes
from .io.tsv import write_stress_file
from .io.vtk import write_mesh_vtu
from .render import require_memory
from .scene import specimen_shapes

# Peak memory of an export per grid node: 420 to 540 bytes measured writing the disk's and the stacked disks'
# .vtu and .TSV at resolutions 128 and 256.
EXPORT_BYTES_PER_NODE = 600


def specimen_grids(scene: mi.Scene, resolution: int = 64, field: StressField | None = None) -> list[StressGrid]:
    """One :class:`StressGrid` per specimen (a shape with a ``stress`` medium), over its bounding box.

    Samples the medium's field (or ``field``, a reconstruction's, in every
    specimen) at the grid nodes exactly as the renderer evaluates it (analytic
    models included); nodes outside the shape carry the field's value there,
    which the renderer never uses.
    """
    # Two nodes per axis at least: one would be a grid of zero spacing, written as a single cell.
    resolution = whole_number("resolution", resolution, minimum=2)
    shapes = specimen_shapes(scene)
    boxes = []
    for shape in shapes:
        box = shape.bbox()
        lo, hi = np.array(box.min, dtype=np.float64).ravel(), np.array(box.max, dtype=np.float64).ravel()
        spacing = (hi - lo).max() / (resolution - 1)
        boxes.append((lo, hi, np.maximum(np.ceil((hi - lo) / spacing).astype(int) + 1, 2)))
    node_count = sum(int(np.prod(counts)) for _, _, counts in boxes)
    require_memory(node_count * EXPORT_BYTES_PER_NODE, f"an export at resolution {resolution} ({node_count} grid "
                   f"nodes in {len(boxes)} specimen(s))", "lower the resolution (mi-nest export --resolution)")
    grids = []
    for shape, (lo, hi, counts) in zip(shapes, boxes):
        nodes = grid_nodes(lo, hi, counts)
        values = shape.interior_medium().sample(nodes) if field is None else sample(field, nodes)
        grids.append(StressGrid(values.reshape(counts[2], counts[1], counts[0], 6), lo, hi))
    return grids


# What the first line of a deviatoric field's .TSV says after its version.
DEVIATORIC_NOTE = "deviatoric stress (trace-free; photoelasticity does not measure the mean stress)"


def export_scene(scene: mi.Scene, output: str | Path, resolution: int = 64,
                 field: StressField | None = None, deviatoric: bool = False,
                 point_data: Callable[[np.ndarray], dict[str, np.ndarray]] | None = None) -> list[Path]:
    """Write each specimen's field (or ``field`` in each) as ``output`` (``output-<i>.<suffix>`` when there
    are several): the hexahedra of a grid over its bounding box whose centres lie inside the specimen, as
    ``.vtu`` or as ``.TSV`` (what 3D-TSV traces stress lines through). A ``deviatoric`` field (a
    reconstruction's) is labelled so in both: the ``.vtu``'s arrays are ``deviatoric_stress``, ``s_1``...,
    the ``.TSV``'s first line says it. ``point_data(nodes)`` adds arrays to the ``.vtu`` (a reconstruction's
    trust map, ``TrustMap.point_data``; 3D-TSV holds stress only)."""
    output = Path(output)
    kind = export_format(output)
    grids = specimen_grids(scene, resolution, field)
    paths = [output] if len(grids) == 1 else [output.with_name(f"{output.stem}-{i}{output.suffix}")
                                              for i in range(len(grids))]
    for shape, grid, path in zip(specimen_shapes(scene), grids, paths):
        nodes, cells, stress = _inside_hexahedra(scene, shape, grid)
        if kind == ".vtu":
            write_mesh_vtu(path, nodes, cells, stress, deviatoric, None if point_data is None else point_data(nodes))
        else:
            write_stress_file(path, nodes, cells, stress, note=DEVIATORIC_NOTE if deviatoric else None)
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
