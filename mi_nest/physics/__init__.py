"""Pure photoelastic physics on NumPy or Dr.Jit arrays; imports no Mitsuba objects."""
from . import polariscope, projection, su2
from .polariscope import (MEASUREMENTS, Compensator, Polariscope, Polarizer, Waveplate, half_wave_plate,
                          measurement_intensities, parse_optics, standard_polariscope)

__all__ = ["su2", "projection", "polariscope", "Polariscope", "MEASUREMENTS", "measurement_intensities",
           "Polarizer", "Waveplate", "Compensator", "half_wave_plate", "parse_optics", "standard_polariscope"]
