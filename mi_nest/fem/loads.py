"""Declarative loads and fixtures, and what they become on a scikit-fem basis.

Units: mm, N, MPa. Loads:

* :class:`PointForce` -- a force (N) at the boundary node nearest ``point``, or
  shared equally by the boundary nodes within ``radius`` of it;
* :class:`SurfaceForce` -- a total force (N) spread uniformly (per area) over the
  boundary facets in a region;
* :class:`Traction` -- a traction vector (MPa = N/mm^2) on the facets in a region;
* :class:`Pressure` -- a normal pressure (MPa), positive pushing into the body;
* :class:`NodeForces` -- a force (N) at each of a set of mesh nodes (the node
  forces of a 3D-TSV file).

Displacements live on a scalar Lagrange basis (P1 or P2) with three vector dofs
per scalar dof ``d``: ``3 d + 0, 1, 2`` for x, y, z.

A :class:`Fixture` prescribes displacement components (zero by default) on the
boundary facets in a region, at the boundary node nearest a point, or at the
mesh nodes of a :class:`~mi_nest.fem.regions.Nodes` region: all three
components clamp, one or two make roller / symmetry supports.

Fixtures must remove all six rigid-body motions; :func:`check_rigid_modes`
proves that before solving (the constrained rows of the rigid-mode matrix must
have rank 6) and names the motions left free otherwise.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .config import FemError, format_point, number, parse_fields, parse_typed, vector, vectors
from .regions import NearestNode, Nodes, boundary_facets_in, nearest_boundary_node, nodes_at, parse_region

if TYPE_CHECKING:
    from skfem import CellBasis, MeshTet

_COMPONENTS = {"x": 0, "y": 1, "z": 2}


def _name(value):
    if not isinstance(value, str) or not value:
        raise FemError(f"'name' must be a non-empty string, got {value!r}")
    return value


@dataclass(frozen=True)
class PointForce:
    """``force`` (N) at the boundary node nearest ``point``, or split over those within ``radius``."""
    name: str
    point: tuple
    force: tuple
    radius: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "name", _name(self.name))
        object.__setattr__(self, "point", vector("point", self.point))
        object.__setattr__(self, "force", vector("force", self.force))
        object.__setattr__(self, "radius", number("radius", self.radius, nonnegative=True))


@dataclass(frozen=True)
class SurfaceForce:
    """Total ``force`` (N) spread uniformly over the area of the boundary facets in ``where``."""
    name: str
    where: object
    force: tuple

    def __post_init__(self):
        object.__setattr__(self, "name", _name(self.name))
        object.__setattr__(self, "where", parse_region(self.where, "region"))
        object.__setattr__(self, "force", vector("force", self.force))


@dataclass(frozen=True)
class Traction:
    """Traction vector (MPa) on the boundary facets in ``where``."""
    name: str
    where: object
    traction: tuple

    def __post_init__(self):
        object.__setattr__(self, "name", _name(self.name))
        object.__setattr__(self, "where", parse_region(self.where, "region"))
        object.__setattr__(self, "traction", vector("traction", self.traction))


@dataclass(frozen=True)
class Pressure:
    """Normal pressure (MPa) on the boundary facets in ``where``; positive pushes into the body."""
    name: str
    where: object
    pressure: float

    def __post_init__(self):
        object.__setattr__(self, "name", _name(self.name))
        object.__setattr__(self, "where", parse_region(self.where, "region"))
        object.__setattr__(self, "pressure", number("pressure", self.pressure))


@dataclass(frozen=True, eq=False)
class NodeForces:
    """``forces[k]`` (N) at the mesh node at ``where.points[k]`` (``where`` is a ``nodes`` region)."""
    name: str
    where: object
    forces: object

    def __post_init__(self):
        object.__setattr__(self, "name", _name(self.name))
        object.__setattr__(self, "where", parse_region(self.where, "region"))
        if not isinstance(self.where, Nodes):
            raise FemError(f"node forces act on a 'nodes' region, got {self.where.describe()}")
        object.__setattr__(self, "forces", vectors("forces", self.forces))
        if len(self.forces) != len(self.where.points):
            raise FemError(f"{len(self.forces)} forces for {len(self.where.points)} nodes: give one per node")


@dataclass(frozen=True)
class Fixture:
    """Prescribed ``displacement`` (mm) of ``components`` on the boundary facets in ``where``.

    ``components`` is a subset of ``("x", "y", "z")``: all three clamp, a single
    normal component makes a roller (symmetry) support. ``where`` of type
    ``point`` fixes only the boundary node nearest that point.
    """
    name: str
    where: object
    components: tuple = ("x", "y", "z")
    displacement: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self):
        object.__setattr__(self, "name", _name(self.name))
        object.__setattr__(self, "where", parse_region(self.where, "region"))
        components = (self.components,) if isinstance(self.components, str) else tuple(self.components)
        bad = [c for c in components if c not in _COMPONENTS]
        if bad or not components or len(set(components)) != len(components):
            raise FemError(f"'components' must be distinct names among 'x', 'y', 'z', got {self.components!r}")
        object.__setattr__(self, "components", components)
        object.__setattr__(self, "displacement", vector("displacement", self.displacement))


Load = PointForce | SurfaceForce | Traction | Pressure | NodeForces

LOADS = {"point_force": PointForce, "force": SurfaceForce, "traction": Traction, "pressure": Pressure,
         "node_forces": NodeForces}


def parse_load(data: Mapping | Load, index: int = 0) -> Load:
    """A load from its dict form; ``type`` is one of :data:`LOADS`."""
    if isinstance(data, Load):
        return data
    label = data.get("name", f"#{index + 1}") if isinstance(data, dict) else f"#{index + 1}"
    return parse_typed(LOADS, data, f"load '{label}'")


def parse_fixture(data: Mapping | Fixture, index: int = 0) -> Fixture:
    if isinstance(data, Fixture):
        return data
    label = data.get("name", f"#{index + 1}") if isinstance(data, dict) else f"#{index + 1}"
    return parse_fields(Fixture, data, f"fixture '{label}'")


def _unique_names(items, kind):
    seen = set()
    for item in items:
        if item.name in seen:
            raise FemError(f"two {kind}s are named '{item.name}'; names must be unique")
        seen.add(item.name)


# --------------------------------------------------------------------------- assembly

def _selected_facets(mesh, region, what):
    if isinstance(region, (NearestNode, Nodes)):
        picked = "a single node" if isinstance(region, NearestNode) else "a set of nodes"
        raise FemError(f"{what} acts on a surface but its region is {picked} ({region.describe()}); "
                       f"use a plane, box, sphere or cylindrical_surface region, or a point_force")
    facets = boundary_facets_in(mesh, region)
    if len(facets) == 0:
        raise FemError(f"{what} selects no boundary facet: {region.describe()}")
    return facets


def load_vector(basis: CellBasis, loads: Sequence[Load]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Global load vector (3 dofs per scalar dof ``d``: ``3 d + component``) and each load's total force (N).

    ``basis`` is the *scalar* Lagrange basis of the displacement components.
    """
    from skfem import FacetBasis, LinearForm

    _unique_names(loads, "load")
    mesh = basis.mesh
    f = np.zeros((basis.N, 3))
    totals = {}
    for load in loads:
        what = f"load '{load.name}'"
        part = np.zeros((basis.N, 3))
        if isinstance(load, PointForce):
            nodes = _point_nodes(mesh, load, what)
            # A point force at a vertex is its vertex-dof entry: exact for P1 and P2 alike.
            np.add.at(part, basis.nodal_dofs[0, nodes], np.asarray(load.force) / len(nodes))
        elif isinstance(load, NodeForces):
            np.add.at(part, basis.nodal_dofs[0, nodes_at(mesh, load.where, what)], load.forces)
        else:
            facets = _selected_facets(mesh, load.where, what)
            facet_basis = FacetBasis(mesh, basis.elem, facets=facets)
            if isinstance(load, Pressure):
                pressure = load.pressure
                for c in range(3):
                    # Outward normal n: a positive pressure pushes along -n.
                    part[:, c] = LinearForm(lambda v, w: -pressure * w.n[c] * v).assemble(facet_basis)
            else:
                if isinstance(load, SurfaceForce):
                    traction = np.asarray(load.force) / _facet_area(mesh, facets)
                else:
                    traction = np.asarray(load.traction)
                shape_integrals = LinearForm(lambda v, w: v).assemble(facet_basis)
                part = shape_integrals[:, None] * traction
        f += part
        # Lagrange shape functions sum to one, so a component's entries sum to its total force.
        totals[load.name] = part.sum(axis=0)
    return f.ravel(), totals


