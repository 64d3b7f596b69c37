"""3D-TSV import, mesh stress fields, the specimen shape and VTK export."""
import math
from pathlib import Path

import meshio
import mitsuba as mi
import numpy as np
import pytest
import trimesh

import mi_nest
from mi_nest.fields.mesh import TetMeshStress
from mi_nest.fields.sources import export_file, grid_from_file
from mi_nest.io.cells import MeshError
from mi_nest.io.mesh import save_mesh_stress
from mi_nest.io.tsv import TsvFileError, read_stress_file, write_stress_file
from scenes import BREWSTER, WAVELENGTH, scene

# The 3D-TSV samples (BSD-2) live in the project's shared/ folder beside the checkout.
KITTEN = Path(__file__).resolve().parents[2] / "shared/data/3d-tsv/kitten.stress"
needs_kitten = pytest.mark.skipif(not KITTEN.is_file(), reason="shared 3D-TSV samples not beside the checkout")


def hex_box(size=(10.0, 10.0, 4.0), cells=(4, 4, 3)):
    """A box of hexahedra in VTK order, corner at the origin."""
    axes = [np.linspace(0, s, n + 1) for s, n in zip(size, cells)]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    nodes = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    nx, ny = cells[0] + 1, cells[1] + 1
    index = np.arange(len(nodes)).reshape(cells[2] + 1, ny, nx)
    c = index[:-1, :-1, :-1].ravel()
    hexes = np.stack([c, c + 1, c + 1 + nx, c + nx, c + nx * ny, c + 1 + nx * ny, c + 1 + nx + nx * ny,
                      c + nx + nx * ny], axis=1)
    return nodes, hexes


def uniaxial(sigma, angle_deg, count):
    """Uniaxial stress sigma along (cos a, sin a, 0): xx, yy, xy non-zero."""
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    return np.tile([sigma * c * c, sigma * s * s, 0.0, 0.0, 0.0, sigma * c * s], (count, 1))


@needs_kitten
def test_kitten_imports_with_its_counts_and_renders_fringes():
    model = read_stress_file(KITTEN)
    assert model.vertices.shape == (17260, 3) and model.elements.shape == (14410, 8)
    assert model.node_forces.shape == (96, 4) and model.fixed_nodes.shape == (384,)
    mesh = TetMeshStress.from_model(model)
    surface = trimesh.Trimesh(mesh.nodes, mesh.surface, process=False)
    assert surface.is_watertight and surface.is_winding_consistent and surface.volume > 0
    specimen = {"type": "specimen", "filename": str(KITTEN), "fringe_value": 2000.0, "grid_resolution": 32}
    channels = mi_nest.render(scene([specimen], res=16, view=55.0, origin=(0, -150, 40), target=(0, 0, 40),
                                    up=(0, 0, 1), step=1.0)).channels
    delta = channels["char.delta"]
    assert np.all(np.isfinite(delta)) and np.count_nonzero(delta > 0.05) > 40 and delta.std() > 0.1


@pytest.mark.parametrize("angle", [0.0, 30.0, 120.0])
def test_uniaxial_field_round_trips_through_3d_tsv_and_renders_its_closed_form(tmp_path, angle):
    sigma, thickness = 2.0, 4.0
    nodes, hexes = hex_box(size=(10.0, 10.0, thickness))
    path = tmp_path / "uniaxial.stress"
    write_stress_file(path, nodes, hexes, uniaxial(sigma, angle, len(nodes)),
                      node_forces=[[0, 0.0, 0.0, -1.0]], fixed_nodes=[1, 2])
    model = read_stress_file(path)
    np.testing.assert_allclose(model.stress, uniaxial(sigma, angle, len(nodes)), atol=1e-9)
    np.testing.assert_array_equal(model.elements, hexes)
    specimen = {"type": "specimen", "filename": str(path), "stress_optic_coefficient": BREWSTER,
                "grid_resolution": 8}
    channels = mi_nest.render(scene([specimen], res=4, view=3.0, origin=(5, 5, 100), target=(5, 5, 0),
                                    step=0.5)).channels
    # Seen along z with u = x, v = y: a retarder of 2 pi C t sigma / lambda at the stress direction.
    np.testing.assert_allclose(channels["char.delta"], 2 * math.pi * BREWSTER * thickness * sigma / WAVELENGTH,
                               atol=1e-4)
    np.testing.assert_allclose(channels["char.theta"], math.radians(angle) % math.pi, atol=1e-4)

    export_file(path, tmp_path / "uniaxial.vtu")
    exported = meshio.read(tmp_path / "uniaxial.vtu")
    assert exported.cells[0].type == "hexahedron" and len(exported.cells[0].data) == len(hexes)
    tensor = exported.point_data["stress"].reshape(-1, 3, 3)
    a = math.radians(angle)
    np.testing.assert_allclose(tensor[0], sigma * np.outer([math.cos(a), math.sin(a), 0], [math.cos(a), math.sin(a), 0]),
                               atol=1e-9)
    np.testing.assert_allclose(exported.point_data["sigma_1"], sigma, atol=1e-9)
    np.testing.assert_allclose(exported.point_data["sigma_3"], 0.0, atol=1e-9)
    np.testing.assert_allclose(exported.point_data["von_mises"], sigma, atol=1e-9)


