"""What a run decided for itself, and from what: the lines ``optimize`` prints before it starts and records in
``reconstruction.json`` (``source.choices``), so that a user who gave no option sees what the defaults became on
their data."""
from __future__ import annotations

import numpy as np

from ..dataset import Dataset
from ..tracer.registry import METHODS as TRACER_METHODS
from .kinds import AUTO, GRID
from .config import DENSE_REGULARISED, FORWARD_MODELS, NO_REGULARISER, REGULARISED, TWO_STEP, OptimizeConfig
from .fields import (DEFAULT_RESOLUTIONS, DENSE_FRINGES_PIXELS, DENSE_FRINGES_SHARE, GRID_NODE_LIMIT,
                     MIN_NODES_ACROSS, dense_fringes, grid_shape, share_at_reference)

METHOD_NAMES = {**{name: TRACER_METHODS[name].label for name in FORWARD_MODELS}, TWO_STEP: "the Two-step baseline"}


def data_facts(dataset: Dataset) -> str:
    """The rotations and the fringe density of ``dataset``, as the choices read them."""
    train = [dataset.rotations[i] for i in dataset.split("train")]
    spans = []
    for axis in ("azimuth", "elevation"):
        angles = np.array([r[axis] for r in train], dtype=float)
        if np.ptp(angles) > 0:
            spans.append(f"{axis}s spanning {np.ptp(angles):.0f} degrees")
    width, height = dataset.resolution
    about = " and ".join(spans) if spans else "one pose"
    facts = f"{len(train)} training rotations, {about}, at {width}x{height} pixels"
    if dataset.bands is not None:
        facts += f", in {len(dataset.bands)} bands ({dataset.bands.describe()})"
    aliasing = dataset.index.get("fringe_aliasing")
    if aliasing and aliasing.get("views"):
        facts += (f"; fringes denser than the pixels in {100 * aliasing['mean_fraction']:.0f}% of the specimen's "
                  f"pixels (up to {aliasing['densest']:.2g} orders per pixel)")
    elif aliasing:
        facts += "; fringes resolved by the pixels"
    return facts


def choices(asked: OptimizeConfig, settled: OptimizeConfig, extent: np.ndarray, dataset: Dataset,
            aliased_share: float = 0.0, pixels: int = DENSE_FRINGES_PIXELS, neighbours_apply: bool = True) -> list[str]:
    """One line on the data, one on what the run chose and why (``asked``: before :func:`~.fields.settle`, which
    was given the same ``extent``, ``aliased_share``, ``pixels`` and ``neighbours_apply``)."""
    field = settled.field
    if field.on_lattice:
        nx, ny, nz = grid_shape(field.resolution, extent)
        if asked.field.resolution is not None:
            why = "--resolution"
        elif dense_fringes(aliased_share, pixels):
            why = f"the finest default: {_dense(aliased_share, pixels)}"
        else:
            why = (f"the coarsest of {', '.join(map(str, DEFAULT_RESOLUTIONS))} nodes along the longest axis with "
                   f"{MIN_NODES_ACROSS} across the thinnest side")
        lattice = f"{nx}x{ny}x{nz} ({why})"
    if field.kind == GRID.name:
        representation = f"grid {lattice}"
    else:
        why = ("--kind" if asked.field.kind != AUTO.name else
               f"a grid at {asked.field.resolution} nodes would pass {GRID_NODE_LIMIT:,} nodes")
        representation = f"{field.kind} ({why}), " + (f"sampled once an iteration on a lattice {lattice}"
                                                      if field.on_lattice else "evaluated at every step")
    if settled.model.step_size is not None:
        step = f"{settled.model.step_size:g} mm steps"
    else:
        step = "steps of half the node spacing" if field.on_lattice else "steps of the box / 64"
    regulariser = settled.regulariser
    if regulariser == REGULARISED:
        smoothing = ("the targets' smoothness, eased above a field RMS of "
                     f"{regulariser.relative_to:g} stress scales")
    elif regulariser == DENSE_REGULARISED:
        smoothing = (f"the targets' smoothness eased above a field RMS of {regulariser.relative_to:g} stress "
                     "scales, for dense fringes")
    elif regulariser == NO_REGULARISER:
        smoothing = "no regulariser"
    else:
        smoothing = "the regulariser as given"
    if regulariser.equilibrium:
        smoothing += f", equilibrium prior {regulariser.equilibrium:g}"
    smoothing += "; " + _neighbour_choice(asked, settled, aliased_share, pixels, neighbours_apply)
    schedule = settled.schedule
    budget = f"{schedule.iterations:,} iterations" + (
        "" if schedule.time_limit is None else f" or {schedule.time_limit / 60:.3g} minutes, whichever ends first")
    if schedule.start is not None:
        budget += f"; from the start field {schedule.start}, on the final grid alone (no coarse stages or path " \
                  f"curriculum), learning rate {settled.optimiser.learning_rate:g}"
        if settled.optimiser.learning_rate != asked.optimiser.learning_rate:
            budget += " (a started run's, below the descent's: its first steps would throw the start off)"
    return [f"data: {data_facts(dataset)}",
            f"chose: {representation}; {METHOD_NAMES[settled.model.method]} in {step}; {smoothing}; {budget}"]


def _neighbour_choice(asked: OptimizeConfig, settled: OptimizeConfig, aliased_share: float, pixels: int,
                      neighbours_apply: bool) -> str:
    """What the run fits of the neighbour loss, and why."""
    optimiser = settled.optimiser
    if asked.optimiser.neighbour_loss is not None:
        why = "neighbour_loss"
    elif not neighbours_apply:
        why = "the scene refracts or the data have bands"
    elif settled.model.method == TWO_STEP:
        why = "the Two-step baseline fits the retardance alone"
    elif dense_fringes(aliased_share, pixels):
        why = _dense(aliased_share, pixels)
    else:
        why = "the fringes resolved by the pixels, straight rays, one band"
    if not optimiser.neighbour_loss:
        return f"no neighbour loss ({why})"
    return (f"the neighbour loss at weight {optimiser.neighbour_loss:g} over the first "
            f"{100 * optimiser.neighbour_share:.0f}% of the run ({why})")


def _dense(aliased_share: float, pixels: int) -> str:
    """Why fringes aliased in ``aliased_share`` of the pixels of images ``pixels`` across count as dense
    (:func:`~.fields.dense_fringes`): the share as the rule reads it."""
    why = f"the fringes alias in more than {100 * DENSE_FRINGES_SHARE:.0f}% of the pixels"
    if pixels != DENSE_FRINGES_PIXELS:
        scaled = share_at_reference(aliased_share, pixels)
        why += f" at {DENSE_FRINGES_PIXELS} across (about {100 * scaled:.0f}%; {100 * aliased_share:.0f}% at {pixels})"
    return why
