"""Issue 18, item 4: results that used to come out silently wrong are now right, an error, or a loud warning."""
import re
import shutil
import warnings

import meshio
import mitsuba as mi
import numpy as np
import pytest
from skfem import MeshTet

import mi_nest
from mi_nest.cli import main
from mi_nest.dataset import CameraModel, DatasetError, SimulationSettings, simulate
from mi_nest.dataset import format as fmt
from mi_nest.fem import FemError, Material, SolverConfig, solve
from mi_nest.io.exr import read_channels, read_metadata, write_channels
from mi_nest.io.mesh import save_mesh_stress
from mi_nest.reconstruct import DivergenceError, optimize
from scenes import TINY, UNIFORM_CUBE_XML

# A 6 mm cube (Mitsuba's cube mesh: two triangles per face) seen along -z by an orthographic camera whose view
# is exactly the cube's face. No robust-intersection flag: at 100x100 pixels, eight pixel centres lie exactly
# on face diagonals where Embree's default intersector misses both triangles.
CUBE_XML = """<scene version="3.0.0">
    <integrator type="photoelastic"><float name="step_size" value="0.5"/></integrator>
    <emitter type="polariscope_light"><float name="polarizer" value="90"/></emitter>
    <sensor type="polariscope">
        <string name="projection" value="orthographic"/>
        <float name="analyzer" value="0"/>
        <transform name="to_world">
            <scale x="3" y="3"/>
            <lookat origin="{origin}" target="{target}" up="0, 1, 0"/>
        </transform>
        <sampler type="stratified"><integer name="sample_count" value="1"/><boolean name="jitter" value="false"/></sampler>
        <film type="hdrfilm">
            <integer name="width" value="{res}"/><integer name="height" value="{res}"/>
            <string name="pixel_format" value="luminance"/><rfilter type="box"/>
        </film>
    </sensor>
""" + UNIFORM_CUBE_XML + "</scene>"
FAST = dict(iterations=3, batch_size=64, views_per_batch=3, resolution=6, evaluate_views=1, pixel_samples=1)


def cube_scene(tmp_path, res=100, origin="0, 0, 50", target="0, 0, 0", stress=1.0):
    path = tmp_path / "cube.xml"
    path.write_text(CUBE_XML.format(res=res, origin=origin, target=target, stress=stress))
    return path


def simulated(directory, settings=TINY):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)     # the disk's load points alias
        simulate("disk_compression", directory, settings, progress=False, defines={"load": 200})
    return directory


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    return simulated(tmp_path_factory.mktemp("data") / "disk")


def copy_of(dataset, tmp_path, name="copy"):
    return shutil.copytree(dataset, tmp_path / name)


def rewrite_rotation(directory, position, change):
    """Rewrite one rotation file with ``change(channels)`` applied, keeping its header."""
    path = directory / fmt.rotation_file(position)
    channels = read_channels(path)
    change(channels)
    write_channels(path, channels, metadata=read_metadata(path), half=True)


# ----------------------------------------------------------------------------------------------- edge rays

@pytest.mark.parametrize("loader", ["mi_nest.load_scene", "mi.load_file"])
def test_rays_through_mesh_edges_cross_the_whole_cube(tmp_path, loader):
    """Edge rays: exact-centre rays on face diagonals went camera-to-exit (52.99 mm) or missed the cube (0 mm).

    ``load_scene`` switches Embree's robust intersections on; a scene loaded without them (plain
    ``mi.load_file``) gets the same path lengths from the walk's second looks.
    """
    path = cube_scene(tmp_path)
    scene = mi_nest.load_scene(path) if loader == "mi_nest.load_scene" else mi.load_file(str(path))
    length = mi_nest.render(scene).channels["path.length"]
    assert length.shape == (100, 100)
    np.testing.assert_allclose(length, 6.0, atol=1e-5)


# ----------------------------------------------------------------------------------------- dataset files

def test_a_rotation_file_swapped_for_another_is_refused_and_a_rerun_repairs_it(tiny_dataset, tmp_path):
    """Swapped dataset file: a rotation's EXR replaced by another rotation's (or another dataset's) was
    trained on with the wrong pose; each view's header is checked against dataset.json."""
    copy = copy_of(tiny_dataset, tmp_path)
    shutil.copy(copy / fmt.rotation_file(1), copy / fmt.rotation_file(2))
    with pytest.raises(DatasetError, match=r"0002.exr: its header says rotation 1, dataset.json lists it as "
                                           r"rotation 2; the file belongs to another rotation or dataset"):
        mi_nest.Dataset(copy).view(2)
    with pytest.raises(DatasetError, match="header says rotation 1"):
        optimize(mi_nest.load_scene("disk_compression", res=8, load=200), copy, progress=False, **FAST)
    simulated(copy)      # a rerun of the simulation renders the rotation again
    np.testing.assert_array_equal(mi_nest.Dataset(copy).measurements(2), mi_nest.Dataset(tiny_dataset).measurements(2))
    # The same rotation from a dataset with another camera.
    noisy = simulated(tmp_path / "noisy", SimulationSettings(**{**TINY.__dict__, "camera": CameraModel(read_noise=0.01)}))
    shutil.copy(noisy / fmt.rotation_file(2), copy / fmt.rotation_file(2))
    with pytest.raises(DatasetError, match="made with other settings"):
        mi_nest.Dataset(copy).view(2)


