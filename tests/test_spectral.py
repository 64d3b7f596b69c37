"""A spectral march (mi_nest/tracer/spectral.py): several wavelengths marched at once, one stress lookup per step
for all, against one monochromatic march per wavelength; its refusals and the white-light renders that use it.
Gradients through it: tests/test_gradients.py."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mi_nest
from mi_nest.render import View, jones_at_wavelengths, phase_scale, render_white_light
from mi_nest.physics import MEASUREMENTS, jones
from mi_nest.physics.colour import white_led
from mi_nest.tracer import LaneChannels, PathKind, Tracer, TracerConfig
from mi_nest.tracer.film import CHANNELS, JONES_CHANNELS
from mi_nest.tracer.setup import SceneSetup
from scenes import box, medium, scene

WAVELENGTHS = (450.0, 532.0, 650.0)


def _lanes(loaded, wavelengths=WAVELENGTHS):
    return tuple((f"I.{w:g}", phase_scale(loaded, 1.0, w)) for w in wavelengths)


@pytest.mark.parametrize("method", ["product", "magnus4", "linear"])
def test_each_lane_of_a_spectral_render_is_the_monochromatic_render_at_its_wavelength(method):
    """The stacked disks (axes turning 45 degrees along each ray) at 300 N: several fringes, so a lane at the
    wrong scale would be far off."""
    loaded = mi_nest.load_scene("stacked_disks", res=24, spp=1)
    loaded.integrator().configure(method=method, step_size=0.25)
    lanes = _lanes(loaded)
    spectral = mi_nest.render(loaded, view=View(lanes=lanes)).channels
    for name, scale in lanes:
        alone = mi_nest.render(loaded, view=View(phase_scale=scale)).channels
        np.testing.assert_allclose(spectral[name], alone["Y"], atol=5e-4)
        assert np.abs(alone["Y"] - mi_nest.render(loaded).channels["Y"]).max() > 0.05 or scale == 1.0
    # The film's own channels are the first wavelength's (its fringe order feeds the aliasing guard).
    first = mi_nest.render(loaded, view=View(phase_scale=lanes[0][1])).channels
    for channel in ("Y", "fringe.order", next(iter(MEASUREMENTS)), "jones.b", "path.length"):
        np.testing.assert_allclose(spectral[channel], first[channel], atol=5e-4)


def test_a_spectral_ray_batch_holds_each_wavelength_s_jones_product():
    loaded = mi_nest.load_scene("stacked_disks", res=8, spp=1)
    tracer = Tracer(TracerConfig(method="magnus4", step_size=0.25))
    sensor = loaded.sensors()[0]
    rays, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(np.random.default_rng(1).uniform(0.2, 0.8, (2, 200))),
                                mi.Point2f(0.5))
    right = sensor.world_transform() @ mi.Vector3f(-1, 0, 0)
    lanes = _lanes(loaded)
    traced = tracer.trace_rays(loaded, rays, right, view=View(lanes=lanes))
    assert traced.kind is PathKind.SPECTRAL and len(traced.state) == 4 * len(lanes)
    for (_, scale), lane in zip(lanes, traced.jones()):
        alone = tracer.trace_rays(loaded, rays, right, view=View(phase_scale=scale)).jones()
        np.testing.assert_allclose(np.array(lane), np.array(alone), atol=2e-5)


def test_each_lane_gives_its_jones_product_for_a_polariscope_as_built():
    """``LaneChannels.JONES``: each wavelength's Jones product, what the rig's twin applies its own optics to; equal
    to the monochromatic render's at that wavelength, and to what ``jones_at_wavelengths`` returns."""
    loaded = mi_nest.load_scene("stacked_disks", res=16, spp=1)
    lanes = _lanes(loaded)
    spectral = mi_nest.render(loaded, view=View(lanes=lanes, lane_outputs=LaneChannels.JONES)).channels
    assert f"{lanes[0][0]}.jones.d" in spectral and f"{lanes[0][0]}.pol.0.0.0" not in spectral
    listed = jones_at_wavelengths(loaded, WAVELENGTHS)
    for (name, scale), product in zip(lanes, listed):
        alone = mi_nest.render(loaded, view=View(phase_scale=scale)).channels
        for k, channel in enumerate(JONES_CHANNELS):
            np.testing.assert_allclose(spectral[f"{name}.{channel}"], alone[channel], atol=5e-4)
            np.testing.assert_array_equal(product[k], spectral[f"{name}.{channel}"])
    assert np.abs(listed[0][1] - listed[2][1]).max() > 0.1      # the wavelengths differ


