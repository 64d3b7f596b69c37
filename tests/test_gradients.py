"""Reverse-mode derivatives by path replay, against central finite differences.

Every trainable field representation and the ``linear``, ``product`` and
``magnus4`` models; through the ray-batch interface the optimiser uses and
through ``mi.render`` + ``dr.backward`` (``render_backward``).
"""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mi_nest.physics import jones
from mi_nest.reconstruct.fields import FieldConfig, make_field
from mi_nest.tracer import SCENE_VIEW, PathKind, Tracer, TracerConfig, View
from scenes import box, scene

# Stress that gives about a radian per mm of path: a few radians across the 4 mm box, so the
# products are far from linear and the test sees the exponential's derivative, not a sum.
SCALE = 4.0
RAYS = 24


def _batch(seed=0):
    rng = np.random.default_rng(seed)
    origins = np.stack([rng.uniform(-1.6, 1.6, RAYS), rng.uniform(-1.6, 1.6, RAYS), np.full(RAYS, 10.0)])
    directions = np.stack([rng.uniform(-0.15, 0.15, RAYS), rng.uniform(-0.15, 0.15, RAYS), -np.ones(RAYS)])
    directions /= np.linalg.norm(directions, axis=0)
    weights = [mi.Float(rng.normal(size=RAYS).astype(np.float32)) for _ in range(4)]
    return mi.Ray3f(mi.Point3f(origins.astype(np.float32)), mi.Vector3f(directions.astype(np.float32))), weights


def _specimen():
    return scene([box((4, 4, 4), interior={"type": "stress", "model": "uniform",
                                           "stress_optic_coefficient": 50.0})], res=2, view=2.5)


def _field(kind, resolution=4):
    config = FieldConfig(kind=kind, resolution=resolution, levels=2, hashmap_size=2 ** 8, base_resolution=2, width=8,
                         layers=2, octaves=2, seed=3)
    field = make_field(config, (-2.0, -2.0, -2.0), (2.0, 2.0, 2.0), SCALE)
    rng = np.random.default_rng(7)
    values = {}
    for name, current in field.parameters().items():
        spread = 0.5 if kind == "grid" else (0.3 if name == "weights" else 1.0)
        values[name] = type(current)(rng.normal(0, spread, current.shape).astype(np.float32))
    field.assign(values)
    return field


@pytest.mark.parametrize("kind, method, resolution", [
    ("grid", "product", 4), ("grid", "linear", 4), ("grid", "magnus4", 4),
    ("hashgrid", "product", 0), ("hashgrid", "linear", 0), ("mlp", "product", 0), ("mlp", "linear", 0),
    # Sampled on a lattice: the gradient the march leaves on the samples, carried back through the network.
    ("hashgrid", "product", 4), ("mlp", "product", 4)])
def test_replayed_gradient_matches_finite_differences(kind, method, resolution):
    loaded = _specimen()
    integrator = mi.load_dict({"type": "photoelastic", "method": method, "step_size": 0.4, "jitter": True,
                               "max_bounces": 0})
    field = _field(kind, resolution)
    rays, weights = _batch()

    def loss(q):
        return sum(dr.sum(w * x) for w, x in zip(weights, q))

    gradients, checked, _ = _replayed_against_finite_differences(loaded, integrator, field, rays, loss, largest=3)
    assert checked >= 3
    assert max(np.abs(g).max() for g in gradients.values()) > 1e-3


@pytest.mark.parametrize("method", ["product", "linear", "magnus4"])
def test_replayed_gradient_of_a_spectral_march_matches_finite_differences(method):
    """Three wavelengths in one march (one lookup per step for all), each lane weighted on its own."""
    loaded = _specimen()
    integrator = mi.load_dict({"type": "photoelastic", "method": method, "step_size": 0.4, "jitter": True,
                               "max_bounces": 0})
    field = _field("grid")
    rays, _ = _batch()
    rng = np.random.default_rng(11)
    view = View(lanes=(("short", 1.3), ("middle", 1.0), ("long", 0.75)))
    weights = [[mi.Float(rng.normal(size=RAYS).astype(np.float32)) for _ in range(4)] for _ in view.lanes]

    def loss(lanes):
        assert len(lanes) == 3
        return sum(dr.sum(w * x) for lane, lane_weights in zip(lanes, weights) for w, x in zip(lane_weights, lane))

    gradients, checked, traced = _replayed_against_finite_differences(loaded, integrator, field, rays, loss,
                                                                      largest=3, view=view)
    assert traced.kind is PathKind.SPECTRAL
    assert checked >= 3
    assert max(np.abs(g).max() for g in gradients.values()) > 1e-3


