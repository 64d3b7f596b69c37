"""Polariscope optics and the 16 multi-axis measurements (docs/physics.md sections 1 and 6).

Light source -> linear polariser (alpha_1) -> optional QWP (beta_1) -> specimen J
-> optional QWP (beta_2) -> optional analyser (alpha_2). Angles are degrees in
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

from dataclasses import dataclass
from functools import lru_cache
from typing import Optional, Sequence

import numpy as np

from . import jones
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
class Polariscope:
    """One polariscope configuration; ``None`` means the element is absent.

    The retardances (degrees) of the two waveplates are 90 for ideal QWPs;
    calibration fits the real ones.
    """
    polarizer: float = 90.0
    input_qwp: Optional[float] = None
    output_qwp: Optional[float] = None
    analyzer: Optional[float] = None
    input_retardance: float = 90.0
    output_retardance: float = 90.0

    def input_state(self) -> np.ndarray:
        t = np.deg2rad(self.polarizer)
        e = np.array([np.cos(t), np.sin(t)], dtype=np.complex128)
        return e if self.input_qwp is None else waveplate(self.input_qwp, self.input_retardance) @ e

    def output_rows(self) -> np.ndarray:
        """Rows ``w^T`` whose squared amplitudes add up to the detected intensity."""
        rows = np.eye(2, dtype=np.complex128)
        if self.output_qwp is not None:
            rows = rows @ waveplate(self.output_qwp, self.output_retardance)
        if self.analyzer is not None:
            t = np.deg2rad(self.analyzer)
            rows = np.array([[np.cos(t), np.sin(t)]]) @ rows
        return rows

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
    measurement_name(b1, b2, a2): Polariscope(POLARIZER, float(b1), float(b2), float(a2))
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
    return Polariscope(polarizer=angle + 90.0, input_qwp=angle + 45.0 if circular else None,
                       output_qwp=angle + 135.0 if circular else None,
                       analyzer=angle + (0.0 if field == "dark" else 90.0))


def measurement_intensities(q: Sequence[Array]) -> dict[str, Array]:
    """The 16 intensities ``{"pol.<b1>.<b2>.<a2>": I}`` of docs/physics.md section 6."""
    return {name: scope.intensity(q) for name, scope in MEASUREMENTS.items()}
