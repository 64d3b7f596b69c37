"""``mi_nest.optimize``: NeST tomography by gradient descent through the photoelastic integrator.

This is the entry point: it checks the scene against the dataset, sets up a
:class:`~mi_nest.reconstruct.loop.Run`, resumes its checkpoint, runs the loop
(``loop.py``), evaluates the result (``evaluation.py``) and saves it
(``checkpoints.py``).
"""
from __future__ import annotations

import contextlib
import warnings
from dataclasses import replace
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from .. import interrupts
from ..dataset import Dataset
from ..dataset.truth import recorded_scene, truth_scene
from ..fields.base import StressField
from ..io.lock import locked_directory
from ..physics.aliasing import NYQUIST, bands_lost_phase, phase_lost, summary_shares
from ..scene import load_scene, scene_field, scene_file, specimen_bounds, specimen_media, specimen_shapes
from . import metrics
from .checkpoints import CHECKPOINT, Reconstruction
from .choices import choices
from .config import LEARNING_RATE_OPTIONS, REGULARISER_OPTIONS, TWO_STEP, OptimizeConfig
from .evaluation import evaluate, heldout_predictions
from .fields import settle
from .loop import Run
from .neighbours import NeighbourPairs, neighbour_loss_applies
from .repair import repair_lines
from .start import start_line
from .trust import TRUST_FILE, trust_map


def optimize(scene: mi.Scene | str | Path, dataset: Dataset | str | Path, *, output: str | Path | None = None,
             resume: bool = True, progress: bool = True, truth: StressField | str | None = "scene",
             **options) -> Reconstruction:
    """Reconstruct the stress field of ``scene``'s specimens from ``dataset``.

    ``scene`` (an ``mi.Scene``, or a scene file or shipped name, loaded with
    the defines the dataset records) gives the specimen shapes (the known
    occupancy), their material and the camera; its own stress field is
    replaced during the optimisation. With ``truth="scene"`` the error metrics
    are measured against the field the dataset was simulated from (the scene
    and defines its ``dataset.json`` records; a given scene that differs is
    named value by value in a warning, and refused when its specimens lie
    elsewhere); pass ``truth=None`` for real captures, or any ``StressField``.

    ``options`` are :class:`OptimizeConfig`'s: flat
    options (``iterations=300, kind="mlp"``...), whole groups
    (``regulariser=NO_REGULARISER``), or ``config=`` a whole configuration that
    the others override. The defaults are the configuration that met the
    reconstruction targets (:mod:`~mi_nest.reconstruct.config`).

    With ``output``, checkpoints go to ``output/checkpoint.npz`` every
    ``checkpoint_every`` iterations (and on interruption), and a rerun resumes
    from there; the result is saved in ``output`` as well.
    """
    base = options.pop("config", None)
    regulariser_given = bool(REGULARISER_OPTIONS & set(options))
    rate_given = bool(LEARNING_RATE_OPTIONS & set(options))
    config = OptimizeConfig(**options) if base is None else replace(base, **options)
    if config.schedule.start is not None and Path(config.schedule.start).exists():
        # Recorded whole: the result and a resumed run name the same file wherever they are run from.
        config = replace(config, schedule=replace(config.schedule, start=str(Path(config.schedule.start).resolve())))
    if not isinstance(dataset, Dataset):
        dataset = Dataset(dataset)
    if not isinstance(scene, mi.Scene):
        scene = _load_as_recorded(scene, dataset)
    shapes = specimen_shapes(scene)
    media = specimen_media(scene)
    _check_material(media, dataset)
    _check_bands(dataset, config)
    _warn_if_aliased(dataset)
    dataset.check_measurements(config.optimiser.mask)
    if truth == "scene":
        truth = scene_field(truth_scene(scene, dataset.index.get("source") or {}, str(dataset.directory)))

    low, high = specimen_bounds(shapes)
    aliasing = dataset.index.get("fringe_aliasing")
    aliased_share = aliasing["mean_fraction"] if aliasing else 0.0
    pixels = max(dataset.resolution)
    neighbours_apply = neighbour_loss_applies(scene, dataset)
    if config.optimiser.neighbour_loss and not neighbours_apply:
        raise ValueError(NeighbourPairs.REFUSED)
    asked, config = config, settle(config, high - low, aliased_share, ease_default_smoothness=not regulariser_given,
                                   slow_started_steps=not rate_given, pixels=pixels, neighbours_apply=neighbours_apply)
    chosen = choices(asked, config, high - low, dataset, aliased_share, pixels, neighbours_apply)
    if progress:
        print("\n".join(chosen), flush=True)
    scale = stress_scale(media, low, high)
    run = Run(scene, dataset, config, low, high, scale, output, progress)
    if truth is not None and config.reporting.track_error_every:
        run.error_probe = metrics.ErrorProbe(truth, metrics.evaluation_points(scene, shapes))
    with contextlib.ExitStack() as stack:
        if output is not None:
            stack.enter_context(locked_directory(output))
        if config.optimiser.deterministic:
            stack.enter_context(one_thread())
        resumed = output is not None and resume and (Path(output) / CHECKPOINT).is_file()
        if resumed:
            run.restore(Path(output) / CHECKPOINT)
        # Ctrl-C waits for the end of an iteration, so that the checkpoint holds whole steps.
        with interrupts.deferred():
            if config.schedule.start is not None and not resumed:
                run.start_from(config.schedule.start)
            if run.began_at:
                chosen.append(start_line(run.began_at, config.schedule.start_scale_range,
                                         config.schedule.start_load_ratio))
                if progress:
                    print(chosen[-1], flush=True)
            run.loop()
        repairs = repair_lines(run.history)
        chosen.extend(repairs)
        if progress and repairs:
            print("\n".join(repairs), flush=True)
        result = run.result()
        result.source["choices"] = chosen
        # The held-out views rendered once: for the PSNR and for the trust map's residuals.
        predictions = heldout_predictions(scene, dataset, result.field, run.tracer(),
                                          config.reporting.evaluate_views)
        result.metrics.update(evaluate(scene, dataset, result.field, truth, predictions, config.optimiser.mask,
                                       shapes))
        if aliasing:
            result.metrics["aliased_share"], beat_share = summary_shares(aliasing)
            if beat_share is not None:
                result.metrics["beat_aliased_share"] = beat_share
        trust = trust_map(scene, dataset, result.field, predictions, config.optimiser.mask, run.second_moment())
        result.metrics["trust"] = trust.summary()
        if output is not None:
            result.save(output)
            trust.save(Path(output) / TRUST_FILE)
    return result


