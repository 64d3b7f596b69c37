from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
from typing import Any, Callable, Iterator

import drjit as dr
import mitsuba as mi

from mi_nest import occupancy
from mi_nest.fields import StressField
from mi_nest.integration import film as films
from mi_nest.integration import guards, methods, refraction
from mi_nest.integration.film import CHANNELS, UNDIFFERENTIATED
from mi_nest.integration.setup import SceneSetup
from mi_nest.physics import MEASUREMENTS, Polariscope, jones, su2
from mi_nest.physics.aliasing import FringeAliasing

# Queries again, each from a little further on, for a crossing that a ray inside a specimen did not find (walk).
EXTRA_LOOKS = 2


@dataclass(frozen=True)
class View:
    """What :meth:`PhotoelasticIntegrator.looking_through` sets: a polariscope instead of the scene's (None: the
    scene's) and a factor on every phase."""
    polariscope: Polariscope | None = None
    phase_scale: float = 1.0


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
class Prepared:
    """What the calls inside one render or ray batch share: the scene set-up and the method decided for it."""
    setup: SceneSetup
    decision: methods.Decision
    norm_error: mi.Float | None = None      # a method that is not unitary: how far |J|^2 drifted


class PhotoelasticIntegrator(mi.ad.integrators.common.ADIntegrator):
    r"""
    .. _integrator-photoelastic:

    Photoelastic integrator (:monosp:`photoelastic`)
    ------------------------------------------------

    .. pluginparameters::

     * - step_size
       - |float|
       - Longest march step in mm. Each chord through a specimen is split into
         ``ceil(L / step_size)`` equal steps. (Default: 0.5)

     * - jitter
       - |bool|
       - Sample each step at a uniformly random (stratified) point instead of
         its midpoint. (Default: |false|)

     * - method
       - |string|
       - Model of the ordered exponential (docs/physics.md section 4): ``product``
         (exact exponential per step), ``linear`` (sum the projected stress
         along the ray, exponentiate once: exact only when the steps commute),
         ``magnus4`` (two Gauss points per step plus the commutator; fourth
         order, unitary) or ``rk4`` (Runge-Kutta on the ODE; fourth order, not
         unitary) or ``auto`` (see ``tolerance``). (Default: ``product``)

     * - tolerance
       - |float|
       - For ``auto``: the largest error of the 16 normalised intensities to aim
         for. ``auto`` samples the field inside the specimens along the light
         before each render: where the principal axes never turn along the rays
         the steps commute and it uses ``linear`` (one step per chord for a field
         constant along the rays); otherwise ``magnus4`` with the longest step
         that step doubling on the hardest sampled chords finds within
         ``tolerance``. It logs its choice and why. (Default: 1e-3)

     * - points
       - |string|
       - For ``product``: sample each step at its ``midpoint`` (second order)
         or at its ``left`` end (first order). (Default: ``midpoint``)

     * - max_crossings
       - |int|
       - Most surface crossings followed per ray; a guard against broken meshes.
         Where surfaces refract, a ray that would cross more (trapped by total
         internal reflection) brings no light. (Default: 64)

     * - max_bounces
       - |int|
       - Where surfaces refract: most partial reflections followed per ghost
         path. Each sample then also walks one path that chooses at random,
         at every crossing, reflection or transmission, and adds its
         intensity (unbiased for the ghosts of up to ``max_bounces``
         reflections); 0 follows the transmitted path alone. Ray batches
         carry the ghost too, so reconstruction models what renders show
         (docs/refraction.md). (Default: 4)

    Renders integrated photoelasticity (docs/physics.md): for every camera ray it
    follows the light from the ``polariscope_light`` panel to the camera through
    every shape whose interior is a ``stress`` medium, entering and leaving as
    often as the geometry requires (entry where the ray meets the outside of a
    surface, exit at the next crossing; specimens may touch face to face, but
    not nest), and multiplies the exact exponential
    of each constant-stress step as an SU(2) quaternion, renormalised at every
    step. Any other shape is opaque, unless its surface is a smooth
    ``dielectric`` (an immersion bath).

    A specimen or bath whose surface carries ``<bsdf type="dielectric">``
    refracts: the walk follows Snell's law at it and multiplies in the Fresnel
    transmission as a Jones matrix in the ray's transverse frame, carried along
    the bent path without twist; total internal reflection reflects the ray
    with its phases (docs/physics.md section 8, ``mi_nest/integration/
    refraction.py``). The Jones channels then hold the specimens' own product
    and the intensities the whole path's. Ray batches (``trace_rays``) then
    return the path's matrix as 8 numbers, and ``backpropagate_rays`` replays
    it (``product`` and ``magnus4``); ``render_backward`` is not available
    through refracting surfaces. With ``max_bounces`` each sample adds a ghost
    path's intensities, in renders and ray batches alike (16 numbers then).

    The film receives the intensity of the scene's polariscope as its main
    channel (``Y``) and, as named channels, the Jones product
    ``jones.a/b/c/d``, its characteristic parameters ``char.delta``,
    ``char.theta``, ``char.gamma`` (radians), the 16 normalised intensities
    ``pol.<b1>.<b2>.<a2>`` of the multi-axis polariscope, ``fringe.order`` (the
    linear model's unwrapped fringe order: exact where the axes do not turn
    along the ray) and ``path.length``, the length (mm) of the ray's path
    inside specimens. After each render it measures the fringe density from
    ``fringe.order`` and warns where fringes are denser than the pixel grid
    (:meth:`render_with_aliasing` returns the report with the image).

    .. tabs::

        .. code-tab:: xml

            <integrator type="photoelastic">
                <float name="step_size" value="0.25"/>
            </integrator>
    """

    def __init__(self, props):
        mi.CppADIntegrator.__init__(self, props)
        self.step_size = float(props.get("step_size", 0.5))
        if not (math.isfinite(self.step_size) and self.step_size > 0):
            raise ValueError(f"photoelastic: 'step_size' must be a positive length in mm, "
                             f"got {self.step_size}")
        self.jitter = bool(props.get("jitter", False))
        self.method = props.get("method", "product")
        self.points = props.get("points", "midpoint")
        self.tolerance = float(props.get("tolerance", 1e-3))
        method = self._method()     # refuses unknown names
        if "points" in props and not isinstance(method, methods.Product):
            raise ValueError("photoelastic: 'points' applies to method 'product' only")
        if not (math.isfinite(self.tolerance) and self.tolerance > 0):
            raise ValueError(f"photoelastic: 'tolerance' must be positive, got {self.tolerance}")
        self.max_crossings = int(props.get("max_crossings", 64))
        if self.max_crossings < 2:
            raise ValueError(f"photoelastic: 'max_crossings' must be at least 2, got {self.max_crossings}")
        self.max_bounces = int(props.get("max_bounces", refraction.DEFAULT_MAX_BOUNCES))
        if self.max_bounces < 0:
            raise ValueError(f"photoelastic: 'max_bounces' must be 0 or more, got {self.max_bounces}")
        self.decision = None        # the method and step of the last render or ray batch, and for 'auto' why
        self._decided = None        # the decision that deciding_once() keeps
        self._prepared_now = None   # what the render in progress shares with sample()
        self._view = View()         # what looking_through() changes

    @contextlib.contextmanager
    def looking_through(self, polariscope: Polariscope | None = None, phase_scale: float = 1.0) -> Iterator[None]:
        """Renders and ray batches inside the block show the specimens through ``polariscope`` instead of the
        scene's, with every phase times ``phase_scale`` (a load scale, or a wavelength's ratio): what a view
        changes without loading the scene again."""
        if not math.isfinite(phase_scale):
            raise ValueError(f"photoelastic: the phase scale must be a finite number, got {phase_scale}")
        saved, self._view = self._view, View(polariscope, float(phase_scale))
        try:
            yield
        finally:
            self._view = saved

    def _method(self):
        """The method the properties name now (they may be changed between renders)."""
        return methods.from_properties(self.method, self.points, self.jitter, self.tolerance)

    def aov_names(self) -> list[str]:
        return list(CHANNELS)

    def to_string(self) -> str:
        return (f"PhotoelasticIntegrator[method={self.method}, step_size={self.step_size:g} mm, "
                f"points={self.points}, jitter={self.jitter}, max_crossings={self.max_crossings}, "
                f"max_bounces={self.max_bounces}]")

    def channel_names(self, film: mi.Film) -> list[str]:
        """Names of the channels of the image :meth:`render` returns, in order."""
        return films.channel_names(film)

    def check_scene(self, scene: mi.Scene, sensor: int | mi.Sensor = 0) -> None:
        """Raise :class:`~mi_nest.integration.guards.SceneSetupError` naming what the scene lacks.

        ``mi.render`` reports exceptions raised inside ``render`` only as a failed
        custom operation, so callers that want the message check first.
        """
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        with self._prepared(scene, sensor):     # what render prepares, the step count included
            pass

    def render(self, scene: mi.Scene, sensor: int | mi.Sensor = 0, seed: int = 0, spp: int = 0, develop: bool = True,
               evaluate: bool = True) -> mi.TensorXf:
        if not develop:
            raise ValueError("photoelastic: develop=True must be specified")
        return self.render_with_aliasing(scene, sensor, seed, spp)[0]

    def render_with_aliasing(self, scene: mi.Scene, sensor: int | mi.Sensor = 0, seed: int = 0, spp: int = 0,
                             field: StressField | None = None) -> tuple[mi.TensorXf, FringeAliasing]:
        """:meth:`render`, and the aliasing guard's report on the image.

        ``field``, if given, is rendered in every specimen instead of its own
        stress (a reconstruction's field); the specimens keep their material.
        """
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        with self._prepared(scene, sensor, field=field) as prepared:
            if films.sums_pixels_directly(sensor.film()):
                image, guarded = self._render_pixel_sums(scene, sensor, seed, spp)
            else:
                image = super().render(scene, sensor, seed, spp)
                guarded = films.guarded_channels(image)
            if prepared.norm_error is not None:
                guards.warn_if_not_unitary(float(prepared.norm_error[0]), prepared.decision.step_size)
            return image, guards.check_aliasing(*guarded)

    def render_backward(self, scene: mi.Scene, params: Any, grad_in: mi.TensorXf, sensor: int | mi.Sensor = 0,
                        seed: int = 0, spp: int = 0) -> None:
        """Reverse-mode derivative of :meth:`render` by path replay: memory does not grow with the steps.

        ``grad_in`` is the adjoint of the developed image; every channel but
        ``fringe.order`` and ``path.length`` propagates to the field.
        """
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        if not films.sums_pixels_directly(sensor.film()):
            raise ValueError("photoelastic: differentiable rendering needs a box-filtered film "
                             '(<rfilter type="box"/>) without border')
        with self._prepared(scene, sensor) as prepared, dr.suspend_grad():
            guards.refuse_refraction(prepared.setup, "differentiable rendering")
            prepared.decision.method.require_adjoint()
            sampler, spp = self.prepare(sensor, seed, spp, self.aov_names())
            ray, weight, _ = self.sample_rays(scene, sensor, sampler)
            # Each pixel is the mean of its spp consecutive samples: each sample receives grad / spp.
            grad = mi.TensorXf(grad_in)
            channels = grad.shape[-1]
            pixel = dr.arange(mi.UInt32, dr.width(ray.o)) // spp
            per_sample = [dr.gather(mi.Float, grad.array, pixel * channels + c) * (weight / spp)
                          for c in range(channels)]
            first = channels - len(CHANNELS)
            _, _, _, state = self.sample(dr.ADMode.Primal, scene, sampler.clone(), ray, mi.Bool(True))
            self.sample(dr.ADMode.Backward, scene, sampler, ray, mi.Bool(True), δL=mi.Spectrum(per_sample[0]),
                        δaovs=per_sample[first:], state_in=state)

    def render_forward(self, scene: mi.Scene, params: Any, sensor: int | mi.Sensor = 0, seed: int = 0,
                       spp: int = 0) -> mi.TensorXf:
        raise NotImplementedError("photoelastic: forward-mode derivatives are not available; differentiate in "
                                  "reverse mode (dr.backward on the rendered image)")

    @contextlib.contextmanager
    def _prepared(self, scene, sensor, right=None, field=None, marching=True):
        """The scene set-up and the method for one render or ray batch (``auto`` decides here); ``marching=False``
        for one that only decides."""
        setup = SceneSetup(scene, sensor, right, field, self._view.phase_scale, marching)
        if self._view.polariscope is not None:
            setup.polariscope = OpaquePolariscope(self._view.polariscope)
        decision = self._decided
        if decision is None:
            decision = self._method().decide(setup, scene, sensor, self.step_size)
            if decision.reason is None:         # a step given, not one 'auto' chose for this field
                guards.warn_if_coarse(setup, scene, sensor, decision.step_size)
        guards.check_steps_per_ray(setup.specimen_diagonal, decision.step_size)
        self.decision = decision
        self._prepared_now = Prepared(setup, decision)
        try:
            yield self._prepared_now
        finally:
            self._prepared_now = None

    @contextlib.contextmanager
    def deciding_once(self, scene: mi.Scene, sensor: int | mi.Sensor = 0,
                      field: StressField | None = None) -> Iterator[None]:
        """Renders inside the block reuse one decision of the method, made on entry.

        For several passes over one unchanged scene and camera (``mi_nest.render``
        splits its samples so): the ``auto`` analysis costs about 10 ms whatever
        the resolution. The scene must not change inside the block.
        """
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        if self._decided is not None:
            yield
            return
        with self._prepared(scene, sensor, field=field, marching=False) as prepared:
            self._decided = prepared.decision
        try:
            yield
        finally:
            self._decided = None

    def trace_rays(self, scene: mi.Scene, rays: mi.Ray3f, right: mi.Vector3f, seed: int = 0,
                   field: StressField | None = None) -> tuple[tuple, mi.Bool, mi.Float]:
        """Primal march of arbitrary rays (e.g. a training batch drawn across views).

        ``right`` is each ray's image-right direction (its camera's), which fixes
        the polariscope frame; ``field``, if given, is marched in every specimen
        instead of its own stress. Returns ``(state, blocked, length)``: the
        accumulated state (the Jones quaternion, or for ``linear`` the summed
        generator; where surfaces refract the path's general Jones matrix, and
        with ``max_bounces`` a sampled ghost path's after it; see :meth:`jones`),
        whether an opaque shape stops the ray (its transmitted path), and its path
        length (mm) inside specimens.
        """
        with dr.suspend_grad(), self._prepared(scene, None, right, field) as prepared:
            seeds = _ray_seeds(seed, dr.width(rays.o))
            method = prepared.decision.method
            if prepared.setup.refracting:
                path = self.walk_refracted(scene, rays, prepared, mi.Bool(True), seeds)
                state = tuple(path.jones[0]) + tuple(path.jones[1])
                if self.max_bounces > 0:
                    state += self._ghost_state(scene, rays, prepared, _ghost_seeds(seed, dr.width(rays.o)))
                dr.eval(state, path.blocked, path.length)
                return state, path.blocked, path.length
            (state, _), blocked, length = self.walk(scene, rays, prepared, mi.Bool(True), seeds,
                                                    method.trace_start(), method.trace)
            blocked = self._past_panel(prepared.setup, rays, blocked)
            dr.eval(state, blocked, length)
            return state, blocked, length

    def backpropagate_rays(self, scene: mi.Scene, rays: mi.Ray3f, right: mi.Vector3f, state: tuple,
                           state_grad: tuple, seed: int = 0, field: StressField | None = None) -> None:
        """Accumulate into the field parameters the gradient of ``sum(state_grad . state)``.

        Replays the march of :meth:`trace_rays` (same rays, right, seed and
        field); Jones steps are unitary, so the part of the product still ahead
        is peeled off with conjugates instead of being stored: memory does not
        grow with the number of steps.
        """
        with dr.suspend_grad(), self._prepared(scene, None, right, field) as prepared:
            prepared.decision.method.require_adjoint()
            if prepared.setup.refracting:
                guards.require_product_through_refraction(prepared.decision.method)
                total, grad = (tuple(mi.Float(x) for x in values) for values in (state, state_grad))
                dr.make_opaque(total, grad)
                count = dr.width(rays.o)
                # The transmitted path, then the ghost (the same choices again: the same seeds).
                for start, seeds, bounces in ((0, _ray_seeds(seed, count), 0),
                                              (8, _ghost_seeds(seed, count), self.max_bounces))[:len(total) // 8]:
                    refraction.replay(scene, rays, prepared.setup, prepared.decision.method,
                                      prepared.decision.step_size, seeds, mi.Bool(True), self.max_crossings,
                                      RaySegment, _biquaternion(total[start:start + 8]),
                                      _biquaternion(grad[start:start + 8]), bounces)
                    # Each replay's accumulation into the field's gradients runs before the next is traced: without
                    # it, the second replay's share was lost in about one run in three (Dr.Jit 1.x, LLVM).
                    dr.eval()
                return
            # Unevaluated adjoints carry the loss's constants (1 / batch size...) into the kernel,
            # which would then be rebuilt whenever they change.
            state, state_grad = tuple(mi.Float(x) for x in state), tuple(mi.Float(x) for x in state_grad)
            dr.make_opaque(state, state_grad)
            seeds = _ray_seeds(seed, dr.width(rays.o))
            self.replay(scene, rays, prepared, mi.Bool(True), seeds, state, state_grad)

    def trace_chords(self, scene: mi.Scene, origins: mi.Point3f, d: mi.Vector3f, chords: list[tuple],
                     right: mi.Vector3f, step_size: float | None = None, seed: int = 0,
                     field: StressField | None = None) -> tuple[mi.Float, list[mi.Float], tuple]:
        """Straight chords that the caller chose, marched as the walk marches its segments (for virtual slices).

        Each of ``chords`` is ``(start, end, medium)`` per line ``origins + t d``:
        distances along ``d`` (away from the camera, in that order) and the index
        of the specimen medium there plus one (0: nothing). Returns a render's
        main intensity, its AOV channels and the summed fringe generator
        ``(b, c)``, with steps no longer than ``step_size`` if given.
        """
        with dr.suspend_grad(), self._prepared(scene, None, right, field) as prepared:
            setup = prepared.setup
            method = prepared.decision.method
            step = prepared.decision.step_size if step_size is None else min(step_size, prepared.decision.step_size)
            coefficients = setup.projection_coefficients(d)
            seeds = _ray_seeds(seed, dr.width(origins))
            carry = method.trace_start()
            length = mi.Float(0)
            for index, (start, end, medium) in enumerate(chords):
                chord = dr.maximum(end - start, 0.0)
                marched = (medium != 0) & (chord > 0)
                steps, h = methods.equal_steps(chord, marched, step)
                segment = RaySegment(steps, h, mi.UInt32(medium), dr.fma(d, start, origins), d, coefficients,
                                     mi.sample_tea_32(seeds, mi.UInt32(index))[0])
                carry = method.trace(carry, segment, setup)
                length += dr.select(marched, chord, 0.0)
            state, fringe = carry
            main, aovs = self.outputs(state, fringe, mi.Bool(False), length)
            dr.eval(main, aovs, fringe)
            return main[0], aovs, fringe

    @staticmethod
    def _past_panel(setup: SceneSetup, ray: mi.Ray3f, blocked: mi.Bool) -> mi.Bool:
        """A straight ray that misses a finite light panel brings no light either."""
        if setup.panel is None:
            return blocked
        return blocked | setup.misses_panel(mi.Point3f(ray.o), mi.Vector3f(ray.d), mi.Vector3f(ray.d))

    def jones(self, state: tuple, blocked: mi.Bool) -> su2.Quaternion | jones.Biquaternion | jones.Incoherent:
        """The Jones matrix from a traced state (zero where blocked): a quaternion, or where surfaces refract
        (an 8-tuple state) the path's general Jones matrix, and with a ghost path (16) both, to be added
        incoherently (the ghost is zero where it has none)."""
        if len(state) == 16:
            return jones.Incoherent((self.jones(state[:8], blocked), _biquaternion(state[8:])))
        if len(state) == 8:
            return _biquaternion(tuple(dr.select(blocked, 0.0, x) for x in state))
        return su2.Quaternion(tuple(dr.select(blocked, 0.0, x) for x in self.decision.method.finish(state)))

    def _render_pixel_sums(self, scene, sensor, seed, spp):
        """``ADIntegrator.render`` for box-filtered films, without per-sample atomics (see ``film``)."""
        with dr.suspend_grad():
            sampler, spp = self.prepare(sensor, seed, spp, self.aov_names())
            ray, weight, _ = self.sample_rays(scene, sensor, sampler)
            main, _, aovs, _ = self.sample(dr.ADMode.Primal, scene, sampler, ray, mi.Bool(True))
            return films.develop_pixel_sums(sensor.film(), spp, (main * weight)[0], aovs)

    def sample(self, mode: dr.ADMode, scene: mi.Scene, sampler: mi.Sampler, ray: mi.Ray3f, active: mi.Bool,
               δL: mi.Spectrum | None = None, δaovs: list[mi.Float] | None = None, state_in: tuple | None = None,
               **kwargs) -> tuple:
        prepared = self._prepared_now
        method = prepared.decision.method
        seeds = mi.UInt32(sampler.next_1d() * 4294967296.0)
        if mode == dr.ADMode.Primal and prepared.setup.refracting:
            path = self.walk_refracted(scene, ray, prepared, active, seeds)
            ghost = None
            if self.max_bounces > 0:
                ghost_seeds = mi.UInt32(sampler.next_1d() * 4294967296.0)
                ghost = _biquaternion(self._ghost_state(scene, ray, prepared, ghost_seeds, active))
            main, aovs = self.outputs(path.stress, path.fringe, path.blocked, path.length, path.jones, ghost)
            return main, mi.Bool(True), aovs, None
        if mode == dr.ADMode.Primal:
            (state, fringe), blocked, length = self.walk(scene, ray, prepared, active, seeds,
                                                         method.trace_start(), method.trace)
            blocked = self._past_panel(prepared.setup, ray, blocked)
            if not method.unitary:
                # Measure how far it drifted (read after the render).
                prepared.norm_error = dr.max(dr.select(blocked, 0.0, dr.abs(su2.norm_squared(state) - 1.0)))
            main, aovs = self.outputs(state, fringe, blocked, length)
            return main, mi.Bool(True), aovs, (state, fringe, blocked, length)
        if mode != dr.ADMode.Backward:
            raise NotImplementedError("photoelastic: forward-mode derivatives are not available")
        state, fringe, blocked, length = state_in
        with dr.resume_grad():
            leaf = tuple(mi.Float(dr.detach(x)) for x in state)
            dr.enable_grad(leaf)
            main, aovs = self.outputs(leaf, fringe, blocked, length)
            objective = dr.sum(δL * main)
            for name, value, grad in zip(CHANNELS, aovs, δaovs):
                # Only channels of the Jones product carry a derivative; skipping zero adjoints also
                # keeps 0 * inf (char.theta at zero retardance) out of the sum.
                if name not in UNDIFFERENTIATED and dr.any(grad != 0, axis=None):
                    objective += grad * value
            dr.backward_from(objective)
            state_grad = dr.grad(leaf)
        self.replay(scene, ray, prepared, active, seeds, state, state_grad)
        return mi.Spectrum(0), mi.Bool(True), [mi.Float(0)] * len(CHANNELS), None

    def outputs(self, state: tuple, fringe: tuple, blocked: mi.Bool, length: mi.Float,
                path_jones: jones.Biquaternion | None = None,
                ghost: jones.Biquaternion | None = None) -> tuple[mi.Spectrum, list[mi.Float]]:
        """Main intensity and the AOV channels from a traced state; with ``path_jones`` (a refracted path's
        whole Jones matrix) the intensities are its, the Jones channels the specimens' own; a ``ghost``
        path's (partly reflected, zero where there is none) intensities add to them (incoherent light)."""
        setup = self._prepared_now.setup
        q = self.jones(state, blocked)
        matrix = q if path_jones is None else self.jones(tuple(path_jones[0]) + tuple(path_jones[1]), blocked)
        if ghost is not None:
            matrix = jones.Incoherent((matrix, ghost))
        delta, theta, gamma = su2.characteristic_parameters(q)
        radiance = setup.radiance
        aovs = list(q) + [delta, theta, gamma]
        aovs += [radiance * scope.intensity(matrix) for scope in MEASUREMENTS.values()]
        aovs.append(dr.select(blocked, 0.0, dr.norm(mi.Vector2f(fringe)) / dr.pi))
        aovs.append(length)
        return mi.Spectrum(radiance * setup.polariscope.intensity(matrix)), aovs

    @dr.syntax
    def walk(self, scene: mi.Scene, ray: mi.Ray3f, prepared: Prepared, active: mi.Bool, seeds: mi.UInt32,
             carry: object, segment: Callable) -> tuple[object, mi.Bool, mi.Float]:
        """Follow each ray through every specimen; ``carry = segment(carry, ...)`` for each inside segment.

        Returns ``(carry, blocked, length)``: whether an opaque shape stops the ray,
        and its length inside specimens. The primal pass and the adjoint replay
        differ only in ``carry`` and ``segment``.

        Inside a specimen the next crossing must be its exit (or a glued
        neighbour's face, or an opaque shape), and an exit must follow an entry
        (or another specimen's exit: faces glued, the coincident entry skipped).
        Where they do not, Embree missed a face where the ray met a mesh edge (it
        does without robust intersections, whatever flags the scene was loaded
        with) or the ray grazed a silhouette: the query is made again from a
        point nudged by a surface clearance (``occupancy.nudged``), not flagged
        coherent (coherent queries round alike), up to :data:`EXTRA_LOOKS`
        times. What is still there was a touch, and marches nothing.
        """
        setup, step_size = prepared.setup, prepared.decision.step_size
        d = mi.Vector3f(ray.d)
        coefficients = setup.projection_coefficients(d)
        origin = mi.Point3f(ray.o)
        launch = mi.Point3f(ray.o)      # where the next intersection query starts
        reach = mi.Float(ray.maxt)      # and how far it looks: the camera's range, then unbounded
        medium = mi.UInt32(0)           # 0 outside, i + 1 inside specimen medium i
        current = mi.UInt32(0)          # the specimen shape the ray is in (0 outside)
        after_exit = mi.Bool(False)     # whether the last crossing left a specimen
        looks = mi.UInt32(0)            # queries again for the same crossing
        blocked = mi.Bool(False)
        length = mi.Float(0)
        crossings = mi.UInt32(0)
        active = mi.Bool(active)

        # Only what changes is loop state: Dr.Jit traces the body again to drop any state that does not.
        while dr.hint(active, exclude=[coefficients, d, prepared, ray, scene, seeds, segment, self, setup,
                                            step_size]):
            si = scene.ray_intersect(mi.Ray3f(launch, d, reach, ray.time, ray.wavelengths),
                                     ray_flags=mi.RayFlags.Minimal, coherent=setup.coherent_rays & (looks == 0),
                                     active=active)
            hit = si.is_valid()
            shape = dr.reinterpret_array(mi.UInt32, si.shape)
            hit_medium = dr.gather(mi.UInt32, setup.medium_of_shape, shape, hit)
            entering = dr.dot(si.n, d) < 0
            exiting = hit & ~entering & (hit_medium != 0)
            unexpected = dr.select(medium != 0, ~hit | (entering & (shape == current)), exiting & ~after_exit)
            look_again = active & unexpected & (looks < EXTRA_LOOKS)
            # Leaving a specimen proves the segment was inside it, even if its entry face was
            # skipped for coinciding with the face just left (specimens glued face to face).
            inside = dr.select(exiting, hit_medium, medium)
            # The chord between hit points, not the spawned ray's t (its origin is offset).
            chord = dr.norm(si.p - origin)
            marched = active & hit & (inside != 0) & ~unexpected
            steps, h = methods.equal_steps(chord, marched, step_size)
            segment_seed = mi.sample_tea_32(seeds, crossings)[0]
            carry = segment(carry, RaySegment(steps, h, inside, origin, d, coefficients, segment_seed), setup)
            length += dr.select(marched, chord, 0.0)
            crossed = ~look_again
            blocked |= crossed & hit & (hit_medium == 0)
            medium = dr.select(crossed, dr.select(entering, hit_medium, 0), medium)
            current = dr.select(crossed, dr.select(entering & (hit_medium != 0), shape, 0), current)
            after_exit = dr.select(crossed, exiting & ~unexpected, after_exit)
            origin = dr.select(crossed, si.p, origin)
            launch = dr.select(crossed, occupancy.past_surface(si, d), occupancy.nudged(launch, d, looks))
            reach = dr.select(crossed, dr.inf, reach)
            looks = dr.select(crossed, 0, looks + 1)
            crossings += 1
            active &= (hit | look_again) & ~blocked & (crossings < self.max_crossings)
        return carry, blocked, length

    def trace_refracted(self, scene: mi.Scene, rays: mi.Ray3f, sensor: int | mi.Sensor = 0,
                        seed: int = 0, bounces: int = 0) -> refraction.RefractedPath:
        """The refracted walk of arbitrary ``rays`` in ``sensor``'s polariscope frame: each ray's exit point and
        direction, interfaces crossed and Jones matrices (for tools and tests; renders call it per sample). With
        ``bounces``, a sampled path of up to that many partial reflections instead of the transmitted one."""
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        with dr.suspend_grad(), self._prepared(scene, sensor) as prepared:
            path = self.walk_refracted(scene, rays, prepared, mi.Bool(True), _ray_seeds(seed, dr.width(rays.o)),
                                       bounces)
            dr.eval(path)
            return path

    def walk_refracted(self, scene: mi.Scene, ray: mi.Ray3f, prepared: Prepared, active: mi.Bool,
                       seeds: mi.UInt32, bounces: int = 0) -> refraction.RefractedPath:
        """The walk where surfaces refract (``mi_nest/integration/refraction.py``)."""
        return refraction.trace(scene, ray, prepared.setup, prepared.decision.method, prepared.decision.step_size,
                                seeds, active, self.max_crossings, RaySegment, bounces)

    def _ghost_state(self, scene: mi.Scene, ray: mi.Ray3f, prepared: Prepared, seeds: mi.UInt32,
                     active: mi.Bool = True) -> tuple:
        """A sampled path of up to ``max_bounces`` partial reflections: its Jones matrix as 8 numbers, zero where
        it took none (that is the transmitted path, counted on its own) or brings no light."""
        ghost = self.walk_refracted(scene, ray, prepared, mi.Bool(active), seeds, self.max_bounces)
        dark = ghost.blocked | (ghost.reflections == 0)
        return tuple(dr.select(dark, 0.0, x) for x in tuple(ghost.jones[0]) + tuple(ghost.jones[1]))

    def replay(self, scene: mi.Scene, ray: mi.Ray3f, prepared: Prepared, active: mi.Bool, seeds: mi.UInt32,
               state: tuple, state_grad: tuple) -> None:
        """Adjoint pass: march again, back-propagating ``state_grad`` into every step's field lookups."""
        method = prepared.decision.method

        def segment(carry: object, segment: RaySegment, setup: SceneSetup) -> object:
            return method.replay(carry, state_grad, segment, setup)
        self.walk(scene, ray, prepared, active, seeds, method.replay_start(state), segment)


class RaySegment:
    """One inside chord of each ray: ``steps`` steps of length ``h`` from ``origin`` along ``d``."""

    DRJIT_STRUCT = {"steps": mi.UInt32, "h": mi.Float, "medium": mi.UInt32, "origin": mi.Point3f,
                    "d": mi.Vector3f, "coefficients": tuple, "seed": mi.UInt32}

    def __init__(self, steps=None, h=None, medium=None, origin=None, d=None, coefficients=None, seed=None):
        self.steps, self.h, self.medium, self.origin, self.d = steps, h, medium, origin, d
        self.coefficients, self.seed = coefficients, seed


def _ray_seeds(seed, count):
    # Opaque: a literal seed would be compiled into the kernel, rebuilding it for every new seed.
    return mi.sample_tea_32(dr.opaque(mi.UInt32, seed), dr.arange(mi.UInt32, count))[0]


def _ghost_seeds(seed, count):
    """Per ray, the ghost walk's own stream (apart from the transmitted walk's jitter)."""
    return mi.sample_tea_32(dr.opaque(mi.UInt32, seed), dr.arange(mi.UInt32, count))[1]


def _biquaternion(values: tuple) -> jones.Biquaternion:
    return jones.Biquaternion((tuple(values[:4]), tuple(values[4:])))


mi.register_integrator("photoelastic", lambda props: PhotoelasticIntegrator(props))
