"""The full stress tensor: the mean stress separated from a deviator by equilibrium (a 3D shear-difference method).

Photoelasticity measures the deviator ``s``; the mean stress ``p`` (``sigma = s + p I``) follows from
equilibrium and the free surfaces (:mod:`.solver`). ``separate(field, scene)`` samples the deviator on a
lattice over the scene's specimens (a reconstruction grid's own nodes), finds where the part is loaded
(:mod:`.regions`), solves for ``p`` and returns the full tensor as a stress grid.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field as dataclass_field
from functools import cached_property
from pathlib import Path

import mitsuba as mi
import numpy as np

from .. import occupancy
from ..fields import StressField
from ..fields.base import sample
from ..fields.grid import GridField
from ..io.atomic import atomic_path
from ..io.grid import StressGrid
from ..physics.tensors import deviatoric_part, tensor_norm
from ..scene import scene_field, specimen_bounds, specimen_shapes
from .regions import Box, MeshRegion, RegionError, fem_loaded, model_loaded, parse_region, suspect_loads
from .solver import Lattice, smooth_extension, solve_mean_stress
from .surface import SeparationError, specimen_surface

__all__ = ["separate", "Separation", "SeparationError", "RegionError", "parse_region", "Box", "MeshRegion",
           "DEFAULT_RESOLUTION"]

DEFAULT_RESOLUTION = 64
# A free surface smaller than this share of the part's surface cannot fix the mean stress reliably.
LEAST_FREE_SHARE = 0.01
FULL_FILE = "full.npz"
RECORD_FILE = "separation.json"
FIGURE_FILE = "separation.png"
LATTICE_OFFSET = 0.618


@dataclass
class Separation:
    """The full stress ``grid`` (``deviator + mean I`` at the lattice's nodes; zero mean outside the cells that
    meet the part), the ``mean`` stress (nz, ny, nx), which nodes lie ``inside`` the part, and ``summary``
    (how it was separated and what it left)."""
    grid: StressGrid
    mean: np.ndarray
    inside: np.ndarray
    summary: dict = dataclass_field(default_factory=dict)
    loaded_points: np.ndarray = dataclass_field(default_factory=lambda: np.zeros((0, 3)))

    @cached_property
    def field(self) -> GridField:
        """The full stress as a field any view or export takes (made once: a texture on the device)."""
        return GridField(self.grid)

    def field_values(self, points: np.ndarray) -> np.ndarray:
        """``(N, 6)`` full stress at ``points`` (mm), trilinear between the lattice's nodes."""
        return sample(self.field, points)

    def save(self, directory: str | Path) -> Path:
        """``directory/full.npz``: a stress grid file (``stress``, ``bbox_min``, ``bbox_max``), with ``mean_stress``
        and ``inside`` beside it."""
        path = Path(directory) / FULL_FILE
        with atomic_path(path, ".npz") as tmp:
            np.savez_compressed(tmp, stress=self.grid.stress, bbox_min=self.grid.bbox_min, bbox_max=self.grid.bbox_max,
                                mean_stress=self.mean.astype(np.float32), inside=self.inside)
        return path

    def write(self, directory: str | Path, record: dict, truth: StressField | None, title: str) -> list[Path]:
        """``full.npz`` (:meth:`save`), ``separation.json`` (``record``, where it came from, with the summary and,
        given the ``truth``, the errors against it: :attr:`summary` gains them) and ``separation.png`` (the mean
        stress on the middle plane, ``title`` above) in ``directory``."""
        from .report import against_truth, write_figure
        if truth is not None:
            self.summary["against_truth"] = against_truth(self, truth)
        directory = Path(directory)
        written = [self.save(directory)]
        with atomic_path(directory / RECORD_FILE, ".json") as tmp:
            Path(tmp).write_text(json.dumps({**record, **self.summary}, indent=2) + "\n")
        written.append(directory / RECORD_FILE)
        written.append(write_figure(directory / FIGURE_FILE, self, truth, title))
        return written


