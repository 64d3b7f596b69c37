"""Refraction and Fresnel at specimen surfaces in the renderer (issue 20; docs/physics.md section 8): closed-form
slabs, an analytic Snell trace through a sphere, total internal reflection, baths and bad input."""
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

import mi_nest
from mi_nest.physics import MEASUREMENTS, interface, jones
from mi_nest.tracer import PathKind
from mi_nest.tracer.guards import SceneSetupError
from test_independent_renderer import MEASUREMENTS as INDEPENDENT_SCOPES
from test_independent_renderer import mitsuba_stack

REFERENCE_SCRIPT = Path(__file__).with_name("polarized_reference.py")

T = mi.ScalarTransform4f
N = 1.55
STRESS = {"xx": 2.0, "yy": -1.0, "xy": 0.5}


def _scene(specimen, light=None, sensor=None, size=8, **shapes):
    """Orthographic camera along -z from +z (image right +x, image up +y), 8 mm across."""
    scene = {
        "type": "scene",
        # The transmitted path alone unless a test follows partial reflections (_with_bounces).
        "integrator": {"type": "photoelastic", "step_size": 0.25, "max_bounces": 0},
        "light": {"type": "polariscope_light", "polarizer": 90.0, "qwp": 45.0, **(light or {})},
        "sensor": {"type": "polariscope", "projection": "orthographic", "qwp": 45.0, "analyzer": 0.0,
                   "to_world": T().look_at(origin=[0, 0, 100], target=[0, 0, 0], up=[0, 1, 0]) @ T().scale([4, 4, 1]),
                   "film": {"type": "hdrfilm", "width": size, "height": size, "pixel_format": "luminance",
                            "rfilter": {"type": "box"}},
                   "sampler": {"type": "stratified", "sample_count": 1, "jitter": False}, **(sensor or {})},
        "specimen": specimen, **shapes,
    }
    for element in ("light", "sensor"):      # None: the element is absent
        scene[element] = {k: v for k, v in scene[element].items() if v is not None}
    return mi.load_dict(scene)


def _slab(ior=None, tilt=0.0, stress=None, half_thickness=2.0, half_width=10.0, ext_ior=1.0):
    slab = {"type": "cube",
            "to_world": T().rotate([1, 0, 0], tilt) @ T().scale([half_width, half_width, half_thickness]),
            "interior": {"type": "stress", "stress_optic_coefficient": 1.0, "wavelength": 532.0, "model": "uniform",
                         **(STRESS if stress is None else stress)}}
    if ior is not None:
        slab["bsdf"] = {"type": "dielectric", "int_ior": ior, "ext_ior": ext_ior}
    return slab


def _channels(scene):
    return mi_nest.render(scene, progress=False).channels


def test_a_stressed_slab_at_normal_incidence_is_the_index_matched_render_times_the_fresnel_transmittance():
    straight, refracted = _channels(_scene(_slab())), _channels(_scene(_slab(N)))
    transmittance = (4 * N / (1 + N) ** 2) ** 2           # in and out, the same for s and p at normal incidence
    for name in list(MEASUREMENTS) + ["Y"]:
        np.testing.assert_allclose(refracted[name], transmittance * straight[name], rtol=2e-5, atol=1e-6,
                                   err_msg=name)
    for name in ("jones.a", "jones.b", "jones.c", "jones.d", "path.length"):
        np.testing.assert_allclose(refracted[name], straight[name], atol=1e-6, err_msg=name)
    assert straight["pol.45.0.0"].std() < 1e-6 and 0.1 < straight["pol.45.0.0"].mean() < 0.9     # a real retarder


def test_the_linear_model_through_refracting_surfaces_gives_the_specimens_own_jones_channels():
    """A uniform slab's steps commute, so the linear model is exact: its Jones channels through refracting
    surfaces are the product's (the linear state is a generator, exponentiated once per segment)."""
    strong = {name: 15.0 * value for name, value in STRESS.items()}      # about 2 rad of retardance
    scenes = {method: _scene(_slab(N, tilt=20.0, stress=strong)) for method in ("product", "linear")}
    scenes["linear"].integrator().configure(method="linear")
    product, linear = (_channels(scenes[method]) for method in ("product", "linear"))
    for name in ("jones.a", "jones.b", "jones.c", "jones.d", "char.delta", "Y", *MEASUREMENTS):
        np.testing.assert_allclose(linear[name], product[name], atol=2e-4, err_msg=name)
    assert np.abs(product["char.delta"]).min() > 1.5


