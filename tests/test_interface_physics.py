"""A ray at a dielectric interface (docs/physics.md section 8): Fresnel coefficients against closed forms and
Mitsuba's own polarised Fresnel code, Snell's law, the transported frame, and general Jones matrices."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mi_nest.physics import interface, jones, su2
from mi_nest.physics.polariscope import MEASUREMENTS, rotation

ANGLES = np.deg2rad(np.linspace(0.0, 89.0, 90))


@pytest.mark.parametrize("n1, n2", [(1.0, 1.55), (1.55, 1.0), (1.33, 1.55), (1.55, 1.45)])
def test_coefficients_equal_mitsubas_polarised_fresnel(n1, n2):
    """Mitsuba's ``fresnel_polarized`` (its polarised renderer's) is an independent implementation: the same
    reflection amplitudes and phases, below and beyond the critical angle."""
    mi.set_variant("scalar_rgb")
    try:
        for angle in ANGLES:
            a_s, a_p, cos_t, _, _ = mi.fresnel_polarized(float(np.cos(angle)), n2 / n1)
            r_s, r_p, _, _ = interface.amplitude_coefficients(np.cos(angle), n1, n2)
            assert complex(a_s.real, a_s.imag) == pytest.approx(complex(r_s), abs=3e-5)
            assert complex(a_p.real, a_p.imag) == pytest.approx(complex(r_p), abs=3e-5)
            assert abs(float(cos_t)) == pytest.approx(np.real(interface.cos_transmitted(np.cos(angle), n1, n2)),
                                                      abs=2e-6)
    finally:
        mi.set_variant("llvm_ad_mono")


@pytest.mark.parametrize("n1, n2", [(1.0, 1.55), (1.55, 1.0), (1.33, 1.55)])
def test_reflected_and_transmitted_power_add_up_per_polarisation(n1, n2):
    r_s, r_p, tau_s, tau_p = interface.flux_coefficients(np.cos(ANGLES), n1, n2)
    np.testing.assert_allclose(np.abs(r_s) ** 2 + np.abs(tau_s) ** 2, 1.0, atol=1e-12)
    np.testing.assert_allclose(np.abs(r_p) ** 2 + np.abs(tau_p) ** 2, 1.0, atol=1e-12)


@pytest.mark.parametrize("n1, n2", [(1.0, 1.55), (1.55, 1.0), (1.33, 1.55), (1.55, 1.45)])
def test_the_walks_real_coefficients_equal_the_complex_ones_on_numpy_and_drjit(n1, n2):
    """What the renderer evaluates per crossing (real amplitudes below the critical angle, phases beyond it)
    is :func:`flux_coefficients`, on either backend."""
    r_s, r_p, tau_s, tau_p = interface.flux_coefficients(np.cos(ANGLES), n1, n2)
    total = np.abs(tau_s) == 0
    # Float32 near the critical angle, where cos_t has an infinite slope: 1e-5.
    for convert, atol in ((np.asarray, 1e-12), (lambda x: mi.Float(np.asarray(x, dtype=np.float32)), 1e-5)):
        cos_i, ratio = convert(np.cos(ANGLES)), n2 / n1
        got = [np.asarray(x, dtype=np.float64) for x in (*interface.reflected_amplitudes(cos_i, ratio),
                                                         *interface.transmitted_flux_amplitudes(cos_i, ratio),
                                                         *interface.reflection_phases(cos_i, ratio))]
        np.testing.assert_allclose(got[0][~total], np.real(r_s[~total]), atol=atol)
        np.testing.assert_allclose(got[1][~total], np.real(r_p[~total]), atol=atol)
        np.testing.assert_allclose(got[2], np.real(tau_s), atol=atol)
        np.testing.assert_allclose(got[3], np.real(tau_p), atol=atol)
        np.testing.assert_allclose(got[4][total], np.angle(r_s[total]), atol=atol)
        np.testing.assert_allclose(got[5][total], np.angle(r_p[total]), atol=atol)
    assert total.any() == (n1 > n2)


def test_normal_incidence_and_brewsters_angle_in_closed_form():
    n1, n2 = 1.0, 1.55
    r_s, r_p, t_s, t_p = interface.amplitude_coefficients(1.0, n1, n2)
    assert complex(r_s) == pytest.approx((n1 - n2) / (n1 + n2)) and complex(r_p) == pytest.approx(-complex(r_s))
    assert complex(t_s) == pytest.approx(2 * n1 / (n1 + n2)) == complex(t_p)
    _, _, tau_s, _ = interface.flux_coefficients(1.0, n1, n2)
    assert abs(complex(tau_s)) ** 2 == pytest.approx(4 * n1 * n2 / (n1 + n2) ** 2)
    brewster = interface.brewster_angle(n1, n2)
    assert np.rad2deg(brewster) == pytest.approx(57.17, abs=0.01)          # arctan(1.55)
    r_s, r_p, _, tau_p = interface.flux_coefficients(np.cos(brewster), n1, n2)
    assert abs(complex(r_p)) < 1e-12 and abs(complex(tau_p)) == pytest.approx(1.0)
    assert abs(complex(r_s)) > 0.2                                      # s still reflects: Brewster polarises
    # Inside the glass, towards air: Brewster at arctan(1 / 1.55), before the critical angle.
    assert interface.brewster_angle(n2, n1) < interface.critical_angle(n2, n1)


def test_total_internal_reflection_keeps_the_power_and_shifts_the_phases_as_a_fresnel_rhomb():
    n1, n2 = 1.51, 1.0
    critical = interface.critical_angle(n1, n2)
    beyond = np.linspace(critical + 1e-6, np.deg2rad(89.0), 50)
    r_s, r_p, tau_s, tau_p = interface.flux_coefficients(np.cos(beyond), n1, n2)
    np.testing.assert_allclose(np.abs(r_s), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.abs(r_p), 1.0, atol=1e-12)
    assert np.all(tau_s == 0) and np.all(tau_p == 0)
    phi_s, phi_p = interface.total_reflection_phases(np.cos(beyond), n1, n2)
    np.testing.assert_allclose(np.angle(r_s), phi_s, atol=1e-12)
    np.testing.assert_allclose(np.angle(r_p), phi_p, atol=1e-12)
    # Fresnel's rhomb (n = 1.51): 45 degrees between s and p at 48.6 and at 54.6 degrees of incidence
    # (Born and Wolf 1.5.4; Hecht 8.6), two reflections making a quarter wave.
    for angle in (48.6, 54.6):
        phi_s, phi_p = interface.total_reflection_phases(np.cos(np.deg2rad(angle)), n1, n2)
        assert np.rad2deg(phi_p - phi_s) == pytest.approx(45.0, abs=0.2)
    assert interface.critical_angle(1.0, 1.5) is None


@pytest.mark.parametrize("bad", [0.0, -1.5, float("nan")])
def test_an_index_that_is_not_positive_is_refused(bad):
    with pytest.raises(ValueError, match="refractive index n2 must be a positive number"):
        interface.amplitude_coefficients(1.0, 1.0, bad)


def _directions(count, seed):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(3, count))
    n = rng.normal(size=(3, count))
    return tuple(d / np.linalg.norm(d, axis=0)), tuple(n / np.linalg.norm(n, axis=0))


@pytest.mark.parametrize("backend", ["numpy", "drjit"])
def test_refraction_obeys_snells_law_in_the_plane_of_incidence(backend):
    d, n = _directions(500, 1)
    n1, n2 = 1.0, 1.55
    convert = (lambda x: x) if backend == "numpy" else (lambda x: mi.Float(np.asarray(x, dtype=np.float32)))
    for a, b in ((n1, n2), (n2, n1)):
        out, cos_i, total = interface.refract(tuple(map(convert, d)), tuple(map(convert, n)), a, b)
        out = np.array([np.asarray(x, dtype=np.float64) for x in out])
        cos_i, total = np.asarray(cos_i, dtype=np.float64), np.asarray(total, dtype=bool)
        tolerance = 1e-12 if backend == "numpy" else 2e-6
        np.testing.assert_allclose(np.linalg.norm(out, axis=0), 1.0, atol=tolerance)
        dd, nn = np.array(d), np.array(n)
        sin_i = np.linalg.norm(np.cross(dd.T, nn.T), axis=1)
        sin_o = np.linalg.norm(np.cross(out.T, nn.T), axis=1)
        np.testing.assert_allclose(np.abs(cos_i), np.abs(np.sum(dd * nn, axis=0)), atol=tolerance)
        # Snell where it refracts, the mirror where it cannot.
        np.testing.assert_allclose((a * sin_i)[~total], (b * sin_o)[~total], atol=10 * tolerance)
        np.testing.assert_allclose(sin_o[total], sin_i[total], atol=10 * tolerance)
        assert np.all(total == (a / b * sin_i > 1.0)) or backend == "drjit"
        # In the plane of incidence, and on across the surface (or back, when totally reflected).
        np.testing.assert_allclose(np.sum(np.cross(dd.T, nn.T) * out.T, axis=1), 0.0, atol=10 * tolerance)
        crossed = np.sign(np.sum(out * nn, axis=0)) == np.sign(np.sum(dd * nn, axis=0))
        assert np.all(crossed == ~total)


def test_the_transported_frame_stays_orthonormal_and_untwisted():
    d, n = _directions(300, 2)
    u = np.cross(np.array(d).T, np.random.default_rng(3).normal(size=(300, 3)))
    u = tuple((u / np.linalg.norm(u, axis=1)[:, None]).T)
    v = tuple(np.cross(np.array(d).T, np.array(u).T).T)
    out, _, _ = interface.refract(d, n, 1.0, 1.55)
    s = interface.s_axis(d, n, u)
    u2, v2 = interface.transported(u, d, out, s), interface.transported(v, d, out, s)
    U, V, D = np.array(u2).T, np.array(v2).T, np.array(out).T
    np.testing.assert_allclose(np.linalg.norm(U, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.sum(U * V, axis=1), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.cross(U, V), D, atol=1e-12)            # right-handed about the new ray
    # No twist: s has the same angle in both frames.
    np.testing.assert_allclose(interface.s_angle(u, v, s), interface.s_angle(u2, v2, s), atol=1e-12)
    # Straight on, nothing turns.
    same = interface.transported(u, d, d, s)
    np.testing.assert_allclose(np.array(same), np.array(u), atol=1e-12)


def test_the_interface_jones_matrix_acts_on_s_and_p_in_any_frame():
    """In a frame where s lies at angle a, the matrix is R(a) diag(t_s, t_p) R(-a): s light keeps its
    direction and takes t_s, p light t_p."""
    rng = np.random.default_rng(4)
    for _ in range(20):
        angle = rng.uniform(-np.pi, np.pi)
        t_s, t_p = complex(*rng.normal(size=2)), complex(*rng.normal(size=2))
        matrix = jones.to_matrix(jones.diattenuator(t_s, t_p, angle))
        s = np.array([np.cos(angle), np.sin(angle)])
        p = np.array([-np.sin(angle), np.cos(angle)])
        np.testing.assert_allclose(matrix @ s, t_s * s, atol=1e-12)
        np.testing.assert_allclose(matrix @ p, t_p * p, atol=1e-12)
        np.testing.assert_allclose(matrix, rotation(np.rad2deg(angle)) @ np.diag([t_s, t_p])
                                   @ rotation(-np.rad2deg(angle)), atol=1e-12)


def test_general_jones_products_and_intensities_equal_the_matrices():
    rng = np.random.default_rng(5)
    for _ in range(20):
        m1 = rng.normal(size=(2, 2)) + 1j * rng.normal(size=(2, 2))
        m2 = rng.normal(size=(2, 2)) + 1j * rng.normal(size=(2, 2))
        q = su2.from_matrix(rotation(30.0) @ np.diag([np.exp(0.3j), np.exp(-0.3j)]) @ rotation(-30.0))
        b1, b2 = jones.from_matrix(m1), jones.from_matrix(m2)
        np.testing.assert_allclose(jones.to_matrix(b1), m1, atol=1e-12)
        np.testing.assert_allclose(jones.to_matrix(jones.multiply(b1, b2)), m1 @ m2, atol=1e-12)
        np.testing.assert_allclose(jones.to_matrix(jones.multiply_unitary(q, b2)), su2.to_matrix(q) @ m2,
                                   atol=1e-12)
        for scope in MEASUREMENTS.values():
            expected = np.sum(np.abs(scope.matrix(m1)) ** 2)
            assert jones.intensity(scope.coefficients(), b1) == pytest.approx(expected, abs=1e-12)
    # A unitary matrix gives what the quaternion gives.
    q = su2.retarder(0.7, 0.2)
    for scope in MEASUREMENTS.values():
        assert jones.intensity(scope.coefficients(), jones.from_quaternion(q)) == pytest.approx(scope.intensity(q))


def test_general_jones_algebra_runs_on_drjit():
    angle = mi.Float([0.1, 0.5, -1.2])
    m = jones.diattenuator((mi.Float(0.9), mi.Float(0.1)), (mi.Float(0.7), mi.Float(-0.2)), angle)
    m = jones.multiply_unitary(su2.retarder(mi.Float(0.4), mi.Float(0.3)), m)
    scope = next(iter(MEASUREMENTS.values()))
    values = jones.intensity(scope.coefficients(), m)
    for i, a in enumerate([0.1, 0.5, -1.2]):
        matrix = su2.to_matrix(su2.retarder(0.4, 0.3)) @ rotation(np.rad2deg(a)) @ np.diag([0.9 + 0.1j, 0.7 - 0.2j]) \
            @ rotation(-np.rad2deg(a))
        assert values[i] == pytest.approx(np.sum(np.abs(scope.matrix(matrix)) ** 2), abs=1e-5)
    assert dr.width(values) == 3
