"""The photoelastic tracer: rays through the specimens' stress, for renders, ray batches and virtual slices.

A :class:`Tracer` is made from a :class:`TracerConfig` (the ``photoelastic``
integrator's properties). Every call sets the scene up and decides the method
(:meth:`Tracer.plan`); what a call marches is passed to it, never left on the
tracer: the field (a reconstruction's, or the specimens' own), the
:class:`View` (a polariscope and a factor on every phase) and a decision made
once for several render passes. A ray batch's result is a
:class:`TracedRays`, which says what its state holds.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from mi_nest.fields import StressField
from mi_nest.physics import MEASUREMENTS, Polariscope, jones, su2

from . import auto, guards, refraction
from .film import CHANNELS, JONES_CHANNELS, UNDIFFERENTIATED
from .methods import Decision, Method
from .segment import Segment, equal_steps
from .registry import method_named, require_adjoint, require_replay_through_refraction
from .setup import SceneSetup
from .spectral import can_march_spectra, spectral, split_lanes
from .walk import SegmentLog, past_panel, walk, walk_logged


@dataclass(frozen=True)
class TracerConfig:
    """How the tracer marches; the ``photoelastic`` integrator's properties (its docstring describes each)."""
    step_size: float = 0.5                  # mm, the longest step
    method: str = "product"                 # a name of registry.METHODS
    points: str = "midpoint"                # for product: where each step is sampled (methods.POINTS)
    jitter: bool = False                    # sample each step at a random point instead
    tolerance: float = 1e-3                 # for auto: the largest error of the 16 intensities
    max_crossings: int = 64                 # surface crossings followed per ray
    max_bounces: int = refraction.DEFAULT_MAX_BOUNCES   # partial reflections per ghost path

    def __post_init__(self):
        if not (math.isfinite(self.step_size) and self.step_size > 0):
            raise ValueError(f"photoelastic: 'step_size' must be a positive length in mm, got {self.step_size}")
        self.model()        # refuses unknown names
        if not (math.isfinite(self.tolerance) and self.tolerance > 0):
            raise ValueError(f"photoelastic: 'tolerance' must be positive, got {self.tolerance}")
        if self.max_crossings < 2:
            raise ValueError(f"photoelastic: 'max_crossings' must be at least 2, got {self.max_crossings}")
        if self.max_bounces < 0:
            raise ValueError(f"photoelastic: 'max_bounces' must be 0 or more, got {self.max_bounces}")

    def model(self) -> Method:
        """The method object this configuration names (``auto``'s decides per render)."""
        return method_named(self.method, self.points, self.jitter, self.tolerance)


class LaneChannels(enum.Enum):
    """What each wavelength of a spectral render adds after its main intensity, as ``<lane>.<name>``."""
    INTENSITY = ()                          # nothing more
    MEASUREMENTS = tuple(MEASUREMENTS)      # its 16 measurements
    JONES = JONES_CHANNELS                  # its Jones product (what a polariscope as built is applied to)

    def values(self, q: su2.Quaternion, seen, radiance: mi.Float) -> list[mi.Float]:
        """This lane's channels from its specimens' product ``q`` and what the polariscope sees of it ``seen`` (the
        whole path's matrix where surfaces refract)."""
        if self is LaneChannels.JONES:
            return list(q)
        return [radiance * MEASUREMENTS[name].intensity(seen) for name in self.value]