@contextlib.contextmanager
def one_thread():
    """Dr.Jit's LLVM backend on one thread for the block (restored after): its scatter-adds then sum in one
    order, so that a seeded run repeats bit for bit."""
    if not mi.variant().startswith("llvm"):
        raise ValueError(f"a deterministic run needs an LLVM variant (one CPU thread), and this is "
                         f"'{mi.variant()}': the GPU's atomic additions sum in no fixed order")
    threads = dr.thread_count()
    dr.set_thread_count(1)
    try:
        yield
    finally:
        dr.set_thread_count(threads)


def stress_scale(media: list[mi.Medium], low: np.ndarray, high: np.ndarray) -> float:
    """The stress (MPa) that gives about one fringe across the specimen: fields are stored in its units."""
    length = float(np.prod(high - low)) ** (1.0 / 3.0)
    return max(m.fringe_value for m in media) / length


def _load_as_recorded(scene: str | Path, dataset: Dataset) -> mi.Scene:
    """The scene file or name loaded with the dataset's defines where the dataset was simulated from it."""
    record = recorded_scene(dataset.index.get("source") or {})
    if record is not None and scene_file(scene) == record.file:
        return record.load()
    return load_scene(scene)


def _warn_if_aliased(dataset):
    summary = dataset.index.get("fringe_aliasing")
    if not summary or not summary["views"]:
        return
    share, beat = summary_shares(summary)
    if beat is not None:
        if not phase_lost(share, beat):
            return      # the bands together tell the orders apart: the result says so (Reconstruction.describe)
        bands = f"; and {bands_lost_phase(share, beat)}"
    elif dataset.bands is None:
        # The accuracy suite's 300 N and stacked disks: 19.3% and 21.3% in one band, 5.4% and 8.9% in three narrow
        # bands on as many images (docs/reconstruction.md, "The accuracy suite").
        bands = ("; images in three narrow bands (mi-nest simulate --bands 450,532,650; filters on the rig) tell the "
                 "fringe orders apart, docs/reconstruction.md 'Several bands'")
    else:
        bands = ""      # a single band named as a band set, or bands simulated before beats were recorded
    warnings.warn(
        f"{dataset.directory}: fringes are denser than the pixels (over {NYQUIST:g} order per pixel) in "
        f"{summary['views']} of {summary['of']} views, over {100 * summary['mean_fraction']:.2g}% of the "
        f"specimen's pixels on average, up to {summary['densest']:.3g} orders per pixel. Pixels there average "
        "several fringes and no longer tell the phase: expect the largest errors there (stress concentrations) "
        "and wrapped local minima; a finer camera, or a smaller load or stress-optic coefficient, resolves them, "
        "and a start from the part reconstructed at a lower load (--start RESULT --option start_load_ratio=R, "
        f"docs/reconstruction.md 'A load series') avoids the minima{bands}",
        RuntimeWarning, stacklevel=3)


def _check_bands(dataset: Dataset, config: OptimizeConfig) -> None:
    """A dataset of several bands is fitted by its intensities in one spectral march: refuse what cannot."""
    if dataset.bands is None:
        return
    if config.model.method == TWO_STEP or config.schedule.warm_start:
        raise ValueError(f"the Two-step unwraps one wavelength's measurements, and {dataset.directory} holds "
                         f"{len(dataset.bands)} bands ({dataset.bands.describe()}): fit them by their intensities "
                         "(leave out method two-step and the warm start)")


def _check_material(media, dataset):
    for name, key in (("wavelength", "wavelength"), ("stress_optic_coefficient", "stress_optic_coefficient")):
        recorded = dataset.index.get(key)
        if recorded is None:
            continue
        ours = sorted({round(getattr(m, name), 6) for m in media})
        if ours != sorted(round(float(x), 6) for x in recorded):
            raise ValueError(f"the scene's {name} {ours} differs from the dataset's {recorded}: reconstruct with "
                             "the material the data was measured with")
