"""Renders against closed forms: slabs, the twisted field, dark field, the disk, re-entry."""
import math

import mitsuba as mi
import numpy as np
import pytest
import trimesh

import mi_nest
from mi_nest.fields import DiskCompressionField
from mi_nest.tracer.film import CHANNELS
from mi_nest.physics import MEASUREMENTS, su2
from mi_nest.physics.polariscope import rotation
from scenes import BREWSTER, WAVELENGTH, box, medium, render, scene

PHASE_RATE = math.pi * BREWSTER / WAVELENGTH   # rad per (MPa mm)


def retardance(sxx, syy, sxy, length, C=BREWSTER):
    return 2 * math.pi * C * length * math.hypot(sxx - syy, 2 * sxy) / WAVELENGTH


def test_uniform_slab_retardance_and_axis():
    sxx, syy, sxy, thickness = 3.0, -1.0, 1.5, 1.5
    channels = render([box((20, 20, thickness), interior=medium(xx=sxx, yy=syy, zz=7.0, xy=sxy, yz=2.0))])
    expected_delta = retardance(sxx, syy, sxy, thickness)
    expected_theta = 0.5 * math.atan2(2 * sxy, sxx - syy) % math.pi
    assert expected_delta < 2 * math.pi
    np.testing.assert_allclose(channels["char.delta"], expected_delta, atol=1e-4)
    np.testing.assert_allclose(channels["char.theta"], expected_theta, atol=1e-4)
    np.testing.assert_allclose(channels["char.gamma"], 0.0, atol=1e-4)
    np.testing.assert_allclose(channels["path.length"], thickness, rtol=1e-5)


def test_oblique_rays_project_onto_their_own_transverse_plane():
    S = np.array([[2.0, 0.7, -0.4], [0.7, -1.0, 1.2], [-0.4, 1.2, 0.5]])
    thickness = 2.0
    origin = np.array([30.0, -20.0, 80.0])
    k = origin / np.linalg.norm(origin)                       # light travels towards the camera
    right = np.cross(np.array([0.0, 1.0, 0.0]), -k)           # Mitsuba's look_at: image right
    right = -right / np.linalg.norm(right)
    u = right - (right @ k) * k
    u /= np.linalg.norm(u)
    v = np.cross(k, u)
    chord = thickness / k[2]
    p, q = u @ S @ u - v @ S @ v, 2 * u @ S @ v
    expected = su2.step(p, q, PHASE_RATE * chord)
    channels = render([box((40, 40, thickness), interior=medium(
        xx=S[0, 0], yy=S[1, 1], zz=S[2, 2], yz=S[1, 2], zx=S[0, 2], xy=S[0, 1]))],
        origin=tuple(origin), view=1.0, res=3)
    for name, value in zip(("jones.a", "jones.b", "jones.c", "jones.d"), expected):
        np.testing.assert_allclose(channels[name], value, atol=2e-5, err_msg=name)


def twisted_closed_form(amplitude, rate_deg, angle_deg, length, C=BREWSTER):
    """docs/physics.md section 5: J = R(theta_0 + psi) M R(-theta_0)."""
    G = 2 * math.pi * C * amplitude * length / WAVELENGTH
    psi = math.radians(rate_deg) * length
    X = math.hypot(psi, G / 2)
    sx = math.sin(X) / X
    M = np.array([[math.cos(X) - 0.5j * G * sx, psi * sx], [-psi * sx, math.cos(X) + 0.5j * G * sx]])
    theta0 = math.radians(angle_deg)
    return su2.from_matrix(rotation(math.degrees(theta0 + psi)) @ M @ rotation(-math.degrees(theta0)))


@pytest.mark.parametrize("steps", [64, 256])
def test_twisted_field_matches_closed_form_in_all_sixteen_channels(steps):
    amplitude, rate, angle, depth = 0.6, 9.0, 30.0, 20.0
    field = medium("twisted", amplitude=amplitude, rate=rate, angle=angle, origin=[0, 0, -0.5 * depth])
    channels = render([box((30, 30, depth), interior=field)], step=depth / steps)
    expected = twisted_closed_form(amplitude, rate, angle, depth)
    errors = {name: np.max(np.abs(channels[name] - scope.intensity(expected)))
              for name, scope in MEASUREMENTS.items()}
    assert max(errors.values()) <= 1e-3, errors
    # A rotation of ~180 degrees along the ray: the product is far from a plain retarder.
    assert abs(np.mean(channels["char.gamma"])) > 0.1


