"""The ``auto`` method: how finely the field must be marched, analysed before a render.

The field inside every specimen is sampled along lines parallel to the light
and projected to the step generator ``(p, q)`` (phase per mm, i.e.
``pi C / lambda`` times ``(s_uu - s_vv, 2 s_uv)``). Steps commute exactly when
the transverse principal axes, ``0.5 atan2(q, p)``, are the same all along every
line (wherever the stress is not negligible): then one exponential of the
summed generator (``linear``) is exact. Otherwise ``magnus4`` marches, with the
longest step that step doubling on the hardest chords finds within the
tolerance (docs/methods.md).
"""
from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_nest import occupancy
from mi_nest.physics import MEASUREMENTS, projection, su2

from .methods import ChainMethod, Decision, GeneratorField, Linear, Magnus4, Method

if TYPE_CHECKING:
    from .setup import SceneSetup

# Lines across each specimen and samples along each line.
LINES, SAMPLES = 32, 65
# Of those lines, how many are marched at halving steps to estimate the magnus4 error.
CHORDS = 64
# The step when no analysis line meets a specimen.
FALLBACK_STEP = 1.0
# Generators below this fraction of the largest one carry no axis worth comparing.
NEGLIGIBLE = 1e-3
# Axis changes below this (radians) along a line count as commuting (float32 noise).
COMMUTING_ANGLE = 1e-4
# Step doubling trusts an error estimate once the step is this fine and the estimate shrank
# like a fourth-order method's from the step before (a coarse pair can agree by chance).
SMALLEST_STEP = 1e-3
# The error that must meet the tolerance: this percentile over the chords marched (the
# hardest few per cent of a specimen's lines). A stress singularity (a contact point)
# needs vanishing steps in a few rays whose fringes alias at any resolution anyway.
QUANTILE = 90.0

class Auto:
    """``auto``: before a render, analyse the field along the light and pick ``linear`` or ``magnus4``."""

    name = "auto"
    label = "linear or magnus4, chosen for the field before each render"

    def __init__(self, tolerance: float, jitter: bool = False):
        self.tolerance, self.jitter = tolerance, jitter

    @classmethod
    def from_options(cls, point: float, jitter: bool, tolerance: float) -> Auto:
        return cls(tolerance, jitter)

    def decide(self, setup: SceneSetup, scene: mi.Scene, sensor: mi.Sensor | None, step_size: float) -> Decision:
        if sensor is None:
            raise ValueError("photoelastic: 'auto' analyses the field as one camera sees it; rays drawn across "
                             "views need an explicit method and step_size")
        method, step_size, reason = choose(setup, scene, sensor, self.tolerance, Linear(jitter=self.jitter),
                                                Magnus4())
        logging.getLogger("mi_nest").info(reason)
        return Decision(method, step_size, reason)


@dataclass(frozen=True)
class FieldRates:
    commuting: bool
    retardance_rate: float    # rad of retardance per mm, largest
    rotation_rate: float      # rad of axis rotation per mm, largest
    path_length: float        # mm, longest line
    curvature: float = 0.0    # largest |d^2 (p, q) / ds^2| (phase per mm^3): the midpoint rule's error


