"""The specimens' surface as the separation sees it: area-weighted points with their outward normals."""
from __future__ import annotations

from dataclasses import dataclass

import mitsuba as mi
import numpy as np

from .. import occupancy

# Surface points per squared grid spacing: enough that every boundary cell holds several.
POINTS_PER_CELL_FACE = 9
MAX_POINTS = 2_000_000


class SeparationError(ValueError):
    """A field or part the mean stress cannot be separated for."""


@dataclass(frozen=True)
class Surface:
    """``points`` (N, 3) mm on the specimens' surface, ``normals`` (N, 3) outward, ``areas`` (N,) mm^2 each
    stands for."""
    points: np.ndarray
    normals: np.ndarray
    areas: np.ndarray

    def __len__(self) -> int:
        return len(self.points)

    def subset(self, chosen: np.ndarray) -> Surface:
        return Surface(self.points[chosen], self.normals[chosen], self.areas[chosen])

    @property
    def area(self) -> float:
        return float(self.areas.sum())


def specimen_surface(scene: mi.Scene, shapes: list[mi.Shape], spacing: float, seed: int = 0) -> Surface:
    """Points spread evenly by area over the triangle meshes of ``shapes`` (about
    :data:`POINTS_PER_CELL_FACE` per ``spacing``^2), their normals turned outward by the inside test."""
    import trimesh
    parts = []
    for shape in shapes:
        name = shape.id() or shape.class_name()
        if not shape.is_mesh():
            raise SeparationError(f"specimen '{name}' ({shape.class_name()}) is not a mesh: the separation samples "
                                  "its surface's triangles (give the part as a closed mesh)")
        vertices = np.array(shape.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
        faces = np.array(shape.faces_buffer(), dtype=np.int64).reshape(-1, 3)
        # Welded (meshes repeat vertices along creases): a closed part has every edge on two faces.
        mesh = trimesh.Trimesh(vertices, faces, process=True)
        if not mesh.is_watertight or not abs(mesh.volume) > 0:
            raise SeparationError(f"specimen '{name}' is not a closed mesh with a volume: a part's mean stress lives "
                                  "in its volume (give the part as a closed mesh)")
        area = float(mesh.area)
        count = int(min(MAX_POINTS, max(1000, np.ceil(POINTS_PER_CELL_FACE * area / spacing ** 2))))
        points, face = trimesh.sample.sample_surface(mesh, count, seed=seed)
        normals = np.asarray(mesh.face_normals)[face]
        # A mesh wound inwards has inward face normals: a point a little along an outward one lies outside.
        if occupancy.inside(scene, [shape], points + 0.05 * spacing * normals).mean() > 0.5:
            normals = -normals
        parts.append(Surface(np.asarray(points), normals, np.full(count, area / count)))
    return Surface(*(np.concatenate([getattr(p, name) for p in parts]) for name in ("points", "normals", "areas")))