def test_linear_model_would_fail_on_the_twisted_field():
    """Guards the test above: summing the projected stress first gives a different answer."""
    amplitude, rate, angle, depth = 0.6, 9.0, 30.0, 20.0
    s = np.linspace(0, depth, 4001)
    phi = np.radians(angle + rate * s)
    p_sum = np.trapezoid(amplitude * np.cos(2 * phi), s)
    q_sum = np.trapezoid(amplitude * np.sin(2 * phi), s)
    linear = su2.step(p_sum, q_sum, PHASE_RATE)
    exact = twisted_closed_form(amplitude, rate, angle, depth)
    assert max(abs(s.intensity(linear) - s.intensity(exact)) for s in MEASUREMENTS.values()) > 0.1


@pytest.mark.parametrize("sxx", [0.5, 3.0, 9.0])
def test_dark_field_circular_polariscope_gives_sin_squared(sxx):
    thickness = 5.0
    channels = render([box((20, 20, thickness), interior=medium(xx=sxx, yy=-0.2, xy=0.8))],
                      input_qwp=45.0, output_qwp=135.0, analyzer=0.0)
    delta = retardance(sxx, -0.2, 0.8, thickness)
    np.testing.assert_allclose(channels["Y"], math.sin(delta / 2) ** 2, atol=2e-5)


def test_free_space_between_parallel_polarisers_is_one():
    specimen = box((2, 2, 2), center=(40, 0, 0), interior=medium(xx=5.0))
    channels = render([specimen], analyzer=90.0)
    np.testing.assert_allclose(channels["Y"], 1.0, atol=1e-6)
    np.testing.assert_allclose(channels["pol.90.0.90"], 1.0, atol=1e-6)
    np.testing.assert_allclose(channels["jones.a"], 1.0, atol=1e-6)


def _pixel_centres(res, view):
    coords = -view + (np.arange(res) + 0.5) * 2 * view / res
    return np.meshgrid(coords, coords[::-1])      # image rows run top (+y) to bottom


def test_disk_centre_fringe_order_and_whole_field():
    diameter, thickness, load, fringe_value = 40.0, 6.0, 80.0, 10.6
    res, view = 41, 22.0
    centre_order = 8 * load / (math.pi * diameter * fringe_value)
    assert centre_order < 1   # unwrapped: char.delta is the retardance itself
    disk = mi.load_dict({
        "type": "ply", "filename": str(mi_nest.scene_path("disk_compression").parent / "meshes/disk.ply"),
        "to_world": mi.ScalarTransform4f().scale([diameter, diameter, thickness]),
        "interior": {"type": "stress", "fringe_value": fringe_value, "model": "disk_compression",
                     "diameter": diameter, "thickness": thickness, "load": load}})
    channels = render([disk], res=res, view=view, step=2.0, input_qwp=45.0, output_qwp=135.0)
    centre = res // 2
    measured_order = channels["char.delta"][centre, centre] / (2 * math.pi)
    assert measured_order == pytest.approx(centre_order, rel=0.02)

    x, y = _pixel_centres(res, view)
    field = DiskCompressionField(diameter=diameter, thickness=thickness, load=load)
    s_x, s_y, t_xy = field.plane_stress(x, y)
    delta = 2 * math.pi * thickness * np.hypot(s_x - s_y, 2 * t_xy) / fringe_value
    r = np.hypot(x, y)
    # Away from the faceted rim and the singular load points.
    interior = (r < 0.45 * diameter) & (np.hypot(x, np.abs(y) - diameter / 2) > 6.0)
    np.testing.assert_allclose(channels["Y"][interior], np.sin(delta[interior] / 2) ** 2, atol=2e-4)
    assert np.all(channels["Y"][r > 0.55 * diameter] < 1e-6)   # crossed polarisers, free space


