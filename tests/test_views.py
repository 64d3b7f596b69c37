"""Novel views of scenes and reconstructions: one code path with mi-nest render, poses as datasets pose,
polariscope, load and wavelength options, turntables and the held-out comparison."""
import json
import re

import imageio.v3 as iio
import numpy as np
import pytest

import mi_nest
from mi_nest.cli import main
from mi_nest.dataset import SimulationSettings, simulate
from mi_nest.views import open_source
from mi_nest.views.novel import held_out_views, render_view, turntable, view_pose
from mi_nest.io.exr import read_channels
from mi_nest.reconstruct import Reconstruction
from mi_nest.scene import pose

SETTINGS = SimulationSettings(azimuths=3, elevations=2, res=12, spp=1, test_fraction=0.34)


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    """A reconstruction of a small disk dataset (a few iterations: the views only need its field)."""
    root = tmp_path_factory.mktemp("views")
    with pytest.warns(RuntimeWarning):
        simulate("disk_compression", root / "data", SETTINGS, progress=False, defines={"load": 200})
    assert main(["reconstruct", str(root / "data"), "--allow-aliased",
                 "-o", str(root / "result"), "--iterations", "3", "--option",
                 "batch_size=64", "--resolution", "6", "--kind", "grid", "--no-progress"]) == 0
    return root


def test_a_reconstruction_records_the_scene_it_was_reconstructed_with(result):
    source = json.loads((result / "result" / "reconstruction.json").read_text())["source"]
    assert source["scene_file"].endswith("disk_compression.xml")
    assert source["defines"]["load"] == "200" and source["defines"]["res"] == "12"


def test_a_view_at_a_held_out_rotation_is_that_rotations_camera(result):
    dataset = mi_nest.Dataset(result / "data")
    source = open_source(result / "result")
    for position in dataset.split("test"):
        rotation = dataset.rotations[position]
        np.testing.assert_allclose(view_pose(source, rotation["azimuth"], rotation["elevation"]),
                                   dataset.to_world(position), atol=1e-6)


def test_mi_nest_render_of_a_reconstruction_is_its_field_rendered_at_that_pose(result, tmp_path, capsys):
    dataset = mi_nest.Dataset(result / "data")
    position = dataset.split("test")[0]
    rotation = dataset.rotations[position]
    output = tmp_path / "view.exr"
    assert main(["render", str(result / "result"), "--azimuth", str(rotation["azimuth"]), "--elevation",
                 str(rotation["elevation"]), "-o", str(output), "--quiet", "--seed", "3"]) == 0
    shown = read_channels(output)
    scene = mi_nest.load_scene("disk_compression", load=200, res=12)
    pose(scene, dataset.to_world(position))
    field = Reconstruction.load(result / "result").field
    direct = mi_nest.render(scene, seed=3, field=field)
    for name in ("Y", "pol.45.0.135", "jones.a", "fringe.order"):
        np.testing.assert_allclose(shown[name], direct.channels[name], atol=1e-6)
    # The reconstruction, not the scene's own stress.
    truth = mi_nest.render(scene, seed=3)
    assert np.abs(truth.channels["jones.b"] - shown["jones.b"]).max() > 1e-3


def test_a_reconstruction_renders_in_white_light_as_its_field_would(result, tmp_path):
    """``mi-nest render RECONSTRUCTION --white-light``: the colours of the reconstructed field (its spectral
    march), each wavelength the monochromatic render of that field."""
    from mi_nest.physics.colour import white_led
    from mi_nest.render import View, phase_scale, render_white_light
    output = tmp_path / "white.exr"
    assert main(["render", str(result / "result"), "-o", str(output), "--white-light", "--quiet"]) == 0
    shown = read_channels(output)
    scene = mi_nest.load_scene("disk_compression", load=200, res=12)
    field = Reconstruction.load(result / "result").field
    direct = render_white_light(scene, white_led(step=10.0), field=field)
    for name in ("R", "G", "B", "I.450", "I.650"):
        np.testing.assert_allclose(shown[name], direct.channels[name], atol=1e-5)
    alone = mi_nest.render(scene, field=field, view=View(phase_scale=phase_scale(scene, 1.0, 650.0))).main
    np.testing.assert_allclose(shown["I.650"], alone, atol=5e-4)
    truth = render_white_light(scene, white_led(step=10.0))
    assert np.abs(truth.channels["R"] - shown["R"]).max() > 1e-3


