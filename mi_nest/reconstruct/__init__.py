"""Inverse reconstruction (NeST tomography): trainable fields, the optimiser, metrics."""
from .fields import FieldConfig, HashGridField, DeviatoricGrid, MLPField, TrainableField, make_field
from .optimization import (REGULARISED, CheckpointError, DivergenceError, OptimizeConfig, Reconstruction,
                           optimize, with_field)

__all__ = ["optimize", "OptimizeConfig", "Reconstruction", "DivergenceError", "CheckpointError", "FieldConfig",
           "TrainableField", "DeviatoricGrid", "HashGridField", "MLPField", "make_field", "with_field", "REGULARISED"]
