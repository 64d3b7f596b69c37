"""What a dataset's channels measure of a traced ray: the forward model's last step, from Jones matrices to the
intensities each channel records.

A channel is a polariscope setting (its 16 measurements, as calibrated) and, in a dataset of several bands
(``physics/bands.py``), a band: the light its camera channel passes, an incoherent mix of wavelengths. Rays are
then traced with one Jones product per wavelength in one spectral march (``tracer/spectral.py``: the
:attr:`ChannelModel.view` passed to ``trace_rays``), and a band's intensity is its weights' sum of each
wavelength's. An intensity is a quadratic form of the Jones quaternion, ``I = q^T M q`` with ``M`` the
polariscope's, so a band's is ``<M, S>`` with ``S = sum_l w_l q_l q_l^T`` its coherency (ten numbers per band):
each channel then costs ten products whatever the band's width, where summing the channels' intensities
wavelength by wavelength cost one quadratic form per channel and wavelength (five times the iteration time of an
RGB camera's 28 wavelengths). Through refracting surfaces a wavelength's Jones matrix is general (interfaces
included, and a ghost path's beside it): a band is then its wavelengths' matrices scaled by the square roots of
their weights and added incoherently, one quadratic form per channel and wavelength.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import mitsuba as mi
import numpy as np

from ..dataset import Dataset
from ..physics import MEASUREMENTS, Polariscope, jones, su2
from ..physics.bands import BandSet
from ..render import phase_scale
from ..tracer import SCENE_VIEW, View


class ChannelModel:
    """Per channel of a dataset (in its ``channels`` order), the polariscope it was measured with and, for a
    dataset of several bands, its band; :attr:`view` is what ray batches are traced with."""

    def __init__(self, scopes: Sequence[Polariscope] = tuple(MEASUREMENTS.values()), bands: BandSet | None = None,
                 channel_bands: Sequence[int] | None = None, view: View = SCENE_VIEW):
        self.scopes, self.bands, self.view = tuple(scopes), bands, view
        self.channel_bands = None if channel_bands is None else tuple(channel_bands)
        if (bands is None) != (self.channel_bands is None) or \
                (self.channel_bands is not None and len(self.channel_bands) != len(self.scopes)):
            raise ValueError("a channel model of several bands needs the band of every channel")
        # Per channel of several bands, its quadratic form's entries on PAIRS (off-diagonal ones counted twice).
        self.forms = None if bands is None else [quadratic_form(scope) for scope in self.scopes]

    @classmethod
    def of(cls, dataset: Dataset, scene: mi.Scene, spectral_step: float | None = None) -> ChannelModel:
        """``dataset``'s channels; their wavelengths' phases scaled by ``C(lambda) / lambda`` in ``scene``; broad
        bands traced every ``spectral_step`` nm (``BandSet.resampled``; None: at the dataset's own)."""
        bands = dataset.bands
        if bands is None:
            return cls(dataset.polariscopes())
        if spectral_step is not None:
            bands = bands.resampled(spectral_step)
        lanes = tuple((f"lane.{index}", phase_scale(scene, 1.0, float(w))) for index, w in enumerate(bands.wavelengths))
        return cls(dataset.polariscopes(), bands, dataset.channel_bands(), View(lanes=lanes))

    def __len__(self) -> int:
        return len(self.scopes)

    def intensities(self, traced: su2.Quaternion | jones.Biquaternion | list) -> list[mi.Float]:
        """Each channel's intensity from a ray batch's Jones matrices (``TracedRays.jones()``: one per
        wavelength where the dataset has bands, quaternions along straight rays, general matrices where
        surfaces refract)."""
        if self.bands is None:
            return [scope.intensity(traced) for scope in self.scopes]
        if isinstance(traced[0], jones.Incoherent) or len(traced[0]) == 2:     # general matrices (refracted)
            mixes = [jones.Incoherent(tuple(_scaled(m, math.sqrt(float(w))) for w, m in zip(weights, traced) if w > 0))
                     for weights in self.bands.weights]
            return [scope.intensity(mixes[band]) for scope, band in zip(self.scopes, self.channel_bands)]
        coherencies = [tuple(sum(float(w) * q[i] * q[j] for w, q in zip(weights, traced) if w > 0) for i, j in PAIRS)
                       for weights in self.bands.weights]
        return [sum(m * s for m, s in zip(form, coherencies[band]) if m != 0.0)
                for form, band in zip(self.forms, self.channel_bands)]


def _scaled(matrix: jones.Biquaternion | jones.Incoherent, factor: float):
    """A general Jones matrix (or incoherent paths' matrices) times ``factor``: its intensities times its square."""
    if isinstance(matrix, jones.Incoherent):
        return jones.Incoherent(tuple(_scaled(path, factor) for path in matrix))
    return jones.Biquaternion(tuple(tuple(factor * x for x in part) for part in matrix))


# The entries (i, j), i <= j, of a symmetric 4 x 4 matrix.
PAIRS = tuple((i, j) for i in range(4) for j in range(i, 4))


def quadratic_form(scope: Polariscope) -> tuple[float, ...]:
    """``M`` with ``scope.intensity(q) = q^T M q`` for a Jones quaternion ``q``, as its entries on :data:`PAIRS`
    (off-diagonal ones doubled), rounded to zero below 1e-12."""
    matrix = sum(np.outer(re, re) + np.outer(im, im) for re, im in scope.coefficients())
    return tuple(float(v) if abs(v) > 1e-12 else 0.0
                 for v in (matrix[i, j] * (1.0 if i == j else 2.0) for i, j in PAIRS))


NOMINAL = ChannelModel()