@pytest.mark.parametrize("tilt", [30.0, math.degrees(interface.brewster_angle(1.0, N))], ids=["30 deg", "Brewster"])
def test_an_unstressed_slab_at_oblique_incidence_transmits_as_fresnel_says(tilt):
    """Tilted about x: the plane of incidence is y-z, so s is image right (u) and p image up (v). Between
    parallel polarisers along s the two surfaces pass T_s^2, along p T_p^2 (1 at Brewster's angle); the chord
    inside is t / cos(theta_t)."""
    cos_i = math.cos(math.radians(tilt))
    _, _, tau_s, tau_p = interface.flux_coefficients(cos_i, 1.0, N)
    cos_t = float(np.real(interface.cos_transmitted(cos_i, 1.0, N)))
    for angle, transmitted in ((0.0, abs(tau_s) ** 4), (90.0, abs(tau_p) ** 4)):
        channels = _channels(_scene(_slab(N, tilt, stress={}, half_width=30.0), light={"polarizer": angle, "qwp": None},
                                    sensor={"qwp": None, "analyzer": angle}))
        np.testing.assert_allclose(channels["Y"], transmitted, rtol=1e-5)
        np.testing.assert_allclose(channels["path.length"], 4.0 / cos_t, rtol=1e-5)
    if tilt > 50:
        assert abs(tau_p) ** 4 == pytest.approx(1.0)


def test_a_tilted_slab_shifts_the_ray_sideways_and_keeps_its_direction():
    tilt, thickness = 35.0, 4.0
    scene = _scene(_slab(N, tilt, stress={}, half_width=30.0))
    offsets = np.linspace(-3, 3, 7)
    rays = mi.Ray3f(mi.Point3f(0.0, mi.Float(offsets), 100.0), mi.Vector3f(0, 0, -1))
    path = scene.integrator().tracer.trace_refracted(scene, rays)
    direction = np.array(path.exit_direction)
    np.testing.assert_allclose(direction, [[0] * 7, [0] * 7, [-1] * 7], atol=1e-6)
    # The exit line's distance from the entry line: t sin(i - t) / cos(t).
    i = math.radians(tilt)
    t = math.asin(math.sin(i) / N)
    shift = thickness * math.sin(i - t) / math.cos(t)
    exit_y = np.array(path.exit_point)[1]
    np.testing.assert_allclose(np.abs(exit_y - offsets), shift, rtol=1e-5)
    assert np.all(np.array(path.interfaces) == 2)


def test_a_glass_sphere_bends_rays_as_an_analytic_snell_trace():
    radius = 5.0
    sphere = {"type": "sphere", "radius": radius, "bsdf": {"type": "dielectric", "int_ior": N, "ext_ior": 1.0},
              "interior": {"type": "stress", "stress_optic_coefficient": 1.0, "wavelength": 532.0, "model": "uniform"}}
    scene = _scene(sphere)
    heights = np.linspace(0.2, 4.8, 12)
    rays = mi.Ray3f(mi.Point3f(mi.Float(heights), 0.0, 100.0), mi.Vector3f(0, 0, -1))
    path = scene.integrator().tracer.trace_refracted(scene, rays)
    i = np.arcsin(heights / radius)
    t = np.arcsin(np.sin(i) / N)
    inside = np.stack([-np.sin(i - t), 0 * i, -np.cos(i - t)])
    entry = np.stack([heights, 0 * i, np.sqrt(radius ** 2 - heights ** 2)])
    exit_point = entry + 2 * radius * np.cos(t) * inside
    deviation = 2 * (i - t)
    exit_direction = np.stack([-np.sin(deviation), 0 * i, -np.cos(deviation)])
    np.testing.assert_allclose(np.array(path.exit_point), exit_point, atol=2e-4)
    np.testing.assert_allclose(np.array(path.exit_direction), exit_direction, atol=2e-5)
    np.testing.assert_allclose(np.array(path.length), 2 * radius * np.cos(t), rtol=1e-5)


