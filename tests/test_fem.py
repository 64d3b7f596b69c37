"""Linear-elastic FEM (mi_nest.fem): closed-form benchmarks, meshes, specs, errors, rendering."""
import json
import math
import sys
import time

import numpy as np
import pytest
import trimesh

import mi_nest
from mi_nest.cli import main
from mi_nest.fem import (BoxGeometry, CylinderGeometry, FemError, FemSpec, Material, Predicate, SolverConfig,
                         MeshFileGeometry, TubeGeometry, load_spec, mesh_surface, read_volume_mesh,
                         rigid_body_modes, solve)
from mi_nest.fem.meshing import require_gmsh
from mi_nest.fem.solve import scalar_basis, stiffness
from mi_nest.fields.analytic import DiskCompressionField, LameCylinderField
from mi_nest.fields.sources import grid_from_file, load_mesh
from mi_nest.physics.tensors import von_mises
from scenes import scene

EPOXY = Material(youngs_modulus=2500.0, poisson_ratio=0.36)


def plane(axis, value, tolerance=1e-3):
    normal = [0.0, 0.0, 0.0]
    normal["xyz".index(axis)] = 1.0
    point = [0.0, 0.0, 0.0]
    point["xyz".index(axis)] = value
    return {"type": "plane", "point": point, "normal": normal, "tolerance": tolerance}


def point(x, y, z):
    return {"type": "point", "point": [x, y, z]}


# --------------------------------------------------------------------------- the discretisation

@pytest.mark.parametrize("order", [1, 2])
def test_stiffness_matches_skfem_linear_elasticity_and_annihilates_rigid_modes(order):
    from skfem import Basis, ElementVector
    from skfem.models.elasticity import linear_elasticity
    mesh = CylinderGeometry(3.0, 2.0, element_size=0.8).mesh()
    basis = scalar_basis(mesh, order)
    K = stiffness(basis, EPOXY, chunk=100)          # several chunks
    reference = linear_elasticity(*EPOXY.lame).assemble(Basis(mesh, ElementVector(basis.elem)))
    assert abs(K - reference).max() <= 1e-12 * abs(reference).max()
    assert np.abs(K @ rigid_body_modes(basis)).max() <= 1e-9 * abs(K).max()


@pytest.mark.parametrize("geometry, volume", [
    (CylinderGeometry(20.0, 4.0, element_size=2.0), None),
    (TubeGeometry(10.0, 20.0, 3.0, element_size=1.5, axis="x", center=(1.0, 2.0, 3.0)), None),
    (BoxGeometry((10.0, 4.0, 3.0), origin=(-5.0, 0.0, 0.0), element_size=1.0), 120.0),
])
def test_primitive_meshes_are_closed_and_fill_their_volume(geometry, volume):
    mesh = geometry.mesh()
    field = load_mesh_from(mesh)
    surface = trimesh.Trimesh(field.nodes, field.surface, process=False)
    assert surface.is_watertight and surface.is_winding_consistent
    corners = field.nodes[field.tets]
    tet_volume = np.einsum("ij,ij->i", np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]),
                           corners[:, 3] - corners[:, 0]) / 6.0
    assert tet_volume.min() > 0
    np.testing.assert_allclose(tet_volume.sum(), surface.volume, rtol=1e-9)
    if volume is not None:
        np.testing.assert_allclose(tet_volume.sum(), volume, rtol=1e-12)
    else:   # a polygon inscribed in the circle: a little less than the exact volume
        outer = geometry.outer_radius if isinstance(geometry, TubeGeometry) else geometry.radius
        inner = geometry.inner_radius if isinstance(geometry, TubeGeometry) else 0.0
        exact = math.pi * (outer ** 2 - inner ** 2) * geometry.height
        assert 0.97 * exact < tet_volume.sum() < exact


def load_mesh_from(mesh):
    from mi_nest.fields.mesh import TetMeshStress
    return TetMeshStress.from_cells(mesh.p.T, mesh.t.T, np.zeros((mesh.nvertices, 6)))


# --------------------------------------------------------------------------- closed-form benchmarks

L, W, H, F = 20.0, 4.0, 3.0, 123.4


