"""Inverse reconstruction (NeST tomography): trainable fields, the optimiser, metrics."""
from .checkpoints import CheckpointError, Reconstruction
from .config import (REGULARISED, FieldConfig, ForwardModel, OptimizeConfig, Optimiser, Regulariser, Reporting,
                     Schedule)
from .fields import DeviatoricGrid, HashGridField, MLPField, TrainableField, make_field
from .loop import DivergenceError
from .optimization import optimize

__all__ = ["optimize", "OptimizeConfig", "Schedule", "Optimiser", "ForwardModel", "Regulariser", "Reporting",
           "Reconstruction", "DivergenceError", "CheckpointError", "FieldConfig", "TrainableField", "DeviatoricGrid",
           "HashGridField", "MLPField", "make_field", "REGULARISED"]
