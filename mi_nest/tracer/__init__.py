"""The photoelastic tracer: rays through the specimens' stress fields (docs/architecture.md).

``tracer.py`` (:class:`Tracer` and its :class:`TracerConfig`: renders' samples,
ray batches, chords and bent paths, each call planned with the method decided
for it), ``setup.py`` (what a trace needs from the scene), ``walk.py`` (the
straight walk) and ``refraction.py`` (the walk that bends at the surfaces
``surfaces.py`` finds), ``methods.py`` (the models of the ordered exponential,
one object each), ``spectral.py`` (several wavelengths in one march),
``auto.py`` (the analysis behind ``auto``), ``registry.py`` (methods by name),
``film.py`` (channels, pixel sums, developing), ``guards.py`` (what the tracer
refuses or warns about) and ``parts.py`` (what the plugins register as). The ``photoelastic`` integrator plugin is a thin Mitsuba adapter
over it; reconstructions and slices use a :class:`Tracer` directly.
"""
from .tracer import SCENE_VIEW, LaneChannels, PathKind, TracedRays, TracePlan, Tracer, TracerConfig, View

__all__ = ["SCENE_VIEW", "LaneChannels", "PathKind", "TracedRays", "TracePlan", "Tracer", "TracerConfig", "View"]
