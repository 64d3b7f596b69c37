"""Colour bands (physics/bands.py): band sets and their refusals, renders in bands against closed forms and
monochromatic renders, datasets of several bands through the colour polarisation mosaic, and the channel model a
reconstruction fits them with."""
import json
import warnings

import mitsuba as mi
import numpy as np
import pytest

import mi_nest
from mi_nest.dataset import Dataset, SimulationSettings, simulate
from mi_nest.dataset.camera import BAYER, MOSAIC, CameraModel, bayer_sites, mosaic_mask
from mi_nest.physics import MEASUREMENTS, su2
from mi_nest.physics.aliasing import UNRESOLVED_BEAT_SHARE, fringe_aliasing
from mi_nest.physics.bands import BandError, BandSet, camera_bands, narrow_bands, parse_bands, read_bands
from mi_nest.physics.colour import plane_polariscope_transmission, white_led
from mi_nest.reconstruct.channels import ChannelModel
from mi_nest.render import View, phase_scale, render, render_bands
from scenes import box, medium, scene


@pytest.mark.parametrize("make, message", [
    (lambda: narrow_bands([]), "at least one wavelength"),
    (lambda: narrow_bands([532, 450]), "must increase"),
    (lambda: narrow_bands([450, 450]), "must increase"),
    (lambda: narrow_bands([-450]), "positive numbers of nm"),
    (lambda: BandSet(("r", "r"), [500, 600], np.eye(2)), "distinct"),
    (lambda: BandSet(("r.g",), [500], [[1.0]]), "without dots"),
    (lambda: BandSet(("r",), [500, 600], [[1.0]]), "weights of shape"),
    (lambda: BandSet(("r",), [500, 600], [[0.0, 0.0]]), "not zero everywhere"),
    (lambda: parse_bands("red"), "bands must be 'rgb'"),
    (lambda: parse_bands(","), "at least one wavelength"),
])
def test_bands_no_camera_has_are_refused(make, message):
    with pytest.raises(BandError, match=message):
        make()


def test_a_colour_camera_s_bands_are_normalised_and_ordered_by_colour():
    bands = camera_bands()
    assert bands.names == ("red", "green", "blue")
    np.testing.assert_allclose(bands.weights.sum(axis=1), 1.0, rtol=1e-12)
    red, green, blue = bands.weights @ bands.wavelengths
    assert 580 < red < 620 and 520 < green < 555 and 450 < blue < 490
    assert parse_bands("rgb").describe() == bands.describe()
    assert parse_bands("450, 532,633").names == ("450", "532", "633")


