"""The pure math against NumPy/SciPy: exponentials, products, invariants, polariscope."""
import itertools

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from scipy.linalg import expm

import mi_nest  # noqa: F401
from mi_nest.physics import MEASUREMENTS, Polariscope, projection, su2
from mi_nest.physics.polariscope import (ANALYZERS, INPUT_QWP_SETTINGS, OUTPUT_QWP_SETTINGS, Compensator, Polarizer,
                                         Waveplate, half_wave_plate, linear_polarizer, parse_optics,
                                         quarter_wave_plate, rotation, standard_polariscope)

SIGMA_X = np.array([[0, 1], [1, 0]])
SIGMA_Z = np.array([[1, 0], [0, -1]])
rng = np.random.default_rng(7)


def random_quaternions(n):
    q = rng.normal(size=(4, n))
    return tuple(q / np.linalg.norm(q, axis=0))


def to_drjit(values):
    return tuple(mi.Float(np.asarray(v, dtype=np.float32)) for v in values)


def test_step_is_the_exact_exponential_of_the_generator():
    p, q, phase = rng.normal(size=50) * 3, rng.normal(size=50) * 3, rng.uniform(0, 2, size=50)
    J = su2.to_matrix(su2.step(p, q, phase))
    for i in range(50):
        expected = expm(-1j * phase[i] * (p[i] * SIGMA_Z + q[i] * SIGMA_X))
        np.testing.assert_allclose(J[i], expected, atol=1e-12)


def test_cos_sinc_series_and_trigonometric_branches_agree_with_numpy():
    x = np.concatenate([[0.0, 1e-20, 1e-6], np.linspace(0.01, 40.0, 4001)])
    expected_sinc = np.sinc(x / np.pi)
    cos_x, sinc_x = su2.cos_sinc(x * x)
    np.testing.assert_allclose(cos_x, np.cos(x), atol=1e-8)
    np.testing.assert_allclose(sinc_x, expected_sinc, atol=1e-8)
    # float32 packets that mix both branches (x^2 on either side of the series limit).
    cos_x, sinc_x = su2.cos_sinc(mi.Float((x * x).astype(np.float32)))
    tolerance = 2e-7 * np.maximum(1.0, x)   # float32 resolution of x itself
    assert np.all(np.abs(np.array(cos_x) - np.cos(x)) <= tolerance)
    assert np.all(np.abs(np.array(sinc_x) - expected_sinc) <= tolerance)


def test_step_at_zero_and_tiny_stress_is_identity_to_first_order():
    a, b, c, d = su2.step(np.array([0.0, 1e-7]), np.array([0.0, 0.0]), 1.0)
    np.testing.assert_allclose(a, 1.0)
    np.testing.assert_allclose(c, [0.0, -1e-7], rtol=1e-9)


def test_quaternion_product_matches_matrix_product_and_conjugate_inverts():
    q1, q2 = random_quaternions(20), random_quaternions(20)
    product = su2.to_matrix(su2.multiply(q1, q2))
    np.testing.assert_allclose(product, su2.to_matrix(q1) @ su2.to_matrix(q2), atol=1e-12)
    identity = su2.to_matrix(su2.multiply(q1, su2.conjugate(q1)))
    np.testing.assert_allclose(identity, np.broadcast_to(np.eye(2), identity.shape), atol=1e-12)
    np.testing.assert_allclose(np.stack(su2.from_matrix(su2.to_matrix(q1))), np.stack(q1), atol=1e-12)


def test_retarder_and_rotator_are_the_physics_conventions():
    delta, theta, gamma = 1.1, 0.3, 0.7
    expected = rotation(np.rad2deg(theta)) @ np.diag([np.exp(-0.5j * delta), np.exp(0.5j * delta)]) \
        @ rotation(-np.rad2deg(theta))
    np.testing.assert_allclose(su2.to_matrix(su2.retarder(delta, theta)), expected, atol=1e-12)
    np.testing.assert_allclose(su2.to_matrix(su2.rotator(gamma)), rotation(np.rad2deg(gamma)), atol=1e-12)