def bar_model(length=L):
    """A box pulled along x: x-roller on x=0, 3 point supports against the rigid modes left."""
    loads = [{"type": "force", "name": "pull", "where": plane("x", length), "force": [F, 0.0, 0.0]}]
    fixtures = [{"name": "end", "where": plane("x", 0.0), "components": ["x"]},
                # Uniaxial stress contracts y and z about the x axis through the origin, so these
                # points stay put in the exact solution: the supports carry no load.
                {"name": "origin", "where": point(0.0, 0.0, 0.0), "components": ["y", "z"]},
                {"name": "corner", "where": point(0.0, W, 0.0), "components": ["z"]}]
    return loads, fixtures


@pytest.mark.parametrize("order, method", [(1, "direct"), (1, "amg"), (2, "amg")])
def test_uniaxial_bar_is_exact(order, method):
    loads, fixtures = bar_model()
    mesh = BoxGeometry((L, W, H), element_size=1.0).mesh()
    result = solve(mesh, EPOXY, loads, fixtures, element_order=order, solver=SolverConfig(method=method))
    sigma = F / (W * H)
    stress = result.field.stress.astype(np.float64)
    np.testing.assert_allclose(stress[:, 0], sigma, rtol=1e-6)
    assert np.abs(stress[:, 1:]).max() <= 1e-6 * sigma
    end = np.isclose(result.field.nodes[:, 0], L)
    np.testing.assert_allclose(result.displacement[end, 0], sigma * L / EPOXY.youngs_modulus, rtol=1e-6)
    report = result.report
    assert report.solver == method and report.residual < 1e-9
    np.testing.assert_allclose(report.applied["pull"], [F, 0, 0], atol=1e-9)
    np.testing.assert_allclose(report.reactions["end"], [-F, 0, 0], atol=1e-6)
    for name in ("origin", "corner"):
        np.testing.assert_allclose(report.reactions[name], 0.0, atol=1e-6)


def test_prescribed_displacement_and_predicate_regions():
    """Displacement control: pull the x=L face by delta; sigma = E delta / L everywhere."""
    delta = 0.01
    loads, fixtures = bar_model()
    fixtures.append({"name": "grip", "components": ["x"], "displacement": [delta, 0.0, 0.0],
                     "where": Predicate(lambda p: np.isclose(p[:, 0], L), "x = L")})
    mesh = BoxGeometry((L, W, H), element_size=2.0).mesh()
    result = solve(mesh, EPOXY, [], fixtures)
    np.testing.assert_allclose(result.field.stress[:, 0], EPOXY.youngs_modulus * delta / L, rtol=1e-5)
    np.testing.assert_allclose(result.report.reactions["grip"][0], EPOXY.youngs_modulus * delta / L * W * H,
                               rtol=1e-6)


R_DISK, T_DISK, P_DISK = 20.0, 4.0, 1000.0


def disk_loads(kind, element_size):
    """Diametral compression: +-P (N) over small patches at the poles (x ~ 0, y = +-R)."""
    half = 1.1 * element_size       # at least one facet wide whatever the ring spacing
    if kind == "force":
        return [{"type": "force", "name": name, "force": [0.0, -sign * P_DISK, 0.0],
                 "where": {"type": "box", "min": [-half, sign * R_DISK - 1.0, -T_DISK],
                           "max": [half, sign * R_DISK + 1.0, T_DISK]}}
                for name, sign in (("top", 1.0), ("bottom", -1.0))]
    return [{"type": "point_force", "name": name, "point": [0.0, sign * R_DISK, 0.0], "radius": half,
             "force": [0.0, -sign * P_DISK, 0.0]} for name, sign in (("top", 1.0), ("bottom", -1.0))]


# The loads balance, so any statically determinate support (the 3-2-1 rule: a node pinned,
# a second held in y and z, a third in z) removes the rigid modes and carries no load.
DISK_FIXTURES = [{"name": "pin", "where": point(-R_DISK, 0.0, -T_DISK / 2)},
                 {"name": "slide", "where": point(R_DISK, 0.0, -T_DISK / 2), "components": ["y", "z"]},
                 {"name": "rest", "where": point(0.0, R_DISK / 2, -T_DISK / 2), "components": ["z"]}]