def test_linear_fields_are_interpolated_exactly_on_tetrahedra_and_grids(tmp_path):
    nodes, hexes = hex_box(size=(6.0, 5.0, 4.0), cells=(3, 3, 2))
    gradient = np.random.default_rng(1).normal(size=(3, 6))
    stress = 1.0 + nodes @ gradient
    mesh = TetMeshStress.from_cells(nodes, hexes, stress)
    points = np.random.default_rng(2).uniform([0, 0, 0], [6, 5, 4], size=(500, 3))
    np.testing.assert_allclose(mesh.sample(points), 1.0 + points @ gradient, atol=1e-5)
    assert np.all(np.isnan(mesh.sample(np.array([[7.0, 1.0, 1.0], [-0.1, 2.0, 2.0]]))))
    # The same field as a tetrahedral mesh .npz (the FEM result format) resampled to a grid.
    save_mesh_stress(tmp_path / "linear.npz", mesh.nodes, mesh.tets, mesh.stress)
    grid = grid_from_file(tmp_path / "linear.npz", resolution=13)
    nz, ny, nx = grid.stress.shape[:3]
    axes = [np.linspace(grid.bbox_min[i], grid.bbox_max[i], n) for i, n in enumerate((nx, ny, nz))]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    inside = (x >= 0) & (x <= 6) & (y >= 0) & (y <= 5) & (z >= 0) & (z <= 4)
    expected = 1.0 + np.stack([x, y, z], axis=-1) @ gradient
    np.testing.assert_allclose(grid.stress[inside], expected[inside], atol=1e-4)


def test_bad_stress_files_give_clear_errors(tmp_path):
    nodes, hexes = hex_box(cells=(2, 2, 1))
    good = tmp_path / "good.stress"
    write_stress_file(good, nodes, hexes, uniaxial(1.0, 0.0, len(nodes)))
    lines = good.read_text().splitlines()
    (tmp_path / "truncated.stress").write_text("\n".join(lines[:-3]) + "\n")
    with pytest.raises(TsvFileError, match="'Cartesian Stress' announces 18 rows but the file ends after 15"):
        read_stress_file(tmp_path / "truncated.stress")
    (tmp_path / "no_stress.stress").write_text("\n".join(lines[:len(nodes) + len(hexes) + 2]) + "\n")
    with pytest.raises(TsvFileError, match="missing section 'Cartesian Stress'"):
        read_stress_file(tmp_path / "no_stress.stress")
    bad_ids = lines.copy()
    bad_ids[len(nodes) + 2] = "1 2 3 4 5 6 7 99"
    (tmp_path / "ids.stress").write_text("\n".join(bad_ids) + "\n")
    with pytest.raises(TsvFileError, match="node ids outside 1..18"):
        read_stress_file(tmp_path / "ids.stress")
    garbage = lines.copy()
    garbage[3] = "1.0 abc 2.0"
    (tmp_path / "garbage.stress").write_text("\n".join(garbage) + "\n")
    with pytest.raises(TsvFileError, match="'Vertices' has malformed rows \\(line 4\\)"):
        read_stress_file(tmp_path / "garbage.stress")
    with pytest.raises(TsvFileError, match="not found"):
        read_stress_file(tmp_path / "absent.stress")
    with pytest.raises(mi_nest.SceneError, match="truncated"):
        mi_nest.load_scene(_specimen_scene(tmp_path, tmp_path / "truncated.stress"))
    with pytest.raises(MeshError, match="stress must have shape"):
        TetMeshStress.from_cells(nodes, hexes, np.zeros((3, 6)))
    flat = nodes.copy()
    flat[:, 2] = 0.0
    with pytest.raises(MeshError, match="degenerate"):
        TetMeshStress.from_cells(flat, hexes, np.zeros((len(nodes), 6)))


def _specimen_scene(tmp_path, stress_file):
    path = tmp_path / "specimen.xml"
    path.write_text(f"""<scene version="3.0.0">
    <integrator type="photoelastic"/>
    <emitter type="polariscope_light"/>
    <sensor type="polariscope"><film type="hdrfilm"><integer name="width" value="4"/>
        <integer name="height" value="4"/></film></sensor>
    <shape type="specimen"><string name="filename" value="{stress_file}"/>
        <float name="fringe_value" value="10"/></shape>
</scene>""")
    return path


