"""Closed-form stress library: equilibrium, the tractions of each load case, Dr.Jit, plugin loading.

Every model is checked in a tilted, off-centre frame so that frame mistakes show up,
with NumPy evaluation in float64 (fast); the Dr.Jit path is compared to it in float32.
"""
import dataclasses
import math

import mitsuba as mi
import numpy as np
import pytest

import mi_nest  # noqa: F401  (selects llvm_ad_mono, registers the stress medium)
from mi_nest.fields import FieldParameterError
from mi_nest.fields.analytic import (MODELS, BeamBendingField, BoussinesqField, DiskCompressionField,
                                     KirschPlateField, LameCylinderField, ShaftTorsionField,
                                     StackedDisksField)
from scenes import box, medium, render
from test_fields import divergence

LAME = LameCylinderField(inner_radius=8.0, outer_radius=20.0, internal_pressure=12.0,
                         external_pressure=3.0, axial_factor=1.0, center=(1.0, -2.0, 3.0),
                         axis=(0.3, -0.2, 1.0))
TORSION = ShaftTorsionField(radius=6.0, torque=5.0e4, center=(2.0, 1.0, -1.0), axis=(1.0, 0.5, 0.2))
BEAM = BeamBendingField(width=8.0, height=14.0, moment=2.0e5, center=(0.0, 1.0, 2.0),
                        axis=(1.0, 0.2, -0.1), height_direction=(0.0, 1.0, 0.3))
KIRSCH = KirschPlateField(radius=4.0, tension=15.0, center=(1.0, 2.0, 0.0), axis=(0.1, 0.2, 1.0),
                          load_direction=(1.0, 1.0, 0.0))
BOUSSINESQ = BoussinesqField(load=800.0, poisson_ratio=0.27, origin=(1.0, -1.0, 2.0),
                             axis=(0.2, 0.1, -1.0))
STACK = StackedDisksField(diameter=30.0, thickness=5.0, load=700.0, count=3.0, gap=1.5,
                          angle_step=35.0, center=(0.5, 0.0, -3.0), axis=(0.1, 0.2, 1.0),
                          load_direction=(0.0, 1.0, 0.0))

MODEL_NAMES = {LameCylinderField: "lame_cylinder", ShaftTorsionField: "shaft_torsion",
               BeamBendingField: "beam_bending", KirschPlateField: "kirsch_plate",
               BoussinesqField: "boussinesq", StackedDisksField: "stacked_disks"}


# --- helpers ------------------------------------------------------------------------------------

def tensor(s6):
    """(..., 3, 3) matrices from a 6-tuple (xx, yy, zz, yz, zx, xy)."""
    xx, yy, zz, yz, zx, xy = (np.asarray(s, float) for s in s6)
    return np.stack([np.stack([xx, xy, zx], -1), np.stack([xy, yy, yz], -1),
                     np.stack([zx, yz, zz], -1)], -2)


def at(origin, frame, *coordinates):
    """Points ``origin + sum_i c_i frame[i]`` as a tuple of three NumPy arrays."""
    coordinates = np.broadcast_arrays(*(np.asarray(c, float) for c in coordinates))
    return tuple(origin[k] + sum(c * e[k] for c, e in zip(coordinates, frame)) for k in range(3))


def direction(frame, *coefficients):
    """(..., 3) vectors ``sum_i c_i frame[i]``."""
    coefficients = np.broadcast_arrays(*(np.asarray(c, float) for c in coefficients))
    return sum(c[..., None] * np.array(e) for c, e in zip(coefficients, frame))


def traction(field, points, normals):
    return np.einsum("...ij,...j->...i", tensor(field.eval(points)), normals)


def unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def rotate(v, axis, degrees):
    """Rodrigues rotation of ``v`` about the unit ``axis``."""
    v, axis, t = np.asarray(v, float), unit(axis), math.radians(degrees)
    return v * math.cos(t) + np.cross(axis, v) * math.sin(t) + axis * (axis @ v) * (1 - math.cos(t))


RNG = np.random.default_rng(11)
N = 200


