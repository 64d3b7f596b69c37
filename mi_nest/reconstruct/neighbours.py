"""A data term on how the Jones matrix changes from a pixel to the next: the fringes' local slope.

The intensities of a pixel are periodic in its retardance, so a field scaled by ``s`` fits them at every
``s`` that wraps each ray's phase onto the truth's: with ``N`` fringes along a ray the loss has minima
``1 / N`` apart in ``s``, and a descent from zero stops at the first it meets. The rotation that takes a
pixel's Jones matrix to its neighbour's, ``conj(q_1) q_2``, turns by the retardance's difference between the
two, under half a turn wherever the pixels resolve the fringes: fitted against the same rotation recovered from
the measurements (``physics/recovery.py``, up to the sign no intensity sees), its first wrapped minimum lies
where the field's slope, not its value, has wrapped, about ``pi / (the phase step between pixels)`` times the
truth, so the descent from zero meets the truth first. Like per-view unwrapping it reads the phase's slope; unlike
it, nothing is integrated along the image, so a pixel that aliases spoils its own pair, not a region.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..arrays import device_array
from ..dataset import Dataset
from ..physics import su2
from ..physics.recovery import jones_and_polarisation
from ..scene import scene_sensor
from ..tracer.setup import SceneSetup

# Image steps (row, column) to a pixel's four neighbours.
STEPS = np.array([(0, 1), (0, -1), (1, 0), (-1, 0)])
# A pair's weight is the lower polarisation of its two pixels to this power: on the 600 N disk's data the truth's
# rotation between neighbours and the measured one differ by 0.06 rad (median) where both keep 95% of the light
# polarised, by 0.8 rad at 50% to 70%, by 1.5 rad below 30% (the fringes denser than the pixels).
POLARISATION_POWER = 4
# Keeps the square root's gradient finite where the two relative rotations agree.
SMOOTHING = 1e-4


def neighbour_loss_applies(scene: mi.Scene, dataset: Dataset) -> bool:
    """Whether the neighbour loss can be fitted to ``dataset`` in ``scene``: straight rays (no surface refracts)
    at one wavelength (no bands); where it cannot, a weight given is refused (:attr:`NeighbourPairs.REFUSED`)."""
    return dataset.bands is None and not SceneSetup(scene, scene_sensor(scene), marching=False).refracting


def neighbours(rows: np.ndarray, columns: np.ndarray, resolution: tuple[int, int],
               rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One of the four neighbours of each pixel ``(rows, columns)``, at random; where that one lies off the
    ``resolution`` (width, height) image, the one opposite."""
    width, height = resolution
    step = STEPS[rng.integers(0, len(STEPS), len(rows))]
    outside = ((rows + step[:, 0] < 0) | (rows + step[:, 0] >= height) |
               (columns + step[:, 1] < 0) | (columns + step[:, 1] >= width))
    step[outside] *= -1
    return rows + step[:, 0], columns + step[:, 1]


