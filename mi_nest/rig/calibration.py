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
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from ..dataset.masks import ANALYSERS, dolp, linear_settings
from ..physics.su2 import identity
from .twin import Optics

# The sweep of QWP2 (degrees) at each QWP1 setting: every 15 degrees over a half turn.
QWP2_SWEEP = tuple(range(0, 180, 15))
QWP1_SETTINGS = (45.0, 90.0)
# Degrees within which a measured mount angle counts as a nominal setting.
SETTING_TOLERANCE = 0.5
PARAMETERS = ("analyzer_offset", "qwp1_offset", "qwp2_offset", "qwp1_retardance", "qwp2_retardance")


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

    def to_dict(self):
        return {"optics": self.optics.to_dict(), "light_level": self.light_level, "residual_rms": self.residual_rms,
                "standard_errors": self.standard_errors, "exposures": self.exposures,
                "background_fraction": self.background_fraction}

    def describe(self):
        lines = [f"{name} = {getattr(self.optics, name):.3f} deg (+/- {self.standard_errors[name]:.3f})"
                 for name in PARAMETERS]
        lines.append(f"light level {self.light_level:.4f}; residual rms {self.residual_rms:.2e} over "
                     f"{self.exposures} exposures x {len(ANALYSERS)} analysers; background mask keeps "
                     f"{100 * self.background_fraction:.1f}% of the pixels")
        return "\n".join(lines)


def background_mask(exposures, threshold=0.9):
    """Pixels whose DoLP stays above ``threshold`` in every exposure whose free-space output is linear.

    An ideal polariscope gives DoLP 1 there (``dataset.masks.linear_settings``);
    a birefringent or scattering object in view turns the light elliptical or
    depolarises it.
    """
    linear = [(float(b1), float(b2)) for b1, b2 in linear_settings()]
    # Measured mount angles are a few counts off the nominal ones.
    chosen = [e for e in exposures if any(abs(e.qwp1 - b1) < SETTING_TOLERANCE and
                                          abs((e.qwp2 - b2 + 180.0) % 360.0 - 180.0) < SETTING_TOLERANCE
                                          for b1, b2 in linear)]
    if not chosen:
        raise ValueError(f"no exposure at a setting with linearly polarised free-space output {sorted(linear)}: "
                         "cannot tell the background")
    return np.min([dolp([e.images[a] for a in ANALYSERS]) for e in chosen], axis=0) > threshold


def _model(parameters, settings):
    optics = Optics(**dict(zip(PARAMETERS, parameters[:-1])))
    q = identity(np.float64(0.0))
    return parameters[-1] * np.array([optics.polariscope(qwp1, qwp2, analyzer).intensity(q)
                                      for qwp1, qwp2, analyzer in settings])


def fit(exposures, threshold=0.9) -> Calibration:
    """Least-squares optics from free-space ``exposures`` (see :data:`QWP2_SWEEP`, :data:`QWP1_SETTINGS`)."""
    if len({e.qwp1 for e in exposures}) < 2 or len({e.qwp2 for e in exposures}) < 4:
        raise ValueError("calibration needs both QWP1 settings and at least 4 QWP2 angles (a sweep over a half "
                         f"turn); got QWP1 {sorted({e.qwp1 for e in exposures})}, QWP2 "
                         f"{sorted({e.qwp2 for e in exposures})}")
    mask = background_mask(exposures, threshold)
    if mask.mean() < 0.01:
        raise ValueError("no background pixel stays polarised: is the light panel on and the view free?")
    settings, measured = [], []
    for exposure in exposures:
        for analyzer in ANALYSERS:
            settings.append((exposure.qwp1, exposure.qwp2, analyzer))
            measured.append(float(np.mean(exposure.images[analyzer][mask])))
    measured = np.array(measured)
    start = np.array([0.0, 0.0, 0.0, 90.0, 90.0, measured.max()])
    solution = least_squares(lambda p: _model(p, settings) - measured, start, x_scale=[1, 1, 1, 1, 1, 0.01])
    residual = solution.fun
    dof = max(len(residual) - len(start), 1)
    variance = float(residual @ residual) / dof
    covariance = np.linalg.pinv(solution.jac.T @ solution.jac) * variance
    errors = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    parameters = solution.x
    return Calibration(Optics(**dict(zip(PARAMETERS, (float(x) for x in parameters[:-1])))), float(parameters[-1]),
                       float(np.sqrt(np.mean(residual ** 2))),
                       {name: float(e) for name, e in zip(PARAMETERS, errors[:-1])}, len(exposures),
                       float(mask.mean()))


def expected_exposures():
    """The (QWP1, QWP2) settings of a calibration run, QWP1 outermost (it is turned by hand)."""
    return [(qwp1, float(qwp2)) for qwp1 in QWP1_SETTINGS for qwp2 in QWP2_SWEEP]
