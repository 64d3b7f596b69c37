"""Light of several wavelengths and the colours a camera or an eye sees of it (issue 37; docs/physics.md section 9).

A :class:`Spectrum` is a light's relative power at sampled wavelengths: one
line (today's renders, 532 nm) or a white source. Between polarisers a
specimen passes each wavelength with its own intensity; the colour is that
spectrum seen through the CIE 1931 2-degree observer, normalised so that the
light itself (every wavelength passed whole) has luminance Y = 1, and turned
into sRGB for a display white-balanced to the light (CAT02), the way a
photoelastician's camera is set up. The colour science (observer, illuminants,
sRGB) is colour-science's, not written here.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

OBSERVER = "CIE 1931 2 Degree Standard Observer"
# CIE 015:2018's illuminant for a phosphor-converted white LED of 4103 K, the kind a polariscope's panel uses.
WHITE_LED = "LED-B3"
# nm between the wavelengths a white light is rendered at: one image each (41 from 380 to 780 nm).
WHITE_LIGHT_STEP = 10.0
# What a light panel's ``spectrum`` may name besides a CSV file: one wavelength (the media's), or the white LED.
MONOCHROMATIC = "monochromatic"
LIGHTS = {"white_led": lambda: white_led(step=WHITE_LIGHT_STEP)}


@dataclass(frozen=True, eq=False)
class Spectrum:
    """Relative power ``power`` at ``wavelengths`` (nm, increasing), each sample standing for its share of the
    band (trapezoid weights)."""
    wavelengths: np.ndarray
    power: np.ndarray
    name: str = ""

    def __post_init__(self):
        wavelengths = checked_wavelengths(self.wavelengths, "a spectrum's wavelengths")
        power = np.broadcast_to(np.asarray(self.power, dtype=np.float64), wavelengths.shape).copy()
        if not (np.all(np.isfinite(power)) and np.all(power >= 0) and power.sum() > 0):
            raise ValueError("a spectrum's power must be finite, not negative, and not zero everywhere")
        object.__setattr__(self, "wavelengths", wavelengths)
        object.__setattr__(self, "power", power)

    def weights(self) -> np.ndarray:
        """Each sample's power times the width of wavelengths it stands for (1 for a single line)."""
        if len(self.wavelengths) == 1:
            return self.power.copy()
        return self.power * np.gradient(self.wavelengths)


def checked_wavelengths(values, what: str, error: type[ValueError] = ValueError) -> np.ndarray:
    """``values`` as wavelengths (nm): one or more, positive, increasing without repeats; else ``error``, whose
    message names them as ``what``."""
    wavelengths = np.atleast_1d(np.asarray(values, dtype=np.float64))
    if wavelengths.ndim != 1 or len(wavelengths) == 0:
        raise error(f"{what}: give at least one wavelength (nm)")
    if not (np.all(np.isfinite(wavelengths)) and np.all(wavelengths > 0)):
        raise error(f"{what} must be positive numbers of nm, got {wavelengths.tolist()}")
    if np.any(np.diff(wavelengths) <= 0):
        raise error(f"{what} must increase, without repeats: got {wavelengths.tolist()}")
    return wavelengths


def read_curves(path: str | Path, kind: str, header: str,
                error: type[ValueError] = ValueError) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """``(names, wavelengths, values (wavelengths, names))`` of a CSV file of curves: a header ``header``
    (``wavelength,<name>,...``), then one row of numbers per wavelength (nm, increasing); lines starting with
    ``#`` are comments. ``kind`` names the file in ``error``'s messages."""
    path = Path(path)
    try:
        with open(path, newline="") as handle:
            rows = [row for row in csv.reader(handle) if row and not row[0].lstrip().startswith("#")]
    except OSError as error_:
        raise error(f"cannot read the {kind} file {path}: {error_.strerror or error_}") from None
    if len(rows) < 3 or len(rows[0]) < 2:
        raise error(f"{path}: a {kind} file needs a header '{header}' and at least two rows of numbers")
    names = tuple(name.strip() for name in rows[0][1:])
    try:
        values = np.array([[float(x) for x in row] for row in rows[1:]])
    except ValueError:
        raise error(f"{path}: every row after the header '{header}' must be numbers") from None
    if values.shape[1] != len(names) + 1:
        raise error(f"{path}: rows must have {len(names) + 1} numbers, as the header names")
    return names, checked_wavelengths(values[:, 0], f"{path}: the wavelengths", error), values[:, 1:]