def test_rays_entering_twice_and_disjoint_specimens(tmp_path):
    # A tube seen from the side: rays through the bore cross the wall twice.
    tube = trimesh.creation.annulus(r_min=6.0, r_max=10.0, height=30.0, sections=256)
    path = str(tmp_path / "tube.ply")
    tube.export(path)
    sxx = 0.4
    tube_shape = {"type": "ply", "filename": path,
                  "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], 90),
                  "interior": medium(xx=sxx)}
    second = box((30, 4, 2), center=(0, 0, -20), interior=medium(xy=0.3))  # behind the tube
    res, view = 21, 12.0
    channels = render([tube_shape, second], res=res, view=view, step=0.5)
    # Independent chord lengths from trimesh's ray caster on the same (rotated) mesh.
    tube.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [1, 0, 0]))
    x, y = _pixel_centres(res, view)
    origins = np.stack([x.ravel(), y.ravel(), np.full(x.size, 50.0)], axis=1)
    directions = np.tile([0.0, 0.0, -1.0], (x.size, 1))
    locations, ray_index, _ = tube.ray.intersects_location(origins, directions)
    chords = np.zeros(x.size)
    for i in range(x.size):
        z = np.sort(locations[ray_index == i][:, 2])[::-1]
        chords[i] = np.sum(z[0::2] - z[1::2]) if len(z) % 2 == 0 else np.nan
    tube_q = su2.step(np.full(x.size, sxx), 0.0, PHASE_RATE * chords)
    box_q = su2.step(0.0, np.full(x.size, 0.6), PHASE_RATE * 2.0)
    inside_box = np.abs(y.ravel()) < 1.9
    expected = su2.multiply(tube_q, tuple(np.where(inside_box, b, i) for b, i in zip(box_q, su2.identity(x.ravel() * 0))))
    np.testing.assert_allclose(channels["path.length"].ravel()[~np.isnan(chords)],
                               (chords + 2.0 * inside_box)[~np.isnan(chords)], atol=1e-4)
    crossings = np.array([np.sum(ray_index == i) for i in range(x.size)])
    assert np.sum(crossings == 4) >= 20   # the bore really is crossed twice by many rays
    valid = ~np.isnan(chords)
    for name, value in zip(("jones.a", "jones.b", "jones.c", "jones.d"), expected):
        np.testing.assert_allclose(channels[name].ravel()[valid], np.asarray(value)[valid], atol=3e-5,
                                   err_msg=name)


def test_stratified_jitter_converges_to_the_midpoint_answer():
    field = medium("twisted", amplitude=0.6, rate=9.0, angle=30.0, origin=[0, 0, -10])
    midpoint = render([box((30, 30, 20), interior=field)], step=0.5)
    jittered = render([box((30, 30, 20), interior=field)], step=0.5, jitter=True, sampler="independent", spp=64)
    difference = max(np.max(np.abs(midpoint[n] - jittered[n])) for n in MEASUREMENTS)
    assert 0 < difference < 1e-2


def test_perspective_rays_use_their_own_transverse_basis():
    """Each perspective ray sees the stress projected on its own (u, v): docs/physics.md section 1."""
    S = np.array([[1.5, 0.6, 0.9], [0.6, -0.8, -0.7], [0.9, -0.7, 0.3]])
    thickness, res = 3.0, 5
    origin = np.array([0.0, 0.0, 30.0])
    scene_ = scene([box((200, 200, thickness), interior=medium(
        xx=S[0, 0], yy=S[1, 1], zz=S[2, 2], yz=S[1, 2], zx=S[0, 2], xy=S[0, 1]))],
        projection="perspective", fov=60.0, origin=tuple(origin), up=(0.3, 1.0, 0.0), res=res)
    channels = mi_nest.render(scene_).channels
    sensor = scene_.sensors()[0]
    right = np.array(sensor.world_transform() @ mi.Vector3f(-1, 0, 0)).ravel()
    right /= np.linalg.norm(right)
    for row in range(res):
        for col in range(res):
            ray, _ = sensor.sample_ray(0.0, 0.0, mi.Point2f((col + 0.5) / res, (row + 0.5) / res), mi.Point2f(0.5))
            k = -np.array(ray.d).ravel()
            u = right - (right @ k) * k
            u /= np.linalg.norm(u)
            v = np.cross(k, u)
            chord = thickness / abs(k[2])
            expected = su2.step(u @ S @ u - v @ S @ v, 2 * u @ S @ v, PHASE_RATE * chord)
            got = [channels[f"jones.{c}"][row, col] for c in "abcd"]
            np.testing.assert_allclose(got, expected, atol=3e-5, err_msg=f"pixel {row},{col}")
    # The basis really varies across the image: the corner and centre axes differ.
    assert abs(channels["char.theta"][0, 0] - channels["char.theta"][2, 2]) > 0.01