def _facet_area(mesh, facets):
    corners = mesh.p[:, mesh.facets[:, facets]]               # (3, 3 corners, F), straight facets
    return 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0],
                                         axis=0), axis=0).sum()


def _nearest(mesh, region, what):
    node, distance = nearest_boundary_node(mesh, region.point)
    if region.max_distance is not None and distance > region.max_distance:
        raise FemError(f"{what} selects no boundary node: the nearest to {format_point(region.point)} is "
                       f"{distance:.3g} mm away (max_distance {region.max_distance:g} mm)")
    return node


def _point_nodes(mesh, load, what):
    if load.radius == 0.0:
        return np.array([_nearest(mesh, NearestNode(load.point), what)])
    candidates = mesh.boundary_nodes()
    distance = np.linalg.norm(mesh.p[:, candidates].T - np.asarray(load.point), axis=1)
    nodes = candidates[distance <= load.radius]
    if len(nodes) == 0:
        raise FemError(f"{what} selects no boundary node: within {load.radius:g} mm of "
                       f"{format_point(load.point)}")
    return nodes


@dataclass(frozen=True)
class Constraints:
    """Constrained dof indices with their prescribed values, and the dofs of each fixture."""
    dofs: np.ndarray
    values: np.ndarray
    by_fixture: dict


