"""The forward model of a reconstruction: the integrator it renders its field with."""
from __future__ import annotations

import mitsuba as mi

from .config import OptimizeConfig
from .fields import TrainableField


# What the scene's own integrator decides about its surfaces, which a reconstruction keeps: the data were
# rendered so (a dataset simulated with ghosts is fitted with them).
SURFACE_SETTINGS = ("max_crossings", "max_bounces")


def make_integrator(config: OptimizeConfig, stress_field: TrainableField, scene: mi.Scene,
                    method: str | None = None) -> mi.Integrator:
    """The photoelastic integrator a reconstruction renders ``scene`` with (jittered steps, no bias from a fixed
    grid; the scene integrator's ``SURFACE_SETTINGS``); ``method`` overrides the config's forward model.

    A grid's default step is half its node spacing: the grid as it stands, so that a coarse-to-fine stage marches
    its own coarse grid with steps as much longer (the 8-node stage of a 64-node run takes an eighth of the
    steps), and the finest stage the final grid's."""
    step = config.model.step_size
    if step is None:
        extent = stress_field.bbox_max - stress_field.bbox_min
        if stress_field.kind == "grid":
            step = 0.5 * extent.max() / (max(stress_field.shape) - 1)
        else:
            step = float(extent.max()) / 64.0
    method = method or config.model.method
    method = "linear" if method == "two-step" else method
    surfaces = {name: getattr(scene.integrator(), name) for name in SURFACE_SETTINGS
                if hasattr(scene.integrator(), name)}
    return mi.load_dict({"type": "photoelastic", "method": method, "step_size": float(step), "jitter": True,
                         **surfaces})