def test_total_internal_reflection_is_followed_without_nan_and_within_max_crossings():
    """Light entering a cube's top face meets a side face beyond the critical angle: a cube turned 45 degrees
    under the camera traps part of its rays by total reflection. A ray that would cross more surfaces than
    ``max_crossings`` never reached the light: it is dark, not half-traced."""
    cube = {**_slab(N, 45.0, stress=STRESS, half_thickness=3.0, half_width=3.0)}
    rays = mi.Ray3f(mi.Point3f(mi.Float(np.linspace(-3.9, 3.9, 40)), mi.Float(np.linspace(-3.9, 3.9, 40)), 100.0),
                    mi.Vector3f(0, 0, -1))
    paths = {}
    for limit in (2, 64):
        scene = _scene(cube, size=32)
        scene.integrator().configure(max_crossings=limit)
        channels = _channels(scene)
        for name, image in channels.items():
            assert np.all(np.isfinite(image)), name
        assert 0.0 <= channels["Y"].min() and channels["Y"].max() <= 1.0 + 1e-5
        paths[limit] = scene.integrator().tracer.trace_refracted(scene, rays)
        assert np.array(paths[limit].interfaces).max() <= limit
    # A ray sent back towards the camera's side by its reflections never meets the panel behind the specimens.
    backwards = np.array(paths[64].exit_direction)[2] >= 0
    np.testing.assert_array_equal(np.array(paths[64].blocked)[backwards], True)
    crossed = np.array(paths[64].interfaces)
    # Some rays meet more than the two faces they cross: they were totally reflected on the way.
    assert crossed.max() >= 3
    np.testing.assert_array_equal(np.array(paths[2].blocked)[crossed > 2], True)
    within = (crossed <= 2) & ~np.array(paths[64].blocked)
    assert within.any()
    np.testing.assert_allclose(np.array(paths[2].jones[0])[:, within], np.array(paths[64].jones[0])[:, within],
                               atol=1e-6)
    # Partial reflections on top: each sampled path takes at most max_bounces of them, total reflections
    # (not a choice: the only way on) aside; everything stays finite and within max_crossings.
    scene = _scene(cube, size=32, sensor={"sampler": {"type": "independent", "sample_count": 16}})
    scene.integrator().configure(max_bounces=3)
    channels = _channels(scene)
    assert all(np.all(np.isfinite(image)) for image in channels.values())
    for seed in range(4):
        sampled = scene.integrator().tracer.trace_refracted(scene, rays, seed=seed, bounces=3)
        taken, crossed = np.array(sampled.reflections), np.array(sampled.interfaces)
        assert taken.max() <= 3 and crossed.max() <= 64 and np.all(np.isfinite(np.array(sampled.jones[0])))
    assert taken.max() >= 1


def test_total_reflection_keeps_the_light_whole():
    """A ray totally reflected inside carries its power on: with the reflections' phases, the path's Jones
    matrix keeps the product of the two transmissions as its only loss."""
    scene = _scene(_slab(N, 45.0, stress={}, half_thickness=3.0, half_width=3.0), size=32)
    rays = mi.Ray3f(mi.Point3f(0.0, mi.Float(np.linspace(-3.9, 3.9, 200)), 100.0), mi.Vector3f(0, 0, -1))
    path = scene.integrator().tracer.trace_refracted(scene, rays)
    reflected = np.array(path.interfaces) == 3
    assert reflected.any()
    # Inside, the march goes on past the reflection: unfolded by the mirror, every chord crosses the square
    # from face to parallel face at the refraction angle.
    inside = 6.0 / math.sqrt(1.0 - (math.sin(math.radians(45.0)) / N) ** 2)
    np.testing.assert_allclose(np.array(path.length), inside, rtol=1e-5)
    matrices = np.array(path.jones[0]).T, np.array(path.jones[1]).T
    for a, b in zip(matrices[0][reflected], matrices[1][reflected]):
        singular = np.linalg.svd(jones.to_matrix((tuple(a), tuple(b))), compute_uv=False)
        cos_i = math.cos(math.radians(45.0))
        _, _, tau_s, tau_p = interface.flux_coefficients(cos_i, 1.0, N)
        np.testing.assert_allclose(sorted(singular), sorted([abs(tau_s) ** 2, abs(tau_p) ** 2]), rtol=1e-4)


def test_an_index_matched_bath_leaves_only_its_own_walls():
    """A specimen of n = 1.5 in a liquid of n = 1.5: its surfaces vanish, the tank's flat walls at normal
    incidence pass (4 n / (1 + n)^2)^2 of the straight render."""
    bath = {"type": "cube", "to_world": T().scale([20, 20, 8]),
            "bsdf": {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0}}
    matched = _channels(_scene(_slab(1.5, 20.0, ext_ior=1.5), bath=bath))
    straight = _channels(_scene(_slab(None, 20.0)))
    walls = (4 * 1.5 / 2.5 ** 2) ** 2
    for name in list(MEASUREMENTS) + ["Y"]:
        np.testing.assert_allclose(matched[name], walls * straight[name], rtol=2e-5, atol=1e-6, err_msg=name)
    np.testing.assert_allclose(matched["path.length"], straight["path.length"], rtol=1e-5)


