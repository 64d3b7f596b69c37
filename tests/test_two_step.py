"""The Two-step baseline: per-pixel Jones recovery, per-view unwrapping, linear tomography."""
import warnings

import numpy as np
import pytest

import mi_nest
from mi_nest.physics import MEASUREMENTS, su2
from mi_nest.physics.polariscope import ANALYZERS, measurement_name
from mi_nest.physics.recovery import quaternion_from_intensities, quaternion_from_rotation, rotation_matrix
from mi_nest.reconstruct import optimize
from mi_nest.reconstruct.two_step import unwrapped_generator


def _random_quaternions(count, seed=1):
    q = np.random.default_rng(seed).normal(size=(count, 4))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _jones_calculus_intensities(q):
    """The 16 intensities by explicit 2x2 complex matrices: independent of the quadratic forms recovery inverts."""
    J = su2.to_matrix(tuple(q.T))
    return np.stack([(np.abs(scope.matrix(J)) ** 2).sum(axis=(-2, -1)) for scope in MEASUREMENTS.values()], -1)


def _same_up_to_sign(p, q):
    return np.abs(np.abs((p * q).sum(-1)) - 1.0)


def test_rotation_and_quaternion_round_trip():
    q = _random_quaternions(1000)
    R = rotation_matrix(q)
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    # Quaternion products compose the rotations.
    p = _random_quaternions(1000, seed=2)
    pq = np.stack(su2.multiply(tuple(p.T), tuple(q.T)), -1)
    np.testing.assert_allclose(rotation_matrix(pq), rotation_matrix(p) @ R, atol=1e-12)
    assert _same_up_to_sign(quaternion_from_rotation(R), q).max() < 1e-12


def test_the_sixteen_intensities_give_back_the_jones_quaternion():
    q = _random_quaternions(5000)
    recovered = quaternion_from_intensities(_jones_calculus_intensities(q))
    assert _same_up_to_sign(recovered, q).max() < 1e-10
    assert (recovered[:, 0] >= 0).all()
    # In any order, as a dataset's channels come.
    shuffled = _jones_calculus_intensities(q)[:, ::-1]
    scopes = list(MEASUREMENTS.values())[::-1]
    assert _same_up_to_sign(quaternion_from_intensities(shuffled, scopes), q).max() < 1e-10


def test_a_calibrated_polariscope_is_inverted_as_built():
    """Waveplates of 88 and 92 degrees and an analyser 0.4 degrees off: the nominal model is biased, the
    calibrated one exact."""
    from mi_nest.physics.polariscope import (ANALYZERS, INPUT_QWP_SETTINGS, OUTPUT_QWP_SETTINGS, POLARIZER,
                                             standard_polariscope)
    q = _random_quaternions(2000)
    built = [standard_polariscope(POLARIZER, b1, b2, a2 + 0.4, 88.0, 92.0)
             for b1 in INPUT_QWP_SETTINGS for b2 in OUTPUT_QWP_SETTINGS for a2 in ANALYZERS]
    measured = np.stack([s.intensity(tuple(q.T)) for s in built], -1)
    assert _same_up_to_sign(quaternion_from_intensities(measured, built), q).max() < 1e-10
    assert _same_up_to_sign(quaternion_from_intensities(measured), q).max() > 1e-4


def test_recovery_under_read_noise_is_a_small_rotation():
    q = _random_quaternions(5000)
    noisy = _jones_calculus_intensities(q) + np.random.default_rng(3).normal(scale=0.01, size=(5000, 16))
    angle = 2 * np.arccos(np.clip(np.abs((quaternion_from_intensities(noisy) * q).sum(-1)), 0, 1))
    # 16 measurements of sigma 0.01 fix a rotation to about a hundredth of a radian.
    assert np.median(angle) < 0.03 and np.quantile(angle, 0.99) < 0.08


def test_recovery_refuses_measurements_that_cannot_fix_the_jones_matrix():
    one_exposure = [MEASUREMENTS[measurement_name(45, 0, a)] for a in ANALYZERS]
    with pytest.raises(ValueError, match="do not determine the Jones matrix"):
        quaternion_from_intensities(np.zeros((4, 4)), one_exposure)
    with pytest.raises(ValueError, match="do not determine the Jones matrix"):
        quaternion_from_intensities(np.zeros((4, 16)), [MEASUREMENTS["pol.45.0.0"]] * 16)
    with pytest.raises(ValueError, match="last axis"):
        quaternion_from_intensities(np.zeros((4, 12)))


def test_unwrapping_recovers_several_turns_of_a_smooth_field():
    y, x = np.mgrid[-1:1:96j, -1:1:96j]
    inside = x * x + y * y < 0.9
    # Retardance up to 6 pi at the centre, none at the rim; the axis turns by about a radian across.
    half = 3 * np.pi * np.clip(1 - (x * x + y * y) / 0.9, 0, None)
    axis = 0.5 * x + 0.3 * y + 0.2
    g = np.stack([half * np.cos(axis), half * np.sin(axis)], -1)
    q = np.stack(su2.exponential((0 * half, g[..., 0], g[..., 1], 0 * half)), -1)
    unwrapped = unwrapped_generator(q, inside)
    np.testing.assert_allclose(unwrapped[inside], g[inside], atol=1e-9)
    assert not unwrapped[~inside].any()


