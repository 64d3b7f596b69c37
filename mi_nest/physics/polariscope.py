"""Polariscope optics and the 16 multi-axis measurements (docs/physics.md sections 1 and 6).

A polariscope is the ordered optics on either side of the specimen J: the
light's (a polariser, then any waveplates, half-wave plates or compensators)
and the camera's (any of them, usually ending in an analyser). The rig's is
linear polariser (alpha_1) -> optional QWP (beta_1) -> specimen J -> optional
QWP (beta_2) -> optional analyser (alpha_2). Angles are degrees in
the transverse (u, v) plane, from u (image right) towards v (image up):
counter-clockwise for an observer looking toward the source. Fields vary as
``exp(+i omega t)``, so a phase lag is a negative phase and a waveplate's fast
axis is the one whose component keeps its phase.

For a unit source the detected intensity is ``sum_rows |w^T J e|^2``. Writing J
in its quaternion coordinates ``q = (a, b, c, d)`` makes every amplitude
``w^T J e = kappa . q`` linear in q with a constant complex 4-vector kappa, so
each intensity is ``(Re kappa . q)^2 + (Im kappa . q)^2`` summed over the rows:
a handful of multiply-adds per ray for any polariscope.
"""
from __future__ import annotations

import inspect
from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np

from . import jones
from .parsing import name_and_numbers
from .backend import Array

# J = a B_a + b B_b + c B_c + d B_d (see su2.py).
_BASIS = np.array([
    [[1, 0], [0, 1]],
    [[0, 1j], [1j, 0]],
    [[1j, 0], [0, -1j]],
    [[0, 1], [-1, 0]],
], dtype=np.complex128)


def rotation(angle_deg: float) -> np.ndarray:
    """2D rotation by ``angle_deg`` from u towards v."""
    t = np.deg2rad(angle_deg)
    return np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]], dtype=np.complex128)


def linear_polarizer(alpha_deg: float) -> np.ndarray:
    """Jones matrix of a linear polariser transmitting ``(cos alpha, sin alpha)``."""
    t = np.deg2rad(alpha_deg)
    p = np.array([np.cos(t), np.sin(t)])
    return np.outer(p, p).astype(np.complex128)


def waveplate(beta_deg: float, retardance_deg: float = 90.0) -> np.ndarray:
    """Linear retarder with fast axis at ``beta``: ``R(beta) diag(1, exp(-i delta)) R(-beta)``.

    The slow component lags by ``delta``, a negative phase under ``exp(+i omega t)``.
    """
    return rotation(beta_deg) @ np.diag([1, np.exp(-1j * np.deg2rad(retardance_deg))]) @ rotation(-beta_deg)


def quarter_wave_plate(beta_deg: float) -> np.ndarray:
    """QWP with fast axis at ``beta``: ``R(beta) diag(1, -i) R(-beta)``."""
    return waveplate(beta_deg, 90.0)


@dataclass(frozen=True)
class Polarizer:
    """A linear polariser transmitting along ``angle`` (degrees)."""
    angle: float

    def matrix(self) -> np.ndarray:
        return linear_polarizer(self.angle)

    def describe(self) -> str:
        return f"polarizer {self.angle:g}"


@dataclass(frozen=True)
class Waveplate:
    """A linear retarder: fast axis at ``angle``, the slow component lagging by ``retardance`` (degrees): 90 a
    quarter-wave plate, 180 a half-wave plate."""
    angle: float
    retardance: float = 90.0

    def matrix(self) -> np.ndarray:
        return waveplate(self.angle, self.retardance)

    def describe(self) -> str:
        return f"waveplate {self.angle:g} {self.retardance:g}"


@dataclass(frozen=True)
class Compensator:
    """A Babinet-Soleil compensator: two quartz wedges and a plate whose retardance, uniform across the aperture,
    is set by a micrometer as ``rate`` (degrees of retardance per mm) times ``position`` (mm from zero); its
    fast axis at ``angle``. Turned against a specimen's axes it cancels the specimen's retardance: the
    position that brings a point to extinction measures its fringe order, fractions included. (A plain Babinet
    has the same wedges without the plate: its retardance varies across the aperture, and at any one point it
    is this.)"""
    angle: float
    rate: float
    position: float = 0.0

    @property
    def retardance(self) -> float:
        return self.rate * self.position

    def matrix(self) -> np.ndarray:
        return waveplate(self.angle, self.retardance)

    def describe(self) -> str:
        return f"compensator {self.angle:g} {self.rate:g} {self.position:g}"


Element = Polarizer | Waveplate | Compensator


