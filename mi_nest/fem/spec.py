"""A whole FEM model as one declarative spec, read from TOML or JSON.

Example (TOML; lengths mm, forces N, stresses MPa)::

    element_order = 2

    [geometry]
    type = "cylinder"            # box | cylinder | tube | file
    radius = 20.0
    height = 4.0
    element_size = 1.5

    [material]
    youngs_modulus = 2500.0
    poisson_ratio = 0.36

    [solver]                     # optional: method = auto | amg | direct, recovery = l2 | average
    method = "auto"

    [[loads]]
    name = "top"
    type = "force"               # point_force | force | traction | pressure
    force = [0.0, -1000.0, 0.0]
    where = { type = "box", min = [-2.0, 19.0, -5.0], max = [2.0, 21.0, 5.0] }

    [[fixtures]]
    name = "pin"
    where = { type = "point", point = [-20.0, 0.0, -2.0] }   # components default to x, y, z

Regions (``where``): ``plane`` (point, normal, tolerance), ``box`` (min, max),
``sphere`` (center, radius), ``cylindrical_surface`` (radius, center, axis,
tolerance), ``point`` (the nearest boundary node), ``nodes`` (points: the mesh
nodes there, within tolerance), ``group`` (name: a named surface of a mesh
file, e.g. a gmsh physical surface). Loads of type ``node_forces`` give one
force per node of a ``nodes`` region (``forces = [[fx, fy, fz], ...]``).

A 3D-TSV file as the mesh of :func:`spec_from_flags` (``mi-nest fem part.TSV``)
brings its own boundary conditions: its fixed nodes clamped, its node forces
applied (:func:`file_boundary_conditions`), besides any flags.
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ..fields.sources import is_tsv_file, load_mesh
from .config import FemError, parse_fields
from .loads import parse_fixture, parse_load
from .meshing import MeshFileGeometry, parse_geometry
from .solve import FemResult, Material, SolverConfig, solve

if TYPE_CHECKING:
    from .loads import Fixture, Load
    from .regions import Region


def _parse_list(items, parse, key):
    if isinstance(items, dict) or not isinstance(items, (list, tuple)):
        raise FemError(f"'{key}' must be a list of tables ([[{key}]] in TOML), got {type(items).__name__}")
    return tuple(parse(item, index) for index, item in enumerate(items))


@dataclass(frozen=True)
class FemSpec:
    """Geometry, material, loads and fixtures of one linear-elastic model, and how to solve it."""
    geometry: object
    material: object
    fixtures: tuple
    loads: tuple = ()
    element_order: int = 1
    solver: object = field(default_factory=SolverConfig)

    def __post_init__(self):
        object.__setattr__(self, "geometry", parse_geometry(self.geometry))
        if not isinstance(self.material, Material):
            object.__setattr__(self, "material", parse_fields(Material, self.material, "material"))
        if not isinstance(self.solver, SolverConfig):
            object.__setattr__(self, "solver", parse_fields(SolverConfig, self.solver, "solver"))
        object.__setattr__(self, "loads", _parse_list(self.loads, parse_load, "loads"))
        object.__setattr__(self, "fixtures", _parse_list(self.fixtures, parse_fixture, "fixtures"))
        if self.element_order not in (1, 2) or isinstance(self.element_order, bool):
            raise FemError(f"'element_order' must be 1 or 2, got {self.element_order!r}")
        object.__setattr__(self, "element_order", int(self.element_order))     # JSON may say 2.0

    @classmethod
    def from_dict(cls, data: Mapping, base: str | Path = "") -> FemSpec:
        """Parse a spec; relative mesh file paths resolve against ``base``."""
        spec = parse_fields(cls, data, "spec", skip=(), prefix_nested=False)
        if isinstance(spec.geometry, MeshFileGeometry) and not spec.geometry.base:
            spec = dataclasses.replace(spec, geometry=dataclasses.replace(spec.geometry, base=str(base)))
        return spec

    def run(self) -> FemResult:
        """Mesh and solve: a :class:`~mi_nest.fem.solve.FemResult`."""
        return solve(self.geometry.mesh(), self.material, self.loads, self.fixtures,
                     element_order=self.element_order, solver=self.solver)


def load_spec(path: str | Path) -> FemSpec:
    """A :class:`FemSpec` from a ``.toml`` or ``.json`` file."""
    path = Path(path)
    if not path.is_file():
        raise FemError(f"FEM spec file not found: {path}")
    try:
        if path.suffix == ".toml":
            try:
                import tomllib
            except ImportError:                              # Python 3.10
                try:
                    import tomli as tomllib
                except ImportError:
                    raise FemError("TOML specs need Python 3.11+ or 'pip install tomli'; or use .json") from None
            with open(path, "rb") as stream:
                data = tomllib.load(stream)
        elif path.suffix == ".json":
            data = json.loads(path.read_text())
        else:
            raise FemError(f"{path}: FEM spec files must be .toml or .json, got '{path.suffix}'")
    except ValueError as error:      # TOMLDecodeError and JSONDecodeError are ValueErrors
        if isinstance(error, FemError):
            raise
        raise FemError(f"{path}: not a valid {path.suffix[1:].upper()} file ({error})") from None
    try:
        return FemSpec.from_dict(data, base=path.parent)
    except FemError as error:
        raise FemError(f"{path}: {error}") from None


def parse_where(text: str) -> Region:
    """``x=V`` / ``y=V`` / ``z=V`` (an axis-aligned plane) or a surface group name."""
    from .regions import Group, Plane
    axis, sep, value = text.partition("=")
    if sep and axis in ("x", "y", "z"):
        try:
            offset = float(value)
        except ValueError:
            raise FemError(f"'{text}': expected {axis}=<number>") from None
        point = [0.0, 0.0, 0.0]
        normal = [0.0, 0.0, 0.0]
        point["xyz".index(axis)] = offset
        normal["xyz".index(axis)] = 1.0
        return Plane(tuple(point), tuple(normal))
    if sep:
        raise FemError(f"'{text}': a plane is x=<v>, y=<v> or z=<v>; anything else names a surface group")
    return Group(text)


def spec_from_flags(mesh: str | Path, fixes: Sequence[str], loads: Sequence[str] = (),
                    pressures: Sequence[str] = (), material: tuple[float, float] = (3000.0, 0.37),
                    element_order: int = 1, element_size: float | None = None) -> FemSpec:
    """A :class:`FemSpec` from command-line style strings.

    ``fixes``: ``WHERE`` or ``WHERE:xz`` (the clamped components); ``loads``:
    ``WHERE:FX,FY,FZ`` (total force in N spread over the faces); ``pressures``:
    ``WHERE:P`` (MPa, positive pushes in). ``material`` is (E in MPa, nu).
    """
    from .loads import Fixture, Pressure, SurfaceForce

    def split(text: str, what: str) -> tuple[Region, str]:
        where, sep, value = text.rpartition(":")
        if not sep or not where:
            raise FemError(f"{what} '{text}': expected WHERE:VALUE")
        return parse_where(where), value

    def numbers(text: str, count: int, what: str) -> tuple[float, ...]:
        try:
            values = tuple(float(v) for v in text.split(","))
        except ValueError:
            values = ()
        if len(values) != count:
            raise FemError(f"{what}: expected {count} comma-separated numbers, got '{text}'")
        return values

    fixtures, applied = file_boundary_conditions(mesh) if is_tsv_file(mesh) else ([], [])
    for index, text in enumerate(fixes):
        where, components = (split(text, "--fix") if ":" in text else (parse_where(text), "xyz"))
        if not components or set(components) - set("xyz"):
            raise FemError(f"--fix '{text}': components must be letters among x, y, z")
        fixtures.append(Fixture(f"fix {index + 1} ({text})", where, tuple(sorted(set(components)))))
    applied += [SurfaceForce(f"load {i + 1} ({t})", split(t, "--load")[0], numbers(split(t, "--load")[1], 3, t))
                for i, t in enumerate(loads)]
    applied += [Pressure(f"pressure {i + 1} ({t})", split(t, "--pressure")[0],
                         numbers(split(t, "--pressure")[1], 1, t)[0]) for i, t in enumerate(pressures)]
    youngs_modulus, poisson_ratio = material
    return FemSpec(MeshFileGeometry(str(mesh), element_size), Material(youngs_modulus, poisson_ratio),
                   tuple(fixtures), tuple(applied), element_order)


def file_boundary_conditions(path: str | Path) -> tuple[list[Fixture], list[Load]]:
    """``(fixtures, loads)`` of a 3D-TSV file's own boundary conditions, as lists (empty when it has none).

    Nodes are found by their coordinates, so they survive the renumbering of
    the solver's mesh.
    """
    from .loads import Fixture, NodeForces
    from .regions import Nodes
    mesh, name = load_mesh(path), Path(path).name
    conditions = mesh.boundary
    fixtures = ([Fixture(f"fixed nodes of {name}", Nodes(mesh.nodes[conditions.fixed_nodes]))]
                if len(conditions.fixed_nodes) else [])
    loads = ([NodeForces(f"node forces of {name}", Nodes(mesh.nodes[conditions.force_nodes]), conditions.forces)]
             if len(conditions.forces) else [])
    return fixtures, loads
