"""Tetrahedral meshes for the FEM solve: BSD-licensed primitives, files, optional gmsh.

The primitives need only NumPy and scikit-fem (both BSD):

* :class:`BoxGeometry` -- an axis-aligned box, a tensor grid of cubes cut into
  six tetrahedra each (``skfem.MeshTet.init_tensor``);
* :class:`CylinderGeometry` -- a solid cylinder or disk;
* :class:`TubeGeometry` -- a hollow cylinder (annulus), for Lame's problem.

Cylinders are extrusions of a triangulated cross-section: concentric rings of
nodes (about one ``element_size`` apart along and across the rings) stitched
into triangles, stacked in layers, each triangular prism cut into three
tetrahedra. The cut of every quadrilateral side runs from the lower-numbered
bottom node to the higher-numbered top node, a rule both prisms sharing the side
apply identically, so the tetrahedra are conforming without any search.

:class:`MeshFileGeometry` reads volume meshes (gmsh ``.msh`` 2.2 or 4, ``.vtu``,
``.vtk``, ... through meshio, MIT; named surfaces from gmsh physical surfaces and
Abaqus sets; the meshes of 3D-TSV stress files, hexahedra cut into six
tetrahedra) and, when the optional ``gmsh`` extra is
installed (``pip install mi_nest[gmsh]``; gmsh is GPL, so it is never a hard
dependency), tetrahedralises closed surfaces (``.stl``, ``.ply``, ``.obj``).
"""
from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass
from collections.abc import Mapping
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from ..io.cells import signed_volumes
from .config import FemError, number, parse_typed, vector

if TYPE_CHECKING:
    import trimesh
    from skfem import MeshTet

SURFACE_SUFFIXES = (".stl", ".ply", ".obj", ".off", ".glb", ".gltf")


# --------------------------------------------------------------------------- cross-sections

def _ring(radius, count):
    angle = 2.0 * np.pi * np.arange(count) / count
    return np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1), angle


def _stitch(inner, inner_angle, outer, outer_angle):
    """Triangles filling the strip between two closed, counter-clockwise rings of node ids.

    Walk both rings in order of angle (a merge of their angle lists): each step
    advances one ring by one node and makes the triangle of that edge with the
    current node of the other ring.
    """
    n_in, n_out = len(inner), len(outer)
    # Angle at which each ring edge ends (the last edge closes the ring at 2 pi + start).
    ends = np.concatenate([np.append(inner_angle[1:], inner_angle[0] + 2 * np.pi),
                           np.append(outer_angle[1:], outer_angle[0] + 2 * np.pi)])
    from_inner = np.concatenate([np.ones(n_in, bool), np.zeros(n_out, bool)])
    from_inner = from_inner[np.argsort(ends, kind="stable")]
    i = np.cumsum(from_inner) - from_inner                    # inner position before each step
    j = np.cumsum(~from_inner) - ~from_inner                  # outer position before each step
    inner_step = np.stack([inner[i % n_in], inner[(i + 1) % n_in], outer[j % n_out]], axis=1)
    outer_step = np.stack([inner[i % n_in], outer[(j + 1) % n_out], outer[j % n_out]], axis=1)
    return np.where(from_inner[:, None], inner_step, outer_step)


def disk_triangles(radius: float, element_size: float) -> tuple[np.ndarray, np.ndarray]:
    """``(points (P, 2), triangles (T, 3))`` of a disk: a centre node and rings of 6k nodes."""
    rings = max(1, round(radius / element_size))
    points, triangles = [np.zeros((1, 2))], []
    previous, previous_angle = None, None
    start = 1
    for k in range(1, rings + 1):
        ring_points, angle = _ring(radius * k / rings, 6 * k)
        ids = start + np.arange(6 * k)
        if previous is None:                                  # fan around the centre node
            triangles.append(np.stack([np.zeros(6, np.int64), ids, np.roll(ids, -1)], axis=1))
        else:
            triangles.append(_stitch(previous, previous_angle, ids, angle))
        points.append(ring_points)
        previous, previous_angle, start = ids, angle, start + 6 * k
    return np.concatenate(points), np.concatenate(triangles)


