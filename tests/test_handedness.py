"""Physical handedness: which axis is slow, which way angles turn, which circular light comes out.

Intensities are unchanged when every retarder is conjugated or every angle is
mirrored, so a simulation is self-consistent whatever its sign conventions; only
physics pins them (docs/physics.md section 1-2):

* fields vary as ``exp(+i omega t)``, so a lagging (slow) component gets a
  negative phase; angles turn from image right u towards image up v,
  counter-clockwise for an observer looking toward the source;
* a waveplate's angle is its fast axis;
* with a positive stress-optic coefficient (epoxy, glass) the larger principal
  stress is the slow axis: ``n1 - n2 = C (sigma1 - sigma2)``.

Two independent references pin them. pypolar (S. Prahl, MIT licence) documents
the same conventions (``exp(j(omega t - kz))``, looking back toward the source)
and writes its retarders by their fast axis. And the textbook case: linear light
at 45 degrees through a quarter-wave retarder whose fast axis is vertical (a bar
in tension along u: its slow axis) leaves with its vertical component a quarter
period ahead, so the field turns from v to u: clockwise for an observer looking
toward the source, right-circular in the optics convention (E. Hecht, *Optics*,
5th ed., section 8.1: "right-circular" light turns clockwise as seen by an
observer toward whom the wave moves). The rotation sense is computed from the
real field ``Re(E exp(i omega t))`` over one period, not from a formula that
already assumes a convention.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import mi_nest  # noqa: F401  (selects the variant, registers the plugins)
from mi_nest.physics import su2
from mi_nest.physics.polariscope import linear_polarizer, standard_polariscope, quarter_wave_plate, waveplate

from scenes import BREWSTER, WAVELENGTH, box, medium, render

jones = pytest.importorskip("pypolar.jones", reason="pypolar is a test dependency (pip install -e '.[test]')")

ANGLES = (-60.0, -15.0, 0.0, 22.5, 45.0, 90.0, 117.0)
# A slab in uniaxial tension sigma along u: a quarter-wave retarder (Delta = 2 pi C L sigma / lambda).
SLAB_LENGTH = 2.0                                                    # mm
QUARTER_WAVE_STRESS = WAVELENGTH / (4.0 * BREWSTER * SLAB_LENGTH)    # MPa, 1.33


def rotation_sense(field):
    """+1 if the real field turns counter-clockwise in the (u, v) plane (looking toward the source), -1 clockwise."""
    t = np.linspace(0.0, 2.0 * np.pi, 65)
    e_u, e_v = (np.real(component * np.exp(1j * t)) for component in field)     # exp(+i omega t)
    swept = np.sum(e_u[:-1] * e_v[1:] - e_v[:-1] * e_u[1:])                      # twice the signed area
    return int(np.sign(swept))


def equal_up_to_phase(a, b, atol=1e-12):
    """Jones matrices equal up to a global phase (which no intensity sees)."""
    k = np.unravel_index(np.argmax(np.abs(b)), b.shape)
    phase = a[k] / b[k]
    return abs(abs(phase) - 1.0) < atol and np.allclose(a, phase * b, atol=atol)


def stress_step(xx, yy, xy, length=SLAB_LENGTH):
    """The Jones matrix of a slab of in-plane stress (MPa) for light along k = u x v, C = BREWSTER."""
    phase = math.pi * BREWSTER * length / WAVELENGTH
    return su2.to_matrix(su2.step(np.float64(xx - yy), np.float64(2.0 * xy), phase))


@pytest.mark.parametrize("angle", ANGLES)
def test_polarisers_and_waveplates_match_pypolar(angle):
    """Polariser axis and waveplate fast axis at ``angle``, retardances of any sign and size."""
    t = math.radians(angle)
    np.testing.assert_allclose(linear_polarizer(angle), jones.op_linear_polarizer(t), atol=1e-12)
    assert equal_up_to_phase(quarter_wave_plate(angle), jones.op_quarter_wave_plate(t))
    for retardance in (30.0, 90.0, 180.0, 250.0):
        assert equal_up_to_phase(waveplate(angle, retardance), jones.op_retarder(t, math.radians(retardance)))


def test_our_quarter_wave_plate_had_its_slow_axis_at_beta_before():
    """The QWP before issue 18, ``R diag(1, i) R^T``, is pypolar's plate turned by 90 degrees."""
    old = quarter_wave_plate(30.0).conj()
    assert not equal_up_to_phase(old, jones.op_quarter_wave_plate(math.radians(30.0)))
    assert equal_up_to_phase(old, jones.op_quarter_wave_plate(math.radians(120.0)))