@pytest.mark.parametrize("backend", ["numpy", "drjit"])
def test_characteristic_parameters_round_trip(backend):
    n = 500
    delta = rng.uniform(0.01, 2 * np.pi - 0.01, n)
    theta = rng.uniform(0.01, np.pi - 0.01, n)
    gamma = rng.uniform(-0.5 * np.pi + 0.01, 0.5 * np.pi - 0.01, n)
    args = (delta, theta, gamma) if backend == "numpy" else to_drjit((delta, theta, gamma))
    q = su2.multiply(su2.rotator(args[2]), su2.retarder(args[0], args[1]))
    recovered = [np.asarray(x, dtype=np.float64) for x in su2.characteristic_parameters(q)]
    tol = 1e-9 if backend == "numpy" else 2e-3
    for got, want in zip(recovered, (delta, theta, gamma)):
        np.testing.assert_allclose(got, want, atol=tol)


def test_characteristic_invariants_of_long_products():
    q = su2.identity(np.zeros(100))
    for _ in range(30):
        q = su2.multiply(q, su2.step(rng.normal(size=100), rng.normal(size=100), 0.3))
    delta, theta, gamma = su2.characteristic_parameters(q)
    a, b, c, d = q
    np.testing.assert_allclose(np.cos(delta / 2) * np.cos(gamma), a, atol=1e-12)
    np.testing.assert_allclose(np.sin(delta / 2) ** 2, b * b + c * c, atol=1e-12)
    rebuilt = su2.multiply(su2.rotator(gamma), su2.retarder(delta, theta))
    np.testing.assert_allclose(np.stack(rebuilt), np.stack(q), atol=1e-12)


@dr.syntax
def _long_product(p, q, phase, steps, renormalize):
    result = su2.identity(mi.Float(0) * p)
    i = mi.UInt32(0)
    while i < steps:
        result = su2.multiply(result, su2.step(p + 1e-3 * mi.Float(i), q, phase))
        if dr.hint(renormalize, mode="scalar"):
            result = su2.renormalize(result)
        i += 1
    return result


def test_float32_products_of_ten_thousand_steps_stay_unitary():
    p, q = mi.Float(rng.normal(size=256)), mi.Float(rng.normal(size=256))
    drift = {}
    for renormalize in (False, True):
        result = _long_product(p, q, mi.Float(0.37), mi.UInt32(10_000), renormalize)
        drift[renormalize] = float(dr.max(dr.abs(su2.norm_squared(result) - 1.0))[0])
    assert drift[True] < 1e-6
    # Without the correction float32 rounding accumulates; the renderer always renormalises.
    assert drift[False] > drift[True]


def test_drjit_and_numpy_agree_on_every_function():
    p, q, phase = rng.normal(size=64), rng.normal(size=64), rng.uniform(0, 1, 64)
    u, v = projection.transverse_basis(tuple(np.array([[0.0], [0.6], [0.8]]) + 0 * p),
                                       tuple(np.array([[1.0], [0.0], [0.0]]) + 0 * p))
    s6 = tuple(rng.normal(size=64) for _ in range(6))
    numpy_results = {
        "step": su2.step(p, q, phase),
        "project": projection.project(s6, u, v),
        "char": su2.characteristic_parameters(su2.multiply(su2.step(p, q, phase), su2.step(q, p, phase))),
        "intensity": tuple(MEASUREMENTS.values())[5].intensity(su2.step(p, q, phase)),
    }
    P, Q, PH = to_drjit((p, q, phase))
    U, V, S6 = to_drjit(u), to_drjit(v), to_drjit(s6)
    drjit_results = {
        "step": su2.step(P, Q, PH),
        "project": projection.project(S6, U, V),
        "char": su2.characteristic_parameters(su2.multiply(su2.step(P, Q, PH), su2.step(Q, P, PH))),
        "intensity": tuple(MEASUREMENTS.values())[5].intensity(su2.step(P, Q, PH)),
    }
    for name, expected in numpy_results.items():
        got = drjit_results[name]
        np.testing.assert_allclose(np.array(got, dtype=np.float64), np.array(expected), atol=2e-5, err_msg=name)


def test_projection_matches_explicit_matrix_products():
    S = rng.normal(size=(3, 3))
    S = S + S.T
    k = np.array([0.3, -0.5, 0.8])
    k /= np.linalg.norm(k)
    u, v = projection.transverse_basis(tuple(k), (1.0, 0.0, 0.0))
    u, v = np.array(u), np.array(v)
    np.testing.assert_allclose(np.cross(u, v), k, atol=1e-12)
    s6 = (S[0, 0], S[1, 1], S[2, 2], S[1, 2], S[2, 0], S[0, 1])
    p, q = projection.project(s6, u, v)
    assert p == pytest.approx(u @ S @ u - v @ S @ v)
    assert q == pytest.approx(2 * u @ S @ v)
    # Adding p I (the trace ambiguity) changes nothing.
    p2, q2 = projection.project(tuple(x + (3.0 if i < 3 else 0.0) for i, x in enumerate(s6)), u, v)
    assert (p2, q2) == pytest.approx((p, q))