def annulus_triangles(inner_radius: float, outer_radius: float, element_size: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """``(points, triangles)`` of an annulus: rings about ``element_size`` apart both ways."""
    rings = max(1, round((outer_radius - inner_radius) / element_size))
    points, triangles = [], []
    previous, previous_angle, start = None, None, 0
    for k in range(rings + 1):
        r = inner_radius + (outer_radius - inner_radius) * k / rings
        count = max(8, round(2 * np.pi * r / element_size))
        ring_points, angle = _ring(r, count)
        ids = start + np.arange(count)
        if previous is not None:
            triangles.append(_stitch(previous, previous_angle, ids, angle))
        points.append(ring_points)
        previous, previous_angle, start = ids, angle, start + count
    return np.concatenate(points), np.concatenate(triangles)


def extrude(points: np.ndarray, triangles: np.ndarray, height: float, layers: int) -> tuple[np.ndarray, np.ndarray]:
    """Tetrahedra ``(nodes (N, 3), tets (M, 4))`` of a cross-section extruded along z over [0, height]."""
    z = np.linspace(0.0, height, layers + 1)
    count = len(points)
    nodes = np.concatenate([np.column_stack([points, np.full(count, level)]) for level in z])
    a, b, c = np.sort(triangles, axis=1).T                    # a < b < c fixes every side's cut
    tets = []
    for layer in range(layers):
        a0, b0, c0 = a + layer * count, b + layer * count, c + layer * count
        a1, b1, c1 = a0 + count, b0 + count, c0 + count
        # Side (a, b) is cut a0-b1, (a, c) a0-c1 and (b, c) b0-c1: lower bottom to higher top.
        tets += [np.stack([a0, b0, c0, c1], 1), np.stack([a0, b0, b1, c1], 1), np.stack([a0, a1, b1, c1], 1)]
    return nodes, np.concatenate(tets)


def _to_skfem(nodes, tets, surface_groups=None):
    from skfem import MeshTet
    used, tets = np.unique(tets, return_inverse=True)         # drop nodes no tetrahedron uses
    tets = tets.reshape(-1, 4)
    nodes = np.asarray(nodes, dtype=np.float64)[used]
    volume = signed_volumes(nodes, tets) / 6.0
    extent = np.ptp(nodes, axis=0).max()
    if np.any(np.abs(volume) <= 1e-12 * extent ** 3):
        raise FemError(f"the mesh has {int(np.sum(np.abs(volume) <= 1e-12 * extent ** 3))} degenerate "
                       f"(zero-volume) tetrahedra")
    mesh = MeshTet(np.ascontiguousarray(nodes.T), np.ascontiguousarray(tets.T.astype(np.int64)))
    if surface_groups:
        mesh = mesh.with_boundaries({name: _facets_of(mesh, used, triangles, name)
                                     for name, triangles in surface_groups.items()})
    return mesh


def _facets_of(mesh, used, triangles, name):
    """Facet indices of ``mesh`` for triangles given by original node ids."""
    position = np.searchsorted(used, triangles)
    if np.any(position >= len(used)) or np.any(used[np.minimum(position, len(used) - 1)] != triangles):
        raise FemError(f"surface group '{name}' uses nodes of no tetrahedron")
    count = np.int64(mesh.p.shape[1])

    def key(corners: np.ndarray) -> np.ndarray:
        corners = np.sort(corners, axis=-1).astype(np.int64)
        return (corners[..., 0] * count + corners[..., 1]) * count + corners[..., 2]
    facet_keys = key(mesh.facets.T)
    order = np.argsort(facet_keys)
    wanted = key(position)
    found = np.searchsorted(facet_keys[order], wanted)
    found = np.minimum(found, len(order) - 1)
    matched = facet_keys[order][found] == wanted
    if not np.all(matched):
        raise FemError(f"surface group '{name}': {int(np.sum(~matched))} of its triangles are not faces "
                       "of the tetrahedra")
    return np.unique(order[found])


# Right-handed placements of a local frame whose z is the cylinder axis.
_AXIS_PERMUTATION = {"x": [2, 0, 1], "y": [1, 2, 0], "z": [0, 1, 2]}


def _placed(nodes, center, axis, height):
    local = nodes - np.array([0.0, 0.0, 0.5 * height])        # centred along the axis
    if axis not in _AXIS_PERMUTATION:
        raise FemError(f"'axis' must be 'x', 'y' or 'z', got {axis!r}")
    # World coordinate i is local coordinate permutation[i].
    return local[:, _AXIS_PERMUTATION[axis]] + np.asarray(center)


# --------------------------------------------------------------------------- geometries

@dataclass(frozen=True)
class BoxGeometry:
    """Box of ``size`` (mm) with its minimum corner at ``origin``; ``element_size`` defaults to size/10."""
    size: tuple
    origin: tuple = (0.0, 0.0, 0.0)
    element_size: float | None = None

    def __post_init__(self):
        object.__setattr__(self, "size", vector("size", self.size))
        if min(self.size) <= 0:
            raise FemError(f"'size' must be positive, got {self.size}")
        object.__setattr__(self, "origin", vector("origin", self.origin))
        if self.element_size is not None:
            object.__setattr__(self, "element_size", number("element_size", self.element_size, positive=True))

    def mesh(self) -> MeshTet:
        from skfem import MeshTet
        h = self.element_size or max(self.size) / 10.0
        axes = [o + np.linspace(0.0, s, max(1, round(s / h)) + 1) for o, s in zip(self.origin, self.size)]
        return MeshTet.init_tensor(*axes)


def _validate_placement(geometry):
    """Check and normalise the ``center``, ``axis`` and ``element_size`` of a round primitive."""
    object.__setattr__(geometry, "center", vector("center", geometry.center))
    if geometry.axis not in _AXIS_PERMUTATION:
        raise FemError(f"'axis' must be 'x', 'y' or 'z', got {geometry.axis!r}")
    if geometry.element_size is not None:
        object.__setattr__(geometry, "element_size", number("element_size", geometry.element_size, positive=True))


@dataclass(frozen=True)
class CylinderGeometry:
    """Solid cylinder (a disk when thin) of ``radius`` and ``height`` about ``axis`` through ``center``.

    ``center`` is the centroid; ``element_size`` defaults to the larger of radius/5 and height/10.
    """
    radius: float
    height: float
    center: tuple = (0.0, 0.0, 0.0)
    axis: str = "z"
    element_size: float | None = None

    def __post_init__(self):
        object.__setattr__(self, "radius", number("radius", self.radius, positive=True))
        object.__setattr__(self, "height", number("height", self.height, positive=True))
        _validate_placement(self)

    def mesh(self) -> MeshTet:
        h = self.element_size or max(self.radius / 5.0, self.height / 10.0)
        points, triangles = disk_triangles(self.radius, h)
        nodes, tets = extrude(points, triangles, self.height, max(1, round(self.height / h)))
        return _to_skfem(_placed(nodes, self.center, self.axis, self.height), tets)


@dataclass(frozen=True)
class TubeGeometry:
    """Hollow cylinder, radii ``inner_radius`` < ``outer_radius``, ``height`` along ``axis``."""
    inner_radius: float
    outer_radius: float
    height: float
    center: tuple = (0.0, 0.0, 0.0)
    axis: str = "z"
    element_size: float | None = None

    def __post_init__(self):
        for name in ("inner_radius", "outer_radius", "height"):
            object.__setattr__(self, name, number(name, getattr(self, name), positive=True))
        if self.inner_radius >= self.outer_radius:
            raise FemError(f"'inner_radius' ({self.inner_radius:g}) must be smaller than "
                           f"'outer_radius' ({self.outer_radius:g})")
        _validate_placement(self)

    def mesh(self) -> MeshTet:
        wall = self.outer_radius - self.inner_radius
        h = self.element_size or max(wall / 4.0, self.height / 10.0)
        points, triangles = annulus_triangles(self.inner_radius, self.outer_radius, h)
        nodes, tets = extrude(points, triangles, self.height, max(1, round(self.height / h)))
        return _to_skfem(_placed(nodes, self.center, self.axis, self.height), tets)


@dataclass(frozen=True)
class MeshFileGeometry:
    """A volume mesh file (tetrahedra, via meshio) or a closed surface meshed with gmsh.

    Relative paths resolve against ``base`` (the spec file's folder).
    ``element_size`` (mm) applies to surfaces only; the default is 1/20 of the
    bounding box diagonal.
    """
    path: str
    element_size: float | None = None
    base: str = ""

    def __post_init__(self):
        if not isinstance(self.path, (str, Path)) or not str(self.path):
            raise FemError(f"'path' must be a file name, got {self.path!r}")
        if self.element_size is not None:
            object.__setattr__(self, "element_size", number("element_size", self.element_size, positive=True))

    def mesh(self) -> MeshTet:
        from ..fields.sources import is_tsv_file, load_mesh
        path = Path(self.base) / Path(self.path)
        if not path.is_file():
            raise FemError(f"mesh file not found: {path}")
        if is_tsv_file(path):
            tsv = load_mesh(path)
            return _to_skfem(tsv.nodes, tsv.tets)
        if path.suffix.lower() in SURFACE_SUFFIXES:
            return mesh_surface(path, self.element_size)
        return read_volume_mesh(path)


Geometry = BoxGeometry | CylinderGeometry | TubeGeometry | MeshFileGeometry

GEOMETRIES = {"box": BoxGeometry, "cylinder": CylinderGeometry, "tube": TubeGeometry,
              "file": MeshFileGeometry}


def parse_geometry(data: Mapping | Geometry, where: str = "geometry") -> Geometry:
    if isinstance(data, Geometry):
        return data
    return parse_typed(GEOMETRIES, data, where)


# --------------------------------------------------------------------------- files and gmsh

def read_volume_mesh(path: str | Path) -> MeshTet:
    """The tetrahedra of a volume mesh file (any format meshio reads); 10-node tets keep their corners."""
    import meshio
    try:
        data = meshio.read(path)
    except Exception as error:    # meshio raises many types for unreadable files
        raise FemError(f"{path}: cannot read as a volume mesh ({error})") from error
    tets = [block.data[:, :4] for block in data.cells if block.type in ("tetra", "tetra10")]
    if not tets:
        kinds = sorted({block.type for block in data.cells})
        raise FemError(f"{path}: no tetrahedra in the file (cells: {', '.join(kinds) or 'none'}); "
                       f"surface meshes need a surface suffix ({', '.join(SURFACE_SUFFIXES)}) and gmsh")
    try:
        return _to_skfem(data.points[:, :3], np.concatenate(tets), _surface_groups(data))
    except FemError as error:
        raise FemError(f"{path}: {error}") from None


def _surface_groups(data):
    """Named sets of boundary triangles: meshio ``cell_sets`` (gmsh 4 physical groups, Abaqus sets) and
    the gmsh physical surfaces named in ``field_data``, which is all meshio keeps of a gmsh 2.2 file's
    groups (a ``gmsh:physical`` tag per cell, ``field_data[name] = [tag, dimension]``)."""
    def triangles_of(blocks_and_picks):
        triangles = [block.data[pick][:, :3] for block, pick in blocks_and_picks
                     if block.type in ("triangle", "triangle6") and np.size(block.data[pick])]
        return np.concatenate(triangles) if triangles else None

    groups = {}
    for name, per_block in data.cell_sets.items():
        if name.startswith("gmsh:"):     # meshio's own bookkeeping (bounding entities), not a group
            continue
        triangles = triangles_of((block, np.asarray(indices, dtype=np.int64))
                                 for block, indices in zip(data.cells, per_block))
        if triangles is not None:
            groups[name] = triangles
    physical = data.cell_data.get("gmsh:physical")
    for name, value in data.field_data.items():
        if physical is None or name in groups or np.shape(value) != (2,) or value[1] != 2:
            continue
        triangles = triangles_of((block, tags == value[0]) for block, tags in zip(data.cells, physical))
        if triangles is not None:
            groups[name] = triangles
    return groups


def require_gmsh() -> ModuleType:
    """The ``gmsh`` module, or a FemError saying how to install the optional extra."""
    try:
        import gmsh
    except ImportError as error:
        raise FemError("meshing a surface into tetrahedra needs gmsh, an optional dependency (GPL): "
                       "pip install 'mi_nest[gmsh]' (or pip install gmsh); or mesh it elsewhere and "
                       f"pass a volume mesh (.msh, .vtu) instead ({error})") from None
    return gmsh


def mesh_surface(surface: str | Path | trimesh.Trimesh, element_size: float | None = None) -> MeshTet:
    """Tetrahedralise a closed surface (a file trimesh reads, or a ``trimesh.Trimesh``) with gmsh.

    The surface is re-meshed at ``element_size`` (gmsh classifies it into
    patches at sharp edges first, so flat faces stay flat).
    """
    import trimesh
    if not isinstance(surface, trimesh.Trimesh):
        loaded = trimesh.load(surface, force="mesh")
        if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
            raise FemError(f"{surface}: not a triangle surface mesh")
        surface = loaded
    if not surface.is_watertight:
        raise FemError("the surface is not closed (watertight), so it bounds no volume to mesh")
    gmsh = require_gmsh()
    size = element_size or float(np.linalg.norm(np.ptp(surface.vertices, axis=0))) / 20.0
    with tempfile.TemporaryDirectory() as folder:
        stl = Path(folder) / "surface.stl"
        surface.export(stl)
        owner = not gmsh.isInitialized()          # leave a caller's own gmsh session running
        if owner:
            gmsh.initialize(interruptible=False)
        try:
            gmsh.option.setNumber("General.Terminal", 0)
            gmsh.model.add("mi_nest_specimen")
            gmsh.merge(str(stl))
            # Split at sharp edges (40 degrees), rebuild a parametrisation, re-mesh at ``size``.
            gmsh.model.mesh.classifySurfaces(math.radians(40), True, True, math.pi)
            gmsh.model.mesh.createGeometry()
            surfaces = [tag for _, tag in gmsh.model.getEntities(2)]
            loop = gmsh.model.geo.addSurfaceLoop(surfaces)
            gmsh.model.geo.addVolume([loop])
            gmsh.model.geo.synchronize()
            gmsh.option.setNumber("Mesh.MeshSizeMin", 0.5 * size)
            gmsh.option.setNumber("Mesh.MeshSizeMax", size)
            gmsh.model.mesh.generate(3)
            tags, coordinates, _ = gmsh.model.mesh.getNodes()
            _, tet_nodes = gmsh.model.mesh.getElementsByType(4)
        except Exception as error:   # gmsh raises plain Exception with its log message
            raise FemError(f"gmsh could not mesh the surface: {error}") from error
        finally:
            if owner:
                gmsh.finalize()
            else:
                gmsh.model.remove()
    index = np.zeros(int(tags.max()) + 1, dtype=np.int64)
    index[tags.astype(np.int64)] = np.arange(len(tags))
    return _to_skfem(coordinates.reshape(-1, 3), index[tet_nodes.astype(np.int64)].reshape(-1, 4))