@pytest.mark.parametrize("spp", [1, 4])
@pytest.mark.parametrize("pixel_format", ["luminance", "luminance_alpha"])
def test_direct_pixel_sums_match_mitsubas_film_splatting(spp, pixel_format):
    """The integrator's box-filter fast path gives what ADIntegrator.render's atomic splats and
    the film's develop give, and leaves the film holding the same image."""
    field = medium("twisted", amplitude=0.6, rate=9.0, angle=30.0, origin=[0, 0, -10])
    scene_ = scene([box((20, 20, 20), interior=field)], res=6, view=14.0, sampler="independent", spp=spp,
                   jitter=True, pixel_format=pixel_format)
    integrator = scene_.integrator()
    film = scene_.sensors()[0].film()
    fast = np.array(mi.render(scene_, seed=3))
    held = np.array(film.bitmap(), copy=True)
    held_sums = np.array(film.develop(raw=True), copy=True)
    names = integrator.channel_names(film)
    with integrator._planned(scene_, scene_.sensors()[0]):
        generic = np.array(mi.ad.integrators.common.ADIntegrator.render(integrator, scene_, seed=3))
    np.testing.assert_allclose(held_sums, np.array(film.develop(raw=True)), atol=1e-5)
    alpha = pixel_format.endswith("alpha")
    assert fast.shape == generic.shape == (6, 6, 1 + alpha + len(CHANNELS))
    assert names == [str(f.name) for f in film.bitmap().struct_()]
    np.testing.assert_allclose(fast, generic, atol=1e-6)
    np.testing.assert_allclose(held, fast, atol=1e-6)
    assert fast[..., 0].std() > 0.01   # the box edges and jitter make pixels differ


def test_check_scene_names_what_mi_render_reports_only_as_a_failed_operation():
    from mi_nest.tracer.guards import SceneSetupError
    loaded = scene([box((2, 2, 2))])        # no stress medium inside
    with pytest.raises(Exception):
        mi.render(loaded)
    with pytest.raises(SceneSetupError, match="the scene has no specimen"):
        loaded.integrator().check_scene(loaded)


@pytest.mark.parametrize("materials", [(BREWSTER, BREWSTER), (BREWSTER, 2 * BREWSTER)])
def test_a_field_passed_to_the_render_fills_every_specimen_and_leaves_the_scene_alone(materials):
    """``mi_nest.render(scene, field=...)``: each specimen keeps its material, the field replaces its stress."""
    from mi_nest.fields import UniformField
    first = box((20, 20, 2), center=(0, 0, 1), interior=medium(xx=1.5, C=materials[0]))
    second = box((20, 20, 3), center=(0, 0, -1.5), interior=medium(xy=0.8, C=materials[1]))
    loaded = scene([first, second], step=0.5)
    replaced = mi_nest.render(loaded, field=UniformField(xx=0.4, xy=-0.3)).channels
    rates = [math.pi * c / WAVELENGTH for c in materials]
    expected = su2.multiply(su2.step(0.4, -0.6, rates[0] * 2.0), su2.step(0.4, -0.6, rates[1] * 3.0))
    for c, value in zip("abcd", expected):
        np.testing.assert_allclose(replaced[f"jones.{c}"], value, atol=2e-5)
    own = mi_nest.render(loaded).channels
    expected = su2.multiply(su2.step(1.5, 0.0, rates[0] * 2.0), su2.step(0.0, 1.6, rates[1] * 3.0))
    for c, value in zip("abcd", expected):
        np.testing.assert_allclose(own[f"jones.{c}"], value, atol=2e-5)


