"""Images of a reconstruction for a person to look at: a held-out view, and the truth beside the result."""
from __future__ import annotations

import warnings
from pathlib import Path

import mitsuba as mi
import numpy as np

from ..dataset import Dataset
from ..io.exr import write_channels
from ..io.preview import write_comparison, write_preview
from ..render import render
from .checkpoints import Reconstruction
from .evaluation import predict_view, view_psnr
from .rays import ViewRays


def write_test_view(scene: mi.Scene, result: Reconstruction, output: str | Path, dataset: Dataset) -> str:
    """EXR of the first held-out rotation, reconstructed beside measured, and a labelled PNG of one channel:
    reconstructed, measured and their difference; returns the names written, for the command's report."""
    test = dataset.split("test") or dataset.split("train")
    position = test[0]
    width, height = dataset.resolution
    predicted = predict_view(scene, ViewRays(scene, dataset), result.tracer(scene), position, result.field)
    measured = dataset.measurements(position)
    channels = {f"reconstructed.{name}": predicted[:, i].reshape(height, width)
                for i, name in enumerate(dataset.channels)}
    channels.update({f"measured.{name}": measured[..., i] for i, name in enumerate(dataset.channels)})
    output = Path(output)
    write_channels(output / "test_view.exr", channels)
    shown = next((name for name in dataset.channels if name.endswith("pol.45.0.135")), dataset.channels[0])
    rotation = dataset.rotations[position]
    ratio = view_psnr(predicted, dataset, position, result.config.optimiser.mask)
    write_comparison(output / "test_view.png", [("reconstructed", channels[f"reconstructed.{shown}"]),
                                                ("measured", channels[f"measured.{shown}"])],
                     f"held-out rotation {rotation['index']} (azimuth {rotation['azimuth']:.1f}, elevation "
                     f"{rotation['elevation']:.1f}): {shown}; PSNR of its {len(dataset.channels)} measurements "
                     f"{ratio:.1f} dB")
    return ", test_view.exr, test_view.png (reconstructed, measured, difference)"


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