def sample_lines(setup: SceneSetup, scene: mi.Scene, sensor: mi.Sensor) -> tuple[FieldRates | None, list, np.ndarray]:
    """The field inside every specimen sampled along lines parallel to the light: ``(rates over all specimens,
    per specimen (generator, p, q, inside, starts, crossings), the light's direction)``; rates None when no
    line crosses a specimen."""
    to_world = sensor.world_transform()
    k = -np.array(dr.normalize(to_world @ mi.Vector3f(0, 0, 1))).ravel()    # light travels towards the camera
    # The frame the walk marches in (SceneSetup.projection_coefficients), here on NumPy.
    right = tuple(np.array(setup.right).ravel())
    u, v = (np.array(x, dtype=np.float64) for x in projection.transverse_basis(tuple(k), right))
    rates, lines = [], []
    for shape, medium in setup.specimens:
        box = shape.bbox()
        corners = np.array([[x, y, z] for x in (box.min.x, box.max.x) for y in (box.min.y, box.max.y)
                            for z in (box.min.z, box.max.z)], dtype=np.float64)
        span = [(corners @ axis).min() for axis in (u, v, k)], [(corners @ axis).max() for axis in (u, v, k)]
        a, b = (np.linspace(lo, hi, LINES + 2)[1:-1] for lo, hi in zip(span[0][:2], span[1][:2]))
        s = np.linspace(span[0][2], span[1][2], SAMPLES)
        grid_a, grid_b, grid_s = np.meshgrid(a, b, s, indexing="ij")
        points = grid_a[..., None] * u + grid_b[..., None] * v + grid_s[..., None] * k
        starts = points[:, :, 0].reshape(-1, 3)
        crossings = occupancy.crossings_along_lines(scene, shape, starts, k)
        inside = (crossings[:, :, None] < (s - s[0])[None, None, :]).sum(axis=0) % 2 == 1
        if not inside.any():
            continue
        generator = generator_field(setup.phase_tensors[medium], u, v, setup.strongest_phase_scale)
        p, q = generator(points.reshape(inside.shape + (3,)))
        rates.append(analyse_lines(p, q, s[1] - s[0], inside))
        lines.append((generator, p, q, inside, starts, crossings))
    if not rates:
        return None, lines, k
    combined = FieldRates(all(r.commuting for r in rates), max(r.retardance_rate for r in rates),
                          max(r.rotation_rate for r in rates), max(r.path_length for r in rates),
                          max(r.curvature for r in rates))
    return combined, lines, k


def choose(setup: SceneSetup, scene: mi.Scene, sensor: mi.Sensor, tolerance: float, linear: Method,
           magnus4: ChainMethod) -> tuple[Method, float, str]:
    """``(method, step_size, reason)``: ``linear`` or ``magnus4``, from the fields sampled along the light."""
    combined, lines, k = sample_lines(setup, scene, sensor)
    if combined is None:
        return linear, FALLBACK_STEP, "photoelastic auto: no analysis line crossed a specimen; linear model"
    if combined.commuting:
        step = linear_step(combined, tolerance)
        return linear, step, (
            f"photoelastic auto: the principal axes do not turn along the light in any specimen, so the steps "
            f"commute and the linear model is exact; step {step:.3g} mm for the summed stress "
            f"(retardance up to {combined.retardance_rate:.3g} rad/mm)")
    # Step doubling on the chords themselves: rates alone cannot tell a field that turns from one that
    # is merely strong (a constant generator is exact at any step) or jumps once at an interface.
    chords = []
    for generator, p, q, inside, starts, crossings in lines:
        hardest = hardest_lines(p, q, inside, CHORDS)
        chords.append((generator, *_chords(starts[hardest], k, crossings[:, hardest])))
    step, error = min(doubled_step(magnus4, generator, starts, -k, lengths, tolerance)
                      for generator, starts, lengths in chords)
    count = sum(len(lengths) for _, _, lengths in chords)
    return magnus4, step, (
        f"photoelastic auto: the principal axes turn along the light (up to {combined.rotation_rate:.3g} rad/mm "
        f"between samples), so the linear model would be wrong; magnus4 with step {step:.3g} mm, where step "
        f"doubling on {count} chords estimates an error of {error:.2g} (tolerance {tolerance:g})")


