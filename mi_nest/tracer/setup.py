"""What one render needs from the scene: the specimens' media and fields, a shape lookup, the polariscope.

Media, the light and the camera are recognised by the parts their plugin
classes register as (``parts.py``).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Callable

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_nest import occupancy
from mi_nest.fields import StressField
from mi_nest.physics import Polariscope, projection

from . import surfaces
from .guards import SceneSetupError, require_closed
from .parts import PolariscopeCameraPart, PolariscopeLightPart, StressMediumPart

if TYPE_CHECKING:
    from .segment import Segment


class SceneSetup:
    """The distinct stress media, the field each one holds, the shape-to-medium table and the optics.

    ``field``, if given, is sampled in every specimen instead of its medium's
    own (a reconstruction's trainable field); the media keep their material.
    ``right`` is each ray's image-right direction; by default the camera's.
    ``phase_scale`` multiplies every phase (a view's load scale or wavelength).
    ``marching=False`` is a set-up that only decides the method, which skips
    building :attr:`projected`.
    """

    def __init__(self, scene: mi.Scene, sensor: mi.Sensor | None, right: mi.Vector3f | None = None,
                 field: StressField | None = None, phase_scale: float = 1.0, marching: bool = True):
        self.phase_scale = phase_scale
        # The largest factor on the phases a march here multiplies (a spectral march's shortest wavelength's):
        # what ``auto`` chooses its steps for.
        self.strongest_phase_scale = phase_scale
        self.media = []
        self.specimens = []     # (shape, index of its medium), in scene order
        shape_media = {}
        shape_ratios = {}       # shape id -> int_ior / ext_ior of its dielectric surface
        baths = []
        bounds = mi.ScalarBoundingBox3f()
        for shape in scene.shapes():
            medium = shape.interior_medium()
            is_specimen = isinstance(medium, StressMediumPart)
            shape_id = occupancy.shape_id(shape)
            ratio = surfaces.interface_ratio(shape)
            if ratio == 1.0 and is_specimen:
                ratio = None        # index-matched: the straight walk, as without a surface
            if ratio is not None:
                shape_ratios[shape_id] = ratio
                if not is_specimen:
                    require_closed(shape, shape_id, "bath")
                    baths.append(shape)
            if is_specimen:
                bounds.expand(shape.bbox())
                require_closed(shape, shape_id)
                if medium not in self.media:
                    self.media.append(medium)
                self.specimens.append((shape, self.media.index(medium)))
                shape_media[shape_id] = self.media.index(medium) + 1
        if not self.media:
            raise SceneSetupError('photoelastic: the scene has no specimen: add a shape with '
                                  '<medium type="stress" name="interior"> inside it')
        # No line crosses the specimens for longer: the bound on any ray's path inside them.
        self.specimen_diagonal = float(dr.norm(bounds.extents()))
        table = np.zeros(max(shape_media) + 1, dtype=np.uint32)
        for shape_id, index in shape_media.items():
            table[shape_id] = index
        self.medium_of_shape = mi.UInt32(table)
        # Where surfaces refract, the walk of tracer/refraction.py follows the bent paths.
        self.refracting = bool(shape_ratios)
        if self.refracting:
            ratios = np.zeros(max(max(shape_ratios), len(table) - 1) + 1, dtype=np.float32)
            for shape_id, ratio in shape_ratios.items():
                ratios[shape_id] = ratio
            self.ratio_of_shape = mi.Float(ratios)
            self.medium_of_shape = mi.UInt32(np.pad(table, (0, len(ratios) - len(table))))
            for bath in baths:
                for shape, _ in self.specimens:
                    surfaces.require_apart(scene, shape, bath)
        self.fields = [medium.field if field is None else field for medium in self.media]
        # Per medium, ``pi C / lambda`` times its field's stress at points: phase per mm.
        self.phase_tensors = [_phase_tensor(f, medium.phase_rate) for f, medium in zip(self.fields, self.media)]

        lights = [e for e in scene.emitters() if isinstance(e, PolariscopeLightPart)]
        if len(lights) != 1:
            raise SceneSetupError(f"photoelastic: the scene needs exactly one "
                                  f'<emitter type="polariscope_light">, found {len(lights)}')
        light = lights[0]
        self.radiance = light.radiance
        # A finite panel: (side, distance behind the specimens' centre, that centre, the camera's axis).
        self.panel = None
        if light.size is not None:
            forward = None if sensor is None else dr.normalize(sensor.world_transform() @ mi.Vector3f(0, 0, 1))
            self.panel = (light.size, light.distance, bounds.center(), forward)
        self.polariscope = Polariscope(light.optics, sensor.optics if isinstance(sensor, PolariscopeCameraPart) else ())
        own_right = right is None
        if right is None:
            right = sensor.world_transform() @ mi.Vector3f(-1, 0, 0)
        self.right = dr.normalize(mi.Vector3f(right))
        self.projected = self._projected_field(sensor, own_right) if marching else None
        # One camera's rays are coherent: Embree traced them 3.7x faster flagged so (512², the disk). A batch
        # drawn across views is not: flagged coherent, the kitten's training batches traced 4 to 6% slower.
        self.coherent_rays = sensor is not None

    def projection_coefficients(self, d: mi.Vector3f) -> tuple[tuple, tuple]:
        """Per ray, what turns :meth:`phase_tensor` into the step generator ``(p, q)``.

        The basis (u, v) is image right/up made perpendicular to the light
        direction -d. With a single medium its phase rate is folded in here,
        once per ray, instead of scaling six components at every step.
        """
        return self.frame_coefficients(*projection.transverse_basis(-d, self.right))

    def misses_panel(self, p: mi.Point3f, d: mi.Vector3f, axis: mi.Vector3f) -> mi.Bool:
        """Whether the line ``p + t d`` (t > 0), traced away from the camera, misses a finite light panel; the
        panel faces the camera's axis (``axis``: each ray's first direction where no camera is given)."""
        if self.panel is None:
            return mi.Bool(False)
        size, distance, centre, forward = self.panel
        forward = axis if forward is None else forward
        along = dr.dot(d, forward)
        t = (distance - dr.dot(p - mi.Point3f(centre), forward)) / dr.maximum(along, 1e-12)
        offset = p + t * d - (mi.Point3f(centre) + distance * forward)
        up = dr.normalize(dr.cross(forward, self.right))
        across = dr.normalize(dr.cross(up, forward))
        inside = (dr.abs(dr.dot(offset, across)) <= 0.5 * size) & (dr.abs(dr.dot(offset, up)) <= 0.5 * size)
        return ~((along > 0) & (t > 0) & inside)

    def frame_coefficients(self, u: mi.Vector3f, v: mi.Vector3f) -> tuple[tuple, tuple]:
        """:meth:`projection_coefficients` in a given transverse frame ``(u, v)``: a straight ray's, or one
        carried along a bent path (tracer/refraction.py)."""
        alpha, beta = projection.projection_coefficients(u, v)
        rate = self.media[0].phase_rate if len(self.media) == 1 else 1.0
        if self.phase_scale != 1.0:
            # Opaque: a view's load or wavelength slider launches the same kernel at every setting.
            rate = rate * dr.opaque(mi.Float, self.phase_scale)
        if not (isinstance(rate, float) and rate == 1.0):
            alpha, beta = tuple(rate * a for a in alpha), tuple(rate * b for b in beta)
        return alpha, beta

    def phase_tensor(self, medium: mi.UInt32, p: mi.Point3f) -> tuple:
        """Stress at ``p`` of each ray's medium; scaled by its phase rate unless folded in above."""
        if len(self.media) == 1:
            return self.fields[0].eval(p)
        return dr.switch(medium - 1, self.phase_tensors, p)

    def transverse(self, segment: Segment, along: mi.Float) -> tuple[mi.Float, mi.Float]:
        """``(s_uu - s_vv, 2 s_uv)`` a distance ``along`` into a walk's ``segment``, scaled to phase per mm."""
        if self.projected is not None:
            return self.projected.eval_ray(segment.origin, segment.d, along)
        p = dr.fma(segment.d, along, segment.origin)
        return projection.apply_coefficients(segment.coefficients, self.phase_tensor(segment.medium, p))

    def _projected_field(self, sensor: mi.Sensor | None, own_right: bool):
        """The one field as the camera sees it (:meth:`StressField.projected`), where every ray shares the
        camera's transverse frame: an orthographic camera's own rays, straight (no refracting surface), through
        one medium. None elsewhere, or where the field has no projected lookup."""
        if sensor is None or not own_right or not _orthographic(sensor) or len(self.fields) != 1 or self.refracting:
            return None
        direction = sensor.world_transform() @ mi.Vector3f(0, 0, 1)
        return self.fields[0].projected(*self.projection_coefficients(dr.normalize(direction)))


def _orthographic(sensor: mi.Sensor) -> bool:
    if isinstance(sensor, PolariscopeCameraPart):
        return sensor.projection == "orthographic"
    return sensor.class_name() == "OrthographicCamera"


def _phase_tensor(field: StressField, phase_rate: float) -> Callable[[mi.Point3f], tuple]:
    return lambda p: tuple(phase_rate * s for s in field.eval(p))