def half_wave_plate(angle: float) -> Waveplate:
    """A half-wave plate with fast axis at ``angle``: it mirrors linear polarisation about its axis."""
    return Waveplate(angle, 180.0)


# Each element by the name a scene's ``optics`` property gives it, with the numbers it takes.
ELEMENTS = {"polarizer": Polarizer, "waveplate": Waveplate, "qwp": Waveplate, "hwp": half_wave_plate,
            "compensator": Compensator}


def parse_optics(text: str) -> tuple[Element, ...]:
    """Elements from ``"polarizer 90; qwp 45; hwp 22.5; waveplate 30 120; compensator 45 360 0.5"``: a name of
    :data:`ELEMENTS` and its numbers (degrees, and a compensator's degrees per mm and mm), in the order the
    light meets them."""
    elements = []
    for part in (p.strip() for p in text.split(";")):
        if not part:
            continue
        name, values = name_and_numbers(part, "optical element")
        if name not in ELEMENTS:
            raise ValueError(f"unknown optical element '{name}' in '{text}'; choose one of {', '.join(ELEMENTS)}")
        try:
            elements.append(ELEMENTS[name](*values))
        except TypeError:
            raise ValueError(f"'{part}': {name} takes {_arguments(ELEMENTS[name])}") from None
    return tuple(elements)


def _arguments(make) -> str:
    return " ".join(inspect.signature(make).parameters)


@dataclass(frozen=True)
class Polariscope:
    """The optics on either side of the specimen, each an ordered tuple of elements in the order the light meets
    them: ``light`` from the panel's polariser to the specimen (it starts with a :class:`Polarizer`: the panel's
    unpolarised light is normalised to a unit state behind it), ``camera`` from the specimen to the camera (an
    empty one is lossless: the camera sees all the light). :func:`standard_polariscope` builds the usual
    polariser, quarter-wave plate | specimen | quarter-wave plate, analyser."""
    light: tuple[Element, ...] = (Polarizer(90.0),)
    camera: tuple[Element, ...] = ()

    def __post_init__(self):
        if not self.light or not isinstance(self.light[0], Polarizer):
            raise ValueError(f"a polariscope's light side starts with its polariser, got {self.light}")
        for element in self.light + self.camera:
            if not isinstance(element, (Polarizer, Waveplate, Compensator)):
                raise TypeError(f"{element!r} is not an optical element (Polarizer, Waveplate, Compensator)")

    def input_state(self) -> np.ndarray:
        t = np.deg2rad(self.light[0].angle)
        e = np.array([np.cos(t), np.sin(t)], dtype=np.complex128)
        for element in self.light[1:]:
            e = element.matrix() @ e
        return e

    def output_rows(self) -> np.ndarray:
        """Rows ``w^T`` whose squared amplitudes add up to the detected intensity: one behind a final polariser
        (its transmission axis), two without one."""
        camera = list(self.camera)
        if camera and isinstance(camera[-1], Polarizer):
            t = np.deg2rad(camera.pop().angle)
            rows = np.array([[np.cos(t), np.sin(t)]], dtype=np.complex128)
        else:
            rows = np.eye(2, dtype=np.complex128)
        for element in reversed(camera):
            rows = rows @ element.matrix()
        return rows

    def describe(self) -> str:
        """``light | specimen | camera``, each element as :func:`parse_optics` reads it."""
        return " | ".join(["; ".join(e.describe() for e in self.light), "specimen",
                           "; ".join(e.describe() for e in self.camera) or "(no analyser)"])

    def coefficients(self) -> tuple[tuple[tuple[float, ...], tuple[float, ...]], ...]:
        """Per output row, the real and imaginary parts of ``kappa`` as float tuples."""
        return _coefficients(self)

    def intensity(self, q: Sequence[Array]) -> Array:
        """Detected intensity for the Jones quaternion ``q``, or for a general Jones matrix (a refracted
        path's: a pair of quaternions, jones.py), or the sum over paths that add incoherently
        (``jones.Incoherent``), on NumPy or Dr.Jit arrays."""
        if isinstance(q, jones.Incoherent):
            return sum((self.intensity(path) for path in q[1:]), self.intensity(q[0]))
        if len(q) == 2:
            return jones.intensity(self.coefficients(), q)
        total = 0.0
        for re, im in self.coefficients():
            amp_re = sum(k * x for k, x in zip(re, q) if not _zero(k))
            amp_im = sum(k * x for k, x in zip(im, q) if not _zero(k))
            total = total + amp_re * amp_re + amp_im * amp_im
        return total

    def matrix(self, J: np.ndarray) -> np.ndarray:
        """Full system matrix for a Jones matrix ``J`` (NumPy; used by tests and calibration)."""
        system = J @ (self.input_state()[:, None])
        return self.output_rows() @ system


