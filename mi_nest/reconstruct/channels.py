"""What a dataset's channels measure of a traced ray: the forward model's last step, from Jones matrices to the
intensities each channel records.

A channel is a polariscope setting (its 16 measurements, as calibrated) and, in a dataset of several bands
(``physics/bands.py``), a band: the light its camera channel passes, an incoherent mix of wavelengths. Rays are
then traced with one Jones product per wavelength in one spectral march (``tracer/spectral.py``: the
:attr:`ChannelModel.view` passed to ``trace_rays``), and a band's intensity is its weights' sum of each
wavelength's (a ``jones.Incoherent`` of the products scaled by the weights' square roots: the intensities are
quadratic in them).
"""
from __future__ import annotations

from collections.abc import Sequence

import mitsuba as mi

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

    @classmethod
    def of(cls, dataset: Dataset, scene: mi.Scene) -> ChannelModel:
        """``dataset``'s channels; their wavelengths' phases scaled by ``C(lambda) / lambda`` in ``scene``."""
        bands = dataset.bands
        if bands is None:
            return cls(dataset.polariscopes())
        lanes = tuple((f"lane.{index}", phase_scale(scene, 1.0, float(w))) for index, w in enumerate(bands.wavelengths))
        return cls(dataset.polariscopes(), bands, dataset.channel_bands(), View(lanes=lanes))

    def __len__(self) -> int:
        return len(self.scopes)

    def intensities(self, traced: su2.Quaternion | jones.Biquaternion | list) -> list[mi.Float]:
        """Each channel's intensity from a ray batch's Jones matrices (``TracedRays.jones()``: one per
        wavelength where the dataset has bands)."""
        if self.bands is None:
            return [scope.intensity(traced) for scope in self.scopes]
        mixes = [jones.Incoherent(tuple(su2.scale(q, float(w) ** 0.5) for w, q in zip(weights, traced) if w > 0))
                 for weights in self.bands.weights]
        return [scope.intensity(mixes[band]) for scope, band in zip(self.scopes, self.channel_bands)]


NOMINAL = ChannelModel()
