"""Images of a reconstruction for a person to look at: a held-out view, and the truth beside the result."""
from __future__ import annotations

import warnings
from pathlib import Path

import mitsuba as mi
import numpy as np

from ..dataset import Dataset
from ..io.exr import write_channels
from ..io.preview import write_preview
from ..render import render
from .checkpoints import Reconstruction
from .evaluation import predict_view
from .rays import ViewRays


def write_test_view(scene: mi.Scene, result: Reconstruction, output: str | Path, dataset: Dataset) -> str:
    """EXR of the first held-out rotation, reconstructed beside measured, and a PNG of one channel pair;
    returns the names written, for the command's report."""
    test = dataset.split("test") or dataset.split("train")
    position = test[0]
    width, height = dataset.resolution
    predicted = predict_view(scene, ViewRays(scene, dataset), result.integrator(scene), position, result.field)
    measured = dataset.measurements(position)
    channels = {f"reconstructed.{name}": predicted[:, i].reshape(height, width) for i, name in enumerate(dataset.channels)}
    channels.update({f"measured.{name}": measured[..., i] for i, name in enumerate(dataset.channels)})
    output = Path(output)
    write_channels(output / "test_view.exr", channels)
    shown = "pol.45.0.135" if "pol.45.0.135" in dataset.channels else dataset.channels[0]
    write_preview(output / "test_view.png", np.concatenate([channels[f"reconstructed.{shown}"],
                                                           channels[f"measured.{shown}"]], axis=1))
    return ", test_view.exr, test_view.png (reconstructed | measured)"


def write_truth_beside_reconstruction(scene: mi.Scene, reconstruction: Reconstruction, output: str | Path) -> str:
    """Render ``scene``'s own view with its true and with the reconstructed field, EXR each and one PNG side
    by side; returns what was written, for the command's report."""
    output = Path(output)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        truth = render(scene, progress=False)
        reconstructed = reconstruction.render(scene, progress=False)
    truth.write_exr(output / "truth.exr")
    reconstructed.write_exr(output / "reconstructed.exr")
    write_preview(output / "truth_vs_reconstructed.png", np.concatenate([truth.main, reconstructed.main], axis=1))
    return f"{(output / 'truth_vs_reconstructed.png').resolve()} (truth | reconstructed)"