def interior_points(field):
    """Random points well inside the material (farther than the FD step from any mask edge)."""
    u = RNG.uniform(0, 1, (3, N))
    angle = 2 * np.pi * u[1]
    if isinstance(field, LameCylinderField):
        r = field.inner_radius + 0.2 + (field.outer_radius - field.inner_radius - 0.4) * u[0]
        return at(field.center, field.frame, r * np.cos(angle), r * np.sin(angle), 20 * u[2] - 10)
    if isinstance(field, ShaftTorsionField):
        r = (field.radius - 0.2) * np.sqrt(u[0])
        return at(field.center, field.frame, r * np.cos(angle), r * np.sin(angle), 20 * u[2] - 10)
    if isinstance(field, BeamBendingField):
        return at(field.center, field.frame, 40 * u[0] - 20, (field.height - 0.4) * (u[1] - 0.5),
                  (field.width - 0.4) * (u[2] - 0.5))
    if isinstance(field, KirschPlateField):
        r = field.radius * (1.05 + 5 * u[0])
        return at(field.center, field.frame, r * np.cos(angle), r * np.sin(angle), 4 * u[2] - 2)
    if isinstance(field, BoussinesqField):
        r = 10 * u[0]
        return at(field.origin, field.frame, r * np.cos(angle), r * np.sin(angle), 0.5 + 10 * u[2])
    if isinstance(field, StackedDisksField):
        r = 0.6 * 0.5 * field.diameter * np.sqrt(u[0])   # the disk regularises r^4 near its load points
        k = RNG.integers(0, int(field.count), N)
        w = k * (field.thickness + field.gap) + (field.thickness - 0.2) * (u[2] - 0.5)
        return at(field.center, field.frame, r * np.cos(angle), r * np.sin(angle), w)
    raise TypeError(field)


def stress_scale(field):
    """(stress, length) scales of each load case, for relative tolerances."""
    if isinstance(field, LameCylinderField):
        return max(field.internal_pressure, field.external_pressure), field.outer_radius - field.inner_radius
    if isinstance(field, ShaftTorsionField):
        return 2 * field.torque / (math.pi * field.radius ** 3), field.radius
    if isinstance(field, BeamBendingField):
        return 6 * field.moment / (field.width * field.height ** 2), field.height
    if isinstance(field, KirschPlateField):
        return field.tension, field.radius
    if isinstance(field, BoussinesqField):
        return field.load / (2 * math.pi * 0.5 ** 2), 0.5    # at the shallowest test depth
    if isinstance(field, StackedDisksField):
        return 8 * field.load / (math.pi * field.diameter * field.thickness), 0.05 * field.diameter
    raise TypeError(field)


FIELDS = [LAME, TORSION, BEAM, KIRSCH, BOUSSINESQ, STACK]
IDS = [MODEL_NAMES[type(f)] for f in FIELDS]


def test_every_new_model_is_registered():
    for cls, name in MODEL_NAMES.items():
        assert MODELS[name] is cls


# --- (1) equilibrium ----------------------------------------------------------------------------

@pytest.mark.parametrize("field", FIELDS, ids=IDS)
def test_equilibrium(field):
    points = interior_points(field)
    stress, length = stress_scale(field)
    assert np.max(np.abs(tensor(field.eval(points)))) > 0.1 * stress     # not trivially zero
    div = np.max(np.abs(divergence(field, points, h=1e-5)))
    # Measured 1e-11 .. 4e-7 (the disks' own r^4 regularisation); a wrong sign or factor gives O(1).
    assert div < 1e-5 * stress / length


# --- (2) the boundary tractions of each load case -----------------------------------------------

def test_lame_pressures_on_the_walls_and_end_cap_balance():
    field, axis = LAME, LAME.frame[2]
    a, b = field.inner_radius, field.outer_radius
    p_i, p_o = field.internal_pressure, field.external_pressure
    angle = np.linspace(0, 2 * np.pi, 25)
    for r, pressure in ((a * (1 + 1e-12), p_i), (b * (1 - 1e-12), p_o)):
        points = at(field.center, field.frame, r * np.cos(angle), r * np.sin(angle), 3.0)
        n = direction(field.frame, np.cos(angle), np.sin(angle))
        np.testing.assert_allclose(traction(field, points, n), -pressure * n, atol=1e-9 * p_i)
    # Closed ends: the axial stress over the wall balances the pressures on the end cap.
    nodes, weights = np.polynomial.legendre.leggauss(8)
    r = a + (b - a) * 0.5 * (nodes + 1)
    points = at(field.center, field.frame, r, 0 * r, 0 * r)
    s_zz = np.einsum("i,...ij,j->...", axis, tensor(field.eval(points)), axis)
    force = np.sum(weights * 0.5 * (b - a) * 2 * np.pi * r * s_zz)
    assert force == pytest.approx(math.pi * (p_i * a ** 2 - p_o * b ** 2), rel=1e-12)
    # Open ends (default): no axial stress; no stress in the bore or outside the wall.
    open_ends = dataclasses.replace(field, axial_factor=0.0)
    assert np.max(np.abs(np.einsum("i,...ij,j->...", axis, tensor(open_ends.eval(points)), axis))) < 1e-12
    outside = at(field.center, field.frame, np.array([0.0, 0.5 * a, 1.01 * b, 3 * b]), 0.0, 1.0)
    assert np.all(tensor(field.eval(outside)) == 0)


