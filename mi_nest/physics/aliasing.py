"""Fringes denser than the pixel grid: where a render's intensities alias.

A fringe is one order (2 pi) of retardance; sampling it needs two pixels, so
more than half an order between neighbouring pixels is above Nyquist. The
order must be unwrapped for its differences to mean anything: the folded
retardance of the Jones product cannot tell 0.1 from 1.1 orders. The linear
model's order, the norm of the summed step generators, is unwrapped (and exact
where the principal axes do not turn along the rays), so that is what is
differentiated here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

# Fringe orders per pixel above which the intensities alias (two pixels per fringe).
NYQUIST = 0.5
# Share of a specimen's pixels that may alias before an image counts as aliased: contact
# points and notches are stress singularities, dense beyond any resolution in a few pixels.
ALIASED_FRACTION = 0.01
# Mean share of a dataset's specimen pixels above Nyquist beyond which a reconstruction loses the phase in too
# much of the part: the disk at 100 N over 4 mm at 64 px aliases in 2.9% and reconstructs to 4.75%; at 300 N in
# 15% and to 18.6%; at 600 N in 29%, to 53% (docs/reconstruction.md, the accuracy suite).
UNRESOLVED_SHARE = 0.10
# Data in several bands lose the phase where the slowest beat between two bands (beat_factor) aliases in more than
# UNRESOLVED_BEAT_SHARE of the pixels, or each band alone (its shortest wavelength) in more than
# UNRESOLVED_BANDS_SHARE. Both sit in the gaps of the accuracy suite's band cases (docs/reconstruction.md, "What
# the bands tell apart"): on one machine, the 300 N disk's beat aliased in 0.7% reconstructed to 11.7% and in 3.8%
# to 18.3% (one band: 19%), the 600 N disk's in 4.0% to 38.1%; with the beat resolved, the stacked disks' bands
# aliased in 24% reconstructed to 8.9%, the 600 N disk's in 31% to 36.9%.
UNRESOLVED_BEAT_SHARE = 0.02
UNRESOLVED_BANDS_SHARE = 0.25


def beat_factor(band_scales, measured_scale: float) -> float | None:
    """The slowest beat between two bands as a multiple of the measured fringe order, or None for one band.

    ``band_scales`` are the bands' phase scales (``C(lambda) / lambda`` relative to the medium's own, each band's
    mean over its wavelengths) and ``measured_scale`` that of the order the aliasing guard read. The difference of
    two bands' orders, their beat, is their scales' difference times the order at scale one: where it is resolved,
    the bands' folded phases together fix each band's whole order (two-wavelength unwrapping), however aliased each
    band is alone. The closest two bands beat slowest.
    """
    scales = np.sort(np.asarray(band_scales, dtype=np.float64).ravel())
    if scales.size < 2:
        return None
    return float(np.diff(scales).min() / measured_scale)


def phase_lost(aliased_share: float, beat_share: float | None = None) -> bool:
    """Whether data whose fringes alias in ``aliased_share`` of the specimen's pixels (on average over the views)
    have lost the phase in too much of the part to reconstruct. Data in several bands give their slowest beat's
    share ``beat_share`` too (None: one band): the beat tells the orders apart, so that each band may alias more."""
    if beat_share is not None:
        return beat_share > UNRESOLVED_BEAT_SHARE or aliased_share > UNRESOLVED_BANDS_SHARE
    return aliased_share > UNRESOLVED_SHARE


def summary_shares(summary: dict) -> tuple[float, float | None]:
    """The aliased shares :func:`phase_lost` takes from a ``fringe_aliasing`` summary (``dataset.json``): each
    band's, and the slowest beat's where there are several bands (else None)."""
    beat = summary.get("beat")
    return summary["mean_fraction"], beat["mean_fraction"] if beat else None


def bands_lost_phase(aliased_share: float, beat_share: float) -> str:
    """Why data in several bands, aliased in ``aliased_share`` of the pixels each and ``beat_share`` in their
    slowest beat, have lost the phase (:func:`phase_lost`)."""
    if beat_share > UNRESOLVED_BEAT_SHARE:
        return (f"even the slowest beat between its bands (the difference of two bands' fringe orders, which tells "
                f"the orders apart) is denser than the pixels in {100 * beat_share:.1f}% of the specimen's pixels on "
                f"average (over {100 * UNRESOLVED_BEAT_SHARE:.0f}% loses the phase)")
    return (f"the fringes of each band are denser than the pixels in {100 * aliased_share:.0f}% of the specimen's "
            f"pixels on average (over {100 * UNRESOLVED_BANDS_SHARE:.0f}% loses the phase even where the bands' "
            f"beat, here {100 * beat_share:.1f}%, is resolved)")


def unresolved_dataset(summary: dict | None, where: str) -> str | None:
    """What is wrong with a dataset whose ``fringe_aliasing`` summary (``dataset.json``) says its fringes are too
    dense to reconstruct, and how to fix it (one line); None when they are resolved well enough."""
    if not summary:
        return None
    share, beat = summary_shares(summary)
    if not phase_lost(share, beat):
        return None
    if beat is not None:
        return (f"{where}: {bands_lost_phase(share, beat)}; simulate or capture it again with less load or more "
                "pixels (--res)" + (", or in bands closer together, whose beat is slower"
                                    if beat > UNRESOLVED_BEAT_SHARE else ""))
    factor = max(2, math.ceil(summary["densest"] / NYQUIST))
    return (f"{where}: fringes are denser than the pixels in {100 * share:.0f}% of the "
            f"specimen's pixels on average (more than {100 * UNRESOLVED_SHARE:.0f}% cannot be reconstructed: their "
            f"phase is lost), up to {summary['densest']:.3g} orders per pixel; simulate or capture it again with "
            f"less load (e.g. -D load=... about 1/{factor} of it) or more pixels (--res about {factor}x), or "
            "supersample (--spp) so that pixels average the fringes as a camera does")


@dataclass(frozen=True)
class FringeAliasing:
    pixels: int          # specimen pixels with a specimen neighbour to compare with
    aliased: int         # of those, pixels more than NYQUIST orders from a neighbour
    densest: float       # fringe orders per pixel, largest
    densities: np.ndarray = field(repr=False, compare=False)   # fringe orders per pixel, one per counted pixel

    @cached_property
    def percentile_99(self) -> float:
        """Fringe orders per pixel, 99th percentile over the specimen."""
        # Computed on demand: a partial sort costs more than the rest of the check.
        if self.densities.size == 0:
            return 0.0
        rank = int(0.99 * (self.densities.size - 1))
        return float(np.partition(self.densities, rank)[rank])

    @property
    def fraction(self) -> float:
        return self.aliased / self.pixels if self.pixels else 0.0

    @property
    def aliases(self) -> bool:
        """Whether more than ``ALIASED_FRACTION`` of the specimen's pixels alias."""
        return self.fraction > ALIASED_FRACTION

    @property
    def resolution_factor(self) -> int:
        """How many times finer the pixels must be for 99% of the specimen to be sampled."""
        # Small images put the 99th percentile below the aliased pixels it should cover.
        return max(2 if self.aliased else 1, math.ceil(self.percentile_99 / NYQUIST - 1e-9))

    def scaled(self, factor: float) -> FringeAliasing:
        """The report on an order ``factor`` times this one, pixel by pixel (a beat between bands, whose order is a
        fixed multiple of the measured one: :func:`beat_factor`)."""
        densities = self.densities * factor
        return FringeAliasing(self.pixels, int(np.count_nonzero(densities > NYQUIST)), self.densest * factor, densities)

    def describe(self) -> str:
        return (f"fringes denser than the pixel grid (over {NYQUIST:g} order per pixel) in "
                f"{100 * self.fraction:.2g}% of the specimen's pixels, up to {self.densest:.3g} orders per "
                f"pixel (99th percentile {self.percentile_99:.3g})")


