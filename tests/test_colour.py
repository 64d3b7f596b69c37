"""White light through a retarder: the interference colours (issue 37), against closed forms and the textbook
sequence of a Michel-Levy chart."""
import numpy as np
import pytest

from mi_nest.physics.colour import (Spectrum, interference_colours, monochromatic, plane_polariscope_transmission,
                                    tristimulus, white_led, white_point)

RETARDATIONS = np.linspace(0.0, 2000.0, 401)


def _lab(retardation, light):
    import colour
    xyz = tristimulus(plane_polariscope_transmission(retardation, light.wavelengths), light)
    return colour.XYZ_to_Lab(xyz, illuminant=white_point(light))


@pytest.mark.parametrize("light", [white_led(), monochromatic(589.0)], ids=["white LED", "sodium line"])
def test_the_dark_and_light_fields_are_complementary_and_add_up_to_the_light(light):
    """Each wavelength passes with sin^2 in one field and cos^2 in the other: their colours sum to the light."""
    dark, bright = (tristimulus(plane_polariscope_transmission(RETARDATIONS, light.wavelengths, field), light)
                    for field in ("dark", "light"))
    np.testing.assert_allclose(dark + bright, np.broadcast_to(tristimulus(np.ones(len(light.wavelengths)), light),
                                                             dark.shape), atol=1e-12)
    assert tristimulus(np.ones(len(light.wavelengths)), light)[1] == pytest.approx(1.0)
    np.testing.assert_allclose(interference_colours(0.0, light, "dark"), 0.0, atol=1e-12)
    np.testing.assert_allclose(interference_colours(0.0, light, "light"), 1.0, atol=1e-4)    # white-balanced


def test_one_line_gives_the_monochromatic_fringes():
    """In monochromatic light the luminance is the render's own intensity, ``sin^2(pi R / lambda)``."""
    light = monochromatic(532.0)
    luminance = tristimulus(plane_polariscope_transmission(RETARDATIONS, light.wavelengths), light)[:, 1]
    np.testing.assert_allclose(luminance, np.sin(np.pi * RETARDATIONS / 532.0) ** 2, atol=1e-12)


@pytest.mark.parametrize("retardation, name, lightness, hue", [
    (100.0, "first-order grey", (40, 75), None),
    (250.0, "first-order white", (90, 101), None),
    (400.0, "first-order yellow", (70, 95), (60, 100)),
    (560.0, "first-order red (the sensitive tint)", (15, 40), (280, 340)),
    (650.0, "second-order blue", (45, 70), (235, 275)),
    (800.0, "second-order green", (85, 100), (100, 160)),
    (900.0, "second-order yellow", (85, 100), (75, 100)),
])
def test_a_white_led_gives_the_textbook_interference_colours(retardation, name, lightness, hue):
    """The Michel-Levy sequence (e.g. Hecht, Optics, section 8.11; Dally and Riley, chapter on photoelasticity):
    CIELAB lightness and hue angle of each named colour within the stated ranges; grey and white without hue
    (chroma under 20)."""
    L, a, b = _lab(retardation, white_led())
    assert lightness[0] <= L <= lightness[1], (name, L)
    chroma, angle = np.hypot(a, b), np.degrees(np.arctan2(b, a)) % 360
    if hue is None:
        assert chroma < 20, (name, chroma)
    else:
        assert chroma > 30 and hue[0] <= angle <= hue[1], (name, chroma, angle)


def test_the_sensitive_tint_is_where_the_eye_sees_least_light():
    """The first-order red is the luminance minimum of the first order, where the retardation cancels the
    wavelengths the eye sees best (photopic peak 555 nm): textbooks put it at 530 to 575 nm."""
    retardation = np.arange(300.0, 800.0)
    luminance = tristimulus(plane_polariscope_transmission(retardation, white_led().wavelengths), white_led())[:, 1]
    assert 530 <= retardation[np.argmin(luminance)] <= 575 and luminance.min() < 0.06


@pytest.mark.parametrize("wavelengths, power, message", [
    ([], [], "at least one wavelength"),
    ([600.0, 500.0], [1.0, 1.0], "must increase"),
    ([500.0, 500.0], [1.0, 1.0], "must increase"),
    ([-500.0], [1.0], "positive numbers of nm"),
    ([500.0, 600.0], [0.0, 0.0], "not zero everywhere"),
    ([500.0, 600.0], [1.0, np.nan], "must be finite")])
def test_a_spectrum_that_is_not_a_light_is_refused(wavelengths, power, message):
    with pytest.raises(ValueError, match=message):
        Spectrum(np.array(wavelengths), np.array(power))
    with pytest.raises(ValueError, match="no power the eye sees"):
        tristimulus(np.ones(1), Spectrum(np.array([1500.0]), np.array([1.0])))