def standard_polariscope(polarizer: float = 90.0, input_qwp: float | None = None, output_qwp: float | None = None,
                         analyzer: float | None = None, input_retardance: float = 90.0,
                         output_retardance: float = 90.0) -> Polariscope:
    """Polariser ``alpha_1``, quarter-wave plate ``beta_1`` | specimen | quarter-wave plate ``beta_2``, analyser
    ``alpha_2`` (degrees; ``None``: the element is absent): the rig's polariscope. The retardances of the two
    waveplates are 90 for ideal quarter-wave plates; calibration fits the real ones."""
    light = (Polarizer(polarizer),) + (() if input_qwp is None else (Waveplate(input_qwp, input_retardance),))
    camera = ((() if output_qwp is None else (Waveplate(output_qwp, output_retardance),))
              + (() if analyzer is None else (Polarizer(analyzer),)))
    return Polariscope(light, camera)


def _zero(k) -> bool:
    """A form's coefficient known to be zero when the kernel is traced (opaque array coefficients never are)."""
    return isinstance(k, float) and k == 0.0


@lru_cache(maxsize=256)
def _coefficients(scope):
    # Renderers trace the intensities on every call: compute each polariscope's forms once.
    e = scope.input_state()
    terms = []
    for w in scope.output_rows():
        kappa = np.einsum("i,kij,j->k", w, _BASIS, e)
        terms.append((tuple(float(x) for x in kappa.real), tuple(float(x) for x in kappa.imag)))
    return tuple(terms)


def measurement_name(input_qwp: float, output_qwp: float, analyzer: float) -> str:
    """The channel name ``pol.<b1>.<b2>.<a2>`` of a measurement."""
    return f"pol.{input_qwp:g}.{output_qwp:g}.{analyzer:g}"


# The settings (degrees) of the paper's rig, the one table every part of mi_nest builds on: the light's
# polariser LP1 (alpha_1), QWP1 (beta_1, turned by hand), QWP2 (beta_2, on a motor) and the camera's four
# micro-polariser analysers (alpha_2). Whole degrees, as dataset.json and the rig's frame files record them.
POLARIZER = 90.0
INPUT_QWP_SETTINGS = (45, 90)
OUTPUT_QWP_SETTINGS = (0, 45)
ANALYZERS = (0, 45, 90, 135)

# The 16 measurements: beta_1 x beta_2 x alpha_2, in this order.
MEASUREMENTS = {
    measurement_name(b1, b2, a2): standard_polariscope(POLARIZER, float(b1), float(b2), float(a2))
    for b1 in INPUT_QWP_SETTINGS for b2 in OUTPUT_QWP_SETTINGS for a2 in ANALYZERS
}


# The textbook polariscopes a view can choose (mi-nest slice, render, view).
POLARISCOPE_KINDS = ("circular", "linear")
POLARISCOPE_FIELDS = ("dark", "light")


def polariscope_setting(kind: str = "circular", field: str = "dark", angle: float = 0.0) -> Polariscope:
    """A plane (``linear``) or ``circular`` polariscope in a ``dark`` or ``light`` field, turned by ``angle``.

    The polariser stands at ``angle + 90`` degrees, the analyser at ``angle``
    (dark: crossed) or ``angle + 90`` (light: parallel); a circular one adds
    QWP1 at ``angle + 45`` and QWP2 at ``angle + 135``. ``angle = 0`` in the
    dark circular field is the shipped scenes' polariscope. Turning a plane
    polariscope moves its isoclinics; a circular one shows none.
    """
    if kind not in POLARISCOPE_KINDS:
        raise ValueError(f"unknown polariscope '{kind}'; choose one of {', '.join(POLARISCOPE_KINDS)}")
    if field not in POLARISCOPE_FIELDS:
        raise ValueError(f"unknown polariscope field '{field}'; choose one of {', '.join(POLARISCOPE_FIELDS)}")
    angle = float(angle)
    if not np.isfinite(angle):
        raise ValueError(f"polariscope angle must be a finite number of degrees, got {angle}")
    circular = kind == "circular"
    return standard_polariscope(polarizer=angle + 90.0, input_qwp=angle + 45.0 if circular else None,
                                output_qwp=angle + 135.0 if circular else None,
                                analyzer=angle + (0.0 if field == "dark" else 90.0))


def measurement_intensities(q: Sequence[Array]) -> dict[str, Array]:
    """The 16 intensities ``{"pol.<b1>.<b2>.<a2>": I}`` of docs/physics.md section 6."""
    return {name: scope.intensity(q) for name, scope in MEASUREMENTS.items()}