def fringe_aliasing(order: np.ndarray, inside: np.ndarray) -> FringeAliasing:
    """Fringe density of an ``(H, W)`` unwrapped ``order`` image over the ``inside`` mask.

    Each pixel's density is the largest order difference to its right and lower
    neighbours. Only pixels whose four neighbours are inside count: the
    silhouette is an edge of the image, not a fringe, and supersampled pixels on
    it average the order with the zero outside.
    """
    order = np.asarray(order, dtype=np.float32)
    inside = np.asarray(inside, dtype=bool)
    if order.shape != inside.shape or order.ndim != 2:
        raise ValueError(f"fringe_aliasing: order {order.shape} and inside {inside.shape} must be one 2D shape")
    # Interior pixels: inside, with all four neighbours inside.
    interior = np.zeros_like(inside)
    core = interior[1:-1, 1:-1]
    np.logical_and(inside[1:-1, 1:-1], inside[:-2, 1:-1], out=core)
    core &= inside[2:, 1:-1]
    core &= inside[1:-1, :-2]
    core &= inside[1:-1, 2:]
    # Order step to the lower and to the right neighbour, where both pixels are interior (else -1).
    top_left = interior[:-1, :-1]
    has_down = top_left & interior[1:, :-1]
    has_right = top_left & interior[:-1, 1:]
    down = np.abs(order[1:, :-1] - order[:-1, :-1])
    right = np.abs(order[:-1, 1:] - order[:-1, :-1])
    down[~has_down] = -1.0
    right[~has_right] = -1.0
    values = np.maximum(down, right, out=down)[has_down | has_right]
    if values.size == 0:
        return FringeAliasing(0, 0, 0.0, values)
    return FringeAliasing(int(values.size), int(np.count_nonzero(values > NYQUIST)), float(values.max()), values)
