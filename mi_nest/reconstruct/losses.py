"""What a reconstruction minimises: the intensities' L1 error, or the Two-step's generator error."""
from __future__ import annotations

from collections.abc import Sequence

import drjit as dr
import mitsuba as mi
import numpy as np

from ..physics import MEASUREMENTS, Polariscope
from ..physics.jones import Biquaternion
from ..physics.su2 import Quaternion
from ..arrays import device_array
from .channels import NOMINAL, ChannelModel


def intensities(q: Quaternion | Biquaternion,
                polariscopes: Sequence[Polariscope] = tuple(MEASUREMENTS.values())) -> list[mi.Float]:
    """The normalised intensities of ``polariscopes`` (default the nominal 16, in dataset channel order) for a
    Jones quaternion, or a refracted path's general Jones matrix (a pair of quaternions)."""
    return [scope.intensity(q) for scope in polariscopes]


def l1_loss(q: Quaternion | list, targets: np.ndarray, pixel_samples: int = 1, weights: mi.Float | None = None,
            channels: ChannelModel = NOMINAL) -> mi.Float:
    """Mean absolute error of the intensities of ``channels`` (a dataset's: ``ChannelModel.of``; default the
    nominal 16) against ``targets`` (N, channels), from the traced rays' Jones matrices ``q``.

    ``q`` holds ``pixel_samples`` consecutive rays per target pixel; their
    intensities are averaged first, as the camera integrates over its pixels.
    ``weights`` (N, 0 or 1) selects the pixels that count.
    """
    targets = np.asarray(targets, dtype=np.float32)
    # One upload of every channel, read per channel on the device: 16 uploads were 16 host calls an iteration.
    flat = device_array(mi.Float, targets.ravel())
    pixel = dr.arange(mi.UInt32, len(targets)) * targets.shape[1]
    error = 0.0
    for channel, predicted in enumerate(channels.intensities(q)):
        if pixel_samples > 1:
            predicted = dr.block_sum(predicted, pixel_samples) / pixel_samples
        error = error + dr.abs(predicted - dr.gather(mi.Float, flat, pixel + channel))
    # One reduction of the summed channels, not one per channel.
    total = dr.sum(error if weights is None else error * weights)
    count = len(targets) if weights is None else dr.maximum(dr.sum(weights), 1.0)
    return total / (count * targets.shape[1])


def generator_loss(state: tuple[mi.Float, ...], targets: np.ndarray, pixel_samples: int = 1) -> mi.Float:
    """Mean squared error of the linear model's summed generator ``(b, c)`` against ``targets`` (N, 2).

    The Two-step baseline's tomography: least squares on unwrapped data.
    """
    targets = np.asarray(targets, dtype=np.float32)
    total = 0.0
    for channel, predicted in enumerate(state[1:3]):
        if pixel_samples > 1:
            predicted = dr.block_sum(predicted, pixel_samples) / pixel_samples
        total = total + dr.sum(dr.square(predicted - device_array(mi.Float, targets[:, channel])))
    return total / len(targets)