def test_torsion_free_lateral_surface_and_resultant_torque():
    field, axis = TORSION, TORSION.frame[2]
    R, T = field.radius, field.torque
    J = 0.5 * math.pi * R ** 4
    angle = np.linspace(0, 2 * np.pi, 25)
    rim = R * (1 - 1e-12)
    points = at(field.center, field.frame, rim * np.cos(angle), rim * np.sin(angle), 2.0)
    n = direction(field.frame, np.cos(angle), np.sin(angle))
    assert np.max(np.abs(traction(field, points, n))) < 1e-9 * T * R / J
    # ... while the surface carries the full shear T R / J along e_theta on a cross-section.
    e_theta = direction(field.frame, -np.sin(angle), np.cos(angle))
    np.testing.assert_allclose(traction(field, points, np.array(axis)), T * R / J * e_theta, rtol=1e-9,
                               atol=1e-12 * T * R / J)
    # Resultants over a cross-section (normal +axis): zero force, moment T about the axis.
    nodes, weights = np.polynomial.legendre.leggauss(10)
    r = 0.5 * R * (nodes + 1)
    theta = np.linspace(0, 2 * np.pi, 32, endpoint=False)
    r, theta = np.meshgrid(r, theta)
    area = np.broadcast_to(0.5 * R * weights * r * (2 * np.pi / 32), r.shape)[..., None]
    points = at(field.center, field.frame, r * np.cos(theta), r * np.sin(theta), 0.0)
    t = traction(field, points, np.array(axis))
    arm = direction(field.frame, r * np.cos(theta), r * np.sin(theta))
    np.testing.assert_allclose(np.sum(t * area, axis=(0, 1)), 0.0, atol=1e-9 * T / R)
    np.testing.assert_allclose(np.sum(np.cross(arm, t) * area, axis=(0, 1)), T * np.array(axis), rtol=1e-9,
                               atol=1e-9 * T)


def test_bending_free_faces_and_resultant_moment():
    field, (e_x, e_y, e_z) = BEAM, BEAM.frame
    b, h, M = field.width, field.height, field.moment
    I = b * h ** 3 / 12
    s = np.linspace(-0.5, 0.5, 11)
    for side in (-1, 1):
        top = at(field.center, field.frame, 3.0, side * 0.5 * h * (1 - 1e-12), s * b)
        assert np.max(np.abs(traction(field, top, side * np.array(e_y)))) < 1e-9 * M * h / I
        # ... and the extreme fibre carries the flexure stress -M y / I.
        fibre = traction(field, top, np.array(e_x)) @ e_x
        np.testing.assert_allclose(fibre, -side * M * 0.5 * h / I, rtol=1e-9)
        lateral = at(field.center, field.frame, 3.0, s * h, side * 0.5 * b * (1 - 1e-12))
        assert np.max(np.abs(traction(field, lateral, side * np.array(e_z)))) < 1e-9 * M * h / I
    # Resultants on the section facing +x: no force, moment M about e_z.
    nodes, weights = np.polynomial.legendre.leggauss(6)
    y, z = np.meshgrid(0.5 * h * nodes, 0.5 * b * nodes)
    area = np.outer(0.5 * b * weights, 0.5 * h * weights)[..., None]
    t = traction(field, at(field.center, field.frame, -7.0, y, z), np.array(e_x))
    arm = direction(field.frame, 0 * y, y, z)
    np.testing.assert_allclose(np.sum(t * area, axis=(0, 1)), 0.0, atol=1e-9 * M / h)
    np.testing.assert_allclose(np.sum(np.cross(arm, t) * area, axis=(0, 1)), M * np.array(e_z), rtol=1e-12,
                               atol=1e-9 * M)