def test_bad_interfaces_are_refused_with_one_line():
    with pytest.raises(SceneSetupError, match="int_ior / ext_ior = 0.0; give both indices as positive"):
        _channels(_scene(_slab(0.0)))
    rough = {**_slab(), "bsdf": {"type": "roughdielectric", "int_ior": N}}
    with pytest.raises(SceneSetupError, match="RoughDielectric: a rough dielectric scatters"):
        _channels(_scene(rough))
    sheet = {"type": "rectangle", "to_world": T().scale(20), "bsdf": {"type": "dielectric", "int_ior": N}}
    with pytest.raises(SceneSetupError, match="bath 'sheet' is not a closed mesh"):
        _channels(_scene(_slab(N), sheet=sheet))
    cutting = {"type": "cube", "to_world": T().translate([10, 0, 0]) @ T().scale([5, 20, 20]),
               "bsdf": {"type": "dielectric", "int_ior": 1.4}}
    with pytest.raises(SceneSetupError, match="the surface of bath 'cutting' cuts specimen 'specimen'"):
        _channels(_scene(_slab(N), cutting=cutting))


def test_max_bounces_defaults_to_the_measured_value_everywhere_and_refuses_a_negative_count():
    from mi_nest.tracer.refraction import DEFAULT_MAX_BOUNCES
    from mi_nest.scene import SceneError
    assert mi.load_dict({"type": "photoelastic"}).tracer.config.max_bounces == DEFAULT_MAX_BOUNCES
    for name in ("disk_compression", "kitten"):
        assert mi_nest.load_scene(name, res=8).integrator().tracer.config.max_bounces == DEFAULT_MAX_BOUNCES
    assert mi_nest.load_scene("disk_compression", res=8, max_bounces=1).integrator().tracer.config.max_bounces == 1
    with pytest.raises(SceneError, match="'max_bounces' must be 0 or more, got -1") as refused:
        mi_nest.load_scene("disk_compression", res=8, max_bounces=-1)
    assert "Traceback" not in str(refused.value) and "\n" not in str(refused.value)


def test_render_backward_through_refracting_surfaces_is_refused_not_traced_straight():
    """Ray batches are differentiated through refraction (tests/test_gradients.py); mi.render + dr.backward
    is not yet, and says so."""
    scene = _scene(_slab(N))
    with pytest.raises(SceneSetupError, match="differentiable rendering through refracting surfaces is not "
                                              "available yet"):
        scene.integrator().render_backward(scene, None, mi.TensorXf(np.zeros((8, 8, 1), dtype=np.float32)))