def disk_centre_error(result):
    """Relative error of the thickness-averaged centre s_x - s_y against Frocht's 8P/(pi D t)."""
    z = np.linspace(-T_DISK / 2, T_DISK / 2, 9)
    stress = result.field.sample(np.stack([0 * z, 0 * z, z], axis=1)).astype(np.float64)
    values = stress[:, 0] - stress[:, 1]
    difference = 0.5 * (values[1:] + values[:-1]).mean()          # trapezoidal mean over the thickness
    frocht = DiskCompressionField(diameter=2 * R_DISK, thickness=T_DISK, load=P_DISK)
    s_x, s_y, _ = frocht.plane_stress(0.0, 0.0)
    assert math.isclose(s_x - s_y, 8 * P_DISK / (math.pi * 2 * R_DISK * T_DISK), rel_tol=1e-6)
    return difference / (s_x - s_y) - 1.0


@pytest.mark.parametrize("order, element_size, kind", [(1, 1.0, "force"), (2, 2.0, "point_force")])
def test_disk_under_diametral_compression_matches_frocht_at_the_centre(order, element_size, kind):
    mesh = CylinderGeometry(R_DISK, T_DISK, element_size=element_size).mesh()
    result = solve(mesh, EPOXY, disk_loads(kind, element_size), DISK_FIXTURES, element_order=order)
    error = disk_centre_error(result)
    print(f"disk P{order} h={element_size}: centre s_x - s_y error {100 * error:+.2f}%")
    assert abs(error) < 0.05
    for name in ("pin", "slide", "rest"):
        np.testing.assert_allclose(result.report.reactions[name], 0.0, atol=1e-6 * P_DISK)
    # Along the loaded diameter s_x is Frocht's uniform tension 2P/(pi D t); the patches (not
    # points) carrying the load lower it towards the poles, so look at the middle half.
    y = np.linspace(-0.25, 0.25, 5) * R_DISK
    s_x = result.field.sample(np.stack([0 * y, y, 0 * y], axis=1))[:, 0]
    np.testing.assert_allclose(s_x, 2 * P_DISK / (math.pi * 2 * R_DISK * T_DISK), rtol=0.05)


def test_lame_thick_cylinder_under_internal_pressure():
    """Plane strain (ends held axially): s_rr, s_tt, s_zz = 2 nu A against Lame at mid-wall."""
    a, b, height, p = 10.0, 20.0, 3.0, 10.0
    mesh = TubeGeometry(a, b, height, element_size=2.0).mesh()
    loads = [{"type": "pressure", "name": "bore", "pressure": p,
              "where": {"type": "cylindrical_surface", "radius": a}}]
    fixtures = [{"name": "bottom", "where": plane("z", -height / 2), "components": ["z"]},
                {"name": "top", "where": plane("z", height / 2), "components": ["z"]},
                # Tangential supports, zero in the axisymmetric solution: they stop x, y and
                # the rotation about z without touching the radial expansion.
                {"name": "east", "where": point(b, 0, 0), "components": ["y"]},
                {"name": "west", "where": point(-b, 0, 0), "components": ["y"]},
                {"name": "north", "where": point(0, b, 0), "components": ["x"]}]
    result = solve(mesh, EPOXY, loads, fixtures, element_order=2)
    np.testing.assert_allclose(result.report.applied["bore"], 0.0, atol=1e-9)   # a closed bore balances
    lame = LameCylinderField(a, b, p, axial_factor=2 * EPOXY.poisson_ratio)
    A, B = lame.lame_constants
    r = 0.5 * (a + b)
    theta = np.linspace(0, 2 * np.pi, 12, endpoint=False) + 0.1
    c, s = np.cos(theta), np.sin(theta)
    stress = result.field.sample(np.stack([r * c, r * s, 0 * theta], axis=1)).astype(np.float64)
    s_rr = stress[:, 0] * c * c + stress[:, 1] * s * s + 2 * stress[:, 5] * c * s
    s_tt = stress[:, 0] * s * s + stress[:, 1] * c * c - 2 * stress[:, 5] * c * s
    errors = {"s_rr": np.abs(s_rr / (A - B / r ** 2) - 1).max(), "s_tt": np.abs(s_tt / (A + B / r ** 2) - 1).max(),
              "s_zz": np.abs(stress[:, 2] / (lame.axial_factor * A) - 1).max()}
    print("Lame mid-wall max errors: " + ", ".join(f"{k} {100 * v:.2f}%" for k, v in errors.items()))
    assert max(errors.values()) < 0.05
    # The closed form of the medium agrees with the recovered tensors (same conventions).
    expected = np.stack(lame.eval(tuple(np.stack([r * c, r * s, 0 * theta]))), axis=1)
    np.testing.assert_allclose(stress, expected, atol=0.05 * abs(A + B / r ** 2))
    # The summary reports the peak of the recovered stress (at the bore), not the first node's.
    assert f"von Mises stress up to {von_mises(result.field.stress).max():.4g} MPa" in result.summary()


