"""The camera model of a dataset: read noise, shot noise, quantisation, the polarisation mosaic.

Intensities are normalised (1 = free space between parallel polarisers). A
seeded generator per rotation makes every image reproducible on its own, so a
resumed simulation writes the same files as an uninterrupted one.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Optional

import numpy as np
from scipy.ndimage import convolve

# The IMX250MZR's 2x2 micro-polariser cell (analyser angles, degrees): 90 45 over 135 0.
MOSAIC = ((90, 45), (135, 0))


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

    def capture(self, images: dict, rotation_index: int) -> dict:
        """Noisy captures of ``{"pol.b1.b2.a2": (H, W)}`` ideal normalised intensities."""
        if self.is_ideal:
            return {name: np.asarray(image, dtype=np.float32) for name, image in images.items()}
        rng = np.random.default_rng([self.seed, rotation_index])
        names = sorted(images)
        stack = np.stack([np.asarray(images[n], dtype=np.float64) for n in names])
        if self.mosaic:
            stack = _through_mosaic(names, stack)
        if self.full_well is not None:
            stack = rng.poisson(np.clip(stack, 0.0, None) * self.full_well) / self.full_well
        stack = stack + rng.normal(0.0, self.read_noise, stack.shape) if self.read_noise else stack
        if self.bits is not None:
            levels = 2 ** self.bits - 1
            stack = np.round(np.clip(stack / self.saturation, 0.0, 1.0) * levels) / levels * self.saturation
        if self.mosaic:
            stack = _demosaic(names, stack)
        return {name: image.astype(np.float32) for name, image in zip(names, stack)}


def analyser_of(name: str) -> int:
    return int(name.split(".")[-1])


def mosaic_mask(analyser: int, shape: tuple[int, int]) -> np.ndarray:
    """Where the micro-polariser ``analyser`` (degrees) sits in an image of ``shape``."""
    mask = np.zeros(shape, dtype=bool)
    for row, cells in enumerate(MOSAIC):
        for column, angle in enumerate(cells):
            if angle == analyser:
                mask[row::2, column::2] = True
    return mask


def _through_mosaic(names, stack):
    """Each analyser image keeps only its own micro-polariser pixels (the sensor's raw frame)."""
    return np.stack([np.where(mosaic_mask(analyser_of(n), image.shape), image, 0.0) for n, image in zip(names, stack)])


# Bilinear demosaicking of a channel sampled on every other row and column.
_BILINEAR = np.array([[0.25, 0.5, 0.25], [0.5, 1.0, 0.5], [0.25, 0.5, 0.25]])


def _interpolated(raw, analyser):
    """Full-resolution image of one micro-polariser from a raw frame (bilinear over its own pixels)."""
    mask = mosaic_mask(analyser, raw.shape).astype(np.float64)
    return convolve(raw * mask, _BILINEAR, mode="mirror") / convolve(mask, _BILINEAR, mode="mirror")


def _demosaic(names, stack):
    return np.stack([_interpolated(image, analyser_of(name)) for name, image in zip(names, stack)])


def demosaic(raw: np.ndarray) -> dict[int, np.ndarray]:
    """``{analyser: (H, W)}`` from a raw polarisation-camera frame ``(H, W)`` (the cell of :data:`MOSAIC`)."""
    raw = np.asarray(raw, dtype=np.float64)
    if raw.ndim != 2 or raw.shape[0] % 2 or raw.shape[1] % 2:
        raise ValueError(f"a raw mosaic frame is a 2D image of even size, got shape {raw.shape}")
    return {analyser: _interpolated(raw, analyser) for analyser in sorted({a for row in MOSAIC for a in row})}