def test_kirsch_free_hole_concentration_and_remote_tension():
    field, (e1, _, axis) = KIRSCH, KIRSCH.frame
    a, S = field.radius, field.tension
    angle = np.linspace(0, 2 * np.pi, 37)
    edge = a * (1 + 1e-12)
    points = at(field.center, field.frame, edge * np.cos(angle), edge * np.sin(angle), 0.5)
    n = direction(field.frame, np.cos(angle), np.sin(angle))
    assert np.max(np.abs(traction(field, points, n))) < 1e-9 * S
    # Hoop stress at the hole: S (1 - 2 cos 2theta): 3S across the load, -S along it.
    e_theta = direction(field.frame, -np.sin(angle), np.cos(angle))
    hoop = np.einsum("...i,...ij,...j->...", e_theta, tensor(field.eval(points)), e_theta)
    np.testing.assert_allclose(hoop, S * (1 - 2 * np.cos(2 * angle)), atol=1e-9 * S)
    # Far away: uniaxial S along the load direction (error ~ a^2/r^2).
    far = at(field.center, field.frame, 100 * a * np.cos(angle), 100 * a * np.sin(angle), -1.0)
    remote = S * np.outer(e1, e1)
    assert np.max(np.abs(tensor(field.eval(far)) - remote)) < 1e-3 * S
    # Plane stress everywhere; nothing inside the hole.
    assert np.max(np.abs(traction(field, interior_points(field), np.array(axis)))) < 1e-12 * S
    hole = at(field.center, field.frame, 0.9 * a * np.cos(angle), 0.9 * a * np.sin(angle), 0.0)
    assert np.all(tensor(field.eval(hole)) == 0)
    # Polar form agrees with the Cartesian evaluation.
    r, theta = 1.7 * a, 0.3
    s_rr, s_tt, t_rt = field.polar_stress(r, theta)
    e_r = direction(field.frame, math.cos(theta), math.sin(theta))
    e_t = direction(field.frame, -math.sin(theta), math.cos(theta))
    sigma = tensor(field.eval(at(field.center, field.frame, r * math.cos(theta), r * math.sin(theta), 0.0)))
    np.testing.assert_allclose([e_r @ sigma @ e_r, e_t @ sigma @ e_t, e_r @ sigma @ e_t], [s_rr, s_tt, t_rt],
                               rtol=1e-12, atol=1e-12 * S)


def test_boussinesq_free_surface_and_load_carried_at_depth():
    field, axis = BOUSSINESQ, BOUSSINESQ.frame[2]
    P, nu = field.load, field.poisson_ratio
    r = np.geomspace(0.5, 20, 20)
    angle = RNG.uniform(0, 2 * np.pi, 20)
    surface = at(field.origin, field.frame, r * np.cos(angle), r * np.sin(angle), 1e-12)
    t = traction(field, surface, np.array(axis))
    assert np.max(np.abs(t) * r[:, None] ** 2) < 1e-9 * P
    # ... where the radial stress is (1 - 2 nu) P / (2 pi r^2) (and the hoop stress its opposite).
    e_r = direction(field.frame, np.cos(angle), np.sin(angle))
    radial = np.einsum("...i,...ij,...j->...", e_r, tensor(field.eval(surface)), e_r)
    np.testing.assert_allclose(radial, (1 - 2 * nu) * P / (2 * math.pi * r ** 2),
                               rtol=10 * (field.core_radius / r[0]) ** 2)    # the core's 3 (c/r)^2
    # Nothing above the surface.
    assert np.all(tensor(field.eval(at(field.origin, field.frame, r, 0.0, -0.1))) == 0)
    # Any plane at depth d carries the load: integral of sigma . axis = -P axis.
    for d in (0.5, 3.0):
        s = np.linspace(0, math.asinh(1e4), 4001)                 # r = d sinh(s), graded
        theta = np.linspace(0, 2 * np.pi, 8, endpoint=False)
        s, theta = np.meshgrid(s, theta)
        rr = d * np.sinh(s)
        points = at(field.origin, field.frame, rr * np.cos(theta), rr * np.sin(theta), d)
        density = traction(field, points, np.array(axis)) * (rr * d * np.cosh(s))[..., None]
        force = np.trapezoid(density, s[0], axis=1).mean(axis=0) * 2 * np.pi
        np.testing.assert_allclose(force, -P * np.array(axis), atol=1e-2 * P)