def test_unwrapping_a_rendered_disk_matches_its_fringe_order():
    """Along its axis the disk's steps commute: the product is the linear model and |g| = pi N."""
    scene = mi_nest.load_scene("disk_compression", res=64, load=150, contact_width=4)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        channels = mi_nest.render(scene, spp=1).channels
    q = quaternion_from_intensities(np.stack([channels[n] for n in MEASUREMENTS], -1))
    inside = channels["path.length"] > 0
    g = unwrapped_generator(q, inside)
    error = np.abs(np.linalg.norm(g, axis=-1) - np.pi * channels["fringe.order"]) * inside
    assert channels["fringe.order"].max() > 2           # several fringes to unwrap
    wrong = error > 1e-4
    assert wrong.sum() < 0.02 * inside.sum()
    # It fails only under the two contacts (top and bottom), where fringes crowd against the rim.
    rows = np.nonzero(wrong)[0]
    assert ((rows < 8) | (rows > 55)).all()
    # exp(g) is the measured Jones matrix, direction included.
    back = np.stack(su2.exponential((0 * g[..., 0], g[..., 0], g[..., 1], 0 * g[..., 0])), -1)
    assert np.quantile(np.abs(np.abs((back * q).sum(-1)) - 1)[inside], 0.99) < 1e-5


@pytest.fixture(scope="module")
def small_disk(tmp_path_factory):
    """A 2 x 2 rotation dataset of the disk over 4 mm contacts at 16x16, and its scene."""
    from mi_nest.dataset import SimulationSettings, simulate
    data = tmp_path_factory.mktemp("data") / "disk"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        simulate("disk_compression", data, SimulationSettings(azimuths=2, elevations=2, res=16, spp=1,
                                                              test_fraction=0.25),
                 progress=False, defines={"load": 100, "contact_width": 4})
    return data, mi_nest.load_scene("disk_compression", res=16, load=100, contact_width=4)


def test_two_step_reconstruction_fits_the_unwrapped_data(small_disk):
    data, scene = small_disk
    result = optimize(scene, data, progress=False, method="two-step", kind="grid", resolution=8, iterations=60,
                      batch_size=256, views_per_batch=3, learning_rate=0.1, pixel_samples=1, evaluate_views=1)
    losses = [h["loss"] for h in result.history]
    assert np.mean(losses[-10:]) < 0.4 * np.mean(losses[:5])
    assert result.metrics["deviatoric_error"] < 1.0
    assert result.tracer(scene).config.method == "linear"


def test_a_warm_start_fits_the_unwrapped_data_then_the_intensities(small_disk, monkeypatch):
    from mi_nest.reconstruct import loop
    data, scene = small_disk
    models = []
    original = loop.make_tracer

    def recording(config, field, scene_, method=None):
        tracer = original(config, field, scene_, method)
        models.append(tracer.config.method)
        return tracer

    monkeypatch.setattr(loop, "make_tracer", recording)     # a spy: the real tracers run
    result = optimize(scene, data, progress=False, warm_start=0.5, kind="grid", resolution=8, iterations=40,
                      batch_size=256, views_per_batch=3, learning_rate=0.1, pixel_samples=1, evaluate_views=1,
                      coarse_to_fine=False)
    assert models[:2] == ["linear", "product"]        # the Two-step fit, then the joint one
    assert np.isfinite(result.metrics["deviatoric_error"]) and result.tracer(scene).config.method == "product"
    with pytest.raises(ValueError, match="warm_start"):
        optimize(scene, data, progress=False, method="two-step", warm_start=0.3)
    with pytest.raises(ValueError, match="warm_start"):
        optimize(scene, data, progress=False, warm_start=1.0)


def test_the_closed_form_recovery_is_the_closest_rotation_and_its_polarisation_the_smaller_singular_value():
    """Against the orthogonal Procrustes solution by SVD of the partial map the measurements fix (and its second
    singular value), on noisy pixels and on pixels that average two Jones matrices."""
    from mi_nest.physics.recovery import _affine_model, jones_and_polarisation
    q, other = _random_quaternions(3000, seed=4), _random_quaternions(3000, seed=5)
    scopes = tuple(MEASUREMENTS.values())
    noisy = _jones_calculus_intensities(q) + np.random.default_rng(6).normal(scale=0.03, size=(3000, 16))
    averaged = (_jones_calculus_intensities(q) + _jones_calculus_intensities(other)) / 2
    offset, A = _affine_model(scopes)
    for values in (noisy, averaged):
        partial = ((values - offset) @ np.linalg.pinv(A, rcond=1e-9).T).reshape(-1, 3, 3)
        U, singular, Vt = np.linalg.svd(partial)
        flip = np.ones((len(values), 3))
        flip[:, 2] = np.sign(np.linalg.det(U @ Vt))
        closest = quaternion_from_rotation((U * flip[:, None, :]) @ Vt)
        recovered, polarisation = jones_and_polarisation(values, scopes)
        assert _same_up_to_sign(recovered, closest).max() < 1e-9
        np.testing.assert_allclose(polarisation, singular[:, 1], atol=1e-9)
    # Two Jones matrices averaged keep less of the light polarised than one does.
    assert np.median(polarisation) < 0.9