# --------------------------------------------------------------------------- errors

def test_a_load_on_no_face_names_the_load_and_its_region():
    loads = [{"type": "pressure", "name": "top", "pressure": 1.0, "where": plane("z", 10.0, tolerance=0.01)}]
    fixtures = [{"name": "base", "where": plane("z", 0.0)}]
    mesh = BoxGeometry((4.0, 4.0, 4.0), element_size=2.0).mesh()
    with pytest.raises(FemError, match=r"load 'top' selects no boundary facet: plane z=10 within 0.01 mm"):
        solve(mesh, EPOXY, loads, fixtures)
    with pytest.raises(FemError, match=r"fixture 'base' selects no boundary facet: box \(9, 9, 9\) to"):
        solve(mesh, EPOXY, [], [{"name": "base", "where": {"type": "box", "min": [9, 9, 9], "max": [10, 10, 10]}}])
    with pytest.raises(FemError, match=r"load 'tip' selects no boundary node: within 0.1 mm of \(2, 2, 9\)"):
        solve(mesh, EPOXY, [{"type": "point_force", "name": "tip", "point": [2, 2, 9], "radius": 0.1,
                             "force": [0, 0, 1]}], fixtures)
    far = {"type": "point", "point": [2, 2, 9], "max_distance": 0.5}
    with pytest.raises(FemError, match=r"fixture 'pin' selects no boundary node: the nearest to \(2, 2, 9\) is 5 mm"):
        solve(mesh, EPOXY, [], [{"name": "pin", "where": far}])
    with pytest.raises(FemError, match=r"load 'top' acts on a surface but its region is a single node"):
        solve(mesh, EPOXY, [{"type": "force", "name": "top", "where": point(0, 0, 4), "force": [0, 0, 1]}],
              fixtures)


def test_unfixed_and_underfixed_models_are_refused_before_solving():
    mesh = BoxGeometry((4.0, 4.0, 4.0), element_size=2.0).mesh()
    loads = [{"type": "traction", "name": "top", "traction": [0, 0, 1.0], "where": plane("z", 4.0)}]
    with pytest.raises(FemError, match="the model has no fixture, so it can move as a rigid body"):
        solve(mesh, EPOXY, loads, [])
    # A roller on the base stops z and the tilts, not sliding or spinning in the plane.
    roller = [{"name": "base", "where": plane("z", 0.0), "components": ["z"]}]
    with pytest.raises(FemError, match=r"the fixtures \('base'\) leave 3 rigid-body motion\(s\) free "
                                       r"\(translation along x, translation along y, rotation about z\)"):
        solve(mesh, EPOXY, loads, roller)
    # Two pinned points leave the rotation about the line through them.
    pins = [{"name": "a", "where": point(0, 0, 0)}, {"name": "b", "where": point(4, 4, 4)}]
    with pytest.raises(FemError, match=r"leave 1 rigid-body motion\(s\) free"):
        solve(mesh, EPOXY, loads, pins)
    # Clamping the base is enough, for P1 and P2.
    for order in (1, 2):
        result = solve(mesh, EPOXY, loads, [{"name": "base", "where": plane("z", 0.0)}], element_order=order)
        np.testing.assert_allclose(result.report.reactions["base"], [0, 0, -16.0], rtol=1e-9, atol=1e-9)