def test_a_white_light_render_takes_one_march_per_sixteen_wavelengths(monkeypatch):
    """41 wavelengths in three marches of 14 (the last padded), the colours those of one render per wavelength."""
    import importlib
    rendering = importlib.import_module("mi_nest.render")
    loaded = mi_nest.load_scene("disk_compression", res=16, spp=1, load=300)
    light = white_led(step=10.0)
    calls = []
    real = rendering.render
    monkeypatch.setattr(rendering, "render", lambda *a, **k: calls.append(len(k["view"].lanes)) or real(*a, **k))
    spectral = render_white_light(loaded, light)
    assert calls == [14, 14, 14]
    monkeypatch.setattr(rendering, "render", real)

    def one_at_a_time(wavelengths):
        result = real(loaded, view=View(phase_scale=phase_scale(loaded, 1.0, wavelengths[0])))
        return [{"Y": result.main}], result
    reference = rendering.in_white_light(rendering.WavelengthRenders(one_at_a_time), light)
    for channel in ("R", "G", "B", "Y", "I.380", "I.600", "I.780"):
        np.testing.assert_allclose(spectral.channels[channel], reference.channels[channel], atol=5e-4)


def test_auto_chooses_its_steps_for_the_shortest_wavelength():
    loaded = mi_nest.load_scene("twisted_block", res=16, spp=1)
    tracer = Tracer(TracerConfig(method="auto"))
    sensor = loaded.sensors()[0]
    own = tracer.decide(loaded, sensor)
    doubled = tracer.decide(loaded, sensor, view=View(phase_scale=2.0))
    spectral = tracer.decide(loaded, sensor, view=View(lanes=(("long", 1.0), ("short", 2.0))))
    assert spectral.step_size == doubled.step_size < own.step_size
    assert spectral.method.lanes == 2 and spectral.method.name == "magnus4"


def test_rk4_marches_one_wavelength_at_a_time():
    loaded = mi_nest.load_scene("disk_compression", res=4, spp=1)
    loaded.integrator().configure(method="rk4")
    with pytest.raises(ValueError, match="'rk4' marches one wavelength at a time; .* use 'product'"):
        mi_nest.render(loaded, view=View(lanes=_lanes(loaded)))
    assert not loaded.integrator().tracer.has_spectral_march()
    result = render_white_light(loaded, white_led(step=50.0))      # one render per wavelength instead
    assert np.isfinite(result.channels["R"]).all()


@pytest.mark.parametrize("bounces", [0, 2])
def test_a_spectral_render_follows_refracted_paths_at_every_wavelength(bounces):
    """The disk at n = 1.55 in air, seen obliquely (rays bend at its faces, Fresnel transmission and, with
    bounces, sampled ghost paths): each lane is the monochromatic render at its wavelength, its 16 measurements
    and Jones product included, and each lane of a ray batch the monochromatic batch's general Jones matrix."""
    from mi_nest.dataset.schedule import Rotation, camera_to_world
    from mi_nest.scene import pose, reference_pose
    loaded = mi_nest.load_scene("disk_compression", res=24, spp=1, ior=1.55, load=300, contact_width=4)
    loaded.integrator().configure(max_bounces=bounces)
    pose(loaded, camera_to_world(reference_pose(loaded), Rotation(0, 35.0, 20.0, "train"), [0.0, 0.0, 0.0]))
    assert SceneSetup(loaded, loaded.sensors()[0], marching=False).refracting
    lanes = _lanes(loaded)
    for outputs in (LaneChannels.MEASUREMENTS, LaneChannels.JONES):
        spectral = mi_nest.render(loaded, view=View(lanes=lanes, lane_outputs=outputs)).channels
        for name, scale in lanes:
            alone = mi_nest.render(loaded, view=View(phase_scale=scale)).channels
            np.testing.assert_allclose(spectral[name], alone["Y"], atol=5e-4)
            for channel in outputs.value:
                np.testing.assert_allclose(spectral[f"{name}.{channel}"], alone[channel], atol=5e-4, err_msg=channel)
    first, last = spectral[f"{lanes[0][0]}"], spectral[f"{lanes[-1][0]}"]
    assert np.abs(first - last).max() > 0.1 and np.ptp(spectral["path.length"]) > 1.0
    sensor = loaded.sensors()[0]
    rays, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(np.random.default_rng(2).uniform(0.2, 0.8, (2, 300))),
                                mi.Point2f(0.5))
    right = sensor.world_transform() @ mi.Vector3f(-1, 0, 0)
    tracer = loaded.integrator().tracer
    traced = tracer.trace_rays(loaded, rays, right, seed=3, view=View(lanes=lanes))
    assert traced.kind is (PathKind.GHOSTED if bounces else PathKind.REFRACTED) and traced.lanes == 3
    for (_, scale), lane in zip(lanes, traced.jones()):
        alone = tracer.trace_rays(loaded, rays, right, seed=3, view=View(phase_scale=scale)).jones()
        np.testing.assert_allclose(_numbers(lane), _numbers(alone), atol=2e-5)