class NeighbourTargets:
    """Each view's Jones quaternions and polarisation recovered from its measurements (``physics/recovery.py``),
    computed when first needed and kept (5 floats a pixel), the least recently used dropped past as many views as
    the dataset's own cache holds of their measurements (``views_kept``): never more than 5/16 of its memory."""

    def __init__(self, dataset: Dataset):
        self.dataset = dataset
        width, height = dataset.resolution
        view_bytes = len(dataset.channels) * np.dtype(np.float32).itemsize * width * height
        self.views_kept = max(1, dataset.cache_bytes // view_bytes)
        self._views = OrderedDict()

    def view(self, position: int) -> np.ndarray:
        """``(H, W, 5)``: rotation ``position``'s recovered quaternions and, last, their polarisation."""
        if position in self._views:
            self._views.move_to_end(position)
        else:
            q, polarisation = jones_and_polarisation(self.dataset.measurements(position), self.dataset.polariscopes())
            self._views[position] = np.concatenate([q, polarisation[..., None]], axis=-1).astype(np.float32)
            if len(self._views) > self.views_kept:
                self._views.popitem(last=False)
        return self._views[position]

    def relative(self, positions: np.ndarray, rows: np.ndarray, columns: np.ndarray, next_rows: np.ndarray,
                 next_columns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(N, 4)``: the rotation from each pixel's recovered Jones quaternion to its neighbour's (up to sign),
        and ``(N,)`` the lower polarisation of the two: how far the pair's measurements describe one Jones matrix
        each."""
        first = np.empty((len(rows), 5), dtype=np.float32)
        second = np.empty_like(first)
        for position in np.unique(positions):
            chosen = positions == position
            recovered = self.view(int(position))
            first[chosen] = recovered[rows[chosen], columns[chosen]]
            second[chosen] = recovered[next_rows[chosen], next_columns[chosen]]
        relative = np.stack(su2.multiply(su2.conjugate(tuple(first[:, :4].T)), tuple(second[:, :4].T)), axis=-1)
        return relative, np.minimum(first[:, 4], second[:, 4])

    def pairs(self, positions: np.ndarray, rows: np.ndarray, columns: np.ndarray,
              rng: np.random.Generator) -> NeighbourPairs:
        """The pixels ``(positions, rows, columns)``, a random neighbour of each and what their measurements say."""
        next_rows, next_columns = neighbours(rows, columns, self.dataset.resolution, rng)
        measured, polarisation = self.relative(positions, rows, columns, next_rows, next_columns)
        return NeighbourPairs((np.concatenate([positions, positions]), np.concatenate([rows, next_rows]),
                               np.concatenate([columns, next_columns])), measured,
                              polarisation ** POLARISATION_POWER)


@dataclass(frozen=True)
class NeighbourPairs:
    """A batch of pixel pairs: ``pixels`` (positions, rows, columns), the first pixel of each pair, then the second;
    the ``measured`` rotation between them and each pair's weight."""
    pixels: tuple[np.ndarray, np.ndarray, np.ndarray]
    measured: np.ndarray
    weights: np.ndarray

    REFUSED = ("neighbour_loss compares the Jones quaternions of straight rays at one wavelength, and this dataset "
               "has several bands or its scene refracts: give neighbour_loss=0")

    def loss(self, jones: su2.Quaternion, offset: int) -> mi.Float:
        """:func:`relative_rotation_loss` of the pairs, whose rays' Jones quaternions follow ``offset`` others in
        ``jones`` (a batch's, traced with them)."""
        if not (isinstance(jones, tuple) and len(jones) == 4):
            raise ValueError(self.REFUSED)
        count = len(self.measured)
        index = dr.arange(mi.UInt32, count) + offset
        first = tuple(dr.gather(mi.Float, x, index) for x in jones)
        second = tuple(dr.gather(mi.Float, x, index + count) for x in jones)
        return relative_rotation_loss(first, second, self.measured, self.weights)


def relative_rotation_loss(first: su2.Quaternion, second: su2.Quaternion, measured: np.ndarray,
                           weights: np.ndarray | None = None) -> mi.Float:
    """Mean of ``sin(theta / 2)`` over the pairs, ``theta`` the angle between the traced rotation from ``first`` to
    ``second`` (Jones quaternions of the pairs' rays) and the ``measured`` one (:meth:`NeighbourTargets.relative`):
    zero where they agree, whatever either pixel's sign; ``weights`` (N,) weigh the pairs (None: alike)."""
    traced = su2.multiply(su2.conjugate(first), second)
    count = len(measured)
    target = device_array(mi.Float, np.asarray(measured, dtype=np.float32).T.ravel())
    index = dr.arange(mi.UInt32, count)
    cosine = sum(t * dr.gather(mi.Float, target, index + k * count) for k, t in enumerate(traced))
    error = dr.sqrt(dr.maximum(1.0 - dr.square(cosine), 0.0) + SMOOTHING)
    if weights is None:
        return dr.mean(error)
    # Normalised on the device: a literal sum would build a new kernel every batch.
    weights = device_array(mi.Float, np.asarray(weights, dtype=np.float32))
    return dr.sum(error * weights) / dr.maximum(dr.sum(weights), 1e-6)