def generator_field(phase_tensor: Callable, u: np.ndarray, v: np.ndarray, scale: float = 1.0) -> GeneratorField:
    """NumPy ``points -> (p, q)``: the step generator per mm of a ``phase_tensor`` in the basis (u, v), times
    ``scale`` (a view's factor on every phase)."""
    coefficients = projection.projection_coefficients(tuple(map(float, u)), tuple(map(float, v)))
    if scale != 1.0:
        coefficients = tuple(tuple(scale * c for c in part) for part in coefficients)

    def generator(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # One kernel from points to (p, q): projected where the field is sampled, two arrays come back, not six.
        shape = points.shape[:-1]
        flat = np.asarray(points, dtype=np.float32).reshape(-1, 3)
        p, q = projection.apply_coefficients(coefficients, phase_tensor(mi.Point3f(flat.T)))
        dr.eval(p, q)
        return tuple(np.broadcast_to(np.array(x, dtype=np.float64), (len(flat),)).reshape(shape) for x in (p, q))
    return generator


def _chords(starts, k, crossings):
    """Inside segments of each line as ``(camera-side ends, lengths)``: crossings pair up in order."""
    ends, lengths = [], []
    for line, distances in enumerate(crossings.T):
        distances = np.sort(distances[np.isfinite(distances)])
        for enter, leave in zip(distances[0::2], distances[1::2]):
            ends.append(starts[line] + leave * k)
            lengths.append(leave - enter)
    return np.array(ends).reshape(-1, 3), np.array(lengths)


def analyse_lines(p: np.ndarray, q: np.ndarray, spacing: float, inside: np.ndarray | None = None) -> FieldRates:
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


def hardest_lines(p: np.ndarray, q: np.ndarray, inside: np.ndarray, count: int) -> np.ndarray:
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


def doubled_step(method: ChainMethod, generator: GeneratorField, starts: np.ndarray, direction: np.ndarray,
                 lengths: np.ndarray, tolerance: float) -> tuple[float, float]:
    """The longest step of a fourth-order ``method`` meeting ``tolerance`` on the given chords, by step doubling.

    Halves the step from the longest chord; the error at step ``h`` is estimated
    as ``16/15 |I_h - I_{h/2}|``, the largest of the 16 intensities per chord and
    the ``QUANTILE`` percentile over chords (Richardson, fourth order), and
    trusted once it also fell about 16-fold from the step before.
    Returns ``(step, estimated error)``.
    """
    def intensities(q: su2.Quaternion) -> np.ndarray:
        return np.stack([scope.intensity(q) for scope in MEASUREMENTS.values()])

    # Chords of round lengths put step ends on interfaces at round depths at every halving, where
    # the rendered rays (a hair longer or shorter) straddle them: shorten each by an irrational share.
    lengths = np.asarray(lengths, dtype=np.float64) * (1.0 - 0.1 * ((np.arange(len(lengths)) * 0.618034) % 1.0))
    h = float(np.max(lengths))
    coarse = intensities(method.march_chords(generator, starts, direction, lengths, h))
    previous = np.inf
    while True:
        fine = intensities(method.march_chords(generator, starts, direction, lengths, h / 2))
        error = 16.0 / 15.0 * float(np.percentile(np.max(np.abs(coarse - fine), axis=0), QUANTILE))
        if (error <= tolerance and previous <= 32.0 * tolerance) or h <= SMALLEST_STEP:
            return h, error
        h, coarse, previous = h / 2, fine, error


def linear_step(rates: FieldRates, tolerance: float) -> float:
    """Midpoint-rule step for the summed generator: its error ``L h^2 / 24 |r''|`` stays under ``tolerance``.

    A generator constant along the rays needs one step per chord.
    """
    if rates.curvature == 0.0 or rates.path_length == 0.0:
        return max(rates.path_length, 1e-3)
    step = (24.0 * tolerance / (rates.path_length * rates.curvature)) ** 0.5
    return float(min(step, rates.path_length))


# A fixed step longer than this share of a specimen's thinnest side is checked against the field (the check samples
# the field along the light, about 10 ms: finer steps, the rule, skip it).
COARSE_SHARE = 0.25
# Axes that turn by more than this (rad) within one step of a field this strong make a step's exponential wrong.
TURN_PER_STEP = 0.3


def warn_if_coarse(setup, scene: mi.Scene, sensor: mi.Sensor | None, step: float) -> None:
    """Warn when a fixed ``step`` (mm) is so long that the field's principal axes turn within it while its phase
    grows: each step then multiplies the wrong exponential (the twisted block at 1000 mm renders 3.6 rad off)."""
    if sensor is None or not setup.specimens:
        return
    thinnest = min(float(dr.min(shape.bbox().extents())) for shape, _ in setup.specimens)
    if step <= COARSE_SHARE * thinnest:
        return
    rates, _, _ = sample_lines(setup, scene, sensor)
    if rates is None or rates.commuting:
        return
    reach = min(step, rates.path_length)
    turn, phase = rates.rotation_rate * reach, rates.retardance_rate * reach
    if turn > TURN_PER_STEP and phase > TURN_PER_STEP:
        finer = TURN_PER_STEP / max(rates.rotation_rate, rates.retardance_rate)
        warnings.warn(f"photoelastic: step_size {step:g} mm is coarse for this field: its principal axes turn by up "
                      f"to {turn:.2g} rad and its phase grows by up to {phase:.2g} rad within one step, so each step's "
                      f"exponential is far from the ordered product; use a step_size of at most about {finer:.2g} mm, "
                      "or method 'auto', which chooses one", RuntimeWarning, stacklevel=2)