def test_polariscope_elements():
    np.testing.assert_allclose(linear_polarizer(30) @ linear_polarizer(30), linear_polarizer(30), atol=1e-15)
    # Two QWPs at the same angle are a half-wave plate: 90-degree light turns to 0 under a 45-degree HWP.
    hwp = quarter_wave_plate(45) @ quarter_wave_plate(45)
    np.testing.assert_allclose(np.abs(hwp @ np.array([0, 1])), [1, 0], atol=1e-15)


def test_sixteen_intensities_match_direct_jones_calculus():
    q = random_quaternions(50)
    J = su2.to_matrix(q)
    settings = itertools.product(INPUT_QWP_SETTINGS, OUTPUT_QWP_SETTINGS, ANALYZERS)
    for (b1, b2, a2), (name, scope) in zip(settings, MEASUREMENTS.items()):
        assert name == f"pol.{b1}.{b2}.{a2}"
        expected = np.sum(np.abs(np.einsum("ij,njk,k->ni", scope.output_rows(), J, scope.input_state())) ** 2, axis=1)
        direct = np.array([np.abs(linear_polarizer(a2) @ quarter_wave_plate(b2) @ J[i]
                                  @ quarter_wave_plate(b1) @ np.array([0, 1])) ** 2
                           for i in range(50)]).sum(axis=1)
        np.testing.assert_allclose(scope.intensity(q), expected, atol=1e-12, err_msg=name)
        np.testing.assert_allclose(scope.intensity(q), direct, atol=1e-12, err_msg=name)
    assert len(MEASUREMENTS) == 16 and "pol.45.0.135" in MEASUREMENTS


def test_free_space_and_dark_field_closed_forms():
    free = su2.identity(np.zeros(1))
    assert standard_polariscope(90, None, None, 90).intensity(free) == pytest.approx(1.0)
    assert standard_polariscope(90, None, None, 0).intensity(free) == pytest.approx(0.0)
    assert standard_polariscope(90).intensity(free) == pytest.approx(1.0)   # no analyser: lossless
    delta = rng.uniform(0, 4 * np.pi, 100)
    q = su2.multiply(su2.rotator(rng.uniform(-1, 1, 100)), su2.retarder(delta, rng.uniform(0, 3, 100)))
    dark_field = standard_polariscope(90, 45, 135, 0)
    np.testing.assert_allclose(dark_field.intensity(q), np.sin(delta / 2) ** 2, atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 30.0, -70.0])
def test_the_textbook_polariscopes_give_their_closed_forms(angle):
    from mi_nest.physics.polariscope import polariscope_setting
    rng = np.random.default_rng(3)
    delta, theta = rng.uniform(0, 2 * np.pi, 200), rng.uniform(0, np.pi, 200)
    q = su2.retarder(delta, theta)
    relative = theta - np.radians(angle)
    circular_dark = np.sin(delta / 2) ** 2
    linear_dark = np.sin(2 * relative) ** 2 * np.sin(delta / 2) ** 2
    for kind, field, expected in (("circular", "dark", circular_dark), ("circular", "light", 1 - circular_dark),
                                  ("linear", "dark", linear_dark), ("linear", "light", 1 - linear_dark)):
        scope = polariscope_setting(kind, field, angle)
        np.testing.assert_allclose(scope.intensity(q), expected, atol=1e-12)
        # The same through the full Jones matrices (NumPy, element by element).
        for i in range(3):
            amplitude = scope.matrix(su2.to_matrix(tuple(x[i] for x in q)))
            assert abs(np.sum(np.abs(amplitude) ** 2) - expected[i]) < 1e-12
    assert polariscope_setting() == standard_polariscope(90.0, 45.0, 135.0, 0.0)    # the shipped scenes'
    with pytest.raises(ValueError, match="choose one of circular, linear"):
        polariscope_setting("elliptic")


