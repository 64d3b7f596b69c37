"""How good a reconstruction is: its intensities against the measured ones, and its stress against the truth."""
from __future__ import annotations

import mitsuba as mi
import numpy as np

from ..dataset import Dataset
from ..fields.base import StressField
from ..tracer import Tracer
from . import metrics
from .channels import ChannelModel
from .rays import ViewRays, stratified


def predict_view(scene: mi.Scene, view_rays: ViewRays, tracer: Tracer, position: int,
                 stress_field: StressField) -> np.ndarray:
    """``(H * W, channels)`` intensities of rotation ``position`` (pixel centres) with ``stress_field`` in the
    specimens, as the dataset's channels measured them (its polariscopes, and bands)."""
    rays, right = view_rays.view(position)
    channels = ChannelModel.of(view_rays.dataset, scene)
    traced = tracer.trace_rays(scene, rays, right, field=stress_field, view=channels.view)
    return np.stack([np.array(c) for c in channels.intensities(traced.jones())], axis=-1)


def view_mask(dataset: Dataset, position: int, mask: str | None) -> np.ndarray | None:
    """The ``(H * W,)`` pixels of rotation ``position`` inside the dataset channel ``mask`` (None: all)."""
    if mask is None:
        return None
    return dataset.view(position, [mask])[mask].ravel() > 0.5


def view_psnr(predicted: np.ndarray, dataset: Dataset, position: int, mask: str | None) -> float:
    """The PSNR (dB, peak 1) of ``(H * W, channels)`` predicted intensities against rotation ``position``'s
    measurements over its ``mask`` pixels: the one definition that ``reconstruct`` and ``compare`` report."""
    measured = dataset.measurements(position).reshape(-1, len(dataset.channels))
    return metrics.psnr(predicted, measured, view_mask(dataset, position, mask))


def dataset_loss(scene: mi.Scene, dataset: Dataset, stress_field: StressField, tracer: Tracer,
                 split: str = "train",
                 mask: str | None = "mask.dolp") -> float:
    """Mean L1 error of the intensities (every channel) over every ``mask`` pixel of the ``split`` rotations."""
    view_rays = ViewRays(scene, dataset)
    total = count = 0.0
    for position in dataset.split(split):
        error = np.abs(predict_view(scene, view_rays, tracer, position, stress_field)
                       - dataset.measurements(position).reshape(-1, len(dataset.channels)))
        inside = view_mask(dataset, position, mask)
        if inside is not None:
            error = error[inside]
        total += float(error.sum())
        count += error.size
    return total / max(count, 1)


class SampledViewLoss:
    """The mean L1 error of the intensities (every channel) over the ``mask`` pixels of a fixed sample of
    ``views`` of the ``split`` rotations, each pixel the mean of ``samples`` stratified rays across it, the same
    rays for every field scored (as the camera integrates, and the finest stage fits: at pixel centres the
    aliased pixels miss every field alike, and hide what tells fields apart)."""

    def __init__(self, scene: mi.Scene, dataset: Dataset, tracer: Tracer, mask: str | None, split: str,
                 views: int, samples: int):
        positions = dataset.split(split)
        self.positions = positions[::max(1, len(positions) // views)][:views]
        self.scene, self.tracer, self.samples = scene, tracer, samples
        self.channels = ChannelModel.of(dataset, scene)
        view_rays = ViewRays(scene, dataset)
        rng = np.random.default_rng(0)
        self.rays, self.measured = [], []
        for position in self.positions:
            inside = view_mask(dataset, position, mask)
            pixels = np.arange(dataset.resolution[0] * dataset.resolution[1]) if inside is None \
                else np.flatnonzero(inside)
            rows, columns = np.divmod(pixels, dataset.resolution[0])
            self.rays.append(view_rays.rays(*(np.repeat(a, samples) for a in
                                              (np.full(len(pixels), position), rows, columns)),
                                            jitter=stratified(len(pixels), samples, rng)))
            self.measured.append(dataset.measurements(position).reshape(-1, len(dataset.channels))[pixels])

    def __call__(self, stress_field: StressField) -> float:
        total = count = 0.0
        for (rays, right), measured in zip(self.rays, self.measured):
            traced = self.tracer.trace_rays(self.scene, rays, right, field=stress_field, view=self.channels.view)
            predicted = np.stack([np.array(c) for c in self.channels.intensities(traced.jones())], axis=-1)
            error = np.abs(predicted.reshape(len(measured), self.samples, -1).mean(axis=1) - measured)
            total += float(error.sum())
            count += error.size
        return total / max(count, 1.0)


def evaluate(scene: mi.Scene, dataset: Dataset, stress_field: StressField, truth: StressField | None,
             predictions: dict[int, np.ndarray], mask: str | None, shapes: list) -> dict:
    """Errors against ``truth`` over the occupied volume, and the PSNR of the held-out rotations' ``predictions``
    (:func:`heldout_predictions`)."""
    results = {}
    if truth is not None:
        points = metrics.evaluation_points(scene, shapes)
        errors = metrics.stress_errors(stress_field, truth, points)
        results.update(deviatoric_error=errors.deviatoric, principal_difference_error=errors.principal_difference,
                       evaluation_points=errors.points)
        floor = metrics.grid_floor(stress_field, truth, points)
        if floor is not None:
            results["grid_floor"] = floor
    if predictions:
        values = [view_psnr(predicted, dataset, position, mask) for position, predicted in predictions.items()]
        results.update(test_psnr=float(np.mean(values)), test_views=len(values))
    return results


def heldout_predictions(scene: mi.Scene, dataset: Dataset, stress_field: StressField, tracer: Tracer,
                        views: int) -> dict[int, np.ndarray]:
    """``{position: (H * W, channels) intensities}`` of up to ``views`` held-out rotations (:func:`predict_view`)."""
    view_rays = ViewRays(scene, dataset)
    return {position: predict_view(scene, view_rays, tracer, position, stress_field)
            for position in dataset.split("test")[:views]}
