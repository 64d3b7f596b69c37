"""The forward model of a reconstruction: the tracer it renders its field with, and its step."""
from __future__ import annotations

import mitsuba as mi

from ..scene import scene_tracer
from ..tracer import Tracer, TracerConfig
from ..tracer.methods import Linear
from .config import TWO_STEP, OptimizeConfig
from .fields import TrainableField


def forward_step(config: OptimizeConfig, stress_field: TrainableField) -> float:
    """The step (mm) a reconstruction marches ``stress_field`` with: the configuration's, else on a lattice (a grid,
    or a network sampled on one) half its node spacing as it stands, so that a coarse-to-fine stage marches its own
    coarse lattice with steps as much longer (the 8-node stage of a 64-node run takes an eighth of the steps), and
    the finest stage the final lattice's."""
    if config.model.step_size is not None:
        return config.model.step_size
    extent = stress_field.bbox_max - stress_field.bbox_min
    if stress_field.lattice:
        return float(0.5 * extent.max() / (max(stress_field.shape) - 1))
    return float(extent.max()) / 64.0


def make_tracer(config: OptimizeConfig, stress_field: TrainableField, scene: mi.Scene,
                method: str | None = None) -> Tracer:
    """The tracer a reconstruction renders ``scene`` with: jittered steps (no bias from a fixed grid) of
    :func:`forward_step`, and the scene integrator's surface settings (``max_crossings``, ``max_bounces``),
    which a reconstruction keeps: the data were rendered so (a dataset simulated with ghosts is fitted with
    them). ``method`` overrides the config's forward model; the Two-step fits through the linear model."""
    method = method or config.model.method
    surfaces = scene_tracer(scene).config
    return Tracer(TracerConfig(method=Linear.name if method == TWO_STEP else method,
                               step_size=forward_step(config, stress_field), jitter=True,
                               max_crossings=surfaces.max_crossings, max_bounces=surfaces.max_bounces))
