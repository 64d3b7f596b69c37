"""Where a run starts: a known field (an FEM model of the part, an earlier reconstruction) instead of zero.

With dense fringes a descent from zero chooses its branch in the coarse stages and keeps it: on the 600 N disk
the 8-node stage already ends behind a ridge of the data loss, and no later stage leaves it
(experiments/history.md, "A start"). A field near the truth (an FEM model of the part) puts the run in the
right basin; the coarse stages and the path curriculum that otherwise choose the branch are then skipped
(:func:`~.fields.settle`). The basin is narrow: on the 600 N disk a model at 95% of the load ended at 9.0%
error, one at 90% at 19.6%. A model's load is rarely the test's, and in linear elasticity stress follows the
load, so the start is first scaled to the load factor whose images fit a sample of the training views best
(:func:`best_scale`), about ``start_load_ratio`` where the start is the part at another load: a reconstruction
at a low load, whose fringes a descent from zero resolves, starts the test load (a load series).
"""
from __future__ import annotations

from pathlib import Path

import mitsuba as mi
import numpy as np

from ..fields import StressField
from ..fields.base import sample
from ..fields.grid import GridField
from ..fields.sources import SUPPORTED, grid_from_file, is_stress_file
from ..scene import specimen_bounds
from . import metrics
from .checkpoints import Reconstruction
from .fields import TrainableField

# Nodes along the longest axis that a mesh start (3D-TSV, FEM .npz) is resampled on before the fit: finer than any
# default grid of a run.
MESH_RESOLUTION = 128
# Load factors tried for a start, apart: the 600 N disk's basin is about 5% of the load wide.
SCALE_STEP = 0.02
# Training views (and rays per pixel: the run's own) that score each load factor.
SCALE_VIEWS = 16
# The share of the specimen a start's box must cover: less, and it describes another part or other coordinates.
MIN_COVERED = 0.9
WHAT = f"a reconstruction directory or a stress file ({SUPPORTED})"


def start_field(source: str | Path) -> StressField:
    """The field ``source`` names: a ``mi-nest reconstruct`` result's, or a stress file's."""
    path = Path(source)
    if path.is_dir():
        if not (path / "field.npz").is_file():
            raise ValueError(f"start {path} is a directory without a reconstruction's field.npz: give {WHAT}")
        return Reconstruction.load(path).field
    if not path.is_file():
        raise ValueError(f"start field not found: {path} (give {WHAT})")
    if not is_stress_file(path):
        raise ValueError(f"start {path}: not a stress file by its suffix '{path.suffix}' (give {WHAT})")
    return GridField(grid_from_file(path, MESH_RESOLUTION))


def starting_nodes(field: TrainableField, start: StressField, scene: mi.Scene, shapes: list, name: str) -> np.ndarray:
    """The nodes of grid ``field`` that fit ``start``'s deviator best inside the specimens (least squares on the
    lattice the errors are fitted on); one-line errors for a start that misses the part or holds no stress."""
    points = metrics.evaluation_points(scene, shapes, 3 * metrics.EVALUATION_POINTS)
    low, high = (np.asarray(start.bbox_min, dtype=np.float64), np.asarray(start.bbox_max, dtype=np.float64))
    margin = 0.01 * (high - low)
    covered = np.all((points >= low - margin) & (points <= high + margin), axis=1).mean()
    if covered < MIN_COVERED:
        part_low, part_high = specimen_bounds(shapes)
        raise ValueError(f"start {name} covers {100 * covered:.0f}% of the specimen (its box {_box(low, high)}, "
                         f"the specimen's {_box(part_low, part_high)}): it describes another part or other "
                         "coordinates")
    values = sample(start, points)
    if not np.isfinite(values).all():
        raise ValueError(f"start {name} holds NaN or infinite stress inside the specimen")
    if not np.abs(values).max() > 0:
        raise ValueError(f"start {name} holds no stress inside the specimen: start from zero instead (drop start)")
    return metrics.nodes_fitting(field, values, points)


def _box(low, high) -> str:
    return "[" + ", ".join(f"{v:.3g}" for v in low) + "] .. [" + ", ".join(f"{v:.3g}" for v in high) + "] mm"


def best_scale(field: TrainableField, nodes: np.ndarray, loss, spread: float) -> float:
    """The factor within ``1 +- spread`` (steps of :data:`SCALE_STEP`) whose ``factor * nodes`` in ``field`` score
    the lowest ``loss``. The loss is periodic in the retardance, so the factors are scanned, not descended."""
    count = int(round(spread / SCALE_STEP))
    factors = 1.0 + SCALE_STEP * np.arange(-count, count + 1)
    losses = []
    for factor in factors:
        field.set_nodes(factor * nodes)
        losses.append(loss(field))
    return float(factors[np.argmin(losses)])


def start_line(began_at: dict, spread: float, ratio: float = 1.0) -> str:
    """What :meth:`~.loop.Run.start_from` did, for the run's choices."""
    line = f"start: {began_at['start']}"
    if spread > 0:
        line += (f" at {began_at['start_factor']:.2f} times its load, the factor from {ratio * (1 - spread):.2f} "
                 f"to {ratio * (1 + spread):.2f} whose images fit {SCALE_VIEWS} training views best")
    elif ratio != 1.0:
        line += f" at {ratio:.2f} times its load, as given"
    return line