def test_an_interrupted_acquisition_rewrites_a_truncated_rotation_file(tmp_path):
    """Truncated rotation EXR: a crash could leave a renamed rotation file cut short, which a rerun declared
    complete; the rerun now reads each file to its end and writes it again from the journaled frames."""
    from mi_nest.rig import sim
    from mi_nest.rig.acquire import acquire
    from mi_nest.rig.config import load
    from test_rig_acquire import rig_file
    sim.reset()
    try:
        config = load(rig_file(tmp_path, resolution=8))
        output = tmp_path / "captured"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            acquire(config, output, progress=False, unverified_handedness=True)
            whole = read_channels(output / fmt.rotation_file(1))
            path = output / fmt.rotation_file(1)
            path.write_bytes(path.read_bytes()[:path.stat().st_size // 2])
            report = acquire(config, output, progress=False, unverified_handedness=True)
    finally:
        sim.reset()
    assert report.captured == 0
    for name, image in read_channels(output / fmt.rotation_file(1)).items():
        np.testing.assert_array_equal(image, whole[name], err_msg=name)
    mi_nest.Dataset(output).check_measurements()


# ----------------------------------------------------------------------------------------------------- FEM

def _cubes(second_at, weld=False):
    """Two 4 mm tetrahedral cubes, the second's corner at ``second_at``; ``weld`` merges coincident nodes."""
    a = MeshTet.init_tensor(*[np.linspace(0, 4, 3)] * 3)
    b = MeshTet.init_tensor(*[np.linspace(c, c + 4, 3) for c in second_at])
    points, tets = np.hstack([a.p, b.p]), np.hstack([a.t, b.t + a.p.shape[1]])
    if weld:
        unique, index = np.unique(points.T.round(9), axis=0, return_inverse=True)
        points, tets = unique.T, index.ravel()[tets]
    return points, tets


def test_a_loaded_body_that_nothing_holds_is_refused(tmp_path, capsys):
    """FEM: with two disjoint bodies and the load on the unfixed one, `mi-nest fem` wrote a solution with
    relative residual 6.1 and exit code 0; rigid modes are checked per connected body."""
    points, tets = _cubes((10, 0, 0))
    meshio.Mesh(points.T, [("tetra", tets.T)]).write(tmp_path / "two.vtu")
    output = tmp_path / "two.npz"
    assert main(["fem", str(tmp_path / "two.vtu"), "--fix", "x=0", "--load", "x=14:10,0,0", "-o", str(output)]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "leave 6 rigid-body motion(s) of body 2 of the mesh's 2 disconnected " \
                                      "bodies (from (10, 0, 0) to (14, 4, 4) mm; each body needs fixtures" in error
    assert not output.exists()
    # Held at both ends, the pair solves.
    assert main(["fem", str(tmp_path / "two.vtu"), "--fix", "x=0", "--fix", "x=14", "-o", str(output)]) == 0


def test_a_solve_that_did_not_converge_is_refused():
    """FEM: a singular system that the direct solver still returns garbage for (a body hinged to another
    at one node) is refused with its residual instead of written."""
    points, tets = _cubes((4, 4, 4), weld=True)
    mesh = MeshTet(points, tets)
    traction = [{"type": "traction", "name": "pull", "traction": [1.0, 0.3, 0.0],
                 "where": {"type": "plane", "point": [8, 0, 0], "normal": [1, 0, 0]}}]
    clamp = [{"name": "base", "where": {"type": "plane", "point": [0, 0, 0], "normal": [1, 0, 0]}}]
    with pytest.raises(FemError, match=r"the sparse LU solution does not solve the system: relative residual "
                                       r"[0-9.]+e-01 .*joined only at a node or an edge"):
        solve(mesh, Material(3000.0, 0.37), traction, clamp, solver=SolverConfig(method="direct"))


# ----------------------------------------------------------------------------------------- reconstruction

def test_a_runaway_fit_is_divergence(tiny_dataset, tmp_path, capsys):
    """Reconstruct: learning rate 1e6 reported a 9e8 % error with exit code 0; a field that runs away
    beyond what the images could resolve stops the run, keeps the last good checkpoint, exits 2."""
    output = tmp_path / "run"
    assert main(["reconstruct", str(tiny_dataset), "--allow-aliased",
                 "-o", str(output), "--option", "learning_rate=1e6", "--iterations",
                 "20", "--option", "batch_size=64", "--resolution", "6", "--no-progress"]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "optimisation diverged at iteration 20: the field ran away to " in error
    assert "no checkpoint was written yet. Lower the learning_rate" in error
    assert not (output / "field.npz").exists() and not (output / "checkpoint.npz").exists()
    # With checkpoints on the way, the last one before the run away is kept.
    with pytest.raises(DivergenceError, match=r"iteration 10: .*ran away.* the last good checkpoint \(iteration "
                                              r"5\) is kept"):
        optimize(mi_nest.load_scene("disk_compression", res=8, load=200), tiny_dataset, output=tmp_path / "later",
                 progress=False, **{**FAST, "iterations": 10, "checkpoint_every": 5, "learning_rate": 0.1,
                                    "final_learning_rate": 1e5})


def test_non_finite_measurements_are_refused_naming_file_and_channel(tiny_dataset, tmp_path):
    """Reconstruct: NaN measurements surfaced only as a divergence traceback; they are refused on load."""
    copy = copy_of(tiny_dataset, tmp_path)

    def poison(channels):
        channels["pol.45.0.45"][2, 3] = np.nan
        channels["pol.90.45.0"][:, 0] = np.inf
    rewrite_rotation(copy, 1, poison)
    with pytest.raises(DatasetError, match=r"rotations/0001.exr: NaN or inf in channel\(s\) pol.45.0.45 \(1 pixels\), "
                                           r"pol.90.45.0 \(8 pixels\)"):
        optimize(mi_nest.load_scene("disk_compression", res=8, load=200), copy, progress=False, **FAST)


def test_all_zero_measurements_are_refused(tiny_dataset, tmp_path, capsys):
    """Reconstruct: all-zero measurements gave a 99.99 % error with no warning; a view of zeros is refused."""
    copy = copy_of(tiny_dataset, tmp_path)
    for position in range(4):
        rewrite_rotation(copy, position, lambda channels: [channels[n].fill(0.0) for n in fmt.CHANNELS])
    assert main(["reconstruct", str(copy), "--allow-aliased",
                 "-o", str(tmp_path / "run"), "--iterations", "3", "--no-progress"]) == 2
    assert "0000.exr: every measurement is zero (no light reached the camera" in capsys.readouterr().err


def test_saturated_views_warn(tmp_path):
    """Reconstruct: views whose specimen sits at the camera's full scale warn once, naming them."""
    clipped = simulated(tmp_path / "clipped", SimulationSettings(**{**TINY.__dict__,
                                                                    "camera": CameraModel(bits=8, saturation=0.25)}))
    with pytest.warns(RuntimeWarning, match=r"in 4 of 4 views \(rotations 0, 1, 2, 3\) more than 5% of the "
                                            r"specimen's measurements sit at the camera's full scale \(0.25\)"):
        mi_nest.Dataset(clipped).check_measurements()
    unclipped = simulated(tmp_path / "unclipped", SimulationSettings(**{**TINY.__dict__,
                                                                        "camera": CameraModel(bits=8)}))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mi_nest.Dataset(unclipped).check_measurements()


# ------------------------------------------------------------------------------------ renders and inputs

def test_a_huge_stress_is_an_error_not_nan_pixels(tmp_path, capsys):
    """Stress of 1e15 MPa rendered NaN into most pixels with exit code 0; the render is refused, naming
    the count and the likely cause."""
    output = tmp_path / "huge.exr"
    stress = 1e15
    assert main(["render", str(cube_scene(tmp_path, res=32, stress=stress)), "-o", str(output), "--quiet"]) == 2
    error = capsys.readouterr().err
    order = 50e-12 * stress * 1e6 * 6e-3 / 532e-9      # C sigma t / lambda: Brewster, MPa, mm, nm in SI
    assert error.count("\n") == 1 and "cube.xml: 1024 of 1024 pixels are NaN or inf (in Y, jones.a, jones.b, ...): " \
           f"the stress field is NaN there, or so large that fringe orders reach {order:.3g} (real parts show a few " \
           "hundred at most); check its magnitude and units (MPa)" in error
    assert not output.exists()


def test_zero_samples_per_pixel_is_refused(tmp_path, capsys):
    """`--spp 0` was taken as the scene's default (render) or stored as it (simulate)."""
    scene = cube_scene(tmp_path, res=8)
    assert main(["render", str(scene), "-o", str(tmp_path / "out.exr"), "--spp", "0", "--quiet"]) == 2
    assert "'spp' must be a positive integer, got 0" in capsys.readouterr().err
    assert main(["simulate", "disk_compression", "-o", str(tmp_path / "data"), "--azimuth", "2", "--elevation", "2",
                 "--res", "8", "--spp", "0"]) == 2
    assert "'spp' must be a positive integer, got 0" in capsys.readouterr().err
    assert not (tmp_path / "out.exr").exists() and not (tmp_path / "data").exists()


@pytest.mark.parametrize("resolution", [0, 1])
def test_export_needs_two_grid_nodes_per_axis(tmp_path, capsys, resolution):
    """`export --resolution 0|1` wrote a one-cell grid."""
    output = tmp_path / "disk.vtu"
    assert main(["export", "disk_compression", "-o", str(output), "--resolution", str(resolution)]) == 2
    assert f"'resolution' must be an integer >= 2, got {resolution}" in capsys.readouterr().err
    assert not output.exists()


def test_fractional_mesh_indices_are_refused(tmp_path, capsys):
    """Float mesh indices were truncated (4.5 became node 4); whole-number floats still load."""
    nodes = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], float)
    stress = np.zeros((5, 6))
    path = tmp_path / "mesh.npz"
    np.savez(path, nodes=nodes, cells=np.array([[0, 1, 2, 3], [1, 2, 3, 4.5]]), stress=stress)
    assert main(["export", str(path), "-o", str(tmp_path / "mesh.vtu")]) == 2
    assert "cell node indices must be whole numbers, got [1.0, 2.0, 3.0, 4.5] in cell 1" in capsys.readouterr().err
    np.savez(path, nodes=nodes, cells=np.array([[0, 1, 2, 3], [1, 2, 3, 4.0]]), stress=stress)
    assert main(["export", str(path), "-o", str(tmp_path / "mesh.vtu")]) == 0
    save_mesh_stress(tmp_path / "int.npz", nodes, [[0, 1, 2, 3], [1, 2, 3, 4]], stress)
    from mi_nest.fields.sources import load_mesh
    np.testing.assert_array_equal(load_mesh(path).tets, load_mesh(tmp_path / "int.npz").tets)


def test_a_view_without_specimen_warns(tmp_path):
    """A view with no specimen in it rendered an empty polariscope without a word."""
    scene = cube_scene(tmp_path, res=8, origin="100, 0, 50", target="100, 0, 0")
    with pytest.warns(RuntimeWarning, match=r"cube.xml: the camera sees no specimen \(path.length is 0 in every "
                                            r"pixel\).*check the camera pose"):
        mi_nest.render(mi_nest.load_scene(scene))
    with pytest.warns(RuntimeWarning, match="the camera sees no specimen"):
        assert main(["render", str(scene), "-o", str(tmp_path / "empty.exr"), "--quiet"]) == 0


def test_fringe_orders_beyond_float32_are_an_error(tmp_path, capsys):
    """A stress large enough to lose the phase in float32 (but not to overflow) rendered garbage silently."""
    output = tmp_path / "large.exr"
    assert main(["render", str(cube_scene(tmp_path, res=8, stress=1e6)), "-o", str(output), "--quiet"]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "fringe orders reach 5.64e+05 in 64 of 64 pixels; beyond 1e+05" in error
    assert not output.exists()
    # a hundred times less is still a faithful render
    assert main(["render", str(cube_scene(tmp_path, res=8, stress=1e4)), "-o", str(output), "--quiet"]) == 0
    assert output.exists()


def test_a_step_too_coarse_for_a_turning_field_warns_with_the_step_that_holds():
    """``-D step=1000`` on the twisted block rendered 3.6 rad off a fine-step render without a word. A fixed
    step that spans a field whose axes turn warns, naming a step that holds; the disk along its axis (steps
    commute: one step is exact) and the scene's own step do not."""
    coarse = mi_nest.load_scene("twisted_block", res=16, step=1000)
    with pytest.warns(RuntimeWarning, match=r"step_size 1000 mm is coarse for this field: its principal axes "
                                            r"turn by up to 3.\d rad .* at most about (\d\.\d+) mm") as caught:
        far = mi_nest.render(coarse, spp=1).channels["char.delta"]
    finer = float(re.search(r"at most about (\d\.\d+) mm", str(caught[0].message)).group(1))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)         # 16 px: the block's fringes alias a little
        warnings.filterwarnings("error", ".*is coarse for this field", RuntimeWarning)
        fine = mi_nest.render(mi_nest.load_scene("twisted_block", res=16), spp=1).channels["char.delta"]
        held = mi_nest.render(mi_nest.load_scene("twisted_block", res=16, step=finer), spp=1).channels["char.delta"]
        mi_nest.render(mi_nest.load_scene("disk_compression", res=16, step=1000, load=100), spp=1)
    assert np.abs(far - fine).max() > 1.0 and np.abs(held - fine).max() < 0.05 * np.abs(fine).max()