def test_spec_keys_are_checked_with_suggestions():
    base = {"geometry": {"type": "box", "size": [4, 4, 4]}, "material": {"youngs_modulus": 2500, "poisson_ratio": 0.3},
            "fixtures": [{"name": "base", "where": plane("z", 0.0)}]}
    FemSpec.from_dict(base)
    cases = [
        ({"loads": [{"name": "top", "type": "pressure", "preasure": 1.0, "where": plane("z", 4)}]},
         r"^load 'top': unknown key 'preasure' \(did you mean 'pressure'\?\)"),
        ({"loads": [{"name": "top", "type": "presure", "pressure": 1.0, "where": plane("z", 4)}]},
         r"load 'top': unknown type 'presure' \(did you mean 'pressure'\?\); expected one of: point_force, force"),
        ({"loads": [{"name": "top", "type": "pressure", "pressure": 1.0, "where": {"type": "plane", "pont": [0, 0, 4],
                                                                                   "normal": [0, 0, 1]}}]},
         r"load 'top': region: unknown key 'pont' \(did you mean 'point'\?\)"),
        ({"load": []}, r"spec: unknown key 'load' \(did you mean 'loads'\?\)"),
        ({"material": {"youngs_modulus": 2500}}, r"material: missing key\(s\) 'poisson_ratio'"),
        ({"material": {"youngs_modulus": 2500, "poisson_ratio": 0.5}}, r"'poisson_ratio' must lie in \(-1, 0.5\)"),
        ({"element_order": 3}, r"'element_order' must be 1 or 2"),
        ({"solver": {"method": "cholesky"}}, r"^solver: 'method' must be one of auto, amg, direct"),
        ({"fixtures": [{"name": "base", "where": plane("z", 0.0), "components": ["x", "w"]}]},
         r"fixture 'base': 'components' must be distinct names among 'x', 'y', 'z'"),
        ({"fixtures": {"name": "base"}}, r"'fixtures' must be a list of tables"),
        ({"geometry": {"type": "tube", "inner_radius": 5, "outer_radius": 4, "height": 1}},
         r"^geometry: 'inner_radius' \(5\) must be smaller than 'outer_radius' \(4\)"),
        ({"loads": [{"name": "top", "type": "force", "force": [1, 2], "where": plane("z", 4)}]},
         r"load 'top': 'force' must be a list of 3 numbers"),
    ]
    for change, message in cases:
        with pytest.raises(FemError, match=message):
            FemSpec.from_dict({**base, **change})


def test_missing_gmsh_names_the_optional_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "gmsh", None)     # import gmsh -> ImportError
    with pytest.raises(FemError, match=r"needs gmsh, an optional dependency \(GPL\): pip install 'mi_nest\[gmsh\]'"):
        require_gmsh()


# --------------------------------------------------------------------------- files, CLI, rendering

SPEC_TOML = """
element_order = 1

[geometry]
type = "cylinder"
radius = 20.0
height = 4.0
element_size = 2.0

[material]
youngs_modulus = 2500.0
poisson_ratio = 0.36

[solver]
recovery = "average"

[[loads]]
name = "top"
type = "force"
force = [0.0, -1000.0, 0.0]
where = { type = "box", min = [-2.2, 19.0, -5.0], max = [2.2, 21.0, 5.0] }

[[loads]]
name = "bottom"
type = "force"
force = [0.0, 1000.0, 0.0]
where = { type = "box", min = [-2.2, -21.0, -5.0], max = [2.2, -19.0, 5.0] }

[[fixtures]]
name = "pin"
where = { type = "point", point = [-20.0, 0.0, -2.0] }

[[fixtures]]
name = "slide"
where = { type = "point", point = [20.0, 0.0, -2.0] }
components = ["y", "z"]

[[fixtures]]
name = "rest"
where = { type = "point", point = [0.0, 10.0, -2.0] }
components = ["z"]
"""


def test_fem_result_loads_as_a_stress_file_and_renders_fringes(tmp_path):
    spec_file = tmp_path / "disk.toml"
    spec_file.write_text(SPEC_TOML)
    spec = load_spec(spec_file)
    assert spec.solver.recovery == "average" and len(spec.loads) == 2
    result = spec.run()
    assert abs(disk_centre_error(result)) < 0.05
    path = tmp_path / "disk.npz"
    result.save(path)
    mesh = load_mesh(path)
    np.testing.assert_allclose(mesh.stress, result.field.stress)
    grid = grid_from_file(path, resolution=24)
    assert np.all(np.isfinite(grid.stress)) and grid.stress[..., 1].min() < -10.0
    specimen = {"type": "specimen", "filename": str(path), "fringe_value": 10.0, "grid_resolution": 32}
    channels = mi_nest.render(scene([specimen], res=12, view=22.0, step=0.5)).channels
    delta = channels["char.delta"]
    assert np.all(np.isfinite(delta)) and delta.std() > 0.1 and delta.max() > 1.0

    # The same spec as JSON gives the same model.
    tomllib = pytest.importorskip("tomllib")
    json_file = tmp_path / "disk.json"
    json_file.write_text(json.dumps(tomllib.loads(SPEC_TOML)))
    assert load_spec(json_file) == spec


