"""Models of the ordered exponential (docs/physics.md section 4): orders, exactness, unitarity, failure."""
import math

import numpy as np
import pytest

from mi_nest.tracer import auto
from mi_nest.tracer.setup import SceneSetup
from mi_nest.physics import MEASUREMENTS, su2
from scenes import BREWSTER, WAVELENGTH, box, medium, render
from test_render import twisted_closed_form

PHASE_RATE = math.pi * BREWSTER / WAVELENGTH
TWIST = dict(amplitude=0.6, rate=9.0, angle=30.0)
DEPTH = 20.0


def jones_error(method, steps, **options):
    field = medium("twisted", origin=[0, 0, -0.5 * DEPTH], **TWIST)
    channels = render([box((30, 30, DEPTH), interior=field)], res=2, step=DEPTH / steps * (1 + 1e-6),
                      method=method, **options)
    expected = twisted_closed_form(TWIST["amplitude"], TWIST["rate"], TWIST["angle"], DEPTH)
    return max(float(np.max(np.abs(channels[f"jones.{c}"] - value))) for c, value in zip("abcd", expected))


@pytest.mark.parametrize("method, options, order, steps", [
    ("product", {"points": "left"}, 1, (16, 32)),
    ("product", {}, 2, (16, 32)),
    ("magnus4", {}, 4, (8, 16)),
    ("rk4", {}, 4, (8, 16)),
])
def test_observed_order_of_convergence_on_the_twisted_field(method, options, order, steps):
    coarse, fine = (jones_error(method, n, **options) for n in steps)
    observed = math.log2(coarse / fine)
    assert abs(observed - order) < 0.35, (coarse, fine, observed)


def test_linear_model_is_exact_when_steps_commute_and_wrong_when_axes_turn():
    uniform = render([box((20, 20, 5), interior=medium(xx=2.0, yy=-0.5, xy=0.7))], res=2, step=5.0,
                     method="linear")
    expected = su2.step(2.5, 1.4, PHASE_RATE * 5.0)
    for c, value in zip("abcd", expected):
        np.testing.assert_allclose(uniform[f"jones.{c}"], value, atol=2e-6)
    assert jones_error("linear", 256) > 0.1      # no rotator term: the twisted field defeats it
    assert jones_error("product", 256) < 1e-3


@pytest.mark.filterwarnings("ignore:photoelastic. rk4 is not unitary")
def test_magnus4_stays_unitary_and_rk4_amplifies_by_its_stability_polynomial():
    thickness, steps = 4.0, 4
    for phase_per_step in (0.5, 2.0, 3.5):                 # RK4 is stable below 2 sqrt(2) = 2.83
        sxx = phase_per_step * steps / (PHASE_RATE * thickness)
        shapes = [box((20, 20, thickness), interior=medium(xx=sxx))]
        rk4 = render(shapes, res=2, step=thickness / steps * (1 + 1e-6), method="rk4")
        magnus = render(shapes, res=2, step=thickness / steps * (1 + 1e-6), method="magnus4")
        x = phase_per_step
        amplification = (1 - x * x / 2 + x ** 4 / 24) ** 2 + (1 - x * x / 6) ** 2 * x * x
        rk4_norm = sum(rk4[f"jones.{c}"] ** 2 for c in "abcd")
        np.testing.assert_allclose(rk4_norm, amplification ** steps, rtol=1e-4)
        np.testing.assert_allclose(sum(magnus[f"jones.{c}"] ** 2 for c in "abcd"), 1.0, atol=1e-5)
    assert amplification ** steps > 10      # past the threshold RK4 blows up


def test_unknown_method_or_points_are_refused():
    with pytest.raises(Exception, match="unknown method 'euler'"):
        render([box((2, 2, 2), interior=medium(xx=1.0))], method="euler")
    with pytest.raises(Exception, match="unknown points 'right'"):
        render([box((2, 2, 2), interior=medium(xx=1.0))], points="right")
    with pytest.raises(Exception, match="'points' applies to method 'product' only"):
        render([box((2, 2, 2), interior=medium(xx=1.0))], method="rk4", points="left")