def read_spectrum(path: str | Path, step: float = WHITE_LIGHT_STEP) -> Spectrum:
    """A light's relative spectral power from a CSV file (:func:`read_curves`, header ``wavelength,power``),
    sampled every ``step`` nm over its span (a spectrometer's 1 nm rows would otherwise each cost a wavelength's
    render)."""
    names, wavelengths, power = read_curves(path, "spectrum", "wavelength,power")
    if len(names) != 1:
        raise ValueError(f"{path}: a spectrum file has one column of power after the wavelength, got {len(names)}")
    grid = np.arange(wavelengths[0], wavelengths[-1] + 0.5 * step, step)
    return Spectrum(grid, np.interp(grid, wavelengths, power[:, 0]), Path(path).name)


def parse_light(text: str, step: float = WHITE_LIGHT_STEP) -> Spectrum | None:
    """A light panel's spectrum: ``monochromatic`` (None: one wavelength, the media's), a name of :data:`LIGHTS`, or
    a CSV file of its spectral power (:func:`read_spectrum`)."""
    text = text.strip()
    if text.lower() == MONOCHROMATIC:
        return None
    if text.lower() in LIGHTS:
        return LIGHTS[text.lower()]()
    if text.lower().endswith(".csv"):
        return read_spectrum(text, step)
    raise ValueError(f"a light's spectrum is {MONOCHROMATIC!r}, {', '.join(repr(n) for n in LIGHTS)} or a CSV file "
                     f"'wavelength,power'; got {text!r}")


def monochromatic(wavelength: float = 532.0) -> Spectrum:
    """One line: the light of today's renders (a green laser or a filtered lamp)."""
    return Spectrum(np.array([float(wavelength)]), np.array([1.0]), f"{wavelength:g} nm")


def white_led(step: float = 5.0) -> Spectrum:
    """A white LED panel: CIE illuminant LED-B3 (CIE 015:2018, phosphor-converted, 4103 K) every ``step`` nm from
    380 to 780 nm."""
    import colour
    source = colour.SDS_ILLUMINANTS[WHITE_LED]
    wavelengths = np.arange(380.0, 780.0 + 0.5 * step, step)
    return Spectrum(wavelengths, np.interp(wavelengths, source.wavelengths, source.values), WHITE_LED)


def plane_polariscope_transmission(retardation: np.ndarray, wavelengths: np.ndarray,
                                   field: str = "dark") -> np.ndarray:
    """``(..., wavelengths)`` intensity of a retarder of ``retardation`` (nm of path difference, the same at
    every wavelength) at 45 degrees between crossed (``dark``) or parallel (``light``) polarisers:
    ``sin^2(pi R / lambda)`` and its complement."""
    if field not in ("dark", "light"):
        raise ValueError(f"unknown polariscope field '{field}'; choose dark or light")
    phase = np.pi * np.asarray(retardation, dtype=np.float64)[..., None] / np.asarray(wavelengths)
    dark = np.sin(phase) ** 2
    return dark if field == "dark" else 1.0 - dark


def tristimulus(intensity: np.ndarray, light: Spectrum) -> np.ndarray:
    """``(..., 3)`` CIE XYZ of ``light`` passed with ``intensity`` (``(..., wavelengths)``) at each of its
    wavelengths, scaled so that the light passed whole has Y = 1."""
    import colour
    cmfs = colour.MSDS_CMFS[OBSERVER]
    observer = np.stack([np.interp(light.wavelengths, cmfs.wavelengths, cmfs.values[:, i], left=0.0, right=0.0)
                         for i in range(3)], axis=-1)
    weighted = light.weights()[:, None] * observer
    luminance = weighted[:, 1].sum()
    if luminance <= 0:
        raise ValueError(f"the light '{light.name}' has no power the eye sees (360 to 830 nm)")
    return np.asarray(intensity, dtype=np.float64) @ weighted / luminance


def white_point(light: Spectrum) -> np.ndarray:
    """The CIE xy chromaticity of ``light`` itself."""
    X, Y, Z = tristimulus(np.ones(len(light.wavelengths)), light)
    return np.array([X, Y]) / (X + Y + Z)


def to_srgb(intensity: np.ndarray, light: Spectrum) -> np.ndarray:
    """``(..., 3)`` sRGB in [0, 1] of ``light`` passed with ``intensity`` at each wavelength, on a display
    white-balanced to the light (CAT02): the light passed whole is white."""
    import colour
    xyz = tristimulus(intensity, light)
    return np.clip(colour.XYZ_to_sRGB(xyz, illuminant=white_point(light), chromatic_adaptation_transform="CAT02"),
                   0.0, 1.0)


def interference_colours(retardation: np.ndarray, light: Spectrum | None = None, field: str = "dark") -> np.ndarray:
    """``(..., 3)`` sRGB of retarders of ``retardation`` (nm) in a plane polariscope at 45 degrees in white light
    (default: :func:`white_led`): the interference colours of a Michel-Levy chart."""
    light = white_led() if light is None else light
    return to_srgb(plane_polariscope_transmission(retardation, light.wavelengths, field), light)