@dataclass(frozen=True)
class View:
    """What a view changes without loading the scene again: a polariscope instead of the scene's (None: the
    scene's), a factor on every phase (a load scale, or a wavelength's ratio) and, for a spectral march
    (``spectral.py``), its wavelengths as ``(channel name, factor on phase_scale)`` pairs: each adds its main
    intensity as that channel, then ``lane_channels``' as ``<name>.<channel>`` (no lanes: one wavelength)."""
    polariscope: Polariscope | None = None
    phase_scale: float = 1.0
    lanes: tuple[tuple[str, float], ...] = ()
    lane_outputs: LaneChannels = LaneChannels.INTENSITY

    def __post_init__(self):
        if not math.isfinite(self.phase_scale):
            raise ValueError(f"photoelastic: the phase scale must be a finite number, got {self.phase_scale}")
        names = [name for name, _ in self.lanes]
        if len(set(names)) != len(names) or set(self.lane_channels) & set(CHANNELS):
            raise ValueError(f"photoelastic: a spectral view's channel names must be distinct and not the "
                             f"integrator's own channels, got {names}")
        bad = [factor for _, factor in self.lanes if not (math.isfinite(factor) and factor > 0)]
        if bad:
            raise ValueError(f"photoelastic: a spectral view's phase factors must be positive numbers, got {bad}")

    @property
    def lane_channels(self) -> tuple[str, ...]:
        """The channels the lanes add to a render, in order."""
        return tuple(channel for name, _ in self.lanes
                     for channel in (name, *(f"{name}.{c}" for c in self.lane_outputs.value)))


SCENE_VIEW = View()


class OpaquePolariscope:
    """A view's polariscope with its linear forms as opaque Dr.Jit values: a view that turns its polariscope (a
    viewer's slider) launches the same kernel, where literal forms compiled one kernel per setting (0.4 s)."""

    def __init__(self, scope: Polariscope):
        self._forms = tuple(tuple(tuple(dr.opaque(mi.Float, k) for k in part) for part in row)
                            for row in scope.coefficients())

    def coefficients(self) -> tuple:
        return self._forms

    def intensity(self, q) -> mi.Float:
        return Polariscope.intensity(self, q)


@dataclass
class TracePlan:
    """What the calls inside one render or ray batch share: the scene set-up, the method decided for it
    (spectral where the view has lanes) and the channels the lanes add (``View.lane_channels``)."""
    setup: SceneSetup
    decision: Decision
    lanes: tuple[str, ...] = ()
    lane_outputs: LaneChannels = LaneChannels.INTENSITY
    norm_error: mi.Float | None = None      # a method that is not unitary: how far |J|^2 drifted


class PathKind(enum.Enum):
    """What a ray batch's state holds."""
    STRAIGHT = "straight"           # the method's state: a Jones quaternion, or linear's summed generator
    REFRACTED = "refracted"         # the bent path's general Jones matrix, 8 numbers (per wavelength: lanes)
    GHOSTED = "refracted, with a ghost"     # and a sampled partly reflected path's after it: 16 numbers
    SPECTRAL = "straight, at several wavelengths"   # a spectral march's state (spectral.py)


# Segments per ray a replayable batch keeps at first: a convex part marches one, a stack of parts a few.
SEGMENTS_KEPT = 4


@dataclass(frozen=True)
class TracedRays:
    """A ray batch's traced state, whether an opaque shape stops each ray, and its path length (mm) inside
    specimens."""
    kind: PathKind
    method: Method
    state: tuple
    blocked: mi.Bool
    length: mi.Float
    lanes: int = 1          # a refracted batch's wavelengths: their matrices (8 or 16 numbers each) side by side
    segments: SegmentLog | None = None      # a straight batch's marched segments, for its replay

    def jones(self, state: tuple | None = None) -> su2.Quaternion | jones.Biquaternion | jones.Incoherent | list:
        """The Jones matrices of ``state`` (default: the traced one; a differentiable copy of it to take a loss's
        gradient), zero where blocked; a ghost's is added incoherently (zero where it has none); a spectral
        batch's, one per wavelength."""
        state = self.state if state is None else state
        if self.kind is not PathKind.SPECTRAL and self.lanes > 1:
            width = len(state) // self.lanes
            return [_jones(self.kind, self.method, state[k:k + width], self.blocked)
                    for k in range(0, len(state), width)]
        return _jones(self.kind, self.method, state, self.blocked)