def test_the_polariscope_load_and_wavelength_options_change_what_they_name():
    source = open_source("disk_compression", {"res": "24"})
    from mi_nest.physics.polariscope import polariscope_setting
    dark = render_view(source, polariscope=polariscope_setting(field="dark"), spp=2)
    light = render_view(source, polariscope=polariscope_setting(field="light"), spp=2)
    own = render_view(source, spp=2)
    np.testing.assert_allclose(dark.main + light.main, 1.0, atol=1e-5)
    np.testing.assert_allclose(own.main, dark.main, atol=1e-6)      # the scene's is the dark circular one
    doubled = render_view(source, load_scale=2.0, spp=2).channels["fringe.order"]
    np.testing.assert_allclose(doubled, 2 * own.channels["fringe.order"], rtol=1e-4, atol=1e-5)
    green = render_view(source, wavelength=266.0, spp=2).channels["fringe.order"]
    np.testing.assert_allclose(green, 2 * own.channels["fringe.order"], rtol=1e-4, atol=1e-5)


def test_a_turntable_is_views_a_turn_apart(tmp_path, capsys):
    source = open_source("twisted_block", {"res": "16"})
    frames = turntable(source, frames=4, elevation=10.0, spp=1)
    for index in (0, 1):
        np.testing.assert_allclose(frames[index], render_view(source, 90.0 * index, 10.0, spp=1,
                                                              seed=index).main, atol=1e-6)
    assert np.abs(frames[0] - frames[1]).max() > 0.05
    output = tmp_path / "turn.gif"
    assert main(["turntable", "twisted_block", "-D", "res=16", "--frames", "5", "-o", str(output)]) == 0
    assert iio.imread(output, index=None).shape[0] == 5


def test_the_held_out_comparison_shows_the_capture_beside_the_same_render(result, tmp_path):
    source = open_source(result / "result")
    dataset = mi_nest.Dataset(result / "data")
    views = held_out_views(source, count=2, channel="pol.45.0.135")
    assert len(views) == min(2, len(dataset.split("test")))
    for (rotation, captured, rendered, _), position in zip(views, dataset.split("test")):
        np.testing.assert_array_equal(captured, dataset.view(position, ["pol.45.0.135"])["pol.45.0.135"])
        expected = render_view(source, rotation["azimuth"], rotation["elevation"]).channels["pol.45.0.135"]
        np.testing.assert_allclose(rendered, expected, atol=1e-6)
    output = tmp_path / "compare.png"
    assert main(["compare", str(result / "result"), "-o", str(output), "--views", "2"]) == 0
    assert output.stat().st_size > 0


@pytest.mark.parametrize("arguments, message", [
    (["turntable", "disk_compression", "-o", "turn.avi"], "written as .gif or .mp4"),
    (["turntable", "disk_compression", "-o", "turn.gif", "--frames", "1"], "at least 2 frames"),
    (["render", "disk_compression", "-o", "x.exr", "--azimuth", "nan"], "--azimuth must be a finite number"),
    (["render", "disk_compression", "-o", "x.exr", "--load-scale", "inf"], "load scale must be a finite"),
    (["compare", "disk_compression", "-o", "x.png"], "held-out views are a reconstruction's"),
    (["render", "{empty}", "-o", "x.exr"], "is a directory but not a reconstruction"),
])
def test_bad_view_options_get_one_line(arguments, message, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "empty").mkdir()
    arguments = [str(tmp_path / "empty") if a == "{empty}" else a for a in arguments]
    assert main(arguments) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and message in error
    assert not any(tmp_path.glob("turn.*")) and not (tmp_path / "x.exr").exists()


def test_a_reconstructions_principal_stresses_are_deviatoric_beside_the_truths(result, tmp_path, capsys):
    from mi_nest.views import Plane
    from mi_nest.views.principal import source_slices
    shown, truth = source_slices(open_source(result / "result"), Plane.parse("z=0"), 24)
    assert shown.deviatoric and truth is not None and truth.deviatoric
    inside = shown.inside & truth.inside
    np.testing.assert_allclose(shown.values[inside].sum(axis=-1), 0.0, atol=1e-4)
    np.testing.assert_allclose(truth.values[inside].sum(axis=-1), 0.0, atol=1e-4)
    np.testing.assert_allclose(shown.minus(truth)["sigma_1"][inside], (shown.values - truth.values)[..., 0][inside])
    output = tmp_path / "principal.png"
    assert main(["principal", str(result / "result"), "--plane", "z=0", "--res", "24", "-o", str(output)]) == 0
    printed = capsys.readouterr().out
    assert "von Mises against the truth: RMS error" in printed and output.stat().st_size > 0
    # The trust map's column: the uncertainty on the plane and the Spearman ranking of the actual error.
    assert re.search(r"where to trust it \(trust.npz\): uncertainty \S+ to \S+ stress scales per box length on this "
                     r"plane; it ranks the actual deviatoric error at Spearman -?\d\.\d\d", printed)
    assert iio.imread(output).shape[1] > 5 * 4 * 80        # five panels across, not four
    from mi_nest.views.principal import deviatoric_error, uncertainty_on
    difference = (shown.stress - truth.stress)[inside]
    difference[:, :3] -= difference[:, :3].mean(axis=1, keepdims=True)
    expected = np.linalg.norm(difference[:, [0, 3, 5, 3, 1, 4, 5, 4, 2]], axis=1)    # the full 3x3 matrix's norm
    np.testing.assert_allclose(deviatoric_error(shown, truth)[inside], expected, rtol=1e-9)
    uncertainty = uncertainty_on(shown, open_source(result / "result").trust)
    assert np.isfinite(uncertainty[shown.inside]).all() and np.isnan(uncertainty[~shown.inside]).all()


