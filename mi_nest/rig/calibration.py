"""Calibration of the polariscope from free-space captures: angle offsets and waveplate retardances.

With no specimen the Jones matrix is the identity, so each exposure's four
analyser means are the known polariscope model (``physics.polariscope``, the
same Jones code the renderer uses) of five unknowns, QWP1/QWP2/analyser angle
offsets and the two retardances, times the light level. Sweeping QWP2 over a
half turn at both QWP1 settings gives a well-posed least-squares fit; its
residuals and the parameters' standard errors go into the report.
Only pixels that stay polarised in every nominal exposure are used (the
background mask: minimum DoLP above a threshold), so dust or a specimen in
view does not bias the fit.

Free space cannot tell a mirrored rig, or both waveplates with fast and slow
axes swapped, from the rig as built (``handedness.py`` checks those on a
specimen of known stress); so the fitted optics are reported in one form of
the several that explain the sweep: offsets within 45 degrees, positive
retardances, and at most one waveplate marked ``swapped``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.optimize import least_squares

from ..dataset.masks import dolp, linear_settings
from ..physics.polariscope import ANALYZERS, INPUT_QWP_SETTINGS
from ..physics.su2 import identity
from .twin import Optics

# The sweep of QWP2 (degrees) at each QWP1 setting: every 15 degrees over a half turn.
QWP2_SWEEP = tuple(range(0, 180, 15))
# Degrees within which a measured mount angle counts as a nominal setting.
SETTING_TOLERANCE = 0.5
PARAMETERS = ("analyzer_offset", "qwp1_offset", "qwp2_offset", "qwp1_retardance", "qwp2_retardance")
# The largest free-space residual rms (of the light level) a polariscope fit may leave: camera noise leaves
# 5e-4 on the twin at 0.5% read noise (0.03 at an absurd 20%), a single mount turning the other way 0.3.
MAX_RESIDUAL = 0.05
NOT_CHECKED = {"verified": False, "reason": "calibrated with --skip-handedness, not on a specimen of known stress"}


@dataclass
class Exposure:
    qwp1: float                  # the manual mount's reading (degrees)
    qwp2: float                  # the ELL14's measured position (degrees)
    images: dict                 # {analyser: (H, W)}


@dataclass
class Calibration:
    optics: Optics
    light_level: float
    residual_rms: float          # normalised intensity
    standard_errors: dict        # per parameter, degrees
    exposures: int
    background_fraction: float   # share of pixels the background mask kept
    handedness: object = None    # the handedness.HandednessCheck, None when not checked

    def to_dict(self) -> dict:
        return {"optics": self.optics.to_dict(), "light_level": self.light_level, "residual_rms": self.residual_rms,
                "standard_errors": self.standard_errors, "exposures": self.exposures,
                "background_fraction": self.background_fraction,
                "handedness": NOT_CHECKED if self.handedness is None else self.handedness.to_dict()}

    def describe(self) -> str:
        lines = [f"{name} = {getattr(self.optics, name):.3f} deg (+/- {self.standard_errors[name]:.3f})"
                 for name in PARAMETERS]
        lines.append(f"light level {self.light_level:.4f}; residual rms {self.residual_rms:.2e} over "
                     f"{self.exposures} exposures x {len(ANALYZERS)} analysers; background mask keeps "
                     f"{100 * self.background_fraction:.1f}% of the pixels")
        swapped = [name.upper() for name in ("qwp1", "qwp2") if getattr(self.optics, f"{name}_swapped")]
        if swapped:
            lines.append(f"{swapped[0]}'s fast axis is 90 deg from its mark (or the other plate's: free space "
                         "cannot tell which)")
        lines.append("handedness not checked" if self.handedness is None else self.handedness.describe())
        return "\n".join(lines)


def background_mask(exposures: Sequence[Exposure], threshold: float = 0.9) -> np.ndarray:
    """Pixels whose DoLP stays above ``threshold`` in every exposure whose free-space output is linear.

    An ideal polariscope gives DoLP 1 there (``dataset.masks.linear_settings``);
    a birefringent or scattering object in view turns the light elliptical or
    depolarises it.
    """
    linear = linear_settings()
    # Measured mount angles are a few counts off the nominal ones.
    chosen = [e for e in exposures if any(abs(e.qwp1 - b1) < SETTING_TOLERANCE and
                                          abs((e.qwp2 - b2 + 180.0) % 360.0 - 180.0) < SETTING_TOLERANCE
                                          for b1, b2 in linear)]
    if not chosen:
        raise ValueError(f"no exposure at a setting with linearly polarised free-space output {sorted(linear)}: "
                         "cannot tell the background")
    return np.min([dolp([e.images[a] for a in ANALYZERS]) for e in chosen], axis=0) > threshold


def _model(parameters, settings):
    optics = Optics(**dict(zip(PARAMETERS, parameters[:-1])))
    q = identity(np.float64(0.0))
    return parameters[-1] * np.array([optics.polariscope(qwp1, qwp2, analyzer).intensity(q)
                                      for qwp1, qwp2, analyzer in settings])


def fit(exposures: Sequence[Exposure], threshold: float = 0.9) -> Calibration:
    """Least-squares optics from free-space ``exposures`` (see :func:`expected_exposures`)."""
    if len({e.qwp1 for e in exposures}) < 2 or len({e.qwp2 for e in exposures}) < 4:
        raise ValueError("calibration needs both QWP1 settings and at least 4 QWP2 angles (a sweep over a half "
                         f"turn); got QWP1 {sorted({e.qwp1 for e in exposures})}, QWP2 "
                         f"{sorted({e.qwp2 for e in exposures})}")
    mask = background_mask(exposures, threshold)
    if mask.mean() < 0.01:
        raise ValueError("no background pixel stays polarised: is the light panel on and the view free?")
    settings, measured = [], []
    for exposure in exposures:
        for analyzer in ANALYZERS:
            settings.append((exposure.qwp1, exposure.qwp2, analyzer))
            measured.append(float(np.mean(exposure.images[analyzer][mask])))
    measured = np.array(measured)
    start = np.array([0.0, 0.0, 0.0, 90.0, 90.0, measured.max()])
    solution = least_squares(lambda p: _model(p, settings) - measured, start, x_scale=[1, 1, 1, 1, 1, 0.01])
    residual = solution.fun
    rms = float(np.sqrt(np.mean(residual ** 2)))
    light_level = solution.x[-1]
    if rms > MAX_RESIDUAL * light_level:
        raise ValueError(f"no polariscope explains the free-space sweep (residual rms {rms / light_level:.3f} of the "
                         f"light level, limit {MAX_RESIDUAL}): does a single mount turn the other way (the ELL14 "
                         "mounted reversed, the camera's 45/135 pixels swapped), or did the light change during the "
                         "sweep?")
    dof = max(len(residual) - len(start), 1)
    variance = float(residual @ residual) / dof
    covariance = np.linalg.pinv(solution.jac.T @ solution.jac) * variance
    errors = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    parameters = solution.x
    return Calibration(_canonical(Optics(**dict(zip(PARAMETERS, (float(x) for x in parameters[:-1]))))),
                       float(light_level), rms,
                       {name: float(e) for name, e in zip(PARAMETERS, errors[:-1])}, len(exposures),
                       float(mask.mean()))


def _canonical(optics):
    """The form of ``optics`` with offsets within 45 degrees, positive retardances and at most one plate swapped.

    A plate turned by 90 degrees, or with its retardance negated, is the same plate with its axes swapped
    (up to a phase); both plates swapped look like neither in free space.
    """
    values = optics.to_dict()
    for plate in ("qwp1", "qwp2"):
        offset = (values[f"{plate}_offset"] + 90.0) % 180.0 - 90.0
        retardance = (values[f"{plate}_retardance"] + 180.0) % 360.0 - 180.0
        swapped = values[f"{plate}_swapped"]
        if abs(offset) > 45.0:
            offset, swapped = offset - math.copysign(90.0, offset), not swapped
        if retardance < 0.0:
            retardance, swapped = -retardance, not swapped
        values.update({f"{plate}_offset": offset, f"{plate}_retardance": retardance, f"{plate}_swapped": swapped})
    if values["qwp1_swapped"] and values["qwp2_swapped"]:
        values["qwp1_swapped"] = values["qwp2_swapped"] = False
    return Optics(**values)


def expected_exposures() -> list[tuple[int, float]]:
    """The (QWP1, QWP2) settings of a calibration run, QWP1 outermost (it is turned by hand)."""
    return [(qwp1, float(qwp2)) for qwp1 in INPUT_QWP_SETTINGS for qwp2 in QWP2_SWEEP]