def _numbers(matrix) -> np.ndarray:
    """A general Jones matrix, or incoherent paths' matrices, as one array."""
    return np.concatenate([_numbers(path) for path in matrix]) if isinstance(matrix, jones.Incoherent) else \
        np.array([x for part in matrix for x in part])


@pytest.mark.parametrize("lanes, message", [
    ((("a", 1.0), ("a", 1.2)), "must be distinct"),
    ((("path.length", 1.0),), "not the integrator's own channels"),
    ((("a", 0.0),), "must be positive numbers"),
    ((("a", float("nan")),), "must be positive numbers"),
])
def test_a_bad_spectral_view_is_refused(lanes, message):
    assert "path.length" in CHANNELS
    with pytest.raises(ValueError, match=message):
        View(lanes=lanes)


def test_one_lane_shares_its_lookups_between_the_lanes():
    """The kernel of three lanes looks the field up as often as the kernel of one: its texture reads (gathers
    of a grid field) do not grow with the lanes."""
    from mi_nest.fields.grid import GridField
    from mi_nest.io.grid import StressGrid
    loaded = scene([box((4, 4, 4), interior=medium(xx=1.0))], res=4)
    grid = GridField(StressGrid(np.random.default_rng(0).normal(size=(4, 4, 4, 6)).astype(np.float32),
                                np.full(3, -2.0), np.full(3, 2.0)))
    tracer = Tracer(TracerConfig(method="product", step_size=0.5))
    rays = mi.Ray3f(mi.Point3f(0.1, 0.2, 10.0), mi.Vector3f(0, 0, -1))

    def gathers(view):
        with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
            dr.kernel_history_clear()
            tracer.trace_rays(loaded, rays, mi.Vector3f(1, 0, 0), field=grid, view=view)
            history = dr.kernel_history()
        sources = [entry["ir"].getvalue() for entry in history if "ir" in entry]
        return max(source.count("gather") for source in sources)

    one, three = gathers(View()), gathers(View(lanes=(("a", 0.8), ("b", 1.0), ("c", 1.2))))
    assert one > 0 and three == one


def test_a_white_light_slice_marches_its_wavelengths_together():
    """A slice in white light (one spectral march per 16 wavelengths) against the same slice one wavelength at a
    time; slices march straight chords, so a refracting scene's slice marches them together too."""
    import importlib
    from mi_nest.render import WavelengthRenders, in_white_light
    from mi_nest.views import Plane, SliceSpec
    from mi_nest.views.slicing import Slicer
    slicing = importlib.import_module("mi_nest.views.slicing")
    light = white_led(step=20.0)
    for defines in ({"load": 300}, {"load": 300, "ior": 1.5}):
        loaded = mi_nest.load_scene("disk_compression", **defines)
        slicer = Slicer(loaded)
        spec = SliceSpec(Plane((0, 0, 1), 0.0), 2.0, resolution=24)
        together = slicing.slice_render_white_light(loaded, spec, light=light)

        def one_at_a_time(wavelengths):
            result = slicer.render(slicing.replace(spec, wavelength=wavelengths[0]))
            return [{"Y": result.main}], result
        reference = in_white_light(WavelengthRenders(one_at_a_time), light)
        for channel in ("R", "G", "B", "I.400", "I.700"):
            np.testing.assert_allclose(together.channels[channel], reference.channels[channel], atol=5e-4)
