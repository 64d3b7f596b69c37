"""The Two-step baseline: per-view phase unwrapping, then linear tensor tomography.

Classical integrated photoelasticity, as the NeST paper's baseline:

1. per view, recover each pixel's Jones quaternion from its 16 intensities
   (``physics.recovery``) and unwrap it into the linear model's integrated
   generator ``g = (b, c)``: ``exp(g)`` is the retarder of the summed projected
   stress, ``|g|`` half its retardance, so ``g`` is linear in the field;
2. fit the field to ``g`` by least squares through the ``linear`` model
   (``optimize(method="two-step")``: the same ray batches and Adam, an L2 loss
   on ``g`` instead of the intensities).

Step 1 is where it fails: the measurement fixes ``g`` only up to whole turns,
``g + k pi g/|g|``, and the axis only up to its sign. The axis angle is
unwrapped first (doubled, so that the sign does not matter), which orients
``g``; then the signed phase ``2 |g|`` is unwrapped with
``skimage.restoration.unwrap_phase``, each connected region offset so that its
rim, where paths through the specimen are short, has no retardance. Isotropic
points, where the axis turns by a full turn around a pixel, and fringes
denser than the pixels break the unwrapping; axes that rotate along the ray
break the linear model.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from ..dataset import Dataset
from ..physics.recovery import quaternion_from_intensities


def _unwrap(phase, inside):
    from skimage.restoration import unwrap_phase
    return np.asarray(unwrap_phase(np.ma.array(phase, mask=~inside)).filled(0.0))


def _wrap(phase):
    return np.angle(np.exp(1j * phase))


def unwrapped_generator(q: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """``(H, W, 2)`` integrated linear-model generator ``(b, c)`` of one view's Jones quaternions ``(H, W, 4)``.

    ``inside`` (H, W) selects the pixels to unwrap over; outside them the result is zero.
    """
    q = np.asarray(q, dtype=np.float64)
    inside = np.asarray(inside, dtype=bool)
    result = np.zeros(q.shape[:2] + (2,))
    if not inside.any():
        return result
    q = q * np.where(q[..., :1] < 0, -1.0, 1.0)
    a, b, c = q[..., 0], q[..., 1], q[..., 2]
    # |g| modulo pi, folded into [0, pi/2] by the sign of q; the rotator part d is what the linear model lacks.
    magnitude = np.arctan2(np.hypot(b, c), a)
    axis = np.arctan2(c, b)
    # The axis is known up to a half turn (flipping it flips the sign of |g|): unwrap it doubled.
    axis_unwrapped = 0.5 * _unwrap(_wrap(2.0 * axis), inside)
    signed = magnitude * np.sign(np.cos(axis - axis_unwrapped) + 1e-30)
    phase = _unwrap(_wrap(2.0 * signed), inside)
    regions, count = ndimage.label(inside)
    rim = inside & ~ndimage.binary_erosion(inside)
    for region in range(1, count + 1):
        in_region = regions == region
        edge = rim & in_region
        turns = np.round(np.median(phase[edge if edge.any() else in_region]) / (2 * np.pi))
        phase[in_region] -= 2 * np.pi * turns
    half = 0.5 * phase * inside
    result[..., 0] = half * np.cos(axis_unwrapped)
    result[..., 1] = half * np.sin(axis_unwrapped)
    return result


class RetardanceTargets:
    """Step 1 over a dataset: each view's unwrapped generator, computed when first needed and kept."""

    def __init__(self, dataset: Dataset, mask: str | None = "mask.dolp"):
        self.dataset = dataset
        self.mask = mask
        self._views = {}

    def view(self, position: int) -> np.ndarray:
        """``(H, W, 2)`` unwrapped generator of rotation ``position``."""
        if position not in self._views:
            q = quaternion_from_intensities(self.dataset.measurements(position), self.dataset.polariscopes())
            if self.mask is None:
                inside = np.ones(q.shape[:2], dtype=bool)
            else:
                inside = self.dataset.view(position, [self.mask])[self.mask] > 0.5
            self._views[position] = unwrapped_generator(q, inside).astype(np.float32)
        return self._views[position]

    def at(self, positions: np.ndarray, rows: np.ndarray, columns: np.ndarray) -> np.ndarray:
        """``(N, 2)`` targets of the pixels ``(positions, rows, columns)`` of a ray batch."""
        out = np.empty((len(positions), 2), dtype=np.float32)
        for position in np.unique(positions):
            chosen = positions == position
            out[chosen] = self.view(int(position))[rows[chosen], columns[chosen]]
        return out
