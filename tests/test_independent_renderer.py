"""Cross-check mi_nest against an independent renderer: Mitsuba's own polarised path tracer.

The specimen is a piecewise-constant stress field: three disjoint slabs (thin
boxes stacked along z with air gaps), each with a different uniform in-plane
stress, so each is a linear retarder (docs/physics.md section 2) and the stack is a
general, non-commuting product. mi_nest renders it (``photoelastic``
integrator, ``llvm_ad_mono``) in an orthographic polariscope looking along -z;
the main channel ``Y`` uses a generic polariscope (LP1 20, QWP1 65, QWP2 10,
LP2 115) and ``pol.<b1>.<b2>.<a2>`` are the 16 measurements of section 6.

The reference renders the optically equivalent stack of thin rectangles with
Mitsuba's ``polarizer`` and ``retarder`` BSDFs in ``llvm_ad_mono_polarized``
(Mueller calculus, ``tests/polarized_reference.py``, in a subprocess because
variants cannot be mixed in one process): unpolarised area light -> LP1 ->
QWP1 -> one retarder per slab (in the order light meets them) -> QWP2 -> LP2
-> orthographic camera. Both renderers are exact for this field, so they must
agree to float32 round-off; a third, tiny Jones-calculus evaluation of the
docs/physics.md ODE (matrix exponential of its generator) pins the reference itself.

Convention mapping (light along +z, rectangles facing +z, image right u = +x,
image up v = +y; an element "at angle t" has its axis at t from u towards v,
counter-clockwise looking toward the source, docs/physics.md section 1). Mitsuba's
``retarder`` documents its fast axis along the rectangle's U and ``delta`` as the
phase difference between fast and slow axes, so each element maps by what it is:

* linear polariser at alpha          -> ``polarizer`` with its rectangle rotated by alpha
* QWP, fast axis at beta              -> ``retarder delta=90``, fast axis (rectangle) at beta
* slab, retardance Delta, its larger
  principal stress (slow axis) at theta -> ``retarder delta=Delta``, fast axis at theta + 90
* unpolarised light loses half at LP1: intensities are divided by a render of
  free space between parallel polarisers (0.5), which is 1 by docs/physics.md.

Intensities alone fix this mapping only up to two symmetries that leave every
intensity unchanged: mirroring all angles at once (t -> -t for every element,
the slabs' axes included, which are fixed by the world-frame stress and so do
not follow a mirrored polariscope) and conjugating all retarders at once
(delta -> -delta for every retarder: the choice of time convention, which no
intensity can see). What the comparison pins down is therefore physical and
relative: the slabs' slow axis is their larger principal stress when the QWPs'
angle is their fast axis (the model before issue 18 had it the other way:
``sigma1_fast`` below), angles turn the same way as the rectangles' rotation
about the direction of propagation, and the slabs act in the order light meets
them. Each of these is shown to change some channel by far more than the
tolerance.

Mitsuba's ``theta`` parameters can replace the rotations (the ``mapped`` set),
with one sign that is Mitsuba's own: in Mitsuba 3.9.1 a retarder's ``theta`` turns
its axis like a rotation of its rectangle, a polariser's ``theta`` the other way
(from U towards -V, whichever way the rectangle faces). The ``mapped`` set
therefore uses ``polarizer theta=-alpha`` and ``retarder theta=+t``.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import pytest
from scipy.linalg import expm

import mi_nest  # noqa: F401  (selects llvm_ad_mono and registers the plugins)
import mitsuba as mi

REFERENCE_SCRIPT = Path(__file__).with_name("polarized_reference.py")

STRESS_OPTIC_COEFFICIENT = 50.0   # Brewster
WAVELENGTH = 532.0                # nm, the stress medium's default
GAP = 0.5                         # mm of air between slabs
FILM_SIZE = 8
TOLERANCE = 1e-3                  # both renderers are exact up to float32 round-off
# A convention error must move some channel by far more than the tolerance.
SENSITIVITY = 0.05


@dataclass(frozen=True)
class Slab:
    """A slab of uniform stress (MPa, 3D-TSV order) and its thickness along z (mm)."""
    thickness: float
    xx: float = 0.0
    yy: float = 0.0
    zz: float = 0.0
    yz: float = 0.0
    zx: float = 0.0
    xy: float = 0.0

    def retarder(self):
        """(Delta, theta) in radians for light along z: docs/physics.md section 2 with u = x, v = y."""
        diff, shear2 = self.xx - self.yy, 2.0 * self.xy
        delta = (2.0 * math.pi * STRESS_OPTIC_COEFFICIENT * self.thickness
                 * math.hypot(diff, shear2) / WAVELENGTH)
        return delta, 0.5 * math.atan2(shear2, diff)


# In the order light meets them (increasing z). The out-of-plane components
# (zz, yz, zx) of the first slab are invisible to rays along z: they check that
# mi_nest projects the tensor instead of reading raw components. The axes are
# about 50 degrees apart, so the product has a large rotator part (|d| ~ 0.3).
SLABS = (
    Slab(thickness=2.0, xx=1.5, yy=0.3, xy=0.4, zz=0.7, yz=0.9, zx=-0.5),   # Delta 1.70, theta 16.8
    Slab(thickness=1.5, xx=-0.5, yy=0.8, xy=-1.0),                         # Delta 2.11, theta -61.5
    Slab(thickness=1.0, xx=0.2, yy=2.2, xy=1.1),                           # Delta 1.76, theta 66.1
)


@dataclass(frozen=True)
class Scope:
    """Polariscope in degrees in the (u, v) plane; ``None`` = element absent."""
    polarizer: float
    input_qwp: Optional[float]
    output_qwp: Optional[float]
    analyzer: Optional[float]


# The scene's own polariscope for the main channel: generic angles, so that
# the polariser angle sign matters too (alpha_1 = 90 in all 16 measurements).
MAIN_SCOPE = Scope(polarizer=20.0, input_qwp=65.0, output_qwp=10.0, analyzer=115.0)

# docs/physics.md section 6: alpha_1 = 90, beta_1 x beta_2 x alpha_2.
MEASUREMENTS = {
    f"pol.{b1}.{b2}.{a2}": Scope(90.0, float(b1), float(b2), float(a2))
    for b1 in (45, 90) for b2 in (0, 45) for a2 in (0, 45, 90, 135)
}
CONFIGURATIONS = {"Y": MAIN_SCOPE, **MEASUREMENTS}


# --- mi_nest -----------------------------------------------------------------

def _slab_positions():
    """(z_min, z_max) of each slab: stacked from z = 0 upwards with air gaps."""
    z, positions = 0.0, []
    for slab in SLABS:
        positions.append((z, z + slab.thickness))
        z += slab.thickness + GAP
    return positions


def mi_nest_scene():
    T = mi.ScalarTransform4f
    scene = {
        "type": "scene",
        "embree_use_robust_intersections": True,
        "integrator": {"type": "photoelastic", "step_size": 0.5},
        "light": {"type": "polariscope_light", "polarizer": MAIN_SCOPE.polarizer,
                  "qwp": MAIN_SCOPE.input_qwp},
        "sensor": {
            "type": "polariscope",
            "projection": "orthographic",
            "qwp": MAIN_SCOPE.output_qwp,
            "analyzer": MAIN_SCOPE.analyzer,
            # Looking along -z from +z with up +y: image right = +x, image up = +y.
            "to_world": T().look_at(origin=[0, 0, 100], target=[0, 0, 0], up=[0, 1, 0])
                        @ T().scale([4, 4, 1]),
            "film": {"type": "hdrfilm", "width": FILM_SIZE, "height": FILM_SIZE,
                     "pixel_format": "luminance", "rfilter": {"type": "box"}},
            "sampler": {"type": "stratified", "sample_count": 1, "jitter": False},
        },
    }
    for index, (slab, (z0, z1)) in enumerate(zip(SLABS, _slab_positions())):
        scene[f"slab_{index}"] = {
            "type": "cube",  # [-1, 1]^3: a 20 x 20 mm slab, wider than the 8 mm view
            "to_world": T().translate([0, 0, 0.5 * (z0 + z1)])
                        @ T().scale([10, 10, 0.5 * (z1 - z0)]),
            "interior": {
                "type": "stress",
                "stress_optic_coefficient": STRESS_OPTIC_COEFFICIENT,
                "wavelength": WAVELENGTH,
                "model": "uniform",
                **{name: getattr(slab, name) for name in ("xx", "yy", "zz", "yz", "zx", "xy")},
            },
        }
    return mi.load_dict(scene)


# --- Jones calculus of docs/physics.md, written from scratch ---------------------

def _rotation(t):
    return np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])


def _transmission(alpha_deg):
    t = np.deg2rad(alpha_deg)
    return np.array([np.cos(t), np.sin(t)], dtype=complex)


def _qwp(beta_deg):
    """Fast axis at beta under exp(+i omega t): the slow component lags a quarter period."""
    t = np.deg2rad(beta_deg)
    return _rotation(t) @ np.diag([1.0, -1.0j]) @ _rotation(-t)


def _slab_jones(slab):
    """exp of the section 2 generator over the slab (not the closed-form retarder)."""
    p, q = slab.xx - slab.yy, 2.0 * slab.xy
    k = math.pi * STRESS_OPTIC_COEFFICIENT / WAVELENGTH
    return expm(-1j * k * slab.thickness * np.array([[p, q], [q, -p]]))


def jones_intensity(scope):
    field = _transmission(scope.polarizer)          # unit intensity after LP1
    if scope.input_qwp is not None:
        field = _qwp(scope.input_qwp) @ field
    for slab in SLABS:                              # light meets the slabs in z order
        field = _slab_jones(slab) @ field
    if scope.output_qwp is not None:
        field = _qwp(scope.output_qwp) @ field
    if scope.analyzer is not None:
        field = _transmission(scope.analyzer).real @ field
    return float(np.sum(np.abs(field) ** 2))


# --- Mitsuba's polarised variant -------------------------------------------

def mitsuba_stack(scope, retarders, geometric=False):
    """Mitsuba elements for ``scope`` around slab retarders ``[(Delta_deg, fast_axis_deg)]``.

    ``geometric=True``: every axis set by rotating the element's rectangle
    (``theta=0``), so no angle sign convention of Mitsuba enters.
    ``geometric=False``: Mitsuba's ``theta`` parameters (module docstring).
    """
    def polarizer(alpha):
        if geometric:
            return {"type": "polarizer", "theta": 0.0, "rotate": alpha}
        return {"type": "polarizer", "theta": -alpha}

    def retarder(delta, fast_axis):
        if geometric:
            return {"type": "retarder", "delta": delta, "theta": 0.0, "rotate": fast_axis}
        return {"type": "retarder", "delta": delta, "theta": fast_axis}

    stack = [polarizer(scope.polarizer)]
    if scope.input_qwp is not None:
        stack.append(retarder(90.0, scope.input_qwp))
    stack += [retarder(delta, fast_axis) for delta, fast_axis in retarders]
    if scope.output_qwp is not None:
        stack.append(retarder(90.0, scope.output_qwp))
    if scope.analyzer is not None:
        stack.append(polarizer(scope.analyzer))
    return stack


def slab_retarders():
    """The slabs as (Delta, fast axis) in degrees, in light order: the fast axis is 90 degrees from sigma_1."""
    return [(math.degrees(delta), math.degrees(theta) + 90.0) for delta, theta in (s.retarder() for s in SLABS)]


# Deliberately wrong references: each breaks one thing the comparison must see.
# (Retarders are symmetric matrices, so reversing the slab order transposes the
# product and only flips its rotator part: the slabs are chosen so that it is
# large, see SLABS.)
WRONG_SLABS = {
    # the larger principal stress as the fast axis: the handedness error of the model before issue 18
    "sigma1_fast": [(delta, fast_axis - 90.0) for delta, fast_axis in slab_retarders()],
    "axis_sign": [(delta, -fast_axis) for delta, fast_axis in slab_retarders()],
    "slab_order": slab_retarders()[::-1],
}


def reference_request():
    requests = {"free_space": [{"type": "polarizer", "theta": 90.0},
                               {"type": "polarizer", "theta": 90.0}]}
    for name, scope in CONFIGURATIONS.items():
        requests[f"mapped/{name}"] = mitsuba_stack(scope, slab_retarders())
        requests[f"geometric/{name}"] = mitsuba_stack(scope, slab_retarders(), geometric=True)
        for wrong, retarders in WRONG_SLABS.items():
            requests[f"{wrong}/{name}"] = mitsuba_stack(scope, retarders)
    return requests


# --- fixtures ----------------------------------------------------------------

@pytest.fixture(scope="module")
def mi_nest_channels():
    if not mi_nest.supported_variant(mi.variant()):
        mi.set_variant(mi_nest.DEFAULT_VARIANT)
    return mi_nest.render(mi_nest_scene()).channels


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """``{"<set>/<channel>": intensity}`` from one polarised-variant subprocess, normalised."""
    folder = tmp_path_factory.mktemp("polarized_reference")
    request_path, result_path = folder / "request.json", folder / "result.json"
    request_path.write_text(json.dumps(reference_request()))
    # os.environ carries mi_nest's DRJIT_LIBLLVM_PATH choice to the child.
    done = subprocess.run([sys.executable, str(REFERENCE_SCRIPT), str(request_path), str(result_path)],
                          env=dict(os.environ), capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, f"reference renderer failed:\n{done.stdout}\n{done.stderr}"
    raw = json.loads(result_path.read_text())
    # Unpolarised light of radiance 1 keeps half its power through LP1.
    assert raw["free_space"] == pytest.approx(0.5, abs=1e-6)
    return {name: value / raw["free_space"] for name, value in raw.items() if name != "free_space"}


# --- tests -------------------------------------------------------------------

def test_slab_design_is_generic():
    """Moderate retardances, axes off the 45-degree grid and all different."""
    for delta, theta in slab_retarders():
        assert 0.5 < math.radians(delta) < 2.5
        assert 5.0 < theta % 45.0 < 40.0
    axes = sorted(theta % 180.0 for _, theta in slab_retarders())
    assert min(np.diff(axes)) > 10.0


def test_reference_reproduces_jones_calculus(reference):
    """The Mitsuba stacks (both mappings) render the docs/physics.md intensities."""
    for name, scope in CONFIGURATIONS.items():
        expected = jones_intensity(scope)
        for mapping in ("mapped", "geometric"):
            assert reference[f"{mapping}/{name}"] == pytest.approx(expected, abs=TOLERANCE), \
                f"{mapping}/{name}"


def _errors(channels, reference, prefix):
    """Max |mi_nest - reference| over the pixels of each channel."""
    return {name: float(np.max(np.abs(channels[name] - reference[f"{prefix}/{name}"])))
            for name in CONFIGURATIONS}


def test_mi_nest_channels_are_the_16_measurements(mi_nest_channels):
    pol = {name for name in mi_nest_channels if name.startswith("pol.")}
    assert pol == set(MEASUREMENTS)
    for name in CONFIGURATIONS:
        assert mi_nest_channels[name].shape == (FILM_SIZE, FILM_SIZE)


@pytest.mark.parametrize("mapping", ["mapped", "geometric"])
def test_mi_nest_matches_mitsuba_polarized(mi_nest_channels, reference, mapping):
    errors = _errors(mi_nest_channels, reference, mapping)
    table = "\n".join(f"  {name:14s} mi_nest {float(mi_nest_channels[name].mean()):+.6f}  "
                      f"mitsuba {reference[f'{mapping}/{name}']:+.6f}  |err| {err:.2e}"
                      for name, err in errors.items())
    assert max(errors.values()) < TOLERANCE, f"{mapping} reference disagrees:\n{table}"


@pytest.mark.parametrize("wrong", sorted(WRONG_SLABS))
def test_comparison_detects_wrong_conventions(mi_nest_channels, reference, wrong):
    """Flipping the slab axes, their retardance sign or their order is clearly visible."""
    errors = _errors(mi_nest_channels, reference, wrong)
    assert max(errors.values()) > SENSITIVITY, f"{wrong}: largest change {max(errors.values()):.3g}"
