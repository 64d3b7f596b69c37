"""Inverse reconstruction (NeST tomography): trainable fields, the optimiser, metrics."""
from .checkpoints import CheckpointError, Reconstruction, ReconstructionFileError
from .config import (FAST_OPTIONS, METHODS, NO_REGULARISER, REGULARISED, FieldConfig, ForwardModel, OptimizeConfig,
                     Optimiser, Regulariser, Reporting, Schedule, option_names, option_value)
from .fields import DeviatoricGrid, HashGridField, MLPField, TrainableField, make_field
from .kinds import CHOICES as KIND_CHOICES
from .loop import DivergenceError
from .optimization import optimize

__all__ = ["optimize", "OptimizeConfig", "Schedule", "Optimiser", "ForwardModel", "Regulariser", "Reporting",
           "Reconstruction", "ReconstructionFileError", "DivergenceError", "CheckpointError", "FieldConfig",
           "TrainableField", "DeviatoricGrid", "HashGridField", "MLPField", "make_field", "REGULARISED",
           "NO_REGULARISER", "FAST_OPTIONS", "option_names", "option_value", "METHODS", "KIND_CHOICES"]