def test_a_replay_through_the_kept_segments_is_the_replay_that_queries_the_scene():
    """Three boxes along the rays, two glued face to face and one across a gap: each ray marches up to three
    segments. Replayed from the segments its primal walk kept, the gradient is the one a replay that finds every
    crossing again gives, and the walk kept each ray's segments (its inside length is theirs). A log too small for
    a batch replays it by querying the scene, and the next batches keep enough."""
    interior = {"type": "stress", "model": "uniform", "stress_optic_coefficient": 50.0}
    loaded = scene([box((4, 4, 1.5), (0, 0, 1.25), interior), box((4, 4, 1.0), (0, 0, 0.0), interior),
                    box((4, 4, 1.0), (0, 0, -1.5), interior)], res=2, view=2.5)
    integrator = mi.load_dict({"type": "photoelastic", "method": "product", "step_size": 0.4, "jitter": True,
                               "max_bounces": 0})
    tracer = integrator.tracer
    field = _field("grid")
    rays, weights = _batch()
    right = mi.Vector3f(1, 0, 0)

    def replayed(replayable):
        variables = {name: type(v)(np.array(v)) for name, v in field.parameters().items()}
        for v in variables.values():
            dr.enable_grad(v)
        field.assign(variables)
        traced = tracer.trace_rays(loaded, rays, right, seed=5, field=field, replayable=replayable)
        tracer.backpropagate_rays(loaded, rays, right, traced, tuple(mi.Float(w) for w in weights), seed=5,
                                  field=field)
        field.finish_backward()
        return np.array(dr.grad(variables["grid"])).ravel(), traced.segments

    queried, _ = replayed(False)
    kept, segments = replayed(True)
    assert np.abs(queried).max() > 1e-3
    np.testing.assert_allclose(kept, queried, rtol=1e-5, atol=1e-6 * np.abs(queried).max())
    counts = np.array(segments.count)
    assert counts.max() == 3 and np.count_nonzero(counts == 3) >= RAYS // 2
    slots = np.arange(RAYS)[:, None] * segments.capacity + np.arange(3)[None, :]
    lengths = np.where(np.arange(3)[None, :] < counts[:, None],
                       np.array(segments.kept["h"])[slots] * np.array(segments.kept["steps"])[slots], 0.0)
    np.testing.assert_allclose(lengths.sum(axis=1), np.array(tracer.trace_rays(loaded, rays, right, seed=5,
                                                                               field=field).length), rtol=1e-5)
    tracer.segments_kept = 2
    overflowed, _ = replayed(True)
    np.testing.assert_allclose(overflowed, queried, rtol=1e-5, atol=1e-6 * np.abs(queried).max())
    assert tracer.segments_kept == 4


