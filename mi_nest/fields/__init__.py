"""Stress sources behind one interface (``StressField``): analytic models, grids, meshes."""
from .analytic import (MODELS, BeamBendingField, BoussinesqField, DiskCompressionField, KirschPlateField,
                       LameCylinderField, ShaftTorsionField, StackedDisksField, TwistedField, UniformField)
from .base import FieldParameterError, StressField

__all__ = ["StressField", "FieldParameterError", "MODELS", "UniformField", "TwistedField",
           "DiskCompressionField", "LameCylinderField", "ShaftTorsionField", "BeamBendingField",
           "KirschPlateField", "BoussinesqField", "StackedDisksField"]