def test_cli_fem_solves_a_spec_and_reports_errors(tmp_path, capsys):
    spec_file = tmp_path / "disk.toml"
    spec_file.write_text(SPEC_TOML)
    out = tmp_path / "field.npz"
    assert main(["fem", "--spec", str(spec_file), "-o", str(out), "--order", "2"]) == 0
    printed = capsys.readouterr().out
    assert "P2:" in printed and "load 'top': force (0, -1000, 0) N" in printed and f"wrote {out}" in printed
    assert load_mesh(out).stress.shape[1] == 6

    spec_file.write_text(SPEC_TOML.replace("force = [0.0, 1000.0, 0.0]", "forse = [0.0, 1000.0, 0.0]"))
    assert main(["fem", "--spec", str(spec_file), "-o", str(out)]) == 2
    assert "load 'bottom': unknown key 'forse' (did you mean 'force'?)" in capsys.readouterr().err
    spec_file.write_text("[geometry\n")
    assert main(["fem", "--spec", str(spec_file), "-o", str(out)]) == 2
    assert "not a valid TOML file" in capsys.readouterr().err


def test_volume_mesh_files_are_read_with_meshio(tmp_path):
    import meshio
    mesh = BoxGeometry((L, W, H), element_size=2.0).mesh()
    meshio.write(tmp_path / "bar.vtu", meshio.Mesh(mesh.p.T, [("tetra", mesh.t.T)]))
    read = read_volume_mesh(tmp_path / "bar.vtu")
    np.testing.assert_allclose(read.p, mesh.p)
    meshio.write(tmp_path / "skin.vtu", meshio.Mesh(mesh.p.T, [("triangle", mesh.facets.T)]))
    with pytest.raises(FemError, match="no tetrahedra in the file"):
        read_volume_mesh(tmp_path / "skin.vtu")


# One tetrahedron as gmsh 4.1 writes it: entities with physical tags and bounding entities (which meshio keeps
# as a cell set of its own, 'gmsh:bounding_entities', of entity tags rather than cell indices).
GMSH_41_TET = """$MeshFormat
4.1 0 8
$EndMeshFormat
$PhysicalNames
2
2 1 "base"
3 2 "solid"
$EndPhysicalNames
$Entities
0 0 1 1
1 0 0 0 1 1 0 1 1 3 1 2 3
1 0 0 0 1 1 1 1 2 1 1
$EndEntities
$Nodes
1 4 1 4
3 1 0 4
1
2
3
4
0 0 0
1 0 0
0 1 0
0 0 1
$EndNodes
$Elements
2 2 1 2
2 1 2 1
1 1 3 2
3 1 4 1
2 1 2 3 4
$EndElements
"""


def test_gmsh_physical_surfaces_are_named_groups_in_msh_4_1_and_2_2(tmp_path):
    import meshio
    version_4 = tmp_path / "tet41.msh"
    version_4.write_text(GMSH_41_TET)
    mesh = read_volume_mesh(version_4)
    assert list(mesh.boundaries) == ["base"] and len(mesh.boundaries["base"]) == 1
    # meshio keeps a 2.2 file's groups only as a physical tag per cell and the names in field_data.
    version_2 = tmp_path / "tet22.msh"
    meshio.write(version_2, meshio.read(version_4), file_format="gmsh22", binary=False)
    assert not meshio.read(version_2).cell_sets
    again = read_volume_mesh(version_2)
    assert list(again.boundaries) == ["base"]
    np.testing.assert_array_equal(again.facets[:, again.boundaries["base"]], mesh.facets[:, mesh.boundaries["base"]])


def test_gmsh_meshes_a_closed_surface_for_a_patch_test():
    pytest.importorskip("gmsh")
    surface = trimesh.creation.box(extents=(L, W, H))
    surface.apply_translation([L / 2, W / 2, H / 2])
    mesh = mesh_surface(surface, element_size=1.5)
    loads, fixtures = bar_model()
    result = solve(mesh, EPOXY, loads, fixtures, solver=SolverConfig(method="direct"))
    # P1 reproduces uniform stress on any mesh (the patch test).
    np.testing.assert_allclose(result.field.stress[:, 0], F / (W * H), rtol=1e-5)


