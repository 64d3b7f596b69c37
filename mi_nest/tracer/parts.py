"""What the tracer needs from a scene's plugins, without importing them.

The plugins (``plugins/``) sit above the tracer and register their classes
here at the bottom of their modules, beside their Mitsuba registration; a
scene's media, light and camera are then recognised with ``isinstance``. The
plugin modules are re-imported whenever the Mitsuba variant changes, and each
new class registers again.
"""
from __future__ import annotations

import abc


class StressMediumPart(abc.ABC):
    """A specimen's interior: ``field`` (a :class:`~mi_nest.fields.StressField`) and ``phase_rate``
    (``pi C / lambda``, radians per mm per MPa)."""


class PolariscopeLightPart(abc.ABC):
    """The polariscope's light panel: ``radiance``, ``optics`` (its optical elements from its polariser to the
    specimen, ``physics.polariscope``), ``size`` (mm or None: unbounded) and ``distance`` (mm behind the
    specimens' centre)."""


class PolariscopeCameraPart(abc.ABC):
    """The polariscope's camera: ``optics`` (its optical elements from the specimen to the camera) and
    ``projection``."""