def test_boussinesq_stress_is_hookes_law_on_boussinesqs_displacement():
    """Independent check of the nu terms: strain of u_r, u_z (Johnson eq. 3.19) through Hooke's law."""
    field = BoussinesqField(load=500.0, poisson_ratio=0.21, core_radius=1e-9)
    G, nu, P = 1.0, field.poisson_ratio, field.load
    lam = 2 * G * nu / (1 - 2 * nu)

    def displacement(x, y, z):
        rho = np.sqrt(x * x + y * y + z * z)
        k = P / (4 * math.pi * G)
        radial_over_r = k * (z / rho ** 3 - (1 - 2 * nu) / (rho * (rho + z)))
        return x * radial_over_r, y * radial_over_r, k * (z * z / rho ** 3 + 2 * (1 - nu) / rho)

    points = [RNG.uniform(-4, 4, 50), RNG.uniform(-4, 4, 50), RNG.uniform(0.5, 5, 50)]
    h = 1e-5
    grad = np.zeros((50, 3, 3))
    for j in range(3):
        plus, minus = [p.copy() for p in points], [p.copy() for p in points]
        plus[j] += h
        minus[j] -= h
        grad[:, :, j] = (np.stack(displacement(*plus), -1) - np.stack(displacement(*minus), -1)) / (2 * h)
    strain = 0.5 * (grad + grad.transpose(0, 2, 1))
    hooke = lam * np.trace(strain, axis1=1, axis2=2)[:, None, None] * np.eye(3) + 2 * G * strain
    # The field's default axis is (0, 0, -1): map depth z to -z.
    got = tensor(field.eval((points[0], points[1], -points[2])))
    flip = np.diag([1.0, 1.0, -1.0])
    np.testing.assert_allclose(flip @ got @ flip, hooke, atol=1e-6 * P)


def test_stacked_disks_are_rotated_frocht_disks_with_empty_gaps():
    field, (e1, e2, _) = STACK, STACK.frame
    t, pitch = field.thickness, field.thickness + field.gap
    reference = unit(field.load_direction)
    for k in range(int(field.count)):
        center = np.array(field.center) + k * pitch * unit(field.axis)
        disk = DiskCompressionField(field.diameter, t, field.load, tuple(center), field.axis,
                                    tuple(rotate(reference, field.axis, k * field.angle_step)))
        u = RNG.uniform(0, 1, (3, 100))
        r, angle, w = 13 * np.sqrt(u[0]), 2 * np.pi * u[1], k * pitch + (t - 0.02) * (u[2] - 0.5)
        points = at(field.center, field.frame, r * np.cos(angle), r * np.sin(angle), w)
        np.testing.assert_allclose(tensor(field.eval(points)), tensor(disk.eval(points)), rtol=1e-12,
                                   atol=1e-12 * field.load)
        np.testing.assert_allclose(tensor(field.disk_field(k).eval(points)), tensor(disk.eval(points)),
                                   rtol=1e-12, atol=1e-12 * field.load)
    # Principal directions at the disk centres turn by angle_step from one disk to the next.
    centres = at(field.center, field.frame, 0.0, 0.0, pitch * np.arange(int(field.count)))
    values, vectors = np.linalg.eigh(tensor(field.eval(centres)))
    compressive = vectors[:, :, 0]                               # most compressive: the load line
    load_angle = np.degrees(np.arctan2(compressive @ e2, compressive @ e1))
    turn = (np.diff(load_angle) + 90) % 180 - 90
    np.testing.assert_allclose(turn, field.angle_step, atol=1e-9)
    assert values[:, 2] - values[:, 0] == pytest.approx(np.full(3, stress_scale(field)[0]), rel=1e-7)
    # Zero stress in the gaps and beyond both ends of the stack.
    w = np.concatenate([k * pitch + 0.5 * t + field.gap * np.array([0.05, 0.5, 0.95]) for k in range(2)]
                       + [[-0.5 * t - 0.01, -5.0, 2 * pitch + 0.5 * t + 0.01, 40.0]])
    gaps = at(field.center, field.frame, 2.0 + 0 * w, -3.0, w)
    assert np.all(tensor(field.eval(gaps)) == 0)