def test_rk4_warns_when_it_loses_unitarity_and_stays_quiet_when_accurate():
    import warnings
    thickness, steps = 4.0, 4
    for phase_per_step, warns in ((0.3, False), (2.0, True), (3.5, True)):
        sxx = phase_per_step * steps / (PHASE_RATE * thickness)
        shapes = [box((20, 20, thickness), interior=medium(xx=sxx))]
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            render(shapes, res=2, step=thickness / steps * (1 + 1e-6), method="rk4")
        messages = [str(w.message) for w in caught if "rk4 is not unitary" in str(w.message)]
        assert bool(messages) == warns, (phase_per_step, messages)
        if warns:
            assert "2 sqrt(2) = 2.83" in messages[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")     # the unitary methods never warn
        render([box((20, 20, 4), interior=medium(xx=50.0))], res=2, step=1.0, method="magnus4")


def test_float32_products_of_a_hundred_thousand_steps_stay_unitary_and_exact():
    thickness, steps = 50.0, 100_000
    channels = render([box((20, 20, thickness), interior=medium(xx=0.8, xy=-0.3))], res=2,
                      step=thickness / steps * (1 + 1e-6))
    norm = sum(channels[f"jones.{c}"] ** 2 for c in "abcd")
    assert np.max(np.abs(norm - 1.0)) < 1e-5
    expected = su2.step(0.8, -0.6, PHASE_RATE * thickness)
    for c, value in zip("abcd", expected):
        np.testing.assert_allclose(channels[f"jones.{c}"], value, atol=1e-4)



def _auto(shapes, tolerance, **options):
    import mi_nest
    from scenes import scene
    scene_ = scene(shapes, method="auto", tolerance=tolerance, **options)
    channels = mi_nest.render(scene_).channels
    decision = scene_.integrator().decide(scene_)
    return channels, decision.method.name, decision.step_size, decision.reason


def test_auto_picks_the_exact_linear_model_where_steps_commute():
    import mi_nest
    disk_mesh = str(mi_nest.scene_path("disk_compression").parent / "meshes/disk.ply")
    import mitsuba as mi
    disk = {"type": "ply", "filename": disk_mesh, "to_world": mi.ScalarTransform4f().scale([40, 40, 6]),
            "interior": {"type": "stress", "fringe_value": 10.6, "model": "disk_compression", "diameter": 40.0,
                         "thickness": 6.0, "load": 300.0}}
    channels, method, step, reason = _auto([disk], 1e-3, res=16, view=22.0, step=0.1)
    assert method == "linear" and step >= 6.0 and "commute" in reason
    reference = render([disk], res=16, view=22.0, step=0.1, method="product")
    assert max(float(np.max(np.abs(channels[n] - reference[n]))) for n in MEASUREMENTS) < 1e-4


def test_auto_analyses_once_for_all_passes_of_a_render(monkeypatch):
    import mi_nest
    import mitsuba as mi
    from scenes import scene
    analyses = []
    choose = auto.choose
    monkeypatch.setattr(auto, "choose", lambda *args: analyses.append(args) or choose(*args))
    field = medium("twisted", origin=[0, 0, -0.5 * DEPTH], **TWIST)
    scene_ = scene([box((30, 30, DEPTH), interior=field)], res=2, spp=4, method="auto", tolerance=1e-3)
    integrator = scene_.integrator()
    mi_nest.render(scene_, passes=4)
    assert len(analyses) == 1 and integrator.tracer.config.method == "auto"
    mi.render(scene_)   # outside a render's passes every render analyses its scene again
    assert len(analyses) == 2
    decision = integrator.decide(scene_)
    assert len(analyses) == 3 and decision.method.name == "magnus4" and decision.reason


def test_auto_samples_the_generator_the_numpy_projection_gives():
    import mi_nest
    from mi_nest.physics import projection
    scene_ = mi_nest.load_scene("kitten", res=8, spp=1)
    setup = SceneSetup(scene_, scene_.sensors()[0])
    medium_ = setup.media[0]
    u, v = np.array([0.6, 0.8, 0.0]), np.array([-0.48, 0.36, 0.8])
    box_ = scene_.bbox()
    points = np.random.default_rng(3).uniform(np.array(box_.min), np.array(box_.max), (4, 50, 3))
    p, q = auto.generator_field(setup.phase_tensors[0], u, v)(points)
    stress = medium_.sample(points.reshape(-1, 3))
    expected = projection.project(tuple(stress.T), tuple(u), tuple(v))
    scale = medium_.phase_rate * np.abs(stress).max()
    assert p.shape == q.shape == (4, 50) and scale > 0
    for got, want in zip((p, q), expected):
        np.testing.assert_allclose(got.ravel(), medium_.phase_rate * want, atol=1e-6 * scale)


@pytest.mark.parametrize("tolerance", [1e-3, 1e-4])
def test_auto_meets_its_tolerance_where_axes_turn(tolerance):
    field = medium("twisted", origin=[0, 0, -0.5 * DEPTH], **TWIST)
    channels, method, step, reason = _auto([box((30, 30, DEPTH), interior=field)], tolerance, res=2)
    assert method == "magnus4" and "turn" in reason and step < DEPTH
    expected = twisted_closed_form(TWIST["amplitude"], TWIST["rate"], TWIST["angle"], DEPTH)
    errors = [float(np.max(np.abs(channels[n] - scope.intensity(expected)))) for n, scope in MEASUREMENTS.items()]
    assert max(errors) <= tolerance
    # ... and it does not over-refine by much: twice the step would miss the tolerance.
    coarser = jones_error("magnus4", max(1, int(DEPTH / (2 * step))))
    assert coarser > tolerance / 16


def test_auto_never_picks_the_linear_model_for_stacked_disks():
    import mi_nest
    scene_ = mi_nest.load_scene("stacked_disks", res=8, spp=1)
    integrator = scene_.integrator()
    integrator.configure(method="auto")
    mi_nest.render(scene_)
    assert integrator.decide(scene_).method.name == "magnus4"


@pytest.mark.parametrize("method", ["product", "magnus4"])
def test_numpy_chords_march_as_the_render_does(method):
    """The ``auto`` analysis marches NumPy chords with the integrator's own method objects."""
    import mi_nest
    from mi_nest.tracer.registry import method_named
    from scenes import scene
    steps = 8
    field = medium("twisted", origin=[0, 0, -0.5 * DEPTH], **TWIST)
    scene_ = scene([box((30, 30, DEPTH), interior=field)], res=2, step=DEPTH / steps * (1 + 1e-6), method=method)
    channels = mi_nest.render(scene_).channels
    setup = SceneSetup(scene_, scene_.sensors()[0])
    u, v = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])     # image right and up; the light runs along +z
    generator = auto.generator_field(setup.phase_tensors[0], u, v)
    starts = np.array([[0.0, 0.0, 0.5 * DEPTH], [3.0, -2.0, 0.5 * DEPTH]])
    marched = method_named(method).march_chords(
        generator, starts, np.array([0.0, 0.0, -1.0]), np.full(2, DEPTH), DEPTH / steps * (1 + 1e-6))
    for c, value in zip("abcd", marched):
        np.testing.assert_allclose(channels[f"jones.{c}"], value[0], atol=2e-6)
        np.testing.assert_allclose(value[1], value[0], atol=1e-12)
    expected = twisted_closed_form(TWIST["amplitude"], TWIST["rate"], TWIST["angle"], DEPTH)
    assert max(abs(got[0] - want) for got, want in zip(marched, expected)) > 1e-4   # eight steps: not exact