def test_the_chart_shows_the_colours_it_computes(tmp_path):
    import imageio.v3 as iio
    from mi_nest.views.plots import write_michel_levy_chart
    path = write_michel_levy_chart(tmp_path / "chart.png", max_retardation=1800.0)
    image = iio.imread(path)[..., :3].astype(float) / 255
    # The dark-field strip's row through its middle: its colours run as computed, left to right.
    expected = interference_colours(np.array([400.0, 560.0, 650.0]))
    rows = np.flatnonzero(np.abs(image - expected[0]).sum(axis=-1).min(axis=1) < 0.06)
    assert len(rows) > 0
    row = image[rows[len(rows) // 2]]
    found = [int(np.argmin(np.abs(row - colour).sum(axis=-1))) for colour in expected]
    assert found == sorted(found) and all(np.abs(row[i] - c).sum() < 0.1 for i, c in zip(found, expected))


def test_a_slab_in_white_light_renders_its_interference_colour():
    """A uniform slab of retardation R = C t (sigma_1 - sigma_2) (Brewster x mm x MPa = nm) at 45 degrees between
    crossed polarisers, and in the circular dark field, renders the closed-form colour of that R."""
    from mi_nest.physics.polariscope import polariscope_setting
    from mi_nest.render import render_white_light
    from scenes import box, medium, scene
    loaded = scene([box((20, 20, 4), interior=medium(xx=3.0))], res=2)        # C = 50 Brewster, 4 mm: 600 nm
    light = white_led(step=10.0)
    expected = interference_colours(50.0 * 4.0 * 3.0, light)
    for scope in (polariscope_setting("linear", "dark", 45.0), polariscope_setting("circular", "dark")):
        result = render_white_light(loaded, light, polariscope=scope)
        rendered = np.stack([result.channels[c] for c in "RGB"], axis=-1)
        np.testing.assert_allclose(rendered, np.broadcast_to(expected, rendered.shape), atol=2e-4)
    assert expected[2] > 0.8 > 0.4 > expected[1]          # second-order blue
    assert len([name for name in result.channels if name.startswith("I.")]) == len(light.wavelengths)


def test_one_line_of_white_light_is_the_monochromatic_render_bit_for_bit():
    import mi_nest
    from mi_nest.render import render_white_light
    loaded = mi_nest.load_scene("disk_compression", res=16, spp=1, load=300)
    own = mi_nest.render(loaded).main
    line = render_white_light(loaded, monochromatic(532.0)).channels["I.532"]
    assert np.array_equal(line, own)


def test_the_command_renders_white_light_in_colour(tmp_path, capsys):
    import imageio.v3 as iio
    from mi_nest.cli import main
    from mi_nest.io.exr import read_channels
    arguments = ["render", "disk_compression", "-D", "res=24", "-D", "load=300", "--white-light", "--quiet"]
    assert main([*arguments, "-o", str(tmp_path / "disk.exr"), "--png", str(tmp_path / "disk.png")]) == 0
    channels = read_channels(tmp_path / "disk.exr")
    assert {"R", "G", "B", "Y", "I.380", "I.780"} <= set(channels)
    image = iio.imread(tmp_path / "disk.png")
    assert image.shape[-1] >= 3 and np.ptp(image[..., 0].astype(int) - image[..., 2].astype(int)) > 50  # colours
    capsys.readouterr()
    assert main([*arguments, "--wavelength", "600", "-o", str(tmp_path / "refused.exr")]) == 2
    err = capsys.readouterr().err
    assert "leave out the wavelength" in err and "Traceback" not in err and not (tmp_path / "refused.exr").exists()


def test_a_slice_in_white_light_shows_the_colour_of_its_slab(tmp_path, capsys):
    """A slab 4 mm thick cut from a uniformly stressed block (C = 50 Brewster, 3 MPa: 600 nm of retardation in
    it) shows that retardation's interference colour in the circular dark field; the command writes it."""
    from mi_nest.cli import main
    from mi_nest.views import Plane, SliceSpec, slice_render_white_light
    from scenes import box, medium, scene
    block = scene([box((20, 20, 20), interior=medium(xx=3.0))], res=2)
    light = white_led(step=10.0)
    result = slice_render_white_light(block, SliceSpec(Plane((0, 0, 1), 0.0), 4.0, resolution=8), light=light)
    inside = result.channels["Y"] > 0.01         # the slab (the dark field is black outside the part)
    rendered = np.stack([result.channels[c] for c in "RGB"], axis=-1)[inside]
    np.testing.assert_allclose(rendered, np.broadcast_to(interference_colours(600.0, light), rendered.shape),
                               atol=2e-4)
    arguments = ["slice", "disk_compression", "-D", "load=300", "--plane", "z=0", "--thickness", "2", "--res", "16",
                 "--white-light"]
    assert main([*arguments, "-o", str(tmp_path / "slice.exr"), "--png", str(tmp_path / "slice.png")]) == 0
    assert (tmp_path / "slice.png").is_file()
    capsys.readouterr()
    for extra, message in ((["--wavelength", "600"], "leave out the wavelength"),
                           (["--maps", str(tmp_path / "maps.png")], "leave out --white-light or --maps")):
        assert main([*arguments, *extra, "-o", str(tmp_path / "refused.exr")]) == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "refused.exr").exists() and not (tmp_path / "maps.png").exists()
    # A scene whose panel is white slices in its light unless a wavelength or the maps are asked for.
    from mi_nest.io.exr import read_channels
    plain = [a for a in arguments if a != "--white-light"]
    assert main([*plain, "-D", "spectrum=white_led", "-o", str(tmp_path / "scene.exr")]) == 0
    np.testing.assert_array_equal(read_channels(tmp_path / "scene.exr")["R"],
                                  read_channels(tmp_path / "slice.exr")["R"])
    assert main([*plain, "-D", "spectrum=white_led", "--wavelength", "600", "-o", str(tmp_path / "one.exr")]) == 0
    assert "R" not in read_channels(tmp_path / "one.exr")