@pytest.mark.slow
def test_a_50k_tet_p1_model_solves_well_under_a_minute():
    mesh = CylinderGeometry(R_DISK, T_DISK, element_size=0.82).mesh()
    assert 45_000 < mesh.nelements < 60_000
    start = time.perf_counter()
    result = solve(mesh, EPOXY, disk_loads("force", 0.82), DISK_FIXTURES, element_order=1)
    seconds = time.perf_counter() - start
    print(f"{mesh.nelements} tets, {result.report.dofs} dofs: {seconds:.1f} s")
    assert seconds < 30.0 and abs(disk_centre_error(result)) < 0.05


def _bar_with_named_ends(path, length=40.0, side=10.0):
    """A tetrahedral bar along x written as Abaqus .inp with surface sets 'left' and 'right'."""
    import meshio
    from skfem import MeshTet
    mesh = MeshTet.init_tensor(np.linspace(0, length, 9), np.linspace(0, side, 3), np.linspace(0, side, 3))
    facets = mesh.boundary_facets()
    corners = mesh.p[0, mesh.facets[:, facets]]
    triangles = mesh.facets[:, facets].T
    left, right = np.all(corners < 1e-9, axis=0), np.all(corners > length - 1e-9, axis=0)
    meshio.Mesh(mesh.p.T, [("tetra", mesh.t.T), ("triangle", triangles)],
                cell_sets={"left": [np.array([], int), np.nonzero(left)[0]],
                           "right": [np.array([], int), np.nonzero(right)[0]]}).write(path)


def test_cli_flags_solve_a_mesh_file_with_named_surface_groups(tmp_path, capsys):
    from mi_nest.cli import main
    from mi_nest.fields.sources import load_mesh
    bar = tmp_path / "bar.inp"
    _bar_with_named_ends(bar)
    output = tmp_path / "bar.npz"
    # Clamp the left group, pull the right group along x: far from the clamp sigma_xx = F / A.
    assert main(["fem", str(bar), "--fix", "left", "--load", "right:500,0,0", "-o", str(output)]) == 0
    assert "wrote" in capsys.readouterr().out
    field = load_mesh(output)
    middle = np.abs(field.nodes[:, 0] - 20.0) < 1e-9
    np.testing.assert_allclose(field.stress[middle, 0], 500.0 / 100.0, rtol=0.03)
    # A plane selects the same face; roller supports on three planes leave pure tension.
    assert main(["fem", str(bar), "--fix", "x=0:x", "--fix", "y=0:y", "--fix", "z=0:z",
                 "--load", "x=40:500,0,0", "-o", str(output)]) == 0
    np.testing.assert_allclose(load_mesh(output).stress[:, 0], 5.0, rtol=1e-6)
    capsys.readouterr()
    assert main(["fem", str(bar), "--fix", "bottom", "--load", "right:1,0,0", "-o", str(output)]) == 2
    assert "no surface group 'bottom'; it has ['left', 'right']" in capsys.readouterr().err
    assert main(["fem", str(bar), "--load", "right:1,0,0", "-o", str(output)]) == 2
    assert "no fixture, so it can move as a rigid body" in capsys.readouterr().err
    assert main(["fem", str(bar), "--fix", "left", "--load", "right:1,0", "-o", str(output)]) == 2
    assert "expected 3 comma-separated numbers" in capsys.readouterr().err
    assert main(["fem", "--fix", "left", "-o", str(output)]) == 2
    assert "either --spec FILE or a MESH" in capsys.readouterr().err


def test_a_surface_that_is_not_closed_is_refused_before_meshing(tmp_path):
    import trimesh
    box = trimesh.creation.box(extents=(4, 4, 4))
    open_box = trimesh.Trimesh(box.vertices, box.faces[2:], process=False)
    with pytest.raises(FemError, match="not closed \\(watertight\\)"):
        mesh_surface(open_box)
    open_box.export(tmp_path / "open.stl")
    with pytest.raises(FemError, match="not closed \\(watertight\\)"):
        MeshFileGeometry(str(tmp_path / "open.stl")).mesh()