@pytest.mark.parametrize("xx, yy, xy", [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (-0.4, 0.9, 0.7), (2.0, -1.0, -0.6)])
def test_the_larger_principal_stress_is_the_slow_axis(xx, yy, xy):
    """A stressed slab is pypolar's retarder with its fast axis along sigma_2 (C > 0)."""
    sigma_mean, radius = 0.5 * (xx + yy), math.hypot(0.5 * (xx - yy), xy)
    sigma1_axis = 0.5 * math.atan2(2.0 * xy, xx - yy)
    delta = 2.0 * math.pi * BREWSTER * SLAB_LENGTH * (2.0 * radius) / WAVELENGTH
    assert sigma_mean + radius > sigma_mean - radius
    J = stress_step(xx, yy, xy)
    assert equal_up_to_phase(J, jones.op_retarder(sigma1_axis + 0.5 * math.pi, delta), atol=1e-9)
    assert not equal_up_to_phase(J, jones.op_retarder(sigma1_axis, delta), atol=1e-3)


def test_tension_bar_between_a_45_degree_polariser_turns_light_right_circular():
    """Hecht's case: quarter-wave, slow axis u (tension along u), linear light at 45 degrees."""
    incoming = np.array([1.0, 1.0]) / math.sqrt(2.0)
    tension = stress_step(QUARTER_WAVE_STRESS, 0.0, 0.0) @ incoming
    compression = stress_step(-QUARTER_WAVE_STRESS, 0.0, 0.0) @ incoming
    for field in (tension, compression):
        assert abs(abs(field[0]) - abs(field[1])) < 1e-12               # circular, not elliptical
    assert rotation_sense(tension) == -1                               # clockwise: right-circular
    assert rotation_sense(compression) == +1                           # counter-clockwise: left-circular
    assert "Right circular" in jones.interpret(tension)
    assert "Left circular" in jones.interpret(compression)
    # the plate with its fast axis at 0 (the same physical element as compression along u)
    assert rotation_sense(quarter_wave_plate(0.0) @ incoming) == +1


def test_the_renderer_shows_the_sign_of_the_stress_through_a_circular_analyser():
    """The whole pipeline: light at 45 degrees -> slab -> QWP fast at 0 -> analyser at 45.

    Right-circular light leaves the QWP linear at 45 degrees and passes the
    analyser; left-circular light is stopped. A bar in tension is bright, one in
    compression dark, and no stress gives the half of circular light.
    """
    intensities = {}
    for name, sigma in (("tension", QUARTER_WAVE_STRESS), ("compression", -QUARTER_WAVE_STRESS), ("free", 0.0)):
        slab = box((20.0, 20.0, SLAB_LENGTH), interior=medium(xx=sigma))
        channels = render([slab], polarizer=45.0, output_qwp=0.0, analyzer=45.0, step=0.25)
        intensities[name] = float(np.mean(channels["Y"]))
        scope = standard_polariscope(45.0, None, 0.0, 45.0)
        q = su2.from_matrix(stress_step(sigma, 0.0, 0.0))
        assert intensities[name] == pytest.approx(float(scope.intensity(q)), abs=1e-4)
    assert intensities["tension"] == pytest.approx(1.0, abs=1e-4)
    assert intensities["compression"] == pytest.approx(0.0, abs=1e-4)
    assert intensities["free"] == pytest.approx(0.5, abs=1e-4)


def test_datasets_simulated_with_the_old_handedness_are_refused(tmp_path):
    """A version-1 simulation shows the stress sign-flipped to today's model; a version-1 capture is physical."""
    import json

    from mi_nest.dataset import format as fmt
    from mi_nest.dataset.simulate import SimulationSettings, simulate

    simulate("disk_compression", tmp_path, SimulationSettings(azimuths=1, elevations=1, res=8, spp=1),
             progress=False)
    index = json.loads((tmp_path / fmt.INDEX).read_text())
    assert index["version"] == fmt.VERSION == 2
    (tmp_path / fmt.INDEX).write_text(json.dumps({**index, "version": 1}))
    with pytest.raises(fmt.DatasetError, match="QWP handedness.*simulate it again"):
        fmt.read_index(tmp_path)
    (tmp_path / fmt.INDEX).write_text(json.dumps({**index, "version": 1, "source": {"kind": "captured"}}))
    assert fmt.read_index(tmp_path)["version"] == 1