@pytest.mark.parametrize("order", ["front_first", "back_first"])
def test_specimens_sharing_a_face_are_both_traversed(order):
    """Two slabs glued face to face (coincident surfaces): the light crosses both."""
    first = box((20, 20, 2), center=(0, 0, 1), interior=medium(xx=1.5))        # z in [0, 2]
    second = box((20, 20, 3), center=(0, 0, -1.5), interior=medium(xy=0.8))    # z in [-3, 0]
    shapes = [first, second] if order == "front_first" else [second, first]
    channels = render(shapes, step=0.5)
    # Light (travelling +z) crosses the second slab, then the first: J = J_first J_second.
    expected = su2.multiply(su2.step(1.5, 0.0, PHASE_RATE * 2.0), su2.step(0.0, 1.6, PHASE_RATE * 3.0))
    for name, value in zip(("jones.a", "jones.b", "jones.c", "jones.d"), expected):
        np.testing.assert_allclose(channels[name], value, atol=2e-5, err_msg=name)


def test_a_scenes_optics_put_any_elements_in_the_polariscope():
    """The light's and the camera's ``optics``: a half-wave plate at 22.5 degrees turns the panel's polariser
    from 0 to 45 degrees (free space through an analyser at 45 then passes everything, at 135 nothing), and a
    Babinet-Soleil compensator along a slab's slow axis, set to the slab's retardance, brings it to extinction
    between crossed polarisers at 45 degrees (sin^2((delta - c) / 2) elsewhere)."""
    free = [box((2, 2, 2), center=(30, 0, 0), interior=medium(xx=0.0))]      # a specimen out of view
    for analyzer, expected in ((45.0, 1.0), (135.0, 0.0)):
        with pytest.warns(RuntimeWarning, match="sees no specimen"):
            channels = render(free, light_optics="polarizer 0; hwp 22.5", analyzer=analyzer)
        np.testing.assert_allclose(channels["Y"], expected, atol=1e-6)
    slab = [box((20, 20, 4), interior=medium(xx=1.0))]          # sigma_1 along x: the slow axis (C > 0)
    own = render(slab)
    delta = float(np.mean(own["char.delta"]))                   # under pi: the characteristic angle is the axis
    assert np.abs(own["char.theta"]).max() < 1e-6
    rate = 360.0
    for position in (0.0, np.degrees(delta) / rate, 0.5 * np.degrees(delta) / rate):
        channels = render(slab, light_optics="polarizer 45", camera_optics=f"compensator 0 {rate} {position}; "
                                                                            "polarizer -45")
        expected = np.sin((delta - np.radians(rate * position)) / 2) ** 2
        np.testing.assert_allclose(channels["Y"], expected, atol=1e-5)
    assert 0.5 < delta < 3.0


@pytest.mark.parametrize("plugin, optics, message", [
    ("light", {"optics": "qwp 45", "polarizer": None}, "starts with the panel's polariser"),
    ("light", {"optics": "polarizer 0", "polarizer": 90.0}, "leave out 'polarizer'"),
    ("sensor", {"optics": "polarizer 0", "analyzer": 0.0}, "leave out 'analyzer'"),
    ("sensor", {"optics": "lens 2"}, "unknown optical element 'lens'")])
def test_optics_that_are_not_a_polariscope_are_refused(plugin, optics, message):
    light = {"type": "polariscope_light"}
    sensor = {"type": "polariscope", "film": {"type": "hdrfilm", "width": 2, "height": 2}}
    part = light if plugin == "light" else sensor
    part.update({key: value for key, value in optics.items() if value is not None})
    with pytest.raises(Exception, match=message):
        mi.load_dict({"type": "scene", "integrator": {"type": "photoelastic"}, "light": light, "sensor": sensor})