# --- (3) Dr.Jit evaluation matches NumPy to float32 precision -----------------------------------

@pytest.mark.parametrize("field", FIELDS, ids=IDS)
def test_drjit_matches_numpy(field):
    points = np.stack(interior_points(field)).astype(np.float32)
    expected = np.stack(field.eval(tuple(points.astype(np.float64))))
    got = np.stack([np.array(s, dtype=np.float64) for s in field.eval(mi.Point3f(points))])
    stress, _ = stress_scale(field)
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-5 * stress)


def test_singular_points_are_finite_in_both_backends():
    """The axis of the bore/hole, the Boussinesq load point and the disks' load points."""
    R = 0.5 * STACK.diameter
    cases = [(LAME, at(LAME.center, LAME.frame, [0.0, 0.0], 0.0, [0.0, 5.0])),
             (KIRSCH, at(KIRSCH.center, KIRSCH.frame, [0.0, 0.0], 0.0, [0.0, 5.0])),
             (BOUSSINESQ, at(BOUSSINESQ.origin, BOUSSINESQ.frame, 0.0, 0.0, [0.0, 2.0, -1.0])),
             (STACK, at(STACK.center, STACK.frame, 0.0, [R, -R], 0.0))]
    for field, points in cases:
        expected = tensor(field.eval(points))
        got = tensor([np.array(s, dtype=np.float64)
                      for s in field.eval(mi.Point3f(np.stack(points).astype(np.float32)))])
        assert np.all(np.isfinite(expected)) and np.all(np.isfinite(got)), field
    assert np.all(tensor(LAME.eval(cases[0][1])) == 0) and np.all(tensor(KIRSCH.eval(cases[1][1])) == 0)
    # Boussinesq: finite at the load point, exact (to the core) on the load line below it.
    sigma = tensor(BOUSSINESQ.eval(cases[2][1]))
    axis = np.array(BOUSSINESQ.frame[2])
    assert axis @ sigma[1] @ axis == pytest.approx(-3 * BOUSSINESQ.load / (2 * math.pi * 2.0 ** 2), rel=1e-8)
    assert np.all(sigma[2] == 0)


# --- (4) loading through the stress medium; bad parameters --------------------------------------

def parameters(field):
    return {f.name: getattr(field, f.name) for f in dataclasses.fields(field) if f.init}


@pytest.mark.parametrize("field", FIELDS, ids=IDS)
def test_loads_through_the_stress_medium(field):
    medium = mi.load_dict({"type": "stress", "model": MODEL_NAMES[type(field)],
                           "stress_optic_coefficient": 50.0, **parameters(field)})
    assert medium.field == field
    points = np.stack(interior_points(field)).astype(np.float32)
    got = np.stack([np.array(s, dtype=np.float64) for s in medium.stress(mi.Point3f(points))])
    stress, _ = stress_scale(field)
    np.testing.assert_allclose(got, np.stack(field.eval(tuple(points.astype(np.float64)))), rtol=1e-5,
                               atol=1e-5 * stress)


ORDER = "'inner_radius'.*smaller than 'outer_radius'"
BAD = [
    ("lame_cylinder", {"inner_radius": -1.0}, "'inner_radius' must be positive"),
    ("lame_cylinder", {"inner_radius": 20.0, "outer_radius": 10.0}, ORDER),
    ("lame_cylinder", {"inner_radius": 10.0, "outer_radius": 10.0}, ORDER),
    ("lame_cylinder", {"internal_pressure": math.inf}, "'internal_pressure' must be finite"),
    ("shaft_torsion", {"radius": -2.0}, "'radius' must be positive"),
    ("shaft_torsion", {"axis": (0.0, 0.0, 0.0)}, "'axis' must be a non-zero vector"),
    ("beam_bending", {"height": 0.0}, "'height' must be positive"),
    ("beam_bending", {"width": -3.0}, "'width' must be positive"),
    ("beam_bending", {"height_direction": (2.0, 0.0, 0.0)}, "'height_direction' must not be parallel"),
    ("kirsch_plate", {"radius": -1.0}, "'radius' must be positive"),
    ("kirsch_plate", {"load_direction": (0.0, 0.0, 1.0)}, "'load_direction' must not be parallel"),
    ("boussinesq", {"poisson_ratio": 0.7}, r"'poisson_ratio' must be in \(-1, 0.5\]"),
    ("boussinesq", {"core_radius": 0.0}, "'core_radius' must be positive"),
    ("stacked_disks", {"count": 0.0}, "'count' must be a whole number >= 1"),
    ("stacked_disks", {"count": 1.5}, "'count' must be a whole number >= 1"),
    ("stacked_disks", {"gap": -1.0}, "'gap' must not be negative"),
    ("stacked_disks", {"thickness": -6.0}, "'thickness' must be positive"),
]


