"""Stress fields of a loaded scene, sampled on grids and written for ParaView."""
from __future__ import annotations

from pathlib import Path

import mitsuba as mi
import numpy as np

from .arguments import whole_number
from .io.grid import StressGrid, grid_nodes
from .io.vtk import write_grid_vtu
from .scene import specimen_shapes


def specimen_grids(scene: mi.Scene, resolution: int = 64) -> list[StressGrid]:
    """One :class:`StressGrid` per specimen (a shape with a ``stress`` medium), over its bounding box.

    Samples the medium's field at the grid nodes exactly as the renderer evaluates
    it (analytic models included); nodes outside the shape carry the field's value
    there, which the renderer never uses.
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
        values = medium.sample(grid_nodes(lo, hi, counts))
        grids.append(StressGrid(values.reshape(counts[2], counts[1], counts[0], 6), lo, hi))
    return grids


def export_scene_vtu(scene: mi.Scene, output: str | Path, resolution: int = 64) -> list[Path]:
    """Write each specimen's field as ``output`` (``output-<i>.vtu`` when there are several)."""
    grids = specimen_grids(scene, resolution)
    output = Path(output)
    paths = [output] if len(grids) == 1 else [output.with_name(f"{output.stem}-{i}{output.suffix}")
                                              for i in range(len(grids))]
    for grid, path in zip(grids, paths):
        write_grid_vtu(path, grid)
    return paths