def lattice_of(field: StressField, shapes: list[mi.Shape], resolution: int | None) -> tuple[Lattice, bool]:
    """The lattice to separate on, and whether it is the field's own: a grid field's nodes (unless a
    ``resolution`` is asked), else about ``resolution`` nodes along the specimens' longest side with a margin."""
    own = getattr(field, "node_counts", None)
    if resolution is None and own is not None:
        return Lattice(np.asarray(field.bbox_min, np.float64), np.asarray(field.bbox_max, np.float64),
                       tuple(int(n) for n in own)), True
    resolution = DEFAULT_RESOLUTION if resolution is None else int(resolution)
    if resolution < 8:
        raise SeparationError(f"a separation needs at least 8 nodes along the part, got resolution {resolution}")
    low, high = specimen_bounds(shapes)
    spacing = float((high - low).max()) / (resolution - 1)
    # Nodes off the box's planes by a fraction of a spacing: a model masked outside its body reads zero at a
    # node that lies on its surface to rounding, and the parity test cannot tell such a node's side.
    low = low - LATTICE_OFFSET * spacing
    counts = np.ceil((high - low) / spacing + LATTICE_OFFSET).astype(int) + 1
    return Lattice(low, low + spacing * (counts - 1), tuple(int(c) for c in counts)), False


def _stress_scale(stress6: np.ndarray) -> float:
    """RMS Frobenius norm of ``(N, 6)`` tensors."""
    return float(np.sqrt(np.mean(tensor_norm(stress6) ** 2)))


def scene_loads(scene: mi.Scene, shapes: list, surface, inside_nodes: np.ndarray, spacing: float) -> np.ndarray:
    """The surface points the scene's model loads: near the loaded and fixed nodes of the FEM model behind its
    specimens (none where their files record no loads), or for a stress model, where it puts traction on the
    surface (``inside_nodes``: points inside the part where its stress scale is taken)."""
    by_fem = fem_loaded(shapes, surface, spacing)
    if by_fem is not None:
        return by_fem
    model = scene_field(scene)
    scale = 0.0 if model is None else _stress_scale(sample(model, inside_nodes))
    return model_loaded(model, surface, scale, spacing) if scale > 0 else np.zeros(len(surface), dtype=bool)


def _region_loads(regions: list[Box | MeshRegion], surface, shapes: list) -> np.ndarray:
    """The surface points inside the given loaded regions; a region that touches none is refused."""
    loaded = np.zeros(len(surface), dtype=bool)
    for region in regions:
        touched = region.contains(surface.points)
        if not touched.any():
            low, high = specimen_bounds(shapes)
            raise RegionError(f"loaded region {region} touches no surface of the part (the part spans "
                              f"{np.round(low, 2).tolist()} .. {np.round(high, 2).tolist()} mm)")
        loaded |= touched
    return loaded


