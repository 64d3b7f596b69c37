"""Stress sources behind one interface (``StressField``): analytic models and grids."""
from .analytic import MODELS, DiskCompressionField, TwistedField, UniformField
from .base import FieldParameterError, StressField

__all__ = ["StressField", "FieldParameterError", "MODELS", "UniformField", "TwistedField",
           "DiskCompressionField"]