def _replayed_against_finite_differences(loaded, integrator, field, rays, loss, largest, view=SCENE_VIEW):
    """The replayed gradient of ``loss(jones)`` over ``rays`` (seen in ``view``) against central differences: the
    gradients, how many entries were checked, and the traced rays. Traced as the optimiser traces: straight rays
    replay the segments their primal walk kept."""
    right = mi.Vector3f(1, 0, 0)

    def value(parameters):
        field.assign(parameters)
        with dr.suspend_grad():
            traced = integrator.tracer.trace_rays(loaded, rays, right, seed=5, field=field, view=view)
            return float(loss(traced.jones())[0])

    base = {name: type(v)(np.array(v)) for name, v in field.parameters().items()}
    variables = {name: type(v)(v) for name, v in base.items()}
    for v in variables.values():
        dr.enable_grad(v)
    field.assign(variables)
    traced = integrator.tracer.trace_rays(loaded, rays, right, seed=5, field=field, view=view, replayable=True)
    with dr.resume_grad():
        leaf = tuple(mi.Float(x) for x in traced.state)
        dr.enable_grad(leaf)
        dr.backward(loss(traced.jones(leaf)))
        state_grad = dr.grad(leaf)
    integrator.tracer.backpropagate_rays(loaded, rays, right, traced, state_grad, seed=5, field=field, view=view)
    field.finish_backward()
    gradients = {name: np.array(dr.grad(v)).ravel() for name, v in variables.items()}
    return gradients, _matches_finite_differences(value, base, gradients, largest), traced


def _matches_finite_differences(value, base, gradients, largest):
    """Each parameter's ``largest`` gradient entries against central differences of ``value``; the count."""
    checked = 0
    for name, gradient in gradients.items():
        flat = np.array(base[name]).ravel()
        for index in np.argsort(-np.abs(gradient))[:largest]:
            step = 1e-2 * max(1.0, abs(flat[index]))
            shifted = []
            for sign in (1, -1):
                moved = flat.copy()
                moved[index] += sign * step
                shifted.append(value({**base, name: type(base[name])(moved.reshape(np.shape(base[name])))}))
            finite_difference = (shifted[0] - shifted[1]) / (2 * step)
            assert float(gradient[index]) == pytest.approx(finite_difference, rel=0.03,
                                                           abs=2e-3 * float(np.abs(gradient).max()))
            checked += 1
    return checked


@pytest.mark.filterwarnings("ignore:photoelastic. fringes denser")
def test_render_backward_matches_finite_differences(tmp_path):
    """``mi.render`` then ``dr.backward`` on a grid medium: the Mitsuba way of differentiating."""
    rng = np.random.default_rng(1)
    np.savez(tmp_path / "grid.npz", stress=rng.normal(0, 3, (4, 4, 4, 6)).astype(np.float32),
             bbox_min=[-2.0, -2, -2], bbox_max=[2.0, 2, 2])
    loaded = scene([box((4, 4, 4), interior={"type": "stress", "filename": str(tmp_path / "grid.npz"),
                                             "stress_optic_coefficient": 50.0})],
                   res=4, view=2.2, step=0.3, input_qwp=45.0, output_qwp=0.0, analyzer=45.0, origin=(20, 30, 100))
    params = mi.traverse(loaded)
    key = next(k for k in params.keys() if k.endswith("stress"))
    names = loaded.integrator().aov_names()
    weights = np.zeros(1 + len(names), dtype=np.float32)
    weights[0] = 1.0
    for i, name in enumerate(names):
        if name.startswith(("pol.", "jones.")):
            weights[1 + i] = 0.1 * (i % 5 + 1)
    base = np.array(params[key])

    def value(stress):
        params[key] = mi.TensorXf(stress)
        params.update()
        with dr.suspend_grad():
            image = mi.render(loaded, params, seed=2).numpy()
        return float((image * weights).sum())

    dr.enable_grad(params[key])
    params.update()
    image = mi.render(loaded, params, seed=2)
    dr.backward(dr.sum(image * mi.TensorXf(np.broadcast_to(weights, image.shape).copy()), axis=None))
    gradient = np.array(dr.grad(params[key]))
    for index in list(zip(*np.unravel_index(np.argsort(-np.abs(gradient).ravel())[:4], gradient.shape))):
        moved = [base.copy(), base.copy()]
        moved[0][index] += 1e-2
        moved[1][index] -= 1e-2
        finite_difference = (value(moved[0]) - value(moved[1])) / 2e-2
        assert float(gradient[index]) == pytest.approx(finite_difference, rel=0.03)