def test_broad_bands_traced_more_coarsely_keep_their_centres_and_narrow_ones_stay():
    bands = camera_bands()
    coarse = bands.resampled(20.0)
    assert len(coarse.wavelengths) == 14 and np.all(np.diff(coarse.wavelengths) == 20.0)
    np.testing.assert_allclose(coarse.weights.sum(axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(coarse.weights @ coarse.wavelengths, bands.weights @ bands.wavelengths, atol=3.0)
    # Slabs of one to eight waves of retardation: each band's intensity within 0.015 of the 10 nm sampling's (the
    # datasets' read noise is 0.01), and not the same (a model that differs).
    for retardation in (550.0, 1100.0, 2200.0, 4400.0):
        fine, rough = (b.weights @ plane_polariscope_transmission(np.array(retardation), b.wavelengths)
                       for b in (bands, coarse))
        assert 1e-4 < np.abs(rough - fine).max() < 0.015
    narrow = narrow_bands([520.0, 532.0])
    assert narrow.resampled(20.0) is narrow and bands.resampled(5.0) is bands
    with pytest.raises(BandError, match="positive number of nm"):
        bands.resampled(0.0)


def test_a_camera_s_curves_are_read_from_csv(tmp_path):
    path = tmp_path / "sensor.csv"
    path.write_text("# wavelength, then each band's relative sensitivity\nwavelength,short,long\n"
                    "400,1,0\n500,1,0\n550,0,0\n600,0,1\n700,0,1\n")
    bands = read_bands(path, white_led(step=10.0))
    assert bands.names == ("short", "long")
    short, long = bands.weights @ bands.wavelengths
    assert 420 < short < 500 < 600 < long < 680
    assert parse_bands(str(path)).names == ("short", "long")
    path.write_text("wavelength,a\n500,x\n600,1\n")
    with pytest.raises(BandError, match="must be numbers"):
        read_bands(path)
    with pytest.raises(BandError, match="cannot read the bands file"):
        read_bands(tmp_path / "missing.csv")


def test_a_band_of_a_uniform_slab_is_its_weighted_closed_form():
    """A slab of retardation R between crossed polarisers at 45 degrees passes sin^2(pi R / lambda) at each
    wavelength; a broad band sees their weighted sum, a narrow band its own wavelength's."""
    loaded = scene([box((20, 20, 4), interior=medium(xx=3.0))], res=2, polarizer=45.0, analyzer=-45.0)
    retardation = 50.0 * 4.0 * 3.0          # Brewster x mm x MPa = nm
    for bands in (camera_bands(), narrow_bands([450.0, 532.0, 650.0])):
        result = render_bands(loaded, bands)
        expected = bands.weights @ plane_polariscope_transmission(np.array(retardation), bands.wavelengths)
        for name, value in zip(bands.names, expected):
            np.testing.assert_allclose(result.channels[name], value, atol=2e-5)


def test_narrow_bands_are_the_monochromatic_renders_at_their_wavelengths():
    loaded = mi_nest.load_scene("stacked_disks", res=16, spp=1)
    bands = narrow_bands([450.0, 532.0, 650.0])
    result = render_bands(loaded, bands)
    for name, wavelength in zip(bands.names, bands.wavelengths):
        alone = render(loaded, view=View(phase_scale=phase_scale(loaded, 1.0, wavelength))).channels
        for measurement in MEASUREMENTS:
            np.testing.assert_allclose(result.channels[f"{name}.{measurement}"], alone[measurement], atol=5e-4)
    assert set(result.channels) >= {"Y", "path.length", "fringe.order"}


def test_a_band_render_reports_the_aliasing_of_its_slowest_beat():
    """The beat's report is the aliasing guard on the difference of the two closest bands' orders, each rendered
    alone: 532 and 650 nm (0.1815 / 532 nm apart in 1 / lambda against 0.1822 for 450 and 532)."""
    loaded = mi_nest.load_scene("disk_compression", res=16, spp=1)       # 1 kN: most pixels alias in each band
    result = render_bands(loaded, narrow_bands([450.0, 532.0, 650.0]))
    orders = {w: render(loaded, view=View(phase_scale=phase_scale(loaded, 1.0, w))).channels["fringe.order"]
              for w in (532.0, 650.0)}
    expected = fringe_aliasing(orders[532.0] - orders[650.0], result.channels["path.length"] > 0)
    assert result.aliasing.fraction > 0.5 and 0 < result.beat.aliased < result.aliasing.aliased
    assert (result.beat.pixels, result.beat.aliased) == (expected.pixels, expected.aliased)
    assert result.beat.densities == pytest.approx(expected.densities, rel=1e-4, abs=1e-6)
    assert render(loaded).beat is None


def test_a_result_from_bands_is_judged_by_their_beat():
    from mi_nest.reconstruct import OptimizeConfig, Reconstruction

    def said(**shares):
        return Reconstruction(None, OptimizeConfig(), [], shares, 0.0).describe()
    # The suite's 300 N disk in three narrow bands: each band aliases in 19% of the pixels, their beat in 0.7%.
    assert said(aliased_share=0.19, beat_aliased_share=0.007) == (
        "the fringes of each band are denser than the pixels in 19% of the specimen's pixels, their slowest beat "
        f"in 0.7% (up to {100 * UNRESOLVED_BEAT_SHARE:.0f}%): the bands tell the fringe orders apart")
    assert said(aliased_share=0.19, beat_aliased_share=UNRESOLVED_BEAT_SHARE + 0.01).startswith(
        "UNRELIABLE: in the dataset even the slowest beat between its bands")
    # The 600 N disk in bands close together: a beat resolved, each band aliased past what it can tell apart.
    assert said(aliased_share=0.31, beat_aliased_share=0.0004).startswith(
        "UNRELIABLE: in the dataset the fringes of each band are denser than the pixels in 31%")
    assert said(aliased_share=0.19).startswith("UNRELIABLE: the dataset's fringes are denser than the pixels in 19%")
    assert said(aliased_share=0.05, beat_aliased_share=0.0) == said(aliased_share=0.05) == ""


def test_the_command_takes_bands_whose_beat_is_resolved_and_refuses_them_where_it_is_not(tmp_path, capsys):
    """A 16-pixel disk in three narrow bands: at 70 N each band aliases in 19% of the pixels (one band is refused
    over 10%) and their beat in none; at 300 N the beat aliases in 5.4%."""
    from mi_nest.cli import main
    settings = SimulationSettings(azimuths=3, elevations=2, res=16, spp=1, bands=narrow_bands([450.0, 532.0, 650.0]))
    tiny = ["--iterations", "2", "--option", "batch_size=64", "--resolution", "6", "--no-progress"]
    for load in (70, 300):
        simulate("disk_compression", tmp_path / f"data{load}", settings, defines={"load": load, "contact_width": 4},
                 progress=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(["reconstruct", str(tmp_path / "data70"), "-o", str(tmp_path / "result70"), *tiny]) == 0
    out = capsys.readouterr().out
    assert "the fringes of each band are denser than the pixels in 19%" in out and "tell the fringe orders apart" in out
    assert "UNRELIABLE" not in out and not [w for w in caught if "fringes are denser than the pixels" in str(w.message)]
    record = json.loads((tmp_path / "result70" / "reconstruction.json").read_text())["metrics"]
    assert record["aliased_share"] > 0.1 and record["beat_aliased_share"] == 0.0
    assert main(["reconstruct", str(tmp_path / "data300"), "-o", str(tmp_path / "result300"), *tiny]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "even the slowest beat between its bands" in error and "--allow-aliased" in error
    assert not (tmp_path / "result300").exists()


def test_the_colour_mosaic_puts_each_pixel_under_one_polariser_and_one_filter():
    shape = (8, 12)
    cover = np.zeros(shape, dtype=int)
    for analyser in (a for row in MOSAIC for a in row):
        for colour in {c for row in BAYER for c in row}:
            cover += mosaic_mask(analyser, shape, colour)
    assert (cover == 1).all()
    assert mosaic_mask(0, shape, "red").sum() == shape[0] * shape[1] // 16
    assert mosaic_mask(0, shape, "green").sum() == shape[0] * shape[1] // 8
    assert bayer_sites(narrow_bands([450.0, 532.0, 650.0])) == {"450": "blue", "532": "green", "650": "red"}
    with pytest.raises(ValueError, match="cannot sit under them"):
        bayer_sites(narrow_bands([450.0, 650.0]))
    with pytest.raises(ValueError, match="cannot sit under them"):
        SimulationSettings(bands=narrow_bands([450.0, 650.0]), camera=CameraModel(mosaic=True))


def test_a_colour_mosaic_keeps_a_smooth_image_and_its_own_pixels():
    """Through the mosaic and back, each band's image keeps the values at its own sites exactly and a linear ramp
    everywhere inside (bilinear interpolation of every 4th pixel)."""
    rows, columns = np.mgrid[0:32, 0:32]
    ramp = (0.01 * rows + 0.02 * columns).astype(np.float64)
    names = [f"{band}.{m}" for band in ("red", "green", "blue") for m in MEASUREMENTS]
    captured = CameraModel(mosaic=True).capture({n: ramp for n in names}, 0, camera_bands())
    for name in names:
        np.testing.assert_allclose(captured[name][4:-4, 4:-4], ramp[4:-4, 4:-4], atol=1e-5)


def test_a_dataset_of_three_bands_is_written_read_and_resumed(tmp_path):
    settings = SimulationSettings(azimuths=2, elevations=2, res=16, spp=1, bands=camera_bands(),
                                  camera=CameraModel(read_noise=0.01, mosaic=True))
    defines = {"load": 100, "contact_width": 4}
    report = simulate("disk_compression", tmp_path / "data", settings, defines=defines, progress=False)
    assert report.rendered == 4
    dataset = Dataset(tmp_path / "data")
    assert len(dataset.channels) == 48 and dataset.channels[0].startswith("red.pol.")
    assert dataset.bands.names == ("red", "green", "blue")
    assert dataset.channel_bands() == tuple(b for b in range(3) for _ in range(16))
    assert [s.intensity(su2.identity(0.0)) for s in dataset.polariscopes()[:16]] == \
        [s.intensity(su2.identity(0.0)) for s in MEASUREMENTS.values()]
    assert dataset.measurements(0).shape == (16, 16, 48)
    aliasing = json.loads((tmp_path / "data" / "dataset.json").read_text())["fringe_aliasing"]
    assert aliasing["beat"]["of"] == aliasing["of"] and aliasing["beat"]["densest"] < aliasing["densest"]
    again = simulate("disk_compression", tmp_path / "data", settings, defines=defines, progress=False)
    assert (again.rendered, again.kept) == (0, 4)
    index = json.loads((tmp_path / "data" / "dataset.json").read_text())
    index["channels"] = index["channels"][:16]
    (tmp_path / "data" / "dataset.json").write_text(json.dumps(index))
    with pytest.raises(ValueError, match=r"must list each of the 48 measurements \(<band>\.pol"):
        Dataset(tmp_path / "data")


def test_a_band_s_intensity_is_the_weighted_sum_of_its_wavelengths():
    """ChannelModel's incoherent mix (the weights' square roots on the Jones products) against the plain weighted
    sum of each wavelength's intensities."""
    rng = np.random.default_rng(4)
    bands = camera_bands(step=20.0)
    lanes = []
    for _ in bands.wavelengths:
        q = rng.normal(size=(4, 50))
        lanes.append(su2.Quaternion(tuple(mi.Float(x) for x in (q / np.linalg.norm(q, axis=0)).astype(np.float32))))
    scopes = tuple(MEASUREMENTS.values()) * 3
    model = ChannelModel(scopes, bands, [b for b in range(3) for _ in range(16)], View(lanes=(("a", 1.0),)))
    for channel, value in enumerate(model.intensities(lanes)):
        band = channel // 16
        expected = sum(w * np.array(scopes[channel].intensity(q)) for w, q in zip(bands.weights[band], lanes))
        np.testing.assert_allclose(np.array(value), expected, atol=2e-6)


def test_a_reconstruction_from_bands_runs_and_refuses_what_cannot_fit_them(tmp_path):
    """Along straight rays and through refracting surfaces (each wavelength's general Jones matrix along the one
    bent path); the Two-step, which unwraps one wavelength, is refused."""
    settings = SimulationSettings(azimuths=3, elevations=2, res=16, spp=1, bands=narrow_bands([450.0, 650.0]))
    simulate("disk_compression", tmp_path / "data", settings, defines={"load": 100, "contact_width": 4},
             progress=False)
    result = mi_nest.optimize("disk_compression", tmp_path / "data", iterations=30, progress=False, resolution=8,
                              output=tmp_path / "result")
    assert np.isfinite(result.metrics["deviatoric_error"]) and np.isfinite(result.metrics["test_psnr"])
    # Its held-out views are rendered in the dataset's bands, and its test view names their channels.
    from mi_nest.reconstruct.outputs import write_test_view
    from mi_nest.views import open_source
    from mi_nest.views.novel import held_out_views
    (rotation, captured, rendered, psnr), = held_out_views(open_source(tmp_path / "result"), count=1)
    assert captured.shape == rendered.shape == (16, 16) and psnr == pytest.approx(result.metrics["test_psnr"], abs=3)
    write_test_view(mi_nest.load_scene("disk_compression", load=100, contact_width=4, res=16), result,
                    tmp_path / "result", Dataset(tmp_path / "data"))
    from mi_nest.io.exr import read_channels
    assert {"reconstructed.650.pol.45.0.135", "measured.450.pol.45.0.0"} <= set(
        read_channels(tmp_path / "result" / "test_view.exr"))
    with pytest.raises(ValueError, match="the Two-step unwraps one wavelength"):
        mi_nest.optimize("disk_compression", tmp_path / "data", iterations=2, progress=False, method="two-step")
    simulate("disk_compression", tmp_path / "refracting", settings,
             defines={"load": 100, "contact_width": 4, "ior": 1.5}, progress=False)
    bent = mi_nest.optimize("disk_compression", tmp_path / "refracting", iterations=30, progress=False, resolution=8)
    assert np.isfinite(bent.metrics["deviatoric_error"]) and bent.metrics["deviatoric_error"] < 1.0


def test_the_command_simulates_bands_and_refuses_bad_ones_in_one_line(tmp_path, capsys):
    from mi_nest.cli import main
    arguments = ["simulate", "disk_compression", "--azimuth", "2", "--elevation", "1", "--res", "8"]
    assert main([*arguments, "-o", str(tmp_path / "ok"), "--bands", "450,650"]) == 0
    assert Dataset(tmp_path / "ok").bands.names == ("450", "650")
    assert main(["show", str(tmp_path / "ok"), "-o", str(tmp_path / "sheet.png")]) == 0     # the first band's
    assert (tmp_path / "sheet.png").is_file()
    for bands, message in (("650,450", "must increase"), ("-5", "positive numbers of nm"),
                           ("blue", "bands must be 'rgb'"), ("450,650 --mosaic", "cannot sit under them")):
        capsys.readouterr()
        extra = ["--mosaic"] if "--mosaic" in bands else []
        code = main([*arguments, "-o", str(tmp_path / "refused"), "--bands", bands.split()[0], *extra])
        err = capsys.readouterr().err
        assert code == 2 and message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
        assert not (tmp_path / "refused" / "dataset.json").exists()


def test_the_scene_names_its_light_and_its_camera_s_bands(tmp_path, capsys):
    """``spectrum`` on the light panel and ``bands`` on the camera (the shipped scenes' $spectrum and $bands):
    ``mi-nest render`` then renders what ``--white-light`` or ``render_bands`` render, ``mi-nest simulate`` records
    the camera's bands as ``--bands`` does, and ``--wavelength`` goes back to one wavelength."""
    from mi_nest.cli import main
    from mi_nest.io.exr import read_channels
    from mi_nest.render import scene_bands, scene_light
    small = ["-D", "res=12", "-D", "load=300", "--spp", "1"]
    assert main(["render", "disk_compression", *small, "-D", "spectrum=white_led", "-o", str(tmp_path / "w.exr")]) == 0
    assert main(["render", "disk_compression", *small, "--white-light", "-o", str(tmp_path / "flag.exr")]) == 0
    scene_white, flag = read_channels(tmp_path / "w.exr"), read_channels(tmp_path / "flag.exr")
    for channel in ("R", "G", "B"):
        np.testing.assert_array_equal(scene_white[channel], flag[channel])
    assert main(["render", "disk_compression", *small, "-D", "spectrum=white_led", "--wavelength", "532",
                 "-o", str(tmp_path / "mono.exr")]) == 0
    assert "R" not in read_channels(tmp_path / "mono.exr")

    assert main(["render", "disk_compression", *small, "-D", "bands=450,650", "-o", str(tmp_path / "b.exr")]) == 0
    loaded = mi_nest.load_scene("disk_compression", res=12, spp=1, load=300, bands="450,650")
    assert scene_light(loaded) is None and scene_bands(loaded).names == ("450", "650")
    expected = render_bands(loaded, narrow_bands([450.0, 650.0])).channels
    banded = read_channels(tmp_path / "b.exr")
    for channel in ("450", "650.pol.45.0.45"):
        np.testing.assert_allclose(banded[channel], expected[channel], atol=1e-6)

    arguments = ["simulate", "disk_compression", "--azimuth", "2", "--elevation", "1", "--res", "8"]
    assert main([*arguments, "-D", "bands=450,650", "-o", str(tmp_path / "scene_bands")]) == 0
    assert main([*arguments, "--bands", "450,650", "-o", str(tmp_path / "option_bands")]) == 0
    ours, theirs = Dataset(tmp_path / "scene_bands"), Dataset(tmp_path / "option_bands")
    assert ours.bands.names == theirs.bands.names == ("450", "650") and ours.channels == theirs.channels
    np.testing.assert_array_equal(ours.measurements(0), theirs.measurements(0))
    capsys.readouterr()
    assert main([*arguments, "-D", "spectrum=white_led", "-o", str(tmp_path / "refused")]) == 2
    err = capsys.readouterr().err
    assert "the camera has no bands" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "refused" / "dataset.json").exists()


def test_a_light_s_spectrum_from_a_file_sets_what_the_camera_s_bands_weigh(tmp_path):
    """A panel's spectral power from a CSV (a spectrometer's 1 nm rows, sampled every 10 nm): an RGB camera's
    bands under a light rising towards the red weigh the long wavelengths more than under the white LED; the file
    is one of the scene's inputs (an output may not overwrite it); bad spectra are refused naming the property."""
    from mi_nest.physics.colour import read_spectrum
    from mi_nest.render import scene_bands, scene_light
    from mi_nest.scene import SceneError, scene_inputs
    rows = "\n".join(f"{w},{0.2 + (w - 400) / 300}" for w in range(400, 701))
    path = tmp_path / "red_lamp.csv"
    path.write_text("# a lamp rising towards the red\nwavelength,power\n" + rows + "\n")
    light = read_spectrum(path)
    np.testing.assert_array_equal(light.wavelengths, np.arange(400.0, 701.0, 10.0))
    loaded = mi_nest.load_scene("disk_compression", res=4, spp=1, spectrum=str(path), bands="rgb")
    assert scene_light(loaded).name == "red_lamp.csv"
    under_lamp, under_led = scene_bands(loaded), camera_bands()
    centres = [bands.weights @ bands.wavelengths for bands in (under_lamp, under_led)]
    # Every band's centre moves towards the red: red and blue by 6 to 8 nm, green by 1.
    assert np.all(centres[0] > centres[1]) and np.all((centres[0] - centres[1])[[0, 2]] > 5.0)
    assert path.resolve() in scene_inputs("disk_compression", spectrum=str(path))
    (tmp_path / "unsorted.csv").write_text("wavelength,power\n500,1\n450,1\n600,1\n")
    (tmp_path / "two.csv").write_text("wavelength,a,b\n450,1,1\n500,1,1\n600,1,1\n")
    for spectrum, message in (("sunlight", "'white_led' or a CSV file"),
                              (str(tmp_path / "unsorted.csv"), "must increase"),
                              (str(tmp_path / "two.csv"), "one column of power"),
                              (str(tmp_path / "missing.csv"), "cannot read the spectrum file")):
        with pytest.raises(SceneError, match=f"polariscope_light: 'spectrum': .*{message}"):
            mi_nest.load_scene("disk_compression", res=4, spp=1, spectrum=spectrum)
    with pytest.raises(SceneError, match="polariscope: 'bands': .*must increase"):
        mi_nest.load_scene("disk_compression", res=4, spp=1, bands="650,450")