def test_a_tilted_glass_block_matches_mitsubas_polarised_dielectric(tmp_path):
    """Mitsuba's polarised path tracer, its own ``dielectric`` BSDF (which picks reflection or transmission at
    random, Fresnel-weighted) and its ``polarizer``/``retarder`` sheets: all 16 channels of an unstressed block
    at 30 degrees. Its paths include the ghosts (light reflected twice inside, R^2 ~ 0.3% here): mi_nest's
    transmitted path alone misses them (0.0021 measured, within 0.006); with ``max_bounces`` it follows them and
    agrees within 0.0006 (measured 0.0002; index-matched rays miss by 0.092). The block's s/p difference
    (T_s^2 = 0.87, T_p^2 = 0.95) is what the comparison must see."""
    tilt = 30.0
    block = {"type": "block", "int_ior": N, "tilt": tilt, "half_thickness": 2.0}
    requests = {"free_space": [{"type": "polarizer", "theta": 90.0}, {"type": "polarizer", "theta": 90.0}]}
    for name, scope in INDEPENDENT_SCOPES.items():
        stack = mitsuba_stack(scope, [])
        stack.insert(1 + (scope.input_qwp is not None), block)
        requests[name] = stack
    request, result = tmp_path / "request.json", tmp_path / "result.json"
    request.write_text(json.dumps(requests))
    done = subprocess.run([sys.executable, str(REFERENCE_SCRIPT), str(request), str(result)], env=dict(os.environ),
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"reference renderer failed:\n{done.stdout}\n{done.stderr}"
    raw = json.loads(result.read_text())
    reference = {name: value / raw["free_space"] for name, value in raw.items() if name != "free_space"}

    def worst(channels):
        return max(abs(float(channels[name].mean()) - reference[name]) for name in MEASUREMENTS)
    transmitted = _channels(_scene(_slab(N, tilt, stress={}, half_width=30.0)))
    with_ghosts = _scene(_slab(N, tilt, stress={}, half_width=30.0),
                         sensor={"sampler": {"type": "independent", "sample_count": 512}})
    with_ghosts.integrator().configure(max_bounces=4)
    index_matched = _channels(_scene(_slab(None, tilt, stress={}, half_width=30.0)))
    errors = worst(transmitted), worst(_channels(with_ghosts)), worst(index_matched)
    assert errors[0] < 0.006 and errors[1] < 0.0006 and errors[2] > 0.05, errors
    assert errors[1] < errors[0] / 2, errors


def test_the_shipped_disk_takes_its_index_and_its_bath_from_defines():
    """``-D ior=1.55`` refracts in air; ``-D ext_ior`` puts it in a bath, and a matched bath is the straight render
    bit for bit (the same walk). Viewed along its axis the disk is a slab at normal incidence; its transmitted path
    alone is the closed form (the ghosts: tests above)."""
    defines = {"res": 32, "spp": 1, "load": 100.0, "contact_width": 4.0, "max_bounces": 0}
    straight = _channels(mi_nest.load_scene("disk_compression", **defines))
    in_air = _channels(mi_nest.load_scene("disk_compression", ior=N, **defines))
    matched = _channels(mi_nest.load_scene("disk_compression", ior=N, ext_ior=N, **defines))
    in_water = _channels(mi_nest.load_scene("disk_compression", ior=N, ext_ior=1.33, **defines))
    inside = straight["path.length"] > 0
    for name in ("Y", "pol.45.0.0", "pol.90.45.135"):
        np.testing.assert_array_equal(matched[name], straight[name])
        np.testing.assert_allclose(in_air[name][inside], (4 * N / (1 + N) ** 2) ** 2 * straight[name][inside],
                                   rtol=1e-4, atol=1e-6)
        ratio = N / 1.33
        np.testing.assert_allclose(in_water[name][inside], (4 * ratio / (1 + ratio) ** 2) ** 2
                                   * straight[name][inside], rtol=1e-4, atol=1e-6)


def test_simulate_renders_the_bent_paths_and_reconstruction_traces_the_same(tmp_path):
    """``mi-nest simulate -D ior=1.55`` renders each rotation along the refracted paths, ghosts included (the
    default max_bounces); the reconstruction loads the dataset's own scene, whose ray batches trace the same
    paths and carry the ghosts: the true field explains the images (up to pixel sampling: a 16 x 16 disk is
    mostly rim) and index-matched straight rays do not."""
    from mi_nest.cli import main
    from mi_nest.reconstruct.evaluation import dataset_loss
    from mi_nest.scene import specimen_shapes
    datasets = {}
    for bounces in (0, None):
        datasets[bounces] = tmp_path / f"data{bounces}"
        main(["simulate", "disk_compression", "-o", str(datasets[bounces]), "--azimuth", "3", "--elevation", "2",
              "--res", "16", "--spp", "64", "--noise", "0", "--float", "-D", "ior=1.55", "-D", "load=20",
              "-D", "contact_width=4"] + ([] if bounces is None else ["-D", f"max_bounces={bounces}"]))
    with_ghosts, transmitted = mi_nest.Dataset(datasets[None]), mi_nest.Dataset(datasets[0])
    assert with_ghosts.index["source"]["defines"]["ior"] == "1.55"
    ghosts = np.mean([np.abs(with_ghosts.measurements(i) - transmitted.measurements(i)).mean()
                      for i in with_ghosts.split("train")])
    assert ghosts > 2e-3, ghosts
    scene = mi_nest.load_scene(with_ghosts.index["source"]["scene"], **with_ghosts.index["source"]["defines"])
    rays = mi.Ray3f(mi.Point3f(0.0, mi.Float(np.linspace(-15, 15, 8)), 100.0), mi.Vector3f(0, 0, -1))
    traced = scene.integrator().tracer.trace_rays(scene, rays, mi.Vector3f(1, 0, 0))
    assert traced.kind is PathKind.GHOSTED and len(traced.state) == 16  # the transmitted path's and a ghost's
    losses = {}
    for label, indices in (("refracted", {}), ("straight", {"ior": 1.0})):
        scene = mi_nest.load_scene("disk_compression", **{**transmitted.index["source"]["defines"], **indices})
        truth = specimen_shapes(scene)[0].interior_medium().field
        losses[label] = dataset_loss(scene, transmitted, truth, scene.integrator().tracer, split="train", mask=None)
    assert losses["straight"] > 2.5 * losses["refracted"], losses
    # The reconstruction renders with the scene integrator's surface settings: a dataset simulated with ghosts
    # is fitted with them, one without, without.
    for bounces in (0, 2):
        scene = mi_nest.load_scene("disk_compression", **{**transmitted.index["source"]["defines"],
                                                          "max_bounces": bounces})
        scene.integrator().configure(max_crossings=16)
        result = mi_nest.optimize(scene, transmitted, iterations=2, kind="grid", resolution=8, progress=False)
        config = result.tracer(scene).config
        assert (config.max_bounces, config.max_crossings) == (bounces, 16)


def test_rays_bent_past_a_finite_panel_bring_no_light():
    """A glass ball is a lens: behind it, rays cross the axis and spread. A 100 mm distant panel catches only
    those that land within its side, as an analytic Snell trace says; the others are dark (a real part's rim)."""
    radius, distance = 5.0, 100.0
    sphere = {"type": "sphere", "radius": radius, "bsdf": {"type": "dielectric", "int_ior": N, "ext_ior": 1.0},
              "interior": {"type": "stress", "stress_optic_coefficient": 1.0, "wavelength": 532.0, "model": "uniform"}}
    heights = np.linspace(0.2, 4.8, 24)
    i = np.arcsin(heights / radius)
    t = np.arcsin(np.sin(i) / N)
    exit_x = heights - 2 * radius * np.cos(t) * np.sin(i - t)
    exit_z = np.sqrt(radius ** 2 - heights ** 2) - 2 * radius * np.cos(t) * np.cos(i - t)
    deviation = 2 * (i - t)
    on_panel = exit_x - np.tan(deviation) * (exit_z + distance)
    size = 2 * float(np.median(np.abs(on_panel)))
    scene = _scene(sphere, light={"size": size, "distance": distance})
    rays = mi.Ray3f(mi.Point3f(mi.Float(heights), 0.0, 100.0), mi.Vector3f(0, 0, -1))
    path = scene.integrator().tracer.trace_refracted(scene, rays)
    missed = np.abs(on_panel) > size / 2
    assert 4 <= missed.sum() <= 20
    np.testing.assert_array_equal(np.array(path.blocked), missed)
    # In the image: the middle lit, the rim (nearly grazing rays, bent most) dark.
    channels = _channels(scene)
    assert channels["Y"][3:5, 3:5].min() > 0.5 and channels["Y"][0, 0] == 0
    with pytest.raises(Exception, match="'size' must be a positive length in mm, got -1"):
        _scene(sphere, light={"size": -1.0})


def test_a_panel_larger_than_the_view_changes_nothing_and_a_small_one_darkens_straight_rays_too():
    plain = _channels(_scene(_slab()))
    large = _channels(_scene(_slab(), light={"size": 50.0}))
    small = _channels(_scene(_slab(), light={"size": 4.0}))     # the view is 8 mm across
    np.testing.assert_array_equal(large["Y"], plain["Y"])
    np.testing.assert_array_equal(small["Y"][2:6, 2:6], plain["Y"][2:6, 2:6])
    assert np.all(small["Y"][0] == 0) and np.all(small["Y"][:, 7] == 0)


@pytest.mark.parametrize("tilt", [25.0, 50.0])
def test_a_stressed_slab_at_oblique_incidence_is_fresnel_times_the_retarder_of_the_refracted_chord(tilt):
    """Written out by hand: tilted about x, s is x at both faces; inside, the light runs along the refracted
    direction for t / cos(theta_t), its frame (x, the carried v); the stress seen is projected on that frame.
    M = diag(tau_s, tau_p) exp(-i k L [[p, q], [q, -p]]) diag(tau_s, tau_p) in (u = x, v)."""
    from scipy.linalg import expm
    stress = {"xx": 3.0, "yy": -1.0, "zz": 0.5, "yz": 1.2, "zx": -0.7, "xy": 0.8}
    channels = _channels(_scene(_slab(N, tilt, stress=stress, half_width=30.0)))
    i = math.radians(tilt)
    t = math.asin(math.sin(i) / N)
    # The slab's normal is z turned by the tilt about x; the camera ray runs along -z.
    normal = np.array([0.0, -math.sin(i), math.cos(i)])
    inside = -(math.cos(t) * normal) + math.sin(t) * np.array([0.0, math.cos(i), math.sin(i)]) * \
        np.sign(np.dot([0.0, 0.0, -1.0], [0.0, math.cos(i), math.sin(i)]))
    inside /= np.linalg.norm(inside)
    assert np.degrees(np.arccos(-np.dot(inside, normal))) == pytest.approx(math.degrees(t), abs=1e-9)
    k = -inside                                            # the light's direction inside
    u = np.array([1.0, 0.0, 0.0])
    v = np.cross(k, u)
    matrix = np.array([[stress["xx"], stress["xy"], stress["zx"]], [stress["xy"], stress["yy"], stress["yz"]],
                       [stress["zx"], stress["yz"], stress["zz"]]])
    p = u @ matrix @ u - v @ matrix @ v
    q = 2 * u @ matrix @ v
    length = 4.0 / math.cos(t)
    rate = math.pi * 1.0 / 532.0                           # pi C / lambda: rad per MPa mm (Brewster, nm)
    retarder = expm(-1j * rate * length * np.array([[p, q], [q, -p]]))
    _, _, tau_s, tau_p = interface.flux_coefficients(math.cos(i), 1.0, N)
    fresnel = np.diag([complex(tau_s), complex(tau_p)])
    total = fresnel @ retarder @ fresnel
    for name, scope in MEASUREMENTS.items():
        expected = float(np.sum(np.abs(scope.matrix(total)) ** 2))
        assert float(channels[name].mean()) == pytest.approx(expected, abs=2e-4), name


def _with_bounces(slab, bounces, spp=4096, **elements):
    """The slab's channels with ``max_bounces``, ``spp`` independent samples per pixel."""
    scene = _scene(slab, sensor={"sampler": {"type": "independent", "sample_count": spp}, **elements.pop("sensor", {})},
                   **elements)
    scene.integrator().configure(max_bounces=bounces)
    return _channels(scene)


def _near(image, expected, name):
    """The image's mean within four standard errors of the sampled estimate of ``expected``."""
    spread = 4.0 * float(image.std()) / math.sqrt(image.size) + 2e-5
    assert abs(float(image.mean()) - expected) < spread, (name, float(image.mean()), expected, spread)


def test_partial_reflections_add_a_slabs_ghosts_as_the_incoherent_series():
    """n = 3 (R = 0.25 per face at normal incidence): light reflected 2j times inside arrives with T^2 R^(2j).
    The transmitted path alone gives T^2; max_bounces gives the partial sums (an odd bounce sends the light back
    to the camera's side, so 1 adds nothing at all); many bounces give the slab's incoherent transmittance
    (1 - R) / (1 + R): the power reflected and transmitted then adds up to the incident."""
    n, reflectance = 3.0, 0.25
    transmittance = 1.0 - reflectance
    plain = _channels(_scene(_slab(None, stress={})))
    transmitted = _with_bounces(_slab(n, stress={}), 0)
    np.testing.assert_array_equal(_with_bounces(_slab(n, stress={}), 1)["Y"], transmitted["Y"])
    for bounces, series in ((0, 1.0), (2, 1.0 + reflectance ** 2), (4, 1.0 + reflectance ** 2 + reflectance ** 4),
                            (24, 1.0 / (1.0 - reflectance ** 2))):
        channels = _with_bounces(_slab(n, stress={}), bounces)
        for name in ["Y"] + list(MEASUREMENTS):
            _near(channels[name], float(plain[name].mean()) * transmittance ** 2 * series, f"{bounces} {name}")
    assert transmittance ** 2 / (1.0 - reflectance ** 2) == pytest.approx((1 - reflectance) / (1 + reflectance))


def test_a_stressed_slabs_first_ghost_crosses_it_three_times():
    """Reflected back and forth at normal incidence the light runs through the retarder three times, and a
    reciprocal retarder met backwards in the carried frame is the same retarder: the first ghost's Jones
    matrix is T R exp(-3 i phi) for the slab's own exp(-i phi) (the double pass of a waveplate on a mirror, once
    more). The Jones channels keep the transmitted path's product."""
    from scipy.linalg import expm
    n, reflectance = 3.0, 0.25
    stress = {"xx": 30.0, "yy": -10.0, "xy": 15.0}   # about 1.2 rad of retardance per pass
    rate = math.pi / 532.0 * 4.0                        # pi C L / lambda, C = 1, L = 4 mm
    generator = rate * np.array([[stress["xx"] - stress["yy"], 2 * stress["xy"]],
                                 [2 * stress["xy"], stress["yy"] - stress["xx"]]])
    once, thrice = expm(-1j * generator), expm(-3j * generator)
    channels = _with_bounces(_slab(n, stress=stress), 2)
    transmitted = _with_bounces(_slab(n, stress=stress), 0)
    for name, scope in MEASUREMENTS.items():
        expected = sum(weight * float(np.sum(np.abs(scope.matrix(matrix)) ** 2))
                       for weight, matrix in (((1 - reflectance) ** 2, once),
                                              ((1 - reflectance) ** 2 * reflectance ** 2, thrice)))
        assert float(transmitted[name].mean()) == pytest.approx((1 - reflectance) ** 2 * float(
            np.sum(np.abs(scope.matrix(once)) ** 2)), abs=1e-5), name
        _near(channels[name], expected, name)
    for name in ("jones.a", "jones.b", "jones.c", "jones.d", "path.length"):
        np.testing.assert_array_equal(channels[name], transmitted[name], err_msg=name)


def test_an_oblique_slabs_ghosts_follow_s_and_p_apart():
    """Tilted 40 degrees about x (s = image right, p = image up): the j-th ghost is diag(T_s R_s^j, T_p R_p^j),
    and all of them together pass (1 - R_s) / (1 + R_s) of s light, (1 - R_p) / (1 + R_p) of p light."""
    n, tilt = 3.0, 40.0
    r_s, r_p, tau_s, tau_p = (abs(complex(x)) ** 2 for x in
                              interface.flux_coefficients(math.cos(math.radians(tilt)), 1.0, n))
    channels = _with_bounces(_slab(n, tilt, stress={}, half_width=30.0), 24)
    for name, scope in MEASUREMENTS.items():
        expected = sum(float(np.sum(np.abs(scope.matrix(np.diag([tau_s * r_s ** j, tau_p * r_p ** j]))) ** 2))
                       for j in range(30))
        _near(channels[name], expected, name)
    for polariser, share in ((0.0, (1 - r_s) / (1 + r_s)), (90.0, (1 - r_p) / (1 + r_p))):
        linear = _with_bounces(_slab(n, tilt, stress={}, half_width=30.0), 24,
                               light={"polarizer": polariser, "qwp": None}, sensor={"qwp": None, "analyzer": polariser})
        _near(linear["Y"], share, f"polariser {polariser}")


def _sphere_crossings(origin, direction, centre, radius):
    """Entry and exit distances of a line through a sphere (NaN where it misses)."""
    offset = origin - centre
    b = offset @ direction
    disc = b * b - (offset @ offset - radius ** 2)
    root = math.sqrt(disc) if disc > 0 else float("nan")
    return -b - root, -b + root


def _trace_spheres(origin, direction, spheres):
    """Light directions along a ray through glass spheres, by Snell's law written out (NumPy)."""
    directions = [direction]
    for centre, radius in spheres:
        entry, _ = _sphere_crossings(origin, direction, centre, radius)
        if not entry > 0:
            return None
        point = origin + entry * direction
        inside, _, total = interface.refract(tuple(direction), tuple((point - centre) / radius), 1.0, N)
        inside = np.array(inside, dtype=np.float64)
        _, leave = _sphere_crossings(point, inside, centre, radius)
        point = point + leave * inside
        out, _, total = interface.refract(tuple(inside), tuple((point - centre) / radius), N, 1.0)
        if total:
            return None
        origin, direction = point, np.array(out, dtype=np.float64)
        directions += [inside, direction]
    return directions


def _solid_angle(directions):
    """Signed solid angle of the spherical polygon through unit ``directions`` (fan from the first; Van
    Oosterom and Strackee's formula per triangle)."""
    a, total = directions[0], 0.0
    for b, c in zip(directions[1:-1], directions[2:]):
        total += 2 * math.atan2(a @ np.cross(b, c), 1 + a @ b + b @ c + c @ a)
    return total


def test_the_light_sheets_turn_by_the_geometric_rotation_of_a_path_that_leaves_its_plane():
    """Two glass balls side by side bend a ray in two different planes. Carried without twist, its frame comes
    back turned from the straight one by the solid angle its directions enclose (Rytov's rotation, Berry's
    phase), computed here from a hand-written Snell trace; a path in one plane (one ball) is not turned."""
    spheres = [(np.array([0.0, 0.0, 15.0]), 5.0), (np.array([-3.0, 3.0, -15.0]), 6.0)]
    shapes = {f"ball{i}": {"type": "sphere", "center": centre.tolist(), "radius": radius,
                           "bsdf": {"type": "dielectric", "int_ior": N, "ext_ior": 1.0},
                           "interior": {"type": "stress", "stress_optic_coefficient": 1.0, "wavelength": 532.0,
                                        "model": "uniform"}}
              for i, (centre, radius) in enumerate(spheres)}
    scene = _scene(shapes.pop("ball0"), **shapes)
    rng = np.random.default_rng(3)
    starts = np.stack([rng.uniform(-4, 4, 200), rng.uniform(-4, 4, 200), np.full(200, 100.0)])
    rays = mi.Ray3f(mi.Point3f(starts.astype(np.float32)), mi.Vector3f(0, 0, -1))
    path = scene.integrator().tracer.trace_refracted(scene, rays)
    rotation, crossed = np.array(path.sheet_rotation), np.array(path.interfaces)
    expected, measured, planar = [], [], []
    for index in range(200):
        directions = _trace_spheres(starts[:, index], np.array([0.0, 0.0, -1.0]), spheres)
        if directions is None or crossed[index] != 4:
            if crossed[index] == 2:
                planar.append(rotation[index])
            continue
        expected.append(_solid_angle(directions))
        measured.append(rotation[index])
    expected, measured = np.array(expected), np.array(measured)
    assert len(expected) >= 20 and np.abs(expected).max() > 0.01
    sign = np.sign(np.sum(expected * measured))
    np.testing.assert_allclose(measured, sign * expected, atol=2e-4)
    assert len(planar) >= 20 and np.abs(planar).max() < 1e-4
