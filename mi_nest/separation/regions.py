"""Where the part is loaded: no traction condition is imposed there.

A free surface carries no traction (``sigma n = 0``); contacts, fixtures, pressure and cut faces do. The loaded
regions come from the scene's own stress model (where it puts traction on the surface: its contacts, its
pressure, the faces a half-space is cut at) and from regions the user gives (``box:X0,Y0,Z0,X1,Y1,Z1`` in mm, or
``mesh:PATH``, the inside of a closed surface mesh).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import occupancy
from ..fields import StressField
from ..fields.base import sample
from ..physics.tensors import stress_matrices
from .surface import Surface

# The scene's model loads a surface point where its traction exceeds this share of its stress there, or this share
# of the stress scale (a concentrated load's neighbourhood, whatever the stress around; the faceted surface of a
# curved part tilts the normals by a few degrees, so a free surface reads a few % of its stress as traction).
TRACTION_SHARE = 0.1
ABSOLUTE_SHARE = 0.01
FACETED_SHARE = 0.05
# A loaded region reaches this many grid spacings past the points where the traction was found.
MARGIN_CELLS = 2.0

REGION_FORMAT = "box:X0,Y0,Z0,X1,Y1,Z1 (mm) or mesh:PATH (a closed surface mesh)"


class RegionError(ValueError):
    """A loaded region that cannot be read or does not touch the part."""


@dataclass(frozen=True)
class Box:
    """An axis-aligned box of space (mm)."""
    low: tuple[float, float, float]
    high: tuple[float, float, float]

    def contains(self, points: np.ndarray) -> np.ndarray:
        points = np.asarray(points)
        return np.all((points >= np.asarray(self.low)) & (points <= np.asarray(self.high)), axis=-1)

    def __str__(self) -> str:
        return "box:" + ",".join(f"{v:g}" for v in (*self.low, *self.high))


@dataclass(frozen=True)
class MeshRegion:
    """The inside of a closed surface mesh (any format trimesh reads: STL, PLY, OBJ...), in mm."""
    path: str

    def __post_init__(self):
        object.__setattr__(self, "_scene", None)

    def contains(self, points: np.ndarray) -> np.ndarray:
        scene, shape = self._loaded()
        return occupancy.inside(scene, [shape], np.asarray(points))

    def _loaded(self):
        if self._scene is None:
            import mitsuba as mi
            import trimesh
            try:
                mesh = trimesh.load(self.path, force="mesh")
            except (OSError, ValueError) as error:
                raise RegionError(f"loaded region mesh:{self.path} cannot be read ({error})") from None
            if not (mesh.is_watertight and abs(mesh.volume) > 0):
                raise RegionError(f"loaded region mesh:{self.path} is not a closed surface: a region is the inside "
                                  "of a closed mesh")
            shape = mi.Mesh("region", len(mesh.vertices), len(mesh.faces))
            params = mi.traverse(shape)
            params["vertex_positions"] = mi.Float(np.asarray(mesh.vertices, dtype=np.float32).ravel())
            params["faces"] = mi.UInt32(np.asarray(mesh.faces, dtype=np.uint32).ravel())
            params.update()
            scene = mi.load_dict({"type": "scene", "region": shape})
            object.__setattr__(self, "_scene", (scene, scene.shapes()[0]))
        return self._scene

    def __str__(self) -> str:
        return f"mesh:{self.path}"


def parse_region(text: str) -> Box | MeshRegion:
    """A region given on the command line: ``box:X0,Y0,Z0,X1,Y1,Z1`` or ``mesh:PATH``."""
    kind, _, values = str(text).partition(":")
    if kind == "mesh":
        if not Path(values).is_file():
            raise RegionError(f"loaded region mesh file not found: {values} (give a closed surface mesh: STL, PLY, "
                              "OBJ)")
        return MeshRegion(str(Path(values).resolve()))
    if kind != "box":
        raise RegionError(f"a loaded region is {REGION_FORMAT}, got '{text}'")
    try:
        numbers = [float(v) for v in values.split(",")]
    except ValueError:
        numbers = []
    if len(numbers) != 6 or not np.all(np.isfinite(numbers)):
        raise RegionError(f"a loaded region is {REGION_FORMAT} with six finite numbers, got '{text}'")
    low, high = np.minimum(numbers[:3], numbers[3:]), np.maximum(numbers[:3], numbers[3:])
    return Box(tuple(low.tolist()), tuple(high.tolist()))


def tractions(field: StressField, surface: Surface, inward: float) -> tuple[np.ndarray, np.ndarray]:
    """``(N, 3)`` traction ``sigma n`` (MPa) of ``field`` at the surface points and ``(N,)`` the Frobenius norm of
    its stress there, each sampled ``inward`` mm inside (a model masked outside its body reads zero on the surface
    itself)."""
    stress = stress_matrices(sample(field, surface.points - inward * surface.normals))
    return np.einsum("nij,nj->ni", stress, surface.normals), np.linalg.norm(stress, axis=(1, 2))


def model_loaded(field: StressField | None, surface: Surface, scale: float, spacing: float) -> np.ndarray:
    """Which surface points the scene's model ``field`` loads: its traction above :data:`TRACTION_SHARE` of its
    stress there or :data:`ABSOLUTE_SHARE` of ``scale``, widened by :data:`MARGIN_CELLS` spacings (none
    without a model)."""
    if field is None:
        return np.zeros(len(surface), dtype=bool)
    traction, stress = tractions(field, surface, 0.05 * spacing)
    magnitude = np.linalg.norm(traction, axis=-1)
    loaded = (magnitude > TRACTION_SHARE * stress) | ((magnitude > ABSOLUTE_SHARE * scale)
                                                     & (magnitude > FACETED_SHARE * stress))
    return widened(surface, loaded, MARGIN_CELLS * spacing)


def fem_loaded(shapes: list, surface: Surface, spacing: float) -> np.ndarray | None:
    """Which surface points lie near a node that an FEM model behind the specimens loads or holds (3D-TSV node
    forces and fixed nodes, a mesh ``.npz``'s own), within :data:`MARGIN_CELLS` spacings and a node spacing.
    None when no specimen comes from a stress file; none loaded where its file records no loads (an FEM field's
    traction on its faces says little about where it was loaded: its stress is recovered to the nodes)."""
    from scipy.spatial import cKDTree

    from ..fields.sources import load_mesh
    from ..scene import specimen_file
    paths = [specimen_file(shape) for shape in shapes]
    if all(path is None for path in paths):
        return None
    loaded = np.zeros(len(surface), dtype=bool)
    for path in paths:
        mesh = None if path is None else load_mesh(path)
        boundary = None if mesh is None else mesh.boundary
        if boundary is None or not (len(boundary.force_nodes) or len(boundary.fixed_nodes)):
            continue
        held = mesh.nodes[np.concatenate([boundary.force_nodes, boundary.fixed_nodes])]
        node_spacing = float(np.median(cKDTree(mesh.nodes).query(held, k=2)[0][:, 1]))
        distance, _ = cKDTree(held).query(surface.points, distance_upper_bound=MARGIN_CELLS * spacing + node_spacing)
        loaded |= np.isfinite(distance)
    return loaded


def widened(surface: Surface, chosen: np.ndarray, margin: float) -> np.ndarray:
    """``chosen`` and every surface point within ``margin`` mm of one."""
    if not chosen.any():
        return chosen
    from scipy.spatial import cKDTree
    distance, _ = cKDTree(surface.points[chosen]).query(surface.points, distance_upper_bound=margin)
    return np.isfinite(distance)


# A free surface whose full traction left exceeds this share of the stress scale is loaded, or the deviator is
# wrong there: reported, never absorbed.
SUSPECT_TRACTION = 0.25
# Reported only where it covers this many squared spacings (single points are noise).
SUSPECT_CELLS = 4.0


def suspect_loads(free: Surface, traction: np.ndarray, scale: float, spacing: float) -> list[dict]:
    """Patches of the free surface that carry traction ``(N, 3)`` above :data:`SUSPECT_TRACTION` of ``scale``:
    each its centre, area, largest traction (in stress scales) and the ``box:`` that would declare it loaded,
    the largest patch first."""
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree
    magnitude = np.linalg.norm(traction, axis=-1) / scale
    chosen = np.flatnonzero(magnitude > SUSPECT_TRACTION)
    if len(chosen) == 0:
        return []
    points = free.points[chosen]
    pairs = cKDTree(points).query_pairs(2.0 * spacing, output_type="ndarray")
    import scipy.sparse
    graph = scipy.sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                                    shape=(len(points), len(points)))
    count, label = connected_components(graph, directed=False)
    patches = []
    for patch in range(count):
        members = label == patch
        area = float(free.areas[chosen][members].sum())
        if area < SUSPECT_CELLS * spacing ** 2:
            continue
        low, high = points[members].min(axis=0) - spacing, points[members].max(axis=0) + spacing
        patches.append({"center_mm": np.round(points[members].mean(axis=0), 2).tolist(), "area_mm2": round(area, 2),
                        "traction_per_scale": round(float(magnitude[chosen][members].max()), 3),
                        "region": str(Box(tuple(np.round(low, 2).tolist()), tuple(np.round(high, 2).tolist())))})
    return sorted(patches, key=lambda p: -p["area_mm2"])


def suspect_line(patch: dict) -> str:
    """One line on a patch of :func:`suspect_loads`."""
    return (f"the free surface near {tuple(patch['center_mm'])} mm carries traction up to "
            f"{patch['traction_per_scale']:.2f} stress scales over {patch['area_mm2']:.3g} mm^2: if the part is "
            f"loaded there, give --loaded {patch['region']}; if not, the deviator is wrong there")