@pytest.mark.parametrize("name, params, message", BAD, ids=[f"{b[0]}-{next(iter(b[1]))}" for b in BAD])
def test_bad_parameters_are_named(name, params, message):
    with pytest.raises(FieldParameterError, match=message):
        MODELS[name](**params)
    with pytest.raises(RuntimeError, match=f"model '{name}'.*{message}"):
        mi.load_dict({"type": "stress", "model": name, "stress_optic_coefficient": 50.0, **params})


@pytest.mark.parametrize("field", FIELDS, ids=IDS)
def test_renders_through_the_photoelastic_integrator(field):
    interior = medium(MODEL_NAMES[type(field)], C=1.0, **parameters(field))
    channels = render([box((30, 30, 20), interior=interior)], res=8, view=14.0, step=0.25)
    assert all(np.all(np.isfinite(np.asarray(v))) for v in channels.values())
    assert np.max(channels["char.delta"]) > 0.1


def test_stacked_disks_spread_their_loads_like_single_disks():
    stack = StackedDisksField(diameter=40.0, thickness=6.0, load=300.0, count=2.0, angle_step=45.0,
                              contact_width=4.0)
    for k in range(2):
        disk = stack.disk_field(k)
        assert disk.contact_width == 4.0
        u = RNG.uniform(0, 1, (3, 100))
        r, angle, w = 19.5 * np.sqrt(u[0]), 2 * np.pi * u[1], k * 6.0 + 5.9 * (u[2] - 0.5)
        points = at(stack.center, stack.frame, r * np.cos(angle), r * np.sin(angle), w)
        np.testing.assert_allclose(tensor(stack.eval(points)), tensor(disk.eval(points)), rtol=1e-9, atol=1e-9)


def test_a_contact_width_spreads_the_load_and_keeps_it():
    point = DiskCompressionField(diameter=40.0, thickness=6.0, load=1000.0)
    spread = DiskCompressionField(diameter=40.0, thickness=6.0, load=1000.0, contact_width=4.0)
    x = np.linspace(-20.0, 20.0, 400_001)
    # The load crosses the horizontal diameter whole: the integral of s_y over it is -P / t.
    for disk in (point, spread):
        assert np.trapezoid(disk.plane_stress(x, np.zeros_like(x))[1], x) == pytest.approx(-1000.0 / 6.0, rel=1e-6)
    # Saint-Venant: far from the contacts the two agree; at the contact the pressure stays bounded.
    u = RNG.uniform(0, 1, (2, 200))
    r, angle = 8.0 * np.sqrt(u[0]), 2 * np.pi * u[1]
    far = [np.stack(d.plane_stress(r * np.cos(angle), r * np.sin(angle))) for d in (point, spread)]
    np.testing.assert_allclose(far[1], far[0], atol=0.02 * np.abs(far[0]).max())
    depth = np.linspace(0.5, 3.0, 20)
    under = spread.plane_stress(np.zeros_like(depth), 20.0 - depth)[1]
    pressure = 1000.0 / (4.0 * 6.0)
    assert np.all(np.abs(under) < 1.5 * pressure) and np.abs(under).max() > 0.5 * pressure
    assert np.abs(point.plane_stress(np.zeros(1), np.array([19.5]))[1][0]) > 4 * pressure   # 1/r: 212 MPa
    with pytest.raises(FieldParameterError, match="contact_width"):
        DiskCompressionField(contact_width=50.0)
    assert np.all(np.isfinite(np.array(spread.eval((np.zeros(3), np.full(3, 20.0), np.zeros(3))))))