def _jones(kind: PathKind, method: Method, state: tuple, blocked: mi.Bool):
    if kind is PathKind.SPECTRAL:
        return [su2.Quaternion(tuple(dr.select(blocked, 0.0, x) for x in q)) for q in method.jones_lanes(state)]
    if kind is PathKind.GHOSTED:
        return jones.Incoherent((_jones(PathKind.REFRACTED, method, state[:8], blocked), _biquaternion(state[8:])))
    if kind is PathKind.REFRACTED:
        return _biquaternion(tuple(dr.select(blocked, 0.0, x) for x in state))
    return su2.Quaternion(tuple(dr.select(blocked, 0.0, x) for x in method.finish(state)))


class Tracer:
    """Rays through a scene's specimens: renders' samples, ray batches, chords and bent paths."""

    def __init__(self, config: TracerConfig = TracerConfig()):
        self.config = config
        self.method = config.model()
        # Segments a replayable batch keeps per ray; grows (up to max_crossings) once a batch marched more.
        self.segments_kept = min(SEGMENTS_KEPT, config.max_crossings)

    def plan(self, scene: mi.Scene, sensor: mi.Sensor | None = None, right: mi.Vector3f | None = None,
             field: StressField | None = None, view: View = SCENE_VIEW, decision: Decision | None = None,
             step_size: float | None = None, marching: bool = True) -> TracePlan:
        """The scene set-up and the method for one render or ray batch: ``decision`` if given, else decided here
        (``auto`` analyses the field) with ``step_size`` (default: the configuration's). ``marching=False`` for
        a plan that only decides."""
        setup = SceneSetup(scene, sensor, right, field, view.phase_scale, marching)
        if view.polariscope is not None:
            setup.polariscope = OpaquePolariscope(view.polariscope)
        if view.lanes:
            # The steps must suit the shortest wavelength's phases, the fastest.
            setup.strongest_phase_scale = view.phase_scale * max(factor for _, factor in view.lanes)
        if decision is None:
            decision = self.method.decide(setup, scene, sensor,
                                          self.config.step_size if step_size is None else step_size)
            if decision.reason is None:         # a step given, not one 'auto' chose for this field
                auto.warn_if_coarse(setup, scene, sensor, decision.step_size)
        if view.lanes:
            decision = decision._replace(method=spectral(decision.method, tuple(f for _, f in view.lanes)))
        guards.check_steps_per_ray(setup.specimen_diagonal, decision.step_size)
        return TracePlan(setup, decision, view.lane_channels, view.lane_outputs)

    def has_spectral_march(self) -> bool:
        """Whether the configured method marches several wavelengths at once (:class:`View` ``lanes``;
        ``auto`` chooses one that does): renders and slices in any scene, ray batches along straight rays."""
        return isinstance(self.method, auto.Auto) or can_march_spectra(self.method)

    def decide(self, scene: mi.Scene, sensor: mi.Sensor, field: StressField | None = None,
               view: View = SCENE_VIEW) -> Decision:
        """The method and step a render of ``sensor`` marches with: for several passes over one unchanged scene
        and camera, decided once (the ``auto`` analysis costs about 10 ms whatever the resolution)."""
        return self.plan(scene, sensor, field=field, view=view, marching=False).decision

    def trace_rays(self, scene: mi.Scene, rays: mi.Ray3f, right: mi.Vector3f, seed: int = 0,
                   field: StressField | None = None, step_size: float | None = None,
                   view: View = SCENE_VIEW, replayable: bool = False) -> TracedRays:
        """Primal march of arbitrary rays (e.g. a training batch drawn across views).

        ``right`` is each ray's image-right direction (its camera's), which fixes
        the polariscope frame; ``field``, if given, is marched in every specimen
        instead of its own stress, with steps of ``step_size`` (default: the
        configuration's). Where surfaces refract the state is the path's general
        Jones matrix, and with ``max_bounces`` a sampled ghost path's after it.
        ``view`` scales the phases; with lanes, one Jones product per wavelength.
        ``replayable``: straight rays keep their marched segments, and :meth:`backpropagate_rays` marches them
        again without querying the scene.
        """
        with dr.suspend_grad():
            plan = self.plan(scene, None, right, field, view, step_size=step_size)
            seeds = _ray_seeds(seed, dr.width(rays.o))
            method = plan.decision.method
            if plan.setup.refracting:
                # Per wavelength, the path's matrix (8 numbers) and, with a ghost, the ghost's after it.
                path = self.walk_refracted(scene, rays, plan, mi.Bool(True), seeds)
                lanes = [tuple(matrix[0]) + tuple(matrix[1]) for matrix, _ in path.lanes]
                kind = PathKind.REFRACTED
                if self.config.max_bounces > 0:
                    ghost = self._ghost_state(scene, rays, plan, _ghost_seeds(seed, dr.width(rays.o)))
                    lanes = [lane + ghost[8 * k:8 * k + 8] for k, lane in enumerate(lanes)]
                    kind = PathKind.GHOSTED
                state = tuple(x for lane in lanes for x in lane)
                dr.eval(state, path.blocked, path.length)
                return TracedRays(kind, method, state, path.blocked, path.length, len(lanes))
            log = SegmentLog(dr.width(rays.o), self.segments_kept) if replayable else None
            (state, _), blocked, length = self._walk(scene, rays, plan, mi.Bool(True), seeds, method.trace_start(),
                                                     method.trace, log)
            blocked = past_panel(plan.setup, rays, blocked)
            dr.eval(state, blocked, length, log.arrays() if log is not None else ())
            return TracedRays(PathKind.SPECTRAL if plan.lanes else PathKind.STRAIGHT, method, state, blocked, length,
                              segments=log)

    def backpropagate_rays(self, scene: mi.Scene, rays: mi.Ray3f, right: mi.Vector3f, traced: TracedRays,
                           state_grad: tuple, seed: int = 0, field: StressField | None = None,
                           step_size: float | None = None, view: View = SCENE_VIEW) -> None:
        """Accumulate into the field parameters the gradient of ``sum(state_grad . traced.state)``.

        Replays the march of :meth:`trace_rays` (same rays, right, seed, field,
        step and view); Jones steps are unitary, so the part of the product still
        ahead is peeled off with conjugates instead of being stored: memory does
        not grow with the number of steps.
        """
        with dr.suspend_grad():
            plan = self.plan(scene, None, right, field, view, step_size=step_size)
            method = plan.decision.method
            require_adjoint(method)
            if plan.setup.refracting:
                require_replay_through_refraction(method)
                total, grad = (tuple(mi.Float(x) for x in values) for values in (traced.state, state_grad))
                dr.make_opaque(total, grad)
                count = dr.width(rays.o)
                width = len(total) // traced.lanes      # each wavelength's numbers
                paths = [(0, _ray_seeds(seed, count), 0)]
                if traced.kind is PathKind.GHOSTED:     # the ghost too, with the same choices: the same seeds
                    paths.append((8, _ghost_seeds(seed, count), self.config.max_bounces))
                for start, seeds, bounces in paths:
                    refraction.replay(scene, rays, plan.setup, method, plan.decision.step_size, seeds,
                                      mi.Bool(True), self.config.max_crossings, _lane_matrices(total, width, start),
                                      _lane_matrices(grad, width, start), bounces)
                    # Each replay's accumulation into the field's gradients runs before the next is traced: without
                    # it, the second replay's share was lost in about one run in three (Dr.Jit 1.x, LLVM).
                    dr.eval()
                return
            # Unevaluated adjoints carry the loss's constants (1 / batch size...) into the kernel,
            # which would then be rebuilt whenever they change.
            state, state_grad = tuple(mi.Float(x) for x in traced.state), tuple(mi.Float(x) for x in state_grad)
            dr.make_opaque(state, state_grad)
            self.replay(scene, rays, plan, mi.Bool(True), _ray_seeds(seed, dr.width(rays.o)), state, state_grad,
                        self._complete(traced.segments))

    def _complete(self, segments: SegmentLog | None) -> SegmentLog | None:
        """``segments`` if they hold every segment the walk marched; else None (the replay queries the scene again)
        and later batches keep as many as this one marched."""
        if segments is None:
            return None
        most = segments.most()
        if most <= segments.capacity:
            return segments
        self.segments_kept = min(1 << (most - 1).bit_length(), self.config.max_crossings)
        return None

    def trace_chords(self, scene: mi.Scene, origins: mi.Point3f, d: mi.Vector3f, chords: list[tuple],
                     right: mi.Vector3f, step_size: float | None = None, seed: int = 0,
                     field: StressField | None = None,
                     view: View = SCENE_VIEW) -> tuple[mi.Float, list[mi.Float], tuple]:
        """Straight chords that the caller chose, marched as the walk marches its segments (for virtual slices).

        Each of ``chords`` is ``(start, end, medium)`` per line ``origins + t d``:
        distances along ``d`` (away from the camera, in that order) and the index
        of the specimen medium there plus one (0: nothing). Returns a render's
        main intensity, its AOV channels and the summed fringe generator
        ``(b, c)``, with steps no longer than ``step_size`` if given.
        """
        with dr.suspend_grad():
            plan = self.plan(scene, None, right, field, view)
            setup = plan.setup
            method = plan.decision.method
            step = plan.decision.step_size if step_size is None else min(step_size, plan.decision.step_size)
            coefficients = setup.projection_coefficients(d)
            seeds = _ray_seeds(seed, dr.width(origins))
            progress = method.trace_start()
            length = mi.Float(0)
            for index, (start, end, medium) in enumerate(chords):
                chord = dr.maximum(end - start, 0.0)
                marched = (medium != 0) & (chord > 0)
                steps, h = equal_steps(chord, marched, step)
                segment = Segment(steps, h, mi.UInt32(medium), dr.fma(d, start, origins), d, coefficients,
                                  mi.sample_tea_32(seeds, mi.UInt32(index))[0])
                progress = method.trace(progress, segment, setup)
                length += dr.select(marched, chord, 0.0)
            state, fringe = progress
            main, aovs = self.outputs(plan, method.finish(state), fringe, mi.Bool(False), length)
            dr.eval(main, aovs, fringe)
            return main[0], aovs, fringe

    def trace_refracted(self, scene: mi.Scene, rays: mi.Ray3f, sensor: mi.Sensor | None = None, seed: int = 0,
                        bounces: int = 0) -> refraction.RefractedPath:
        """The refracted walk of arbitrary ``rays`` in ``sensor``'s (default: the scene's first) polariscope frame:
        each ray's exit point and direction, interfaces crossed and Jones matrices (for tools and tests; renders
        walk per sample). With ``bounces``, a sampled path of up to that many partial reflections instead of the
        transmitted one."""
        with dr.suspend_grad():
            plan = self.plan(scene, scene.sensors()[0] if sensor is None else sensor)
            path = self.walk_refracted(scene, rays, plan, mi.Bool(True), _ray_seeds(seed, dr.width(rays.o)), bounces)
            dr.eval(path)
            return path

    def trace_samples(self, plan: TracePlan, scene: mi.Scene, sampler: mi.Sampler, ray: mi.Ray3f,
                      active: mi.Bool) -> tuple[mi.Spectrum, list[mi.Float], tuple | None]:
        """A render's samples: the main intensity, the AOV channels and what :meth:`replay_samples` needs (None
        where surfaces refract: renders through them are not differentiated)."""
        method = plan.decision.method
        seeds = mi.UInt32(sampler.next_1d() * 4294967296.0)
        if plan.setup.refracting:
            path = self.walk_refracted(scene, ray, plan, active, seeds)
            ghosts = None
            if self.config.max_bounces > 0:
                ghost_seeds = mi.UInt32(sampler.next_1d() * 4294967296.0)
                ghost = self._ghost_state(scene, ray, plan, ghost_seeds, active)
                ghosts = [_biquaternion(ghost[k:k + 8]) for k in range(0, len(ghost), 8)]
            stress = tuple(x for _, lane in path.lanes for x in lane)
            main, aovs = self.outputs(plan, stress, path.fringe, path.blocked, path.length,
                                      [matrix for matrix, _ in path.lanes], ghosts)
            return main, aovs, None
        (state, fringe), blocked, length = self._walk(scene, ray, plan, active, seeds, method.trace_start(),
                                                      method.trace)
        blocked = past_panel(plan.setup, ray, blocked)
        if not method.unitary:
            # Measure how far it drifted (read after the render).
            plan.norm_error = dr.max(dr.select(blocked, 0.0, dr.abs(su2.norm_squared(state) - 1.0)))
        main, aovs = self.outputs(plan, method.finish(state), fringe, blocked, length)
        return main, aovs, (state, fringe, blocked, length)

    def replay_samples(self, plan: TracePlan, scene: mi.Scene, sampler: mi.Sampler, ray: mi.Ray3f,
                       active: mi.Bool, main_grad: mi.Spectrum, aov_grads: list[mi.Float], traced: tuple) -> None:
        """The adjoint of :meth:`trace_samples`: ``main_grad`` and ``aov_grads`` (the adjoints of its outputs)
        into the field, by path replay."""
        seeds = mi.UInt32(sampler.next_1d() * 4294967296.0)
        state, fringe, blocked, length = traced
        with dr.resume_grad():
            leaf = tuple(mi.Float(dr.detach(x)) for x in state)
            dr.enable_grad(leaf)
            main, aovs = self.outputs(plan, plan.decision.method.finish(leaf), fringe, blocked, length)
            objective = dr.sum(main_grad * main)
            for name, value, grad in zip(CHANNELS, aovs, aov_grads):
                # Only channels of the Jones product carry a derivative; skipping zero adjoints also
                # keeps 0 * inf (char.theta at zero retardance) out of the sum.
                if name not in UNDIFFERENTIATED and dr.any(grad != 0, axis=None):
                    objective += grad * value
            dr.backward_from(objective)
            state_grad = dr.grad(leaf)
        self.replay(scene, ray, plan, active, seeds, state, state_grad)

    def outputs(self, plan: TracePlan, specimens: tuple, fringe: tuple, blocked: mi.Bool, length: mi.Float,
                paths: list[jones.Biquaternion] | None = None,
                ghosts: list[jones.Biquaternion] | None = None) -> tuple[mi.Spectrum, list[mi.Float]]:
        """Main intensity and the AOV channels (``film.CHANNELS``, then the lanes') from the specimens' Jones
        quaternion (a method's finished state; a spectral march's, one per wavelength side by side, the film's
        channels being the first wavelength's); with ``paths`` (a refracted path's whole Jones matrix, per
        wavelength) the intensities are theirs, the Jones channels the specimens' own; a ``ghost`` path's
        (partly reflected, zero where there is none; per wavelength) intensities add to them (incoherent light)."""
        setup = plan.setup
        radiance = setup.radiance
        lanes = [su2.Quaternion(tuple(dr.select(blocked, 0.0, x) for x in lane)) for lane in split_lanes(specimens)]
        # What the polariscope sees at each wavelength.
        seen = lanes
        if paths is not None:
            seen = [_jones(PathKind.REFRACTED, plan.decision.method, tuple(path[0]) + tuple(path[1]), blocked)
                    for path in paths]
            if ghosts is not None:
                seen = [jones.Incoherent(pair) for pair in zip(seen, ghosts)]
        q, matrix = lanes[0], seen[0]
        delta, theta, gamma = su2.characteristic_parameters(q)
        aovs = list(q) + [delta, theta, gamma]
        aovs += [radiance * scope.intensity(matrix) for scope in MEASUREMENTS.values()]
        aovs.append(dr.select(blocked, 0.0, dr.norm(mi.Vector2f(fringe)) / dr.pi))
        aovs.append(length)
        if plan.lanes:
            for lane, lane_seen in zip(lanes, seen):
                aovs.append(radiance * setup.polariscope.intensity(lane_seen))
                aovs += plan.lane_outputs.values(lane, lane_seen, radiance)
        return mi.Spectrum(radiance * setup.polariscope.intensity(matrix)), aovs

    def _walk(self, scene, ray, plan, active, seeds, progress, segment_step, log=None):
        return walk(scene, ray, plan.setup, plan.decision.step_size, active, seeds, progress, segment_step,
                    self.config.max_crossings, log)

    def walk_refracted(self, scene: mi.Scene, ray: mi.Ray3f, plan: TracePlan, active: mi.Bool,
                       seeds: mi.UInt32, bounces: int = 0) -> refraction.RefractedPath:
        """The walk where surfaces refract (``refraction.py``)."""
        return refraction.trace(scene, ray, plan.setup, plan.decision.method, plan.decision.step_size, seeds,
                                active, self.config.max_crossings, bounces)

    def _ghost_state(self, scene: mi.Scene, ray: mi.Ray3f, plan: TracePlan, seeds: mi.UInt32,
                     active: mi.Bool = True) -> tuple:
        """A sampled path of up to ``max_bounces`` partial reflections: its Jones matrix as 8 numbers (per
        wavelength of a spectral march, side by side), zero where it took none (that is the transmitted path,
        counted on its own) or brings no light."""
        ghost = self.walk_refracted(scene, ray, plan, mi.Bool(active), seeds, self.config.max_bounces)
        dark = ghost.blocked | (ghost.reflections == 0)
        return tuple(dr.select(dark, 0.0, x) for matrix, _ in ghost.lanes for x in tuple(matrix[0]) + tuple(matrix[1]))

    def replay(self, scene: mi.Scene, ray: mi.Ray3f, plan: TracePlan, active: mi.Bool, seeds: mi.UInt32,
               state: tuple, state_grad: tuple, segments: SegmentLog | None = None) -> None:
        """Adjoint pass of the straight walk: march again, back-propagating ``state_grad`` into every step's
        field lookups; through the primal walk's ``segments`` where it kept them."""
        method = plan.decision.method

        def segment_step(progress: object, segment: Segment, setup: SceneSetup) -> object:
            return method.replay(progress, state_grad, segment, setup)
        if segments is not None:
            walk_logged(ray, plan.setup, segments, method.replay_start(state), segment_step)
        else:
            self._walk(scene, ray, plan, active, seeds, method.replay_start(state), segment_step)


def _ray_seeds(seed, count):
    # Opaque: a literal seed would be compiled into the kernel, rebuilding it for every new seed.
    return mi.sample_tea_32(dr.opaque(mi.UInt32, seed), dr.arange(mi.UInt32, count))[0]


def _ghost_seeds(seed, count):
    """Per ray, the ghost walk's own stream (apart from the transmitted walk's jitter)."""
    return mi.sample_tea_32(dr.opaque(mi.UInt32, seed), dr.arange(mi.UInt32, count))[1]


def _lane_matrices(values: tuple, width: int, start: int) -> list[jones.Biquaternion]:
    """From a refracted batch's state (``width`` numbers per wavelength), each wavelength's matrix at ``start``
    (0: the transmitted path's, 8: the ghost's)."""
    return [_biquaternion(values[k + start:k + start + 8]) for k in range(0, len(values), width)]


def _biquaternion(values: tuple) -> jones.Biquaternion:
    return jones.Biquaternion((tuple(values[:4]), tuple(values[4:])))
