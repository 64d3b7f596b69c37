"""Regions of space that pick the boundary facets (or nodes) where loads and fixtures act.

A region answers ``contains(points)`` for an (N, 3) array (mm) and describes
itself for error messages. A boundary facet belongs to a region when all its
corners do, so a plane picks a flat face and not the facets that merely touch
it along an edge. :class:`NearestNode` instead picks the single boundary node
closest to a point (point supports, the 3-2-1 rule), :class:`Nodes` the mesh
nodes at given points (the fixed and loaded nodes of a 3D-TSV file).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Callable

import numpy as np

from .config import FemError, format_point, number, parse_typed, vector, vectors

if TYPE_CHECKING:
    from skfem import MeshTet

_AXES = "xyz"


def _axis_name(direction):
    """'x', 'y' or 'z' when ``direction`` is a (signed) coordinate axis, else None."""
    index = int(np.argmax(np.abs(direction)))
    return _AXES[index] if abs(abs(direction[index]) - 1.0) < 1e-12 else None


def _unit(name, value):
    v = np.asarray(vector(name, value))
    norm = np.linalg.norm(v)
    if norm == 0:
        raise FemError(f"'{name}' must not be the zero vector")
    return tuple(v / norm)


@dataclass(frozen=True)
class Plane:
    """Points within ``tolerance`` (mm) of the plane through ``point`` with ``normal``."""
    point: tuple
    normal: tuple
    tolerance: float = 1e-3

    def __post_init__(self):
        object.__setattr__(self, "point", vector("point", self.point))
        object.__setattr__(self, "normal", _unit("normal", self.normal))
        object.__setattr__(self, "tolerance", number("tolerance", self.tolerance, positive=True))

    def contains(self, points: np.ndarray) -> np.ndarray:
        return np.abs((points - self.point) @ np.asarray(self.normal)) <= self.tolerance

    def describe(self) -> str:
        axis = _axis_name(self.normal)
        if axis is not None:
            offset = self.point[_AXES.index(axis)]
            return f"plane {axis}={offset:g} within {self.tolerance:g} mm"
        return (f"plane through {format_point(self.point)} with normal {format_point(self.normal)} "
                f"within {self.tolerance:g} mm")


@dataclass(frozen=True)
class Box:
    """Points inside the axis-aligned box ``[min, max]`` (mm), faces included."""
    min: tuple
    max: tuple

    def __post_init__(self):
        object.__setattr__(self, "min", vector("min", self.min))
        object.__setattr__(self, "max", vector("max", self.max))
        if any(lo > hi for lo, hi in zip(self.min, self.max)):
            raise FemError(f"box 'min' {format_point(self.min)} exceeds 'max' {format_point(self.max)}")

    def contains(self, points: np.ndarray) -> np.ndarray:
        return np.all((points >= self.min) & (points <= self.max), axis=1)

    def describe(self) -> str:
        return f"box {format_point(self.min)} to {format_point(self.max)}"


@dataclass(frozen=True)
class Sphere:
    """Points within ``radius`` (mm) of ``center``."""
    center: tuple
    radius: float

    def __post_init__(self):
        object.__setattr__(self, "center", vector("center", self.center))
        object.__setattr__(self, "radius", number("radius", self.radius, positive=True))

    def contains(self, points: np.ndarray) -> np.ndarray:
        return np.linalg.norm(points - self.center, axis=1) <= self.radius

    def describe(self) -> str:
        return f"sphere of radius {self.radius:g} mm around {format_point(self.center)}"


@dataclass(frozen=True)
class CylindricalSurface:
    """Points within ``tolerance`` of the cylinder of ``radius`` about the line (``center``, ``axis``).

    Picks a bore or an outer mantle; add a box to restrict it along the axis.
    """
    radius: float
    center: tuple = (0.0, 0.0, 0.0)
    axis: tuple = (0.0, 0.0, 1.0)
    tolerance: float = 1e-3

    def __post_init__(self):
        object.__setattr__(self, "radius", number("radius", self.radius, positive=True))
        object.__setattr__(self, "center", vector("center", self.center))
        object.__setattr__(self, "axis", _unit("axis", self.axis))
        object.__setattr__(self, "tolerance", number("tolerance", self.tolerance, positive=True))

    def contains(self, points: np.ndarray) -> np.ndarray:
        relative = points - self.center
        along = relative @ np.asarray(self.axis)
        distance = np.linalg.norm(relative - along[:, None] * np.asarray(self.axis), axis=1)
        return np.abs(distance - self.radius) <= self.tolerance

    def describe(self) -> str:
        return (f"cylindrical surface r={self.radius:g} about {format_point(self.axis)} through "
                f"{format_point(self.center)} within {self.tolerance:g} mm")


@dataclass(frozen=True)
class NearestNode:
    """The one boundary node nearest ``point`` (a point support); none if farther than ``max_distance``."""
    point: tuple
    max_distance: float | None = None

    def __post_init__(self):
        object.__setattr__(self, "point", vector("point", self.point))
        if self.max_distance is not None:
            object.__setattr__(self, "max_distance", number("max_distance", self.max_distance, positive=True))

    def describe(self) -> str:
        return f"boundary node nearest {format_point(self.point)}"


@dataclass(frozen=True, eq=False)
class Nodes:
    """The mesh nodes (boundary or interior) at ``points`` (K, 3) mm, each within ``tolerance`` mm."""
    points: object
    tolerance: float = 1e-6

    def __post_init__(self):
        object.__setattr__(self, "points", vectors("points", self.points))
        object.__setattr__(self, "tolerance", number("tolerance", self.tolerance, positive=True))

    def describe(self) -> str:
        return f"{len(self.points)} mesh nodes at given points"


@dataclass(frozen=True)
class Predicate:
    """Points where ``function(points) -> bool array`` holds (Python only, not in spec files)."""
    function: Callable
    label: str = field(default="predicate")

    def contains(self, points: np.ndarray) -> np.ndarray:
        mask = np.asarray(self.function(points), dtype=bool)
        if mask.shape != (len(points),):
            raise FemError(f"{self.label}: predicate must return one bool per point, got shape {mask.shape}")
        return mask

    def describe(self) -> str:
        return self.label


@dataclass(frozen=True)
class Group:
    """A named surface group of the mesh file (a gmsh physical surface, an Abaqus set...)."""
    name: str

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise FemError(f"a surface group needs a non-empty 'name', got {self.name!r}")

    def describe(self) -> str:
        return f"surface group '{self.name}'"


Region = Plane | Box | Sphere | CylindricalSurface | NearestNode | Nodes | Predicate | Group

REGIONS = {"plane": Plane, "box": Box, "sphere": Sphere, "cylindrical_surface": CylindricalSurface,
           "point": NearestNode, "nodes": Nodes, "group": Group}


def parse_region(data: Mapping | Region, where: str) -> Region:
    """A region from its dict form, e.g. ``{"type": "plane", "point": [0, 0, 10], "normal": [0, 0, 1]}``."""
    if isinstance(data, Region):
        return data
    return parse_typed(REGIONS, data, where)


def boundary_facets_in(mesh: MeshTet, region: Region) -> np.ndarray:
    """Indices of the boundary facets of ``mesh`` whose corners all lie in ``region`` (or in its group)."""
    if isinstance(region, Group):
        groups = mesh.boundaries or {}
        if region.name not in groups:
            low, high = mesh.p.min(axis=1), mesh.p.max(axis=1)
            extent = ", ".join(f"{axis} {lo:g} to {hi:g}" for axis, lo, hi in zip(_AXES, low, high))
            raise FemError(f"the mesh has no surface group '{region.name}'; it has {sorted(groups) or 'none'}. "
                           "Name its faces in the mesh file (gmsh physical surfaces in .msh, surface sets in "
                           "Abaqus .inp; .vtu, .stl and 3D-TSV files carry no names) or select them by a plane: "
                           f"x=<v>, y=<v> or z=<v> (a 'plane' region in a spec); the mesh spans {extent} mm")
        return np.intersect1d(groups[region.name], mesh.boundary_facets())
    facets = mesh.boundary_facets()
    corners = mesh.p[:, mesh.facets[:, facets]]               # (3, 3 corners, F)
    inside = region.contains(corners.reshape(3, -1).T).reshape(3, -1)
    return facets[np.all(inside, axis=0)]


def nearest_boundary_node(mesh: MeshTet, point: Sequence[float]) -> tuple[int, float]:
    """``(node index, distance)`` of the boundary node of ``mesh`` nearest ``point``."""
    nodes = mesh.boundary_nodes()
    distance = np.linalg.norm(mesh.p[:, nodes].T - np.asarray(point), axis=1)
    best = int(np.argmin(distance))
    return int(nodes[best]), float(distance[best])


def nodes_at(mesh: MeshTet, region: Nodes, what: str) -> np.ndarray:
    """Indices of the nodes of ``mesh`` at the points of a :class:`Nodes` region."""
    from scipy.spatial import cKDTree
    distance, index = cKDTree(mesh.p.T).query(region.points)
    far = distance > region.tolerance
    if np.any(far):
        first = int(np.argmax(far))
        raise FemError(f"{what}: no mesh node at {format_point(region.points[first])} (the nearest is "
                       f"{distance[first]:.3g} mm away; tolerance {region.tolerance:g} mm)")
    return index
