"""The camera model of a dataset: read noise, shot noise, quantisation, the polarisation (and colour) mosaic.

Intensities are normalised (1 = free space between parallel polarisers). A
seeded generator per rotation makes every image reproducible on its own, so a
resumed simulation writes the same files as an uninterrupted one.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Optional, Sequence

import numpy as np
from scipy.ndimage import convolve

from ..physics.bands import BandSet
from .format import band_of

# The IMX250MZR's 2x2 micro-polariser cell (analyser angles, degrees): 90 45 over 135 0.
MOSAIC = ((90, 45), (135, 0))
# The IMX250MYR's colour filters: one colour over each 2x2 polariser cell, the cells in a Bayer pattern.
BAYER = (("red", "green"), ("green", "blue"))


@dataclass(frozen=True)
class CameraModel:
    read_noise: float = 0.0             # Gaussian, standard deviation in normalised intensity
    full_well: Optional[float] = None   # electrons at intensity 1; photon shot noise when set
    bits: Optional[int] = None          # quantisation (8 or 12); None keeps floats
    saturation: float = 1.0             # intensity read as full scale (clipped above)
    mosaic: bool = False                # sample through the 2x2 micro-polariser mosaic, then demosaic
    seed: int = 0

    def __post_init__(self):
        if not (self.read_noise >= 0.0 and np.isfinite(self.read_noise)):
            raise ValueError(f"read_noise must be finite and >= 0, got {self.read_noise}")
        if self.full_well is not None and not self.full_well > 0:
            raise ValueError(f"full_well must be positive, got {self.full_well}")
        if self.bits not in (None, 8, 10, 12, 16):
            raise ValueError(f"bits must be 8, 10, 12 or 16, got {self.bits}")
        if not self.saturation > 0:
            raise ValueError(f"saturation must be positive, got {self.saturation}")

    @property
    def is_ideal(self) -> bool:
        return self.read_noise == 0 and self.full_well is None and self.bits is None and not self.mosaic

    def to_dict(self) -> dict:
        return asdict(self)

    def capture(self, images: dict, rotation_index: int, bands: BandSet | None = None) -> dict:
        """Noisy captures of ``{"pol.b1.b2.a2": (H, W)}`` ideal normalised intensities (of each band's:
        ``<band>.pol.b1.b2.a2``, for ``bands``; through the mosaic, each under its colour filter,
        :func:`bayer_sites`)."""
        if self.is_ideal:
            return {name: np.asarray(image, dtype=np.float32) for name, image in images.items()}
        rng = np.random.default_rng([self.seed, rotation_index])
        names = sorted(images)
        stack = np.stack([np.asarray(images[n], dtype=np.float64) for n in names])
        sites = None
        if self.mosaic:
            sites = {} if bands is None else bayer_sites(bands)
            stack = _through_mosaic(names, stack, sites)
        if self.full_well is not None:
            stack = rng.poisson(np.clip(stack, 0.0, None) * self.full_well) / self.full_well
        stack = stack + rng.normal(0.0, self.read_noise, stack.shape) if self.read_noise else stack
        if self.bits is not None:
            levels = 2 ** self.bits - 1
            stack = np.round(np.clip(stack / self.saturation, 0.0, 1.0) * levels) / levels * self.saturation
        if self.mosaic:
            stack = _demosaic(names, stack, sites)
        return {name: image.astype(np.float32) for name, image in zip(names, stack)}


def analyser_of(name: str) -> int:
    return int(name.split(".")[-1])


def bayer_sites(bands: BandSet) -> dict[str, str]:
    """Which colour filter of :data:`BAYER` each of three bands is seen through: by their centre wavelengths,
    the longest red, the shortest blue."""
    if len(bands) != 3:
        raise ValueError(f"a colour mosaic has red, green and blue filters; {len(bands)} band(s) cannot sit under "
                         "them: simulate three bands (--bands rgb, or three wavelengths), or leave out --mosaic")
    shortest_first = [bands.names[i] for i in np.argsort(bands.weights @ bands.wavelengths)]
    return dict(zip(shortest_first, ("blue", "green", "red")))


def filter_colours(bands: BandSet) -> list[str]:
    """The colour filter of each band of ``bands``, in order (:func:`bayer_sites`)."""
    sites = bayer_sites(bands)
    return [sites[band] for band in bands.names]


def mosaic_mask(analyser: int, shape: tuple[int, int], colour: str | None = None) -> np.ndarray:
    """Where the micro-polariser ``analyser`` (degrees) sits in an image of ``shape``; under the ``colour``
    filter only, for a colour sensor (:data:`BAYER`)."""
    mask = np.zeros(shape, dtype=bool)
    for row, cells in enumerate(MOSAIC):
        for column, angle in enumerate(cells):
            if angle == analyser:
                mask[row::2, column::2] = True
    if colour is not None:
        # Each pixel's 2 x 2 polariser cell, and that cell's place in the Bayer pattern of cells.
        cell_row, cell_column = (np.arange(n) // 2 % 2 for n in shape)
        mask &= np.array(BAYER)[cell_row[:, None], cell_column[None, :]] == colour
    return mask


def _site(name, sites):
    """The colour filter a channel ``<band>.pol...`` is seen through (None: a monochrome sensor)."""
    band = band_of(name)
    return sites.get(band) if sites and band is not None else None


def _through_mosaic(names, stack, sites):
    """Each analyser image keeps only its own micro-polariser pixels (the sensor's raw frame)."""
    return np.stack([np.where(mosaic_mask(analyser_of(n), image.shape, _site(n, sites)), image, 0.0)
                     for n, image in zip(names, stack)])


def _tent(radius: int) -> np.ndarray:
    """The separable tent ``(1 - |d| / radius)`` over ``|d| < radius``: bilinear interpolation, by normalised
    convolution, of samples ``radius`` pixels apart."""
    line = 1.0 - np.abs(np.arange(1 - radius, radius)) / radius
    return np.outer(line, line)


def _interpolated(raw, analyser, colour=None):
    """Full-resolution image of one micro-polariser (under one colour filter) from a raw frame: bilinear over
    its own pixels, every 2nd (every 4th under a colour filter) along each axis."""
    mask = mosaic_mask(analyser, raw.shape, colour).astype(np.float64)
    kernel = _tent(2 if colour is None else 4)
    return convolve(raw * mask, kernel, mode="mirror") / convolve(mask, kernel, mode="mirror")


def _demosaic(names, stack, sites):
    return np.stack([_interpolated(image, analyser_of(name), _site(name, sites)) for name, image in zip(names, stack)])


def raw_frame(images: dict[int, np.ndarray], colours: Sequence[str] | None = None) -> np.ndarray:
    """The raw frame ``(H, W)`` a polarisation camera records of ``{analyser: (H, W)}`` images: each pixel its own
    micro-polariser's (:data:`MOSAIC`). A colour camera's images are ``(bands, H, W)``, band ``k`` seen through the
    colour filter ``colours[k]`` (:data:`BAYER`)."""
    return sum(np.where(mosaic_mask(analyser, image.shape[-2:], colour), band, 0.0)
               for analyser, image in images.items()
               for colour, band in (zip(colours, image) if colours is not None else [(None, image)]))


def demosaic(raw: np.ndarray, colours: Sequence[str] | None = None) -> dict[int, np.ndarray]:
    """``{analyser: (H, W)}`` from a raw polarisation-camera frame ``(H, W)`` (the cell of :data:`MOSAIC`); a
    colour camera's ``{analyser: (len(colours), H, W)}``, one image per colour filter of :data:`BAYER`."""
    raw = np.asarray(raw, dtype=np.float64)
    cell = 4 if colours is not None else 2
    if raw.ndim != 2 or raw.shape[0] % cell or raw.shape[1] % cell:
        raise ValueError(f"a raw {'colour ' if colours is not None else ''}mosaic frame is a 2D image whose sides "
                         f"are multiples of {cell}, got shape {raw.shape}")
    analysers = sorted({a for row in MOSAIC for a in row})
    if colours is None:
        return {analyser: _interpolated(raw, analyser) for analyser in analysers}
    return {analyser: np.stack([_interpolated(raw, analyser, colour) for colour in colours]) for analyser in analysers}
