"""Pure photoelastic physics on NumPy or Dr.Jit arrays; imports no Mitsuba objects."""
from . import polariscope, projection, su2
from .polariscope import MEASUREMENTS, Polariscope, measurement_intensities

__all__ = ["su2", "projection", "polariscope", "Polariscope", "MEASUREMENTS",
           "measurement_intensities"]
