"""How finely a field must be marched: the analysis behind the integrator's ``auto`` method.

Input: the generator ``(p, q)`` (phase per mm, i.e. ``pi C / lambda`` times
``(s_uu - s_vv, 2 s_uv)``) sampled at evenly spaced points along lines parallel
to the light. Steps commute exactly when the transverse principal axes,
``0.5 atan2(q, p)``, are the same all along every line (wherever the stress is
not negligible); then one exponential of the summed generator is exact.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Generators below this fraction of the largest one carry no axis worth comparing.
NEGLIGIBLE = 1e-3
# Axis changes below this (radians) along a line count as commuting (float32 noise).
COMMUTING_ANGLE = 1e-4
# Magnus-4 error over a path L with steps h: about MAGNUS4_CONSTANT * L * h^4 * K^5, K the
# larger of the retardance rate and the axis rotation rate (rad/mm), fitted on the
# twisted block (8.8e-4) and rounded up for safety.
MAGNUS4_CONSTANT = 2e-3


@dataclass(frozen=True)
class FieldRates:
    commuting: bool
    retardance_rate: float    # rad of retardance per mm, largest
    rotation_rate: float      # rad of axis rotation per mm, largest
    path_length: float        # mm, longest line
    curvature: float = 0.0    # largest |d^2 (p, q) / ds^2| (phase per mm^3): the midpoint rule's error


def analyse_lines(p, q, spacing):
    """Rates of ``(p, q)`` given as (lines, points) arrays sampled every ``spacing`` mm."""
    p, q = np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64)
    magnitude = np.hypot(p, q)
    largest = float(magnitude.max()) if magnitude.size else 0.0
    length = spacing * (p.shape[-1] - 1)
    if largest == 0.0:
        return FieldRates(True, 0.0, 0.0, length)
    significant = magnitude > NEGLIGIBLE * largest
    # Axis angle doubled lives on a circle: compare unit vectors (p, q) / |(p, q)|.
    unit_p = np.where(significant, p / np.maximum(magnitude, 1e-300), 0.0)
    unit_q = np.where(significant, q / np.maximum(magnitude, 1e-300), 0.0)
    both = significant[:, 1:] & significant[:, :-1]
    turn = np.arctan2(unit_p[:, :-1] * unit_q[:, 1:] - unit_q[:, :-1] * unit_p[:, 1:],
                      unit_p[:, :-1] * unit_p[:, 1:] + unit_q[:, :-1] * unit_q[:, 1:])
    turn = np.where(both, np.abs(turn) / 2.0, 0.0)            # axis angle = half the doubled angle
    # Commuting also needs one axis per line across gaps of negligible stress.
    reference = np.argmax(significant, axis=1)
    ref_p = np.take_along_axis(unit_p, reference[:, None], axis=1)
    ref_q = np.take_along_axis(unit_q, reference[:, None], axis=1)
    spread = np.where(significant, np.abs(np.arctan2(ref_p * unit_q - ref_q * unit_p,
                                                     ref_p * unit_p + ref_q * unit_q)) / 2.0, 0.0)
    commuting = bool(spread.max() <= COMMUTING_ANGLE)
    curvature = 0.0
    if p.shape[-1] >= 3:
        second = np.hypot(np.diff(p, 2, axis=-1), np.diff(q, 2, axis=-1)) / spacing ** 2
        curvature = float(second.max())
    return FieldRates(commuting, 2.0 * largest, float(turn.max()) / spacing, length, curvature)


def magnus4_step(rates: FieldRates, tolerance):
    """The longest Magnus-4 step whose predicted error over the longest path stays under ``tolerance``."""
    rate = max(rates.retardance_rate, rates.rotation_rate)
    if rate == 0.0 or rates.path_length == 0.0:
        return max(rates.path_length, 1e-3)
    step = (tolerance / (MAGNUS4_CONSTANT * rates.path_length * rate ** 5)) ** 0.25
    return float(min(step, rates.path_length))


def linear_step(rates: FieldRates, tolerance):
    """Midpoint-rule step for the summed generator: its error ``L h^2 / 24 |r''|`` stays under ``tolerance``.

    A generator constant along the rays needs one step per chord.
    """
    if rates.curvature == 0.0 or rates.path_length == 0.0:
        return max(rates.path_length, 1e-3)
    step = (24.0 * tolerance / (rates.path_length * rates.curvature)) ** 0.5
    return float(min(step, rates.path_length))