def separate(source, scene: mi.Scene, loaded: tuple = (), resolution: int | None = None,
             model_loads: bool = True) -> Separation:
    """The full stress of ``source`` (a reconstruction, any stress field, its trace ignored, or None: the scene's
    own) in ``scene``'s specimens, its mean stress separated by equilibrium.

    ``loaded``: regions (``Box``, ``MeshRegion``, ``"box:X0,Y0,Z0,X1,Y1,Z1"`` or ``"mesh:PATH"``) where the part
    is loaded, besides those of the scene's own stress model (its contacts, pressures and cut faces: where it puts
    traction on the surface; ``model_loads=False`` leaves them out). ``resolution``: nodes along the part's
    longest side (default: a grid field's own nodes, else :data:`DEFAULT_RESOLUTION`).
    """
    start = time.perf_counter()
    field = scene_field(scene) if source is None else getattr(source, "field", source)
    if field is None:
        raise SeparationError("the scene's specimens hold different stress fields: give the field to separate")
    if not isinstance(field, StressField):
        raise SeparationError(f"separate takes a stress field or a reconstruction, got {type(source).__name__}")
    regions = [parse_region(r) if isinstance(r, str) else r for r in loaded]
    shapes = specimen_shapes(scene)
    lattice, own = lattice_of(field, shapes, resolution)
    spacing = float(lattice.spacing.min())
    surface = specimen_surface(scene, shapes, spacing)
    nodes = lattice.nodes()
    node_inside = occupancy.inside(scene, shapes, nodes)
    if not node_inside.any():
        raise SeparationError(f"no node of the {'x'.join(map(str, lattice.shape))} grid lies inside the part: "
                              "raise the resolution")
    deviator = deviatoric_part(sample(field, nodes))
    if not np.all(np.isfinite(deviator[node_inside])):
        raise SeparationError("the field holds NaN or inf inside the part")
    if not own:
        deviator = smooth_extension(deviator, node_inside, lattice.shape)
    scale = _stress_scale(deviator[node_inside])
    if scale == 0:
        raise SeparationError("the field has no deviatoric stress inside the part: nothing to separate")
    by_model = scene_loads(scene, shapes, surface, nodes[node_inside], spacing) if model_loads else \
        np.zeros(len(surface), dtype=bool)
    by_region = _region_loads(regions, surface, shapes)
    free = surface.subset(~(by_model | by_region))
    if free.area < LEAST_FREE_SHARE * surface.area:
        raise SeparationError(f"only {100 * free.area / surface.area:.1f}% of the part's surface is free: the mean "
                              "stress is fixed by free surfaces (sigma n = 0); give fewer loaded regions")

    def inside(points):
        return occupancy.inside(scene, shapes, points)

    solution = solve_mean_stress(lattice, node_inside, deviator, free, surface, inside)
    mean = np.zeros(len(nodes))
    mean[solution.nodes] = solution.mean
    full = deviator.copy()
    full[:, :3] += mean[:, None]
    nx, ny, nz = lattice.shape
    grid = StressGrid(full.reshape(nz, ny, nx, 6).astype(np.float32), lattice.low, lattice.high)
    free_rms = float(np.sqrt(np.sum(free.areas * solution.free_residual ** 2) / free.area))
    # The deviator's own shear on the free surface: no mean stress removes it (a model's or a reconstruction's
    # departure from sigma n = 0, its discretisation or its error).
    normal = np.einsum("ni,ni->n", solution.free_traction, free.normals)
    shear = np.linalg.norm(solution.free_traction - normal[:, None] * free.normals, axis=1)
    shear_rms = float(np.sqrt(np.sum(free.areas * shear ** 2) / free.area))
    suspects = suspect_loads(free, solution.free_traction, scale, spacing)
    summary = {
        "grid": list(lattice.shape), "own_grid": own, "spacing_mm": round(spacing, 4),
        "deviator_scale_mpa": round(scale, 6),
        "loaded": {"by_model": round(float(surface.areas[by_model].sum() / surface.area), 4),
                   "regions": [str(r) for r in regions],
                   "by_regions": round(float(surface.areas[by_region].sum() / surface.area), 4),
                   "free_share": round(free.area / surface.area, 4)},
        "residual": {"interior_per_scale": round(solution.interior_residual * float((lattice.high - lattice.low).max())
                                                 / scale, 6),
                     "free_surface_per_scale": round(free_rms / scale, 6),
                     "free_surface_shear_per_scale": round(shear_rms / scale, 6)},
        "suspect_loads": suspects,
        "cells": solution.cells, "iterations": solution.iterations,
        "seconds": round(time.perf_counter() - start, 2),
    }
    return Separation(grid, mean.reshape(nz, ny, nx), node_inside.reshape(nz, ny, nx), summary,
                      surface.points[by_model | by_region])