def test_a_half_wave_plate_mirrors_linear_light_about_its_fast_axis():
    """Linear light at ``a`` leaves a half-wave plate at ``h`` linear at ``2h - a``: behind an analyser at ``b``,
    ``cos^2(2h - a - b)`` (Hecht, section 8.7), through free space and through a specimen seen by the rig."""
    rng = np.random.default_rng(5)
    free = su2.identity(np.zeros(1))
    for a, h, b in rng.uniform(-180, 180, (20, 3)):
        scope = Polariscope((Polarizer(a), half_wave_plate(h)), (Polarizer(b),))
        expected = np.cos(np.radians(2 * h - a - b)) ** 2
        assert float(scope.intensity(free)[0]) == pytest.approx(expected, abs=1e-12)
    # A half-wave plate at 22.5 degrees turns the rig's polariser from 90 to -45: the same as a polariser there.
    q = random_quaternions(30)
    turned = Polariscope((Polarizer(90.0), half_wave_plate(22.5), Waveplate(45.0)), (Waveplate(0.0), Polarizer(45.0)))
    direct = standard_polariscope(-45.0, 45.0, 0.0, 45.0)
    np.testing.assert_allclose(turned.intensity(q), direct.intensity(q), atol=1e-12)


def test_a_babinet_soleil_compensator_cancels_the_retardance_it_is_set_to():
    """Crossed polarisers at 45 degrees to a retarder's axes; a compensator with its fast axis along the
    retarder's slow axis at retardance ``c``: ``I = sin^2((delta - c) / 2)``, dark where it cancels the
    specimen (the compensation method: the position that darkens a point reads its fringe order)."""
    rng = np.random.default_rng(6)
    delta, theta = rng.uniform(0, 4 * np.pi, 50), rng.uniform(0, np.pi, 50)
    rate, positions = 360.0, rng.uniform(0, 2, 50)         # degrees per mm, mm
    for d, t, x in zip(delta, theta, positions):
        # su2.retarder's angle is sigma_1's, the slow axis (docs/physics.md): the compensator's fast axis there.
        q = su2.retarder(np.array([d]), np.array([t]))
        fast = np.degrees(t)
        scope = Polariscope((Polarizer(fast + 45.0),), (Compensator(fast, rate, x), Polarizer(fast - 45.0)))
        expected = np.sin((d - np.radians(rate * x)) / 2) ** 2
        assert float(scope.intensity(q)[0]) == pytest.approx(expected, abs=1e-12)
    # Set to the specimen's retardance, it extinguishes: the reading is the fringe order, fractions included.
    q = su2.retarder(np.array([2.6 * 2 * np.pi]), np.array([0.3]))
    reading = Compensator(np.degrees(0.3), rate, 2.6)
    nulled = Polariscope((Polarizer(np.degrees(0.3) + 45.0),), (reading, Polarizer(np.degrees(0.3) - 45.0)))
    assert reading.retardance == pytest.approx(360.0 * 2.6) and float(nulled.intensity(q)[0]) < 1e-20


def test_any_ordered_optics_give_the_direct_jones_product():
    """Elements in any order, a polariser between others included (its two-row projector), against the product
    of their Jones matrices."""
    q = random_quaternions(20)
    J = su2.to_matrix(q)
    light = (Polarizer(10.0), Waveplate(30.0, 75.0), half_wave_plate(-20.0))
    camera = (Compensator(50.0, 200.0, 0.3), Polarizer(70.0), Waveplate(15.0, 120.0))
    scope = Polariscope(light, camera)
    e = linear_polarizer(10.0)[:, 0] / np.cos(np.radians(10.0))           # the unit state behind the polariser
    for element in light[1:]:
        e = element.matrix() @ e
    after = np.eye(2)
    for element in camera:
        after = element.matrix() @ after
    direct = np.sum(np.abs(np.einsum("ij,njk,k->ni", after, J, e)) ** 2, axis=1)
    np.testing.assert_allclose(scope.intensity(q), direct, atol=1e-12)
    assert parse_optics(scope.describe().split(" | ")[2]) == camera         # what describe() writes reads back


def test_optics_read_from_text_and_refuse_what_is_not_an_element():
    assert parse_optics("polarizer 90; hwp 22.5;qwp 45 ; waveplate 30 120; compensator 45 360 0.5") == (
        Polarizer(90.0), Waveplate(22.5, 180.0), Waveplate(45.0, 90.0), Waveplate(30.0, 120.0),
        Compensator(45.0, 360.0, 0.5))
    assert parse_optics("") == ()
    for text, message in (("lens 3", "unknown optical element 'lens'"), ("hwp", "hwp takes angle"),
                          ("qwp 1 2 3", "qwp takes angle retardance"), ("polarizer x", "give numbers after 'polarizer'"),
                          ("polarizer nan", "must be finite")):
        with pytest.raises(ValueError, match=message):
            parse_optics(text)
    with pytest.raises(ValueError, match="starts with its polariser"):
        Polariscope((Waveplate(45.0),), ())