def constraints(basis: CellBasis, fixtures: Sequence[Fixture]) -> Constraints:
    """Vector dofs and values prescribed by ``fixtures`` on the scalar ``basis`` (later fixtures win)."""
    if not fixtures:
        raise FemError("the model has no fixture, so it can move as a rigid body: add at least one "
                       "fixture (e.g. a clamped face, or roller supports that remove all 6 rigid motions)")
    _unique_names(fixtures, "fixture")
    mesh = basis.mesh
    values = np.zeros(3 * basis.N)
    by_fixture = {}
    for fixture in fixtures:
        what = f"fixture '{fixture.name}'"
        if isinstance(fixture.where, NearestNode):
            node = _nearest(mesh, fixture.where, what)
            scalar_dofs = basis.nodal_dofs[0, [node]]
        elif isinstance(fixture.where, Nodes):
            scalar_dofs = basis.nodal_dofs[0, nodes_at(mesh, fixture.where, what)]
        else:
            scalar_dofs = basis.get_dofs(facets=_selected_facets(mesh, fixture.where, what)).all()
        picked = []
        for name in fixture.components:
            c = _COMPONENTS[name]
            values[3 * scalar_dofs + c] = fixture.displacement[c]
            picked.append(3 * scalar_dofs + c)
        by_fixture[fixture.name] = np.unique(np.concatenate(picked))
    dofs = np.unique(np.concatenate(list(by_fixture.values())))
    return Constraints(dofs, values[dofs], by_fixture)


# --------------------------------------------------------------------------- rigid-body modes

_MODE_NAMES = ("translation along x", "translation along y", "translation along z",
               "rotation about x", "rotation about y", "rotation about z")


