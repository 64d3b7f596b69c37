"""Object masks: from the measurements alone (real captures) and exact (simulations).

Free space leaves the light linearly polarised after QWP2 for three of the four
(QWP1, QWP2) settings (LP1 at 90: with QWP1 at 90 and QWP2 at 45 it leaves
circular), so behind free space those settings show a degree of linear
polarisation (DoLP) of 1. A specimen changes the polarisation, so the smallest
DoLP over those settings drops wherever the specimen is birefringent. Zero-stress
parts of a specimen are invisible to any polariscope; filling the holes of the
mask recovers those enclosed by stressed material.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import binary_fill_holes

from ..physics import MEASUREMENTS, su2
from ..physics.polariscope import (ANALYZERS, INPUT_QWP_SETTINGS, OUTPUT_QWP_SETTINGS, POLARIZER, measurement_name,
                                  standard_polariscope)


def linear_settings() -> list[tuple[int, int]]:
    """The (b1, b2) settings whose free-space output is linearly polarised."""
    identity = su2.identity(np.zeros(1))
    return [(b1, b2) for b1 in INPUT_QWP_SETTINGS for b2 in OUTPUT_QWP_SETTINGS
            if dolp([standard_polariscope(POLARIZER, b1, b2, a).intensity(identity) for a in ANALYZERS])[0] > 0.999]


def dolp(by_analyser: Sequence[np.ndarray]) -> np.ndarray:
    """Degree of linear polarisation from the four analyser images ``(I0, I45, I90, I135)``."""
    i0, i45, i90, i135 = by_analyser
    total = 0.5 * (i0 + i45 + i90 + i135)
    return np.hypot(i0 - i90, i45 - i135) / np.maximum(total, 1e-12)


def min_dolp(channels: dict[str, np.ndarray]) -> np.ndarray:
    """The smallest DoLP over the linear-output settings, per pixel."""
    values = [dolp([channels[measurement_name(b1, b2, a)] for a in ANALYZERS]) for b1, b2 in linear_settings()]
    return np.min(values, axis=0)


def dolp_mask(channels: dict[str, np.ndarray], threshold: float = 0.95, fill_holes: bool = True) -> np.ndarray:
    """Object mask of one rotation from its 16 measurements: DoLP below ``threshold``."""
    mask = min_dolp(channels) < threshold
    return binary_fill_holes(mask) if fill_holes else mask


def banded_dolp_mask(channels: dict[str, np.ndarray], bands: Sequence[str] | None,
                     threshold: float = 0.95) -> np.ndarray:
    """The object mask of a rotation measured in ``bands`` (channels ``<band>.pol...``; None: one band, ``pol...``):
    free space shows a DoLP of 1 in every band, so the specimen is where any band's drops."""
    prefixes = [""] if bands is None else [f"{band}." for band in bands]
    return np.any([dolp_mask({name: channels[prefix + name] for name in MEASUREMENTS}, threshold)
                   for prefix in prefixes], axis=0)


@dataclass(frozen=True)
class MaskAgreement:
    iou: float
    precision: float    # of the DoLP mask's pixels, the share inside the specimen
    recall: float       # of the specimen's pixels, the share the DoLP mask found

    def describe(self) -> str:
        return f"IoU {self.iou:.3f}, precision {self.precision:.3f}, recall {self.recall:.3f}"


def agreement(estimated: np.ndarray, exact: np.ndarray) -> MaskAgreement:
    estimated, exact = np.asarray(estimated, dtype=bool), np.asarray(exact, dtype=bool)
    both = np.count_nonzero(estimated & exact)
    union = np.count_nonzero(estimated | exact)
    return MaskAgreement(both / union if union else 1.0,
                         both / max(np.count_nonzero(estimated), 1) if estimated.any() else 1.0,
                         both / max(np.count_nonzero(exact), 1) if exact.any() else 1.0)
