"""A camera's colour bands: what each of its channels sees of a light, as weights over the wavelengths marched.

A band's intensity is the light's spectrum between the polarisers weighted by
the band: ``I_band = sum_l w_l I(lambda_l)``, with ``w`` proportional to the
light's power times the channel's sensitivity times the width each sample
stands for, normalised to sum to 1 (free space between parallel polarisers
stays 1 in every band). A :class:`BandSet` holds several bands over one list
of wavelengths, the lanes a spectral march advances together
(``tracer/spectral.py``).

- :func:`narrow_bands`: one wavelength per band (filtered lasers or narrow
  interference filters);
- :func:`camera_bands`: an RGB sensor's curves under a light (default the
  white LED). The curves shipped are colour-science's measurement of a Nikon
  D5100 (National Physical Laboratory, via ``colour.MSDS_CAMERA_SENSITIVITIES``,
  BSD-3): a Sony-made Bayer CMOS sensor, the kind a colour polarisation
  camera's (Sony IMX250MYR) filters are. The IMX250MYR's own published curves
  can be given as a CSV (:func:`read_bands`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .colour import Spectrum, checked_wavelengths, read_curves, white_led

# colour-science's name of the curves :func:`camera_bands` uses by default, and the names its channels get.
RGB_SENSOR = "Nikon 5100 (NPL)"
RGB_NAMES = ("red", "green", "blue")
# nm between the wavelengths a camera's bands are sampled at: a band of 100 nm over fringes a few orders deep
# varies over 50 nm and more (lambda^2 / retardation), so 10 nm resolves its average.
BAND_STEP = 10.0
# A wavelength where no band weighs more than this share of its largest weight is left out of the lanes.
NEGLIGIBLE_WEIGHT = 1e-3


class BandError(ValueError):
    """Bands that no camera has: empty, unsorted or negative wavelengths, weights that are not a light."""


@dataclass(frozen=True, eq=False)
class BandSet:
    """Bands ``names`` over ``wavelengths`` (nm, increasing): ``weights[b, l]`` of band ``b`` at wavelength ``l``,
    each row summing to 1; ``source`` says where the curves come from."""
    names: tuple[str, ...]
    wavelengths: np.ndarray
    weights: np.ndarray
    source: str = ""

    def __post_init__(self):
        names = tuple(str(n) for n in self.names)
        wavelengths = checked_wavelengths(self.wavelengths, "band wavelengths", BandError)
        weights = np.atleast_2d(np.asarray(self.weights, dtype=np.float64))
        if not names:
            raise BandError("a band set needs at least one band")
        if len(set(names)) != len(names) or any(not n or "." in n or n.isspace() for n in names):
            raise BandError(f"band names must be distinct, not empty and without dots, got {list(names)}")
        if weights.shape != (len(names), len(wavelengths)):
            raise BandError(f"{len(names)} band(s) over {len(wavelengths)} wavelength(s) need weights of shape "
                            f"({len(names)}, {len(wavelengths)}), got {weights.shape}")
        if not (np.all(np.isfinite(weights)) and np.all(weights >= 0)) or np.any(weights.sum(axis=1) <= 0):
            raise BandError("band weights must be finite, not negative, and not zero everywhere in a band")
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "wavelengths", wavelengths)
        object.__setattr__(self, "weights", weights / weights.sum(axis=1, keepdims=True))

    def __len__(self) -> int:
        return len(self.names)

    def to_dict(self) -> dict:
        """What ``dataset.json`` records (:func:`band_set_from_dict` reads it back)."""
        return {"names": list(self.names), "wavelengths": self.wavelengths.tolist(),
                "weights": self.weights.tolist(), "source": self.source}

    def combine(self, per_wavelength: np.ndarray) -> np.ndarray:
        """``(bands, ...)`` band images from ``(wavelengths, ...)`` images, one per wavelength."""
        per_wavelength = np.asarray(per_wavelength)
        return np.tensordot(self.weights, per_wavelength, axes=(1, 0))

    def resampled(self, step: float) -> BandSet:
        """The bands every ``step`` nm over their span, each band's weight per nm interpolated and normalised
        again: fewer wavelengths to trace where the bands are broad and their curves smooth. Bands already
        sampled no finer, or any band of a single wavelength (a narrow band), are kept as they are."""
        if not (math.isfinite(step) and step > 0):
            raise BandError(f"the wavelength step must be a positive number of nm, got {step}")
        if len(self.wavelengths) < 2 or np.diff(self.wavelengths).min() >= step or \
                (np.count_nonzero(self.weights, axis=1) <= 1).any():
            return self
        grid = np.arange(self.wavelengths[0], self.wavelengths[-1] + 0.5 * step, step)
        density = self.weights / np.gradient(self.wavelengths)
        weights = np.stack([np.interp(grid, self.wavelengths, d) for d in density]) * \
            (np.gradient(grid) if len(grid) > 1 else 1.0)
        kept = weights.any(axis=0)
        return BandSet(self.names, grid[kept], weights[:, kept], f"{self.source}, traced every {step:g} nm")

    def describe(self) -> str:
        centres = self.weights @ self.wavelengths
        return ", ".join(f"{name} ({centre:.0f} nm)" for name, centre in zip(self.names, centres))


def band_set_from_dict(record: dict) -> BandSet:
    try:
        return BandSet(tuple(record["names"]), np.array(record["wavelengths"]), np.array(record["weights"]),
                       str(record.get("source", "")))
    except (KeyError, TypeError, ValueError) as error:
        raise BandError(f"corrupt bands record ({error}): it needs names, wavelengths and weights") from None


def narrow_bands(wavelengths) -> BandSet:
    """One band per wavelength (nm, increasing), each named by its wavelength (``632_8`` for 632.8 nm: channel
    names keep their dots for the measurement's parts)."""
    wavelengths = np.atleast_1d(np.asarray(wavelengths, dtype=np.float64))
    if wavelengths.ndim != 1 or not len(wavelengths):
        raise BandError("give at least one wavelength (nm) for narrow bands")
    return BandSet(tuple(f"{w:g}".replace(".", "_") for w in wavelengths), wavelengths, np.eye(len(wavelengths)),
                   "narrow bands at " + ", ".join(f"{w:g}" for w in wavelengths) + " nm")


def camera_bands(light: Spectrum | None = None, curves: tuple[np.ndarray, np.ndarray, tuple[str, ...]] | None = None,
                 step: float = BAND_STEP, source: str | None = None) -> BandSet:
    """A camera's bands under ``light`` (default: the white LED every ``step`` nm): ``curves`` is
    ``(wavelengths, sensitivities (wavelengths, bands), names)`` (default: :data:`RGB_SENSOR`'s red, green and
    blue), interpolated onto the light's wavelengths (zero outside the curves)."""
    light = white_led(step=step) if light is None else light
    if curves is None:
        import colour
        measured = colour.MSDS_CAMERA_SENSITIVITIES[RGB_SENSOR]
        curves = (np.asarray(measured.wavelengths), np.asarray(measured.values), RGB_NAMES)
        source = source or (f"{RGB_SENSOR} RGB sensitivities (colour-science, National Physical Laboratory) "
                            f"under {light.name or 'the light'}")
    wavelengths, sensitivities, names = curves
    sensitivities = np.asarray(sensitivities, dtype=np.float64).reshape(len(wavelengths), -1)
    sampled = np.stack([np.interp(light.wavelengths, wavelengths, s, left=0.0, right=0.0)
                        for s in sensitivities.T])
    weights = sampled * light.weights()
    kept = (weights > NEGLIGIBLE_WEIGHT * weights.max(axis=1, keepdims=True)).any(axis=0)
    if not kept.any():
        raise BandError("the camera's curves and the light share no wavelength: no band sees any light")
    return BandSet(tuple(names), light.wavelengths[kept], weights[:, kept], source or "camera curves")


def read_bands(path: str | Path, light: Spectrum | None = None, step: float = BAND_STEP) -> BandSet:
    """A camera's bands from a CSV file: a header ``wavelength,<band>,<band>...`` then one row per wavelength
    (nm, increasing) with each band's relative sensitivity; seen under ``light`` (default: the white LED)."""
    names, wavelengths, sensitivities = read_curves(path, "bands", "wavelength,<band>,...", BandError)
    return camera_bands(light, (wavelengths, sensitivities, names), step, f"{Path(path).name} under the light")


def parse_bands(text: str, light: Spectrum | None = None) -> BandSet:
    """``rgb`` (:func:`camera_bands`), a list of wavelengths in nm (``450,532,633``: :func:`narrow_bands`), or a
    CSV file of a camera's curves (:func:`read_bands`); a camera's curves seen under ``light`` (default: the
    white LED)."""
    text = text.strip()
    if text.lower() == "rgb":
        return camera_bands(light)
    if text.lower().endswith(".csv"):
        return read_bands(text, light)
    try:
        wavelengths = [float(x) for x in text.replace(" ", "").split(",") if x]
    except ValueError:
        raise BandError(f"bands must be 'rgb', wavelengths in nm such as 450,532,633, or a CSV file of a "
                        f"camera's curves; got '{text}'") from None
    if not wavelengths:
        raise BandError("bands need at least one wavelength (nm), 'rgb' or a CSV file")
    return narrow_bands(wavelengths)