def test_a_reconstruction_exports_to_3d_tsv_and_reads_back_as_its_field(result, tmp_path, capsys):
    from mi_nest.fields.base import sample
    from mi_nest.io.tsv import read_stress_file
    output = tmp_path / "disk.TSV"
    assert main(["export", str(result / "result"), "-o", str(output), "--resolution", "12"]) == 0
    assert "deviatoric" in capsys.readouterr().out
    model = read_stress_file(output)
    field = Reconstruction.load(result / "result").field
    np.testing.assert_allclose(model.stress, sample(field, model.vertices), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(model.stress[:, :3].sum(axis=1), 0.0, atol=1e-5)     # trace-free


def test_a_reconstruction_s_exports_say_deviatoric_and_hold_only_the_part(result, tmp_path, capsys):
    import meshio
    from mi_nest.io.tsv import read_stress_file
    vtu, tsv = tmp_path / "field.vtu", tmp_path / "field.TSV"
    for output in (vtu, tsv):
        assert main(["export", str(result / "result"), "-o", str(output), "--resolution", "16"]) == 0
    exported = meshio.read(vtu)
    assert {"deviatoric_stress", "s_1", "s_3", "s_1_direction", "s_1_minus_s_3"} <= set(exported.point_data)
    assert not {"stress", "sigma_1"} & set(exported.point_data)
    np.testing.assert_allclose(np.trace(exported.point_data["deviatoric_stress"].reshape(-1, 3, 3), axis1=1, axis2=2),
                               0.0, atol=1e-4)
    # Every cell's centre lies inside the 40 mm disk, 6 mm thick; its nodes a cell's diagonal from it at most.
    cells = exported.cells_dict["hexahedron"]
    centres = exported.points[cells].mean(axis=1)
    assert np.hypot(centres[:, 0], centres[:, 1]).max() < 20.0 and np.abs(centres[:, 2]).max() < 3.0
    first_line = tsv.read_text().splitlines()[0]
    assert first_line.startswith("Version 2.0") and "deviatoric stress" in first_line
    assert len(read_stress_file(tsv).vertices) == len(exported.points)       # mi_nest reads its own note back
    printed = capsys.readouterr().out
    assert "deviatoric_stress and s_1..s_3" in printed
    # The trust map goes into the .vtu at its nearest measured node, and the .TSV says it is not there.
    from mi_nest.reconstruct.trust import TrustMap
    trust = TrustMap.load(result / "result" / "trust.npz")
    for name in ("uncertainty", "coverage", "direction_spread", "heldout_residual"):
        np.testing.assert_allclose(exported.point_data[f"trust_{name}"], trust.at(exported.points, name))
    assert np.isfinite(exported.point_data["trust_uncertainty"]).all()
    assert (exported.point_data["trust_uncertainty"] >= 0).all()
    assert "its trust map written beside it as trust_uncertainty" in printed
    assert "its trust map is not written: 3D-TSV holds stress only" in printed


def test_principal_names_a_deviator_and_its_colour_bars_show_what_they_clip(result, tmp_path, capsys):
    output = tmp_path / "principal.png"
    assert main(["principal", str(result / "result"), "--plane", "z=0", "--res", "24", "-o", str(output)]) == 0
    printed = capsys.readouterr().out
    assert "deviatoric s_1" in printed and "deviatoric s_3" in printed and " sigma_1" not in printed
    from mi_nest.views import principal
    plt = principal.pyplot()
    figure, axis = plt.subplots()
    values = np.array([[0.0, 0.5], [1.0, 9.0]])
    drawn = axis.imshow(values, vmin=-1, vmax=1)
    principal._colour_bar(figure, axis, drawn, values, -1.0, 1.0, "s_1 (MPa)")
    bar = figure.axes[-1]
    assert "beyond the ends: 0 to 9" in bar.get_ylabel()
    plt.close(figure)


def test_the_test_view_is_a_labelled_full_size_figure(result):
    image = iio.imread(result / "result" / "test_view.png")
    assert image.shape[1] >= 1000 and image.shape[0] >= 400        # not a 2-image-wide thumbnail