def rigid_body_modes(basis: CellBasis, scalar_dofs: np.ndarray | None = None) -> np.ndarray:
    """(3 N, 6) rigid-body displacements at the vector dofs of the scalar ``basis``.

    Three translations and three rotations about the centroid.

    Rotations are divided by the mesh size so all six columns are O(1); they
    span the null space of the unconstrained stiffness matrix (and are the
    near-null space AMG needs to coarsen elasticity well). With ``scalar_dofs``,
    the (3 len, 6) motions of those dofs alone (one body), about their centroid.
    """
    if scalar_dofs is None:
        points, dof_points = basis.mesh.p, basis.doflocs
    else:
        points = dof_points = basis.doflocs[:, scalar_dofs]
    count = 3 * dof_points.shape[1]
    locations = np.repeat(dof_points.T, 3, axis=0)            # vector dof 3 d + c sits at scalar dof d
    component = np.arange(count) % 3
    centre = points.mean(axis=1)
    scale = np.ptp(points, axis=1).max()
    relative = (locations - centre) / scale
    modes = np.zeros((count, 6))
    modes[np.arange(count), component] = 1.0
    for axis in range(3):
        rotation = np.cross(np.eye(3)[axis], relative)        # e_axis x r
        modes[:, 3 + axis] = rotation[np.arange(count), component]
    return modes


def bodies(mesh: MeshTet) -> list[np.ndarray]:
    """Element indices of each connected body of ``mesh`` (tetrahedra sharing a vertex are one body)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    t = mesh.t
    links = sp.coo_matrix((np.ones(3 * t.shape[1]), (np.tile(t[0], 3), t[1:].ravel())),
                          shape=(mesh.nvertices, mesh.nvertices))
    _, vertex_body = connected_components(links, directed=False)
    element_body = vertex_body[t[0]]
    return [np.flatnonzero(element_body == body) for body in np.unique(element_body)]


def check_rigid_modes(basis: CellBasis, constraints: Constraints, fixtures: Sequence[Fixture]) -> None:
    """Raise :class:`FemError` if the constrained dofs leave a rigid-body motion of any body free.

    A rigid motion ``m = modes @ c`` of a body is free when it moves none of
    its constrained dofs, i.e. ``c`` is a null vector of ``modes[D]`` -- an
    eigenvector of the 6 x 6 Gram matrix ``modes[D]^T modes[D]`` with
    eigenvalue zero. Each connected body is checked on its own: a second body
    that nothing holds floats whatever holds the first.
    """
    constrained = np.zeros(3 * basis.N, dtype=bool)
    constrained[constraints.dofs] = True
    pieces = bodies(basis.mesh)
    for number, elements in enumerate(pieces, 1):
        scalar_dofs = np.unique(basis.element_dofs[:, elements])
        held = constrained[(3 * scalar_dofs[:, None] + np.arange(3)).ravel()]
        modes = rigid_body_modes(basis, scalar_dofs)[held]
        eigenvalues, eigenvectors = np.linalg.eigh(modes.T @ modes)
        free = eigenvectors[:, eigenvalues <= 1e-10 * max(1.0, eigenvalues.max())].T   # columns are O(1)
        if len(free) == 0:
            continue
        # Name the pure motions that lie (mostly) in the free subspace.
        share = np.linalg.norm(free, axis=0)
        named = [_MODE_NAMES[i] for i in range(6) if share[i] > 0.7]
        listing = ", ".join(named) if named else "combinations of translations and rotations"
        names = ", ".join(f"'{f.name}'" for f in fixtures)
        body = ""
        if len(pieces) > 1:
            corners = basis.mesh.p[:, np.unique(basis.mesh.t[:, elements])]
            body = (f" of body {number} of the mesh's {len(pieces)} disconnected bodies (from "
                    f"{format_point(corners.min(axis=1))} to {format_point(corners.max(axis=1))} mm; each "
                    f"body needs fixtures of its own)")
        raise FemError(f"the fixtures ({names}) leave {len(free)} rigid-body motion(s){body} free ({listing}); "
                       f"the model can move without straining. Fix more displacement components, e.g. "
                       f"roller supports at points away from the existing ones")
