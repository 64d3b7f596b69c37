"""Multi-axis polariscope datasets: simulate, store, load, mask (one format for simulations and captures)."""
from .camera import CameraModel
from .format import DatasetError
from .loader import Dataset
from .masks import agreement, dolp_mask
from .simulate import SimulationReport, SimulationSettings, simulate

__all__ = ["CameraModel", "Dataset", "DatasetError", "SimulationReport", "SimulationSettings", "agreement",
           "dolp_mask", "simulate"]