def test_rk4_has_no_adjoint_and_auto_needs_one_camera():
    loaded = _specimen()
    rays, _ = _batch()
    rk4 = Tracer(TracerConfig(method="rk4"))
    traced = rk4.trace_rays(loaded, rays, mi.Vector3f(1, 0, 0))
    with pytest.raises(ValueError, match="not unitary"):
        rk4.backpropagate_rays(loaded, rays, mi.Vector3f(1, 0, 0), traced, traced.state)
    with pytest.raises(ValueError, match="explicit method"):
        Tracer(TracerConfig(method="auto")).trace_rays(loaded, rays, mi.Vector3f(1, 0, 0))


@pytest.mark.parametrize("method", ["product", "magnus4"])
def test_replayed_gradient_through_refracting_surfaces_matches_finite_differences(method):
    """A glass box (n = 1.55) turned 20 degrees: each segment's product is differentiated inside the path's
    general Jones matrix, the Fresnel matrices and the bent geometry held fixed (docs/refraction.md)."""
    from mi_nest.reconstruct.losses import intensities
    glass = {"type": "cube",
             "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], 20.0).scale([2.0, 2.0, 2.0]),
             "bsdf": {"type": "dielectric", "int_ior": 1.55, "ext_ior": 1.0},
             "interior": {"type": "stress", "model": "uniform", "stress_optic_coefficient": 50.0}}
    loaded = scene([glass], res=2, view=2.5)
    integrator = mi.load_dict({"type": "photoelastic", "method": method, "step_size": 0.4, "jitter": True,
                               "max_bounces": 0})
    field = _field("grid")
    rays, _ = _batch()
    weights = [mi.Float(w) for w in np.random.default_rng(11).normal(size=(16, RAYS)).astype(np.float32)]

    def loss(matrix):
        return sum(dr.sum(w * x) for w, x in zip(weights, intensities(matrix)))

    gradients, checked, traced = _replayed_against_finite_differences(loaded, integrator, field, rays, loss, largest=6)
    assert checked == 6 and traced.kind is PathKind.REFRACTED and len(traced.state) == 8     # a general Jones matrix
    assert np.abs(gradients["grid"]).max() > 1e-3


@pytest.mark.parametrize("part", ["ghost", "both"])
def test_replayed_gradient_of_the_ghosts_matches_finite_differences(part):
    """With ``max_bounces`` a ray batch carries a sampled ghost path (partly reflected) beside the transmitted
    one; the replay walks it again with the same choices. n = 3 (R = 0.25 at normal incidence): the ghosts
    are strong enough to be differentiated on their own."""
    from mi_nest.reconstruct.losses import intensities
    glass = {"type": "cube",
             "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], 20.0).scale([2.0, 2.0, 2.0]),
             "bsdf": {"type": "dielectric", "int_ior": 3.0, "ext_ior": 1.0},
             "interior": {"type": "stress", "model": "uniform", "stress_optic_coefficient": 50.0}}
    loaded = scene([glass], res=2, view=2.5)
    integrator = mi.load_dict({"type": "photoelastic", "step_size": 0.4, "jitter": True, "max_bounces": 2})
    field = _field("grid")
    rays, _ = _batch()
    weights = [mi.Float(w) for w in np.random.default_rng(12).normal(size=(16, RAYS)).astype(np.float32)]

    def loss(matrix):
        assert isinstance(matrix, jones.Incoherent)
        return sum(dr.sum(w * x) for w, x in zip(weights, intensities(matrix[1] if part == "ghost" else matrix)))

    gradients, checked, traced = _replayed_against_finite_differences(loaded, integrator, field, rays, loss, largest=6)
    # The transmitted path's and the ghost's Jones matrices.
    assert checked == 6 and traced.kind is PathKind.GHOSTED and len(traced.state) == 16
    ghost = np.array(traced.state[8:])
    assert 0 < np.count_nonzero(np.abs(ghost).sum(axis=0)) < RAYS     # some rays took a partial reflection
    assert np.abs(gradients["grid"]).max() > 1e-4


