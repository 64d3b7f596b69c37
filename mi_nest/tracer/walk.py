"""The straight walk: each ray through every specimen of an index-matched scene, segment by segment.

Where surfaces refract, ``refraction.py`` walks instead; both hand each inside
segment to the method as a :class:`~.methods.Segment`.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Callable

import drjit as dr
import mitsuba as mi

from mi_nest import occupancy

from .segment import Segment, equal_steps

if TYPE_CHECKING:
    from .setup import SceneSetup

# Queries again, each from a little further on, for a crossing that a ray inside a specimen did not find.
RETRIES = 2


@dr.syntax
def walk(scene: mi.Scene, ray: mi.Ray3f, setup: SceneSetup, step_size: float, active: mi.Bool, seeds: mi.UInt32,
         progress: object, segment_step: Callable, max_crossings: int,
         log: SegmentLog | None = None) -> tuple[object, mi.Bool, mi.Float]:
    """Follow each ray through every specimen; ``progress = segment_step(progress, segment, setup)`` for each
    inside segment (what the pass threads along the ray: the primal product so far, or the replay's). With a
    ``log``, the marched segments go into it, for :func:`walk_logged` to march again.

    Returns ``(progress, blocked, length)``: whether an opaque shape stops the ray,
    and its length inside specimens. The primal pass and the adjoint replay
    differ only in ``progress`` and ``segment_step``.

    Inside a specimen the next crossing must be its exit (or a glued
    neighbour's face, or an opaque shape), and an exit must follow an entry
    (or another specimen's exit: faces glued, the coincident entry skipped).
    Where they do not, Embree missed a face where the ray met a mesh edge (it
    does without robust intersections, whatever flags the scene was loaded
    with) or the ray grazed a silhouette: the query is made again from a
    point nudged by a surface clearance (``occupancy.nudged``), not flagged
    coherent (coherent queries round alike), up to :data:`RETRIES`
    times. What is still there was a touch, and marches nothing.
    """
    d = mi.Vector3f(ray.d)
    coefficients = setup.projection_coefficients(d)
    origin = mi.Point3f(ray.o)
    launch = mi.Point3f(ray.o)      # where the next intersection query starts
    reach = mi.Float(ray.maxt)      # and how far it looks: the camera's range, then unbounded
    medium = mi.UInt32(0)           # 0 outside, i + 1 inside specimen medium i
    current = mi.UInt32(0)          # the specimen shape the ray is in (0 outside)
    after_exit = mi.Bool(False)     # whether the last crossing left a specimen
    retries = mi.UInt32(0)          # queries again for the same crossing
    blocked = mi.Bool(False)
    length = mi.Float(0)
    crossings = mi.UInt32(0)
    logged = mi.UInt32(0)
    active = mi.Bool(active)

    # Only what changes is loop state: Dr.Jit traces the body again to drop any state that does not.
    while dr.hint(active, exclude=[coefficients, d, ray, scene, seeds, segment_step, setup, step_size, log]):
        si = scene.ray_intersect(mi.Ray3f(launch, d, reach, ray.time, ray.wavelengths),
                                 ray_flags=mi.RayFlags.Minimal, coherent=setup.coherent_rays & (retries == 0),
                                 active=active)
        hit = si.is_valid()
        shape = dr.reinterpret_array(mi.UInt32, si.shape)
        hit_medium = dr.gather(mi.UInt32, setup.medium_of_shape, shape, hit)
        entering = dr.dot(si.n, d) < 0
        exiting = hit & ~entering & (hit_medium != 0)
        unexpected = dr.select(medium != 0, ~hit | (entering & (shape == current)), exiting & ~after_exit)
        retry = active & unexpected & (retries < RETRIES)
        # Leaving a specimen proves the segment was inside it, even if its entry face was
        # skipped for coinciding with the face just left (specimens glued face to face).
        inside = dr.select(exiting, hit_medium, medium)
        # The chord between hit points, not the spawned ray's t (its origin is offset).
        chord = dr.norm(si.p - origin)
        marched = active & hit & (inside != 0) & ~unexpected
        steps, h = equal_steps(chord, marched, step_size)
        segment_seed = mi.sample_tea_32(seeds, crossings)[0]
        segment = Segment(steps, h, inside, origin, d, coefficients, segment_seed)
        progress = segment_step(progress, segment, setup)
        logged = _log_segment(log, segment, logged, marched)
        length += dr.select(marched, chord, 0.0)
        crossed = ~retry
        blocked |= crossed & hit & (hit_medium == 0)
        medium = dr.select(crossed, dr.select(entering, hit_medium, 0), medium)
        current = dr.select(crossed, dr.select(entering & (hit_medium != 0), shape, 0), current)
        after_exit = dr.select(crossed, exiting & ~unexpected, after_exit)
        origin = dr.select(crossed, si.p, origin)
        launch = dr.select(crossed, occupancy.past_surface(si, d), occupancy.nudged(launch, d, retries))
        reach = dr.select(crossed, dr.inf, reach)
        retries = dr.select(crossed, 0, retries + 1)
        crossings += 1
        active &= (hit | retry) & ~blocked & (crossings < max_crossings)
    _close_log(log, logged)
    return progress, blocked, length


class SegmentLog:
    """The inside segments a straight walk marched, ray by ray (the first ``capacity`` of each), so that a replay
    of it marches them again without querying the scene: a walk's intersections cost as much as a coarse grid's
    steps. ``count`` is how many each ray marched, kept or not."""

    # What a segment keeps, of Segment's fields (the ray's direction and coefficients are the ray's own).
    KEPT = (("steps", mi.UInt32), ("h", mi.Float), ("medium", mi.UInt32), ("origin", mi.Point3f), ("seed", mi.UInt32))

    def __init__(self, rays: int, capacity: int):
        self.capacity = capacity
        # Only the first ``count`` slots of a ray are written and read.
        self.kept = {name: dr.empty(kind, rays * capacity) for name, kind in self.KEPT}
        self.count = mi.UInt32(0)

    def slots(self, index: mi.UInt32) -> mi.UInt32:
        return dr.arange(mi.UInt32, dr.width(index)) * self.capacity + index

    def keep(self, segment: Segment, index: mi.UInt32, active: mi.Bool) -> None:
        """``segment`` as each ray's ``index``-th, where ``active`` and there is room."""
        slot = self.slots(index)
        for name, _ in self.KEPT:
            dr.scatter(self.kept[name], getattr(segment, name), slot, active & (index < self.capacity))

    def segment(self, index: mi.UInt32, d: mi.Vector3f, coefficients: tuple) -> Segment:
        """Each ray's ``index``-th kept segment, along ``d``."""
        slot = self.slots(index)
        return Segment(d=d, coefficients=coefficients,
                       **{name: dr.gather(kind, self.kept[name], slot) for name, kind in self.KEPT})

    def arrays(self) -> tuple:
        return *self.kept.values(), self.count

    def most(self) -> int:
        """The most segments any ray marched (a read back from the device)."""
        return int(dr.max(self.count, axis=None)[0]) if dr.width(self.count) else 0


def _log_segment(log: SegmentLog | None, segment: Segment, logged: mi.UInt32, marched: mi.Bool) -> mi.UInt32:
    if log is None:
        return logged
    log.keep(segment, logged, marched)
    return logged + dr.select(marched, 1, 0)


def _close_log(log: SegmentLog | None, logged: mi.UInt32) -> None:
    if log is not None:
        log.count = logged


@dr.syntax
def walk_logged(ray: mi.Ray3f, setup: SceneSetup, log: SegmentLog, progress: object,
                segment_step: Callable) -> object:
    """:func:`walk`'s segments again, from its ``log``: ``progress`` threaded through them in the same order."""
    d = mi.Vector3f(ray.d)
    coefficients = setup.projection_coefficients(d)
    index = mi.UInt32(0)
    while dr.hint(index < log.count, exclude=[coefficients, d, log, segment_step, setup]):
        progress = segment_step(progress, log.segment(index, d, coefficients), setup)
        index += 1
    return progress


def past_panel(setup: SceneSetup, ray: mi.Ray3f, blocked: mi.Bool) -> mi.Bool:
    """``blocked``, or where a straight ray misses a finite light panel (it brings no light either)."""
    if setup.panel is None:
        return blocked
    return blocked | setup.misses_panel(mi.Point3f(ray.o), mi.Vector3f(ray.d), mi.Vector3f(ray.d))
