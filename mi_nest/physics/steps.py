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

from . import su2
from .polariscope import MEASUREMENTS

# Generators below this fraction of the largest one carry no axis worth comparing.
NEGLIGIBLE = 1e-3
# Axis changes below this (radians) along a line count as commuting (float32 noise).
COMMUTING_ANGLE = 1e-4
# Gauss-Legendre points of Magnus-4 within a step (fractions of it from the camera side):
# the farther one from the camera first, as the light meets it.
GAUSS_POINTS = (0.5 + 3.0 ** 0.5 / 6.0, 0.5 - 3.0 ** 0.5 / 6.0)
# Step doubling trusts an error estimate once the step is this fine and the estimate shrank
# like a fourth-order method's from the step before (a coarse pair can agree by chance).
SMALLEST_STEP = 1e-3
# The error that must meet the tolerance: this percentile over the chords marched (the
# hardest few per cent of a specimen's lines). A stress singularity (a contact point)
# needs vanishing steps in a few rays whose fringes alias at any resolution anyway.
QUANTILE = 90.0


@dataclass(frozen=True)
class FieldRates:
    commuting: bool
    retardance_rate: float    # rad of retardance per mm, largest
    rotation_rate: float      # rad of axis rotation per mm, largest
    path_length: float        # mm, longest line
    curvature: float = 0.0    # largest |d^2 (p, q) / ds^2| (phase per mm^3): the midpoint rule's error


def analyse_lines(p, q, spacing, inside=None):
    """Rates of ``(p, q)`` given as (lines, points) arrays sampled every ``spacing`` mm.

    ``inside`` (same shape, optional) marks the samples within the specimen; the
    field elsewhere is never marched, so it neither counts nor bounds a step.
    """
    p, q = np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64)
    inside = np.ones(p.shape, dtype=bool) if inside is None else np.asarray(inside, dtype=bool)
    p, q = np.where(inside, p, 0.0), np.where(inside, q, 0.0)
    # sqrt of squares, not np.hypot: several times faster here, and phase rates are nowhere near overflow.
    magnitude = np.sqrt(p * p + q * q)
    largest = float(magnitude.max()) if magnitude.size else 0.0
    length = spacing * float(np.count_nonzero(inside, axis=-1).max(initial=0))
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
        second_p, second_q = np.diff(p, 2, axis=-1), np.diff(q, 2, axis=-1)
        within = inside[:, :-2] & inside[:, 1:-1] & inside[:, 2:]
        squared = float(np.where(within, second_p * second_p + second_q * second_q, 0.0).max(initial=0.0))
        curvature = squared ** 0.5 / spacing ** 2
    return FieldRates(commuting, 2.0 * largest, float(turn.max(initial=0.0)) / spacing, length, curvature)


def magnus4_chords(generator, starts, direction, lengths, step):
    """Magnus-4 Jones quaternions of chords ``starts + t direction``, ``t`` in ``[0, lengths]``.

    As the integrator marches: ``ceil(L / step)`` equal steps from the camera side,
    later steps multiplied on the right. ``generator(points)`` returns the
    generator ``(p, q)`` per mm at ``(..., 3)`` points.
    """
    lengths = np.asarray(lengths, dtype=np.float64)
    counts = np.maximum(np.ceil(lengths / step - 1e-9), 1).astype(np.int64)
    h = lengths / counts
    index = np.arange(counts.max())
    live = index[None, :] < counts[:, None]
    first, second = (su2.generator(*generator(starts[:, None, :] + ((index[None, :] + g) * h[:, None])[..., None]
                                              * direction)) for g in GAUSS_POINTS)
    q = su2.magnus4(first, second, np.where(live, h[:, None], 0.0))
    # Ordered product along each chord by pairwise halving (associative; padding is the identity).
    while q[0].shape[1] > 1:
        if q[0].shape[1] % 2:
            q = tuple(np.concatenate([x, np.full((len(x), 1), float(i == 0))], axis=1) for i, x in enumerate(q))
        q = su2.multiply(tuple(x[:, 0::2] for x in q), tuple(x[:, 1::2] for x in q))
    return tuple(x[:, 0] for x in q)


def hardest_lines(p, q, inside, count):
    """Indices of the ``count`` sampled lines (rows) most likely to need fine steps.

    Half are the lines whose successive generators fail most to commute (the sum
    of ``|g_i x g_{i+1}|``: axes turning under strong stress, or jumping at an
    interface), half those with the most retardance (quadrature error).
    """
    p, q = np.where(inside, p, 0.0), np.where(inside, q, 0.0)
    commutator = np.abs(p[:, :-1] * q[:, 1:] - q[:, :-1] * p[:, 1:]).sum(axis=1)
    retardance = np.hypot(p, q).sum(axis=1)
    chosen = list(np.argsort(-commutator, kind="stable")[:count // 2])
    chosen += [i for i in np.argsort(-retardance, kind="stable") if i not in chosen][:count - len(chosen)]
    return np.array(sorted(chosen), dtype=np.int64)


def magnus4_step(generator, starts, direction, lengths, tolerance):
    """The longest Magnus-4 step meeting ``tolerance`` on the given chords, by step doubling.

    Halves the step from the longest chord; the error at step ``h`` is estimated
    as ``16/15 |I_h - I_{h/2}|``, the largest of the 16 intensities per chord and
    the ``QUANTILE`` percentile over chords (Richardson, fourth order), and
    trusted once it also fell about 16-fold from the step before.
    Returns ``(step, estimated error)``.
    """
    def intensities(q):
        return np.stack([scope.intensity(q) for scope in MEASUREMENTS.values()])

    # Chords of round lengths put step ends on interfaces at round depths at every halving, where
    # the rendered rays (a hair longer or shorter) straddle them: shorten each by an irrational share.
    lengths = np.asarray(lengths, dtype=np.float64) * (1.0 - 0.1 * ((np.arange(len(lengths)) * 0.618034) % 1.0))
    h = float(np.max(lengths))
    coarse = intensities(magnus4_chords(generator, starts, direction, lengths, h))
    previous = np.inf
    while True:
        fine = intensities(magnus4_chords(generator, starts, direction, lengths, h / 2))
        error = 16.0 / 15.0 * float(np.percentile(np.max(np.abs(coarse - fine), axis=0), QUANTILE))
        if (error <= tolerance and previous <= 32.0 * tolerance) or h <= SMALLEST_STEP:
            return h, error
        h, coarse, previous = h / 2, fine, error


def linear_step(rates: FieldRates, tolerance):
    """Midpoint-rule step for the summed generator: its error ``L h^2 / 24 |r''|`` stays under ``tolerance``.

    A generator constant along the rays needs one step per chord.
    """
    if rates.curvature == 0.0 or rates.path_length == 0.0:
        return max(rates.path_length, 1e-3)
    step = (24.0 * tolerance / (rates.path_length * rates.curvature)) ** 0.5
    return float(min(step, rates.path_length))