@pytest.mark.parametrize("method, bounces", [("product", 0), ("magnus4", 0), ("product", 2)])
def test_replayed_gradient_of_a_spectral_march_through_refracting_surfaces_matches_finite_differences(method,
                                                                                                      bounces):
    """Three wavelengths along one bent path (a glass box, n = 1.55, turned 20 degrees; with bounces, n = 3 and
    sampled ghosts): each wavelength's general Jones matrix weighted on its own, the replay back-propagating
    every wavelength's adjoint into the one march of the lanes."""
    from mi_nest.reconstruct.losses import intensities
    glass = {"type": "cube",
             "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], 20.0).scale([2.0, 2.0, 2.0]),
             "bsdf": {"type": "dielectric", "int_ior": 3.0 if bounces else 1.55, "ext_ior": 1.0},
             "interior": {"type": "stress", "model": "uniform", "stress_optic_coefficient": 50.0}}
    loaded = scene([glass], res=2, view=2.5)
    integrator = mi.load_dict({"type": "photoelastic", "method": method, "step_size": 0.4, "jitter": True,
                               "max_bounces": bounces})
    field = _field("grid")
    rays, _ = _batch()
    view = View(lanes=(("short", 1.3), ("middle", 1.0), ("long", 0.75)))
    rng = np.random.default_rng(13)
    weights = [[mi.Float(w) for w in rng.normal(size=(16, RAYS)).astype(np.float32)] for _ in view.lanes]

    def loss(lanes):
        assert len(lanes) == 3
        return sum(dr.sum(w * x) for matrix, lane_weights in zip(lanes, weights)
                   for w, x in zip(lane_weights, intensities(matrix)))

    gradients, checked, traced = _replayed_against_finite_differences(loaded, integrator, field, rays, loss,
                                                                      largest=6, view=view)
    assert checked == 6 and traced.lanes == 3
    assert traced.kind is (PathKind.GHOSTED if bounces else PathKind.REFRACTED)
    assert len(traced.state) == 3 * (16 if bounces else 8)
    assert np.abs(gradients["grid"]).max() > 1e-3


def test_linear_gradients_through_refracting_surfaces_are_refused():
    glass = {**box((4, 4, 4), interior={"type": "stress", "model": "uniform", "stress_optic_coefficient": 50.0}),
             "bsdf": {"type": "dielectric", "int_ior": 1.55, "ext_ior": 1.0}}
    loaded = scene([glass], res=2, view=2.5)
    tracer = Tracer(TracerConfig(method="linear", step_size=0.4))
    rays, _ = _batch()
    traced = tracer.trace_rays(loaded, rays, mi.Vector3f(1, 0, 0))
    with pytest.raises(ValueError, match="gradients through refracting surfaces need 'product' or 'magnus4'"):
        tracer.backpropagate_rays(loaded, rays, mi.Vector3f(1, 0, 0), traced,
                                  tuple(mi.Float(0) for _ in traced.state))


def test_replayed_gradient_of_the_neighbour_loss_matches_finite_differences():
    """The neighbour loss (reconstruct/neighbours.py) compares the rotation between two rays' Jones matrices with a
    measured one: its gradient reaches both rays of each pair through the replay."""
    from mi_nest.reconstruct.neighbours import relative_rotation_loss
    loaded = _specimen()
    integrator = mi.load_dict({"type": "photoelastic", "method": "product", "step_size": 0.4, "jitter": True,
                               "max_bounces": 0})
    field = _field("grid")
    rays, _ = _batch()
    pairs = RAYS // 2
    measured = np.random.default_rng(5).normal(size=(pairs, 4))
    measured /= np.linalg.norm(measured, axis=1, keepdims=True)

    def loss(q):
        index = dr.arange(mi.UInt32, pairs)
        return relative_rotation_loss(tuple(dr.gather(mi.Float, x, index) for x in q),
                                      tuple(dr.gather(mi.Float, x, index + pairs) for x in q), measured)

    gradients, checked, _ = _replayed_against_finite_differences(loaded, integrator, field, rays, loss, largest=4)
    assert checked >= 4
    assert max(np.abs(g).max() for g in gradients.values()) > 1e-3
