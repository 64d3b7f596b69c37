"""How a material's stress-optic coefficient C changes with the wavelength (issue 37; docs/physics.md section 9).

A stress medium gives C at its own wavelength; its dispersion says what C is at
any other, so that a view at another wavelength (or, later, a spectral render)
scales each phase by ``C(lambda) / lambda`` rather than by ``1 / lambda`` alone.
A scene's ``dispersion`` property reads as :func:`parse_dispersion`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .parsing import name_and_numbers


@dataclass(frozen=True)
class Constant:
    """C the same at every wavelength (the default, and what renders assumed before)."""

    def coefficient(self, wavelength: float, reference: float, at_reference: float) -> float:
        return at_reference

    def describe(self) -> str:
        return "constant"


@dataclass(frozen=True)
class Cauchy:
    """``C(lambda) = A + B / lambda^2`` (Brewster, nm), with A set by C at the medium's own wavelength."""
    b: float        # Brewster nm^2

    def coefficient(self, wavelength: float, reference: float, at_reference: float) -> float:
        value = at_reference + self.b * (1.0 / wavelength ** 2 - 1.0 / reference ** 2)
        if value <= 0:
            raise ValueError(f"the Cauchy dispersion 'cauchy {self.b:g}' makes C {value:.3g} Brewster at "
                             f"{wavelength:g} nm: C must stay positive; check B (Brewster nm^2)")
        return value

    def describe(self) -> str:
        return f"cauchy {self.b:g}"


@dataclass(frozen=True)
class Table:
    """C (Brewster) measured at ``wavelengths`` (nm, increasing), linear between them; none outside."""
    wavelengths: tuple[float, ...]
    values: tuple[float, ...]

    def __post_init__(self):
        if len(self.wavelengths) < 2 or len(self.wavelengths) != len(self.values):
            raise ValueError("a dispersion table needs at least two (wavelength, C) pairs")
        if not (np.all(np.isfinite(self.wavelengths)) and min(self.wavelengths) > 0
                and np.all(np.diff(self.wavelengths) > 0)):
            raise ValueError(f"a dispersion table's wavelengths must be positive nm, increasing: {self.wavelengths}")
        if not (np.all(np.isfinite(self.values)) and min(self.values) > 0):
            raise ValueError(f"a dispersion table's C must be positive Brewster: {self.values}")

    def coefficient(self, wavelength: float, reference: float = 0.0, at_reference: float = 0.0) -> float:
        low, high = self.wavelengths[0], self.wavelengths[-1]
        if not low <= wavelength <= high:
            raise ValueError(f"the dispersion table covers {low:g} to {high:g} nm; {wavelength:g} nm is outside it "
                             "(measure C there, or view within the table)")
        return float(np.interp(wavelength, self.wavelengths, self.values))

    def describe(self) -> str:
        return "table " + " ".join(f"{w:g} {c:g}" for w, c in zip(self.wavelengths, self.values))


Dispersion = Constant | Cauchy | Table


def parse_dispersion(text: str) -> Dispersion:
    """``"constant"``, ``"cauchy B"`` (Brewster nm^2) or ``"table L1 C1 L2 C2 ..."`` (nm, Brewster)."""
    name, values = name_and_numbers(text, "dispersion")
    if name == "constant" and not values:
        return Constant()
    if name == "cauchy" and len(values) == 1:
        return Cauchy(values[0])
    if name == "table" and len(values) % 2 == 0:
        return Table(tuple(values[0::2]), tuple(values[1::2]))
    raise ValueError(f"dispersion '{text}': write 'constant', 'cauchy B' (Brewster nm^2) or "
                     "'table L1 C1 L2 C2 ...' (nm and Brewster pairs)")