def test_scene_fields_export_to_vtk_including_analytic_models(tmp_path, capsys):
    from mi_nest.cli import main
    output = tmp_path / "disk.vtu"
    # 49 nodes across the 40 mm disk put one node at its centre.
    assert main(["export", "disk_compression", "-o", str(output), "--resolution", "49", "-D", "load=500"]) == 0
    assert str(output) in capsys.readouterr().out
    exported = meshio.read(output)
    centre = np.argmin(np.linalg.norm(exported.points, axis=1))
    assert np.linalg.norm(exported.points[centre]) < 1e-5
    difference = exported.point_data["sigma_1_minus_sigma_3"][centre]
    assert difference == pytest.approx(8 * 500 / (math.pi * 40 * 6), rel=1e-5)
    with pytest.raises(ValueError, match="no shape with a stress medium"):
        from mi_nest.export import export_scene
        export_scene(mi.load_dict({"type": "scene", "s": {"type": "cube"}}), tmp_path / "none.vtu")


def test_carti_grid_orientation_order_and_rendering(tmp_path):
    from mi_nest.io.carti import read_carti_file, write_carti_file
    cells, lower, upper = (4, 3, 2), (0.0, -3.0, 1.0), (8.0, 3.0, 5.0)
    # An L-shaped solid: every voxel but those with ix >= 2 and iy == 0 (the top row, y max).
    ix, iy, iz = np.meshgrid(np.arange(4), np.arange(3), np.arange(2), indexing="ij")
    ids = (iy + 3 * (ix + 4 * iz)).ravel()
    solid = ids[~((ix >= 2) & (iy == 0)).ravel()]
    gradient = np.array([[1.0, 0.2, 0.0, 0.1, 0.0, 0.3], [0.5, -1.0, 0.2, 0.0, 0.4, 0.0], [0.0, 0.3, 2.0, 0.0, 0.0, -0.2]])
    write_carti_file(tmp_path / "l.carti", cells, lower, upper, solid, lambda p: p @ gradient,
                     node_forces=[(0, 0.0, 0.0, -5.0)], fixed_nodes=[1, 2])
    carti = read_carti_file(tmp_path / "l.carti")
    model = carti.model()
    assert model.elements.shape == (len(solid), 8) and model.node_forces.shape == (1, 4)
    # Each node's stress row matches its position: pins y orientation and the id order.
    np.testing.assert_allclose(model.stress, model.vertices @ gradient, atol=1e-6)
    mesh = TetMeshStress.from_model(model)
    surface = trimesh.Trimesh(mesh.nodes, mesh.surface, process=False)
    assert surface.is_watertight and surface.volume == pytest.approx(8 * 6 * 4 * (1 - 2 / 12), rel=1e-9)
    # The missing voxels are at the top (largest y), right (largest x).
    assert not np.any((mesh.nodes[:, 0] > 4.0 + 1e-9) & (mesh.nodes[:, 1] > 1.0 + 1e-9))
    grid = grid_from_file(tmp_path / "l.carti")
    z, y, x = np.meshgrid(*[np.linspace(grid.bbox_min[i], grid.bbox_max[i], n)
                            for i, n in zip((2, 1, 0), grid.stress.shape[:3])], indexing="ij")
    solid_nodes = ~((x > 4.0 + 1e-9) & (y > 1.0 + 1e-9))
    np.testing.assert_allclose(grid.stress[solid_nodes], (np.stack([x, y, z], -1) @ gradient)[solid_nodes],
                               atol=1e-5)
    specimen = {"type": "specimen", "filename": str(tmp_path / "l.carti"), "fringe_value": 50.0}
    channels = mi_nest.render(scene([specimen], res=8, view=5.0, origin=(4, 0, 100), target=(4, 0, 0),
                                    step=0.25)).channels
    assert np.all(np.isfinite(channels["char.delta"])) and channels["char.delta"].std() > 0.01
    (tmp_path / "cut.carti").write_text("\n".join((tmp_path / "l.carti").read_text().splitlines()[:-5]))
    with pytest.raises(TsvFileError, match="ends early"):
        read_carti_file(tmp_path / "cut.carti")


CUBE = KITTEN.parent / "ansys_cube.stress"


@pytest.mark.skipif(not CUBE.is_file(), reason="shared 3D-TSV samples not beside the checkout")
def test_the_ansys_cube_sample_imports_with_a_closed_boundary():
    model = read_stress_file(CUBE)
    assert model.vertices.shape == (68921, 3) and model.elements.shape == (64000, 8)
    assert model.node_forces.shape == (1681, 4) and model.fixed_nodes.shape == (1681,)
    mesh = TetMeshStress.from_model(model)
    surface = trimesh.Trimesh(mesh.nodes, mesh.surface, process=False)
    assert surface.is_watertight and surface.volume == pytest.approx(np.prod(np.ptp(mesh.nodes, axis=0)), rel=1e-6)
